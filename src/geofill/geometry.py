"""The optimize stage: the geometry the render uses (pose, intrinsics, source depth), refined by
the joint pose-depth optimisation (:mod:`geofill.optimize`) where it applies."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .camera import Intrinsics
from .config import OptimizeConfig
from .depth.align import sample_at
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
    thin: bool = False  # skipped because the evidence was too thin (a fallback the report lists)

    def summary(self) -> str:
        return self.optimization.summary() if self.optimization is not None else f"skipped: {self.skipped}"

    def report(self) -> dict[str, Any]:
        if self.optimization is None:
            return {"status": "skipped", "reason": self.skipped}
        return self.optimization.to_dict()


def thin_evidence(matches: Matches, on_depth: int, cfg: OptimizeConfig) -> str:
    """Why the optimisation must keep the initial geometry ('' when the evidence suffices): the
    matches come from a ladder rung that did not verify, or fewer than ``cfg.min_features`` pose
    inliers land on the source depth. The photometric term alone has far minima (every point
    pushed out of the target costs nothing), and the feature term is what anchors the pose.

    >>> from geofill.matching import Matches
    >>> m = Matches(np.zeros((30, 2)), np.zeros((30, 2)), np.eye(3), 30, 30, 30)
    >>> thin_evidence(m, 12, OptimizeConfig())
    'only 12 pose inliers on the source depth (optimize.min_features = 20): too thin to optimise'
    """
    if not matches.verified:
        return f"matches from an unverified {matches.rung} rung: too thin to optimise"
    if on_depth < cfg.min_features:
        return (
            f"only {on_depth} pose inliers on the source depth "
            f"(optimize.min_features = {cfg.min_features}): too thin to optimise"
        )
    return ""


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
    on_depth = int(np.isfinite(sample_at(depth.aligned.depth, matches.pts_source[inl])).sum())
    if why := thin_evidence(matches, on_depth, cfg):
        return Geometry(pose.T, focal.K_target, focal.K_source, depth.depth, skipped=why, thin=True)
    opt = optimize_pose_depth(
        views.target, views.hole, views.source, focal.K_target, focal.K_source, pose.T, depth.aligned,
        matches.pts_target[inl], matches.pts_source[inl], cfg,
    )  # fmt: skip
    return Geometry(opt.T, opt.K_target, opt.K_source, opt.depth.depth, opt.report, opt)
