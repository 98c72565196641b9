"""The depth stage: run the chosen backend on the source and align it to the triangulated points."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import GeometryConfig
from . import BackendChoice, DepthContext, get_backend
from .align import AlignedDepth, align_depth


@dataclass(frozen=True)
class SourceDepth:
    """Dense source depth in pose units (working resolution) and how it was obtained."""

    aligned: AlignedDepth
    backend: str
    choice: str  # which backend ran and why

    @property
    def depth(self) -> np.ndarray:
        return self.aligned.depth

    def summary(self) -> str:
        d = self.aligned
        return (
            f"{self.backend}: scale {d.scale:.4g}, offset {d.offset:.4g} "
            f"({d.space} space, {d.method}, {d.n_points} points)"
        )

    def report(self) -> dict[str, Any]:
        d = self.aligned
        return {
            "backend": self.backend,
            "choice": self.choice,
            "scale": d.scale,
            "offset": d.offset,
            "space": d.space,
            "method": d.method,
            "n_points": d.n_points,
            "median_rel_error": d.median_rel_error,
            "negative_fraction": d.negative_fraction,
        }


def estimate_depth(ctx: DepthContext, choice: BackendChoice, cfg: GeometryConfig) -> SourceDepth:
    """Run ``choice``'s backend on ``ctx`` and fit its scale/offset to ``ctx.points``. Too little
    evidence raises :class:`geofill.errors.ReferenceUnusable`; anything else is a bug and propagates."""
    aligned = align_depth(get_backend(choice.name).predict(ctx), ctx.points, cfg)
    return SourceDepth(aligned, choice.name, choice.reason)


def rotation_only_depth(shape: tuple[int, int]) -> SourceDepth:
    """Any positive depth renders a pure rotation exactly (the infinite homography): ones."""
    aligned = AlignedDepth(np.ones(shape, np.float32), 1.0, 0.0, "depth", "identity", 0, 0.0, 0.0)
    return SourceDepth(aligned, "none (rotation only)", "rotation only: no depth needed")
