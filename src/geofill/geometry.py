"""The optimize stage: the geometry the render uses (pose, intrinsics, source depth), refined by
the joint pose-depth optimisation (:mod:`geofill.optimize`) where it applies."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .camera import Intrinsics
from .config import OptimizeConfig
from .depth.stage import SourceDepth
from .focal import FocalEstimate
from .matching import Matches
from .optimize import OptimizationReport, OptimizationResult, optimize_pose_depth
from .pose import PoseEstimate
from .views import WorkingViews


@dataclass(frozen=True)
class Geometry:
    """Pose (4x4 source->target), intrinsics and source depth (pose units) at working resolution;
    ``optimization`` is None where the optimisation did not run (``skipped`` says why)."""

    T: np.ndarray
    K_target: Intrinsics
    K_source: Intrinsics
    depth: np.ndarray  # (H, W) float32, source, working resolution
    optimization: OptimizationReport | None = None
    result: OptimizationResult | None = None
    skipped: str = ""

    def summary(self) -> str:
        return self.optimization.summary() if self.optimization is not None else f"skipped: {self.skipped}"

    def report(self) -> dict[str, Any]:
        if self.optimization is None:
            return {"status": "skipped", "reason": self.skipped}
        return self.optimization.to_dict()


def optimize_geometry(
    views: WorkingViews,
    focal: FocalEstimate,
    pose: PoseEstimate,
    depth: SourceDepth,
    matches: Matches,
    cfg: OptimizeConfig,
) -> Geometry:
    """Jointly refine pose and depth scale/offset (and the focal, if configured) on the paper's
    objective; a rejected optimisation keeps the initial geometry (its report says why)."""
    if not cfg.enabled or pose.status != "ok":
        why = "optimize.enabled is false" if not cfg.enabled else f"pose is {pose.status}"
        return Geometry(pose.T, focal.K_target, focal.K_source, depth.depth, skipped=why)
    inl = pose.inliers
    opt = optimize_pose_depth(
        views.target, views.hole, views.source, focal.K_target, focal.K_source, pose.T, depth.aligned,
        matches.pts_target[inl], matches.pts_source[inl], cfg,
    )  # fmt: skip
    return Geometry(opt.T, opt.K_target, opt.K_source, opt.depth.depth, opt.report, opt)
