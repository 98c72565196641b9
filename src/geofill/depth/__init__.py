"""Dense depth of the source view, behind one interface.

A backend returns a :class:`DepthPrediction`: values that are an affine function of depth or of
inverse depth (learned networks and stereo disparity give the latter), plus where they are known.
:func:`geofill.depth.align.align_depth` then fixes the affine ambiguity with the triangulated points,
in the units of the pose translation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from ..camera import Intrinsics
from ..config import DepthConfig
from ..pose import PoseEstimate
from ..triangulation import TriangulatedPoints


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
    """The backend registered under ``name`` (see :data:`geofill.config.DepthConfig.backend`)."""
    from .file import FileDepth
    from .sparse import SparseDepth

    backends: dict[str, type] = {"file": FileDepth, "sparse": SparseDepth}
    if name not in backends:
        raise ValueError(f"unknown depth backend {name!r}; known: {sorted(backends)}")
    return backends[name]()


__all__ = ["DepthBackend", "DepthContext", "DepthPrediction", "get_backend"]
