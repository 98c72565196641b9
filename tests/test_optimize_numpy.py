"""The fast solver without torch: the compiled bilinear sampler against ``grid_sample``, the NumPy
objective against the same code evaluated in torch, its hand-written gradient against autograd, and
a default fill that never imports torch."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import geofill.optimize as opt
from geofill.camera import Intrinsics
from geofill.config import OptimizeConfig
from geofill.optimize.objective import objective_gradient, project_all
from geofill.optimize.problem import sample_target_with_gradient

# torch: the reference side of these comparisons.
torch = pytest.importorskip("torch", reason="torch is not installed (the 'torch' extra)")


def test_sampler_and_its_derivative_equal_grid_sample_and_autograd():
    rng = np.random.default_rng(0)
    texture = rng.uniform(0, 1, (20, 30, 5)).astype(np.float32)
    # Inside, on the border, partly outside (taps outside count as zero) and far away.
    x = np.r_[rng.uniform(-1.5, 30.5, 400), 0.0, 29.0, 1e6].astype(np.float32)
    y = np.r_[rng.uniform(-1.5, 20.5, 400), 0.0, 19.0, 1e6].astype(np.float32)
    values, dx, dy = sample_target_with_gradient(texture, x, y)
    np.testing.assert_allclose(opt.sample_target(texture, x, y), values, rtol=0, atol=0)

    tx, ty = (torch.from_numpy(v).requires_grad_() for v in (x, y))
    want = opt.sample_target(torch.from_numpy(texture), tx, ty)
    np.testing.assert_allclose(values, want.detach().numpy(), atol=2e-6)
    assert np.count_nonzero(values[:, :400]) > 300 * 5 and not values[:, -1].any()
    for c in range(5):  # one channel at a time: the Jacobian is diagonal in the points
        gx, gy = torch.autograd.grad(want[c].sum(), [tx, ty], retain_graph=True)
        np.testing.assert_allclose(dx[c], gx.numpy(), atol=5e-5)
        np.testing.assert_allclose(dy[c], gy.numpy(), atol=5e-5)


def _problem(cfg: OptimizeConfig) -> tuple[opt.Problem, opt.PoseDepthParams]:
    """A two-level problem on smooth random images with 60 keypoints, and a start off the identity."""
    rng = np.random.default_rng(1)
    h, w = 60, 80
    base = rng.uniform(0, 1, (h // 4, w // 4, 3)).astype(np.float32)
    image = np.kron(base, np.ones((4, 4, 1), np.float32))
    hole = np.zeros((h, w), bool)
    hole[20:35, 30:50] = True
    values = rng.uniform(0.3, 1.0, (h, w)).astype(np.float32)
    K = Intrinsics.from_focal(70.0, w, h)
    pts_s = rng.uniform(2, [w - 3, h - 3], (60, 2))
    pts_t = pts_s + rng.normal(0, 2, (60, 2))
    problem = opt.build_problem(image, hole, image, values, "inverse", K, K, pts_t, pts_s, cfg)
    p = opt.PoseDepthParams(
        Rotation.from_rotvec([0.01, -0.02, 0.005]).as_matrix(), np.array([0.1, 0.02, 0.01]), 1.1, 0.02, 0.03
    )
    return replace(problem, prior_ref=0.7), p


CFG = OptimizeConfig(pyramid_levels=2, refine_focal=True, use_hole_weight=False)


def test_numpy_and_torch_evaluate_the_same_objective():
    problem, p = _problem(CFG)
    tproblem = problem.as_torch()
    for level in range(2):
        mine = opt.evaluate(problem, p, level).to_json()
        args = [torch.from_numpy(a) for a in opt.array_params(p)]
        tl = tproblem.levels[level]
        theirs = opt.objective(tproblem, tl, *project_all(tproblem, tl, *args), *args[2:]).to_json()
        assert mine["photo"] > 0 and mine["feat"] > 0 and mine["prior"] > 0
        for k, v in mine.items():
            assert v == pytest.approx(theirs[k], rel=1e-5, abs=1e-9), k


def test_written_out_gradient_equals_autograd():
    problem, p = _problem(CFG)
    level = problem.levels[0]
    x, y, xf, yf = project_all(problem, level, *opt.array_params(p))
    mine = objective_gradient(problem, level, x, y, xf, yf)

    tproblem = problem.as_torch()
    leaves = [torch.from_numpy(v).requires_grad_() for v in (x, y, xf, yf)]
    s, b, phi = (torch.from_numpy(a) for a in opt.array_params(p)[2:])
    total = opt.objective(tproblem, tproblem.levels[0], *leaves, s, b, phi).total
    theirs = torch.autograd.grad(total, leaves)
    for m, t in zip(mine, theirs, strict=True):
        t = t.numpy()
        assert np.abs(t).max() > 0
        np.testing.assert_allclose(m, t, rtol=1e-3, atol=1e-4 * np.abs(t).max())


def test_both_solvers_lower_the_objective_from_numpy_problem_data():
    problem, p = _problem(replace(CFG, paper_iterations=(3, 6)))
    start = float(opt.evaluate(problem, p).total)
    fast, _ = opt.solve_fast(problem, p)
    paper, logs = opt.solve_paper(problem, p)
    assert float(opt.evaluate(problem, fast).total) < start
    # The paper solver's first value on the coarse level is the start's (then DiffGrad improves it).
    assert 0 < logs[0].objective <= float(opt.evaluate(problem, p, 1).total) * (1 + 1e-5)
    assert np.isfinite(float(opt.evaluate(problem, paper).total))


_NO_TORCH = """
import sys
from geofill.synthetic import make_pair
from geofill.pipeline import fill
pair = make_pair(seed=0, width=320, height=240)
result = fill(pair.target, pair.hole, [pair.source])
assert result.report.status == "reference", result.report.status
optimize = result.report.references[0]["optimize"]
assert optimize["status"] == "accepted", optimize
loaded = sorted(m for m in sys.modules if m.split(".")[0] in ("torch", "pytorch_optimizer"))
assert not loaded, loaded[:5]
# scipy.ndimage parses its docstrings on import (~0.08 s): the fill's distance transform is its own.
assert "scipy.ndimage" not in sys.modules
print("ok")
"""


def test_default_fill_imports_neither_torch_nor_scipy_ndimage():
    out = subprocess.run([sys.executable, "-c", _NO_TORCH], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]
