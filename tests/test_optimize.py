"""Joint pose-depth optimisation: losses, weight maps, projection, convergence test, both solvers,
guard rails and focal refinement, on hand-made arrays and synthetic scenes with exact ground truth."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import geofill.optimize as opt
from geofill.camera import Intrinsics, default_focal_px, pose_errors_deg
from geofill.config import FillConfig, OptimizeConfig
from geofill.depth.align import AlignedDepth
from geofill.match import match_pair
from geofill.optimize import fast_solver as opt_fast
from geofill.optimize import params as opt_params
from geofill.optimize import stage as opt_stage
from geofill.optimize.importance import edge_maps, edge_weight, hole_weight, importance_map
from geofill.pipeline import fill, render_margin_px
from geofill.render import project_source_grid, render_mesh, render_roi
from geofill.synthetic import blanked, make_pair

# ---------------------------------------------------------------------------------------------
# Losses


@pytest.mark.needs("torch")
def test_barron_alpha_minus_two_is_geman_mcclure():
    import torch

    x = torch.tensor([0.0, 0.5, 3.0, 10.0, 25.0, 400.0], dtype=torch.float64)
    u = (x / 10.0) ** 2
    got = opt.barron_loss(x * x, -2.0, 10.0)
    assert torch.allclose(got, 2 * u / (u + 4), rtol=1e-12, atol=0)
    assert float(got[-1]) < 2.0  # bounded: an outlier costs at most 2
    # The limits the general formula cannot evaluate: L2 and Cauchy.
    assert torch.allclose(opt.barron_loss(x * x, 2.0, 10.0), 0.5 * u)
    assert torch.allclose(opt.barron_loss(x * x, 0.0, 10.0), torch.log(0.5 * u + 1))


@pytest.mark.needs("torch")
@pytest.mark.parametrize("alpha", [-2.0, 0.0, 1.0, 2.0])
def test_barron_weight_is_the_derivative_in_x_squared(alpha):
    import torch

    sq = torch.tensor([0.1, 4.0, 90.0, 1000.0], dtype=torch.float64, requires_grad=True)
    (grad,) = torch.autograd.grad(opt.barron_loss(sq, alpha, 10.0).sum(), sq)
    assert torch.allclose(opt.barron_weight(sq.detach(), alpha, 10.0), grad, rtol=1e-10)


def _flat_problem(target, hole, source, values, cfg, K=None):
    """A one-level problem between two images of the same camera (no features)."""
    h, w = hole.shape
    K = K or Intrinsics.from_focal(50.0, w, h)
    none = np.zeros((0, 2))
    return opt.build_problem(target, hole, source, values, "inverse", K, K, none, none, cfg)


def _identity():
    return opt.PoseDepthParams(np.eye(3), np.zeros(3))


def test_photo_loss_ignores_hole_colours_and_normalises_by_known_area():
    rng = np.random.default_rng(0)
    h, w = 24, 32
    image = rng.uniform(0.2, 0.8, (h, w, 3)).astype(np.float32)
    hole = np.zeros((h, w), bool)
    hole[5:12, 6:15] = True
    values = np.ones((h, w), np.float32)
    cfg = OptimizeConfig(pyramid_levels=1, use_hole_weight=False, use_edge_weight=False, use_feat=False)
    target = image.copy()
    target[hole] = rng.uniform(0, 1, (int(hole.sum()), 3))  # garbage where the object was
    # Identity pose, same camera: every source pixel lands on itself.
    assert float(opt.evaluate(_flat_problem(target, hole, image, values, cfg), _identity()).photo) < 1e-10
    target[20, 25, 1] += 0.5  # one known pixel differs by 0.5 in one channel
    photo = float(opt.evaluate(_flat_problem(target, hole, image, values, cfg), _identity()).photo)
    assert photo == pytest.approx(0.25 / (h * w - hole.sum()), rel=1e-4)


def test_negative_depth_hinge_sums_over_pixels():
    h, w = 16, 16
    image = np.full((h, w, 3), 0.5, np.float32)
    hole = np.zeros((h, w), bool)
    hole[0, 0] = True
    values = np.linspace(0.1, 1.0, h * w, dtype=np.float32).reshape(h, w)
    cfg = OptimizeConfig(pyramid_levels=1, use_feat=False)
    problem = _flat_problem(image, hole, image, values, cfg)
    p = replace(_identity(), scale=1.0, offset=-0.4)  # s v + b < 0 where v < 0.4
    expected = np.maximum(0.0, 0.4 - values.astype(np.float64)).sum()
    terms = opt.evaluate(problem, p)
    assert float(terms.negd) == pytest.approx(expected, rel=1e-5)
    assert float(terms.total) == pytest.approx(10 * float(terms.photo) + 0.5 * expected, rel=1e-6)
    off = opt.evaluate(replace(problem, cfg=replace(cfg, use_negd=False)), p)
    assert float(off.negd) == 0.0


# ---------------------------------------------------------------------------------------------
# Weight maps


def test_hole_weight_is_gaussian_of_distance():
    hole = np.zeros((40, 120), bool)
    hole[:, :10] = True  # the last hole column is 9
    wh = hole_weight(hole, sigma_px=20.0)
    assert np.all(wh[:, :10] == 1.0)
    assert wh[7, 29] == pytest.approx(math.exp(-0.5), rel=1e-5)  # 20 px from the hole
    assert wh[7, 49] == pytest.approx(math.exp(-2.0), rel=1e-5)


def test_edge_weight_normalises_each_map_and_skips_empty_ones():
    a = np.zeros((10, 10), bool)
    a[2, :] = True
    b = np.zeros((10, 10), bool)
    b[:, 3:5] = True
    we = edge_weight([a, b, np.zeros((10, 10), bool)])
    assert we.sum() == pytest.approx(2.0)
    assert we[2, 3] == pytest.approx(1 / 10 + 1 / 20)
    assert we[2, 0] == pytest.approx(1 / 10) and we[0, 3] == pytest.approx(1 / 20) and we[0, 0] == 0


def test_edges_follow_the_image_not_the_hole_border():
    h, w = 120, 160
    image = np.full((h, w, 3), 90, np.uint8)
    image[:, 110:] = 200  # one vertical step edge at x = 109.5
    hole = np.zeros((h, w), bool)
    hole[30:90, 20:70] = True
    image[hole] = 0  # a black hole: its border must not count as an edge
    maps = edge_maps(image, hole, [3, 7, 15, 31], 4, 90.0, 0.4)
    for e in maps:
        xs = np.nonzero(e)[1]
        assert xs.size and xs.min() >= 104 and xs.max() <= 114
    W = importance_map(image, hole, OptimizeConfig(), px_scale=0.125)
    assert W[:, :100].max() == 0.0 and W[:, 105:115].max() > 0


# ---------------------------------------------------------------------------------------------
# Projection


@pytest.mark.parametrize("space", ["inverse", "depth"])
def test_projection_matches_render_projection(space):
    rng = np.random.default_rng(1)
    h, w = 30, 40
    depth = rng.uniform(1.0, 5.0, (h, w))
    K_s = Intrinsics(60.0, 62.0, 19.0, 15.5, w, h)
    K_t = Intrinsics(55.0, 54.0, 21.0, 14.0, w, h)
    R = Rotation.from_rotvec([0.05, -0.1, 0.02]).as_matrix()
    t = np.array([0.3, -0.1, 0.2])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    u_ref, v_ref, _ = project_source_grid(depth, K_s, K_t, T)
    jj, ii = np.meshgrid(np.arange(w), np.arange(h))
    px = np.stack([jj.ravel(), ii.ravel()], 1).astype(np.float64)
    values = depth.ravel() if space == "depth" else 1.0 / depth.ravel()
    pts = opt.Points.from_pixels(px, K_s, values)
    x, y = opt.project(*opt.array_params(opt.PoseDepthParams(R, t)), pts, K_t, space)
    assert np.allclose(x, u_ref.ravel(), atol=2e-3)
    assert np.allclose(y, v_ref.ravel(), atol=2e-3)


@pytest.mark.parametrize("space", ["inverse", "depth"])
def test_analytic_jacobian_matches_finite_differences(space):
    rng = np.random.default_rng(2)
    K_s = Intrinsics(300.0, 300.0, 160.0, 120.0, 320, 240)
    K_t = Intrinsics(310.0, 305.0, 150.0, 125.0, 320, 240)
    px = rng.uniform(0, [320, 240], (50, 2))
    values = rng.uniform(0.2, 1.0, 50) if space == "inverse" else rng.uniform(1.0, 5.0, 50)
    pts = opt.Points.from_pixels(px, K_s, values)
    p = opt.PoseDepthParams(
        Rotation.from_rotvec([0.02, 0.1, -0.03]).as_matrix(), np.array([0.6, 0.1, 0.2]), 1.1, 0.05, 0.1
    )
    chart = opt_fast._Chart(p, with_focal=True)
    r = chart.reproject(pts, K_t, space)
    Jx, Jy = chart.jacobian(r, pts, K_t, space)
    gx, gy = rng.normal(size=(2, 50)).astype(np.float32)
    raw = opt.reprojection_vjp(r, pts, K_t, space, chart.R, chart.t, p.log_focal, gx, gy)
    g = chart.gradient(raw)  # J^T v without the Jacobian
    assert np.allclose(g, (Jx.T @ gx + Jy.T @ gy).astype(np.float64), rtol=1e-4, atol=1e-3)
    pts64 = opt.Points(pts.rays.astype(np.float64), pts.value.astype(np.float64))

    def xy(d):
        q = chart.retract(d)
        args = [np.asarray(v, np.float64) for v in (q.R, q.t, q.scale, q.offset, q.log_focal)]
        return np.stack(opt.project(*args, pts64, K_t, space), 1)

    eps = 1e-6
    for i in range(chart.n):
        d = np.zeros(chart.n)
        d[i] = eps
        fd = (xy(d) - xy(-d)) / (2 * eps)
        assert np.allclose(Jx[:, i], fd[:, 0], rtol=1e-3, atol=1e-2), i
        assert np.allclose(Jy[:, i], fd[:, 1], rtol=1e-3, atol=1e-2), i


@pytest.mark.needs("torch")
def test_quaternion_to_matrix_matches_scipy():
    import torch

    rot = Rotation.from_rotvec([0.3, -1.2, 0.5])
    x, y, z, w = rot.as_quat()
    q = torch.tensor([w, x, y, z], dtype=torch.float64) * 3.0  # not normalised on purpose
    assert np.allclose(opt.quaternion_to_matrix(q).numpy(), rot.as_matrix(), atol=1e-12)


@pytest.mark.needs("torch")
@pytest.mark.parametrize("space", ["inverse", "depth"])
def test_reprojection_vjp_equals_autograd_through_the_projection(space):
    import torch

    rng = np.random.default_rng(3)
    K_s = Intrinsics(300.0, 300.0, 160.0, 120.0, 320, 240)
    K_t = Intrinsics(310.0, 305.0, 150.0, 125.0, 320, 240)
    values = rng.uniform(0.2, 1.0, 200) if space == "inverse" else rng.uniform(1.0, 5.0, 200)
    pts = opt.Points.from_pixels(rng.uniform(0, [320, 240], (200, 2)), K_s, values)
    gx, gy = rng.normal(size=(2, 200)).astype(np.float32)
    x, y, z, w = Rotation.from_rotvec([0.05, -0.1, 0.02]).as_quat()
    q = torch.tensor([w, x, y, z], dtype=torch.float64, requires_grad=True)
    rest = [
        torch.tensor(v, dtype=torch.float64, requires_grad=True) for v in ([0.6, 0.1, 0.2], 1.1, 0.05, 0.1)
    ]
    R = opt.quaternion_to_matrix(q)
    args = [R.float(), *(v.float() for v in rest)]
    px, py = opt.project(*args, opt.Points(*map(torch.from_numpy, (pts.rays, pts.value))), K_t, space)
    (torch.from_numpy(gx) * px + torch.from_numpy(gy) * py).sum().backward()
    mine_args = [a.detach().numpy() for a in args]
    r = opt_params.reproject_points(*mine_args, pts, K_t, space)
    raw = opt.reprojection_vjp(r, pts, K_t, space, mine_args[0], mine_args[1], 0.1, gx, gy)
    (gq,) = torch.autograd.grad(opt.quaternion_to_matrix(q), q, torch.from_numpy(raw.R))
    mine_all = [gq.numpy(), raw.t, raw.scale, raw.offset, raw.log_focal]
    for mine, leaf in zip(mine_all, [q, *rest], strict=True):
        want = leaf.grad.numpy()
        assert np.allclose(mine, want, rtol=1e-3, atol=1e-4 * float(np.abs(want).max()))


# ---------------------------------------------------------------------------------------------
# Convergence test (supplement)


def test_convergence_compares_the_last_two_half_windows():
    assert not opt.converged([1.0] * 9, 10, 1e-6)  # fewer than m values
    assert opt.converged([1.0] * 10, 10, 1e-6)
    # |5 (1 + d) - 5| / (5 (1 + d)) = d / (1 + d)
    assert not opt.converged([1.0] * 5 + [1.0 + 2e-6] * 5, 10, 1e-6)
    assert opt.converged([1.0] * 5 + [1.0 + 5e-7] * 5, 10, 1e-6)
    assert opt.converged([9.0] * 5 + [1.0] * 10, 10, 1e-6)  # only the last m values count


# ---------------------------------------------------------------------------------------------
# Solvers on a synthetic scene with exact depth and a perturbed start


@pytest.fixture(scope="module")
def scene():
    sp = make_pair(seed=1, width=320, height=240)
    target, source = sp.target.astype(np.float32) / 255, sp.source.astype(np.float32) / 255
    m = match_pair(target, source, sp.hole, FillConfig().matching, 0.25)
    T = sp.T_source_to_target.copy()
    baseline = np.linalg.norm(T[:3, 3])
    T[:3, 3] /= baseline
    K = Intrinsics.from_matrix(sp.K_target, 320, 240)
    return sp, target, source, m, T, sp.depth_source / baseline, K


def _perturbed_start(T, depth, rot_deg=4.0, tdir_deg=8.0, depth_factor=1.15):
    T0 = T.copy()
    T0[:3, :3] = (
        Rotation.from_rotvec(np.radians(rot_deg) * np.array([0.6, -0.8, 0.0])).as_matrix() @ T[:3, :3]
    )
    axis = np.cross(T[:3, 3], [0.0, 1.0, 0.0])
    T0[:3, 3] = (
        Rotation.from_rotvec(np.radians(tdir_deg) * axis / np.linalg.norm(axis)).as_matrix() @ T[:3, 3]
    )
    d0 = AlignedDepth((depth * depth_factor).astype(np.float32), 1.0, 0.0, "inverse", "gt", 0, 0.0, 0.0)
    return T0, d0


def _run(scene, cfg, T0, d0):
    sp, target, source, m, _, _, K = scene
    return opt.optimize_pose_depth(target, sp.hole, source, K, K, T0, d0, m.pts_target, m.pts_source, cfg)


def test_fast_solver_recovers_a_perturbed_pose_and_depth_scale(scene):
    T, depth = scene[4], scene[5]
    T0, d0 = _perturbed_start(T, depth)
    assert pose_errors_deg(T0, T)[0] == pytest.approx(4.0)
    res = _run(scene, OptimizeConfig(), T0, d0)
    rep = res.report
    assert rep.status == "accepted" and rep.final_objective < 0.05 * rep.initial_objective
    rot, tdir = pose_errors_deg(res.T, T)
    assert rot < 0.3 and tdir < 2.0
    assert res.params.scale == pytest.approx(1.15, rel=0.02)  # inverse depth x1.15 undoes depth x1.15
    assert np.linalg.norm(res.T[:3, 3]) == pytest.approx(1.0)
    valid = np.isfinite(res.depth.depth)
    assert np.median(np.abs(res.depth.depth[valid] / depth[valid] - 1)) < 0.02


@pytest.mark.needs("torch", "pytorch_optimizer")
def test_fast_objective_no_worse_than_paper_solver(scene):
    T, depth = scene[4], scene[5]
    T0, d0 = _perturbed_start(T, depth, rot_deg=2.0, tdir_deg=4.0, depth_factor=1.1)
    paper = _run(scene, OptimizeConfig(solver="paper", paper_iterations=[100, 200, 300, 400]), T0, d0)
    fast = _run(scene, OptimizeConfig(), T0, d0)
    assert paper.report.status == "accepted"
    assert [lv["level"] for lv in paper.report.levels] == [3, 2, 1, 0]
    assert sum(lv["iterations"] for lv in paper.report.levels) <= 400
    assert paper.report.final_objective < 0.5 * paper.report.initial_objective
    assert fast.report.final_objective <= paper.report.final_objective
    assert fast.report.initial_objective == paper.report.initial_objective
    assert np.linalg.norm(paper.T[:3, 3]) == pytest.approx(1.0)  # renormalised after DiffGrad


def test_lm_step_lands_on_the_positive_depth_constraint():
    # 7 chart coordinates; the gradient pulls the offset b (index 6) down by 1.
    lin = opt_fast._Linearisation(np.eye(7)[6], np.eye(7), np.zeros((1, 7)), np.zeros((1, 7)))
    level = SimpleNamespace(value_range=(0.05, 2.0))
    p = replace(_identity(), t=np.array([1.0, 0, 0]), scale=1.0, offset=0.0)
    free = opt_fast._lm_step(lin, np.zeros(7), level, p, negd=False)
    assert free[6] == pytest.approx(-1.0)  # unconstrained: b = -1 makes s v + b < 0
    step = opt_fast._lm_step(lin, np.zeros(7), level, p, negd=True)
    floor = (p.scale + step[5]) * 0.05 + p.offset + step[6]
    assert floor == pytest.approx(0.0, abs=1e-12) and step[6] < 0  # as far as the constraint allows


def test_guard_rails():
    p = _identity()
    assert opt.guard(p, 2.0, 1.0) == ""
    assert "NaN" in opt.guard(replace(p, t=np.array([np.nan, 0, 0])), 2.0, 1.0)
    assert "NaN" in opt.guard(p, 2.0, float("nan"))
    assert "non-positive depth scale" in opt.guard(replace(p, scale=-0.5), 2.0, 1.0)
    assert "worse" in opt.guard(p, 1.0, 2.0)


def test_rejected_result_keeps_the_initial_geometry(scene, monkeypatch):
    T, depth = scene[4], scene[5]
    T0, d0 = _perturbed_start(T, depth)
    flipped = lambda problem, init: (replace(init, scale=-1.0), [])  # noqa: E731
    monkeypatch.setattr(opt_stage, "solve_fast", flipped)
    res = _run(scene, OptimizeConfig(), T0, d0)
    assert res.report.status == "rejected" and "depth scale" in res.report.reason
    assert res.T is T0 and res.depth is d0


def test_rotation_only_pose_is_skipped(scene):
    sp, target, source, m, _, depth, K = scene
    d0 = AlignedDepth(depth.astype(np.float32), 1.0, 0.0, "inverse", "gt", 0, 0.0, 0.0)
    res = opt.optimize_pose_depth(
        target, sp.hole, source, K, K, np.eye(4), d0, m.pts_target, m.pts_source, OptimizeConfig()
    )
    assert res.report.status == "skipped" and "rotation-only" in res.report.reason


# ---------------------------------------------------------------------------------------------
# Pipeline and focal refinement


def test_pipeline_renders_with_the_optimised_geometry():
    sp = make_pair(seed=2, width=320, height=240)
    target = blanked(sp.target, sp.hole)  # nothing to remove: the render is the mesh's, uncut
    res = fill(target, sp.hole, sp.source)
    o, art = res.report.references[0]["optimize"], res.references[0]
    assert o["status"] == "accepted" and o["final_objective"] <= o["initial_objective"]
    assert o["rotation_change_deg"] > 0 and "optimize" in res.report.timings_s
    g = art.geometry  # working resolution == input resolution here
    roi = render_roi(sp.hole, int(render_margin_px(FillConfig()) * 320 / 1280))
    again = render_mesh(g.depth, g.K_source, g.K_target, g.T, 0.04, roi)
    assert np.array_equal(again.map_x, art.render.render.map_x)
    off = fill(target, sp.hole, sp.source, FillConfig().updated({"optimize.enabled": False}))
    assert off.report.references[0]["optimize"] == {
        "status": "skipped",
        "reason": "optimize.enabled is false",
    }


def test_focal_refinement_moves_towards_the_true_focal():
    w, h = 640, 480
    f_assumed = default_focal_px(w, h)
    f_true = 1.25 * f_assumed
    sp = make_pair(seed=1, width=w, height=h, focal_px=f_true)
    res = fill(sp.target, sp.hole, sp.source, FillConfig().updated({"optimize.refine_focal": True}))
    o = res.report.references[0]["optimize"]
    assert o["status"] == "accepted"
    f_refined = o["focal_target_px"]
    assert abs(math.log(f_refined / f_true)) < 0.5 * abs(math.log(f_assumed / f_true))
    assert res.references[0].geometry.K_source.origin == "refined"
    assert res.report.references[0]["intrinsics_target"]["origin"] == "refined"
    assert res.report.references[0]["intrinsics_target"]["fx_px"] == pytest.approx(f_refined)
