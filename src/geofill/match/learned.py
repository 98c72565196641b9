"""The ``learned`` rung of the matching ladder: which learned matcher ``matching.learned_matcher``
selects (:func:`learned_matcher`): XFeat + LighterGlue on torch (:mod:`geofill.match.xfeat`), or an
end-to-end keypoint + matcher ONNX graph such as LightGlue-ONNX's SuperPoint + LightGlue pipeline
export, run through ONNX Runtime (:class:`LearnedMatcher`, below).

The graph's contract (that of the LightGlue-ONNX pipeline export): one input ``images``
(2, 1, H, W) float32 grey in [0, 1], the target then the source, H and W multiples of 8; outputs
``keypoints`` (2, N, 2) pixel positions (x, y) of each image, ``matches`` (M, 3) rows (batch
index, keypoint index in image 0, keypoint index in image 1) and ``mscores`` (M,). Both images are
resized to a long side of at most ``matching.learned_max_side`` and padded to a common size; the
matches come back in the input images' pixels.

Weights are resolved like the depth networks' (:func:`geofill.weights.resolve_weights`):
``matching.learned_model`` -> ``$GEOFILL_MATCHER_MODEL`` -> cache -> download (only with
``matching.download`` or ``geofill models download superpoint-lightglue``). No checksum of the
published export is known here, so a downloaded file is used unverified and said so."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from ..config import MatchingConfig
from ..errors import MatcherModelError
from ..extras import available, require
from ..weights import ResolvedWeights, WeightsSpec, WeightsUnavailable, resolve_weights

#: LightGlue-ONNX (Apache-2.0; SuperPoint's weights carry Magic Leap's non-commercial licence):
#: the pipeline export of its v2.0 release. The address could not be checked from this machine
#: (no network) and no checksum is published: the file is used unverified, and every report says so.
MATCHER_WEIGHTS = WeightsSpec(
    name="SuperPoint+LightGlue (ONNX)",
    filename="superpoint_lightglue_pipeline.onnx",
    url="https://github.com/fabio-sim/LightGlue-ONNX/releases/download/v2.0/superpoint_lightglue_pipeline.onnx",
    env_var="GEOFILL_MATCHER_MODEL",
    license="Apache-2.0 (export); SuperPoint weights: Magic Leap, non-commercial",
)
#: Image sides the graph accepts are multiples of this (SuperPoint's 8-px cells).
_CELL = 8


class LearnedMatcher:
    """A loaded matcher graph; call it with two grey uint8 images -> (pts_target, pts_source, scores)."""

    def __init__(self, path: str | Path, max_side: int):
        ort = require("onnxruntime", "learned matching (matching.learned)")
        self.path, self.max_side = Path(path), max_side
        self.session = ort.InferenceSession(str(self.path), providers=["CPUExecutionProvider"])
        inputs = self.session.get_inputs()
        outputs = {o.name for o in self.session.get_outputs()}
        if len(inputs) != 1 or len(inputs[0].shape) != 4 or not {"keypoints", "matches"} <= outputs:
            desc = ", ".join(f"{i.name}{list(i.shape)}" for i in inputs)
            raise ValueError(
                f"{self.path}: not a keypoints+matches graph (inputs {desc}; outputs {sorted(outputs)})"
            )
        self.input_name = inputs[0].name

    def cannot_take(self, gray_t: np.ndarray, gray_s: np.ndarray) -> str:
        """Why the graph cannot take these images: never (any side is resized to at least one
        pixel and padded to whole cells)."""
        return ""

    def __call__(
        self, gray_t: np.ndarray, gray_s: np.ndarray, mask_t: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Matched positions (M, 2) in each image's own pixels, and the matcher's scores (M,). The
        graph detects on the whole target: ``mask_t`` is the ladder's to apply."""
        f = min(1.0, self.max_side / max(*gray_t.shape, *gray_s.shape))
        small = [_resized(g, f) for g in (gray_t, gray_s)]
        h = -(-max(g.shape[0] for g in small) // _CELL) * _CELL
        w = -(-max(g.shape[1] for g in small) // _CELL) * _CELL
        batch = np.zeros((2, 1, h, w), np.float32)
        for k, g in enumerate(small):
            batch[k, 0, : g.shape[0], : g.shape[1]] = g / np.float32(255.0)
        names = [o.name for o in self.session.get_outputs()]
        out = dict(zip(names, self.session.run(None, {self.input_name: batch}), strict=True))
        kps = np.asarray(out["keypoints"], np.float64)
        matches = np.asarray(out["matches"], np.int64).reshape(-1, 3)
        scores = np.asarray(out.get("mscores", np.ones(len(matches))), np.float64).reshape(-1)
        matches = matches[matches[:, 0] == 0] if len(matches) else matches
        # Pixel centres: position p at scale f is (p + 0.5) / f - 0.5 in the input image.
        pts_t = (kps[0, matches[:, 1]] + 0.5) / f - 0.5
        pts_s = (kps[1, matches[:, 2]] + 0.5) / f - 0.5
        return pts_t, pts_s, scores[: len(matches)]


def _resized(gray: np.ndarray, f: float) -> np.ndarray:
    if f >= 1.0:
        return gray
    size = (max(round(gray.shape[1] * f), 1), max(round(gray.shape[0] * f), 1))
    return cv2.resize(gray, size, interpolation=cv2.INTER_AREA)


#: Loaded sessions by (resolved path, max side): loading costs seconds, every fill reuses it.
_SESSIONS: dict[tuple[Path, int], LearnedMatcher] = {}


def resolve_matcher_model(
    cfg: MatchingConfig, say: Callable[[str], None] | None = None
) -> ResolvedWeights | WeightsUnavailable:
    """The matcher graph (see the module docstring for the order), or why there is none."""
    return resolve_weights(MATCHER_WEIGHTS, cfg.learned_model, allow_download=cfg.download, say=say)


def learned_matcher(cfg: MatchingConfig) -> tuple[Callable | None, str]:
    """The matcher ``cfg`` asks for and what was used (for the report), or (None, why not).
    ``learned = on`` or an explicit model path that cannot be used raises (the missing extra:
    :class:`MissingExtraError`; unusable weights: :class:`MatcherModelError`)."""
    if cfg.learned == "off" and not cfg.learned_model:
        return None, "matching.learned is off"
    required = cfg.learned == "on" or bool(cfg.learned_model)
    if cfg.learned_model or cfg.learned_matcher == "onnx":
        return _onnx_matcher(cfg, required)
    from .xfeat import missing_modules, require_extra, xfeat_matcher

    missing = missing_modules()
    if missing:
        if required:
            require_extra()
        return None, f"the learned matcher needs the 'learned' extra (not installed: {', '.join(missing)})"
    try:
        matcher = xfeat_matcher(
            cfg.learned_max_keypoints, cfg.learned_max_side, cfg.learned_threads, cfg.learned_confidence
        )
    except MatcherModelError as exc:
        if required:
            raise
        return None, str(exc)
    return matcher, matcher.describe


def _onnx_matcher(cfg: MatchingConfig, required: bool) -> tuple[LearnedMatcher | None, str]:
    if not available("onnxruntime"):
        if required:
            require("onnxruntime", "learned matching (matching.learned)")
        return None, "learned matching needs onnxruntime, not installed"
    weights = resolve_matcher_model(cfg)
    if isinstance(weights, WeightsUnavailable):
        problem = str(weights)
    else:
        key = (weights.path.resolve(), cfg.learned_max_side)
        try:
            if key not in _SESSIONS:
                _SESSIONS[key] = LearnedMatcher(weights.path, cfg.learned_max_side)
            return _SESSIONS[key], weights.describe()
        except Exception as exc:  # onnxruntime raises its own types for unreadable/invalid models
            problem = f"{weights.describe()} could not be loaded: {type(exc).__name__}: {exc}".replace(
                "\n", " "
            )
    if required:
        raise MatcherModelError(problem)
    return None, problem
