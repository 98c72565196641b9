"""The search space and the reprojection: parameters (pose, depth scale/offset, log focal scale),
source pixels as rays, their projection into the target and its derivative (the backward pass
written out), and the gauge fix of the paper solver."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np
from array_api_compat import array_namespace

from ..camera import Intrinsics, make_pose, quaternion_wxyz

#: Coordinate given to points that must not touch the target (bilinear sampling returns zeros).
_FAR_PX = 1e6

# ---------------------------------------------------------------------------------------------
# Parameters


@dataclass(frozen=True)
class PoseDepthParams:
    """One point of the search space (see the module docstring); numpy float64."""

    R: np.ndarray  # (3, 3)
    t: np.ndarray  # (3,)
    scale: float = 1.0
    offset: float = 0.0
    log_focal: float = 0.0

    @property
    def T(self) -> np.ndarray:
        """4x4 source->target pose."""
        return make_pose(self.R, self.t)

    def quaternion_wxyz(self) -> np.ndarray:
        return quaternion_wxyz(self.R)

    def is_finite(self) -> bool:
        values = [*self.R.ravel(), *self.t, self.scale, self.offset, self.log_focal]
        return bool(np.all(np.isfinite(values)))

    def to_json(self) -> dict[str, Any]:
        return {
            "quaternion_wxyz": self.quaternion_wxyz().tolist(),
            "t": self.t.tolist(),
            "scale": self.scale,
            "offset": self.offset,
            "focal_scale": math.exp(self.log_focal),
        }


def array_params(p: PoseDepthParams) -> tuple[np.ndarray, ...]:
    """(R, t, scale, offset, log_focal) as float32 arrays (0-d for the scalars), the precision the
    objective is evaluated in."""
    return tuple(np.asarray(v, np.float32) for v in (p.R, p.t, p.scale, p.offset, p.log_focal))


# ---------------------------------------------------------------------------------------------
# Reprojection


@dataclass
class Points:
    """Source pixels as rays (z = 1, at the initial focal) with their depth value in the fit space."""

    rays: Any  # (N, 3) float32 (NumPy, or torch for the paper solver)
    value: Any  # (N,) depth or inverse depth; scale * value + offset is what is used

    def __len__(self) -> int:
        return int(self.value.shape[0])

    def take(self, keep: Any) -> Points:
        return Points(self.rays[keep], self.value[keep])

    @classmethod
    def from_pixels(cls, px: np.ndarray, K: Intrinsics, value: np.ndarray) -> Points:
        """Points for pixel positions ``px`` (N, 2) of the camera ``K``."""
        rays = np.stack([(px[:, 0] - K.cx) / K.fx, (px[:, 1] - K.cy) / K.fy, np.ones(len(px))], axis=1)
        return cls(rays.astype(np.float32), value.astype(np.float32))


class Reprojection(NamedTuple):
    x: Any  # (N,) target pixel x (far outside where not ok)
    y: Any
    ok: Any  # (N,) bool: positive depth, in front of the target camera
    rays: Any  # (N, 3) source rays with z = 1 at the current focal
    rotated: Any  # (N, 3) R @ ray
    Y: Any  # (N, 3) R @ ray + rho t (the target-camera point times rho)
    rho: Any  # (N,) inverse depth (1 where not ok)


def reproject_points(
    R, t, scale, offset, log_focal, pts: Points, K_t: Intrinsics, space: str
) -> Reprojection:
    """The reprojection of ``pts`` with everything the derivatives need (see :func:`project`).
    Written once for NumPy arrays (the fast solver) and torch tensors (the paper solver's autograd)."""
    xp = array_namespace(pts.value, R)
    a = scale * pts.value + offset
    ok = a > 0
    one = xp.ones_like(a)
    a_safe = xp.where(ok, a, one)
    rho = a_safe if space == "inverse" else 1.0 / a_safe
    ef = xp.exp(log_focal)
    rays = pts.rays
    if getattr(log_focal, "requires_grad", False) or bool(log_focal != 0):
        rays = rays * xp.stack([1.0 / ef, 1.0 / ef, xp.ones_like(ef)])  # a longer focal shortens x, y
    rotated = rays @ R.T
    Y = rotated + rho[:, None] * t
    ok = ok & (Y[:, 2] > 1e-6)
    z = xp.where(ok, Y[:, 2], one)
    far = xp.full_like(a, _FAR_PX)
    x = xp.where(ok, (K_t.fx * ef) * Y[:, 0] / z + K_t.cx, far)
    y = xp.where(ok, (K_t.fy * ef) * Y[:, 1] / z + K_t.cy, far)
    return Reprojection(x, y, ok, rays, rotated, Y, rho)


def project(
    R: Any,
    t: Any,
    scale: Any,
    offset: Any,
    log_focal: Any,
    pts: Points,
    K_t: Intrinsics,
    space: str,
) -> tuple[Any, Any]:
    """Target pixel (x, y) of the source points ``pts`` whose depth is ``scale * value + offset`` in
    ``space`` ("depth" or "inverse"); both focal lengths multiplied by exp(log_focal).

    Computed in homogeneous form ``Y = R r + rho t`` (r the source ray with z = 1, rho the inverse
    depth), which stays finite for far points. Points with non-positive depth or behind the target
    camera get coordinates far outside the target. Differentiable in every parameter."""
    r = reproject_points(R, t, scale, offset, log_focal, pts, K_t, space)
    return r.x, r.y


class RawGradient(NamedTuple):
    """Gradient of a loss with respect to the parameters of :func:`project` (float64)."""

    R: np.ndarray  # (3, 3)
    t: np.ndarray  # (3,)
    scale: np.ndarray  # 0-d
    offset: np.ndarray
    log_focal: np.ndarray

    def __add__(self, other: RawGradient) -> RawGradient:  # type: ignore[override]
        return RawGradient(*(a + b for a, b in zip(self, other, strict=True)))


def dxy_dY(r: Reprojection, K_t: Intrinsics, ef: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows (N, 3) of dx/dY and dy/dY (zero where the point is not ok)."""
    z = np.where(r.ok, r.Y[:, 2], np.float32(1.0))
    fx = np.where(r.ok, np.float32(K_t.fx * ef) / z, np.float32(0.0))
    fy = np.where(r.ok, np.float32(K_t.fy * ef) / z, np.float32(0.0))
    zero = np.zeros_like(z)
    return np.stack([fx, zero, -fx * r.Y[:, 0] / z], 1), np.stack([zero, fy, -fy * r.Y[:, 1] / z], 1)


def drho_da(r: Reprojection, space: str) -> np.ndarray:
    """d rho / d a with a = scale * value + offset."""
    return np.ones_like(r.rho) if space == "inverse" else -r.rho * r.rho


def reprojection_vjp(
    r: Reprojection,
    pts: Points,
    K_t: Intrinsics,
    space: str,
    R: np.ndarray,
    t: np.ndarray,
    log_focal: float,
    gx: np.ndarray,
    gy: np.ndarray,
) -> RawGradient:
    """``sum_p gx_p dx_p/d theta + gy_p dy_p/d theta`` for theta = (R, t, scale, offset, log focal):
    the backward pass of :func:`project` written out, so that the fast solver gets its exact
    gradient from d loss / d(x, y) without forming the (N, n) Jacobian."""
    ef = math.exp(log_focal)
    ax, ay = dxy_dY(r, K_t, ef)
    Ybar = gx[:, None] * ax + gy[:, None] * ay  # d loss / dY, (N, 3)
    c = (Ybar @ t) * drho_da(r, space)
    d7 = -(r.rays[:, :2] @ R[:, :2].T)  # dY / d log_focal: rays shrink as the focal grows
    zero = np.float32(0.0)
    direct = gx * np.where(r.ok, r.x - K_t.cx, zero) + gy * np.where(r.ok, r.y - K_t.cy, zero)
    sums = (Ybar.T @ r.rays, r.rho @ Ybar, c @ pts.value, c.sum(), (Ybar * d7).sum() + direct.sum())
    return RawGradient(*(np.asarray(v, np.float64) for v in sums))


def renormalise(p: PoseDepthParams, norm: float, space: str) -> PoseDepthParams:
    """The same projections with |t| = ``norm``: t and the depth scaled by norm / |t|."""
    n = float(np.linalg.norm(p.t))
    if n == 0.0 or norm == 0.0:
        return p
    k = norm / n  # depth and t are multiplied by k; inverse depth by 1 / k
    m = k if space == "depth" else 1.0 / k
    return replace(p, t=p.t * k, scale=p.scale * m, offset=p.offset * m)
