"""The planes around a hole, from the depth the pipeline measured: which known pixels lie on the same
plane (a wall, the ground), where each plane runs inside the hole, and where two planes meet there.

A plane is fitted to the known ring's pixels with depth (back-projected through the target's
intrinsics) by sequential RANSAC; each known pixel takes the plane it lies on, the pixels on none
(a bush, a car, or no depth at all) the painter's appearance surfaces
(:func:`geofill.composite.surfaces.segment`), unless that appearance surface lies mostly on one
plane. Inside the hole a pixel takes the surface of its nearest known pixel, and where two planes
meet on the ring around the hole, the hole pixels that went to either are shared between them
along their 3D meeting line projected into the image: for planes ``n1.X = d1`` and ``n2.X = d2``
(camera frame) the rays meeting both at once are those with ``(d1 n2 - d2 n1).K^-1 x = 0``, a
straight image line, and each plane keeps the side its own ring pixels are on. So the wall's foot
continues where the geometry puts it, not where the colours happen to change.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .surfaces import extend, reduced, segment

#: A point lies on a plane when its distance to it is at most this share of its depth (render and
#: stereo depth are relative: their error grows with the distance).
_PLANE_TOL = 0.015
#: A plane must hold this share of the ring's points with depth (and at least _MIN_POINTS).
_MIN_SHARE = 0.12
_MIN_POINTS = 200
_MAX_PLANES = 3
#: Points the planes are fitted on, and plane hypotheses (three points each) tried per plane.
_FIT_POINTS = 4000
_TRIALS = 300
#: Ring pixels this close (px) to two planes' meeting line show where they meet.
_MEET_PX = 3.0
#: A ray grazing a plane (cosine to its normal below this) is never put on it: the plane would be
#: stretched without bound there.
_MIN_COS = 0.05


@dataclass(frozen=True)
class SceneDepth:
    """Depth of the target view the painter may use: ``depth`` (HxW float32, target-camera z in
    pose units; NaN or inf where unknown) and ``K`` (3x3 float64 target intrinsics in pixels of this
    image)."""

    depth: np.ndarray
    K: np.ndarray

    def window(self, rows: slice, cols: slice) -> SceneDepth:
        """The same depth cropped to ``rows`` x ``cols`` (the principal point moved with it)."""
        K = self.K.copy()
        K[0, 2] -= cols.start or 0
        K[1, 2] -= rows.start or 0
        return SceneDepth(self.depth[rows, cols], K)


@dataclass(frozen=True)
class Plane:
    """A plane ``normal . X = offset`` in the camera frame (``normal`` a unit vector pointing away
    from the camera, ``offset`` > 0, pose units)."""

    normal: np.ndarray
    offset: float


@dataclass(frozen=True)
class PlaneSurfaces:
    """Surface labels (HxW int32) of every pixel, known or in the hole: labels below
    ``len(planes)`` are those planes, the others appearance surfaces of pixels on no plane."""

    labels: np.ndarray
    planes: tuple[Plane, ...]


def rays(K: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """HxWx3 float64: each pixel centre's ray ``K^-1 (x, y, 1)`` (z = 1)."""
    ys, xs = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    return np.dstack([xs, ys, np.ones_like(xs)]) @ np.linalg.inv(K).T


def plane_surfaces(
    image: np.ndarray, hole: np.ndarray, scene: SceneDepth, patch_px: int
) -> PlaneSurfaces | None:
    """The surfaces of ``image`` (HxWx3 RGB, uint8 or float32 in [0, 1]) around ``hole`` (HxW bool)
    from ``scene``'s depth, or None when no plane is found on the ring (then the appearance surfaces
    stand alone). ``patch_px``: the painter's patch width. Above
    :data:`geofill.composite.surfaces.LONG_SIDE` px the surfaces are found on the image reduced to
    that and scaled back (per-pixel rays and distances to every plane cost a gigabyte at 4K)."""
    f, small_image, small_hole = reduced(image, hole)
    if f == 1:
        return _plane_surfaces(small_image, hole, scene, patch_px)
    h, w = hole.shape
    K = np.diag([1.0 / f, 1.0 / f, 1.0]) @ scene.K
    K[:2, 2] += 0.5 / f - 0.5  # pixel centres: x_small = (x + 0.5) / f - 0.5
    small = _plane_surfaces(
        small_image,
        small_hole,
        SceneDepth(cv2.resize(scene.depth, small_hole.shape[::-1], interpolation=cv2.INTER_NEAREST), K),
        max(3, patch_px // f),
    )
    if small is None:
        return None
    labels = cv2.resize(small.labels, (w, h), interpolation=cv2.INTER_NEAREST)
    return PlaneSurfaces(labels, small.planes)


def _plane_surfaces(
    image: np.ndarray, hole: np.ndarray, scene: SceneDepth, patch_px: int
) -> PlaneSurfaces | None:
    known = ~hole
    ring = known & (_distance_from(hole) <= _ring_px(hole, patch_px))
    depth = np.where(np.isfinite(scene.depth), scene.depth, np.nan).astype(np.float64)
    ray = rays(scene.K, hole.shape)
    points = ray * depth[..., None]
    usable = ring & (depth > 0)
    planes = _fit(points[usable])
    if not planes:
        return None
    n = len(planes)
    # Relative distance of every pixel with depth to every plane.
    resid = np.stack([np.abs(points @ p.normal - p.offset) / depth for p in planes], axis=-1)
    best = np.argmin(np.nan_to_num(resid, nan=np.inf), axis=-1)
    on_plane = (
        known & (depth > 0) & (np.take_along_axis(resid, best[..., None], -1)[..., 0] <= 2 * _PLANE_TOL)
    )
    # Pixels on no plane (without depth beyond the references' renders, or off every plane: an
    # apple on the table, a bush) keep their appearance surface, unless most of that surface's
    # pixels with depth lie on one plane: then they are that plane's, as the painter without depth
    # would have put them on one surface with it. Label noise is smoothed as segment() does.
    look = segment(image, hole, patch_px)
    labels = np.where(on_plane, best, n + look).astype(np.int32)
    measured = known & (depth > 0)
    off = known & ~on_plane
    for a in np.unique(look[off]):
        votes = np.bincount(best[on_plane & (look == a)], minlength=n)
        if votes.max(initial=0) >= 0.5 * np.count_nonzero(measured & (look == a)) > 0:
            labels[off & (look == a)] = int(np.argmax(votes))
    # (Not where the 5x5 median reads the hole: its pixels' labels are no one's yet.)
    smooth = cv2.medianBlur(labels.astype(np.uint8), 5).astype(np.int32)
    labels = np.where(cv2.dilate(hole.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0, labels, smooth)
    labels[hole] = 0
    extend(labels, hole)
    _split_by_meeting_lines(labels, hole, ring, planes, scene.K, ray, patch_px)
    return PlaneSurfaces(labels, tuple(planes))


def _distance_from(mask: np.ndarray) -> np.ndarray:
    return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 3)


def _ring_px(hole: np.ndarray, patch_px: int) -> float:
    """How far around the hole the planes are fitted: as far as the hole is deep, at least a few
    patches (a plane seen on a thin ring tilts freely)."""
    return max(4.0 * patch_px, float(_distance_from(~hole).max()))


def _fit(points: np.ndarray) -> list[Plane]:
    """Sequential RANSAC: up to _MAX_PLANES planes, each holding at least _MIN_SHARE of ``points``
    (N x 3, camera frame) within _PLANE_TOL of their depth. Hand-written: neither OpenCV nor
    scikit-image fits planes with a depth-relative tolerance, and this is a few vectorised lines.
    Fixed seed: the same planes every run."""
    rng = np.random.default_rng(0)
    if points.shape[0] > _FIT_POINTS:
        points = points[rng.choice(points.shape[0], _FIT_POINTS, replace=False)]
    need = max(_MIN_POINTS, _MIN_SHARE * points.shape[0])
    planes: list[Plane] = []
    left = points
    while len(planes) < _MAX_PLANES and left.shape[0] >= need:
        tri = left[rng.integers(0, left.shape[0], (_TRIALS, 3))]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(normal, axis=1)
        ok = length > 1e-12
        normal, tri = normal[ok] / length[ok, None], tri[ok]
        offset = (normal * tri[:, 0]).sum(1)
        inliers = np.abs(left @ normal.T - offset) <= _PLANE_TOL * left[:, 2:3]
        counts = inliers.sum(0)
        if not counts.size or counts.max() < need:
            break
        plane = _refine(left[inliers[:, int(np.argmax(counts))]])
        # Refitted on the points nearest to it: the other plane's points next to where the two
        # meet are within the tolerance too, and tilt a single fit towards it.
        plane = _refine(left[np.abs(left @ plane.normal - plane.offset) <= 0.5 * _PLANE_TOL * left[:, 2]])
        on = np.abs(left @ plane.normal - plane.offset) <= _PLANE_TOL * left[:, 2]
        if on.sum() < need:
            break
        planes.append(plane)
        left = left[~on]
    return planes


def _refine(points: np.ndarray) -> Plane:
    """Least-squares plane through ``points`` (their centroid, the least principal direction)."""
    centre = points.mean(0)
    normal = np.linalg.svd(points - centre, full_matrices=False)[2][2]
    offset = float(normal @ centre)
    if offset < 0:
        normal, offset = -normal, -offset
    return Plane(normal, offset)


def meeting_line(a: Plane, b: Plane, K: np.ndarray) -> np.ndarray:
    """The image line (a, b, c: ``a x + b y + c = 0``) where planes ``a`` and ``b`` meet: the rays
    that reach both at the same depth."""
    return np.linalg.inv(K).T @ (a.offset * b.normal - b.offset * a.normal)


def _split_by_meeting_lines(
    labels: np.ndarray,
    hole: np.ndarray,
    ring: np.ndarray,
    planes: list[Plane],
    K: np.ndarray,
    ray: np.ndarray,
    patch_px: int,
) -> None:
    """In place: where two planes meet on the ``ring`` (each has at least a patch width of ring
    pixels within _MEET_PX of their meeting line), the hole pixels that went to either are shared
    between them by that line, each keeping the side where its ring pixels next to the line are
    (and only rays that meet it in front of the camera). Planes that meet only behind something
    else (a wall and the ground behind a parked car) do not take each other's hole pixels: the
    nearest known pixel decides there, as without depth."""
    h, w = labels.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    for i in range(len(planes)):
        for j in range(i + 1, len(planes)):
            line = meeting_line(planes[i], planes[j], K)
            # Signed distance (px) to the line; > 0 where the ray meets plane j nearer than i.
            side = (line[0] * xs + line[1] * ys + line[2]) / np.hypot(line[0], line[1])
            near = ring & (np.abs(side) <= _MEET_PX)
            a, b = near & (labels == i), near & (labels == j)
            if min(np.count_nonzero(a), np.count_nonzero(b)) < patch_px:
                continue
            side_i = np.sign(np.median(side[a]))
            pair = hole & ((labels == i) | (labels == j))
            r = ray[pair]
            length = np.linalg.norm(r, axis=1)
            faces_i = r @ planes[i].normal > _MIN_COS * length
            faces_j = r @ planes[j].normal > _MIN_COS * length
            on_i = (np.sign(side[pair]) == side_i) & faces_i
            labels[pair] = np.where(on_i | ~faces_j, i, j)
