"""Objects that lie on the surface: the hole's own content found in the reference where the surface
behind it says it is.

Depth cannot tell a manhole cover from the cobbles around it, nor the foot of a bush from the
ground it stands on: both are at the surface's depth. What tells them apart is that the ring around
the hole does not explain them. Each hole patch is compared with the ring's patches; the ones no
ring patch resembles are the object's *core* (the brushed margin shows the background, which the
ring does explain, so it is no part of it). The reference, warped onto the hole by the ring
surface's own homography (the sweep's plane at ratio 1), then shows the core at its place, or a few
pixels off where the surface's fit is a little wrong (the pose and the ring's depth are estimates):
a masked NCC of the core, with its outline, searched over small shifts, says whether it does. Where
it does, the core, shifted by the best match, is projected into the reference through the surface:
that is the object as the reference shows it, and render pixels sampling it are refused however the
render's own depth placed them. A look-alike elsewhere in the reference, or at another scale, is
not where the surface puts the object and is not taken.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..config import ScreenConfig
from ..utils.resolution import config_px, odd_px
from .depth import DepthLocation, ObjectSweep, region_in_reference

#: Side (px, at the sweep's resolution) of the patches compared with the ring's, and the number of
#: principal components they are reduced to (the nearest-neighbour search is fast in few dimensions).
_PATCH_PX = 5
_COMPONENTS = 12
#: A hole patch is unexplained by the ring when its nearest ring patch is farther than this
#: percentile of the ring patches' distances to their own nearest (spatially apart) ring patch.
_RING_PERCENTILE = 90
#: Ring patches sampled (the ring's self-distances are measured among them).
_MAX_RING_PATCHES = 4000
#: Gaussian blur (px, sweep resolution) of the target's grey before its core is matched.
_BLUR_PX = 1.5
#: Spatial neighbours within this many patch sides share pixels: they are not what explains a patch.
_NEIGHBOURS = 24


def unexplained(shown: np.ndarray, hole: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """HxW bool: the ``hole`` pixels of ``shown`` (HxWx3 uint8) whose CIELAB patch no ``ring`` patch
    resembles as closely as the ring's patches resemble each other (at the
    :data:`_RING_PERCENTILE`-th percentile). Nearest neighbours by SciPy's k-d tree over the patches'
    principal components: no library ranks a region's patches against another region's.

    >>> rng = np.random.default_rng(0)
    >>> img = (rng.random((40, 40, 3)) * 60 + 100).astype(np.uint8); img[15:25, 15:25] = (200, 20, 20)
    >>> hole = np.zeros((40, 40), bool); hole[10:30, 10:30] = True
    >>> core = unexplained(img, hole, ~hole)
    >>> bool(core[17:23, 17:23].all()), float(core[hole].mean()) < 0.5
    (True, True)
    """
    out = np.zeros(hole.shape, bool)
    space = _RingPatches.of(shown, ring)
    hy, hx = np.nonzero(hole)
    if space is None or len(hy) == 0:
        return out
    out[hy, hx] = ~space.explains(space.reduce(space.patches(shown, hy, hx)))
    return out


def like_the_object(render: np.ndarray, shown: np.ndarray, hole: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """HxW int32 watershed markers: 1 on the ``hole`` pixels where ``render`` (HxWx3 uint8, a
    reference's colours rendered into the target) shows what only the object shows: its CIELAB
    patch is unexplained by the ``ring`` of ``shown`` (as in :func:`unexplained`) and as near to a
    patch of the hole's own unexplained content (the object ``shown`` holds) as the ring's patches
    are to each other. The object, or a passer-by dressed like the one brushed out, coming back;
    background the reference sees behind the object is either explained by the ring (the brushed
    margin) or unlike the object. 2 where the ring explains the render's patch, 0 elsewhere.

    >>> rng = np.random.default_rng(0)
    >>> img = (rng.random((40, 40, 3)) * 60 + 100).astype(np.uint8); hole = np.zeros((40, 40), bool)
    >>> hole[10:30, 10:30] = True; shown = img.copy(); shown[14:26, 14:26] = (200, 20, 20)
    >>> render = img.copy(); render[12:20, 20:28] = (205, 25, 15); render[22:28, 12:18] = (20, 20, 200)
    >>> found = like_the_object(render, shown, hole, ~hole) == 1
    >>> bool(found[14:18, 22:26].all()), bool(found[23:27, 13:17].any())  # red comes back, blue is new
    (True, False)
    """
    out = np.zeros(hole.shape, np.int32)
    found = _object_patches(shown, hole, ring)
    if found is None:
        return out
    space, core_tree = found
    hy, hx = np.nonzero(hole)
    rendered = space.reduce(space.patches(render, hy, hx))
    explained = space.explains(rendered)
    # Only what the ring does not explain is compared with the object's patches.
    out[hy, hx] = np.where(explained, 2, 0)
    rest = ~explained
    out[hy[rest], hx[rest]] = _within(core_tree, rendered[rest], space.scale)
    return out


def _within(tree: Any, points: np.ndarray, radius: float) -> np.ndarray:
    """Whether each of ``points`` has a point of the k-d ``tree`` within ``radius``: the query is
    bounded a little beyond it (the search prunes what lies farther) and runs on every core; the
    distances it returns are exact, so the answer is the unbounded query's (the screen stage of
    the Berlin fill: 0.70-0.78 s before, 0.57-0.63 s, the same pixels refused).

    >>> from scipy.spatial import cKDTree
    >>> pts = np.random.default_rng(0).normal(size=(501, 12)); tree = cKDTree(pts[:200])
    >>> d = tree.query(pts)[0]; r = float(np.median(d))  # one point lies exactly at r
    >>> bool((_within(tree, pts, r) == (d <= r)).all()), int((d == r).sum())
    (True, 1)
    >>> bool(_within(tree, pts[:200], 0.0).all())  # each point lies at distance 0 from itself
    True
    """
    # A hair above the radius, relative and absolute: at radius 0 (a ring of one flat colour) a
    # bound of exactly 0 finds nothing, not even the patches the ring holds itself.
    bound = radius * (1 + 1e-6) + 1e-9
    return tree.query(points, distance_upper_bound=bound, workers=-1)[0] <= radius


#: The target's side of :func:`like_the_object` (its ring's patches and a k-d tree over the hole's
#: unexplained ones) for the last few (shown, hole, ring): the same for every reference of a fill,
#: and most of the test's time (0.46 of 0.88 s on a 320x240 window here).
_OBJECT_CACHE: OrderedDict[bytes, tuple[_RingPatches, Any] | None] = OrderedDict()
_OBJECT_CACHE_SIZE = 2
_OBJECT_LOCK = threading.Lock()


def _object_patches(shown: np.ndarray, hole: np.ndarray, ring: np.ndarray) -> tuple[_RingPatches, Any] | None:
    """The ring's patch space of ``shown`` and a k-d tree over the reduced patches of the ``hole``
    that the ring does not explain (the object), or None where there are none; cached."""
    h = hashlib.blake2b(digest_size=16)
    for a in (shown, hole, ring):
        h.update(repr(a.shape).encode() + np.ascontiguousarray(a).tobytes())
    key = h.digest()
    with _OBJECT_LOCK:
        if key in _OBJECT_CACHE:
            _OBJECT_CACHE.move_to_end(key)
            return _OBJECT_CACHE[key]
    found = None
    space = _RingPatches.of(shown, ring)
    hy, hx = np.nonzero(hole)
    if space is not None and len(hy):
        own = space.reduce(space.patches(shown, hy, hx))
        core = ~space.explains(own)
        if core.any():
            from scipy.spatial import cKDTree

            found = (space, cKDTree(own[core]))
    with _OBJECT_LOCK:
        _OBJECT_CACHE[key] = found
        while len(_OBJECT_CACHE) > _OBJECT_CACHE_SIZE:
            _OBJECT_CACHE.popitem(last=False)
    return found


@dataclass(frozen=True)
class _RingPatches:
    """The ring's CIELAB patches in their principal components, with a k-d tree over them and the
    distance (``scale``) within which the ring's patches explain each other."""

    mean: np.ndarray
    basis: np.ndarray
    tree: Any
    scale: float

    @staticmethod
    def patches(image: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
        """(N, 3 * :data:`_PATCH_PX` ** 2) float32: ``image``'s CIELAB patches centred on (ys, xs)."""
        lab = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2LAB).astype(np.float32)
        r = _PATCH_PX // 2
        padded = cv2.copyMakeBorder(lab, r, r, r, r, cv2.BORDER_REFLECT)
        oy, ox = (o.ravel() for o in np.mgrid[0:_PATCH_PX, 0:_PATCH_PX])
        return padded[ys[:, None] + oy, xs[:, None] + ox].reshape(len(ys), -1)

    def reduce(self, patches: np.ndarray) -> np.ndarray:
        return (patches - self.mean) @ self.basis

    def explains(self, reduced: np.ndarray) -> np.ndarray:
        """Whether each patch, reduced by :meth:`reduce`, has a ring patch within :attr:`scale`."""
        return _within(self.tree, reduced, self.scale)

    @classmethod
    def of(cls, image: np.ndarray, ring: np.ndarray) -> _RingPatches | None:
        """``image``'s ``ring`` patches (at most :data:`_MAX_RING_PATCHES`), or None where too few."""
        ry, rx = np.nonzero(ring)
        step = max(1, len(ry) // _MAX_RING_PATCHES)
        ry, rx = ry[::step], rx[::step]
        if len(ry) < 2 * _NEIGHBOURS:
            return None
        ring_p = cls.patches(image, ry, rx)
        # Imported here: scipy.spatial (with scipy.sparse) costs a process 0.2 s to import, and most
        # fills never run this test.
        from scipy.spatial import cKDTree

        mean = ring_p.mean(axis=0)
        centred = ring_p - mean
        basis = np.linalg.eigh(centred.T @ centred)[1][:, ::-1][:, :_COMPONENTS]  # principal axes
        tree = cKDTree(centred @ basis)
        dist, idx = tree.query(centred @ basis, k=_NEIGHBOURS, workers=-1)
        apart = np.hypot(ry[idx] - ry[:, None], rx[idx] - rx[:, None]) > _PATCH_PX
        own = np.where(apart, dist, np.inf).min(axis=1)
        own = own[np.isfinite(own)]
        if own.size == 0:
            return None
        return cls(mean, basis, tree, float(np.percentile(own, _RING_PERCENTILE)))


def locate_on_surface(
    location: DepthLocation, source: np.ndarray, hole: np.ndarray, sc: ScreenConfig
) -> np.ndarray | None:
    """HxW bool at the reference's input size: the hole's unexplained core, where the reference
    ``source`` shows it on the ring's surface (see the module docstring); None where there is no
    such core or the reference does not show it there. ``location``:
    :func:`~geofill.screen.depth.locate_by_depth`'s (its sweep)."""
    sweep = location.sweep
    if sweep is None:
        return None
    f = sweep.hole.shape[1] / (sweep.cols.stop - sweep.cols.start)  # sweep px per input px
    px = config_px(1.0, hole.shape) * f
    core = unexplained(sweep.shown, sweep.hole, ~sweep.hole)
    # Specks are texture the ring happens not to hold, not an object: thin parts are opened away
    # and parts smaller than a square of 1.5 ``screen.stranger_min_px`` dropped.
    m = max(3, odd_px(sc.stranger_min_px / 2 * px))
    core = cv2.morphologyEx(core.astype(np.uint8), cv2.MORPH_OPEN, np.ones((m, m), np.uint8))
    _, labels, stats, _ = cv2.connectedComponentsWithStats(core, connectivity=8)
    big = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= (1.5 * sc.stranger_min_px * px) ** 2)
    core = np.isin(labels, big[big > 0])
    if not core.any():
        return None
    # Parts of the object can look like the ring (a car's dark windows like the trees' shade):
    # the object is what the core's pieces enclose, their convex hull.
    ys, xs = np.nonzero(core)
    hull = cv2.convexHull(np.column_stack([xs, ys]).astype(np.int32))
    core = cv2.fillConvexPoly(np.zeros(core.shape, np.uint8), hull, 1).astype(bool) & sweep.hole
    where = _shown_at(core, sweep, source, sc.surface_search_px * px, sc.surface_min_ncc)
    if where is None:
        return None
    found = region_in_reference(*where, core, sweep.K_source, source.shape, sc)
    return found if found.any() else None


def _shown_at(
    core: np.ndarray, sweep: ObjectSweep, source: np.ndarray, reach_px: float, min_ncc: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Where (u, v maps: reference px at the sweep's scale, per grid pixel) the reference shows
    ``core`` on the ring's surface, or None. The reference is warped onto the grid by the sweep's
    surface (ratio 1), then aligned to the target on the ring by OpenCV's ECC (an affine motion:
    the plane fitted to the rendered depth can be tilted or a little off, as on the Lund cobbles,
    where it turned the manhole by 15 degrees and moved it by 10 px); ``core`` with its outline
    must then match it (masked NCC of grey, at least ``min_ncc``) at some shift within
    ``reach_px``."""
    ss = sweep.source_size
    grey_s = cv2.cvtColor(cv2.resize(source, ss, interpolation=cv2.INTER_AREA), cv2.COLOR_RGB2GRAY)
    u, v = sweep.project(1.0)
    warped = cv2.remap(
        grey_s.astype(np.float32), u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0
    )
    grey_t = cv2.cvtColor(sweep.shown, cv2.COLOR_RGB2GRAY).astype(np.float32)
    h, w = grey_t.shape
    ring = ~sweep.hole & (warped >= 0)
    affine = np.eye(2, 3, dtype=np.float32)
    try:
        _, affine = cv2.findTransformECC(
            grey_t, np.maximum(warped, 0), affine, cv2.MOTION_AFFINE,
            (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-5), ring.astype(np.uint8), 5,
        )  # fmt: skip
    except cv2.error:
        return None  # the ring does not register: nothing says where on the surface the object is
    aligned = cv2.warpAffine(
        warped, affine, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0,
    )  # fmt: skip
    # The outline: what sets the object apart from the surface around it (a flat dark disc has no
    # texture of its own to match).
    mask = cv2.dilate(core.astype(np.uint8), np.ones((5, 5), np.uint8))
    r = max(1, int(np.ceil(reach_px)))
    # The search may leave the grid: padded with "outside" (negative) and blank.
    aligned = cv2.copyMakeBorder(aligned, r, r, r, r, cv2.BORDER_CONSTANT, value=-1.0)
    ys, xs = np.nonzero(mask)
    y0, y1, x0, x1 = int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1
    # Both at the reference's sharpness (resampled, often softer): the target's fine texture would
    # not correlate with a blurred copy of itself.
    template = cv2.GaussianBlur(grey_t, (0, 0), _BLUR_PX)[y0:y1, x0:x1]
    weight = mask[y0:y1, x0:x1].astype(np.float32)
    area = aligned[y0 : y1 + 2 * r, x0 : x1 + 2 * r]
    if (area[r : r + y1 - y0, r : r + x1 - x0][weight > 0] < 0).mean() > 0.5:
        return None  # the reference does not see where the surface puts the object
    scores = cv2.matchTemplate(np.maximum(area, 0), template, cv2.TM_CCOEFF_NORMED, mask=weight)
    scores = np.nan_to_num(scores, nan=-1.0, posinf=-1.0, neginf=-1.0)
    dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
    scores[np.hypot(dx, dy) > reach_px] = -1.0
    iy, ix = np.unravel_index(int(scores.argmax()), scores.shape)
    if scores[iy, ix] < min_ncc:
        return None
    # Grid pixel p shows what the aligned reference shows at p + shift, the warped one at
    # affine(p + shift), the reference at (u, v) there.
    gy, gx = np.mgrid[0:h, 0:w].astype(np.float32)
    gx, gy = gx + float(ix - r), gy + float(iy - r)
    wx = affine[0, 0] * gx + affine[0, 1] * gy + affine[0, 2]
    wy = affine[1, 0] * gx + affine[1, 1] * gy + affine[1, 2]
    at = (cv2.remap(m, wx, wy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE) for m in (u, v))
    return tuple(at)  # type: ignore[return-value]
