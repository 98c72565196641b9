"""The multi-view depth stage on ray-cast scenes with exact poses and depth: a reference's depth
where it lands in the target's hole (which the target cannot see) is measured from the other
reference, in one frame though each pair has its own units."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from geofill.camera import Intrinsics
from geofill.config import FillConfig, MultiViewConfig
from geofill.multiview import ViewGeometry, common_scales, footprint_crop, joint_scales, multiview_depth
from geofill.optimize.stage import Geometry
from geofill.pipeline import fill
from geofill.prepare import prepare_views
from geofill.render import project_source_points, source_pixel_grid
from geofill.synthetic import blanked, make_views
from geofill.triangulate import TriangulatedPoints

W, H = 320, 240
#: Each pair's own units: reference k's translation and depth are the scene's times this.
UNITS = (1.0, 0.4)


def _hole() -> np.ndarray:
    hole = np.zeros((H, W), bool)
    hole[80:170, 130:210] = True
    return hole


def _points(depth: np.ndarray, K: Intrinsics, T: np.ndarray) -> TriangulatedPoints:
    """Exact 'triangulated' points on a 10-px grid of the source."""
    x, y = source_pixel_grid(H, W)
    x, y, z = x[5::10, 5::10].ravel(), y[5::10, 5::10].ravel(), depth[5::10, 5::10].ravel().astype(np.float64)
    u, v, _ = project_source_points(x, y, z, K, K, T)
    xyz = np.stack([(x - K.cx) / K.fx * z, (y - K.cy) / K.fy * z, z], 1)
    n = len(z)
    return TriangulatedPoints(xyz, np.stack([x, y], 1), np.stack([u, v], 1), np.zeros(n), np.full(n, 5.0))


@pytest.fixture(scope="module")
def scene():
    """Target and two references (stepped left and right), each in its own units, with the true
    depth everywhere except where it lands in the hole: there, 30 % too far (a wrong completion)."""
    v = make_views(seed=0, width=W, height=H)
    hole = _hole()
    K = Intrinsics.from_matrix(v.K, W, H)
    pose_t = v.scene.target_pose()
    cfg = FillConfig()
    refs, truth = [], []
    poses = [pose_t @ T for T in v.T_source_to_target]
    for k, (source, T) in enumerate(zip(v.sources, v.T_source_to_target, strict=True)):
        gt = v.scene.depth_map(v.K, pose_t @ T, W, H).astype(np.float32) * UNITS[k]
        T_k = T.copy()
        T_k[:3, 3] *= UNITS[k]
        views = prepare_views(blanked(v.target, hole), hole, source, cfg, None, None)
        exact = ViewGeometry(k + 1, views, Geometry(T_k, K, K, gt), _points(gt, K, T_k))
        foot = _footprint(exact)
        wrong = ViewGeometry(k + 1, views, Geometry(T_k, K, K, np.where(foot, 1.3 * gt, gt)), exact.points)
        refs.append(wrong)
        # Where the stage looks: the pixels its (wrong) depth puts in the hole.
        seen = _seen_by(v.scene, v.K, poses[k], gt / UNITS[k], poses[1 - k])
        truth.append((gt, foot & _footprint(wrong) & seen, _footprint(wrong)))
    return refs, truth


def _seen_by(scene, K, pose_k, depth, pose_j) -> np.ndarray:
    """(H, W) bool: camera k's surface point at each pixel is the first hit of camera j's ray."""
    x, y = source_pixel_grid(H, W)
    X = np.stack([(x - K[0, 2]) / K[0, 0] * depth, (y - K[1, 2]) / K[1, 1] * depth, depth], -1).reshape(-1, 3)
    world = X @ pose_k[:3, :3].T + pose_k[:3, 3]
    Xj = (world - pose_j[:3, 3]) @ pose_j[:3, :3]
    uv = (Xj @ K.T)[:, :2] / Xj[:, 2:]
    inside = (Xj[:, 2] > 0) & np.all((uv >= 0) & (uv <= [W - 1, H - 1]), axis=1)
    seen = np.zeros(len(X), bool)
    seen[inside] = np.abs(scene.depth_at(K, pose_j, uv[inside]) / Xj[inside, 2] - 1) < 1e-3
    return seen.reshape(H, W)


def _footprint(g: ViewGeometry) -> np.ndarray:
    crop = footprint_crop(g, 1.0, 0)
    foot = np.zeros((H, W), bool)
    fh, fw = crop.footprint.shape
    foot[crop.y0 : crop.y0 + fh, crop.x0 : crop.x0 + fw] = crop.footprint
    return foot


def test_the_references_are_placed_in_one_frame(scene):
    refs, _ = scene
    (s1, spread1), (s2, spread2) = common_scales(refs)
    assert s1 == pytest.approx(1.0, abs=1e-6) and spread1 < 0.03
    # Reference 2's units are 0.4 of reference 1's: its lengths times 2.5 are in the common frame.
    assert s2 == pytest.approx(UNITS[0] / UNITS[1], rel=0.02) and spread2 < 0.03


def test_the_joint_registrations_baselines_fix_the_scales_and_the_spread_measures_them(scene):
    """Baselines in a joint registration's units (3x the scene's here): they give the scale, and
    one 10 % off shows as a 10 % spread against the depths."""
    refs, _ = scene
    true = [np.linalg.norm(g.geometry.T[:3, 3]) / u for g, u in zip(refs, UNITS, strict=True)]
    joint = [replace(g, joint_baseline=3.0 * t * f) for g, t, f in zip(refs, true, (1.0, 1.1), strict=True)]
    known = joint_scales(joint)
    assert known[0] == pytest.approx(1.0) and known[1] == pytest.approx(1.1 * UNITS[0] / UNITS[1])
    (s1, spread1), (s2, spread2) = common_scales(joint, known)
    assert s1 == pytest.approx(1.0) and spread1 < 0.03
    assert s2 == pytest.approx(known[1]) and spread2 == pytest.approx(0.1, abs=0.03)
    assert joint_scales([replace(joint[0], joint_baseline=None), joint[1]]) == [None, None]


def test_each_footprint_gets_the_true_depth_from_the_other_reference(scene):
    refs, truth = scene
    geometries, result = multiview_depth(refs, MultiViewConfig())
    for geo, ref, (gt, foot, looked), rep in zip(geometries, refs, truth, result.references, strict=True):
        assert foot.sum() > 2000  # the footprint (in the hole, seen by the other reference only)
        before = np.abs(ref.geometry.depth[foot] / gt[foot] - 1)
        after = np.abs(geo.depth[foot] / gt[foot] - 1)
        assert np.median(before) == pytest.approx(0.3, abs=1e-3)
        assert np.median(after) < 0.03 and np.mean(after < 0.05) > 0.8
        # Outside the footprint the depth is left as it was.
        assert np.array_equal(geo.depth[~looked], ref.geometry.depth[~looked])
        assert rep.footprint_px > 1000 and 0.5 < rep.measured_fraction <= 1.0
        assert rep.views == 2  # the target and the other reference
    assert "of its hole footprint measured" in result.summary()
    assert result.report()["references"][1]["measured_fraction"] == result.references[1].measured_fraction


def test_one_reference_alone_is_left_as_it_is(scene):
    refs, _ = scene
    geometries, result = multiview_depth(refs[:1], MultiViewConfig())
    assert geometries[0] is refs[0].geometry and result.references == ()


def test_fills_report_what_was_measured_and_a_single_reference_is_untouched():
    v = make_views(seed=0, width=W, height=H)
    hole = _hole()
    cfg = FillConfig().updated({"intrinsics.estimate": "none"})
    off = cfg.updated({"multiview.depth": False})
    both = fill(blanked(v.target, hole), hole, v.sources, cfg)
    refs = both.report.multiview["references"]
    assert [r["index"] for r in refs] == [1, 2]
    assert all(r["footprint_px"] > 0 and 0 < r["measured_fraction"] <= 1 for r in refs)
    assert fill(blanked(v.target, hole), hole, v.sources, off).report.multiview == {}
    one, one_off = (fill(blanked(v.target, hole), hole, v.sources[:1], c) for c in (cfg, off))
    assert np.array_equal(one.image, one_off.image) and one.report.multiview == {}
