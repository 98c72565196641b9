"""Small numerical routines written out instead of imported from SciPy.

Importing ``scipy.optimize``, ``scipy.sparse.linalg`` and ``scipy.spatial`` took ~0.13 s of every
fill (``python -X importtime``, on top of the ``scipy.linalg`` that numba imports anyway; a whole
1280x720 fill aims at 2 s), and a fill needs only these pieces of them. Each routine reproduces
SciPy's answer to the problem it solves; ``tests/test_numerics.py`` compares them.

* :func:`robust_linear_fit`: ``least_squares`` with a robust loss and box bounds for a residual
  linear in the parameters (the colour gain/offset fits of refinement, the depth scale/offset fit);
* :func:`robust_least_squares`: ``least_squares`` with a robust loss for a small non-linear problem
  with an analytic Jacobian (the essential-matrix fit of the focal search, where SciPy's
  per-iteration overhead was most of the time);
* :func:`minimize_bounded`: ``minimize_scalar(method="bounded")`` (Brent's method).

The losses and the cost are SciPy's: ``cost = 0.5 f^2 sum(rho((r / f)^2))`` with ``f`` the loss
scale, so a cost or a minimiser here means the same as there.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import numpy as np

#: Loss names accepted (SciPy's ``least_squares`` names).
LOSSES = ("linear", "soft_l1", "huber")


def robust_loss(r: np.ndarray, loss: str, f_scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per residual: ``f^2 rho(z)`` (z = (r / f)^2), ``rho'(z)`` and ``2 rho''(z) z + rho'(z)``.

    The last is the second derivative of ``0.5 f^2 rho`` in ``r``: the curvature a Newton step uses
    (clipped at a tiny positive value where it vanishes, as SciPy does)."""
    z = (r / f_scale) ** 2
    if loss == "linear":
        one = np.ones_like(z)
        return f_scale**2 * z, one, one
    if loss == "soft_l1":
        t = 1.0 + z
        s = np.sqrt(t)
        return f_scale**2 * 2.0 * (s - 1.0), 1.0 / s, 1.0 / (t * s)
    if loss == "huber":
        inside = z <= 1.0
        zs = np.sqrt(np.maximum(z, 1.0))
        rho = np.where(inside, z, 2.0 * zs - 1.0)
        rho1 = np.where(inside, 1.0, 1.0 / zs)
        return f_scale**2 * rho, rho1, np.where(inside, 1.0, np.finfo(float).eps)
    raise ValueError(f"unknown loss {loss!r}; expected one of {LOSSES}")


def robust_cost(r: np.ndarray, loss: str, f_scale: float) -> float:
    """SciPy's ``least_squares`` cost of residuals ``r``: ``0.5 f^2 sum(rho((r / f)^2))``."""
    return 0.5 * float(np.sum(robust_loss(r, loss, f_scale)[0]))


def robust_linear_fit(
    A: np.ndarray,
    y: np.ndarray,
    loss: str,
    f_scale: float,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    x0: np.ndarray | None = None,
    xtol: float = 1e-12,
    max_iter: int = 100,
) -> np.ndarray:
    """The minimiser of ``0.5 f^2 sum(rho(((A x - y) / f)^2))`` over ``lower <= x <= upper``.

    What ``least_squares(lambda x: A @ x - y, x0, loss=loss, f_scale=f_scale, bounds=(lower,
    upper))`` converges to; the losses offered are convex, so the minimiser is unique. Newton steps
    on the cost (the box-constrained quadratic model solved exactly by its active sets, so only for
    a few parameters) with a backtracking line search; weight rows of ``A`` and ``y`` by the square
    root of any sample weight. ``x0`` (default: the least-squares solution, clipped) only changes
    the iterations, not the answer."""
    A = np.asarray(A, np.float64)
    y = np.asarray(y, np.float64)
    n = A.shape[1]
    lo = np.full(n, -np.inf) if lower is None else np.asarray(lower, np.float64)
    hi = np.full(n, np.inf) if upper is None else np.asarray(upper, np.float64)
    x = np.linalg.lstsq(A, y, rcond=None)[0] if x0 is None else np.asarray(x0, np.float64)
    x = np.clip(x, lo, hi)
    r = A @ x - y
    rho, rho1, curv = robust_loss(r, loss, f_scale)
    cost = 0.5 * float(rho.sum())
    for _ in range(max_iter):
        g = A.T @ (rho1 * r)
        H = A.T @ (curv[:, None] * A)
        step = _box_qp(H, g, lo - x, hi - x)
        # The cost is convex, so the Newton step is a descent direction; halve it until it
        # decreases the cost (a full step almost always does near the minimum).
        t, slope = 1.0, float(g @ step)
        while True:
            x_new = np.clip(x + t * step, lo, hi)
            r_new = A @ x_new - y
            rho_new, rho1_new, curv_new = robust_loss(r_new, loss, f_scale)
            cost_new = 0.5 * float(rho_new.sum())
            if cost_new <= cost + 1e-4 * t * slope or t < 1e-10:
                break
            t *= 0.5
        done = np.linalg.norm(x_new - x) <= xtol * (1.0 + np.linalg.norm(x))
        if cost_new <= cost:
            x, r, cost, rho1, curv = x_new, r_new, cost_new, rho1_new, curv_new
        if done or cost_new > cost:
            break
    return x


def _box_qp(H: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """argmin of ``g.d + 0.5 d.H.d`` (H positive definite) over ``lo <= d <= hi`` (lo <= 0 <= hi),
    by trying every set of parameters held at a bound when the free minimum is outside the box:
    the convex minimum is the best feasible candidate. 3^n candidates, so for a handful of
    parameters only."""
    n = g.size
    try:
        d = np.linalg.solve(H, -g)
        if np.all(d >= lo) and np.all(d <= hi):
            return d
    except np.linalg.LinAlgError:
        pass
    best, best_val = np.zeros(n), 0.0
    for pattern in itertools.product((0, -1, 1), repeat=n):
        d = np.where(np.array(pattern) < 0, lo, np.where(np.array(pattern) > 0, hi, 0.0))
        if not np.all(np.isfinite(d)):
            continue
        free = np.array(pattern) == 0
        if free.any():
            Hf = H[np.ix_(free, free)]
            rhs = -(g[free] + H[np.ix_(free, ~free)] @ d[~free])
            try:
                d[free] = np.linalg.solve(Hf, rhs)
            except np.linalg.LinAlgError:
                continue
            if np.any(d[free] < lo[free] - 1e-15) or np.any(d[free] > hi[free] + 1e-15):
                continue
        val = float(g @ d + 0.5 * d @ H @ d)
        if val < best_val:
            best, best_val = d, val
    return best


def robust_least_squares(
    fun_jac: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    x0: np.ndarray,
    loss: str,
    f_scale: float,
    ftol: float = 1e-8,
    xtol: float = 1e-8,
    max_evaluations: int | None = None,
) -> tuple[np.ndarray, float, np.ndarray]:
    """The local minimum of ``0.5 f^2 sum(rho((r(x) / f)^2))`` that SciPy's ``least_squares(fun,
    x0, jac, loss=loss, f_scale=f_scale)`` (method "trf" without bounds) finds: the same
    trust-region Gauss-Newton iteration (robust curvature J^T diag(rho' + 2 rho'' z) J, the
    trust-region subproblem solved exactly, the same radius updates starting from 1 for x0 = 0,
    and its termination tests with SciPy's tolerances), for a few parameters. ``fun_jac(x)``
    returns the residuals (m,) and their Jacobian (m, n), evaluated together (the Jacobian of a
    rejected step, which is rare, is wasted). Returns (x, cost, residuals at x)."""
    x = np.asarray(x0, np.float64).copy()
    n = x.size
    max_evaluations = 100 * n if max_evaluations is None else max_evaluations
    r, J = fun_jac(x)
    evaluations = 1
    rho, rho1, curv = robust_loss(r, loss, f_scale)
    cost = 0.5 * float(rho.sum())
    radius = float(np.linalg.norm(x)) or 1.0
    lam = 0.0
    while evaluations < max_evaluations:
        g = J.T @ (rho1 * r)
        if np.max(np.abs(g)) < 1e-8:
            break
        H = J.T @ (curv[:, None] * J)
        eigval, eigvec = np.linalg.eigh(H)
        g_eig = eigvec.T @ g
        while evaluations < max_evaluations:
            step, lam = _trust_region_step(eigval, eigvec, g_eig, radius, lam)
            predicted = -float(g @ step) - 0.5 * float(step @ H @ step)
            r_new, J_new = fun_jac(x + step)
            evaluations += 1
            step_norm = float(np.linalg.norm(step))
            if not np.all(np.isfinite(r_new)):
                radius = 0.25 * step_norm
                continue
            rho_new, rho1_new, curv_new = robust_loss(r_new, loss, f_scale)
            cost_new = 0.5 * float(rho_new.sum())
            reduction = cost - cost_new
            if predicted > 0:
                ratio = reduction / predicted
            else:
                ratio = 1.0 if predicted == reduction == 0 else 0.0
            new_radius = radius
            if ratio < 0.25:
                new_radius = 0.25 * step_norm
            elif ratio > 0.75 and step_norm > 0.95 * radius:
                new_radius = 2.0 * radius
            done = (reduction < ftol * cost and ratio > 0.25) or step_norm < xtol * (xtol + np.linalg.norm(x))
            if not done:
                lam *= radius / new_radius
                radius = new_radius
            if reduction > 0:
                x, r, J, cost, rho1, curv = x + step, r_new, J_new, cost_new, rho1_new, curv_new
            if done:
                return x, cost, r
            if reduction > 0:
                break
    return x, cost, r


def _trust_region_step(
    eigval: np.ndarray, eigvec: np.ndarray, g_eig: np.ndarray, radius: float, lam: float
) -> tuple[np.ndarray, float]:
    """argmin of g.p + 0.5 p.H.p over |p| <= radius, H = eigvec diag(eigval) eigvec^T, g =
    eigvec g_eig: the Gauss-Newton step if it fits, else the damped step (H + lam I) p = -g whose
    length is the radius to 1 %, lam found by Newton's method on 1/|p| (More & Sorensen), started
    from the previous lam. Returns (p, lam)."""
    eigval = np.maximum(eigval, 0.0)
    if eigval[0] > 1e-12 * max(eigval[-1], 1e-300):
        p = g_eig / eigval
        if np.linalg.norm(p) <= radius:
            return -(eigvec @ p), 0.0
    lam = max(lam, 1e-12 * max(eigval[-1], 1e-300))
    for _ in range(30):
        d = eigval + lam
        p_norm = float(np.linalg.norm(g_eig / d))
        if abs(p_norm - radius) <= 0.01 * radius:
            break
        q_norm2 = float(np.sum(g_eig**2 / d**3))
        lam = max(lam + (p_norm / radius - 1.0) * p_norm**2 / q_norm2, 0.1 * lam)
    return -(eigvec @ (g_eig / (eigval + lam))), lam


_GOLDEN = 0.5 * (3.0 - math.sqrt(5.0))


def minimize_bounded(
    f: Callable[[float], float], lo: float, hi: float, xatol: float = 1e-5
) -> tuple[float, float]:
    """(x, f(x)) at a local minimum of ``f`` on [lo, hi]: Brent's method (golden sections and
    parabolic steps), step for step the algorithm of SciPy's ``minimize_scalar(method="bounded",
    options={"xatol": xatol})``, so it evaluates ``f`` at the same points and returns the same x."""
    sqrt_eps = math.sqrt(2.2e-16)
    a, b = lo, hi
    v = w = x = a + _GOLDEN * (b - a)
    fv = fw = fx = f(x)
    d = e = 0.0
    xm = 0.5 * (a + b)
    tol1 = sqrt_eps * abs(x) + xatol / 3.0
    tol2 = 2.0 * tol1
    for _ in range(500):
        if abs(x - xm) <= tol2 - 0.5 * (b - a):
            break
        golden = True
        if abs(e) > tol1:  # try a parabola through x, w, v
            golden = False
            r = (x - w) * (fx - fv)
            q = (x - v) * (fx - fw)
            p = (x - v) * q - (x - w) * r
            q = 2.0 * (q - r)
            if q > 0.0:
                p = -p
            q = abs(q)
            r, e = e, d
            if abs(p) < abs(0.5 * q * r) and q * (a - x) < p < q * (b - x):
                d = p / q
                u = x + d
                if u - a < tol2 or b - u < tol2:
                    d = tol1 if xm >= x else -tol1
            else:
                golden = True
        if golden:
            e = (a - x) if x >= xm else (b - x)
            d = _GOLDEN * e
        u = x + (1.0 if d >= 0 else -1.0) * max(abs(d), tol1)
        fu = f(u)
        if fu <= fx:
            if u >= x:
                a = x
            else:
                b = x
            v, fv, w, fw, x, fx = w, fw, x, fx, u, fu
        else:
            if u < x:
                a = u
            else:
                b = u
            if fu <= fw or w == x:
                v, fv, w, fw = w, fw, u, fu
            elif fu <= fv or v == x or v == w:
                v, fv = u, fu
        xm = 0.5 * (a + b)
        tol1 = sqrt_eps * abs(x) + xatol / 3.0
        tol2 = 2.0 * tol1
    return x, fx
