"""Weight-free dense depth: two-view plane-sweep stereo on the source view, then edge-aware completion.

Sweep
    Depth hypotheses of the source pixels, uniform in inverse depth between bounds taken from the
    triangulated points (widened), are mapped into the target through
    :func:`geofill.render.project_source_points` (the renderer's own reprojection operator, so any
    camera motion works: no rectification). The hypotheses are fronto-parallel planes, except
    where the whole range would move a pixel's match by more than the hypothesis budget (forward
    motion, wide baselines): there each pixel sweeps a window of one-px steps around the inverse
    depth interpolated from the triangulated points. At each hypothesis the target's grey image,
    resized to the source's pixel footprint, is resampled onto the source grid and compared with
    zero-mean normalised cross-correlation (NCC) over a small window: NCC is invariant to gain and
    offset, so exposure changes between the two photos do not bias the match. Target pixels in
    the hole (the object being removed) and outside the image carry no evidence; windows that
    touch them are marked invalid.
Aggregation
    Each cost slice is smoothed by a guided filter with the source image as guide (cost-volume
    filtering, Hosni et al. 2013): support follows image edges, so depth edges stay sharp.
Winner-take-all and confidence
    The best plane per pixel is refined to sub-plane precision by a parabola through its
    neighbours. A pixel is confident when its best match is good (NCC), clearly better than the
    best rival outside its own peak, its window was fully valid, and it is not occluded in the
    target (a z-buffer of the winners splatted into the target: a pixel hidden behind a nearer
    winner cannot have been matched).
Completion
    Confident pixels (plus the triangulated points) seed
    :func:`geofill.depth.completion.interpolate_edge_aware`, which fills the rest with
    locally-affine, edge-aware fits: above all the source pixels whose match lies inside the target
    hole, which no photo-consistency can measure and which are exactly the ones the fill needs.

The result is inverse depth in the units of the pose translation (``in_pose_units``): the sweep
uses the pose itself, so no scale/offset fit is needed (see :class:`StereoDepth`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..camera import Intrinsics
from ..config import DepthConfig
from ..errors import ReferenceUnusable
from ..render import project_source_points, source_pixel_grid
from ..utils.jit import njit_cached
from . import DepthContext, DepthPrediction
from .completion import interpolate_edge_aware, to_uint8

#: Fewest planes of a sweep, however short its displacement range.
MIN_PLANES = 16
#: Target sampling step (px at the sweep's resolution) between neighbouring planes.
PLANE_STEP_PX = 1.0
#: Guided filter regulariser (grey levels in [0, 1], squared).
_GF_EPS = 1e-3
#: Rival planes this close to the winner belong to its own peak and do not count as rivals.
_PEAK_HALF_WIDTH = 2
#: Occlusion test: a pixel farther than the nearest winner at its target pixel by this factor is hidden.
_OCCLUSION_RATIO = 1.03
#: Confident pixels are subsampled on a grid of this step (px) before seeding the completion:
#: as accurate as every second pixel on the GT-depth pairs (mean inverse-depth error on the
#: hole-projecting pixels 0.37-0.41 vs 0.40; a step of 8: 0.47) and 4x faster.
_SEED_STEP = 4


@dataclass
class SweepResult:
    """Winner-take-all inverse depth of the source at the sweep's resolution, with its evidence."""

    inv_depth: np.ndarray  # (h, w) float32 inverse depth of the winner, pose units
    confidence: np.ndarray  # (h, w) float32 in [0, 1]
    ncc: np.ndarray  # (h, w) float32 aggregated NCC of the winner
    hyp: Hypotheses
    K_source: Intrinsics  # source intrinsics at the sweep's resolution
    bounds: tuple[float, float]  # inverse-depth range of the sweep (:func:`inverse_depth_bounds`)


def grey(image: np.ndarray) -> np.ndarray:
    """Float RGB -> float32 grey."""
    return cv2.cvtColor(image.astype(np.float32), cv2.COLOR_RGB2GRAY)


def resize_to(image: np.ndarray, scale: float) -> np.ndarray:
    """``image`` shrunk by ``scale`` (area averaging; at least 8 px a side), as is when ``scale >= 1``."""
    h, w = image.shape[:2]
    if scale >= 1.0:
        return image
    return cv2.resize(
        image, (max(round(w * scale), 8), max(round(h * scale), 8)), interpolation=cv2.INTER_AREA
    )


def inverse_depth_bounds(inv_points: np.ndarray) -> tuple[float, float]:
    """Sweep range (lo, hi) in inverse depth from the triangulated points' inverse depths: their
    2-98 % range widened by half its span (nearer) and 30 % (farther), and to at least a factor
    1.25 on either side, since surfaces without matches can lie outside it; ``lo`` stays above
    2 % of ``hi`` (the far plane of a sky or a long street would take all the hypotheses)."""
    lo, hi = np.quantile(inv_points, [0.02, 0.98])
    span = hi - lo
    hi = max(hi + 0.5 * span, 1.25 * hi)
    lo = max(min(lo - 0.3 * span, lo / 1.25), 0.02 * hi)
    return float(lo), float(hi)


def displacement_span(
    shape: tuple[int, int], K_s: Intrinsics, K_t: Intrinsics, T: np.ndarray, lo: float, hi: float
) -> np.ndarray:
    """(h, w) distance (target px) each source pixel's match moves over the inverse-depth range."""
    x, y = source_pixel_grid(*shape)
    u0, v0, _ = project_source_points(x, y, 1.0 / lo, K_s, K_t, T)
    u1, v1, _ = project_source_points(x, y, 1.0 / hi, K_s, K_t, T)
    return np.nan_to_num(np.hypot(u1 - u0, v1 - v0), nan=0.0)


def plane_count(span_px: np.ndarray, max_planes: int) -> int:
    """About one hypothesis per :data:`PLANE_STEP_PX` of the 95th-percentile displacement span,
    within [:data:`MIN_PLANES`, ``max_planes``]."""
    span = float(np.percentile(span_px, 95))
    return int(np.clip(np.ceil(span / PLANE_STEP_PX), MIN_PLANES, max(max_planes, MIN_PLANES)))


def target_magnification(
    shape: tuple[int, int], K_s: Intrinsics, K_t: Intrinsics, T: np.ndarray, depth: float
) -> float:
    """Median linear scale (target px per source px) of the source->target map at ``depth``."""
    h, w = shape
    x, y = source_pixel_grid(h, w)
    x, y = x[4::16, 4::16], y[4::16, 4::16]
    u, v, _ = project_source_points(x, y, depth, K_s, K_t, T)
    ux, vx, _ = project_source_points(x + 1.0, y, depth, K_s, K_t, T)
    uy, vy, _ = project_source_points(x, y + 1.0, depth, K_s, K_t, T)
    det = np.abs((ux - u) * (vy - v) - (uy - u) * (vx - v))
    det = det[np.isfinite(det)]
    return float(np.sqrt(np.median(det))) if det.size else 1.0


@dataclass
class Hypotheses:
    """Per-pixel depth hypotheses: ``count`` inverse depths ``lo + k * step`` (k = 0..count-1)."""

    lo: np.ndarray  # (h, w) float64
    step: np.ndarray  # (h, w) float64
    count: int

    def at(self, k: float | np.ndarray) -> np.ndarray:
        return self.lo + k * self.step


def hypotheses(span_px: np.ndarray, prior: np.ndarray | None, lo: float, hi: float, count: int) -> Hypotheses:
    """``count`` hypotheses per pixel, uniform in inverse depth. Where the global range [lo, hi]
    moves the pixel's match (``span_px``) by more than ``count`` x :data:`PLANE_STEP_PX` (forward
    motion, wide baselines: hundreds of px), the pixel gets a window of that many steps centred on
    ``prior`` (inverse depth interpolated from the triangulated points; needed only then) instead:
    a coarser global sweep would step over the narrow NCC peak of fine texture."""
    budget = count * PLANE_STEP_PX
    half = 0.5 * (hi - lo) * np.minimum(1.0, budget / np.maximum(span_px, 1e-9))
    centre = 0.5 * (lo + hi) if prior is None else np.nan_to_num(prior, nan=0.5 * (lo + hi))
    centre = np.clip(centre, lo + half, hi - half)
    return Hypotheses(centre - half, 2.0 * half / max(count - 1, 1), count)


#: Target value that marks samples without evidence (in the hole, outside the image): any
#: bilinear sample that gives it weight lands far above the grey range, so one ``cv2.remap`` both
#: samples the target and says whether the sample is valid.
_NO_EVIDENCE = np.float32(1e30)


# The kernels below run on flattened images (channels last where there are 4): numba vectorises
# the flat loops, not the 2-D ones (measured 2-3x). NumPy's error model drops the division-by-zero
# checks that otherwise keep the loops scalar (the map kernel: 4x); the fast-maths flags leave out
# "no NaN / no inf", as a point on the target camera's plane divides by zero.
_FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}


@njit_cached(nogil=True, fastmath=_FAST, error_model="numpy")
def _plane_maps(rays, t, k_t, lo, step, i, mu, mv):  # pragma: no cover - compiled
    """Remap maps (target px) of every source pixel at inverse depth ``lo + i * step``; -1 where the
    point is behind the target camera or projects outside the target. Hand-written because the
    same map through :func:`geofill.render.project_source_points` (float64 temporaries) took about
    half of the sweep: per pixel ``(R r + rho t)``, ``r`` the source ray, is a few float32 ops."""
    fx, fy, cx, cy, umax, vmax = k_t[0], k_t[1], k_t[2], k_t[3], k_t[4], k_t[5]
    fi = np.float32(i)
    for j in range(lo.size):
        rho = lo[j] + fi * step[j]
        zt = rays[2, j] + rho * t[2]
        u = fx * (rays[0, j] + rho * t[0]) / zt + cx
        v = fy * (rays[1, j] + rho * t[1]) / zt + cy
        inside = (zt > 0) & (u >= 0) & (u <= umax) & (v >= 0) & (v <= vmax)
        mu[j] = u if inside else np.float32(-1)
        mv[j] = v if inside else np.float32(-1)


@njit_cached(nogil=True, fastmath=_FAST, error_model="numpy")
def _window_moments(warped, src, out):  # pragma: no cover - compiled
    """Per pixel (warped, warped^2, src * warped, valid) into ``out`` (4 per pixel), warped zeroed
    where it holds no evidence: what one 4-channel box filter turns into window moments."""
    for j in range(src.size):
        val = warped[j]
        ok = val < np.float32(2)
        val = val if ok else np.float32(0)
        out[4 * j] = val
        out[4 * j + 1] = val * val
        out[4 * j + 2] = src[j] * val
        out[4 * j + 3] = np.float32(1) if ok else np.float32(0)


@njit_cached(nogil=True, fastmath=_FAST, error_model="numpy")
def _ncc(m, mu_s, var_s, ncc, valid):  # pragma: no cover - compiled
    """NCC and validity of every window from its moments ``m`` (:func:`_window_moments` boxed);
    invalid windows score 0 (no evidence either way)."""
    for j in range(mu_s.size):
        mt = m[4 * j]
        var_t = max(m[4 * j + 1] - mt * mt, np.float32(0))
        ok = m[4 * j + 3] > np.float32(0.999)
        c = (m[4 * j + 2] - mu_s[j] * mt) / np.sqrt(var_s[j] * var_t + np.float32(1e-6))
        ncc[j] = c if ok else np.float32(0)
        valid[j] = ok


def sweep_ncc(
    src: np.ndarray,
    tgt: np.ndarray,
    tgt_invalid: np.ndarray,
    K_s: Intrinsics,
    K_t: Intrinsics,
    T: np.ndarray,
    hyp: Hypotheses,
    patch: int,
) -> tuple[np.ndarray, np.ndarray]:
    """NCC volume (D, h, w) float32 of grey ``src`` against grey ``tgt`` resampled at each
    hypothesis, and its validity (D, h, w) bool (False where the window touches a target pixel
    outside the image or in ``tgt_invalid``; the NCC is 0 there)."""
    h, w = src.shape
    ht, wt = tgt.shape
    # R r of each source pixel's ray r = K_s^-1 (x, y, 1): its match at inverse depth rho is
    # K_t (R r + rho t) (the reprojection of :func:`geofill.render.project_source_points`).
    R = T[:3, :3]
    rx = ((np.arange(w) - K_s.cx) / K_s.fx)[None, :]
    ry = ((np.arange(h) - K_s.cy) / K_s.fy)[:, None]
    rays = (
        np.stack([R[i, 0] * rx + R[i, 1] * ry + R[i, 2] for i in range(3)]).astype(np.float32).reshape(3, -1)
    )
    t = T[:3, 3].astype(np.float32)
    k_t = np.array([K_t.fx, K_t.fy, K_t.cx, K_t.cy, wt - 1, ht - 1], np.float32)
    lo, step = (np.broadcast_to(a, (h, w)).astype(np.float32).ravel() for a in (hyp.lo, hyp.step))
    tgt = np.where(tgt_invalid, _NO_EVIDENCE, tgt).astype(np.float32)
    k = (patch, patch)
    mu_s = cv2.boxFilter(src, -1, k, borderType=cv2.BORDER_REFLECT)
    var_s = np.maximum(cv2.boxFilter(src * src, -1, k, borderType=cv2.BORDER_REFLECT) - mu_s * mu_s, 0.0)
    mu, mv, warped = (np.empty((h, w), np.float32) for _ in range(3))
    moments, boxed = np.empty((h, w, 4), np.float32), np.empty((h, w, 4), np.float32)
    flat = np.ravel
    ncc = np.empty((hyp.count, h, w), np.float32)
    valid = np.empty((hyp.count, h, w), bool)
    for i in range(hyp.count):
        _plane_maps(rays, t, k_t, lo, step, i, flat(mu), flat(mv))
        cv2.remap(tgt, mu, mv, cv2.INTER_LINEAR, warped, cv2.BORDER_CONSTANT, float(_NO_EVIDENCE))
        _window_moments(flat(warped), flat(src), flat(moments))
        # One 4-channel box filter costs about what two single-channel ones do.
        cv2.boxFilter(moments, -1, k, boxed, borderType=cv2.BORDER_REFLECT)
        _ncc(flat(boxed), flat(mu_s), flat(var_s), flat(ncc[i]), flat(valid[i]))
    return ncc, valid


@njit_cached(nogil=True, fastmath=_FAST, error_model="numpy")
def _gf_inputs(c0, c1, guide, out):  # pragma: no cover - compiled
    """(p, I p) of two cost slices into ``out`` (4 per pixel) for one 4-channel box filter."""
    for j in range(guide.size):
        out[4 * j] = c0[j]
        out[4 * j + 1] = guide[j] * c0[j]
        out[4 * j + 2] = c1[j]
        out[4 * j + 3] = guide[j] * c1[j]


@njit_cached(nogil=True, fastmath=_FAST, error_model="numpy")
def _gf_coefficients(m, mean_g, inv_denom, out):  # pragma: no cover - compiled
    """The guided filter's local linear models (a, b) of two slices from their box means ``m``."""
    for j in range(mean_g.size):
        a0 = (m[4 * j + 1] - mean_g[j] * m[4 * j]) * inv_denom[j]
        a1 = (m[4 * j + 3] - mean_g[j] * m[4 * j + 2]) * inv_denom[j]
        out[4 * j] = a0
        out[4 * j + 1] = m[4 * j] - a0 * mean_g[j]
        out[4 * j + 2] = a1
        out[4 * j + 3] = m[4 * j + 2] - a1 * mean_g[j]


@njit_cached(nogil=True, fastmath=_FAST, error_model="numpy")
def _gf_outputs(m, guide, c0, c1):  # pragma: no cover - compiled
    """Filtered slices from the box means ``m`` of their local models: mean(a) I + mean(b)."""
    for j in range(guide.size):
        c0[j] = m[4 * j] * guide[j] + m[4 * j + 1]
        c1[j] = m[4 * j + 2] * guide[j] + m[4 * j + 3]


def aggregate(cost: np.ndarray, guide: np.ndarray, radius: int) -> np.ndarray:
    """Guided-filter each (h, w) slice of ``cost`` (D, h, w) with ``guide`` (grey, [0, 1]); in place.

    The guided filter (He et al. 2013; ``cv2.ximgproc``'s, which this matches to float rounding)
    runs on two slices at a time through 4-channel box filters: one 4-channel box filter costs
    about what two single-channel ones do (measured: 58 slices of 448 x 252 in 16 ms, ``ximgproc``
    slice by slice 27 ms)."""
    if radius <= 0:
        return cost
    k = (2 * radius + 1,) * 2

    def box(a: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(a, -1, k, borderType=cv2.BORDER_REFLECT)

    mean_g = box(guide)
    inv_denom = 1.0 / (box(guide * guide) - mean_g * mean_g + np.float32(_GF_EPS))
    buf = np.empty(guide.shape + (4,), np.float32)
    flat, g, mean_g, inv_denom = np.ravel, guide.ravel(), mean_g.ravel(), inv_denom.ravel()
    for i in range(0, len(cost), 2):
        j = min(i + 1, len(cost) - 1)  # an odd last slice is filtered twice
        _gf_inputs(flat(cost[i]), flat(cost[j]), g, flat(buf))
        _gf_coefficients(flat(box(buf)), mean_g, inv_denom, flat(buf))
        _gf_outputs(flat(box(buf)), g, flat(cost[i]), flat(cost[j]))
    return cost


@njit_cached(nogil=True, error_model="numpy")
def _winner_take_all(score, lo, step, peak_half_width, inv, best_score, rival, best):  # pragma: no cover
    """:func:`winner_take_all` on ``score`` (D, n) into (n,) arrays. Hand-written because the NumPy
    version made six passes over the whole volume (argmax, gathers, a peak mask, a masked max)
    and was the sweep's most expensive step; here two streaming passes over the planes (a pixel's
    scores are a plane apart in memory, so the loops run plane by plane) and one gather."""
    D, n = score.shape
    best_score[:] = score[0]
    best[:] = 0
    for k in range(1, D):
        for j in range(n):
            if score[k, j] > best_score[j]:
                best_score[j] = score[k, j]
                best[j] = k
    rival[:] = -np.inf
    for k in range(D):
        below, above = max(k - 1, 0), min(k + 1, D - 1)  # an end plane is compared with itself
        for j in range(n):
            s = score[k, j]
            rival_peak = (
                (s >= score[below, j]) & (s >= score[above, j]) & (abs(k - best[j]) > peak_half_width)
            )
            rival[j] = max(rival[j], s) if rival_peak else rival[j]
    for j in range(n):
        rival[j] = max(rival[j], np.float32(-1))
        b = best[j]
        off = np.float32(0)
        if 1 <= b <= D - 2:
            sa, sb, sc = score[b - 1, j], score[b, j], score[b + 1, j]
            curv = sa - (sb + sb) + sc
            if curv < 0:
                off = min(max(np.float32(0.5) * (sa - sc) / curv, np.float32(-0.5)), np.float32(0.5))
        inv[j] = lo[j] + (b + np.float64(off)) * step[j]


def winner_take_all(
    score: np.ndarray, hyp: Hypotheses
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Best hypothesis per pixel of ``score`` (D, h, w; higher is better), refined by a parabola.

    Returns (inverse depth, best score, best rival score, winner index); the rival is the best
    other local maximum, so the shoulders of the winner's own peak do not count."""
    shape = score.shape[1:]
    n = score[0].size
    inv = np.empty(n, np.float32)
    s1, rival = np.empty(n, np.float32), np.empty(n, np.float32)
    best = np.empty(n, np.int64)
    lo, step = (np.broadcast_to(a, shape).astype(np.float64).ravel() for a in (hyp.lo, hyp.step))
    flat = np.ascontiguousarray(score, np.float32).reshape(len(score), n)
    _winner_take_all(flat, lo, step, _PEAK_HALF_WIDTH, inv, s1, rival, best)
    return inv.reshape(shape), s1.reshape(shape), rival.reshape(shape), best.reshape(shape)


def confidence(ncc: np.ndarray, margin: np.ndarray) -> np.ndarray:
    """Confidence in [0, 1] of a winner with aggregated NCC ``ncc`` that beats its best rival by
    ``margin``: the smaller of two ramps, NCC 0.2 -> 0.8 and margin 0 -> 0.2, so 0.5 means NCC >= 0.5
    and margin >= 0.1. On the synthetic scenes and GT-depth pairs lower thresholds added pixels
    mostly wrong by > 10 % (benchmarks/studies/depth_eval.py; docs/results.md)."""
    return np.minimum(np.clip((ncc - 0.2) / 0.6, 0, 1), np.clip(margin / 0.2, 0, 1))


def occluded_in_target(
    inv: np.ndarray, K_s: Intrinsics, K_t: Intrinsics, T: np.ndarray, target_shape: tuple[int, int]
) -> np.ndarray:
    """(h, w) bool: source pixels that a nearer source pixel covers in the target (z-buffer of the
    winners splatted to the nearest target pixel): hidden there, so their match is not theirs."""
    ht, wt = target_shape
    u, v, z = project_source_grid_inv(inv, K_s, K_t, T)
    ui, vi = np.rint(u), np.rint(v)
    ok = np.isfinite(z) & (z > 0) & (ui >= 0) & (ui < wt) & (vi >= 0) & (vi < ht)
    flat = (vi[ok] * wt + ui[ok]).astype(np.int64)
    zbuf = np.full(ht * wt, np.inf)
    np.minimum.at(zbuf, flat, z[ok])
    hidden = np.zeros(inv.shape, bool)
    hidden[ok] = z[ok] > _OCCLUSION_RATIO * zbuf[flat]
    return hidden


def project_source_grid_inv(inv: np.ndarray, K_s: Intrinsics, K_t: Intrinsics, T: np.ndarray):
    """:func:`geofill.render.project_source_points` of every pixel of an inverse-depth map."""
    x, y = source_pixel_grid(*inv.shape)
    with np.errstate(divide="ignore"):
        return project_source_points(x, y, 1.0 / inv.astype(np.float64), K_s, K_t, T)


def plane_sweep(ctx: DepthContext) -> SweepResult:
    """Plane sweep of ``ctx.source`` against ``ctx.target`` with ``ctx.pose`` (see module docstring)."""
    cfg: DepthConfig = ctx.cfg
    pts = ctx.points
    if len(pts) < 3:
        raise ReferenceUnusable(f"stereo needs triangulated points to bound its depth range; got {len(pts)}")
    hs0, ws0 = ctx.source.shape[:2]
    s = min(1.0, cfg.stereo_max_side / max(hs0, ws0))
    src_rgb = resize_to(ctx.source, s)
    hs, ws = src_rgb.shape[:2]
    K_s = ctx.K_source.resized(ws, hs)
    T = ctx.pose.T
    lo, hi = inverse_depth_bounds(1.0 / pts.depth)
    # The target at the source's pixel footprint, so that resampling it onto the source grid does
    # not alias when it sees the scene closer up (wide baselines, zoom).
    s_t = min(1.0, 1.0 / target_magnification((hs, ws), K_s, ctx.K_target, T, np.median(pts.depth)))
    tgt = resize_to(grey(ctx.target), s_t)
    ht, wt = tgt.shape
    K_t = ctx.K_target.resized(wt, ht)
    hole = cv2.resize(ctx.hole.astype(np.uint8), (wt, ht), interpolation=cv2.INTER_AREA) > 0
    span = displacement_span((hs, ws), K_s, K_t, T, lo, hi)
    D = plane_count(span, cfg.stereo_max_planes)
    prior = sparse_prior(to_uint8(src_rgb), pts, (hs0, ws0)) if (span > D * PLANE_STEP_PX).any() else None
    hyp = hypotheses(span, prior, lo, hi, D)
    src = grey(src_rgb)
    # Invalid windows score 0 (no evidence either way): aggregation neither rewards nor punishes them.
    ncc, valid = sweep_ncc(src, tgt, hole, K_s, K_t, T, hyp, cfg.stereo_patch_px)
    ncc = aggregate(ncc, src, cfg.stereo_aggregation_radius)
    inv, s1, rival, best = winner_take_all(ncc, hyp)
    conf = confidence(s1, s1 - rival)
    conf[~np.take_along_axis(valid, best[None], 0)[0]] = 0.0
    # Only winners that pass the other tests may hide others: a wrong winner must not veto a right one.
    occl = occluded_in_target(np.where(conf >= cfg.stereo_min_confidence, inv, np.nan), K_s, K_t, T, (ht, wt))
    conf[occl] = 0.0
    return SweepResult(inv, conf.astype(np.float32), s1.astype(np.float32), hyp, K_s, (lo, hi))


class StereoDepth:
    """``stereo`` backend: :func:`plane_sweep` + edge-aware completion, in pose units.

    It does not go through a scale/offset fit (``in_pose_units``): depths come from the very pose
    and intrinsics the renderer uses, so rendering them reproduces the matched correspondences
    exactly; refitting them to the triangulated points (same pose) could only add the points'
    noise."""

    name = "stereo"

    def predict(self, ctx: DepthContext) -> DepthPrediction:
        sweep = plane_sweep(ctx)
        inv = complete(sweep, ctx)
        h, w = ctx.source.shape[:2]
        conf = cv2.resize(sweep.confidence, (w, h), interpolation=cv2.INTER_LINEAR)
        inv = cv2.resize(inv, (w, h), interpolation=cv2.INTER_LINEAR)
        inv[~(inv > 0)] = np.nan
        return DepthPrediction(inv, "inverse", self.name, in_pose_units=True, confidence=conf)


def sparse_prior(guide: np.ndarray, pts, source_shape: tuple[int, int]) -> np.ndarray:
    """Inverse depth of the triangulated points (pixels of a ``source_shape`` image) interpolated
    edge-aware over ``guide`` (the source at the sweep's resolution)."""
    h, w = guide.shape[:2]
    hs0, ws0 = source_shape
    uv = (pts.uv_source + 0.5) * [w / ws0, h / hs0] - 0.5
    return interpolate_edge_aware(guide, uv, 1.0 / pts.depth)


def complete(sweep: SweepResult, ctx: DepthContext) -> np.ndarray:
    """Dense inverse depth at the sweep's resolution: confident sweep pixels (on a grid) and the
    triangulated points seed an edge-aware interpolation guided by the source, kept inside the
    sweep's range: the interpolator's affine fits, extrapolated far from their seeds, can run to
    ~0 or negative inverse depth (measured: forward-motion street pairs; clamping gained +2.1 dB
    hole PSNR on one, +0.13 dB mean over the 18 pairs, nothing on the synthetic scenes)."""
    h, w = sweep.inv_depth.shape
    conf_ok = (sweep.confidence >= ctx.cfg.stereo_min_confidence) & np.isfinite(sweep.inv_depth)
    grid = np.zeros_like(conf_ok)
    grid[::_SEED_STEP, ::_SEED_STEP] = True
    ys, xs = np.nonzero(conf_ok & grid)
    pts = ctx.points
    hs0, ws0 = ctx.source.shape[:2]
    uv = np.concatenate([np.stack([xs, ys], axis=1), (pts.uv_source + 0.5) * [w / ws0, h / hs0] - 0.5])
    vals = np.concatenate([sweep.inv_depth[ys, xs], 1.0 / pts.depth])
    guide = to_uint8(cv2.resize(ctx.source, (w, h), interpolation=cv2.INTER_AREA))
    return np.clip(interpolate_edge_aware(guide, uv, vals), *sweep.bounds)
