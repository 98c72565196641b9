"""Where a target pixel is in each reference, for the object-removal protocols: plane-induced
homographies, sparse scene depth from SIFT matches triangulated with the ground-truth pose, and a
map of a target region into each reference (exact, from GT pose and interpolated depth, or from a
homography fitted to matches).

Conventions as in the rest of geofill: pixel (0, 0) centred at (0, 0), K in that convention,
``T_source_to_target`` 4x4 with ``X_t = R X_s + t`` (OpenCV camera axes)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from ..camera import Intrinsics
from ..config import GeometryConfig, MatchingConfig
from ..match import match_pair
from ..triangulate import triangulate
from .pairs import Pair, PairGeometry

#: Matching of the clean images (the protocol's own knowledge of the scene): plain and loose
#: SIFT, no slower rungs.
_MATCHING = MatchingConfig(max_rung="loose")
#: A homography needs this many matches near the hole (else the search widens); MAGSAC++ inlier
#: threshold in px at a 1280-px long side.
_MIN_NEAR_MATCHES = 30
_HOMOGRAPHY_PX = 3.0
_MIN_HOMOGRAPHY_INLIERS = 12


def plane_homography(
    K_target: np.ndarray, K_source: np.ndarray, T_source_to_target: np.ndarray, depth: float
) -> np.ndarray:
    """3x3 map of target pixels to source pixels induced by the plane ``z = depth`` of the target
    camera (fronto-parallel to it): ``K_s (R + t n^T / d) K_t^-1`` with ``[R | t]`` the target ->
    source pose and ``n = (0, 0, 1)``, ``d = depth``.

    >>> K = np.array([[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]])
    >>> T = np.eye(4); T[0, 3] = 1.0  # the source sits 1 unit to the right of the target
    >>> H = plane_homography(K, K, T, 4.0)
    >>> (H @ [50.0, 40.0, 1.0]).round(6).tolist()  # 100 px * 1 / 4 = 25 px to the left
    [25.0, 40.0, 1.0]
    """
    to_source = np.linalg.inv(np.asarray(T_source_to_target, dtype=np.float64))
    R, t = to_source[:3, :3], to_source[:3, 3]
    n = np.array([0.0, 0.0, 1.0])
    H = np.asarray(K_source, np.float64) @ (R + np.outer(t, n) / float(depth)) @ np.linalg.inv(K_target)
    return H / H[2, 2]


def plane_depth_map(
    K_source: np.ndarray, T_source_to_target: np.ndarray, depth: float, shape: tuple[int, int]
) -> np.ndarray:
    """(h, w) z-depth in the source camera of the target-fronto-parallel plane ``z_t = depth``
    along each source pixel's ray; +inf where the ray does not meet it in front of the camera."""
    T = np.asarray(T_source_to_target, dtype=np.float64)
    R, t = T[:3, :3], T[:3, 3]
    # X_t = R X_s + t on the plane: (R^T e_z) . X_s = depth - t_z; X_s = z K^-1 [x, y, 1].
    n_s = R[2, :]
    h, w = shape
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    K_inv = np.linalg.inv(np.asarray(K_source, np.float64))
    rays = np.stack([xs, ys, np.ones_like(xs)], axis=-1) @ K_inv.T
    denom = rays @ n_s
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (float(depth) - t[2]) / denom
    return np.where(np.isfinite(z) & (z > 0), z, np.inf)


def project(
    xy: np.ndarray, z: np.ndarray, K_target: np.ndarray, K_source: np.ndarray, T_source_to_target: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Target pixels ``xy`` (N, 2) at z-depths ``z`` (N,) -> (source pixels (N, 2), source z (N,))."""
    rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ np.linalg.inv(K_target).T
    X_t = rays * np.asarray(z, np.float64)[:, None]
    to_source = np.linalg.inv(np.asarray(T_source_to_target, dtype=np.float64))
    X_s = X_t @ to_source[:3, :3].T + to_source[:3, 3]
    z_s = X_s[:, 2]
    p = X_s @ np.asarray(K_source, np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = p[:, :2] / np.where(np.abs(z_s) > 1e-12, z_s, 1e-12)[:, None]
    return uv, z_s


def _match(target: np.ndarray, source: np.ndarray):
    h, w = target.shape[:2]
    return match_pair(target, source, np.zeros((h, w), bool), _MATCHING, scale_px=max(h, w) / 1280.0)


@dataclass(frozen=True)
class ScenePoints:
    """Sparse scene points seen by the target: pixel, z-depth in the target camera, and how many
    came from each reference."""

    uv: np.ndarray  # (N, 2)
    z: np.ndarray  # (N,)
    per_reference: tuple[int, ...]


def triangulated_points(pair: Pair, geometry: PairGeometry) -> ScenePoints:
    """SIFT matches of the clean target with every reference that has K and a pose, triangulated
    with that ground-truth pose (the paper's midpoint rule; reprojection <= 4 px, parallax >=
    0.05 deg, in front of both cameras), pooled in the target's frame."""
    h, w = pair.target.shape[:2]
    K_t = Intrinsics.from_matrix(geometry.K_target, w, h)
    uv, z, counts = [], [], []
    for source, K, T in zip(pair.sources, geometry.K_sources, geometry.T_source_to_target, strict=True):
        if K is None or T is None:
            counts.append(0)
            continue
        matches = _match(pair.target, source)
        K_s = Intrinsics.from_matrix(K, source.shape[1], source.shape[0])
        pts = triangulate(matches.pts_source, matches.pts_target, K_s, K_t, T, GeometryConfig())
        z_t = pts.xyz_source @ T[2, :3] + T[2, 3]
        uv.append(pts.uv_target)
        z.append(z_t)
        counts.append(len(pts))
    if not uv:
        return ScenePoints(np.zeros((0, 2)), np.zeros(0), tuple(counts))
    return ScenePoints(np.concatenate(uv), np.concatenate(z), tuple(counts))


@dataclass
class ReferenceMap:
    """Where the target's region pixels (``np.nonzero(region)`` order) are in one reference:
    ``xy`` (N, 2) reference pixels, ``valid`` where that is known and inside the reference (and,
    for exact maps, the surface point is seen by it); ``kind`` says how it was found."""

    xy: np.ndarray
    valid: np.ndarray
    kind: str
    info: dict[str, Any] = field(default_factory=dict)


def _inside(xy: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    h, w = shape[:2]
    with np.errstate(invalid="ignore"):
        return np.all(np.isfinite(xy), axis=1) & np.all((xy >= -0.5) & (xy < np.array([w, h]) - 0.5), axis=1)


def _exact_maps(pair: Pair, g: PairGeometry, region: np.ndarray) -> list[ReferenceMap]:
    from ..synthetic import covisible

    ys, xs = np.nonzero(region)
    xy_t = np.stack([xs, ys], axis=1).astype(np.float64)
    z_t = g.depth_target[ys, xs].astype(np.float64)
    maps = []
    for source, K, T in zip(pair.sources, g.K_sources, g.T_source_to_target, strict=True):
        xy, _ = project(xy_t, z_t, g.K_target, K, T)
        pose_s = g.target_to_world @ T
        seen = covisible(
            g.scene, g.K_target, g.target_to_world, g.depth_target, K, pose_s, source.shape[1::-1]
        )
        maps.append(
            ReferenceMap(xy, seen[ys, xs] & _inside(xy, source.shape), "exact (scene depth and pose)")
        )
    return maps


def _interpolated_depth(points: ScenePoints, xy: np.ndarray) -> np.ndarray:
    """z-depth at target pixels ``xy``: inverse depth of the scene points interpolated linearly
    (Delaunay), nearest point outside their hull."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

    inv = 1.0 / points.z
    values = LinearNDInterpolator(points.uv, inv)(xy)
    missing = ~np.isfinite(values)
    if missing.any():
        values[missing] = NearestNDInterpolator(points.uv, inv)(xy[missing])
    return 1.0 / np.maximum(values, 1e-12)


def _posed_maps(pair: Pair, g: PairGeometry, region: np.ndarray, points: ScenePoints) -> list[ReferenceMap]:
    ys, xs = np.nonzero(region)
    xy_t = np.stack([xs, ys], axis=1).astype(np.float64)
    z_t = _interpolated_depth(points, xy_t)
    maps = []
    for source, K, T in zip(pair.sources, g.K_sources, g.T_source_to_target, strict=True):
        xy, z_s = project(xy_t, z_t, g.K_target, K, T)
        info = {"n_points": len(points.z)}
        kind = "GT pose, depth interpolated from triangulated SIFT matches"
        maps.append(ReferenceMap(xy, (z_s > 0) & _inside(xy, source.shape), kind, info))
    return maps


def homography_map(target: np.ndarray, source: np.ndarray, region: np.ndarray) -> ReferenceMap:
    """``region``'s pixels mapped by one homography target -> source fitted (MAGSAC++) to the SIFT
    matches of the clean images whose target point lies within a distance of the region: 5 % of
    the image diagonal, widened (10, 20, 40 %, everything) until 30 matches are in reach. An
    approximation where the scene around the region is not planar."""
    ys, xs = np.nonzero(region)
    xy_t = np.stack([xs, ys], axis=1).astype(np.float64)
    matches = _match(target, source)
    h, w = region.shape
    diag = float(np.hypot(h, w))
    dist = cv2.distanceTransform((~region).astype(np.uint8), cv2.DIST_L2, 5)
    pt = np.clip(np.rint(matches.pts_target).astype(int), 0, [w - 1, h - 1])
    near_d = dist[pt[:, 1], pt[:, 0]] if len(pt) else np.zeros(0)
    for reach in (0.05, 0.1, 0.2, 0.4, np.inf):
        near = near_d <= reach * diag
        if near.sum() >= _MIN_NEAR_MATCHES:
            break
    info: dict[str, Any] = {"n_matches": len(matches), "n_near": int(near.sum()), "reach": float(reach)}
    none = ReferenceMap(np.full_like(xy_t, np.nan), np.zeros(len(xy_t), bool), "none", info)
    if near.sum() < _MIN_HOMOGRAPHY_INLIERS:
        none.kind = f"none: {int(near.sum())} matches near the hole"
        return none
    H, inliers = cv2.findHomography(
        matches.pts_target[near],
        matches.pts_source[near],
        cv2.USAC_MAGSAC,
        _HOMOGRAPHY_PX * max(h, w) / 1280.0,
    )
    info["n_inliers"] = 0 if inliers is None else int(inliers.sum())
    if H is None or info["n_inliers"] < _MIN_HOMOGRAPHY_INLIERS:
        none.kind = f"none: homography kept {info['n_inliers']} inliers"
        return none
    p = np.concatenate([xy_t, np.ones((len(xy_t), 1))], axis=1) @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = p[:, :2] / p[:, 2:]
    return ReferenceMap(
        xy, (p[:, 2] > 0) & _inside(xy, source.shape), "homography (SIFT near the hole, MAGSAC++)", info
    )


def reference_maps(
    pair: Pair, geometry: PairGeometry, region: np.ndarray, points: ScenePoints | None = None
) -> list[ReferenceMap]:
    """Where ``region``'s target pixels are in each reference: exact on synthetic scenes (their
    depth and pose; visibility by ray casting), from the GT pose and depth interpolated from
    ``points`` (default: :func:`triangulated_points`) where every reference is posed, else a
    :func:`homography_map` per reference."""
    if geometry.depth_target is not None and geometry.scene is not None and geometry.posed:
        return _exact_maps(pair, geometry, region)
    if geometry.posed:
        points = points if points is not None else triangulated_points(pair, geometry)
        if len(points.z) >= 8:
            return _posed_maps(pair, geometry, region, points)
    return [homography_map(pair.target, source, region) for source in pair.sources]
