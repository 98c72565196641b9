"""The optimize stage: the geometry the render uses (pose, intrinsics, source depth), refined by the
joint pose-depth optimisation where it applies (:func:`optimize_geometry`): build the problem, run
the configured solver, apply the guard rails, and report."""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from ..camera import Intrinsics, rotation_error_deg, translation_direction_error_deg
from ..config import OptimizeConfig
from ..depth.align import AlignedDepth, sample_at, to_depth
from ..depth.stage import SourceDepth
from ..focal import FocalEstimate
from ..match import Matches
from ..pose import PoseEstimate
from ..prepare import WorkingViews
from .fast_solver import solve_fast
from .objective import evaluate
from .params import PoseDepthParams
from .problem import build_problem


def guard(params: PoseDepthParams, initial: float, final: float) -> str:
    """Why ``params`` must be rejected ('' when they are acceptable): NaN, a non-positive depth scale,
    or an objective worse than the initial one."""
    if not params.is_finite() or not math.isfinite(final):
        return "optimisation produced NaN/inf parameters or objective"
    if params.scale <= 0:
        return f"optimisation produced a non-positive depth scale ({params.scale:.4g})"
    if final > initial:
        return f"optimised objective {final:.6g} is worse than the initial {initial:.6g}"
    return ""


@dataclass
class OptimizationReport:
    """What the optimisation did (units: degrees, seconds; objective values are dimensionless)."""

    solver: str = ""
    status: str = ""  # "accepted", "rejected" (initial parameters kept) or "skipped"
    reason: str = ""
    initial_objective: float = float("nan")
    final_objective: float = float("nan")
    initial_terms: dict[str, float] = field(default_factory=dict)
    final_terms: dict[str, float] = field(default_factory=dict)
    levels: list[dict[str, Any]] = field(default_factory=list)
    params: dict[str, Any] = field(default_factory=dict)
    rotation_change_deg: float = 0.0
    translation_change_deg: float = 0.0
    focal_target_px: float = float("nan")
    focal_source_px: float = float("nan")
    n_features: int = 0
    seconds: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def summary(self) -> str:
        if self.status == "skipped":
            return f"skipped: {self.reason}"
        its = "/".join(str(lv["iterations"]) for lv in self.levels)
        text = (
            f"{self.solver} {self.status}: objective {self.initial_objective:.4g} -> "
            f"{self.final_objective:.4g} (iterations {its}), dR {self.rotation_change_deg:.2f} deg, "
            f"dt {self.translation_change_deg:.2f} deg, scale {self.params.get('scale', 1.0):.3f}"
        )
        return text + (f"; {self.reason}" if self.reason else "")


@dataclass
class OptimizationResult:
    """The geometry the render uses: pose, depth and intrinsics (working resolution), plus the report."""

    T: np.ndarray
    depth: AlignedDepth
    K_target: Intrinsics
    K_source: Intrinsics
    params: PoseDepthParams
    report: OptimizationReport


def fit_space_values(depth: AlignedDepth) -> np.ndarray:
    """The aligned depth in its fit space: z, or 1/z for an inverse-depth fit (NaN stays NaN)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return depth.depth if depth.space == "depth" else (1.0 / depth.depth).astype(np.float32)


def optimize_pose_depth(
    target: np.ndarray,
    hole: np.ndarray,
    source: np.ndarray,
    K_t: Intrinsics,
    K_s: Intrinsics,
    T: np.ndarray,
    depth: AlignedDepth,
    pts_t: np.ndarray,
    pts_s: np.ndarray,
    cfg: OptimizeConfig,
) -> OptimizationResult:
    """Jointly refine the pose ``T`` (source->target, |t| kept) and the depth's scale/offset (and
    optionally the focal lengths) for one pair at working resolution; see the module docstring.

    ``target``/``source``: float32 RGB in [0, 1]; ``hole``: bool; ``pts_t``/``pts_s``: matched pixels
    (the pose inliers). Rejected results keep the initial geometry, with the reason in the report."""
    # BLAS threads for the solver's small matrix products (restored afterwards; the paper solver's
    # torch threads follow the same setting, see solve_paper).
    with threadpool_limits(limits=max(1, cfg.threads)):
        return _optimize(target, hole, source, K_t, K_s, T, depth, pts_t, pts_s, cfg)


def _optimize(target, hole, source, K_t, K_s, T, depth, pts_t, pts_s, cfg) -> OptimizationResult:
    t0 = time.perf_counter()
    init = PoseDepthParams(np.asarray(T[:3, :3], np.float64), np.asarray(T[:3, 3], np.float64).copy())
    report = OptimizationReport(solver=cfg.solver)
    unchanged = OptimizationResult(T, depth, K_t, K_s, init, report)
    if float(np.linalg.norm(init.t)) == 0.0:
        report.status, report.reason = "skipped", "no translation (rotation-only pose): depth is unobservable"
        return unchanged
    values = fit_space_values(depth)
    problem = build_problem(target, hole, source, values, depth.space, K_t, K_s, pts_t, pts_s, cfg)
    report.n_features = len(problem.features.points)
    initial = evaluate(problem, init)
    problem.prior_ref = float(initial.total)
    if cfg.solver == "paper":
        from .paper_solver import solve_paper as solve
    else:
        solve = solve_fast
    params, logs = solve(problem, init)
    final = evaluate(problem, params)
    report.initial_objective, report.initial_terms = float(initial.total), initial.to_json()
    report.final_objective, report.final_terms = float(final.total), final.to_json()
    report.levels = [lg.to_json() for lg in logs]
    report.reason = guard(params, float(initial.total), float(final.total))
    report.status = "rejected" if report.reason else "accepted"
    report.seconds = time.perf_counter() - t0
    if report.reason:
        report.params = init.to_json()
        return unchanged
    report.params = params.to_json()
    report.rotation_change_deg = rotation_error_deg(init.R, params.R)
    report.translation_change_deg = translation_direction_error_deg(init.t, params.t)
    ef = math.exp(params.log_focal)
    K_t2 = replace(K_t, fx=K_t.fx * ef, fy=K_t.fy * ef, origin="refined") if cfg.refine_focal else K_t
    K_s2 = replace(K_s, fx=K_s.fx * ef, fy=K_s.fy * ef, origin="refined") if cfg.refine_focal else K_s
    report.focal_target_px, report.focal_source_px = K_t2.fx, K_s2.fx
    z, neg = to_depth(values, depth.space, params.scale, params.offset)
    new_depth = replace(
        depth,
        depth=z,
        scale=params.scale * depth.scale,
        offset=params.scale * depth.offset + params.offset,
        negative_fraction=neg,
    )
    report.seconds = time.perf_counter() - t0
    return OptimizationResult(params.T, new_depth, K_t2, K_s2, params, report)


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

    >>> from geofill.match import Matches
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
