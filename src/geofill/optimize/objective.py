"""The objective (module :mod:`geofill.optimize`): each term's value next to its gradient in the
reprojected positions and its Gauss-Newton block (what the fast solver's quadratic model uses), so a
term is added in one place.

The values are written once against the array API: NumPy arrays for the fast solver (no torch on
the default path; its gradient is written out below) and torch tensors for the paper solver, which
differentiates them with autograd."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from array_api_compat import array_namespace

from .params import PoseDepthParams, Reprojection, array_params, project
from .problem import PhotoLevel, Problem, sample_target, sample_target_with_gradient


def barron_loss(sq: Any, alpha: float, c: float) -> Any:
    """Barron's general robust loss f(x, alpha, c) (CVPR 2019, paper Eq. 4) of ``sq = x^2``, with its
    limits at alpha = 2 (L2) and alpha = 0 (Cauchy); alpha = -2 is Geman-McClure
    ``2 (x/c)^2 / ((x/c)^2 + 4)``."""
    xp = array_namespace(sq)
    u = sq / (c * c)
    if alpha == 2.0:
        return 0.5 * u
    if alpha == 0.0:
        return xp.log1p(0.5 * u)
    b = abs(alpha - 2.0)
    return (b / alpha) * (xp.pow(u / b + 1.0, alpha / 2.0) - 1.0)


def barron_weight(sq: Any, alpha: float, c: float) -> Any:
    """d f / d(x^2): the IRLS weight of :func:`barron_loss`."""
    xp = array_namespace(sq)
    if alpha == 2.0:
        return xp.full_like(sq, 0.5 / (c * c))
    b = abs(alpha - 2.0)
    return 0.5 / (c * c) * xp.pow(sq / (c * c * b) + 1.0, alpha / 2.0 - 1.0)


@dataclass
class Terms:
    """Objective terms (unweighted L_photo, L_feat, L_negD, the focal prior) and the weighted total."""

    photo: Any  # 0-d float64 arrays (NumPy or torch)
    feat: Any
    negd: Any
    prior: Any
    total: Any

    def to_json(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


def photo_loss(level: PhotoLevel, x: Any, y: Any) -> Any:
    """L_photo of ``level`` with its source points reprojected to (x, y) (paper Eq. 3)."""
    xp = array_namespace(x)
    s = sample_target(level.texture, x, y)
    d = s[3] * level.colour.T - s[:3]
    return xp.sum(s[4] * xp.sum(d * d, axis=0), dtype=xp.float64) / level.known_area


def photo_gradient(level: PhotoLevel, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d L_photo / dx and / dy per point (N,) (the derivative of :func:`photo_loss`)."""
    s, sx, sy = sample_target_with_gradient(level.texture, x, y)
    colour = level.colour.T
    d = s[3] * colour - s[:3]  # residual (3, N)
    e = np.sum(d * d, axis=0)
    scale = np.float32(1.0 / level.known_area)

    def along(ds: np.ndarray) -> np.ndarray:
        return scale * (ds[4] * e + 2.0 * s[4] * np.sum(d * (ds[3] * colour - ds[:3]), axis=0))

    return along(sx), along(sy)


def photo_gauss_newton(
    problem: Problem,
    level: PhotoLevel,
    r: Reprojection,
    colour: np.ndarray,
    count: int,
    Jx: np.ndarray,
    Jy: np.ndarray,
) -> np.ndarray:
    """Gauss-Newton block (n, n) of ``lambda_photo L_photo`` from the reprojection ``r`` of points of
    ``level`` with RGB ``colour`` (N, 3) and chart Jacobians ``Jx``, ``Jy`` (N, n); each point
    stands for ``count`` points of the level (an even subsample)."""
    smp = sample_target(level.texture, r.x, r.y)
    grad = sample_target(level.gradients, r.x, r.y)
    colour = colour.T  # (3, N)
    Mx = grad[3] * colour - grad[0:3]  # d residual / dx, (3, N)
    My = grad[7] * colour - grad[4:7]
    # sum_p 2 c_p J_p^T M_p^T M_p J_p with M_p = [Mx My] (3x2), J_p = [Jx; Jy] (2xn).
    c = 2.0 * count * problem.cfg.lambda_photo / level.known_area * np.maximum(smp[4], 0)
    a, m, e = (c * (Mx * Mx).sum(0)), (c * (Mx * My).sum(0)), (c * (My * My).sum(0))
    Hxy = (Jx * m[:, None]).T @ Jy
    return ((Jx * a[:, None]).T @ Jx + Hxy + Hxy.T + (Jy * e[:, None]).T @ Jy).astype(np.float64)


def feature_loss(problem: Problem, x: Any, y: Any) -> Any:
    """L_feat with the source keypoints reprojected to (x, y) (paper Eq. 5)."""
    xp = array_namespace(x)
    f = problem.features
    if len(f.points) == 0:
        return xp.zeros((), dtype=xp.float64)
    sq = (x - f.q_t[:, 0]) ** 2 + (y - f.q_t[:, 1]) ** 2
    rho = barron_loss(sq, problem.cfg.barron_alpha, problem.barron_c)
    return xp.sum(f.weight * rho, dtype=xp.float64) / len(f.points)


def feature_gradient(problem: Problem, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d L_feat / dx and / dy per keypoint (M,) (the derivative of :func:`feature_loss`)."""
    f = problem.features
    if len(f.points) == 0:
        return np.zeros_like(x), np.zeros_like(y)
    dx, dy = x - f.q_t[:, 0], y - f.q_t[:, 1]
    w = f.weight * barron_weight(dx * dx + dy * dy, problem.cfg.barron_alpha, problem.barron_c)
    w *= np.float32(2.0 / len(f.points))
    return w * dx, w * dy


def feature_gauss_newton(problem: Problem, r: Reprojection, Jx: np.ndarray, Jy: np.ndarray) -> np.ndarray:
    """IRLS Gauss-Newton block (n, n) of ``lambda_feat L_feat`` from the keypoints' reprojection
    ``r`` and chart Jacobians ``Jx``, ``Jy`` (M, n)."""
    f, cfg = problem.features, problem.cfg
    sq = (r.x - f.q_t[:, 0]) ** 2 + (r.y - f.q_t[:, 1]) ** 2
    w = 2.0 * cfg.lambda_feat / len(f.points) * f.weight
    sw = np.sqrt(np.maximum(w * barron_weight(sq, cfg.barron_alpha, problem.barron_c), 0))[:, None]
    Jf = np.concatenate([Jx * sw, Jy * sw]).astype(np.float64)
    return Jf.T @ Jf


def focal_prior(problem: Problem, log_focal: Any) -> Any:
    """The weak prior on the log focal scale, relative to the initial objective: w l0 phi^2."""
    xp = array_namespace(log_focal)
    return problem.cfg.focal_prior_weight * problem.prior_ref * xp.astype(log_focal, xp.float64) ** 2


def focal_prior_gradient(problem: Problem, log_focal: float) -> float:
    """d :func:`focal_prior` / d phi."""
    return 2.0 * problem.cfg.focal_prior_weight * problem.prior_ref * log_focal


def prior_gauss_newton(problem: Problem) -> float:
    """Curvature d^2 / d phi^2 of :func:`focal_prior` (exact: the prior is quadratic)."""
    return 2.0 * problem.cfg.focal_prior_weight * problem.prior_ref


def objective(
    problem: Problem,
    level: PhotoLevel,
    x: Any,
    y: Any,
    xf: Any,
    yf: Any,
    scale: Any,
    offset: Any,
    log_focal: Any,
) -> Terms:
    """The objective of ``level`` given the reprojected photometric points (x, y), the reprojected
    keypoints (xf, yf) and the depth scale/offset and log focal scale. Switched-off terms are 0."""
    cfg = problem.cfg
    xp = array_namespace(x, log_focal)
    zero = xp.zeros((), dtype=xp.float64)
    photo = photo_loss(level, x, y) if cfg.use_photo else zero
    feat = feature_loss(problem, xf, yf) if cfg.use_feat else zero
    hinge = xp.clip(-(scale * level.all_values + offset), min=0.0) if cfg.use_negd else None
    negd = xp.sum(hinge, dtype=xp.float64) if cfg.use_negd else zero
    prior = focal_prior(problem, log_focal) if cfg.refine_focal else zero
    total = cfg.lambda_photo * photo + cfg.lambda_feat * feat + cfg.lambda_negd * negd + prior
    return Terms(photo, feat, negd, prior, total)


def project_all(problem: Problem, level: PhotoLevel, R, t, s, b, phi):
    """(x, y) of the level's photometric points and of the keypoints."""
    x, y = project(R, t, s, b, phi, level.points, level.K_t, problem.space)
    xf, yf = project(R, t, s, b, phi, problem.features.points, problem.levels[0].K_t, problem.space)
    return x, y, xf, yf


def objective_gradient(problem: Problem, level: PhotoLevel, x, y, xf, yf):
    """d total / d(x, y, xf, yf) of :func:`objective` (the terms that depend on the positions;
    L_negD and the focal prior do not)."""
    cfg = problem.cfg
    if cfg.use_photo and len(x):
        gx, gy = photo_gradient(level, x, y)
        gx, gy = cfg.lambda_photo * gx, cfg.lambda_photo * gy
    else:
        gx, gy = np.zeros_like(x), np.zeros_like(y)
    if cfg.use_feat:
        gxf, gyf = feature_gradient(problem, xf, yf)
        gxf, gyf = cfg.lambda_feat * gxf, cfg.lambda_feat * gyf
    else:
        gxf, gyf = np.zeros_like(xf), np.zeros_like(yf)
    return gx, gy, gxf, gyf


def evaluate(problem: Problem, params: PoseDepthParams, level: int | PhotoLevel = 0) -> Terms:
    """Objective terms at ``params`` on a pyramid level (default the finest: "the objective")."""
    lv = problem.levels[level] if isinstance(level, int) else level
    R, t, s, b, phi = array_params(params)
    return objective(problem, lv, *project_all(problem, lv, R, t, s, b, phi), s, b, phi)
