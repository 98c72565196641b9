"""The removal protocols that look like real removals: brushed holes, the solid box ray-cast into
every view, the walker that moves between views, and the ghost measure (an object reproduced
anywhere in the hole)."""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest

from geofill.evaluation.baselines import opencv_inpaint
from geofill.evaluation.cli import main_eval
from geofill.evaluation.cutouts import photo_crop
from geofill.evaluation.masks import brush_margin_px, brushed_hole, brushed_interior, closed_silhouette
from geofill.evaluation.metrics import ghost
from geofill.evaluation.pairs import load_pairs, pair_geometry
from geofill.evaluation.removal import REMOVAL_PROTOCOLS, make_case, solid_case, walker_case
from geofill.evaluation.scene_geometry import plane_homography
from geofill.evaluation.solids import Box, Figure, face_shades, render_box

K = np.array([[500.0, 0.0, 160.0], [0.0, 500.0, 120.0], [0.0, 0.0, 1.0]])
#: One flat colour per face (-x, +x, -y, +y, -z, +z), far apart.
FACE_COLOURS = [(250, 0, 0), (0, 250, 0), (0, 0, 250), (250, 250, 0), (0, 250, 250), (250, 0, 250)]


@pytest.fixture(scope="module")
def view_set():
    (pair,) = load_pairs(["synthetic-views:1"])
    return pair


def _box(centre, axes=None, half=(0.5, 0.4, 0.3)) -> Box:
    axes = np.eye(3) if axes is None else axes
    textures = tuple(np.full((2, 2, 3), c, np.float32) for c in FACE_COLOURS)
    return Box(np.asarray(centre, float), np.asarray(axes, float), np.asarray(half, float), textures)


def _pose(yaw_deg: float, position) -> np.ndarray:
    """view_from_target of a camera at ``position`` (target frame) turned by ``yaw`` about y."""
    R, _ = cv2.Rodrigues(np.array([0.0, np.radians(yaw_deg), 0.0]))
    M = np.eye(4)
    M[:3, :3] = R.T
    M[:3, 3] = -R.T @ np.asarray(position, float)
    return M


# ---------------------------------------------------------------------------------------------
# Brushed holes


@pytest.mark.parametrize("size", [(720, 1280), (360, 640)])
def test_brushed_hole_holds_the_silhouette_and_its_margin_is_15_to_45_px_at_1280(size):
    h, w = size
    silhouette = np.zeros(size, bool)
    cv2.ellipse(silhouette.view(np.uint8), (w // 2, h // 2), (w // 10, h // 6), 20, 0, 360, 1, -1)
    silhouette[h // 2 : h // 2 + h // 5, w // 2 - 3 : w // 2 + 3] = True  # a thin leg
    hole = brushed_hole(silhouette, np.random.default_rng(4))
    lo, hi = brush_margin_px(h, w)
    assert (lo, hi) == pytest.approx((15.0 * w / 1280, 45.0 * w / 1280))
    assert not np.any(silhouette & ~hole)
    # Every outline pixel of the hole lies 15-45 px (scaled) from the closed silhouette ...
    closed = closed_silhouette(silhouette, hi)
    distance = cv2.distanceTransform((~closed).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    outline = hole & ~cv2.erode(hole.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    margins = distance[outline]
    assert margins.min() >= lo - 1.5 and margins.max() <= hi + 1.5
    # ... and wobbles over most of that range, not one constant dilation.
    assert margins.max() - margins.min() > 0.6 * (hi - lo)
    assert np.array_equal(hole, brushed_hole(silhouette, np.random.default_rng(4)))


def test_brushed_interior_leaves_the_margin_of_a_stroke():
    h, w = 360, 640
    hole = np.zeros((h, w), bool)
    cv2.line(hole.view(np.uint8), (100, 180), (540, 200), 1, thickness=120)
    inner = brushed_interior(hole, np.random.default_rng(0))
    lo, _ = brush_margin_px(h, w)
    outside = cv2.distanceTransform((~hole).view(np.uint8) ^ 1, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    assert inner.any() and not np.any(inner & ~hole)
    assert outside[inner].min() > lo - 1.0
    # The hole pixels within the smallest margin of the outside are never the object.
    assert not np.any(inner & (outside < lo))


def test_removal_cases_brush_around_the_object_by_default(view_set):
    brushed, tight = make_case("static", view_set, 0), make_case("static", view_set, 0, mask="tight")
    assert np.array_equal(brushed.pair.target, tight.pair.target)  # the same object either way
    obj = np.any(brushed.pair.target != brushed.truth, axis=2)
    assert not np.any(obj & ~brushed.hole) and brushed.hole.sum() > 1.3 * tight.hole.sum()
    assert brushed.info["hole_mask"] == "brushed" and tight.info["hole_mask"] == "tight"


# ---------------------------------------------------------------------------------------------
# Solid


def test_box_faces_occlude_each_other_as_seen_from_the_camera():
    box = _box((0.0, 0.0, 4.0))
    shades = face_shades(box.axes)
    colour, alpha, z = render_box(box, K, np.eye(4), (240, 320))
    # Head on, only the near face (-z) is seen, at its depth 4 - 0.3.
    assert alpha[120, 160] == 1.0 and z[120, 160] == pytest.approx(3.7, abs=1e-6)
    assert colour[120, 160] == pytest.approx(np.array(FACE_COLOURS[4]) * shades[4], abs=0.01)
    # Its outline: x = 160 +- 500 * 0.5 / 3.7 = 92.4 .. 227.6, y = 120 +- 54.05 = 65.95 .. 174.05
    # (pixels 66 and 174 are half covered by the 4 x 4 samples, so alpha 0.5 there).
    cols = np.nonzero(alpha[120] > 0.5)[0]
    rows = np.nonzero(alpha[:, 160] > 0.5)[0]
    assert cols.min() == 93 and cols.max() == 227 and rows.min() == 67 and rows.max() == 173
    # A camera 3 units to the right, turned 30 deg towards the box, sees its +x face too.
    colour, alpha, _ = render_box(box, K, _pose(-30.0, (3.0, 0.0, 0.0)), (240, 320))
    full = alpha == 1.0
    for f in (1, 4):
        expect = np.array(FACE_COLOURS[f]) * shades[f]
        assert np.sum(np.all(np.abs(colour[full] - expect) < 0.5, axis=1)) > 500
    # The -x face, turned away from it, is nowhere.
    expect = np.array(FACE_COLOURS[0]) * shades[0]
    assert not np.any(np.all(np.abs(colour[full] - expect) < 0.5, axis=1))


def test_box_is_hidden_where_the_scene_is_nearer():
    box = _box((0.0, 0.0, 4.0))
    depth = np.zeros((240, 320), np.float32)
    depth[:, :160] = 2.0  # a wall nearer than the box on the left; 0 = unknown on the right
    _, alpha, _ = render_box(box, K, np.eye(4), (240, 320), depth)
    assert alpha[120, 100:159].max() == 0.0 and alpha[120, 161:220].min() == 1.0


def test_solid_case_draws_the_box_where_the_gt_camera_projects_it(view_set):
    case = solid_case(view_set, 0, plain=True)
    g = pair_geometry(view_set)
    info = case.info
    box = _box(info["box_centre"], np.array(info["box_axes"]), info["box_half_extents"])
    for image, original, Kv, T in [
        (case.pair.target, view_set.target, g.K_target, np.eye(4)),
        *zip(case.pair.sources, view_set.sources, g.K_sources, g.T_source_to_target, strict=True),
    ]:
        # The corners through OpenCV's own projection with the GT pose: the box's outline is
        # their convex hull, and the pixels the case changed lie in it.
        M = np.linalg.inv(T)
        rvec, _ = cv2.Rodrigues(M[:3, :3])
        uv, _ = cv2.projectPoints(box.corners(), rvec, M[:3, 3], Kv, None)
        hull = np.zeros(image.shape[:2], np.uint8)
        corners = cv2.convexHull(np.rint(uv.reshape(-1, 2) * 16).astype(np.int32))
        cv2.fillConvexPoly(hull, corners, 1, cv2.LINE_8, 4)
        changed = np.any(image != original, axis=2)
        grown = cv2.dilate(hull, np.ones((3, 3), np.uint8)).astype(bool)
        assert changed.sum() > 500 and not np.any(changed & ~grown)
        assert changed.sum() >= 0.8 * hull.sum()  # hidden by the scene in places at most
    # One colour, a few shades: a plain box shows at most three faces, one colour each (pixels on
    # the edges between faces mix two).
    changed = np.any(case.pair.target != case.truth, axis=2).astype(np.uint8)
    inner = cv2.erode(changed, np.ones((5, 5), np.uint8)) > 0
    _, counts = np.unique(case.pair.target[inner], axis=0, return_counts=True)
    assert np.sort(counts)[::-1][:3].sum() >= 0.97 * counts.sum()


# ---------------------------------------------------------------------------------------------
# Walker


def test_figure_has_a_head_a_torso_and_two_legs():
    fig = Figure((50.0, 10.0), 100.0, stride=0.8)
    head, torso = fig.inside(np.array([[50.0, 16.0]])), fig.inside(np.array([[50.0, 45.0]]))
    neck_side, crotch = fig.inside(np.array([[60.0, 14.0]])), fig.inside(np.array([[50.0, 90.0]]))
    assert head[0] and torso[0] and not neck_side[0] and not crotch[0]  # the legs apart below the hips
    _, y0, _, y1 = fig.bbox
    assert y0 == pytest.approx(10.0 + 0.065 * 100 - 6.2) and y1 == pytest.approx(10.0 + 96.5 + 4.5)


def test_walker_stands_elsewhere_in_each_reference(view_set):
    case = walker_case(view_set, 0)
    g = pair_geometry(view_set)
    walker = np.any(case.pair.target != case.truth, axis=2)
    ys, xs = np.nonzero(walker)
    centre = np.array([xs.mean(), ys.mean(), 1.0])
    for k, ref in enumerate(case.info["references"]):
        H = plane_homography(g.K_target, g.K_sources[k], g.T_source_to_target[k], case.info["z_object"])
        still = H @ centre  # where it would be had it stood still
        drawn = np.any(case.pair.sources[k] != view_set.sources[k], axis=2)
        ry, rx = np.nonzero(drawn)
        moved = np.array([rx.mean(), ry.mean()]) - still[:2] / still[2]
        scale = np.sqrt(abs(np.linalg.det(H[:2, :2] / H[2, 2])))
        # Sideways by its step on the plane (seen through the plane's homography), hardly up or down.
        assert abs(ref["step_px"]) > 0.4 * (xs.max() - xs.min())
        assert moved[0] == pytest.approx(ref["step_px"] * scale, rel=0.25, abs=4)
        assert abs(moved[1]) < 0.1 * (ys.max() - ys.min())


def test_walker_crowd_adds_passers_by_in_the_references_only(view_set):
    alone, crowd = walker_case(view_set, 0), walker_case(view_set, 0, crowd=True)
    assert all(r.get("passers_by", 0) >= 1 for r in crowd.info["references"])
    assert "passers_by" not in alone.info["references"][0]
    for (_, shown), (_, more) in zip(alone.appearances[1:], crowd.appearances[1:], strict=True):
        assert more.sum() > shown.sum() * 0.5
    # Only the references: the target shows one walker.
    n, _ = cv2.connectedComponents(np.any(crowd.pair.target != crowd.truth, axis=2).astype(np.uint8))
    assert n == 2


# ---------------------------------------------------------------------------------------------
# Ghost


def _scene(seed: int = 0):
    rng = np.random.default_rng(seed)
    truth = np.clip(photo_crop(rng, 320, 240), 0, 255).astype(np.uint8)
    obj = np.clip(photo_crop(rng, 320, 240), 0, 255).astype(np.uint8)
    mask = np.zeros((240, 320), bool)
    cv2.ellipse(mask.view(np.uint8), (130, 120), (40, 55), 0, 0, 360, 1, -1)
    shown = np.where(mask[..., None], obj, truth)
    hole = cv2.dilate(mask.astype(np.uint8), np.ones((81, 81), np.uint8)).astype(bool)
    return truth, shown, mask, hole


def test_ghost_is_zero_on_the_truth_and_finds_the_object_pasted_30_px_aside():
    truth, shown, mask, hole = _scene()
    looks = [(shown, mask)]
    assert ghost(truth, truth, hole, looks).fraction == 0.0
    moved = np.roll(mask, 30, axis=1)
    pasted = truth.copy()
    pasted[moved] = np.roll(shown, 30, axis=1)[moved]
    found = ghost(pasted, truth, hole, looks)
    share = (moved & hole).sum() / hole.sum()  # the fragment's share of the hole
    # Its textured parts are found (this crop is smooth in places, which never count) ...
    assert 0.35 * share <= found.fraction <= share
    # ... on the pasted fragment, not on the background beside it.
    assert (found.mask & moved).sum() >= 0.95 * found.mask.sum()
    # A copy darkened by 15 % (a method's colour correction) is found as well.
    dark = truth.copy()
    dark[moved] = np.clip(np.roll(shown, 30, axis=1)[moved] * 0.85, 0, 255).astype(np.uint8)
    assert ghost(dark, truth, hole, looks).fraction >= 0.8 * found.fraction
    # A smear of the surroundings (Telea) copies nothing and scores next to nothing.
    smear = ghost(opencv_inpaint(truth, hole), truth, hole, looks).fraction
    assert smear < 0.1 * found.fraction


def test_ghost_finds_a_rescaled_fragment():
    truth, shown, mask, hole = _scene(1)
    big = cv2.resize(shown, None, fx=1.4, fy=1.4, interpolation=cv2.INTER_LINEAR)
    big_mask = cv2.resize(mask.astype(np.uint8), None, fx=1.4, fy=1.4, interpolation=cv2.INTER_NEAREST) > 0
    out = truth.copy()
    window = big_mask[60:300, 80:400]
    out[window] = big[60:300, 80:400][window]
    share = (window & hole).sum() / hole.sum()
    found = ghost(out, truth, hole, [(shown, mask)])
    assert found.fraction >= 0.35 * share and (found.mask & window).sum() >= 0.95 * found.mask.sum()


# ---------------------------------------------------------------------------------------------
# CLI


@pytest.mark.parametrize("protocol", [p for p in REMOVAL_PROTOCOLS if p != "static"])
def test_cli_runs_each_removal_protocol_on_synthetic_pairs(tmp_path, protocol):
    out = tmp_path / protocol
    assert main_eval(["--pairs", "synthetic:1", "--out", str(out), "--methods", "opencv_inpaint",
                      "--protocol", protocol]) == 0  # fmt: skip
    with (out / "results.csv").open() as fh:
        (row,) = list(csv.DictReader(fh))
    assert row["error"] == "" and 0.0 <= float(row["ghost"]) < 0.1 and 0.0 <= float(row["leak"]) <= 1.0
    cases = json.loads((out / "cases.json").read_text())
    assert cases["synthetic_000"]["hole_mask"] == "brushed"
    assert "- ghost:" in (out / "summary.md").read_text()


def test_cli_removal_mask_tight_and_its_errors(tmp_path):
    argv = ["--pairs", "synthetic:1", "--out", str(tmp_path), "--methods", "opencv_inpaint"]
    assert main_eval([*argv, "--protocol", "walker", "--removal-mask", "tight"]) == 0
    assert json.loads((tmp_path / "cases.json").read_text())["synthetic_000"]["hole_mask"] == "tight"
    assert main_eval([*argv, "--removal-mask", "tight"]) == 2  # restoration has no object


def test_ghost_finds_a_copy_rotated_rescaled_and_resampled_as_a_warp_leaves_it():
    truth, shown, mask, hole = _scene(2)
    # The object turned by 12 degrees, shrunk to 0.8 and moved 25 px, bilinear as a warp samples:
    # 7-px patches of it lie 10-20 levels from any patch of the object, so a patch library misses it.
    A = cv2.getRotationMatrix2D((130.0, 120.0), 12.0, 0.8)
    A[:, 2] += (25.0, 10.0)
    warped = cv2.warpAffine(shown, A, (320, 240), flags=cv2.INTER_LINEAR)
    moved = (cv2.warpAffine(mask.astype(np.uint8), A, (320, 240), flags=cv2.INTER_NEAREST) > 0) & hole
    out = truth.copy()
    out[moved] = warped[moved]
    share = moved.sum() / hole.sum()
    found = ghost(out, truth, hole, [(shown, mask)])
    assert found.fraction >= 0.6 * share
    assert (found.mask & moved).sum() >= 0.95 * found.mask.sum()
