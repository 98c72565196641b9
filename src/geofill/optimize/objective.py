"""The objective (module :mod:`geofill.optimize`): each term's value next to its Gauss-Newton block
(the curvature the fast solver's quadratic model uses), so a term is added in one place."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch

from .params import PoseDepthParams, Reprojection, project, torch_params
from .problem import PhotoLevel, Problem, sample_target


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


def photo_gauss_newton(
    problem: Problem,
    level: PhotoLevel,
    r: Reprojection,
    colour: torch.Tensor,
    count: int,
    Jx: torch.Tensor,
    Jy: torch.Tensor,
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
    c = 2.0 * count * problem.cfg.lambda_photo / level.known_area * smp[4].clamp_min(0)
    a, m, e = (c * (Mx * Mx).sum(0)), (c * (Mx * My).sum(0)), (c * (My * My).sum(0))
    Hxy = (Jx * m[:, None]).T @ Jy
    return ((Jx * a[:, None]).T @ Jx + Hxy + Hxy.T + (Jy * e[:, None]).T @ Jy).double().numpy()


def feature_loss(problem: Problem, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """L_feat with the source keypoints reprojected to (x, y) (paper Eq. 5)."""
    f = problem.features
    if len(f.points) == 0:
        return torch.zeros((), dtype=torch.float64)
    sq = (x - f.q_t[:, 0]) ** 2 + (y - f.q_t[:, 1]) ** 2
    rho = barron_loss(sq, problem.cfg.barron_alpha, problem.barron_c)
    return (f.weight * rho).sum(dtype=torch.float64) / len(f.points)


def feature_gauss_newton(problem: Problem, r: Reprojection, Jx: torch.Tensor, Jy: torch.Tensor) -> np.ndarray:
    """IRLS Gauss-Newton block (n, n) of ``lambda_feat L_feat`` from the keypoints' reprojection
    ``r`` and chart Jacobians ``Jx``, ``Jy`` (M, n)."""
    f, cfg = problem.features, problem.cfg
    sq = (r.x - f.q_t[:, 0]) ** 2 + (r.y - f.q_t[:, 1]) ** 2
    w = 2.0 * cfg.lambda_feat / len(f.points) * f.weight
    sw = (w * barron_weight(sq, cfg.barron_alpha, problem.barron_c)).clamp_min(0).sqrt()[:, None]
    Jf = torch.cat([Jx * sw, Jy * sw]).double()
    return (Jf.T @ Jf).numpy()


def focal_prior(problem: Problem, log_focal: torch.Tensor) -> torch.Tensor:
    """The weak prior on the log focal scale, relative to the initial objective: w l0 phi^2."""
    return problem.cfg.focal_prior_weight * problem.prior_ref * log_focal.double() ** 2


def prior_gauss_newton(problem: Problem) -> float:
    """Curvature d^2 / d phi^2 of :func:`focal_prior` (exact: the prior is quadratic)."""
    return 2.0 * problem.cfg.focal_prior_weight * problem.prior_ref


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
    prior = focal_prior(problem, log_focal) if cfg.refine_focal else zero
    total = cfg.lambda_photo * photo + cfg.lambda_feat * feat + cfg.lambda_negd * negd + prior
    return Terms(photo, feat, negd, prior, total)


def project_all(problem: Problem, level: PhotoLevel, R, t, s, b, phi):
    """(x, y) of the level's photometric points and of the keypoints."""
    x, y = project(R, t, s, b, phi, level.points, level.K_t, problem.space)
    xf, yf = project(R, t, s, b, phi, problem.features.points, problem.levels[0].K_t, problem.space)
    return x, y, xf, yf


def evaluate(problem: Problem, params: PoseDepthParams, level: int | PhotoLevel = 0) -> Terms:
    """Objective terms at ``params`` on a pyramid level (default the finest: "the objective")."""
    lv = problem.levels[level] if isinstance(level, int) else level
    with torch.no_grad():
        R, t, s, b, phi = torch_params(params)
        return objective(problem, lv, *project_all(problem, lv, R, t, s, b, phi), s, b, phi)
