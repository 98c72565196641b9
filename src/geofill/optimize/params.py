"""The search space and the reprojection: parameters (pose, depth scale/offset, log focal scale),
source pixels as rays, their projection into the target and its derivative (the backward pass
written out), and the gauge fix of the paper solver."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ..camera import Intrinsics, make_pose

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
        x, y, z, w = Rotation.from_matrix(self.R).as_quat()
        return np.array([w, x, y, z])

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


def torch_params(p: PoseDepthParams) -> tuple[torch.Tensor, ...]:
    """(R, t, scale, offset, log_focal) as float32 tensors without gradient."""
    f = lambda v: torch.as_tensor(np.asarray(v, np.float64), dtype=torch.float32)  # noqa: E731
    return f(p.R), f(p.t), f(p.scale), f(p.offset), f(p.log_focal)


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrix of the quaternion (w, x, y, z), normalised first (differentiable; torch has
    no quaternion type and PyTorch3D's conversion comes with no CPU wheel)."""
    w, x, y, z = q / torch.linalg.vector_norm(q)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
        ]
    )


# ---------------------------------------------------------------------------------------------
# Reprojection


@dataclass
class Points:
    """Source pixels as rays (z = 1, at the initial focal) with their depth value in the fit space."""

    rays: torch.Tensor  # (N, 3) float32
    value: torch.Tensor  # (N,) depth or inverse depth; scale * value + offset is what is used

    def __len__(self) -> int:
        return int(self.value.shape[0])

    def take(self, keep: torch.Tensor) -> Points:
        return Points(self.rays[keep], self.value[keep])

    @classmethod
    def from_pixels(cls, px: np.ndarray, K: Intrinsics, value: np.ndarray) -> Points:
        """Points for pixel positions ``px`` (N, 2) of the camera ``K``."""
        rays = np.stack([(px[:, 0] - K.cx) / K.fx, (px[:, 1] - K.cy) / K.fy, np.ones(len(px))], axis=1)
        return cls(torch.from_numpy(rays.astype(np.float32)), torch.from_numpy(value.astype(np.float32)))


class Reprojection(NamedTuple):
    x: torch.Tensor  # (N,) target pixel x (far outside where not ok)
    y: torch.Tensor
    ok: torch.Tensor  # (N,) bool: positive depth, in front of the target camera
    rays: torch.Tensor  # (N, 3) source rays with z = 1 at the current focal
    rotated: torch.Tensor  # (N, 3) R @ ray
    Y: torch.Tensor  # (N, 3) R @ ray + rho t (the target-camera point times rho)
    rho: torch.Tensor  # (N,) inverse depth (1 where not ok)


def reproject_points(
    R, t, scale, offset, log_focal, pts: Points, K_t: Intrinsics, space: str
) -> Reprojection:
    """The reprojection of ``pts`` with everything the derivatives need (see :func:`project`)."""
    a = scale * pts.value + offset
    ok = a > 0
    a_safe = torch.where(ok, a, 1.0)
    rho = a_safe if space == "inverse" else 1.0 / a_safe
    ef = torch.exp(log_focal)
    rays = pts.rays
    if log_focal.requires_grad or bool(log_focal != 0):  # a longer focal shortens the rays' x, y
        rays = rays * torch.stack([1.0 / ef, 1.0 / ef, torch.ones_like(ef)])
    rotated = rays @ R.T
    Y = rotated + rho[:, None] * t
    ok = ok & (Y[:, 2] > 1e-6)
    z = torch.where(ok, Y[:, 2], 1.0)
    x = torch.where(ok, (K_t.fx * ef) * Y[:, 0] / z + K_t.cx, _FAR_PX)
    y = torch.where(ok, (K_t.fy * ef) * Y[:, 1] / z + K_t.cy, _FAR_PX)
    return Reprojection(x, y, ok, rays, rotated, Y, rho)


def project(
    R: torch.Tensor,
    t: torch.Tensor,
    scale: torch.Tensor,
    offset: torch.Tensor,
    log_focal: torch.Tensor,
    pts: Points,
    K_t: Intrinsics,
    space: str,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Target pixel (x, y) of the source points ``pts`` whose depth is ``scale * value + offset`` in
    ``space`` ("depth" or "inverse"); both focal lengths multiplied by exp(log_focal).

    Computed in homogeneous form ``Y = R r + rho t`` (r the source ray with z = 1, rho the inverse
    depth), which stays finite for far points. Points with non-positive depth or behind the target
    camera get coordinates far outside the target. Differentiable in every parameter."""
    r = reproject_points(R, t, scale, offset, log_focal, pts, K_t, space)
    return r.x, r.y


class RawGradient(NamedTuple):
    """Gradient of a loss with respect to the parameters of :func:`project` (float64)."""

    R: torch.Tensor  # (3, 3)
    t: torch.Tensor  # (3,)
    scale: torch.Tensor  # 0-d
    offset: torch.Tensor
    log_focal: torch.Tensor

    def __add__(self, other: RawGradient) -> RawGradient:  # type: ignore[override]
        return RawGradient(*(a + b for a, b in zip(self, other, strict=True)))


def dxy_dY(r: Reprojection, K_t: Intrinsics, ef: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Rows (N, 3) of dx/dY and dy/dY (zero where the point is not ok)."""
    z = torch.where(r.ok, r.Y[:, 2], 1.0)
    fx = torch.where(r.ok, K_t.fx * ef / z, 0.0)
    fy = torch.where(r.ok, K_t.fy * ef / z, 0.0)
    zero = torch.zeros_like(z)
    return torch.stack([fx, zero, -fx * r.Y[:, 0] / z], 1), torch.stack([zero, fy, -fy * r.Y[:, 1] / z], 1)


def drho_da(r: Reprojection, space: str) -> torch.Tensor:
    """d rho / d a with a = scale * value + offset."""
    return torch.ones_like(r.rho) if space == "inverse" else -r.rho * r.rho


def reprojection_vjp(
    r: Reprojection,
    pts: Points,
    K_t: Intrinsics,
    space: str,
    R: torch.Tensor,
    t: torch.Tensor,
    log_focal: float,
    gx: torch.Tensor,
    gy: torch.Tensor,
) -> RawGradient:
    """``sum_p gx_p dx_p/d theta + gy_p dy_p/d theta`` for theta = (R, t, scale, offset, log focal):
    the backward pass of :func:`project` written out, so that the fast solver gets its exact
    gradient from autograd's d loss / d(x, y) without forming the (N, n) Jacobian."""
    ef = math.exp(log_focal)
    ax, ay = dxy_dY(r, K_t, ef)
    Ybar = gx[:, None] * ax + gy[:, None] * ay  # d loss / dY, (N, 3)
    c = (Ybar @ t) * drho_da(r, space)
    d7 = -(r.rays[:, :2] @ R[:, :2].T)  # dY / d log_focal: rays shrink as the focal grows
    direct = gx * torch.where(r.ok, r.x - K_t.cx, 0.0) + gy * torch.where(r.ok, r.y - K_t.cy, 0.0)
    sums = (Ybar.T @ r.rays, r.rho @ Ybar, c @ pts.value, c.sum(), (Ybar * d7).sum() + direct.sum())
    return RawGradient(*(v.double() for v in sums))


def renormalise(p: PoseDepthParams, norm: float, space: str) -> PoseDepthParams:
    """The same projections with |t| = ``norm``: t and the depth scaled by norm / |t|."""
    n = float(np.linalg.norm(p.t))
    if n == 0.0 or norm == 0.0:
        return p
    k = norm / n  # depth and t are multiplied by k; inverse depth by 1 / k
    m = k if space == "depth" else 1.0 / k
    return replace(p, t=p.t * k, scale=p.scale * m, offset=p.offset * m)
