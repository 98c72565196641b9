"""Dense depth of the source view, behind one interface.

A backend returns a :class:`DepthPrediction`: values that are an affine function of depth or of
inverse depth (learned networks and stereo disparity give the latter), plus where they are known.
:func:`geofill.depth.align.align_depth` then fixes the affine ambiguity with the triangulated points,
in the units of the pose translation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from ..camera import Intrinsics
from ..config import DepthConfig
from ..pose import PoseEstimate
from ..triangulate import TriangulatedPoints


@dataclass
class DepthPrediction:
    """Dense depth cue of the source at working resolution.

    ``values`` are affine in ``space`` (``depth`` = z, ``inverse`` = 1/z); NaN where unknown.
    ``in_pose_units``: already in the units of the pose translation (no alignment needed).
    ``metric``: true scale known up to the pose's unit translation (alignment fits a scale only).
    """

    values: np.ndarray  # (H, W) float32
    space: Literal["depth", "inverse"]
    backend: str
    in_pose_units: bool = False
    metric: bool = False
    confidence: np.ndarray | None = None  # (H, W) float32 in [0, 1]


@dataclass
class DepthContext:
    """Everything a backend may use; images float32 RGB in [0, 1] at working resolution."""

    source: np.ndarray
    target: np.ndarray
    hole: np.ndarray  # target hole, bool
    K_source: Intrinsics
    K_target: Intrinsics
    pose: PoseEstimate
    points: TriangulatedPoints
    source_size_px: tuple[int, int]  # (w, h) of the original source (file maps are stored at this size)
    cfg: DepthConfig


class DepthBackend(Protocol):
    name: str

    def predict(self, ctx: DepthContext) -> DepthPrediction:
        """Dense depth cue for ``ctx.source``."""
        ...


def get_backend(name: str) -> DepthBackend:
    """The backend registered under ``name`` (see :data:`geofill.config.DepthConfig.backend`;
    ``auto`` is resolved by :func:`choose_backend` first)."""
    from .file import FileDepth
    from .fused import FusedDepth
    from .onnx import OnnxDepth
    from .sparse import SparseDepth
    from .stereo import StereoDepth

    backends: dict[str, type] = {
        "file": FileDepth,
        "sparse": SparseDepth,
        "stereo": StereoDepth,
        "onnx": OnnxDepth,
        "fused": FusedDepth,
    }
    if name not in backends:
        raise ValueError(f"unknown depth backend {name!r}; known: {sorted(backends)}")
    return backends[name]()


@dataclass(frozen=True)
class BackendChoice:
    """The backend that runs and why (one line for the user and the report)."""

    name: str
    reason: str


def choose_backend(cfg: DepthConfig, say: Callable[[str], None] | None = None) -> BackendChoice:
    """Resolve ``auto``: ``fused`` when ONNX Runtime is installed and the learned model's weights
    resolve (path, environment variable, cache, or a download where ``cfg.download`` allows it),
    else ``stereo``, with the reason. An explicit ``cfg.model_path`` that cannot be used is an
    error, not a fallback. Other backends as given."""
    if cfg.backend != "auto":
        return BackendChoice(cfg.backend, f"{cfg.backend} (configured)")
    from ..errors import DepthModelError
    from ..extras import available, require
    from ..weights import WeightsUnavailable
    from .onnx import resolve_model

    if not available("onnxruntime"):
        if cfg.model_path:
            require("onnxruntime", "depth.model_path (learned depth)")
        return BackendChoice("stereo", "stereo (auto: learned depth needs onnxruntime, not installed)")
    weights = resolve_model(cfg, say)
    if isinstance(weights, WeightsUnavailable):
        if cfg.model_path:
            raise DepthModelError(str(weights))
        return BackendChoice("stereo", f"stereo (auto: {weights})")
    return BackendChoice("fused", f"fused (auto: learned depth {weights.describe()})")


__all__ = [
    "BackendChoice",
    "DepthBackend",
    "DepthContext",
    "DepthPrediction",
    "choose_backend",
    "get_backend",
]
