"""The ``fast`` solver: Levenberg-Marquardt in a chart that keeps |t| fixed, with the exact gradient
(d loss / d(x, y) of :mod:`geofill.optimize.objective` chained through the analytic reprojection
derivative) and its Gauss-Newton / IRLS curvature. NumPy only: no torch on the default path."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..camera import Intrinsics, rotation_from_rotvec
from ..utils.rotations import tangent_basis
from .objective import (
    evaluate,
    feature_gauss_newton,
    focal_prior_gradient,
    objective_gradient,
    photo_gauss_newton,
    prior_gauss_newton,
)
from .params import (
    Points,
    PoseDepthParams,
    RawGradient,
    Reprojection,
    array_params,
    drho_da,
    dxy_dY,
    project,
    reproject_points,
    reprojection_vjp,
)
from .problem import LevelLog, PhotoLevel, Problem, sample_target

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


class _Chart:
    """Local coordinates delta around ``p``: rotation vector (3, left-multiplied), translation on its
    sphere (2), scale, offset[, log focal]. Derivatives are taken at delta = 0."""

    def __init__(self, p: PoseDepthParams, with_focal: bool):
        self.p = p
        self.n = 8 if with_focal else 7
        self.norm = float(np.linalg.norm(p.t))
        self.B = tangent_basis(p.t)
        self.R, self.t, self.scale, self.offset, self.log_focal = array_params(p)
        self.ef = math.exp(p.log_focal)

    def reproject(self, pts: Points, K_t: Intrinsics, space: str) -> Reprojection:
        return reproject_points(self.R, self.t, self.scale, self.offset, self.log_focal, pts, K_t, space)

    def jacobian(self, r: Reprojection, pts: Points, K_t: Intrinsics, space: str):
        """dx/d delta and dy/d delta, (N, n), of the reprojection ``r`` of ``pts`` (analytic)."""
        Rr = r.rotated
        dY = np.zeros((*r.Y.shape, self.n), dtype=r.Y.dtype)  # (N, 3, n)
        # Rotation (I + [w]x) R: d(R ray) = w x (R ray); t is not rotated.
        dY[:, 1, 0], dY[:, 2, 0] = -Rr[:, 2], Rr[:, 1]
        dY[:, 0, 1], dY[:, 2, 1] = Rr[:, 2], -Rr[:, 0]
        dY[:, 0, 2], dY[:, 1, 2] = -Rr[:, 1], Rr[:, 0]
        dY[:, :, 3:5] = r.rho[:, None, None] * (self.norm * self.B).astype(r.Y.dtype)
        drho = drho_da(r, space)
        dY[:, :, 5] = self.t * (drho * pts.value)[:, None]
        dY[:, :, 6] = self.t * drho[:, None]
        if self.n == 8:  # rays shrink as the focal grows
            dY[:, :, 7] = -(r.rays[:, :2] @ self.R[:, :2].T)
        ax, ay = dxy_dY(r, K_t, self.ef)
        Jx = np.einsum("nk,nkj->nj", ax, dY)
        Jy = np.einsum("nk,nkj->nj", ay, dY)
        if self.n == 8:  # x - cx scales with the target focal
            zero = np.float32(0.0)
            Jx[:, 7] += np.where(r.ok, r.x - K_t.cx, zero)
            Jy[:, 7] += np.where(r.ok, r.y - K_t.cy, zero)
        return Jx, Jy

    def gradient(self, raw: RawGradient) -> np.ndarray:
        """The chart gradient (n,) from the gradient in (R, t, scale, offset, log focal)."""
        M = raw.R @ self.p.R.T  # rotation (I + [w]x) R: dl/dw = vee(M - M^T)
        g = np.empty(self.n)
        g[0:3] = [M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]]
        g[3:5] = (self.norm * self.B.T) @ raw.t
        g[5], g[6] = float(raw.scale), float(raw.offset)
        if self.n == 8:
            g[7] = float(raw.log_focal)
        return g

    def retract(self, d: np.ndarray) -> PoseDepthParams:
        """The parameters at ``d`` (exact rotation and a unit-sphere translation)."""
        R = rotation_from_rotvec(d[:3]) @ self.p.R
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
    keep = np.zeros(len(level.points), dtype=bool)
    floor = cfg.fast_min_weight * float(level.support.max())
    for p in params:
        x, y = project(*array_params(p), level.points, level.K_t, problem.space)
        keep |= sample_target(level.support, x, y)[0] >= floor
    return level.subset(keep)


class _Linearisation(NamedTuple):
    g: np.ndarray  # (n,) exact gradient of the level's objective in the chart at delta = 0
    H: np.ndarray  # (n, n) Gauss-Newton / IRLS curvature
    Jx: np.ndarray  # (N, n) d x / d delta of the points that measure a step's motion
    Jy: np.ndarray


def _step_motion_px(lin: _Linearisation, step: np.ndarray) -> float:
    """95th percentile over (at most 4096 of) the points of the displacement (px) a chart step
    predicts."""
    d = step.astype(np.float32)
    k = max(1, lin.Jx.shape[0] // 4096)
    motion = np.hypot(lin.Jx[::k] @ d, lin.Jy[::k] @ d)
    return float(np.quantile(motion, 0.95)) if motion.size else 0.0


def _linearise(problem: Problem, level: PhotoLevel, chart: _Chart) -> _Linearisation:
    """Exact gradient and Gauss-Newton / IRLS curvature of the level's objective in ``chart``.

    The gradient chains d loss / d(x, y) through the analytic reprojection derivative over every
    point; the curvature only steers the step, so its photometric part is summed over
    an even subsample of at most ``_CURVATURE_SAMPLES`` points (scaled up)."""
    cfg = problem.cfg
    f = problem.features
    space = problem.space
    K_f = problem.levels[0].K_t
    r = chart.reproject(level.points, level.K_t, space)
    rf = chart.reproject(f.points, K_f, space)
    gx, gy, gxf, gyf = objective_gradient(problem, level, r.x, r.y, rf.x, rf.y)
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
    rs = Reprojection(*(v[sub] for v in r))
    pts_s = Points(level.points.rays[sub], level.points.value[sub])
    Jx, Jy = chart.jacobian(rs, pts_s, level.K_t, space)
    if cfg.use_photo and n_pts:
        H += photo_gauss_newton(problem, level, rs, level.colour[sub], step, Jx, Jy)
    Jxf, Jyf = chart.jacobian(rf, f.points, K_f, space)
    if cfg.use_feat and len(f.points):
        H += feature_gauss_newton(problem, rf, Jxf, Jyf)
    if cfg.refine_focal:
        g[7] += focal_prior_gradient(problem, lf)
        H[7, 7] += prior_gauss_newton(problem)
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
