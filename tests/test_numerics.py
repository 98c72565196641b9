"""The routines written out instead of SciPy's (geofill.utils.numerics, the rotation helpers of
geofill.camera) give SciPy's answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares, minimize_scalar
from scipy.spatial.transform import Rotation

from geofill.camera import quaternion_wxyz, rotation_from_rotvec
from geofill.utils.numerics import minimize_bounded, robust_cost, robust_least_squares, robust_linear_fit


def colour_samples(seed: int, gain: float, offset: float, outliers: float = 0.2, n: int = 4000):
    """A band's (render, target) intensities: target = gain * render + offset with noise and a
    fraction of gross outliers (occluders)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.0, 1.0, n)
    y = gain * x + offset + rng.normal(0.0, 0.02, n)
    bad = rng.random(n) < outliers
    y[bad] += rng.normal(0.0, 0.3, bad.sum())
    return x, y


@pytest.mark.parametrize("loss", ["soft_l1", "huber", "linear"])
@pytest.mark.parametrize(
    ("gain", "offset"),
    [(1.3, 0.05), (0.9, -0.1), (3.6, 0.1), (0.2, -0.7)],  # last two: a gain / both bounds active
)
def test_robust_linear_fit_matches_least_squares_with_bounds(loss, gain, offset):
    x, y = colour_samples(0, gain, offset)
    A = np.column_stack([x, np.ones_like(x)])
    lower, upper = np.array([1 / 3, -0.5]), np.array([3.0, 0.5])
    ours = robust_linear_fit(A, y, loss, 0.03, lower, upper, x0=np.array([1.0, 0.0]))
    ref = least_squares(lambda p: A @ p - y, [1.0, 0.0], loss=loss, f_scale=0.03, bounds=(lower, upper))
    assert ours == pytest.approx(ref.x, abs=1e-7)
    assert np.all(ours >= lower) and np.all(ours <= upper)
    assert robust_cost(A @ ours - y, loss, 0.03) == pytest.approx(ref.cost, rel=1e-9)


def test_robust_linear_fit_weighted_one_parameter_huber():
    # The depth fit's case: a weighted scale-only fit, weights as square roots on the rows.
    x, y = colour_samples(1, 2.0, 0.0, outliers=0.3)
    w = np.sqrt(np.random.default_rng(2).uniform(0.1, 1.0, x.size))
    ours = robust_linear_fit(x[:, None] * w[:, None], y * w, "huber", 0.05)
    ref = least_squares(lambda p: w * (p[0] * x - y), [1.0], loss="huber", f_scale=0.05)
    assert ours[0] == pytest.approx(ref.x[0], abs=1e-9)


def test_robust_least_squares_matches_trf_on_a_nonlinear_fit():
    # y = a exp(-b t) + c with outliers: soft-L1, analytic Jacobian, started far off.
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 5.0, 300)
    y = 2.5 * np.exp(-1.3 * t) + 0.4 + rng.normal(0.0, 0.02, t.size)
    y[rng.random(t.size) < 0.15] += 1.0

    def fun(p):
        return p[0] * np.exp(-p[1] * t) + p[2] - y

    def jac(p):
        e = np.exp(-p[1] * t)
        return np.column_stack([e, -p[0] * t * e, np.ones_like(t)])

    x, cost, res = robust_least_squares(
        lambda p: (fun(p), jac(p)), np.array([1.0, 0.5, 0.0]), "soft_l1", 0.05
    )
    ref = least_squares(fun, [1.0, 0.5, 0.0], jac=jac, loss="soft_l1", f_scale=0.05)
    assert x == pytest.approx(ref.x, abs=1e-6)
    assert cost == pytest.approx(ref.cost, rel=1e-9)
    assert res == pytest.approx(fun(x))


@pytest.mark.parametrize("bounds", [(-1.0, 2.0), (0.5, 0.6), (-3.0, -2.0)])
def test_minimize_bounded_evaluates_what_scipy_evaluates(bounds):
    calls: dict[str, list[float]] = {"ours": [], "scipy": []}

    def f(x, who):
        calls[who].append(x)
        return (x - 0.3) ** 2 + 0.1 * np.sin(5.0 * x)

    x, fx = minimize_bounded(lambda v: f(v, "ours"), *bounds, xatol=3e-3)
    ref = minimize_scalar(lambda v: f(v, "scipy"), bounds=bounds, method="bounded", options={"xatol": 3e-3})
    assert calls["ours"] == calls["scipy"]
    assert (x, fx) == (ref.x, ref.fun)


def test_rotation_helpers_match_scipy_rotation():
    rng = np.random.default_rng(4)
    for magnitude in (1e-9, 1e-4, 0.1, 1.0, 3.1):
        for _ in range(50):
            w = rng.normal(size=3) * magnitude
            rot = Rotation.from_rotvec(w)
            assert rotation_from_rotvec(w) == pytest.approx(rot.as_matrix(), abs=1e-14)
            x, y, z, q = Rotation.from_matrix(rot.as_matrix()).as_quat()  # what params.py used
            assert quaternion_wxyz(rot.as_matrix()) == pytest.approx([q, x, y, z], abs=1e-14)
    # Half turns: every branch of the quaternion's construction.
    for axis in np.eye(3):
        R = Rotation.from_rotvec(np.pi * axis).as_matrix()
        x, y, z, q = Rotation.from_matrix(R).as_quat()
        assert quaternion_wxyz(R) == pytest.approx([q, x, y, z])
