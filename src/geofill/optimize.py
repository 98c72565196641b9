"""Joint optimisation of the relative pose and the depth scale/offset (paper Sec. 3.2, supplement).

Parameters
    Rotation R, translation t (source -> target, ``X_t = R X_s + t``), depth scale s and offset b
    applied in the space of the initial depth fit (``AlignedDepth.space``): the depth used is
    ``s v + b`` where v is the initial aligned depth (``space == "depth"``) or inverse depth
    (``"inverse"``, the default), so s = 1, b = 0 is the initial guess. Optionally (issue 7) a log
    focal scale phi multiplies both images' focal lengths by exp(phi), with a weak prior.

Objective (one function, :func:`objective`, used by both solvers)
    ``l = lambda_photo L_photo + lambda_feat L_feat + lambda_negD L_negD (+ focal prior)``.

    - Reprojection (:func:`project`): every source pixel p with its depth is lifted to 3D, moved into
      the target camera and projected to q_p. The target is sampled bilinearly at q_p, as an
      alpha-premultiplied RGBA image (alpha = 0 in the hole and outside the image), so
      ``d_p = alpha(q_p) I_s(p) - (alpha I_t)(q_p)`` carries no colour from the hole.
    - ``L_photo = 1/|M| sum_p W(q_p) |d_p|^2`` at one level of the Gaussian pyramids of both images,
      |M| the known (non-hole) area of that level (paper Eq. 3). W is the target's importance map
      (:mod:`geofill.importance`) sampled at q_p: W is defined in the target frame, and sampling it
      where each source pixel lands is the weighting Eq. 3 applies to the warped image.
    - ``L_feat = 1/N sum_m W(q_t^m) f(|reproj(q_s^m) - q_t^m|, alpha, c)``, Barron's general loss
      (alpha = -2, c = 10 px: Geman-McClure), over the pose inliers (Eq. 5).
    - ``L_negD = sum_p max(0, -(s v_p + b))`` over the source pixels of the level (Eq. 6).
    Points with non-positive depth or behind the target camera are moved outside the target, so
    they add no photometric error (and the saturated error to L_feat); L_negD pushes them back.

Coarse to fine
    The paper computes L_photo on the coarsest level first and moves to the next finer level when
    the level has converged (it notes that the multi-scale sum in every iteration would be too
    expensive), so level k's objective uses L_photo of level k only and "the objective" of a
    solution is that of the finest level. Level k has its images, depth and intrinsics downsampled
    by ``cv2.pyrDown`` k times (pixel x of level k+1 is pixel 2x of level k, so f and c halve).

Gauge
    Scaling t and the depth by the same factor changes no projection, so with t as 3 free numbers
    one direction of the problem is flat. The ``paper`` solver optimises the 9 numbers as published
    (quaternion 4, t 3, s, b) and renormalises |t| to its initial length afterwards, adjusting s and
    b so that every projection is unchanged. The ``fast`` solver keeps |t| fixed by moving t on its
    sphere (2 degrees of freedom), which removes the flat direction from its normal equations.

Solvers
    ``paper``: DiffGrad (pytorch_optimizer) with a constant learning rate, cumulative iteration limits
    per level, the supplement's convergence test (:func:`converged`) and the best parameters of each
    level carried to the next. ``fast``: Levenberg-Marquardt on the same objective (exact gradient
    by autograd, Gauss-Newton / IRLS curvature), on the source pixels whose reprojection lands where
    W is significant, coarse to fine over the same pyramid. Both are followed by the guard rails of
    :func:`guard`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any, NamedTuple

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from scipy.spatial.transform import Rotation

from .camera import Intrinsics, make_pose, rotation_error_deg, translation_direction_error_deg
from .config import OptimizeConfig
from .depth.align import AlignedDepth, sample_at, to_depth
from .importance import importance_map

#: Coordinate given to points that must not touch the target (bilinear sampling returns zeros).
_FAR_PX = 1e6
#: Levenberg-Marquardt damping: start, bounds and the factors applied on rejection / acceptance.
_LM_MU0, _LM_MU_MIN, _LM_MU_MAX = 1e-4, 1e-9, 1e6
_LM_UP, _LM_DOWN = 8.0, 4.0
#: The fast solver's trust region (``fast_step_px`` at the start of each level) grows and shrinks by
#: factors of 2 within this factor of its start.
_RADIUS_GROWTH = 16.0
#: Largest factor by which an accepted fast-solver step is extended along its direction.
_MAX_EXTENSION = 64.0
#: Photometric points (an even subsample) that the fast solver's curvature and step length use.
_CURVATURE_SAMPLES = 1 << 16


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


def _torch_params(p: PoseDepthParams) -> tuple[torch.Tensor, ...]:
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
# Reprojection and losses


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


class _Reprojection(NamedTuple):
    x: torch.Tensor  # (N,) target pixel x (far outside where not ok)
    y: torch.Tensor
    ok: torch.Tensor  # (N,) bool: positive depth, in front of the target camera
    rays: torch.Tensor  # (N, 3) source rays with z = 1 at the current focal
    rotated: torch.Tensor  # (N, 3) R @ ray
    Y: torch.Tensor  # (N, 3) R @ ray + rho t (the target-camera point times rho)
    rho: torch.Tensor  # (N,) inverse depth (1 where not ok)


def _reproject(R, t, scale, offset, log_focal, pts: Points, K_t: Intrinsics, space: str) -> _Reprojection:
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
    return _Reprojection(x, y, ok, rays, rotated, Y, rho)


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
    r = _reproject(R, t, scale, offset, log_focal, pts, K_t, space)
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


def _dxy_dY(r: _Reprojection, K_t: Intrinsics, ef: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Rows (N, 3) of dx/dY and dy/dY (zero where the point is not ok)."""
    z = torch.where(r.ok, r.Y[:, 2], 1.0)
    fx = torch.where(r.ok, K_t.fx * ef / z, 0.0)
    fy = torch.where(r.ok, K_t.fy * ef / z, 0.0)
    zero = torch.zeros_like(z)
    return torch.stack([fx, zero, -fx * r.Y[:, 0] / z], 1), torch.stack([zero, fy, -fy * r.Y[:, 1] / z], 1)


def _drho_da(r: _Reprojection, space: str) -> torch.Tensor:
    """d rho / d a with a = scale * value + offset."""
    return torch.ones_like(r.rho) if space == "inverse" else -r.rho * r.rho


def reprojection_vjp(
    r: _Reprojection,
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
    ax, ay = _dxy_dY(r, K_t, ef)
    Ybar = gx[:, None] * ax + gy[:, None] * ay  # d loss / dY, (N, 3)
    c = (Ybar @ t) * _drho_da(r, space)
    d7 = -(r.rays[:, :2] @ R[:, :2].T)  # dY / d log_focal: rays shrink as the focal grows
    direct = gx * torch.where(r.ok, r.x - K_t.cx, 0.0) + gy * torch.where(r.ok, r.y - K_t.cy, 0.0)
    sums = (Ybar.T @ r.rays, r.rho @ Ybar, c @ pts.value, c.sum(), (Ybar * d7).sum() + direct.sum())
    return RawGradient(*(v.double() for v in sums))


def barron_loss(sq: torch.Tensor, alpha: float, c: float) -> torch.Tensor:
    """Barron's general robust loss f(x, alpha, c) (CVPR 2019, paper Eq. 4) of ``sq = x^2``, with its
    limits at alpha = 2 (L2) and alpha = 0 (Cauchy); alpha = -2 is Geman-McClure
    ``2 (x/c)^2 / ((x/c)^2 + 4)``."""
    u = sq / (c * c)
    if alpha == 2.0:
        return 0.5 * u
    if alpha == 0.0:
        return torch.log1p(0.5 * u)
    b = abs(alpha - 2.0)
    return (b / alpha) * (torch.pow(u / b + 1.0, alpha / 2.0) - 1.0)


def barron_weight(sq: torch.Tensor, alpha: float, c: float) -> torch.Tensor:
    """d f / d(x^2): the IRLS weight of :func:`barron_loss`."""
    if alpha == 2.0:
        return torch.full_like(sq, 0.5 / (c * c))
    b = abs(alpha - 2.0)
    return 0.5 / (c * c) * torch.pow(sq / (c * c * b) + 1.0, alpha / 2.0 - 1.0)


def sample_target(texture: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Bilinear samples (C, N) of ``texture`` (1, C, H, W) at pixel positions (x, y); zero outside."""
    h, w = texture.shape[-2:]
    grid = torch.stack([x * (2.0 / (w - 1)) - 1.0, y * (2.0 / (h - 1)) - 1.0], dim=-1)
    out = F.grid_sample(
        texture, grid.view(1, 1, -1, 2), mode="bilinear", padding_mode="zeros", align_corners=True
    )
    return out[0, :, 0]


def converged(history: Sequence[float], window: int, eps: float) -> bool:
    """The supplement's convergence test on the objective values ``history`` of one level.

    Its formula is printed with garbled summation bounds; the intended test, implemented here, is the
    relative change between the sum of the last m/2 values and the sum of the m/2 before them:
    ``|sum(l[-m/2:]) - sum(l[-m:-m/2])| / sum(l[-m/2:]) < eps`` (False until m values exist)."""
    if len(history) < window:
        return False
    half = window // 2
    recent = math.fsum(history[-half:])
    previous = math.fsum(history[-window:-half])
    if recent == 0.0:
        return previous == 0.0
    return abs(recent - previous) / abs(recent) < eps


# ---------------------------------------------------------------------------------------------
# Problem data


@dataclass
class PhotoLevel:
    """One pyramid level: the target texture and the source pixels that are reprojected into it."""

    texture: torch.Tensor  # (1, 5, H, W): alpha-premultiplied target RGB, alpha, W
    gradients: torch.Tensor  # (1, 8, H, W): d/dx of channels 0-3, then d/dy (central differences)
    support: torch.Tensor  # (1, 1, H, W): W max-filtered by the fast solver's margin
    known_area: float  # |M|: sum of alpha at this level
    K_t: Intrinsics
    points: Points  # the photometric points: source pixels with a depth
    colour: torch.Tensor  # (N, 3) their RGB in [0, 1]
    all_values: torch.Tensor  # depth values of every source pixel of the level (L_negD)
    value_range: tuple[float, float]  # their min and max

    def subset(self, keep: torch.Tensor) -> PhotoLevel:
        """The same level with only the photometric points ``keep`` (L_negD still sees all pixels)."""
        return replace(self, points=self.points.take(keep), colour=self.colour[keep])


@dataclass
class FeatureSet:
    """Matched keypoints at the finest level: source points, target pixels, W at the target pixels."""

    points: Points
    q_t: torch.Tensor  # (M, 2)
    weight: torch.Tensor  # (M,)


@dataclass
class Problem:
    """Everything the objective needs; ``levels[0]`` is the finest."""

    levels: list[PhotoLevel]
    features: FeatureSet
    space: str
    cfg: OptimizeConfig
    barron_c: float  # px at the finest level
    prior_ref: float = 0.0  # l0 of the focal prior (set from the initial objective)


def _pyr_down(image: np.ndarray) -> np.ndarray:
    """``cv2.pyrDown`` of an (H, W, C) float32 image, C taken in groups OpenCV accepts."""
    parts = [cv2.pyrDown(np.ascontiguousarray(image[..., i : i + 4])) for i in range(0, image.shape[2], 4)]
    return np.concatenate([p.reshape(*p.shape[:2], -1) for p in parts], axis=2)


def _level_intrinsics(K: Intrinsics, level: int, width: int, height: int) -> Intrinsics:
    """Intrinsics after ``level`` pyrDown steps (pixel x of the coarser level = pixel 2x)."""
    s = 0.5**level
    return replace(K, fx=K.fx * s, fy=K.fy * s, cx=K.cx * s, cy=K.cy * s, width=width, height=height)


def _central_gradients(texture: torch.Tensor) -> torch.Tensor:
    """Central differences in x and y of (1, C, H, W), zero outside the image (as the sampler)."""
    p = F.pad(texture, (1, 1, 1, 1))
    gx = 0.5 * (p[..., 1:-1, 2:] - p[..., 1:-1, :-2])
    gy = 0.5 * (p[..., 2:, 1:-1] - p[..., :-2, 1:-1])
    return torch.cat([gx, gy], dim=1).contiguous()


def _resize_views(target, hole, source, values, K_t, K_s, pts_t, pts_s, max_side):
    """Everything downsized so that the longer of the two images has ``max_side`` px (no upsizing)."""
    s = min(1.0, max_side / max(*target.shape[:2], *source.shape[:2]))
    if s >= 1.0:
        return target, hole, source, values, K_t, K_s, pts_t, pts_s

    def size(img):
        return max(round(img.shape[1] * s), 8), max(round(img.shape[0] * s), 8)

    wt, ws = size(target), size(source)
    ok = np.isfinite(values)
    num = cv2.resize(np.where(ok, values, 0).astype(np.float32), ws, interpolation=cv2.INTER_AREA)
    den = cv2.resize(ok.astype(np.float32), ws, interpolation=cv2.INTER_AREA)
    with np.errstate(invalid="ignore", divide="ignore"):
        values_r = np.where(den > 0.5, num / den, np.nan).astype(np.float32)
    K_t2, K_s2 = K_t.resized(*wt), K_s.resized(*ws)

    def scale_pts(p, K_old, K_new):
        return (p + 0.5) * [K_new.width / K_old.width, K_new.height / K_old.height] - 0.5

    return (
        cv2.resize(target, wt, interpolation=cv2.INTER_AREA),
        cv2.resize(hole.astype(np.float32), wt, interpolation=cv2.INTER_AREA) > 0,
        cv2.resize(source, ws, interpolation=cv2.INTER_AREA),
        values_r,
        K_t2,
        K_s2,
        scale_pts(pts_t, K_t, K_t2),
        scale_pts(pts_s, K_s, K_s2),
    )


def build_problem(
    target: np.ndarray,
    hole: np.ndarray,
    source: np.ndarray,
    values: np.ndarray,
    space: str,
    K_t: Intrinsics,
    K_s: Intrinsics,
    pts_t: np.ndarray,
    pts_s: np.ndarray,
    cfg: OptimizeConfig,
) -> Problem:
    """Pyramids, weight map and point sets of one pair.

    ``target``/``source``: float32 RGB in [0, 1]; ``hole``: bool (target); ``values``: the source's
    depth (``space == "depth"``) or inverse depth (``"inverse"``) in pose units, NaN where unknown;
    ``pts_t``/``pts_s``: matched pixels (N, 2). All at the resolution of ``K_t``/``K_s``."""
    target, hole, source, values, K_t, K_s, pts_t, pts_s = _resize_views(
        target, hole, source, values, K_t, K_s, pts_t, pts_s, cfg.max_side
    )
    px_scale = max(*target.shape[:2], *source.shape[:2]) / 1280.0
    weight = importance_map(target, hole, cfg, px_scale)
    alpha = (~hole).astype(np.float32)
    tex = np.concatenate([target * alpha[..., None], alpha[..., None], weight[..., None]], axis=2)
    ok = np.isfinite(values)
    src = np.concatenate([source, np.where(ok, values, 0)[..., None], ok[..., None]], axis=2).astype(
        np.float32
    )
    margin = 2 * cfg.fast_margin_px + 1
    levels = []
    for k in range(cfg.pyramid_levels):
        if k:
            tex, src = _pyr_down(tex), _pyr_down(src)
        ht, wt = tex.shape[:2]
        hs, ws = src.shape[:2]
        den = src[..., 4]
        ok_k = den > 0.5
        val = np.where(ok_k, src[..., 3] / np.maximum(den, 1e-6), np.nan)
        ii, jj = np.nonzero(ok_k)
        K_sk = _level_intrinsics(K_s, k, ws, hs)
        texture = torch.from_numpy(np.ascontiguousarray(tex.transpose(2, 0, 1)))[None]
        support = cv2.dilate(np.ascontiguousarray(tex[..., 4]), np.ones((margin, margin), np.uint8))
        points = Points.from_pixels(np.stack([jj, ii], axis=1).astype(np.float64), K_sk, val[ii, jj])
        levels.append(
            PhotoLevel(
                texture=texture,
                gradients=_central_gradients(texture[:, :4]),
                support=torch.from_numpy(support)[None, None],
                known_area=float(tex[..., 3].sum()),
                K_t=_level_intrinsics(K_t, k, wt, ht),
                points=points,
                colour=torch.from_numpy(src[ii, jj, :3].copy()),
                all_values=points.value,
                value_range=(float(np.nanmin(val)), float(np.nanmax(val))) if ii.size else (1.0, 1.0),
            )
        )
    fv = sample_at(values, pts_s)
    fw = sample_at(weight, pts_t)
    keep = np.isfinite(fv) & np.isfinite(fw)
    features = FeatureSet(
        Points.from_pixels(pts_s[keep], K_s, fv[keep]),
        torch.from_numpy(pts_t[keep].astype(np.float32)),
        torch.from_numpy(fw[keep].astype(np.float32)),
    )
    return Problem(levels, features, space, cfg, cfg.barron_c_px * px_scale)


# ---------------------------------------------------------------------------------------------
# Objective


@dataclass
class Terms:
    """Objective terms (unweighted L_photo, L_feat, L_negD, the focal prior) and the weighted total."""

    photo: torch.Tensor
    feat: torch.Tensor
    negd: torch.Tensor
    prior: torch.Tensor
    total: torch.Tensor

    def to_json(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


def photo_loss(level: PhotoLevel, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """L_photo of ``level`` with its source points reprojected to (x, y) (paper Eq. 3)."""
    s = sample_target(level.texture, x, y)
    d = s[3] * level.colour.T - s[:3]
    return (s[4] * (d * d).sum(0)).sum(dtype=torch.float64) / level.known_area


def feature_loss(problem: Problem, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """L_feat with the source keypoints reprojected to (x, y) (paper Eq. 5)."""
    f = problem.features
    if len(f.points) == 0:
        return torch.zeros((), dtype=torch.float64)
    sq = (x - f.q_t[:, 0]) ** 2 + (y - f.q_t[:, 1]) ** 2
    rho = barron_loss(sq, problem.cfg.barron_alpha, problem.barron_c)
    return (f.weight * rho).sum(dtype=torch.float64) / len(f.points)


def objective(
    problem: Problem,
    level: PhotoLevel,
    x: torch.Tensor,
    y: torch.Tensor,
    xf: torch.Tensor,
    yf: torch.Tensor,
    scale: torch.Tensor,
    offset: torch.Tensor,
    log_focal: torch.Tensor,
) -> Terms:
    """The objective of ``level`` given the reprojected photometric points (x, y), the reprojected
    keypoints (xf, yf) and the depth scale/offset and log focal scale. Switched-off terms are 0."""
    cfg = problem.cfg
    zero = torch.zeros((), dtype=torch.float64)
    photo = photo_loss(level, x, y) if cfg.use_photo else zero
    feat = feature_loss(problem, xf, yf) if cfg.use_feat else zero
    negd = torch.relu(-(scale * level.all_values + offset)).sum(dtype=torch.float64) if cfg.use_negd else zero
    prior = cfg.focal_prior_weight * problem.prior_ref * log_focal.double() ** 2 if cfg.refine_focal else zero
    total = cfg.lambda_photo * photo + cfg.lambda_feat * feat + cfg.lambda_negd * negd + prior
    return Terms(photo, feat, negd, prior, total)


def _project_all(problem: Problem, level: PhotoLevel, R, t, s, b, phi):
    """(x, y) of the level's photometric points and of the keypoints."""
    x, y = project(R, t, s, b, phi, level.points, level.K_t, problem.space)
    xf, yf = project(R, t, s, b, phi, problem.features.points, problem.levels[0].K_t, problem.space)
    return x, y, xf, yf


def evaluate(problem: Problem, params: PoseDepthParams, level: int | PhotoLevel = 0) -> Terms:
    """Objective terms at ``params`` on a pyramid level (default the finest: "the objective")."""
    lv = problem.levels[level] if isinstance(level, int) else level
    with torch.no_grad():
        R, t, s, b, phi = _torch_params(params)
        return objective(problem, lv, *_project_all(problem, lv, R, t, s, b, phi), s, b, phi)


# ---------------------------------------------------------------------------------------------
# Paper solver: DiffGrad


@dataclass
class LevelLog:
    """What one pyramid level did (level 0 = finest)."""

    level: int
    iterations: int
    objective: float  # best objective of this level (its own L_photo level)
    n_photo_points: int
    converged: bool

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def solve_paper(problem: Problem, init: PoseDepthParams) -> tuple[PoseDepthParams, list[LevelLog]]:
    """DiffGrad on (quaternion, t, s, b[, log focal]) as in the paper: constant learning rate,
    coarse to fine with cumulative iteration limits, the supplement's convergence test, the best
    parameters of each level carried to the next; |t| renormalised at the end (see the module
    docstring)."""
    from pytorch_optimizer import DiffGrad  # imports torch.distributed (~2 s): only when used

    cfg = problem.cfg
    f64 = lambda v: torch.tensor(np.asarray(v, np.float64), dtype=torch.float64, requires_grad=True)  # noqa: E731
    q, t, s, b, phi = (
        f64(init.quaternion_wxyz()),
        f64(init.t),
        f64(init.scale),
        f64(init.offset),
        f64(init.log_focal),
    )
    leaves = [q, t, s, b] + ([phi] if cfg.refine_focal else [])
    logs: list[LevelLog] = []
    done = 0
    for k in reversed(range(len(problem.levels))):
        level = problem.levels[k]
        limit = cfg.paper_iterations[len(problem.levels) - 1 - k]
        opt = DiffGrad(leaves, lr=cfg.paper_lr)
        history: list[float] = []
        best_value, best = math.inf, [p.detach().clone() for p in leaves]
        is_conv = False
        while done < limit:
            opt.zero_grad()
            R = quaternion_to_matrix(q).float()
            s32, b32, phi32 = s.float(), b.float(), phi.float()
            xy = _project_all(problem, level, R, t.float(), s32, b32, phi32)
            terms = objective(problem, level, *xy, s32, b32, phi32)
            terms.total.backward()
            value = float(terms.total.detach())
            if value < best_value:
                best_value, best = value, [p.detach().clone() for p in leaves]
            opt.step()
            history.append(value)
            done += 1
            if converged(history, cfg.paper_window, cfg.paper_eps):
                is_conv = True
                break
        with torch.no_grad():
            for p, v in zip(leaves, best, strict=True):
                p.copy_(v)
        logs.append(LevelLog(k, len(history), best_value, len(level.points), is_conv))
    with torch.no_grad():
        R = quaternion_to_matrix(q).numpy()
    raw = PoseDepthParams(R, t.detach().numpy().copy(), s.item(), b.item(), phi.item())
    return renormalise(raw, float(np.linalg.norm(init.t)), problem.space), logs


def renormalise(p: PoseDepthParams, norm: float, space: str) -> PoseDepthParams:
    """The same projections with |t| = ``norm``: t and the depth scaled by norm / |t|."""
    n = float(np.linalg.norm(p.t))
    if n == 0.0 or norm == 0.0:
        return p
    k = norm / n  # depth and t are multiplied by k; inverse depth by 1 / k
    m = k if space == "depth" else 1.0 / k
    return replace(p, t=p.t * k, scale=p.scale * m, offset=p.offset * m)


# ---------------------------------------------------------------------------------------------
# Fast solver: Levenberg-Marquardt


def _tangent_basis(t: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis of the plane orthogonal to ``t``."""
    n = t / np.linalg.norm(t)
    a = np.eye(3)[int(np.argmin(np.abs(n)))]
    b1 = np.cross(n, a)
    b1 /= np.linalg.norm(b1)
    return np.stack([b1, np.cross(n, b1)], axis=1)


class _Chart:
    """Local coordinates delta around ``p``: rotation vector (3, left-multiplied), translation on its
    sphere (2), scale, offset[, log focal]. Derivatives are taken at delta = 0."""

    def __init__(self, p: PoseDepthParams, with_focal: bool):
        self.p = p
        self.n = 8 if with_focal else 7
        self.norm = float(np.linalg.norm(p.t))
        self.B = _tangent_basis(p.t)
        self.R, self.t, self.scale, self.offset, self.log_focal = _torch_params(p)
        self.ef = math.exp(p.log_focal)

    def reproject(self, pts: Points, K_t: Intrinsics, space: str) -> _Reprojection:
        return _reproject(self.R, self.t, self.scale, self.offset, self.log_focal, pts, K_t, space)

    def jacobian(self, r: _Reprojection, pts: Points, K_t: Intrinsics, space: str):
        """dx/d delta and dy/d delta, (N, n), of the reprojection ``r`` of ``pts`` (analytic)."""
        Rr = r.rotated
        zero = torch.zeros_like(r.rho)
        dY = torch.empty((*r.Y.shape, self.n), dtype=r.Y.dtype)  # (N, 3, n)
        # Rotation (I + [w]x) R: d(R ray) = w x (R ray); t is not rotated.
        dY[:, :, 0] = torch.stack([zero, -Rr[:, 2], Rr[:, 1]], 1)
        dY[:, :, 1] = torch.stack([Rr[:, 2], zero, -Rr[:, 0]], 1)
        dY[:, :, 2] = torch.stack([-Rr[:, 1], Rr[:, 0], zero], 1)
        dY[:, :, 3:5] = r.rho[:, None, None] * torch.as_tensor(self.norm * self.B, dtype=r.Y.dtype)
        drho = _drho_da(r, space)
        dY[:, :, 5] = self.t * (drho * pts.value)[:, None]
        dY[:, :, 6] = self.t * drho[:, None]
        if self.n == 8:  # rays shrink as the focal grows
            dY[:, :, 7] = -(r.rays[:, :2] @ self.R[:, :2].T)
        ax, ay = _dxy_dY(r, K_t, self.ef)
        Jx = torch.einsum("nk,nkj->nj", ax, dY)
        Jy = torch.einsum("nk,nkj->nj", ay, dY)
        if self.n == 8:  # x - cx scales with the target focal
            Jx[:, 7] += torch.where(r.ok, r.x - K_t.cx, 0.0)
            Jy[:, 7] += torch.where(r.ok, r.y - K_t.cy, 0.0)
        return Jx, Jy

    def gradient(self, raw: RawGradient) -> np.ndarray:
        """The chart gradient (n,) from the gradient in (R, t, scale, offset, log focal)."""
        M = raw.R @ torch.as_tensor(self.p.R).T  # rotation (I + [w]x) R: dl/dw = vee(M - M^T)
        g = np.empty(self.n)
        g[0:3] = [M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]]
        g[3:5] = (self.norm * self.B.T) @ raw.t.numpy()
        g[5], g[6] = float(raw.scale), float(raw.offset)
        if self.n == 8:
            g[7] = float(raw.log_focal)
        return g

    def retract(self, d: np.ndarray) -> PoseDepthParams:
        """The parameters at ``d`` (exact rotation and a unit-sphere translation)."""
        R = Rotation.from_rotvec(d[:3]).as_matrix() @ self.p.R
        t = self.p.t / self.norm + self.B @ d[3:5]
        return PoseDepthParams(
            R,
            self.norm * t / np.linalg.norm(t),
            self.p.scale + float(d[5]),
            self.p.offset + float(d[6]),
            self.p.log_focal + (float(d[7]) if self.n == 8 else 0.0),
        )


def _select_points(problem: Problem, level: PhotoLevel, *params: PoseDepthParams) -> PhotoLevel:
    """The level restricted to the source pixels whose reprojection at any of ``params`` lands where
    the (margin-grown) weight is at least ``fast_min_weight`` of its maximum."""
    cfg = problem.cfg
    if cfg.fast_min_weight <= 0 or not cfg.use_photo:
        return level
    keep = torch.zeros(len(level.points), dtype=torch.bool)
    floor = cfg.fast_min_weight * float(level.support.max())
    with torch.no_grad():
        for p in params:
            R, t, s, b, phi = _torch_params(p)
            x, y = project(R, t, s, b, phi, level.points, level.K_t, problem.space)
            keep |= sample_target(level.support, x, y)[0] >= floor
    return level.subset(keep)


class _Linearisation(NamedTuple):
    g: np.ndarray  # (n,) exact gradient of the level's objective in the chart at delta = 0
    H: np.ndarray  # (n, n) Gauss-Newton / IRLS curvature
    Jx: torch.Tensor  # (N, n) d x / d delta of the points that measure a step's motion
    Jy: torch.Tensor


def _step_motion_px(lin: _Linearisation, step: np.ndarray) -> float:
    """95th percentile over (at most 4096 of) the points of the displacement (px) a chart step
    predicts."""
    d = torch.as_tensor(step, dtype=torch.float32)
    k = max(1, lin.Jx.shape[0] // 4096)
    motion = torch.hypot(lin.Jx[::k] @ d, lin.Jy[::k] @ d)
    return float(torch.quantile(motion, 0.95)) if motion.numel() else 0.0


def _linearise(problem: Problem, level: PhotoLevel, chart: _Chart) -> _Linearisation:
    """Exact gradient and Gauss-Newton / IRLS curvature of the level's objective in ``chart``.

    The gradient chains autograd's d loss / d(x, y) through the analytic reprojection derivative
    over every point; the curvature only steers the step, so its photometric part is summed over
    an even subsample of at most ``_CURVATURE_SAMPLES`` points (scaled up)."""
    cfg = problem.cfg
    f = problem.features
    space = problem.space
    K_f = problem.levels[0].K_t
    r = chart.reproject(level.points, level.K_t, space)
    rf = chart.reproject(f.points, K_f, space)
    x, y, xf, yf = (v.detach().requires_grad_() for v in (r.x, r.y, rf.x, rf.y))
    s, b, phi = (v.clone().requires_grad_() for v in (chart.scale, chart.offset, chart.log_focal))
    terms = objective(problem, level, x, y, xf, yf, s, b, phi)
    gx, gy, gxf, gyf, gphi = torch.autograd.grad(
        terms.total, [x, y, xf, yf, phi], allow_unused=True, materialize_grads=True
    )
    lf = chart.p.log_focal
    raw = reprojection_vjp(r, level.points, level.K_t, space, chart.R, chart.t, lf, gx, gy)
    raw += reprojection_vjp(rf, f.points, K_f, space, chart.R, chart.t, lf, gxf, gyf)
    # s and b enter the objective directly only through L_negD, a hinge that _lm_step enforces as
    # the constraint s v + b >= 0: its gradient (steep, and zero once feasible) would only mislead
    # the quadratic model, so gs and gb are left out.
    g = chart.gradient(raw)
    H = np.zeros((chart.n, chart.n))
    n_pts = len(level.points)
    step = max(1, -(-n_pts // _CURVATURE_SAMPLES))
    sub = slice(0, n_pts, step)
    rs = _Reprojection(*(v[sub] for v in r))
    pts_s = Points(level.points.rays[sub], level.points.value[sub])
    Jx, Jy = chart.jacobian(rs, pts_s, level.K_t, space)
    with torch.no_grad():
        if cfg.use_photo and n_pts:
            smp = sample_target(level.texture, rs.x, rs.y)
            grad = sample_target(level.gradients, rs.x, rs.y)
            colour = level.colour[sub].T  # (3, N)
            Mx = grad[3] * colour - grad[0:3]  # d residual / dx, (3, N)
            My = grad[7] * colour - grad[4:7]
            # sum_p 2 c_p J_p^T M_p^T M_p J_p with M_p = [Mx My] (3x2), J_p = [Jx; Jy] (2xn).
            c = 2.0 * step * cfg.lambda_photo / level.known_area * smp[4].clamp_min(0)
            a, m, e = (c * (Mx * Mx).sum(0)), (c * (Mx * My).sum(0)), (c * (My * My).sum(0))
            Hxy = (Jx * m[:, None]).T @ Jy
            H += ((Jx * a[:, None]).T @ Jx + Hxy + Hxy.T + (Jy * e[:, None]).T @ Jy).double().numpy()
        Jxf, Jyf = chart.jacobian(rf, f.points, K_f, space)
        if cfg.use_feat and len(f.points):
            sq = (rf.x - f.q_t[:, 0]) ** 2 + (rf.y - f.q_t[:, 1]) ** 2
            w = 2.0 * cfg.lambda_feat / len(f.points) * f.weight
            sw = (w * barron_weight(sq, cfg.barron_alpha, problem.barron_c)).clamp_min(0).sqrt()[:, None]
            Jf = torch.cat([Jxf * sw, Jyf * sw]).double()
            H += (Jf.T @ Jf).numpy()
        if cfg.refine_focal:
            g[7] += float(gphi)
            H[7, 7] += 2.0 * cfg.focal_prior_weight * problem.prior_ref
    if not n_pts:
        Jx, Jy = Jxf, Jyf
    return _Linearisation(g, H, Jx, Jy)


def _level_value(problem: Problem, level: PhotoLevel, p: PoseDepthParams) -> float:
    return float(evaluate(problem, p, level).total)


def _lm_step(lin: _Linearisation, damping: np.ndarray, level: PhotoLevel, p: PoseDepthParams, negd: bool):
    """The damped Gauss-Newton step ``(H + diag(damping)) delta = -g`` (NaN if singular).

    L_negD is a hinge the quadratic model cannot see: a step that would make any depth of the level
    negative (``s v + b <= 0`` at the smallest or largest v) is replaced by the model's best step that
    lands on ``s v + b = 0`` instead (equality-constrained, KKT system). Without this the steps kept
    hitting the hinge's wall and being rejected whenever the photometric optimum leans on it (far
    pixels at inverse depth ~ 0 make it a wall at b ~ 0)."""
    A = lin.H + np.diag(damping)
    try:
        step = np.linalg.solve(A, -lin.g)
        if not negd:
            return step
        v = (
            level.value_range[0]
            if p.scale * level.value_range[0] <= p.scale * level.value_range[1]
            else level.value_range[1]
        )
        floor = p.scale * v + p.offset
        if floor + step[5] * v + step[6] >= 0:
            return step
        n = np.zeros(len(step))
        n[5], n[6] = v, 1.0
        kkt = np.block([[A, n[:, None]], [n[None, :], np.zeros((1, 1))]])
        return np.linalg.solve(kkt, np.concatenate([-lin.g, [-floor]]))[: len(step)]
    except np.linalg.LinAlgError:
        return np.full(len(lin.g), np.nan)


def _extend(problem, level, chart, step, cand, cand_value, lin, radius):
    """Doubling line search along ``step`` beyond an accepted ``cand``: the farthest of 2, 4, 8, ...
    times the step that still lowers the level's objective and moves the points by at most
    ``radius``; ``cand`` itself when the first doubling does not pay."""
    factor = 2.0
    while factor <= _MAX_EXTENSION and _step_motion_px(lin, factor * step) <= radius:
        further = chart.retract(factor * step)
        further_value = _level_value(problem, level, further)
        if not further_value < cand_value:
            break
        cand, cand_value = further, further_value
        factor *= 2.0
    return cand, cand_value


def solve_fast(problem: Problem, init: PoseDepthParams) -> tuple[PoseDepthParams, list[LevelLog]]:
    """Levenberg-Marquardt on the objective, coarse to fine over the same pyramid (module docstring).

    Steps solve ``(H + mu diag(H)) delta = -g`` with the exact gradient g and the Gauss-Newton /
    IRLS curvature H (:func:`_lm_step`, which also keeps every depth positive), shortened so that
    they move the reprojected points by at most a trust radius (95th percentile, px of the level;
    ``fast_step_px`` at the start of each level, doubled after a cut step the model predicted well,
    halved after a rejected one): the objective has degenerate minima far away (every point pushed
    out of the target leaves no photometric error), and bounded steps keep to the basin of the
    start. A step is kept only if it lowers the level's objective (on the selected points),
    otherwise mu grows. A level ends after ``fast_iterations`` steps, when a step gains less than
    ``fast_ftol`` (relative), when a step the model expected less than that from fails, or when no
    damping finds a lower value. A level starts
    from the initial parameters instead of the carried ones when those are better on it."""
    cfg = problem.cfg
    p = init
    logs: list[LevelLog] = []
    for k in reversed(range(len(problem.levels))):
        # Where the carried or the initial parameters land: the level compares both.
        level = _select_points(problem, problem.levels[k], *((p,) if p is init else (p, init)))
        radius = cfg.fast_step_px
        max_it = cfg.fast_iterations[len(problem.levels) - 1 - k]
        mu = _LM_MU0
        value = _level_value(problem, level, p)
        if p is not init and (v0 := _level_value(problem, level, init)) < value:
            p, value = init, v0
        it, is_conv = 0, False
        while it < max_it and not is_conv:
            chart = _Chart(p, cfg.refine_focal)
            lin = _linearise(problem, level, chart)
            diag = np.diag(lin.H).copy()
            diag = np.maximum(diag, 1e-12 * max(float(diag.max()), 1e-300))
            while True:
                step = _lm_step(lin, mu * diag, level, p, cfg.use_negd)
                truncated = False
                if np.all(np.isfinite(step)):
                    motion = _step_motion_px(lin, step)
                    if motion > radius:
                        step *= radius / motion
                        truncated = True
                    predicted = -(lin.g @ step + 0.5 * step @ lin.H @ step)
                    cand = chart.retract(step)
                    cand_value = _level_value(problem, level, cand)
                else:
                    cand_value = math.inf
                if cand_value < value:
                    gain = (value - cand_value) / max(abs(value), 1e-300)
                    if truncated and value - cand_value > 0.75 * predicted:  # the model holds: reach further
                        radius = min(2.0 * radius, _RADIUS_GROWTH * cfg.fast_step_px)
                    if value - cand_value > predicted:
                        # Gauss-Newton overrates the curvature here (the objective is flatter than the
                        # model along the step, e.g. in depth scale): extend the step while it keeps paying.
                        cand, cand_value = _extend(problem, level, chart, step, cand, cand_value, lin, radius)
                        gain = (value - cand_value) / max(abs(value), 1e-300)
                    p, value = cand, cand_value
                    mu = max(mu / _LM_DOWN, _LM_MU_MIN)
                    is_conv = not truncated and gain < cfg.fast_ftol
                    break
                if truncated:
                    radius = max(0.5 * radius, cfg.fast_step_px / _RADIUS_GROWTH)
                elif np.isfinite(cand_value) and predicted < cfg.fast_ftol * abs(value):
                    is_conv = True  # a full step the model expected almost nothing from failed
                    break
                mu *= _LM_UP
                if mu > _LM_MU_MAX:
                    is_conv = True
                    break
            it += 1
        logs.append(LevelLog(k, it, value, len(level.points), is_conv))
    return p, logs


# ---------------------------------------------------------------------------------------------
# Guard rails and the pipeline stage


def guard(params: PoseDepthParams, initial: float, final: float) -> str:
    """Why ``params`` must be rejected ('' when they are acceptable): NaN, a non-positive depth scale,
    or an objective worse than the initial one."""
    if not params.is_finite() or not math.isfinite(final):
        return "optimisation produced NaN/inf parameters or objective"
    if params.scale <= 0:
        return f"optimisation produced a non-positive depth scale ({params.scale:.4g})"
    if final > initial:
        return f"optimised objective {final:.6g} is worse than the initial {initial:.6g}"
    return ""


@dataclass
class OptimizationReport:
    """What the optimisation did (units: degrees, seconds; objective values are dimensionless)."""

    solver: str = ""
    status: str = ""  # "accepted", "rejected" (initial parameters kept) or "skipped"
    reason: str = ""
    initial_objective: float = float("nan")
    final_objective: float = float("nan")
    initial_terms: dict[str, float] = field(default_factory=dict)
    final_terms: dict[str, float] = field(default_factory=dict)
    levels: list[dict[str, Any]] = field(default_factory=list)
    params: dict[str, Any] = field(default_factory=dict)
    rotation_change_deg: float = 0.0
    translation_change_deg: float = 0.0
    focal_target_px: float = float("nan")
    focal_source_px: float = float("nan")
    n_features: int = 0
    seconds: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def summary(self) -> str:
        if self.status == "skipped":
            return f"skipped: {self.reason}"
        its = "/".join(str(lv["iterations"]) for lv in self.levels)
        text = (
            f"{self.solver} {self.status}: objective {self.initial_objective:.4g} -> "
            f"{self.final_objective:.4g} (iterations {its}), dR {self.rotation_change_deg:.2f} deg, "
            f"dt {self.translation_change_deg:.2f} deg, scale {self.params.get('scale', 1.0):.3f}"
        )
        return text + (f"; {self.reason}" if self.reason else "")


@dataclass
class OptimizationResult:
    """The geometry the render uses: pose, depth and intrinsics (working resolution), plus the report."""

    T: np.ndarray
    depth: AlignedDepth
    K_target: Intrinsics
    K_source: Intrinsics
    params: PoseDepthParams
    report: OptimizationReport


def fit_space_values(depth: AlignedDepth) -> np.ndarray:
    """The aligned depth in its fit space: z, or 1/z for an inverse-depth fit (NaN stays NaN)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return depth.depth if depth.space == "depth" else (1.0 / depth.depth).astype(np.float32)


def optimize_pose_depth(
    target: np.ndarray,
    hole: np.ndarray,
    source: np.ndarray,
    K_t: Intrinsics,
    K_s: Intrinsics,
    T: np.ndarray,
    depth: AlignedDepth,
    pts_t: np.ndarray,
    pts_s: np.ndarray,
    cfg: OptimizeConfig,
) -> OptimizationResult:
    """Jointly refine the pose ``T`` (source->target, |t| kept) and the depth's scale/offset (and
    optionally the focal lengths) for one pair at working resolution; see the module docstring.

    ``target``/``source``: float32 RGB in [0, 1]; ``hole``: bool; ``pts_t``/``pts_s``: matched pixels
    (the pose inliers). Rejected results keep the initial geometry, with the reason in the report."""
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(max(1, cfg.threads))
    try:
        return _optimize(target, hole, source, K_t, K_s, T, depth, pts_t, pts_s, cfg)
    finally:
        torch.set_num_threads(previous_threads)


def _optimize(target, hole, source, K_t, K_s, T, depth, pts_t, pts_s, cfg) -> OptimizationResult:
    t0 = time.perf_counter()
    init = PoseDepthParams(np.asarray(T[:3, :3], np.float64), np.asarray(T[:3, 3], np.float64).copy())
    report = OptimizationReport(solver=cfg.solver)
    unchanged = OptimizationResult(T, depth, K_t, K_s, init, report)
    if float(np.linalg.norm(init.t)) == 0.0:
        report.status, report.reason = "skipped", "no translation (rotation-only pose): depth is unobservable"
        return unchanged
    values = fit_space_values(depth)
    problem = build_problem(target, hole, source, values, depth.space, K_t, K_s, pts_t, pts_s, cfg)
    report.n_features = int(problem.features.q_t.shape[0])
    initial = evaluate(problem, init)
    problem.prior_ref = float(initial.total)
    solve = solve_paper if cfg.solver == "paper" else solve_fast
    params, logs = solve(problem, init)
    final = evaluate(problem, params)
    report.initial_objective, report.initial_terms = float(initial.total), initial.to_json()
    report.final_objective, report.final_terms = float(final.total), final.to_json()
    report.levels = [lg.to_json() for lg in logs]
    report.reason = guard(params, float(initial.total), float(final.total))
    report.status = "rejected" if report.reason else "accepted"
    report.seconds = time.perf_counter() - t0
    if report.reason:
        report.params = init.to_json()
        return unchanged
    report.params = params.to_json()
    report.rotation_change_deg = rotation_error_deg(init.R, params.R)
    report.translation_change_deg = translation_direction_error_deg(init.t, params.t)
    ef = math.exp(params.log_focal)
    K_t2 = replace(K_t, fx=K_t.fx * ef, fy=K_t.fy * ef, origin="refined") if cfg.refine_focal else K_t
    K_s2 = replace(K_s, fx=K_s.fx * ef, fy=K_s.fy * ef, origin="refined") if cfg.refine_focal else K_s
    report.focal_target_px, report.focal_source_px = K_t2.fx, K_s2.fx
    z, neg = to_depth(values, depth.space, params.scale, params.offset)
    new_depth = replace(
        depth,
        depth=z,
        scale=params.scale * depth.scale,
        offset=params.scale * depth.offset + params.offset,
        negative_fraction=neg,
    )
    report.seconds = time.perf_counter() - t0
    return OptimizationResult(params.T, new_depth, K_t2, K_s2, params, report)
