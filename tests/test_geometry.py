"""Pose, triangulation and depth scale/offset fit on points with known geometry."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from geofill.camera import Intrinsics, make_pose, pose_errors_deg
from geofill.config import GeometryConfig, MatchingConfig
from geofill.depth import DepthPrediction
from geofill.depth.align import align_depth, fit_affine, sample_at
from geofill.match import Matches
from geofill.pose import estimate_pose
from geofill.triangulate import TriangulatedPoints, project, triangulate

K_T = Intrinsics.from_focal(700.0, 960, 540)
K_S = Intrinsics.from_focal(820.0, 800, 600)  # different size and focal: each image has its own K


def scene_points(n: int, rng: np.random.Generator) -> np.ndarray:
    """Points in the source frame, 4-12 units in front, spread over the field of view."""
    z = rng.uniform(4.0, 12.0, n)
    x = rng.uniform(-0.45, 0.45, n) * z
    y = rng.uniform(-0.3, 0.3, n) * z
    return np.stack([x, y, z], axis=1)


def make_matches(T: np.ndarray, n: int = 400, noise_px: float = 0.3, seed: int = 0):
    rng = np.random.default_rng(seed)
    X = scene_points(n, rng)
    Xt = X @ T[:3, :3].T + T[:3, 3]
    uv_s = project(X, K_S) + rng.normal(0, noise_px, (n, 2))
    uv_t = project(Xt, K_T) + rng.normal(0, noise_px, (n, 2))
    return Matches(uv_t, uv_s, None, n, n, n), X


def test_pose_recovered_within_tolerance():
    T = make_pose(Rotation.from_euler("xyz", [2.0, -6.0, 1.0], degrees=True).as_matrix(), [0.6, 0.1, 0.15])
    m, _ = make_matches(T)
    est = estimate_pose(m, K_T, K_S, GeometryConfig(), MatchingConfig())
    assert est.status == "ok"
    r_err, t_err = pose_errors_deg(est.T, T)
    assert r_err < 0.5
    assert t_err < 2.0
    assert np.isclose(np.linalg.norm(est.T[:3, 3]), 1.0)
    assert est.n_inliers > 0.9 * len(m)


def test_pose_rejects_outliers():
    T = make_pose(Rotation.from_euler("y", -4.0, degrees=True).as_matrix(), [0.5, 0.0, 0.1])
    m, _ = make_matches(T, n=300)
    rng = np.random.default_rng(1)
    bad = rng.choice(300, 90, replace=False)
    m.pts_source[bad] = rng.uniform([0, 0], [800, 600], (90, 2))
    est = estimate_pose(m, K_T, K_S, GeometryConfig(), MatchingConfig())
    r_err, t_err = pose_errors_deg(est.T, T)
    assert r_err < 0.5 and t_err < 2.0
    assert est.inliers[bad].mean() < 0.1  # nearly all planted outliers rejected


def test_pure_rotation_detected_and_rotation_recovered():
    R = Rotation.from_euler("xyz", [1.0, 5.0, -2.0], degrees=True).as_matrix()
    m, _ = make_matches(make_pose(R, np.zeros(3)))
    est = estimate_pose(m, K_T, K_S, GeometryConfig(), MatchingConfig())
    assert est.status == "rotation_only"
    assert "rotation" in est.reason
    assert np.allclose(est.T[:3, 3], 0.0)
    assert pose_errors_deg(est.T, make_pose(R, np.zeros(3)))[0] < 0.2


def test_too_few_matches_fail_with_reason():
    T = make_pose(np.eye(3), [1.0, 0, 0])
    m, _ = make_matches(T, n=10)
    est = estimate_pose(m, K_T, K_S, GeometryConfig(), MatchingConfig())
    assert est.status == "failed" and not est.usable
    assert "too few" in est.reason


def test_midpoint_triangulation_is_exact_without_noise():
    T = make_pose(Rotation.from_euler("y", -5.0, degrees=True).as_matrix(), [0.8, 0.0, 0.1])
    m, X = make_matches(T, noise_px=0.0)
    pts = triangulate(m.pts_source, m.pts_target, K_S, K_T, T, GeometryConfig())
    assert len(pts) == len(X)
    np.testing.assert_allclose(pts.xyz_source, X, rtol=1e-8)
    assert pts.reprojection_px.max() < 1e-6


def test_triangulation_drops_points_behind_cameras_and_large_errors():
    T = make_pose(np.eye(3), [1.0, 0.0, 0.0])
    m, _ = make_matches(T, n=50, noise_px=0.0)
    m.pts_source[:5] = m.pts_target[:5] + [40.0, 0.0]  # rays diverge: intersection behind the cameras
    m.pts_source[5:10, 1] += 30.0  # off the epipolar line: large reprojection error
    pts = triangulate(m.pts_source, m.pts_target, K_S, K_T, T, GeometryConfig(max_reprojection_px=4.0))
    assert len(pts) == 40
    assert (pts.depth > 0).all()


@pytest.mark.parametrize("robust", [False, True])
def test_affine_fit_recovers_known_map(robust):
    rng = np.random.default_rng(3)
    x = rng.uniform(0.1, 2.0, 200)
    y = 2.5 * x - 0.3 + rng.normal(0, 1e-4, 200)
    s, b = fit_affine(x, y, robust)
    assert s == pytest.approx(2.5, abs=1e-3) and b == pytest.approx(-0.3, abs=1e-3)


def test_robust_fit_ignores_outliers_that_break_least_squares():
    rng = np.random.default_rng(4)
    x = rng.uniform(0.1, 2.0, 200)
    y = 2.5 * x - 0.3
    y[:20] += rng.uniform(3, 6, 20)  # 10 % gross outliers
    s_ls, _ = fit_affine(x, y, robust=False)
    s_rb, b_rb = fit_affine(x, y, robust=True)
    assert abs(s_ls - 2.5) > 0.05
    assert s_rb == pytest.approx(2.5, abs=0.02) and b_rb == pytest.approx(-0.3, abs=0.03)


def test_sample_at_is_bilinear_clamped_and_propagates_nan():
    # v = 2x + 3y is reproduced exactly by bilinear interpolation; positions outside clamp to the border.
    yy, xx = np.mgrid[0:5, 0:7].astype(np.float32)
    v = 2 * xx + 3 * yy
    uv = np.array([[0.0, 0.0], [2.25, 1.5], [6.0, 4.0], [-3.0, 1.0], [9.0, 7.5], [5.5, 3.75]])
    np.testing.assert_allclose(sample_at(v, uv), [0.0, 9.0, 24.0, 3.0, 24.0, 22.25], atol=1e-6)
    v[2, 3] = np.nan  # every position whose four taps include (x=3, y=2) is NaN, the others are not
    out = sample_at(v, np.array([[3.0, 2.0], [2.5, 1.5], [3.5, 2.5], [1.0, 1.0], [4.0, 3.0]]))
    assert np.isnan(out[:3]).all() and np.isfinite(out[3:]).all()


def points_on(z: np.ndarray, n: int = 100) -> TriangulatedPoints:
    """``n`` triangulated points at random pixels of the depth map ``z``, at its depth there."""
    h, w = z.shape
    rng = np.random.default_rng(0)
    uv = np.stack([rng.integers(0, w, n), rng.integers(0, h, n)], axis=1).astype(np.float64)
    zs = z[uv[:, 1].astype(int), uv[:, 0].astype(int)].astype(np.float64)
    xyz = np.stack([np.zeros(n), np.zeros(n), zs], axis=1)
    return TriangulatedPoints(xyz, uv, uv, np.zeros(n), np.ones(n))


def test_align_depth_inverse_space_recovers_true_depth():
    """A relative inverse-depth map (a / z + c) is aligned to triangulated depths exactly."""
    h, w = 60, 80
    z_true = np.linspace(3.0, 9.0, w, dtype=np.float32)[None].repeat(h, 0)
    pred = DepthPrediction((0.7 / z_true + 0.05).astype(np.float32), "inverse", "test")
    out = align_depth(pred, points_on(z_true), GeometryConfig(depth_fit="lstsq"))
    assert out.space == "inverse"
    np.testing.assert_allclose(out.depth, z_true, rtol=1e-4)
    assert out.scale == pytest.approx(1 / 0.7, rel=1e-4)
    assert out.offset == pytest.approx(-0.05 / 0.7, rel=1e-3)
    assert out.negative_fraction == 0.0


@pytest.mark.parametrize("unit", [1e-40, 1e30])
def test_align_depth_takes_a_map_in_any_unit_without_overflow(unit):
    """A depth map in a unit so small that its inverse overflows float32 (1 / 1e-40 > 3.4e38), or
    so large, is aligned like the same map in metres, with no numeric warning; the scale reported
    applies to the map's own values."""
    h, w = 60, 80
    z_true = np.linspace(3.0, 9.0, w, dtype=np.float32)[None].repeat(h, 0)
    values = (z_true.astype(np.float64) * unit).astype(np.float32)
    values[0, :3] = [3e38, 1e-45, np.inf]  # outliers far beyond float32 once brought near 1
    pred = DepthPrediction(values, "depth", "test")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = align_depth(pred, points_on(z_true), GeometryConfig(depth_fit="lstsq"))
    assert out.space == "inverse" and out.n_points >= 97
    # inf has no depth, nor 3e38 where it overflows float32 in the map's unit (1e-40: 3e78 units);
    # 1e-45 is just very near.
    assert np.isnan(out.depth[0, 2]) and (np.isnan(out.depth[0, 0]) or unit > 1)
    np.testing.assert_allclose(out.depth[1:], z_true[1:], rtol=1e-3)
    assert out.scale == pytest.approx(unit, rel=1e-3)  # 1 / z = unit / v
    assert abs(out.offset) < 1e-5


def test_matching_keeps_no_duplicate_correspondences_and_no_hole_keypoints():
    from geofill.config import MatchingConfig as MC
    from geofill.match import match_pair
    from geofill.synthetic import make_pair

    p = make_pair(seed=4, width=320, height=240)
    m = match_pair(p.target, p.source, p.hole, MC())
    pairs = np.concatenate([m.pts_target, m.pts_source], axis=1)
    assert len(np.unique(pairs, axis=0)) == len(m) > 100
    xy = np.rint(m.pts_target).astype(int)
    assert not p.hole[xy[:, 1], xy[:, 0]].any()
