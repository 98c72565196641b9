"""The fill as composable stages: prepare -> match -> pose -> triangulate -> depth -> render -> composite.

Each stage takes and returns small typed objects; :func:`fill` chains them, times them, and turns
every degenerate case into a single-image fallback with the reason in the report (never a crash).
Geometry runs at a working resolution (long side <= ``working_max_side``); rendering and compositing
run at the input resolution.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

import cv2
import numpy as np

from .camera import Intrinsics
from .config import FillConfig
from .depth import DepthContext, choose_backend, get_backend
from .depth.align import AlignedDepth, align_depth
from .focal import FocalEstimate, estimate_focal
from .inpaint import get_inpainter
from .intrinsics import ExifLens, resolve_intrinsics
from .io import as_rgb_uint8, validate_pair
from .matching import Matches, match_pair
from .merge import merge_fill
from .optimize import OptimizationResult, optimize_pose_depth
from .pose import PoseEstimate, estimate_pose
from .progress import Progress
from .refine import RefinedRender, refine_render
from .render import RenderResult, render_mesh
from .triangulation import TriangulatedPoints, triangulate

#: Margin (px at a 1280-px long side) around the hole's bounding box that is rendered too: the
#: known ring around the hole is what colour correction and seam checks compare against.
RENDER_MARGIN_PX = 48


@dataclass
class WorkingViews:
    """Both images as float32 RGB in [0, 1] at working resolution, with their intrinsics."""

    target: np.ndarray
    source: np.ndarray
    hole: np.ndarray  # bool, working resolution
    K_target: Intrinsics
    K_source: Intrinsics
    px_scale: float  # working long side / 1280: converts config pixel distances


@dataclass
class FillReport:
    """What happened, for humans and for ``--debug-dir``'s report.json. Units: px, degrees, seconds."""

    status: str = "reference"  # "reference" (source used) or "single_image" (fallback)
    fallbacks: list[str] = field(default_factory=list)
    intrinsics_target: dict[str, Any] = field(default_factory=dict)
    intrinsics_source: dict[str, Any] = field(default_factory=dict)
    focal: dict[str, Any] = field(default_factory=dict)  # focal stage: status, reason, candidates, profile
    working_size_target: tuple[int, int] = (0, 0)
    working_size_source: tuple[int, int] = (0, 0)
    pose_status: str = ""
    pose_source_to_target: list[list[float]] = field(default_factory=list)
    median_parallax_deg: float = 0.0
    n_keypoints_target: int = 0
    n_keypoints_source: int = 0
    n_tentative_matches: int = 0
    n_verified_matches: int = 0
    n_pose_inliers: int = 0
    n_triangulated: int = 0
    depth_backend: str = ""
    depth_choice: str = ""  # which depth backend ran and why (``auto`` says what it found)
    depth_fit: dict[str, Any] = field(default_factory=dict)
    hole_pixels: int = 0
    hole_coverage: float = 0.0  # fraction of hole pixels the rendered source supplies
    refine: dict[str, Any] = field(default_factory=dict)  # geofill.refine.RefineInfo
    inpaint_method: str = ""  # single-image inpainter used, and why (geofill.inpaint)
    optimization: dict[str, Any] = field(default_factory=dict)  # OptimizationReport (optimize stage)
    timings_s: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)


@dataclass
class FillArtifacts:
    """Intermediate results (for debugging, evaluation and later stages); None where not reached."""

    views: WorkingViews | None = None
    matches: Matches | None = None
    focal: FocalEstimate | None = None
    pose: PoseEstimate | None = None
    points: TriangulatedPoints | None = None
    depth: AlignedDepth | None = None
    optimization: OptimizationResult | None = None  # the pose/depth/intrinsics the render used
    render: RenderResult | None = None
    warped: np.ndarray | None = None  # HxWx3 uint8 rendered source at target resolution
    refined: RefinedRender | None = None


@dataclass
class FillResult:
    image: np.ndarray  # HxWx3 uint8; pixels outside the hole are the target's, byte for byte
    report: FillReport
    artifacts: FillArtifacts


class Fallback(Exception):
    """Internal: the source cannot help; the message is the reason shown to the user."""


def _resize_long(image: np.ndarray, max_side: int) -> np.ndarray:
    h, w = image.shape[:2]
    s = max_side / max(h, w)
    if s >= 1.0:
        return image
    size = (max(round(w * s), 1), max(round(h * s), 1))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def prepare(
    target: np.ndarray,
    hole: np.ndarray,
    source: np.ndarray,
    cfg: FillConfig,
    target_exif: ExifLens | None,
    source_exif: ExifLens | None,
) -> WorkingViews:
    """Working-resolution float views and per-image intrinsics (resolved at input size, then resized)."""
    ic = cfg.intrinsics
    K_t = resolve_intrinsics(target.shape[1], target.shape[0], ic, target_exif, ic.target)
    K_s = resolve_intrinsics(source.shape[1], source.shape[0], ic, source_exif, ic.source)
    t = _resize_long(target, cfg.working_max_side)
    s = _resize_long(source, cfg.working_max_side)
    # Area-resampled: any hole pixel of the input makes its working pixel a hole (no object leaks).
    hole_w = _resize_long(hole.astype(np.float32), cfg.working_max_side) > 0
    return WorkingViews(
        t.astype(np.float32) / 255.0,
        s.astype(np.float32) / 255.0,
        hole_w,
        K_t.resized(t.shape[1], t.shape[0]),
        K_s.resized(s.shape[1], s.shape[0]),
        max(t.shape[:2]) / 1280.0,
    )


def render_roi(hole: np.ndarray, margin: int) -> tuple[int, int, int, int]:
    """Bounding box (x0, y0, x1, y1), half-open, of the hole grown by ``margin`` px, clipped."""
    ys, xs = np.nonzero(hole)
    h, w = hole.shape
    return (
        max(int(xs.min()) - margin, 0),
        max(int(ys.min()) - margin, 0),
        min(int(xs.max()) + margin + 1, w),
        min(int(ys.max()) + margin + 1, h),
    )


def composite(
    target: np.ndarray, hole: np.ndarray, warped: np.ndarray | None, alpha: np.ndarray | None, cfg: FillConfig
) -> np.ndarray:
    """Rendered source inside the hole where it exists, single-image inpainting for the rest,
    merged with a feathered blending map (:func:`geofill.merge.merge_fill`); pixels outside the
    hole are copied from ``target`` unchanged."""
    feather = cfg.refine.feather_px * max(hole.shape) / 1280.0
    return merge_fill(target, hole, warped, alpha, cfg.inpaint, feather)


def fill(
    target: np.ndarray,
    mask: np.ndarray,
    source: np.ndarray,
    config: FillConfig | None = None,
    *,
    target_exif: ExifLens | None = None,
    source_exif: ExifLens | None = None,
    progress: Progress | None = None,
) -> FillResult:
    """Fill the hole ``mask`` (True/255 = hole) of ``target`` with content from ``source``.

    Images are HxWx3 uint8 RGB (other dtypes/channels are normalised); target and source may
    differ in size. Raises :class:`geofill.errors.InputError` subclasses for bad inputs; any
    geometric failure falls back to single-image inpainting, with the reason in
    ``result.report.fallbacks``.
    """
    cfg = config or FillConfig()
    prog = progress or Progress(quiet=True)
    report = FillReport()
    art = FillArtifacts()
    with prog.stage("check inputs"):
        target = as_rgb_uint8(target)
        source = as_rgb_uint8(source)
        hole = validate_pair(
            target,
            mask,
            source,
            min_side=cfg.min_side_px,
            max_pixels=cfg.max_pixels,
            max_mask_fraction=cfg.max_mask_fraction,
        )
    report.hole_pixels = int(hole.sum())
    # Whatever the hole shows (the object being removed) must not steer the fill: every stage sees
    # it blanked, so the result depends on the known pixels only. Black beat a Telea pre-fill
    # (mean hole PSNR 19.02 vs 18.75 dB on the DEV pairs): keypoints are dropped near the hole
    # anyway, and a flat region gives the stereo and the flow no false texture.
    target = target.copy()
    target[hole] = 0
    try:
        warped, alpha = _reference_fill(
            target, hole, source, cfg, target_exif, source_exif, prog, report, art
        )
    except Fallback as exc:
        report.status = "single_image"
        report.fallbacks.append(str(exc))
        prog.say(f"falling back to single-image inpainting: {exc}")
        warped, alpha = None, None
    with prog.stage("composite") as notes:
        report.inpaint_method = get_inpainter(cfg.inpaint, prog.say).description
        notes.append(f"single-image inpainting: {report.inpaint_method}")
        image = composite(target, hole, warped, alpha, cfg)
    report.timings_s = dict(prog.timings)
    return FillResult(image, report, art)


def _reference_fill(target, hole, source, cfg, target_exif, source_exif, prog, report, art):
    """Stages that use the source; raise :class:`Fallback` when it cannot help."""
    with prog.stage("prepare"):
        views = prepare(target, hole, source, cfg, target_exif, source_exif)
        art.views = views
        report.intrinsics_target = views.K_target.resized(target.shape[1], target.shape[0]).to_json()
        report.intrinsics_source = views.K_source.resized(source.shape[1], source.shape[0]).to_json()
        report.working_size_target = (views.K_target.width, views.K_target.height)
        report.working_size_source = (views.K_source.width, views.K_source.height)

    with prog.stage("match") as notes:
        matches = match_pair(views.target, views.source, views.hole, cfg.matching, views.px_scale)
        art.matches = matches
        report.n_keypoints_target = matches.n_keypoints_target
        report.n_keypoints_source = matches.n_keypoints_source
        report.n_tentative_matches = matches.n_tentative
        report.n_verified_matches = len(matches)
        notes.append(f"{len(matches)} verified of {matches.n_tentative} tentative matches")

    # Focal length: estimated from the matches, before the pose uses it (issue 7).
    with prog.stage("focal") as notes:
        focal = estimate_focal(
            matches,
            views.K_target,
            views.K_source,
            cfg.intrinsics,
            cfg.matching.ransac_threshold_px * max(views.px_scale, 0.5),
        )
        art.focal = focal
        views.K_target, views.K_source = focal.K_target, focal.K_source
        report.focal = focal.to_json()
        report.intrinsics_target = views.K_target.resized(target.shape[1], target.shape[0]).to_json()
        report.intrinsics_source = views.K_source.resized(source.shape[1], source.shape[0]).to_json()
        notes.append(focal.summary())

    with prog.stage("pose") as notes:
        pose = estimate_pose(matches, views.K_target, views.K_source, cfg.geometry, cfg.matching)
        art.pose = pose
        report.pose_status = pose.status
        report.n_pose_inliers = pose.n_inliers
        report.median_parallax_deg = pose.median_parallax_deg
        report.pose_source_to_target = pose.T.tolist()
        notes.append(
            f"{pose.status}, {pose.n_inliers} inliers, median parallax {pose.median_parallax_deg:.2f} deg"
        )
    if not pose.usable:
        raise Fallback(pose.reason)

    if pose.status == "rotation_only":
        report.fallbacks.append(pose.reason)
        prog.say(pose.reason)
        # Any positive depth renders a pure rotation exactly (the infinite homography).
        depth_s = np.ones((views.K_source.height, views.K_source.width), np.float32)
        report.depth_backend = "none (rotation only)"
    else:
        with prog.stage("triangulate") as notes:
            pts = triangulate(
                matches.pts_source[pose.inliers],
                matches.pts_target[pose.inliers],
                views.K_source,
                views.K_target,
                pose.T,
                cfg.geometry,
            )
            art.points = pts
            report.n_triangulated = len(pts)
            notes.append(f"{len(pts)} points kept of {pose.n_inliers}")
        with prog.stage("depth") as notes:
            choice = choose_backend(cfg.depth, prog.say)  # may verify or download weights: timed
            report.depth_backend, report.depth_choice = choice.name, choice.reason
            prog.say(f"depth backend: {choice.reason}")
            depth = _dense_depth(views, pose, pts, source.shape[1::-1], cfg, choice.name)
            art.depth = depth
            report.depth_fit = {
                "scale": depth.scale,
                "offset": depth.offset,
                "space": depth.space,
                "method": depth.method,
                "n_points": depth.n_points,
                "median_rel_error": depth.median_rel_error,
                "negative_fraction": depth.negative_fraction,
            }
            notes.append(
                f"{choice.name}: scale {depth.scale:.4g}, offset {depth.offset:.4g} "
                f"({depth.space} space, {depth.method}, {depth.n_points} points)"
            )
        depth_s = depth.depth

    # Joint pose-depth optimisation (issue 5): refines pose.T, the depth and optionally the focal.
    T, K_tw, K_sw = pose.T, views.K_target, views.K_source
    if cfg.optimize.enabled and pose.status == "ok":
        with prog.stage("optimize") as notes:
            inl = pose.inliers
            opt = optimize_pose_depth(
                views.target, views.hole, views.source, K_tw, K_sw, T, depth,
                matches.pts_target[inl], matches.pts_source[inl], cfg.optimize,
            )  # fmt: skip
            art.optimization = opt
            report.optimization = opt.report.to_dict()
            notes.append(opt.report.summary())
            if opt.report.status == "rejected":
                report.fallbacks.append(f"optimisation rejected, initial geometry kept: {opt.report.reason}")
            T, K_tw, K_sw, depth_s = opt.T, opt.K_target, opt.K_source, opt.depth.depth
            if K_tw.origin == "refined":
                report.intrinsics_target = K_tw.resized(target.shape[1], target.shape[0]).to_json()
                report.intrinsics_source = K_sw.resized(source.shape[1], source.shape[0]).to_json()

    with prog.stage("render") as notes:
        H, W = target.shape[:2]
        K_t = K_tw.resized(W, H)
        K_s = K_sw.resized(source.shape[1], source.shape[0])
        if depth_s.shape != (K_s.height, K_s.width):
            depth_s = cv2.resize(depth_s, (K_s.width, K_s.height), interpolation=cv2.INTER_LINEAR)
        roi = render_roi(hole, int(RENDER_MARGIN_PX * max(H, W) / 1280))
        rendered = render_mesh(depth_s, K_s, K_t, T, cfg.render.edge_threshold, roi)
        art.render = rendered
        warped = rendered.sample(source)
        art.warped = warped
        coverage = float(rendered.alpha[hole].mean())
        report.hole_coverage = coverage
        notes.append(f"source covers {100 * coverage:.1f}% of the hole")
    if coverage < cfg.render.min_hole_coverage:
        raise Fallback(
            f"the source covers only {100 * coverage:.1f}% of the hole "
            f"(< {100 * cfg.render.min_hole_coverage:.0f}%): it does not see what the hole hides"
        )

    # Refinement (issue 6): residual flow alignment and colour correction of the render.
    with prog.stage("refine") as notes:
        refined = refine_render(target, hole, source, rendered, cfg.refine)
        art.refined = refined
        report.refine = asdict(refined.info)
        i = refined.info
        notes.append(
            f"flow {'applied' if i.flow_applied else 'off'} (band median {i.flow_median_band_px:.2f} px), "
            f"colour {i.colour}: band error {i.band_error_before:.1f} -> {i.band_error_after:.1f}"
        )
    return refined.image, refined.alpha


def _dense_depth(views, pose, pts, source_size, cfg, backend: str) -> AlignedDepth:
    """Run depth backend ``backend`` and align it to the triangulated points."""
    ctx = DepthContext(
        views.source,
        views.target,
        views.hole,
        views.K_source,
        views.K_target,
        pose,
        pts,
        source_size,
        cfg.depth,
    )
    try:
        pred = get_backend(backend).predict(ctx)
        return align_depth(pred, pts, cfg.geometry)
    except ValueError as exc:
        raise Fallback(f"depth stage failed: {exc}") from exc
