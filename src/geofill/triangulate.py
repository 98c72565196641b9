"""Triangulation of verified matches with the paper's Eq. 1 (midpoint of the two rays).

OpenCV's ``triangulatePoints`` minimises an algebraic (DLT) error, not Eq. 1; the midpoint has a
closed form that vectorises over all points, so it is written here (a few lines of numpy)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .camera import Intrinsics
from .config import GeometryConfig
from .pose import bearing


@dataclass(frozen=True)
class TriangulatedPoints:
    """3D points in SOURCE camera coordinates (units of the pose translation) and their pixels."""

    xyz_source: np.ndarray  # (N, 3)
    uv_source: np.ndarray  # (N, 2) px
    uv_target: np.ndarray  # (N, 2) px
    reprojection_px: np.ndarray  # (N,) max of the two images' reprojection errors
    parallax_deg: np.ndarray  # (N,) angle between the two rays at the point

    def __len__(self) -> int:
        return int(self.xyz_source.shape[0])

    @property
    def depth(self) -> np.ndarray:
        """z in the source camera."""
        return self.xyz_source[:, 2]

    def summary(self) -> str:
        return f"{len(self)} points kept"

    def report(self) -> dict[str, Any]:
        return {"n_points": len(self)}


def project(xyz: np.ndarray, K: Intrinsics) -> np.ndarray:
    """(N, 3) camera-frame points -> (N, 2) pixels."""
    z = xyz[:, 2:3]
    return np.concatenate([K.fx * xyz[:, :1] / z + K.cx, K.fy * xyz[:, 1:2] / z + K.cy], axis=1)


def midpoint_triangulate(
    uv_s: np.ndarray, uv_t: np.ndarray, K_s: Intrinsics, K_t: Intrinsics, T: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 1: the point minimising the summed squared distances to both rays.

    Returns (xyz in the source frame, ray parameter along the source ray, along the target ray);
    a negative parameter means the point is behind that camera."""
    R, t = T[:3, :3], T[:3, 3]
    d_s = bearing(uv_s, K_s)  # source ray: origin 0
    d_t = bearing(uv_t, K_t) @ R  # target ray in the source frame: R^T d
    c_t = -R.T @ t  # target centre in the source frame
    # Solve [d_s, -d_t] [a, b]^T ~= c_t in least squares per point (2x2 normal equations).
    b_ = np.sum(d_s * d_t, axis=1)
    e = d_s @ c_t
    f = d_t @ c_t
    denom = 1.0 - b_**2
    denom = np.where(np.abs(denom) < 1e-12, 1e-12, denom)
    a = (e - b_ * f) / denom
    b = (b_ * e - f) / denom
    xyz = 0.5 * (a[:, None] * d_s + (c_t + b[:, None] * d_t))
    return xyz, a, b


def triangulate(
    uv_s: np.ndarray,
    uv_t: np.ndarray,
    K_s: Intrinsics,
    K_t: Intrinsics,
    T: np.ndarray,
    cfg: GeometryConfig,
) -> TriangulatedPoints:
    """Triangulate and keep points in front of both cameras (cheirality) with small reprojection
    error and enough parallax to carry depth information."""
    xyz, a, b = midpoint_triangulate(uv_s, uv_t, K_s, K_t, T)
    xyz_t = xyz @ T[:3, :3].T + T[:3, 3]
    front = (a > 0) & (b > 0) & (xyz[:, 2] > 0) & (xyz_t[:, 2] > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        err_s = np.linalg.norm(project(xyz, K_s) - uv_s, axis=1)
        err_t = np.linalg.norm(project(xyz_t, K_t) - uv_t, axis=1)
    err = np.maximum(err_s, err_t)
    ray_s = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    c_t = -T[:3, :3].T @ T[:3, 3]
    ray_t = xyz - c_t
    ray_t /= np.linalg.norm(ray_t, axis=1, keepdims=True)
    par = np.degrees(np.arccos(np.clip(np.sum(ray_s * ray_t, axis=1), -1.0, 1.0)))
    keep = front & (err < cfg.max_reprojection_px) & (par > cfg.min_point_parallax_deg)
    keep &= np.isfinite(err)
    return TriangulatedPoints(xyz[keep], uv_s[keep], uv_t[keep], err[keep], par[keep])
