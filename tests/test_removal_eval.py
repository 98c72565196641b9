"""The object-removal protocols of ``geofill eval`` (static, strangers): exact placement of the
planar object, exact truth, the leak metric, the runner and the CLI."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from geofill.evaluation.baselines import opencv_inpaint
from geofill.evaluation.cli import main_eval
from geofill.evaluation.cutouts import Blob, coverage, photo_crop, random_blob
from geofill.evaluation.metrics import leak
from geofill.evaluation.pairs import load_pairs, pair_geometry, pair_mask
from geofill.evaluation.removal import (
    ProtocolSkip,
    hole_dilation_px,
    make_case,
    static_case,
    strangers_case,
)
from geofill.evaluation.runner import run_eval
from geofill.evaluation.scene_geometry import homography_map, plane_depth_map, plane_homography, project
from test_evaluation import planar_pair, planar_pairs

MULTIVIEW = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "multiview"


@pytest.fixture(scope="module")
def synthetic_pair():
    (pair,) = load_pairs(["synthetic:1"])
    return pair


@pytest.fixture(scope="module")
def static(synthetic_pair):
    return static_case(synthetic_pair, seed=0, mask="tight")


def _read_csv(path: Path) -> list[dict[str, str]]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


# ---------------------------------------------------------------------------------------------
# Cutouts


def test_blob_coverage_integrates_to_its_area():
    blob = Blob((40.0, 30.0), 12.0, 1.6, 0.7, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # a plain ellipse
    alpha = coverage(blob, np.eye(3), (60, 80))
    assert alpha.sum() == pytest.approx(np.pi * 12.0**2, rel=0.005)
    assert alpha[30, 40] == 1.0 and alpha[0, 0] == 0.0
    # Seen through a 2x zoom about the origin, the same blob covers four times the pixels.
    zoom = np.diag([2.0, 2.0, 1.0])
    assert coverage(blob, zoom, (120, 160)).sum() == pytest.approx(4 * np.pi * 12.0**2, rel=0.005)


def test_photo_crops_are_seeded_and_grey_on_request():
    a = photo_crop(np.random.default_rng(3), 50, 40)
    b = photo_crop(np.random.default_rng(3), 50, 40)
    assert a.shape == (40, 50, 3) and np.array_equal(a, b)
    grey = photo_crop(np.random.default_rng(3), 50, 40, grey=True)
    assert np.array_equal(grey[..., 0], grey[..., 1]) and np.array_equal(grey[..., 0], grey[..., 2])
    blob = random_blob(np.random.default_rng(1), (0.0, 0.0), 10.0)
    assert blob.inside(np.zeros((1, 2)))[0] and not blob.inside(np.array([[blob.reach + 0.01, 0.0]]))[0]


# ---------------------------------------------------------------------------------------------
# Geometry


def test_plane_depth_map_agrees_with_projection():
    K = np.array([[200.0, 0, 80], [0, 200.0, 60], [0, 0, 1]])
    T = np.eye(4)
    c, s = np.cos(0.2), np.sin(0.2)
    T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    T[:3, 3] = [0.4, -0.1, 0.3]
    xy_t = np.array([[90.0, 30.0], [120.0, 60.0], [150.0, 100.0]])
    xy_s, z_s = project(xy_t, np.full(3, 3.0), K, K, T)
    H = plane_homography(K, K, T, 3.0)
    p = np.concatenate([xy_t, np.ones((3, 1))], axis=1) @ H.T
    assert np.abs(p[:, :2] / p[:, 2:] - xy_s).max() < 1e-9
    depth = plane_depth_map(K, T, 3.0, (200, 300))
    assert np.all((xy_s > 0) & (xy_s < [299, 199]))
    for (x, y), z in zip(xy_s, z_s, strict=True):  # at the nearest pixel centre: within its slope
        assert depth[round(y), round(x)] == pytest.approx(z, rel=0.01)


def test_homography_map_recovers_a_planar_scene():
    target, source, source_to_target = planar_pair()
    region = np.zeros(target.shape[:2], bool)
    region[100:140, 120:200] = True
    m = homography_map(target, source, region)
    ys, xs = np.nonzero(region)
    truth = (
        np.concatenate([xs[:, None], ys[:, None], np.ones((len(xs), 1))], axis=1)
        @ np.linalg.inv(source_to_target).T
    )
    err = np.linalg.norm(m.xy - truth[:, :2] / truth[:, 2:], axis=1)
    assert m.kind.startswith("homography") and m.valid.all() and np.median(err) < 0.5


# ---------------------------------------------------------------------------------------------
# static


def test_static_object_lands_where_the_exact_geometry_says(synthetic_pair, static):
    """The object's projection into the reference, through world coordinates and the scene's own
    camera poses (not the homography): corners agree to 1e-6 px, and the drawn silhouette matches
    a ray cast of the plane (centroid within 0.5 px)."""
    from geofill.synthetic import make_pair

    sp = make_pair(seed=0)
    g = pair_geometry(synthetic_pair)
    place = static.placement
    z, H = place.z_object, place.homographies[0]
    x0, y0, x1, y1 = place.blob.bbox
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], list(place.blob.centre)])
    X_t = np.concatenate([corners, np.ones((5, 1))], axis=1) @ np.linalg.inv(g.K_target).T * z
    world = X_t @ sp.target_to_world[:3, :3].T + sp.target_to_world[:3, 3]
    X_s = (world - sp.source_to_world[:3, 3]) @ sp.source_to_world[:3, :3]
    expected = (X_s @ sp.K_source.T)[:, :2] / X_s[:, 2:]
    p = np.concatenate([corners, np.ones((5, 1))], axis=1) @ H.T
    assert np.abs(p[:, :2] / p[:, 2:] - expected).max() < 1e-6

    # Ray cast: every reference pixel centre's ray meets the plane; inside the silhouette there?
    h, w = synthetic_pair.source.shape[:2]
    xs, ys = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    rays = np.stack([xs, ys, np.ones_like(xs)], -1).reshape(-1, 3) @ np.linalg.inv(sp.K_source).T
    dirs = rays @ sp.source_to_world[:3, :3].T
    normal, origin = sp.target_to_world[:3, 2], sp.source_to_world[:3, 3]
    on_plane = sp.target_to_world[:3, 3] + z * normal
    lam = ((on_plane - origin) @ normal) / (dirs @ normal)
    hit_t = (origin + lam[:, None] * dirs - sp.target_to_world[:3, 3]) @ sp.target_to_world[:3, :3]
    hit_px = (hit_t @ g.K_target.T)[:, :2] / hit_t[:, 2:]
    cast = (place.blob.inside(hit_px) & (lam * rays[:, 2] < sp.depth_source.ravel())).reshape(h, w)
    drawn = np.any(static.pair.source != synthetic_pair.source, axis=2)
    assert place.visible[0] >= 0.8 and cast.sum() > 500
    ys_c, xs_c = np.nonzero(cast)
    ys_d, xs_d = np.nonzero(drawn)
    assert abs(xs_c.mean() - xs_d.mean()) < 0.5 and abs(ys_c.mean() - ys_d.mean()) < 0.5
    assert (cast & drawn).sum() / (cast | drawn).sum() > 0.95


def test_static_object_is_in_front_of_everything_it_covers(synthetic_pair, static):
    g = pair_geometry(synthetic_pair)
    place = static.placement
    assert 0.5 <= place.fraction <= 0.8
    changed_t = np.any(static.pair.target != synthetic_pair.target, axis=2)
    assert np.all(g.depth_target[changed_t] > place.z_object)
    assert place.z_object == pytest.approx(place.fraction * place.z_near)
    assert place.z_near == pytest.approx(float(g.depth_target[changed_t].min()), rel=0.25)
    changed_s = np.any(static.pair.source != synthetic_pair.source, axis=2)
    plane = plane_depth_map(g.K_sources[0], g.T_source_to_target[0], place.z_object, changed_s.shape)
    assert changed_s.any() and np.all(plane[changed_s] < g.depth_sources[0][changed_s])


def test_static_truth_is_the_clean_target_and_the_hole_holds_the_object(synthetic_pair, static):
    h, w = synthetic_pair.target.shape[:2]
    assert np.array_equal(static.truth, synthetic_pair.target)  # inside and outside the hole
    changed = np.any(static.pair.target != static.truth, axis=2)
    assert changed.any() and not np.any(changed & ~static.hole)
    # The hole is the silhouette dilated by a few px (an elliptic disc of radius r).
    r = hole_dilation_px(h, w)

    def grown(radius):
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1,) * 2)
        return cv2.dilate(changed.astype(np.uint8), disc).astype(bool)

    assert r == 2 and not np.any(grown(r) & ~static.hole) and not np.any(static.hole & ~grown(r + 1))
    assert 0.02 <= static.info["object_area"] <= 0.10
    assert static.info["references"][0]["parallax_px"] > 5.0  # parallax-shifted in the reference


def test_leak_is_one_for_the_object_and_zero_for_the_truth(static):
    full = leak(static.pair.target, static.truth, static.objects, static.hole)
    assert full.fraction == 1.0 and full.distinguishable > 1000
    everything = [*static.objects, *static.extra_objects]
    assert leak(static.truth, static.truth, everything, static.hole).fraction == 0.0
    # The reference's object mapped back as if it were background: copying it leaks all of it.
    ((obj, mask),) = static.extra_objects
    copied = np.where(mask[..., None], obj, static.truth)
    assert mask.any() and leak(copied, static.truth, static.extra_objects, static.hole).fraction == 1.0
    assert leak(static.truth, static.truth, static.objects, static.hole).fraction == 0.0
    # The object in the left half of the hole, the truth in the right half.
    cols = np.nonzero(static.hole.any(axis=0))[0]
    left = np.zeros_like(static.hole)
    left[:, : (cols.min() + cols.max()) // 2] = True
    half = np.where(left[..., None], static.pair.target, static.truth)
    found = leak(half, static.truth, static.objects, static.hole)
    distinct = np.linalg.norm(static.pair.target.astype(float) - static.truth.astype(float), axis=2) > 30
    assert found.leaked == int((distinct & left & static.hole).sum())
    assert found.fraction == pytest.approx(found.leaked / full.distinguishable) and 0.3 < found.fraction < 0.7


def test_leak_half_and_half_on_known_pixels():
    truth = np.full((4, 10, 3), 50, np.uint8)
    obj = truth.copy()
    obj[:, :, 0] = 250  # distinguishable everywhere
    region = np.ones((4, 10), bool)
    out = truth.copy()
    out[:, :5] = obj[:, :5]
    assert leak(out, truth, [(obj, region)], region).fraction == 0.5
    # Invisible objects (within 30 of the truth) count nowhere; masked-out object pixels neither.
    faint = truth + 15  # RGB distance 26
    assert leak(out, truth, [(faint, region)], region).distinguishable == 0
    assert leak(out, truth, [(obj, np.zeros_like(region))], region).fraction is None


def test_static_skips_pairs_without_geometry():
    with pytest.raises(ProtocolSkip, match="pose"):
        static_case(planar_pairs(1)[0])


def test_telea_ignores_what_the_hole_shows(static):
    blank = static.pair.target.copy()
    blank[static.hole] = 0
    assert np.array_equal(opencv_inpaint(static.pair.target, static.hole), opencv_inpaint(blank, static.hole))


# ---------------------------------------------------------------------------------------------
# strangers


def test_strangers_cover_the_holes_background_in_the_reference(synthetic_pair):
    case = strangers_case(synthetic_pair, seed=0)
    assert np.array_equal(case.hole, pair_mask(synthetic_pair, 0))  # the restoration hole
    assert np.array_equal(case.truth, synthetic_pair.target)
    changed = np.any(case.pair.target != case.truth, axis=2)
    assert changed.any() and not np.any(changed & ~case.hole)
    (ref,) = case.info["references"]
    assert ref["mapping"].startswith("exact") and 0.3 <= ref["coverage"] <= 0.6
    assert abs(ref["coverage"] - ref["goal"]) < 0.02
    # The strangers' pixels mapped back: where the exact map lands on them, the reference's pixel.
    ((obj, mask),) = case.objects
    assert mask.sum() / case.hole.sum() == pytest.approx(ref["coverage"] * ref["hole_mapped"], abs=0.01)
    copied = np.where(mask[..., None], obj, case.truth)  # a method that copied the strangers in
    assert leak(copied, case.truth, case.objects, case.hole).fraction == 1.0
    assert leak(case.truth, case.truth, case.objects, case.hole).fraction == 0.0
    # The target's own cutout is the extra object (leak_all): showing it leaks all of it.
    assert leak(case.pair.target, case.truth, case.extra_objects, case.hole).fraction == 1.0


# ---------------------------------------------------------------------------------------------
# Runner and CLI


def test_restoration_results_keep_their_columns(tmp_path):
    run_eval(planar_pairs(1), ["opencv_inpaint"], tmp_path, contact_sheets=False)
    header = (tmp_path / "results.csv").read_text().splitlines()[0]
    assert header == (
        "pair,method,stroke_width_720p,stroke_width_px,hole_ratio,psnr,ssim,psnr_hole,ssim_hole,"
        "lpips,lpips_status,time_s,error,info"
    )
    summary = (tmp_path / "summary.md").read_text()
    assert "leak" not in summary and "protocol" not in summary and not (tmp_path / "cases.json").exists()


def test_cli_static_end_to_end(tmp_path):
    out = tmp_path / "out"
    argv = ["--pairs", "synthetic:1", "--out", str(out), "--methods", "opencv_inpaint,homography"]
    assert main_eval([*argv, "--protocol", "static"]) == 0
    rows = _read_csv(out / "results.csv")
    assert [(r["pair"], r["method"]) for r in rows] == [
        ("synthetic_000", "opencv_inpaint"),
        ("synthetic_000", "homography"),
    ]
    for r in rows:
        assert r["error"] == "" and 0.0 <= float(r["leak"]) <= float(r["leak_all"]) <= 1.0
        assert int(r["distinguishable_px"]) > 1000
    cases = json.loads((out / "cases.json").read_text())
    assert cases["synthetic_000"]["depth_from"] == "exact scene depth"
    hole = cv2.imread(str(out / "masks" / "synthetic_000.png"), cv2.IMREAD_GRAYSCALE) > 0
    assert float(rows[0]["hole_ratio"]) == pytest.approx(hole.mean())
    summary = (out / "summary.md").read_text()
    assert "- protocol: static:" in summary and "## Per set" in summary and "| leak |" in summary
    sheet = cv2.imread(str(out / "contact_synthetic_000.jpg"))
    assert sheet.shape == (2 * (300 + 24), 3 * 400, 3)  # truth, target, reference, two outputs


def test_removal_protocol_skips_and_reports(tmp_path):
    pairs = planar_pairs(1)
    rows = run_eval(pairs, ["opencv_inpaint"], tmp_path, protocol="static", contact_sheets=False)
    assert rows == []
    assert "- planar_0: static needs K" in (tmp_path / "summary.md").read_text()
    assert "skipped" in json.loads((tmp_path / "cases.json").read_text())["planar_0"]
    assert main_eval(["--pairs", "x", "--out", "o", "--sweep", "hole-size", "--protocol", "static"]) == 2


def test_cases_are_seeded():
    (pair,) = load_pairs(["synthetic:1"])
    a, b = make_case("strangers", pair, 1), make_case("strangers", pair, 1)
    assert np.array_equal(a.pair.target, b.pair.target) and np.array_equal(a.pair.source, b.pair.source)
    assert not np.array_equal(a.hole, make_case("strangers", pair, 2).hole)


@pytest.mark.skipif(not MULTIVIEW.is_dir(), reason=f"multi-view sets not found at {MULTIVIEW}")
def test_real_sets_geometry_from_meta():
    posed = {}
    for p in load_pairs([MULTIVIEW]):
        g = pair_geometry(p)
        posed[p.id] = (g.posed, sum(d is not None for d in g.depth_sources))
    assert posed["dev_mv_instantngp_fox_lower"] == (True, 0)
    assert posed["dev_mv_slambook_livingroom"] == (True, 3)
    assert posed["dev_mv_kitti_drive"][0] is False and posed["dev_mv_cotracker_apple"][0] is False
