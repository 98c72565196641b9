"""The multi-view depth stage: the references' geometries in one frame, and each reference's depth
behind the hole measured from the other references.

Each pair (target, reference k) is registered alone, so its pose translation and depth are in its
own units. The part of reference k that lands in the target's hole (its *footprint*) is exactly
what the target cannot see, so the two-view sweep of the depth stage cannot measure it: it is
completed from the surroundings. The other references do see it. This stage runs once every
reference has its geometry (after ``optimize``):

One frame
    Each reference's triangulated points, put in the target camera by its pose, are compared with
    the first reference's depth splatted into the target (z-buffer) at the same target pixels, and
    the first reference's points with this reference's depth: the median ratio fixes each
    reference's scale in one common frame (the target's camera, the first reference's units). The
    spread of those ratios says how far two pairs' geometries disagree; a reference whose spread
    is over ``multiview.max_scale_spread`` is neither swept nor a view.
Sweep
    For reference k, inverse-depth hypotheses along its rays (the range of its own depth map,
    widened as the depth stage does) are scored by NCC against every other view: the other
    references (through the common frame) and the target (its hole carries no evidence), with the
    depth stage's kernels (:func:`geofill.depth.stereo.sweep_ncc`), on the footprint's bounding box
    only. Occlusion: per hypothesis the mean of the best ``best_k`` views' NCC (a view that does not
    see the point scores low and is left out). Then the depth stage's guided-filter aggregation,
    winner-take-all and confidence (a good NCC clearly better than the best rival peak).
Completion
    Confident footprint pixels and the reference's own depth elsewhere (outside the footprint, or
    farther than a few px from any measured pixel) seed the same edge-aware completion as the depth
    stage; the result replaces the depth only in the footprint near measured pixels. A footprint
    with no confident pixel keeps its depth unchanged.

Each pair's geometry is still its own (pose and focal from its pair alone, placed by one scale):
where the pairs' focal lengths or poses disagree, the other views are misregistered and the sweep
finds little (see docs/architecture.md for what it measured on the real sets).
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from .camera import Intrinsics
from .config import MultiViewConfig
from .depth.completion import interpolate_edge_aware, to_uint8
from .depth.stereo import (
    Hypotheses,
    aggregate,
    confidence,
    displacement_span,
    grey,
    inverse_depth_bounds,
    plane_count,
    project_source_grid_inv,
    resize_to,
    sweep_ncc,
    winner_take_all,
)
from .optimize.stage import Geometry
from .prepare import WorkingViews
from .triangulate import TriangulatedPoints

#: Source pixels are splatted into the target on a grid of this step (px, working resolution)
#: to compare the references' scales: every pixel would cost 16x as much for the same median.
_SPLAT_STEP = 4
#: Footprint pixels farther than this (px at the sweep's resolution) from a measured pixel keep
#: their depth: a re-completion from a few measured pixels changed footprints it did not measure.
_REACH_PX = 8
#: Fewest depth comparisons that place a reference in the common frame.
_MIN_SHARED = 20


@dataclass(frozen=True)
class ViewGeometry:
    """One reference as the stage sees it: its working views and its geometry (pose units)."""

    index: int  # 1-based, as the references were given
    views: WorkingViews
    geometry: Geometry
    points: TriangulatedPoints
    # Its source->target translation length in the joint registration's units, which every
    # reference that has one shares (None: registered by its pair alone).
    joint_baseline: float | None = None


@dataclass(frozen=True)
class ReferenceMultiView:
    """What the stage measured for one reference. ``scale`` multiplies its pose units into the
    common frame's (NaN: too few depth comparisons with the first reference to place it);
    ``scale_spread`` is the median relative disagreement of those comparisons after the scale."""

    index: int
    scale: float
    scale_spread: float
    footprint_px: int  # sweep-resolution source pixels that land in the target's hole
    measured_px: int  # of those, how many got a confident multi-view depth
    views: int  # other views the sweep scored against (references, and the target)

    @property
    def measured_fraction(self) -> float:
        return self.measured_px / self.footprint_px if self.footprint_px else 0.0

    def report(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "scale": self.scale,
            "scale_spread": self.scale_spread,
            "footprint_px": self.footprint_px,
            "measured_px": self.measured_px,
            "measured_fraction": self.measured_fraction,
            "views": self.views,
        }


@dataclass(frozen=True)
class MultiViewDepth:
    """Per reference, its place in the common frame and how much of its hole footprint the other
    views measured."""

    references: tuple[ReferenceMultiView, ...]

    def summary(self) -> str:
        if not self.references:
            return "fewer than two references with geometry: nothing to measure"
        return "; ".join(
            f"ref {r.index}: {100 * r.measured_fraction:.0f}% of its hole footprint measured "
            f"({r.views} views, scale {r.scale:.3g})"
            for r in self.references
        )

    def report(self) -> dict[str, Any]:
        return {"references": [r.report() for r in self.references]}


def _pose_with_scale(T: np.ndarray, scale: float) -> np.ndarray:
    out = T.copy()
    out[:3, 3] *= scale
    return out


def target_view_depth(g: ViewGeometry) -> np.ndarray:
    """z in the target camera (the reference's units; NaN where no source pixel lands) on the
    target's pixels ``[::_SPLAT_STEP, ::_SPLAT_STEP]``, from the reference's depth on the same grid
    splatted to the nearest pixel, nearest first."""
    geo = g.geometry
    K_t = _subsampled(geo.K_target, _SPLAT_STEP)
    inv = 1.0 / geo.depth[::_SPLAT_STEP, ::_SPLAT_STEP].astype(np.float64)
    u, v, z = project_source_grid_inv(inv, _subsampled(geo.K_source, _SPLAT_STEP), K_t, geo.T)
    ui, vi = np.rint(u), np.rint(v)
    ok = np.isfinite(z) & (z > 0) & (ui >= 0) & (ui < K_t.width) & (vi >= 0) & (vi < K_t.height)
    zbuf = np.full(K_t.height * K_t.width, np.inf)
    np.minimum.at(zbuf, (vi[ok] * K_t.width + ui[ok]).astype(np.int64), z[ok])
    zbuf[~np.isfinite(zbuf)] = np.nan
    return zbuf.reshape(K_t.height, K_t.width).astype(np.float32)


def _subsampled(K: Intrinsics, step: int) -> Intrinsics:
    """Intrinsics of the image's pixels ``[::step, ::step]`` (pixel ``i`` there is ``step * i``)."""
    w, h = -(-K.width // step), -(-K.height // step)
    return replace(K, fx=K.fx / step, fy=K.fy / step, cx=K.cx / step, cy=K.cy / step, width=w, height=h)


def _target_z(g: ViewGeometry) -> tuple[np.ndarray, np.ndarray]:
    """The reference's triangulated points: their target pixels (N, 2) and z in the target camera."""
    T = g.geometry.T
    return g.points.uv_target, g.points.xyz_source @ T[2, :3] + T[2, 3]


def _sample(depth: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``depth`` (a :func:`target_view_depth`) at the target pixels ``uv`` (N, 2; NaN outside)."""
    ui, vi = (np.rint(a / _SPLAT_STEP).astype(np.int64) for a in (uv[:, 0], uv[:, 1]))
    h, w = depth.shape
    ok = (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
    out = np.full(len(uv), np.nan, np.float32)
    out[ok] = depth[vi[ok], ui[ok]]
    return out


def joint_scales(refs: Sequence[ViewGeometry]) -> list[float | None]:
    """Per reference, its scale into the first reference's units from the joint registration's
    baselines (None where it or the first reference has none, or a pose has no translation)."""

    def units(g: ViewGeometry) -> float | None:
        length = float(np.linalg.norm(g.geometry.T[:3, 3]))
        return None if g.joint_baseline is None or length < 1e-12 else g.joint_baseline / length

    first = units(refs[0])
    return [None if first is None or (u := units(g)) is None else u / first for g in refs]


def common_scales(
    refs: Sequence[ViewGeometry], known: Sequence[float | None] | None = None
) -> list[tuple[float, float]]:
    """Per reference, (scale into the first reference's units, median relative spread of the
    ratios): the ``known`` scale where there is one, else the median ratio. Each ratio compares one
    measured depth with the other reference's at the same target pixel: a reference's
    triangulated points (target z) against the other's depth splatted into the target, both ways.
    Dense against dense spread 2-3x as much on the real sets (completed depth on both sides)."""
    depths = [target_view_depth(g) for g in refs]
    points = [_target_z(g) for g in refs]
    out = []
    for d, (uv, z), given in zip(depths, points, known or [None] * len(refs), strict=True):
        uv0, z0 = points[0]
        log_ratio = np.concatenate([np.log(_sample(depths[0], uv) / z), np.log(z0 / _sample(d, uv0))])
        log_ratio = log_ratio[np.isfinite(log_ratio)]
        if log_ratio.size < _MIN_SHARED:
            out.append((float("nan"), float("nan")))
            continue
        centre = float(np.median(log_ratio)) if given is None else float(np.log(given))
        out.append((float(np.exp(centre)), float(np.expm1(np.median(np.abs(log_ratio - centre))))))
    return out


@dataclass(frozen=True)
class _Sweep:
    """Reference k's footprint crop at the sweep's resolution."""

    x0: int
    y0: int
    grey: np.ndarray  # (h, w) float32 grey of the crop
    rgb: np.ndarray  # (h, w, 3) float32 crop
    K: Intrinsics  # of the crop
    footprint: np.ndarray  # (h, w) bool
    inv: np.ndarray  # (h, w) inverse depth the reference already has, pose units
    size: tuple[int, int]  # (w, h) of the whole sweep-resolution image


def footprint_crop(g: ViewGeometry, s: float, margin: int) -> _Sweep | None:
    """The pixels of reference ``g`` (at scale ``s`` of its working views) that its own depth puts
    in the target's hole, in their bounding box grown by ``margin`` px; None when there are none."""
    geo = g.geometry
    rgb = resize_to(g.views.source, s)
    h, w = rgb.shape[:2]
    K = geo.K_source.resized(w, h)
    inv = 1.0 / cv2.resize(geo.depth, (w, h), interpolation=cv2.INTER_LINEAR).astype(np.float64)
    u, v, z = project_source_grid_inv(inv, K, geo.K_target, geo.T)
    hole = g.views.hole
    ht, wt = hole.shape
    ui, vi = (
        np.rint(np.nan_to_num(u, nan=-1)).astype(np.int64),
        np.rint(np.nan_to_num(v, nan=-1)).astype(np.int64),
    )
    inside = np.isfinite(z) & (z > 0) & (ui >= 0) & (ui < wt) & (vi >= 0) & (vi < ht)
    foot = np.zeros((h, w), bool)
    foot[inside] = hole[vi[inside], ui[inside]]
    if not foot.any():
        return None
    ys, xs = np.nonzero(foot)
    y0, y1 = max(ys.min() - margin, 0), min(ys.max() + margin + 1, h)
    x0, x1 = max(xs.min() - margin, 0), min(xs.max() + margin + 1, w)
    Kc = replace(K, cx=K.cx - x0, cy=K.cy - y0, width=x1 - x0, height=y1 - y0)
    crop = rgb[y0:y1, x0:x1]
    return _Sweep(
        x0, y0, grey(crop), crop, Kc, foot[y0:y1, x0:x1], inv[y0:y1, x0:x1].astype(np.float32), (w, h)
    )


@dataclass(frozen=True)
class _View:
    """A view the sweep scores against: grey image, where it has no evidence, intrinsics, and the
    pose from the swept reference's camera into it (the swept reference's units)."""

    grey: np.ndarray
    invalid: np.ndarray
    K: Intrinsics
    T: np.ndarray


@dataclass(frozen=True)
class _Greys:
    """The target (with its hole) and every reference in grey at the sweep's resolution, each
    resized once for all the sweeps that use it."""

    target: np.ndarray
    hole: np.ndarray
    sources: list[np.ndarray]

    @classmethod
    def of(cls, refs: Sequence[ViewGeometry], max_side: int) -> _Greys:
        views = refs[0].views
        tgt = grey(resize_to(views.target, _scale(views.target.shape, max_side)))
        ht, wt = tgt.shape
        hole = cv2.resize(views.hole.astype(np.uint8), (wt, ht), interpolation=cv2.INTER_AREA) > 0
        sources = [grey(resize_to(g.views.source, _scale(g.views.source.shape, max_side))) for g in refs]
        return cls(tgt, hole, sources)


def _scale(shape: tuple[int, ...], max_side: int) -> float:
    return min(1.0, max_side / max(shape[:2]))


def other_views(
    k: int, refs: Sequence[ViewGeometry], scales: Sequence[float], greys: _Greys, use_target: bool
) -> list[_View]:
    """The views reference ``refs[k]`` is swept against: every other placed reference (through the
    common frame) and, when ``use_target``, the target with its hole marked invalid."""
    gk = refs[k].geometry
    out = []
    if use_target:
        ht, wt = greys.target.shape
        out.append(_View(greys.target, greys.hole, gk.K_target.resized(wt, ht), gk.T))
    for j, g in enumerate(refs):
        if j == k or not np.isfinite(scales[j]):
            continue
        # X_j = R_j^T (X_t - t_j) with X_t and t_j both in reference k's units.
        T_tj = np.linalg.inv(_pose_with_scale(g.geometry.T, scales[j] / scales[k]))
        hj, wj = greys.sources[j].shape
        K_j = g.geometry.K_source.resized(wj, hj)
        out.append(_View(greys.sources[j], np.zeros((hj, wj), bool), K_j, T_tj @ gk.T))
    return out


def best_k_score(ncc: list[np.ndarray], best_k: int) -> np.ndarray:
    """Per hypothesis and pixel, the mean NCC of the ``best_k`` best views (each (D, h, w); the
    first is overwritten). A view without evidence scores 0 (neither for nor against): a view that
    does not see the point (occluded, outside) has a low NCC there and drops out."""
    k = min(best_k, len(ncc))
    if k == 1:
        out = ncc[0]
        for c in ncc[1:]:
            np.maximum(out, c, out=out)
        return out
    return -np.partition(-np.stack(ncc), k - 1, axis=0)[:k].mean(axis=0)


def sweep_reference(
    k: int, refs: Sequence[ViewGeometry], scales: Sequence[float], greys: _Greys, cfg: MultiViewConfig
) -> tuple[np.ndarray | None, int, int, int]:
    """Multi-view depth of ``refs[k]``'s hole footprint: (new working-resolution depth or None when
    nothing was measured, footprint px, measured px, views)."""
    g = refs[k]
    geo = g.geometry
    margin = cfg.patch_px + cfg.aggregation_radius
    crop = footprint_crop(g, _scale(g.views.source.shape, cfg.max_side), margin)
    views = other_views(k, refs, scales, greys, cfg.use_target)
    if crop is None or not views:
        return None, 0, 0, len(views)
    foot_px = int(crop.footprint.sum())
    lo, hi = inverse_depth_bounds(1.0 / geo.depth[np.isfinite(geo.depth) & (geo.depth > 0)])
    shape = crop.grey.shape
    span = np.max([displacement_span(shape, crop.K, v.K, v.T, lo, hi) for v in views], axis=0)
    D = plane_count(span, cfg.max_planes)
    hyp = Hypotheses(np.full(shape, lo), np.full(shape, (hi - lo) / max(D - 1, 1)), D)
    scored = [sweep_ncc(crop.grey, v.grey, v.invalid, crop.K, v.K, v.T, hyp, cfg.patch_px) for v in views]
    score = aggregate(best_k_score([c for c, _ in scored], cfg.best_k), crop.grey, cfg.aggregation_radius)
    inv, s1, rival, best = winner_take_all(score, hyp)
    conf = confidence(s1, s1 - rival)
    n_valid = sum(np.take_along_axis(valid, best[None], 0)[0] for _, valid in scored)
    seen = n_valid >= min(cfg.best_k, len(views))
    measured = crop.footprint & seen & (conf >= cfg.min_confidence) & np.isfinite(inv)
    n_measured = int(measured.sum())
    if n_measured == 0:
        return None, foot_px, 0, len(views)
    return _completed(g, crop, inv, measured, (lo, hi)), foot_px, n_measured, len(views)


def _grid(shape: tuple[int, int], step: int) -> np.ndarray:
    out = np.zeros(shape, bool)
    out[::step, ::step] = True
    return out


def _completed(
    g: ViewGeometry, crop: _Sweep, inv: np.ndarray, measured: np.ndarray, bounds: tuple[float, float]
) -> np.ndarray:
    """The reference's working depth with the footprint near its measured pixels replaced: the
    measured pixels (every second) and the reference's own depth elsewhere (outside the footprint,
    or farther than :data:`_REACH_PX` from a measured pixel; every fourth) seed an edge-aware
    completion of the crop, as the depth stage completes its sweep."""
    h, w = crop.footprint.shape
    ys_m, xs_m = np.nonzero(measured & _grid((h, w), 2))
    if len(ys_m) == 0:
        ys_m, xs_m = np.nonzero(measured)
    far = cv2.distanceTransform((~measured).astype(np.uint8), cv2.DIST_L2, 3) > _REACH_PX
    kept = (far | ~crop.footprint) & np.isfinite(crop.inv) & (crop.inv > 0)
    ys_r, xs_r = np.nonzero(kept & _grid((h, w), 4))
    uv = np.concatenate([np.stack([xs_m, ys_m], 1), np.stack([xs_r, ys_r], 1)]).astype(np.float32)
    vals = np.concatenate([inv[ys_m, xs_m], crop.inv[ys_r, xs_r]])
    dense = np.clip(interpolate_edge_aware(to_uint8(crop.rgb), uv, vals), *bounds)
    # Back to working resolution: sweep pixel x is working pixel (x + 0.5) * sw - 0.5.
    depth = g.geometry.depth.copy()
    H, W = depth.shape
    sw, sh = W / crop.size[0], H / crop.size[1]
    X0, X1 = int(np.floor(crop.x0 * sw)), min(int(np.ceil((crop.x0 + w) * sw)), W)
    Y0, Y1 = int(np.floor(crop.y0 * sh)), min(int(np.ceil((crop.y0 + h) * sh)), H)
    mx, my = np.meshgrid(
        ((np.arange(X0, X1) + 0.5) / sw - 0.5 - crop.x0).astype(np.float32),
        ((np.arange(Y0, Y1) + 0.5) / sh - 0.5 - crop.y0).astype(np.float32),
    )
    up_inv = cv2.remap(dense, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    changed = (crop.footprint & ~far).astype(np.float32)
    up_foot = cv2.remap(changed, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT) > 0.5
    region = depth[Y0:Y1, X0:X1]
    region[up_foot] = 1.0 / up_inv[up_foot]
    return depth


def multiview_depth(
    refs: Sequence[ViewGeometry], cfg: MultiViewConfig, parallel: int = 1
) -> tuple[list[Geometry], MultiViewDepth]:
    """Each reference's geometry with its hole footprint's depth measured from the other views
    (unchanged where nothing was measured), and what was measured (see the module docstring)."""
    if len(refs) < 2:
        return [g.geometry for g in refs], MultiViewDepth(())
    placed = common_scales(refs, joint_scales(refs) if cfg.joint_scale else None)
    scales = [sc if np.isfinite(sp) and sp <= cfg.max_scale_spread else float("nan") for sc, sp in placed]
    greys = _Greys.of(refs, cfg.max_side)

    def one(k: int):
        if not np.isfinite(scales[k]):
            return None, 0, 0, 0
        return sweep_reference(k, refs, scales, greys, cfg)

    with ThreadPoolExecutor(max(1, min(parallel, len(refs)))) as pool:
        results = list(pool.map(one, range(len(refs))))
    geometries = [
        g.geometry if depth is None else replace(g.geometry, depth=depth)
        for g, (depth, *_) in zip(refs, results, strict=True)
    ]
    summary = tuple(
        ReferenceMultiView(g.index, sc, sp, foot, meas, nv)
        for g, (sc, sp), (_, foot, meas, nv) in zip(refs, placed, results, strict=True)
    )
    return geometries, MultiViewDepth(summary)
