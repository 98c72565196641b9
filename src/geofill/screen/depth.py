"""Geometry decides what is the removed object.

In a removal the hole shows the object, so stereo between the target's hole (as given) and a
reference measures the object's own depth; the surface behind it is the one the known ring around
the hole gives (the render's depth there is measured: target and reference both see the ring),
extended across the hole as a plane fitted robustly to the ring's inverse depth in target camera
coordinates (a plane's inverse depth is affine in the pixel coordinates). A plane sweep in the
target's view, over inverse depths from a little behind that surface to far in front of it, finds
per hole pixel where its patch matches the reference best (zero-mean normalised cross-correlation):

- pixels that match in front of the surface (and clearly better than on it) are the object;
- pixels that match on the surface are background, however much the brushed margin around the
  object shows (the margin is in every reference too: only its depth tells it from the object);
- the rest (flat patches, occluded ones) take the label of their region: OpenCV's watershed on the
  hole's content grows the two from their seeds, so the object's own edges bound it (a flat part
  that no measured background bounds goes with the object).

The object's pixels, at their depth (measured, or carried over the object from its measured
pixels by a membrane), are projected into the reference: that is the object as the reference shows
it, whatever its other faces, scale or reflections look like there. Render pixels that sample it
are refused; with several references it is also cut out of the reference's mesh before rendering.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..camera import Intrinsics
from ..config import ScreenConfig
from ..render import RenderResult
from ..utils.distance import known_ring
from ..utils.membrane import membrane_fill
from ..utils.numerics import robust_linear_fit
from ..utils.resolution import config_px, odd_px
from ..utils.windows import mask_window
from .strangers import watershed_region

#: Long side (px) of the hole's window in which the sweep runs: it separates regions tens of pixels
#: wide, and its cost grows with the pixels times the planes.
DEPTH_TEST_SIDE = 320
#: Inverse-depth ratios to the surface swept: from a little behind it (the surface's own error) to
#: an object at a sixth of the surface's distance.
_NEAREST_RATIO = 6.0
_FARTHEST_RATIO = 0.8
#: The planes are spaced so that a hole pixel moves about this far (px, sweep resolution) in the
#: reference between two of them; at most this many planes.
_PLANE_STEP_PX = 1.0
_MAX_PLANES = 64
#: The match a hole patch needs in front of the surface to seed the object (zero-mean NCC, over
#: the aggregated support).
_FRONT_NCC = 0.8
#: Side (px, at the sweep's resolution) of the box over which each plane's patch NCC is averaged
#: before the best plane is picked: over 7-px patches alone the best of ~50 planes in front matched
#: 10-20 % of a photo cutout no reference shows at >= 0.8 by chance (and the watershed grew those
#: seeds over 53-93 % of it); averaged over 9 px, none, while 78-82 % of a box's textured pixels
#: still matched (`tests/test_screen_depth.py`). Neighbouring patches of a real surface agree on its
#: depth; chance matches do not.
_SUPPORT_PX = 9
#: Planes within this many of the best one belong to its peak; the best match farther away is the
#: second candidate the best has to beat by ``screen.object_ncc_gap`` (uniqueness).
_PEAK_PLANES = 3
#: Ring pixels with a rendered depth needed to fit the surface.
_MIN_RING_PX = 30


@dataclass(frozen=True)
class DepthLocation:
    """What the depth test found in one reference. ``source``: HxW bool at the reference's input
    size, where it shows the removed object (None: nothing there is the object); ``in_hole``: HxW
    bool at the target's size, the hole pixels whose content lies in front of the surface;
    ``measured``: the share of the hole whose depth the sweep measured (front or on the surface);
    ``reason``: why nothing could be decided ('' when the test ran)."""

    source: np.ndarray | None
    in_hole: np.ndarray | None
    measured: float = 0.0
    object_px: int = 0
    reason: str = ""
    sweep: ObjectSweep | None = None  # what the sweep measured, for :func:`locate_together`
    #: ``source`` comes from :func:`~geofill.screen.appearance.locate_by_appearance` (the depth test
    #: located nothing).
    by_appearance: bool = False
    #: ``source`` comes from :func:`~geofill.screen.surface.locate_on_surface` (the depth test
    #: located nothing): the hole's content that its ring does not explain, shown by the reference on
    #: the ring's surface.
    on_surface: bool = False

    @property
    def located(self) -> bool:
        return self.source is not None and bool(self.source.any())

    def summary(self) -> str:
        if self.reason:
            return f"object not located: {self.reason}"
        if self.by_appearance:
            return "nothing in front of the surface; the hole's content located by its look"
        if not self.located:
            return f"nothing in front of the surface ({100 * self.measured:.0f}% of the hole measured)"
        if self.on_surface:
            return "nothing in front of the surface; what the ring does not explain found on the surface"
        return (
            f"the object in front of the surface: {self.object_px} px of the hole "
            f"({100 * self.measured:.0f}% measured)"
        )


def surface_plane(depth: np.ndarray, ring: np.ndarray, rows: slice, cols: slice) -> np.ndarray | None:
    """(a, b, c) with inverse depth ``a x + b y + c`` (x, y full-image pixels): the plane fitted
    to ``depth`` (a window's target-camera z, inf/NaN where empty) on ``ring``, robustly (soft-L1
    residuals, scale 2 % of the ring's median inverse depth: a pole or a step at the ring's edge is
    an outlier, not a tilt). None with fewer than :data:`_MIN_RING_PX` ring pixels.

    >>> z = 1 / (0.01 * np.arange(40)[None, :] + 0.5 + np.zeros((30, 1)))
    >>> ring = np.ones((30, 40), bool); ring[10:20, 10:30] = False
    >>> np.round(surface_plane(z, ring, slice(0, 30), slice(0, 40)), 4).tolist()
    [0.01, 0.0, 0.5]
    """
    ok = ring & np.isfinite(depth) & (depth > 0)
    ys, xs = np.nonzero(ok)
    if len(ys) < _MIN_RING_PX:
        return None
    step = max(1, len(ys) // 4000)  # a few thousand points fit a plane
    ys, xs = ys[::step], xs[::step]
    inv = 1.0 / depth[ys, xs].astype(np.float64)
    scale = float(np.median(inv))
    x, y = xs + cols.start, ys + rows.start
    A = np.column_stack([x, y, np.full(len(x), 1.0)])
    norm = np.array([1.0 / max(x.max(), 1), 1.0 / max(y.max(), 1), 1.0])  # well-conditioned columns
    p = robust_linear_fit(A * norm, inv / scale, "soft_l1", 0.02)
    return p * norm * scale


@dataclass(frozen=True)
class ObjectSweep:
    """One reference's plane sweep of the hole, on the target's sweep grid (the hole's window
    ``rows``/``cols`` resized to ``size``, the same for every reference of a fill): ``front``
    (seeds of the object, at inverse-depth ratio ``front_ratio`` to the surface), ``behind``
    (seeds of the background, on the surface), ``unmatched`` (textured content the reference shows
    at no depth), and what projects a grid pixel at a ratio into the reference (``rays`` rotated
    into its frame, its translation ``t``, the surface's inverse depth, its intrinsics at
    ``source_size``)."""

    rows: slice
    cols: slice
    hole: np.ndarray
    shown: np.ndarray
    front: np.ndarray
    front_ratio: np.ndarray
    behind: np.ndarray
    unmatched: np.ndarray
    measured: float
    rays: np.ndarray
    t: np.ndarray
    inv_surface: np.ndarray
    K_source: Intrinsics
    source_size: tuple[int, int]

    def project(self, ratio: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the grid's pixels at inverse-depth ``ratio`` to the surface land in the reference
        (float32 px at the sweep's scale; -1e6 behind its camera)."""
        z = 1.0 / (self.inv_surface * ratio)
        P = self.rays * z + self.t[:, None, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.K_source.fx * P[0] / P[2] + self.K_source.cx
            v = self.K_source.fy * P[1] / P[2] + self.K_source.cy
        behind = ~(P[2] > 1e-9)
        u[behind], v[behind] = -1e6, -1e6
        return u.astype(np.float32), v.astype(np.float32)


def locate_by_depth(
    shown: np.ndarray,
    hole: np.ndarray,
    source: np.ndarray,
    render: RenderResult,
    K_target: Intrinsics,
    K_source: Intrinsics,
    T: np.ndarray,
    sc: ScreenConfig,
) -> DepthLocation:
    """The removed object as the reference ``source`` (HxWx3 uint8) shows it, found by depth (see
    the module docstring). ``shown``: the target as given (its hole shows the object); ``render``:
    the reference's render (its depth on the ring gives the surface); ``K_*`` and ``T`` (4x4
    source -> target): the pair's geometry (any resolution: resized here). The location keeps its
    sweep, for :func:`locate_together`."""
    H, W = hole.shape
    K_t = K_target.resized(W, H)
    ring_px = config_px(sc.surface_ring_px, hole.shape)
    rows, cols = mask_window(hole, int(ring_px) + 2)
    ring = known_ring(hole[rows, cols], ring_px)
    plane = surface_plane(render.depth[rows, cols], ring & render.alpha[rows, cols], rows, cols)
    if plane is None:
        return DepthLocation(None, None, reason="the render shows too little of the hole's surroundings")
    h, w = rows.stop - rows.start, cols.stop - cols.start
    f = min(1.0, DEPTH_TEST_SIDE / max(h, w))
    size = (max(round(w * f), 1), max(round(h * f), 1))
    hole_s = cv2.resize(hole[rows, cols].astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    shown_s = cv2.resize(np.ascontiguousarray(shown[rows, cols]), size, interpolation=cv2.INTER_AREA)
    grey_t = cv2.cvtColor(shown_s, cv2.COLOR_RGB2GRAY).astype(np.float32)
    # The reference at about the sweep's scale (its own size times the target's factor).
    fs = min(1.0, f * max(W / source.shape[1], H / source.shape[0]))
    ss = (max(round(source.shape[1] * fs), 1), max(round(source.shape[0] * fs), 1))
    grey_s = cv2.cvtColor(cv2.resize(source, ss, interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2GRAY)
    # Full-image coordinates of the sweep's pixel centres, and the surface's inverse depth there.
    ys = rows.start + (np.arange(size[1], dtype=np.float64) + 0.5) * (h / size[1]) - 0.5
    xs = cols.start + (np.arange(size[0], dtype=np.float64) + 0.5) * (w / size[0]) - 0.5
    X, Y = np.meshgrid(xs, ys)
    rays = np.stack([(X - K_t.cx) / K_t.fx, (Y - K_t.cy) / K_t.fy, np.ones_like(X)])
    T_st = np.linalg.inv(T)  # target -> source
    empty = np.zeros(hole_s.shape, bool)
    sweep = ObjectSweep(
        rows, cols, hole_s, shown_s, empty, np.zeros(hole_s.shape, np.float32), empty, empty, 0.0,
        np.einsum("ij,jhw->ihw", T_st[:3, :3], rays), T_st[:3, 3],
        np.maximum(plane[0] * X + plane[1] * Y + plane[2], 1e-9), K_source.resized(*ss), ss,
    )  # fmt: skip
    # Planes spaced by the reference's displacement at the hole's centre.
    cy, cx = np.argwhere(hole_s).mean(axis=0) if hole_s.any() else (size[1] / 2, size[0] / 2)
    iy, ix = int(cy), int(cx)
    u0, v0 = sweep.project(_FARTHEST_RATIO)
    u1, v1 = sweep.project(_NEAREST_RATIO)
    span = float(np.hypot(u1[iy, ix] - u0[iy, ix], v1[iy, ix] - v0[iy, ix]))
    if not np.isfinite(span) or span < 4 * _PLANE_STEP_PX:
        return DepthLocation(None, None, reason="the reference sees the hole from about the same place")
    n = int(np.clip(span / _PLANE_STEP_PX, 8, _MAX_PLANES))
    # Uniform in inverse depth: the displacement grows linearly with it.
    ratios = np.linspace(_FARTHEST_RATIO, _NEAREST_RATIO, n)
    volume = ncc_volume(grey_t, grey_s.astype(np.float32), [sweep.project(r) for r in ratios])
    on_surface, in_front, front_ratio, rival = _best_matches(volume, ratios, 1.0 + sc.object_depth_margin)
    textured = np.sqrt(np.maximum(_box_variance(grey_t), 0.0)) > sc.object_min_texture
    # Each side only where it matches well and clearly better than the other: a flat or repetitive
    # patch matches at many depths and is left to the watershed.
    # The ring around the hole is swept too: where it is measured on the surface it bounds the object.
    good = textured & (np.maximum(in_front, on_surface) > sc.object_min_ncc)
    # In front only where it matches very well and uniquely: better by the gap than on the surface
    # and than at any other depth in front (a repetitive or smooth patch matches at several).
    front = good & hole_s & (in_front - rival > sc.object_ncc_gap) & (in_front > _FRONT_NCC)
    # On the surface where it matches best there: a smooth texture matches almost as well a pixel or
    # two off, so no gap is asked of the background (the object has to beat it by one).
    behind = good & (on_surface >= in_front)
    measured = float(np.count_nonzero((front | behind) & hole_s)) / max(int(hole_s.sum()), 1)
    # Seeds too small to be a region are matching noise.
    m = max(3, odd_px(sc.stranger_min_px / 2 * config_px(1.0, hole.shape) * f))
    opening = np.ones((m, m), np.uint8)
    sweep = replace(
        sweep,
        front=cv2.morphologyEx(front.astype(np.uint8), cv2.MORPH_OPEN, opening) > 0,
        front_ratio=front_ratio,
        behind=cv2.morphologyEx(behind.astype(np.uint8), cv2.MORPH_OPEN, opening) > 0,
        # Textured content that matches nowhere is not in the reference (an object only the target
        # shows): nothing of it to refuse there. Flat content goes with the region it lies in.
        unmatched=textured & (np.maximum(in_front, on_surface) <= sc.object_min_ncc),
        measured=measured,
    )
    return replace(_locate([sweep], hole, [source.shape], sc)[0], sweep=sweep)


def locate_together(
    locations: list[DepthLocation], hole: np.ndarray, sources: list[np.ndarray], sc: ScreenConfig
) -> list[DepthLocation]:
    """The object located in every reference from the evidence of all: what any reference's sweep
    puts in front of the surface seeds it (a solid object one reference matches well, another
    sees from so far or near that its patches match at no depth), at the depth that reference
    measured, projected into each of them. ``locations``: :func:`locate_by_depth`'s, one per
    reference of ``sources``; one whose test could not run keeps its own."""
    ran = [i for i, loc in enumerate(locations) if loc.sweep is not None]
    if len(ran) < 2:
        return locations
    joint = _locate([locations[i].sweep for i in ran], hole, [sources[i].shape for i in ran], sc)
    out = list(locations)
    for i, loc in zip(ran, joint, strict=True):
        out[i] = replace(loc, sweep=locations[i].sweep)
    return out


def _locate(
    sweeps: list[ObjectSweep], hole: np.ndarray, shapes: list[tuple[int, ...]], sc: ScreenConfig
) -> list[DepthLocation]:
    """The object seeded by every sweep's ``front`` (at the mean of the ratios measured there), grown
    over the hole against their ``behind``, and projected into each sweep's reference (``shapes``:
    their input sizes)."""
    first = sweeps[0]
    front = np.logical_or.reduce([s.front for s in sweeps])
    measured = max(s.measured for s in sweeps)
    if not front.any():
        return [DepthLocation(None, None, s.measured) for s in sweeps]
    # Only what was measured marks (the ring too, where measured): a flat part of the hole that no
    # measured background separates from the object goes with the object (painting a flat margin
    # costs little; copying a flat part of the object back is a ghost).
    markers = np.zeros(front.shape, np.int32)
    markers[np.logical_or.reduce([s.behind for s in sweeps])] = 2
    markers[front] = 1
    grown = watershed_region(first.shown, markers)  # with the seam around the object
    unmatched = np.logical_and.reduce([s.unmatched for s in sweeps])
    # One object: the convex hull of its parts in the hole (a flat or bright band across it, which
    # the stereo cannot place, split a planar cutout on the living room in two, and the band came
    # back from the reference between the two parts' hulls there).
    obj = _hull(front | (grown & ~unmatched)) & first.hole
    counts = np.sum([s.front for s in sweeps], axis=0)
    ratio = np.sum([np.where(s.front, s.front_ratio, 0.0) for s in sweeps], axis=0) / np.maximum(counts, 1)
    # The object's depth where no sweep measured it: carried over the object from where one did.
    typical = float(np.median(ratio[front]))  # where no measured pixel reaches
    ratio_map = membrane_fill(ratio.astype(np.float32), front, obj, typical)
    h, w = first.rows.stop - first.rows.start, first.cols.stop - first.cols.start
    in_hole = np.zeros(hole.shape, bool)
    in_hole[first.rows, first.cols] = (
        cv2.resize(obj.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
    )
    in_hole &= hole
    out = []
    for s, shape in zip(sweeps, shapes, strict=True):
        u, v = s.project(np.where(obj, ratio_map, 1.0))
        source = region_in_reference(u, v, obj, s.K_source, shape, sc)
        out.append(
            DepthLocation(source, in_hole, measured if len(sweeps) > 1 else s.measured, int(in_hole.sum()))
        )
    return out


def region_in_reference(
    u: np.ndarray, v: np.ndarray, obj: np.ndarray, K_s: Intrinsics, shape: tuple[int, ...], sc: ScreenConfig
) -> np.ndarray:
    """HxW bool at the reference's input ``shape``: the sweep grid's ``obj`` pixels, which land at
    ``(u, v)`` in the reference at the sweep's scale (intrinsics ``K_s``), closed, each part's
    convex hull, grown by ``screen.object_margin_px``."""
    K_full = K_s.resized(shape[1], shape[0])
    sx, sy = K_full.fx / K_s.fx, K_full.fy / K_s.fy
    uf = (u[obj] + 0.5) * sx - 0.5
    vf = (v[obj] + 0.5) * sy - 0.5
    inside = (uf >= 0) & (uf < shape[1] - 0.5) & (vf >= 0) & (vf < shape[0] - 0.5)
    mask = np.zeros(shape[:2], np.uint8)
    mask[np.rint(vf[inside]).astype(int), np.rint(uf[inside]).astype(int)] = 1
    # The projected points are a sweep pixel apart (times the reference's magnification): close
    # the gaps between them, take each part's convex hull (what the stereo left out inside the
    # object, a flat or dark part, is the object's too: a ghost costs more than painting a
    # concavity's background), then grow by the object's margin (its silhouette is approximate).
    gap = odd_px(2.0 * max(sx, sy) * _magnification(u, v, obj) + 1)
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (gap, gap)))
    r = odd_px(2.0 * config_px(sc.object_margin_px, shape))
    return cv2.dilate(_hulls(mask), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (r, r))) > 0


#: Side (px, at the sweep's resolution) of the patches compared.
_PATCH_PX = 7


def _box_variance(grey: np.ndarray) -> np.ndarray:
    """Grey variance over each pixel's :data:`_PATCH_PX` box."""
    box = (_PATCH_PX, _PATCH_PX)
    mean = cv2.blur(grey, box)
    return cv2.blur(grey * grey, box) - mean * mean


def ncc_volume(
    grey_t: np.ndarray, grey_s: np.ndarray, maps: list[tuple[np.ndarray, np.ndarray]]
) -> np.ndarray:
    """(planes, h, w) float32: the zero-mean NCC of each pixel's :data:`_PATCH_PX` box of ``grey_t``
    with ``grey_s`` (grey 0-255, float32) warped by each plane's ``(u, v)`` maps; -2 where the warped
    patch leaves the reference or is flat there. Written with OpenCV's box filter: no library
    computes a masked NCC against a per-pixel warp."""
    box = (_PATCH_PX, _PATCH_PX)
    mean_t = cv2.blur(grey_t, box)
    var_t = cv2.blur(grey_t * grey_t, box) - mean_t * mean_t
    out = np.empty((len(maps), *grey_t.shape), np.float32)
    for i, (u, v) in enumerate(maps):
        warped = cv2.remap(grey_s, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
        inside = cv2.blur((warped >= 0).astype(np.float32), box) > 0.999
        mean_w = cv2.blur(warped, box)
        var_w = cv2.blur(warped * warped, box) - mean_w * mean_w
        cov = cv2.blur(warped * grey_t, box) - mean_w * mean_t
        ncc = cov / np.sqrt(np.maximum(var_w * var_t, 1e-6))
        out[i] = np.where(inside & (var_w > 1.0), ncc, -2.0)
    return out


def _best_matches(
    volume: np.ndarray, ratios: np.ndarray, margin: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel, from ``volume`` averaged over :data:`_SUPPORT_PX`: the best NCC on the surface
    (inverse-depth ratio <= ``margin``), the best in front of it, that one's ratio, and its rival:
    the better of the best on the surface and the best in front outside its peak (more than
    :data:`_PEAK_PLANES` planes from it)."""
    support = (_SUPPORT_PX, _SUPPORT_PX)
    volume = np.stack([cv2.blur(plane, support) for plane in volume])
    surface = ratios <= margin
    on_surface = volume[surface].max(axis=0) if surface.any() else np.full(volume.shape[1:], -2.0, np.float32)
    front = volume[~surface]
    best = front.argmax(axis=0)
    in_front = np.take_along_axis(front, best[None], axis=0)[0]
    planes = np.arange(len(front))[:, None, None]
    elsewhere = np.where(np.abs(planes - best[None]) > _PEAK_PLANES, front, -2.0).max(axis=0)
    rival = np.maximum(on_surface, elsewhere)
    return on_surface, in_front, ratios[~surface][best].astype(np.float32), rival


def _magnification(u: np.ndarray, v: np.ndarray, region: np.ndarray) -> float:
    """Median distance (px) in the reference between horizontally neighbouring sweep pixels of
    ``region``: how far apart their projections land."""
    both = region[:, 1:] & region[:, :-1]
    if not both.any():
        return 1.0
    d = np.hypot(np.diff(u, axis=1)[both], np.diff(v, axis=1)[both])
    d = d[np.isfinite(d)]
    return float(np.clip(np.median(d), 0.5, 20.0)) if d.size else 1.0


def _hull(mask: np.ndarray) -> np.ndarray:
    """The convex hull of all of ``mask``'s pixels (bool).

    >>> two = np.zeros((7, 7), bool); two[1:3, 1:6] = True; two[4:6, 1:6] = True
    >>> bool(_hull(two)[3, 3])
    True
    """
    points = cv2.findNonZero(mask.astype(np.uint8))
    out = np.zeros(mask.shape, np.uint8)
    if points is not None:
        cv2.fillConvexPoly(out, cv2.convexHull(points), 1)
    return out > 0


def _hulls(mask: np.ndarray) -> np.ndarray:
    """uint8 ``mask`` with each connected part replaced by its convex hull.

    >>> c = np.zeros((9, 9), np.uint8); c[1:8, 1:3] = 1; c[6:8, 1:8] = 1  # an L
    >>> int(_hulls(c).sum()) > int(c.sum())
    True
    """
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = np.zeros(mask.shape, np.uint8)
    for c in contours:
        cv2.fillConvexPoly(out, cv2.convexHull(c), 1)
    return out
