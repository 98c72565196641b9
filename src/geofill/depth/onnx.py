"""Learned monocular depth with ONNX Runtime: Depth Anything V2 Small, DPT-Hybrid, MiDaS v2.1 small.

Each network has its own preprocessing (input size and resize rule, multiple-of constraint,
normalisation) and outputs relative inverse depth ("disparity", affine-ambiguous) at its input
resolution, which is resized back to the source's. The pipeline then fixes the affine ambiguity
(``align_depth``, or the dense fit to stereo in ``fused``). Weights are resolved by
:func:`geofill.weights.resolve_weights`; none ship with geofill.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from ..config import DepthConfig
from ..errors import DepthModelError, MissingExtraError
from ..extras import require
from ..weights import ResolvedWeights, WeightsSpec, WeightsUnavailable, resolve_weights
from . import DepthContext, DepthPrediction

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


@dataclass(frozen=True)
class ModelSpec:
    """A network's weights, preprocessing and output convention.

    Resize rule (transformers' ``DPTImageProcessor``, which the ONNX exports were made for): with
    ``keep_aspect`` the image is scaled by whichever of ``size/height`` and ``size/width`` is closer
    to 1 (the smallest change), else stretched to ``size`` x ``size``; each side is then rounded to
    the nearest multiple of ``multiple_of``. Pixels go to [0, 1] RGB, then ``(x - mean) / std``."""

    weights: WeightsSpec
    size: int
    keep_aspect: bool
    multiple_of: int
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    interpolation: int  # cv2 flag of the resize to the network's input


MODELS: dict[str, ModelSpec] = {
    # onnx-community's export of depth-anything/Depth-Anything-V2-Small-hf (Apache-2.0): input
    # ``pixel_values`` 1x3xHxW (H, W multiples of the ViT's 14-px patch), output ``predicted_depth``
    # 1xHxW; preprocessing from its preprocessor_config.json (518, keep aspect, x14, bicubic, ImageNet).
    "depth-anything-v2-small": ModelSpec(
        WeightsSpec(
            name="Depth Anything V2 Small (ONNX)",
            repo_id="onnx-community/depth-anything-v2-small",
            filename="onnx/model.onnx",
            revision="d0c64dd0d482bee54ac575ba679315716526f4f3",
            sha256="afb6a5c28f3b6bf1618c6e43f02073ef9dfdc70e937502d51603e57b0a1df10c",
            env_var="GEOFILL_DEPTH_ANYTHING_V2_SMALL",
            license="Apache-2.0",
        ),
        size=518,
        keep_aspect=True,
        multiple_of=14,
        mean=IMAGENET_MEAN,
        std=IMAGENET_STD,
        interpolation=cv2.INTER_CUBIC,
    ),
    # Xenova's export of Intel/dpt-hybrid-midas (the paper's network; Apache-2.0), pinned to the
    # commit that added onnx/model.onnx (533 MB). No published checksum was found, so it is used
    # unverified (and said so). Preprocessing from its preprocessor_config.json: 384x384 without
    # keeping the aspect, bilinear, mean = std = 0.5.
    "dpt-hybrid": ModelSpec(
        WeightsSpec(
            name="DPT-Hybrid MiDaS (ONNX)",
            repo_id="Xenova/dpt-hybrid-midas",
            filename="onnx/model.onnx",
            revision="c9ab952ed178a2f0c085a4602d0a9da35bc54bca",
            env_var="GEOFILL_DPT_HYBRID",
            license="Apache-2.0",
        ),
        size=384,
        keep_aspect=False,
        multiple_of=1,
        mean=(0.5, 0.5, 0.5),
        std=(0.5, 0.5, 0.5),
        interpolation=cv2.INTER_LINEAR,
    ),
    # The official MiDaS v2.1 small ONNX (GitHub release v2_1, MIT): 256x256 RGB in [0, 1] resized
    # bicubically; the ImageNet normalisation is inside the exported graph (MiDaS' tf/
    # make_onnx_model.py wraps the net in a normalising forward), so none is applied here. Two
    # different SHA-256 values circulate for this file, so none is pinned.
    "midas-v2.1-small": ModelSpec(
        WeightsSpec(
            name="MiDaS v2.1 small (ONNX)",
            url="https://github.com/isl-org/MiDaS/releases/download/v2_1/model-small.onnx",
            filename="model-small.onnx",
            revision="v2_1",
            env_var="GEOFILL_MIDAS_SMALL",
            license="MIT",
        ),
        size=256,
        keep_aspect=False,
        multiple_of=32,
        mean=(0.0, 0.0, 0.0),
        std=(1.0, 1.0, 1.0),
        interpolation=cv2.INTER_CUBIC,
    ),
}


def input_size(height: int, width: int, spec: ModelSpec) -> tuple[int, int]:
    """(height, width) of the network input for an image of ``height`` x ``width``."""
    sh, sw = spec.size / height, spec.size / width
    if spec.keep_aspect:
        sh = sw = sw if abs(1 - sw) < abs(1 - sh) else sh
    m = spec.multiple_of
    return max(round(sh * height / m) * m, m), max(round(sw * width / m) * m, m)


def preprocess(image: np.ndarray, spec: ModelSpec) -> np.ndarray:
    """Float RGB image in [0, 1] (H, W, 3) -> network input (1, 3, h, w) float32."""
    h, w = input_size(*image.shape[:2], spec)
    x = cv2.resize(image.astype(np.float32), (w, h), interpolation=spec.interpolation)
    x = (x - np.array(spec.mean, np.float32)) / np.array(spec.std, np.float32)
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None])


def postprocess(output: np.ndarray, height: int, width: int) -> np.ndarray:
    """Network output (1, h, w) or (1, 1, h, w) -> (height, width) float32, bilinear."""
    out = np.asarray(output, dtype=np.float32)
    out = out.reshape(out.shape[-2:])
    return cv2.resize(out, (width, height), interpolation=cv2.INTER_LINEAR)


@lru_cache(maxsize=2)
def _session(path: str, mtime_ns: int):
    """One ONNX Runtime session per model file (loading a 100-MB model takes ~1 s)."""
    ort = require("onnxruntime", "learned depth (depth.backend onnx or fused)")
    return ort.InferenceSession(path, providers=["CPUExecutionProvider"])


def run_model(path: str, batch: np.ndarray) -> np.ndarray:
    """Run the ONNX model at ``path`` on ``batch``; its first input and first output are used."""
    sess = _session(str(path), Path(path).stat().st_mtime_ns)
    name = sess.get_inputs()[0].name
    return sess.run([sess.get_outputs()[0].name], {name: batch})[0]


def resolve_model(
    cfg: DepthConfig, say: Callable[[str], None] | None = None
) -> ResolvedWeights | WeightsUnavailable:
    """Weights of ``cfg.model`` (``cfg.model_path`` first; see :func:`geofill.weights.resolve_weights`)."""
    return resolve_weights(MODELS[cfg.model].weights, cfg.model_path, allow_download=cfg.download, say=say)


def predict_learned(image: np.ndarray, cfg: DepthConfig) -> np.ndarray:
    """Relative inverse depth (H, W) of ``image`` (float RGB in [0, 1]) from ``cfg.model``.

    Raises :class:`geofill.errors.DepthModelError` when the weights cannot be resolved or run."""
    weights = resolve_model(cfg)
    if isinstance(weights, WeightsUnavailable):
        raise DepthModelError(str(weights))
    spec = MODELS[cfg.model]
    try:
        out = run_model(str(weights.path), preprocess(image, spec))
    except MissingExtraError:
        raise
    except Exception as exc:  # onnxruntime raises its own exception types for bad files/shapes
        raise DepthModelError(f"{weights.path}: cannot run {spec.weights.name}: {exc}") from exc
    return postprocess(out, *image.shape[:2])


class OnnxDepth:
    """``onnx`` backend: the learned network's relative inverse depth, aligned later to the
    triangulated points by the pipeline's affine fit."""

    name = "onnx"

    def predict(self, ctx: DepthContext) -> DepthPrediction:
        values = predict_learned(ctx.source, ctx.cfg)
        return DepthPrediction(values, "inverse", self.name)
