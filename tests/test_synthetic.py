"""The synthetic oracle must be right before anything is tested against it: depth and pose are
checked end to end by reprojection (independently of the renderer's own visibility code), colours
agree across views, and SIFT matches the pair well."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from geofill.camera import default_focal_px, rotation_error_deg
from geofill.config import MatchingConfig
from geofill.match import match_pair
from geofill.synthetic import SyntheticPair, covisible, depth_edges, make_pair, make_scene


@pytest.fixture(scope="module")
def pair() -> SyntheticPair:
    return make_pair(0)


def _pixel_rays(width: int, height: int, K: np.ndarray) -> np.ndarray:
    xs, ys = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pix = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)], axis=1)
    return pix @ np.linalg.inv(K).T


def _target_in_source(p: SyntheticPair) -> tuple[np.ndarray, np.ndarray]:
    """Every target pixel centre unprojected with its depth, moved with inv(T) and projected with
    K_source: (N, 2) source positions and (N,) source z-depths."""
    h, w = p.depth_target.shape
    X_t = _pixel_rays(w, h, p.K_target) * p.depth_target.reshape(-1, 1)
    T_inv = np.linalg.inv(p.T_source_to_target)
    X_s = X_t @ T_inv[:3, :3].T + T_inv[:3, 3]
    proj = X_s @ p.K_source.T
    return proj[:, :2] / proj[:, 2:], X_s[:, 2]


def _interp_depth(depth: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """z-depth at sub-pixel ``uv`` by bilinear interpolation of inverse depth, which is exact when the
    four surrounding pixel centres lie on one plane (1/z is affine in the image there); the flag
    says the cell passed that planarity check and lies inside the image."""
    h, w = depth.shape
    x0, y0 = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    ok = (x0 >= 0) & (y0 >= 0) & (x0 < w - 1) & (y0 < h - 1)
    x0, y0 = np.where(ok, x0, 0), np.where(ok, y0, 0)
    inv = 1.0 / depth.astype(np.float64)
    a, b, c, d = inv[y0, x0], inv[y0, x0 + 1], inv[y0 + 1, x0], inv[y0 + 1, x0 + 1]
    ok &= np.abs(a + d - b - c) <= 1e-5 * a
    fx, fy = uv[:, 0] - x0, uv[:, 1] - y0
    top, bottom = a + fx * (b - a), c + fx * (d - c)
    return 1.0 / (top + fy * (bottom - top)), ok


# (make_pair arguments, least fraction of target pixels seen by the source at the right depth)
CASES = {
    "orbit": ({}, 0.85),
    # A landscape source cannot see the top and bottom of a portrait target.
    "portrait_forward_other_source_size": (
        {"width": 240, "height": 320, "source_size": (400, 300), "motion": "forward"},
        0.55,
    ),
    "rotate": ({"motion": "rotate"}, 0.8),
    "sideways": ({"motion": "sideways", "seed": 3}, 0.8),
}


def _consistent(p: SyntheticPair, T: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per target pixel, under pose ``T``: its source position and z-depth, depth agreement with the
    source depth map (relative 1e-3, planar cells only), the relative depth error and the colour
    error (grey levels) against the source."""
    uv, z_s = _target_in_source(SyntheticPair(**{**vars(p), "T_source_to_target": T}))
    z_interp, planar = _interp_depth(p.depth_source, uv)
    rel = np.abs(z_interp - z_s) / z_s
    agree = planar & (rel < 1e-3)
    h, w = p.depth_target.shape
    maps = [c.astype(np.float32).reshape(h, w) for c in uv.T]
    warped = cv2.remap(p.source.astype(np.float32), *maps, cv2.INTER_LINEAR).reshape(-1, 3)
    return uv, z_s, agree, rel, np.abs(warped - p.target.reshape(-1, 3)).mean(axis=1)


def _covisible(p: SyntheticPair) -> np.ndarray:
    """The module's own (N,) visibility of target pixels in the source."""
    args = (p.K_target, p.target_to_world, p.depth_target, p.K_source, p.source_to_world)
    return covisible(p.scene, *args, p.source.shape[1::-1]).ravel()


@pytest.mark.parametrize("case", list(CASES))
def test_reprojection_matches_depth_pose_and_colour(case: str, pair: SyntheticPair) -> None:
    kwargs, min_overlap = CASES[case]
    p = pair if case == "orbit" else make_pair(**kwargs)
    for depth in (p.depth_target, p.depth_source):
        assert np.isfinite(depth).all() and depth.min() > 0.5
    uv, _, agree, rel, err = _consistent(p, p.T_source_to_target)
    assert agree.mean() > min_overlap
    # Where the cell is planar and in view, the depth is exact up to float32 rounding.
    assert np.median(rel[agree]) < 1e-6
    # The module's own visibility (exact ray casting through the projected points) agrees.
    vis = _covisible(p)
    assert np.mean(vis[agree]) > 0.995
    assert np.mean(agree[vis]) > 0.95
    # Colours agree where both views see the point, away from depth edges in either view.
    near_edge_t = cv2.dilate(depth_edges(p.depth_target).astype(np.uint8), np.ones((5, 5))).ravel() > 0
    near_edge_s = cv2.dilate(depth_edges(p.depth_source).astype(np.uint8), np.ones((5, 5))) > 0
    xi, yi = np.clip(np.rint(uv).astype(int), 0, np.array(p.depth_source.shape[::-1]) - 1).T
    clean = agree & ~near_edge_t & ~near_edge_s[yi, xi]
    assert clean.mean() > 0.5 * min_overlap
    assert err[clean].mean() < 4.0  # grey levels; measured 0.9-2.1
    # The opposite pose convention fails the same check. Depth alone cannot tell for planes parallel
    # to a pure translation (their depth map is invariant along it), so colour is required too.
    _, _, agree_w, _, err_w = _consistent(p, np.linalg.inv(p.T_source_to_target))
    assert np.mean(agree_w & (err_w < 12.0)) < 0.3


def test_exact_depth_at_projected_points(pair: SyntheticPair) -> None:
    """Casting the source ray through each projected target point (sub-pixel) hits that very point."""
    uv, z_s, agree, _, _ = _consistent(pair, pair.T_source_to_target)
    z_cast = pair.scene.depth_at(pair.K_source, pair.source_to_world, uv[agree])
    assert np.max(np.abs(z_cast - z_s[agree]) / z_s[agree]) < 1e-6  # float32 depth_target rounding


def test_default_pair_is_handheld_like(pair: SyntheticPair) -> None:
    T = pair.T_source_to_target
    angle = rotation_error_deg(T[:3, :3], np.eye(3))
    assert 2.0 < angle < 8.0
    baseline_ratio = np.linalg.norm(T[:3, 3]) / np.median(pair.depth_target)
    assert 0.05 <= baseline_ratio <= 0.1
    # Parallax: target pixels mapped with their true depth vs. at infinity (rotation only) move by
    # different amounts for near boxes and the far wall.
    h, w = pair.depth_target.shape
    uv, _ = _target_in_source(pair)
    rays_s = _pixel_rays(w, h, pair.K_target) @ T[:3, :3]  # R^T d, row form
    proj_inf = rays_s @ pair.K_source.T
    parallax = np.linalg.norm(uv - proj_inf[:, :2] / proj_inf[:, 2:], axis=1)
    p5, p95 = np.percentile(parallax, [5, 95])
    assert p95 - p5 > 5.0  # px at 320x240
    assert pair.depth_target.max() / pair.depth_target.min() > 3.0


def test_rotate_has_exactly_zero_translation() -> None:
    p = make_pair(1, motion="rotate", rotation_deg=7.0)
    assert np.array_equal(p.T_source_to_target[:3, 3], np.zeros(3))
    assert rotation_error_deg(p.T_source_to_target[:3, :3], np.eye(3)) == pytest.approx(7.0, abs=1e-9)
    assert np.array_equal(p.T_source_to_target[3], [0.0, 0.0, 0.0, 1.0])


def test_portrait_and_other_source_size_intrinsics() -> None:
    p = make_pair(2, width=180, height=320, source_size=(300, 200))
    assert p.target.shape == (320, 180, 3) and p.target.dtype == np.uint8
    assert p.source.shape == (200, 300, 3)
    assert p.depth_target.shape == (320, 180) and p.depth_target.dtype == np.float32
    assert p.depth_source.shape == (200, 300)
    assert p.hole.shape == (320, 180) and p.hole.dtype == bool
    np.testing.assert_array_equal(p.K_target[:2, 2], [(180 - 1) / 2, (320 - 1) / 2])
    np.testing.assert_array_equal(p.K_source[:2, 2], [(300 - 1) / 2, (200 - 1) / 2])
    assert p.K_target[0, 0] == p.K_target[1, 1] == default_focal_px(180, 320)
    assert p.K_source[0, 0] == default_focal_px(300, 200)
    q = make_pair(2, width=180, height=320, focal_px=400.0, source_focal_px=300.0)
    assert q.K_target[0, 0] == 400.0 and q.K_source[1, 1] == 300.0


def test_deterministic_per_seed() -> None:
    a, b, c = make_pair(5), make_pair(5), make_pair(6)
    for name in ("target", "source", "depth_target", "depth_source", "hole", "T_source_to_target"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert np.abs(a.target.astype(int) - c.target.astype(int)).mean() > 10
    assert not np.allclose(a.depth_target, c.depth_target)


def test_depth_at_pixel_centres_independent_of_supersampling() -> None:
    scene = make_scene(4)
    K = np.array([[150.0, 0.0, 79.5], [0.0, 150.0, 59.5], [0.0, 0.0, 1.0]])
    pose = scene.target_pose()
    rgb1, d1 = scene.render(K, pose, 160, 120, supersample=1)
    rgb3, d3 = scene.render(K, pose, 160, 120, supersample=3)
    assert np.array_equal(d1, d3)
    # Anti-aliased colour is centred on the same pixel grid (no half-pixel shift).
    g1, g3 = (cv2.cvtColor(im, cv2.COLOR_RGB2GRAY).astype(np.float64) for im in (rgb1, rgb3))
    (dx, dy), _ = cv2.phaseCorrelate(g1, g3)
    assert abs(dx) < 0.05 and abs(dy) < 0.05
    # A ray through the principal point of a camera at the origin meets the scene at z = depth.
    centre = scene.depth_at(K, pose, np.array([[79.5, 59.5]]))[0]
    assert d1[59:61, 79:81].min() <= centre <= d1[59:61, 79:81].max()


def test_sift_matches_and_hole(pair: SyntheticPair) -> None:
    m = match_pair(pair.target, pair.source, pair.hole, MatchingConfig(), scale_px=320 / 1280)
    assert len(m) >= 100  # measured ~600
    # Verified matches are true correspondences: the target keypoint, moved with the exact depth
    # and pose, lands within 2 px of its matched source keypoint.
    z = pair.scene.depth_at(pair.K_target, pair.target_to_world, m.pts_target)
    X_t = np.concatenate([m.pts_target, np.ones((len(m), 1))], axis=1) @ np.linalg.inv(pair.K_target).T
    T_inv = np.linalg.inv(pair.T_source_to_target)
    X_s = (X_t * z[:, None]) @ T_inv[:3, :3].T + T_inv[:3, 3]
    proj = X_s @ pair.K_source.T
    err = np.linalg.norm(proj[:, :2] / proj[:, 2:] - m.pts_source, axis=1)
    assert np.mean(err < 2.0) > 0.9
    # The default hole: 5-15 % of the target, across a depth edge, seen by the source.
    assert 0.05 <= pair.hole.mean() <= 0.15
    assert depth_edges(pair.depth_target)[pair.hole].sum() > 20
    vis = _covisible(pair).reshape(pair.hole.shape)
    assert vis[pair.hole].mean() > 0.95


def test_photometric_knobs_leave_ground_truth(pair: SyntheticPair) -> None:
    p = make_pair(0, source_gain=1.2, noise_sigma=2.0)
    for name in ("depth_target", "depth_source", "hole", "T_source_to_target", "K_source"):
        assert np.array_equal(getattr(p, name), getattr(pair, name)), name
    unsaturated = (pair.source > 20) & (pair.source < 200)
    ratio = p.source[unsaturated].astype(float) / pair.source[unsaturated]
    assert np.median(ratio) == pytest.approx(1.2, abs=0.02)
    noise = p.target.astype(float) - pair.target
    assert 1.7 < noise.std() < 2.3


def test_bad_arguments_raise(pair: SyntheticPair) -> None:
    with pytest.raises(ValueError, match="motion"):
        make_pair(0, motion="zoom")
    outside = np.eye(4)
    outside[:3, 3] = [0.0, 0.0, -100.0]
    with pytest.raises(ValueError, match="outside the room"):
        pair.scene.render(pair.K_target, outside, 32, 24)
