"""The matching ladder on rendered scenes with exact geometry: easy pairs stop at plain SIFT, a
climb keeps true correspondences and the best rung, the budget stops it, guided matching stays on
the epipolar lines, and degenerate or out-of-range inputs never raise from OpenCV."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from functools import partial

import numpy as np
import pytest

from geofill.config import FillConfig, MatchingConfig
from geofill.errors import ConfigError
from geofill.match import MIN_MATCHES_FOR_F, Matches, match_pair
from geofill.match.features import (
    detect_sift,
    detect_sift_pair,
    epipolar_band,
    keypoint_mask,
    mutual_ratio_matches,
    to_gray_u8,
)
from geofill.match.ladder import hole_support, sampson_px, verify_essential, verify_fundamental
from geofill.synthetic import SyntheticPair, make_pair

SCALE = 320 / 1280
#: Keeps the ASIFT rung small on 320x240 renders (the matching cost grows with the product).
SMALL_ASIFT = {"asift_max_features": 3000, "asift_max_tilt": 3}
#: The SIFT ladder alone: the same rungs whether or not the learned extra is installed.
SiftLadder = partial(MatchingConfig, learned="off")


@pytest.fixture(scope="module")
def wide() -> SyntheticPair:
    """A 33-degree orbit of the default scene, hole blanked as the pipeline does."""
    p = make_pair(0, baseline=4.0)
    p.target[p.hole] = 0
    return p


def _reprojection_px(p: SyntheticPair, pts_t: np.ndarray, pts_s: np.ndarray) -> np.ndarray:
    """Distance (px) between each source point and its target point moved with the exact depth and pose."""
    z = p.scene.depth_at(p.K_target, p.target_to_world, pts_t)
    X_t = np.c_[pts_t, np.ones(len(pts_t))] @ np.linalg.inv(p.K_target).T * z[:, None]
    T_inv = np.linalg.inv(p.T_source_to_target)
    proj = (X_t @ T_inv[:3, :3].T + T_inv[:3, 3]) @ p.K_source.T
    return np.linalg.norm(proj[:, :2] / proj[:, 2:] - pts_s, axis=1)


def _true_F(p: SyntheticPair) -> np.ndarray:
    R, t = p.T_source_to_target[:3, :3], p.T_source_to_target[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return np.linalg.inv(p.K_target).T @ tx @ R @ np.linalg.inv(p.K_source)


def test_easy_pair_stops_at_plain_sift(wide: SyntheticPair) -> None:
    ladder = match_pair(wide.target, wide.source, wide.hole, SiftLadder(), SCALE)
    plain = match_pair(wide.target, wide.source, wide.hole, SiftLadder(max_rung="sift"), SCALE)
    assert ladder.rung == "sift" and ladder.verified and not ladder.budget_spent
    assert [r.rung for r in ladder.rungs] == ["sift"]
    # Exactly the matches plain SIFT gives: an easy pair pays nothing for the ladder.
    np.testing.assert_array_equal(ladder.pts_target, plain.pts_target)
    np.testing.assert_array_equal(ladder.pts_source, plain.pts_source)
    assert ladder.rungs[0].n_verified == len(ladder) >= 60  # measured 100
    assert "rung sift (verified)" in ladder.summary()


def test_climb_keeps_true_matches_and_the_best_rung(wide: SyntheticPair) -> None:
    # A bar no rung reaches: every rung runs, and the richest geometry is returned as weak.
    cfg = SiftLadder(min_verified=100_000, time_budget_s=600.0, **SMALL_ASIFT)
    m = match_pair(wide.target, wide.source, wide.hole, cfg, SCALE)
    by_rung = {r.rung: r for r in m.rungs}
    assert list(by_rung) == ["sift", "loose", "asift", "guided"]
    assert not m.verified and all("100000" in r.weak for r in m.rungs)
    assert (
        len(m) == max(r.n_verified for r in m.rungs)
        and m.rung == max(m.rungs, key=lambda r: r.n_verified).rung
    )
    # What the climb returns is right (measured 96 %; a 0.9 guided ratio gave 142 matches but
    # only 77 % right: epipolar-consistent false matches pass F verification by construction).
    assert np.mean(_reprojection_px(wide, m.pts_target, m.pts_source) < 2.0) > 0.9
    assert len(m.notes) == 4 and m.notes[0].startswith("rung sift weak")


def test_budget_stops_the_ladder_after_the_first_rung(wide: SyntheticPair) -> None:
    m = match_pair(
        wide.target, wide.source, wide.hole, SiftLadder(min_verified=100_000, time_budget_s=0.0), SCALE
    )
    assert [r.rung for r in m.rungs] == ["sift"]
    assert m.budget_spent and m.notes[-1] == "time budget 0 s spent before rung loose"
    assert len(m) > 0  # the weak geometry is still handed on; the pose stage decides


def test_hole_support_climbs_when_the_hole_is_far_from_every_match(wide: SyntheticPair) -> None:
    # Plenty of matches, but few within 4 px of the hole: the sift rung is weak by support alone.
    cfg = SiftLadder(hole_support_radius_px=4.0, min_hole_support=0.99, max_rung="loose")
    m = match_pair(wide.target, wide.source, wide.hole, cfg, SCALE)
    assert m.rungs[0].n_verified >= cfg.min_verified
    assert "of the hole near a verified match" in m.rungs[0].weak and len(m.rungs) == 2


def test_hole_support_fraction() -> None:
    hole = np.zeros((100, 100), bool)
    hole[40:60, 40:60] = True
    assert hole_support(hole, np.array([[50.0, 30.0]]), 20.0) == pytest.approx(
        np.mean([np.hypot(x - 50, y - 30) <= 20 for y in range(40, 60) for x in range(40, 60)]), abs=0.03
    )
    assert hole_support(hole, np.zeros((0, 2)), 20.0) == 0.0


def test_guided_matching_stays_in_the_epipolar_band(wide: SyntheticPair) -> None:
    rng = np.random.default_rng(0)
    pts_t = rng.uniform(0, 320, (200, 2))
    pts_s = rng.uniform(0, 320, (300, 2))
    F = _true_F(wide)
    band = epipolar_band(pts_t, pts_s, F, 2.0)
    line = np.c_[pts_s, np.ones(300)] @ F.T
    dist = np.abs(np.sum(np.c_[pts_t, np.ones(200)][:, None, :] * line[None], axis=2)) / np.hypot(
        line[:, 0], line[:, 1]
    )
    np.testing.assert_array_equal(band, dist < 2.0)
    # Identical descriptors everywhere: unguided, the ratio test rejects everything; guided, a
    # target point whose band holds a single candidate is matched to it.
    desc = np.full((300, 128), 1 / np.sqrt(128), np.float32)
    assert len(mutual_ratio_matches(desc[:200], desc, 0.9, False)) == 0
    pairs = mutual_ratio_matches(desc[:200], desc, 0.9, False, band)
    single = np.flatnonzero(band.sum(axis=1) == 1)
    assert set(pairs[:, 0]) == set(single)
    assert band[pairs[:, 0], pairs[:, 1]].all()


def _brute_force_matches(a: np.ndarray, b: np.ndarray, ratio: float, mutual: bool) -> set[tuple[int, int]]:
    """The ratio test and mutual check spelled out on float64 Euclidean distances."""
    d = np.linalg.norm(a[:, None].astype(np.float64) - b[None], axis=2)
    out = set()
    for i, row in enumerate(d):
        j, k = np.argsort(row, kind="stable")[:2]
        if row[j] < ratio * row[k] and (not mutual or np.argmin(d[:, j]) == i):
            out.add((i, int(j)))
    return out


@pytest.mark.parametrize("mutual", [True, False])
def test_matrix_matching_equals_brute_force_distances(wide: SyntheticPair, mutual: bool) -> None:
    ft = detect_sift(to_gray_u8(wide.target), 600)
    fs = detect_sift(to_gray_u8(wide.source), 600)
    got = mutual_ratio_matches(ft.desc, fs.desc, 0.8, mutual)
    want = _brute_force_matches(ft.desc, fs.desc, 0.8, mutual)
    assert len(want) > 50
    assert set(map(tuple, got.tolist())) == want
    assert np.all(np.diff(got[:, 0]) > 0)  # rows in order, each at most once


def test_sift_pair_in_two_threads_equals_one_after_the_other(wide: SyntheticPair) -> None:
    grays = (to_gray_u8(wide.target), to_gray_u8(wide.source))
    masks = (keypoint_mask(wide.hole, 8.0), None)
    pair = detect_sift_pair(grays, 0, masks)
    for got, g, m in zip(pair, grays, masks, strict=True):
        want = detect_sift(g, 0, m)
        assert len(got) > 100
        np.testing.assert_array_equal(got.pts, want.pts)
        np.testing.assert_array_equal(got.desc, want.desc)


def test_references_of_one_target_share_its_sift_features(wide: SyntheticPair, monkeypatch) -> None:
    """Four references matched in parallel threads against one target: the target's SIFT runs
    once (the others wait for it), each source once, and every result equals its own detection."""
    from concurrent.futures import ThreadPoolExecutor

    import geofill.match.features as features

    grays_t = to_gray_u8(wide.target)
    mask_t = keypoint_mask(wide.hole, 8.0)
    sources = [to_gray_u8(np.roll(wide.source, 7 * k, axis=1)) for k in range(4)]
    calls: list[int] = []
    detect = features.detect_sift
    monkeypatch.setattr(features, "_targets", type(features._targets)())  # nothing cached by other tests
    monkeypatch.setattr(features, "detect_sift", lambda g, *a: calls.append(id(g)) or detect(g, *a))
    with ThreadPoolExecutor(2) as pool:
        pairs = list(pool.map(lambda s: detect_sift_pair((grays_t, s), 0, (mask_t, None)), sources))
    assert calls.count(id(grays_t)) == 1
    assert len(calls) == 5
    want_t = detect(grays_t, 0, mask_t)
    for (got_t, got_s), s in zip(pairs, sources, strict=True):
        np.testing.assert_array_equal(got_t.pts, want_t.pts)
        np.testing.assert_array_equal(got_t.desc, want_t.desc)
        np.testing.assert_array_equal(got_s.pts, detect(s, 0, None).pts)
    # Another mask of the same target is another target.
    detect_sift_pair((grays_t, sources[0]), 0, (np.zeros_like(mask_t), None))
    assert calls.count(id(grays_t)) == 2


@pytest.mark.parametrize(
    "pts",
    [
        np.c_[np.linspace(0, 100, 20), np.linspace(0, 50, 20)],  # collinear
        np.repeat([[10.0, 10.0], [50.0, 20.0], [30.0, 90.0]], 7, axis=0),  # three repeated points
        np.zeros((MIN_MATCHES_FOR_F - 1, 2)),  # too few
    ],
)
def test_degenerate_match_sets_give_no_geometry_instead_of_raising(pts: np.ndarray) -> None:
    F, keep = verify_fundamental(pts, pts + 3.0, 1.0, MatchingConfig())
    assert keep.shape == (len(pts),)
    if F is None:
        assert not keep.any()


@pytest.mark.parametrize("side", [64, 96, 150])
def test_featureless_and_repetitive_images_never_raise(side: int) -> None:
    flat = np.full((side, side + 20, 3), 128, np.uint8)
    hole = np.zeros(flat.shape[:2], bool)
    hole[side // 3 : side // 2, side // 3 : side // 2] = True
    m = match_pair(flat, flat, hole, SiftLadder(), side / 1280)
    assert m.too_few and len(m) == 0 and m.F is None and not m.verified
    # A periodic pattern: many identical descriptors, matches at repeated positions.
    yy, xx = np.mgrid[0:side, 0 : side + 20]
    stripes = np.repeat((((xx // 6 + yy // 6) % 2) * 255).astype(np.uint8)[..., None], 3, axis=2)
    m = match_pair(stripes, np.roll(stripes, 3, axis=1), hole, SiftLadder(time_budget_s=1.0), side / 1280)
    assert m.pts_target.shape == m.pts_source.shape == (len(m), 2)


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("matching.max_features", 10**12),
        ("matching.ransac_max_iters", 10**10),
        ("matching.ratio", 1.5),
        ("matching.ransac_threshold_px", float("nan")),
        ("matching.time_budget_s", -1.0),
        ("matching.asift_max_tilt", 0),
    ],
)
def test_out_of_range_settings_are_refused_with_their_key(key: str, value: float) -> None:
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        FillConfig().updated({key: value})


def test_focal_keeps_the_prior_when_the_matches_did_not_verify():
    from dataclasses import replace

    from geofill.camera import Intrinsics
    from geofill.config import IntrinsicsConfig
    from geofill.focal import estimate_focal

    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 300, (60, 2))
    K = Intrinsics.from_focal(300.0, 320, 240)
    m = Matches(pts, pts + 3.0, np.eye(3), 60, 60, 60, rung="asift", verified=False)
    est = estimate_focal(m, K, K, IntrinsicsConfig())
    assert est.status == "prior" and "unverified asift rung" in est.reason
    assert est.K_target.fx == K.fx
    assert estimate_focal(replace(m, verified=True), K, K, IntrinsicsConfig()).reason != est.reason


def test_downsized_sift_reports_positions_in_the_images_pixels() -> None:
    """``matching.sift_max_side``: matches found on a 2x smaller copy land on true correspondences
    of the full-size pair (a 640x480 render matched at a 320-px long side)."""
    p = make_pair(0, width=640, height=480, baseline=2.0)
    p.target[p.hole] = 0
    full = match_pair(p.target, p.source, p.hole, SiftLadder(max_rung="sift"), 0.5)
    small = match_pair(p.target, p.source, p.hole, SiftLadder(max_rung="sift", sift_max_side=320), 0.5)
    assert len(small) >= 40 and len(small) < len(full)
    err_small = _reprojection_px(p, small.pts_target, small.pts_source)
    err_full = _reprojection_px(p, full.pts_target, full.pts_source)
    # Opposite half-pixel offsets in the mapping back show as a median error of 1.4 px.
    assert np.median(err_small) < 0.4 and np.median(err_full) < 0.2  # measured 0.19 and 0.10


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc arenas")
def test_memory_freed_in_worker_threads_goes_back_to_the_system() -> None:
    """What SIFT's threads free stays in glibc's per-thread arenas until released (4K fills held
    ~0.2 GB of it to the end); ``release_free_memory`` gives it back."""
    code = textwrap.dedent(
        """
        import threading, numpy as np
        from geofill.match.features import release_free_memory
        def rss_mb():
            with open("/proc/self/statm") as f:
                return int(f.read().split()[1]) * 4096 / 2**20
        np.ones(30 << 20, np.uint8)  # once a 30 MB block is freed, glibc keeps smaller ones in arenas
        base = rss_mb()
        def work():
            blocks = [np.ones(8 << 20, np.uint8) for _ in range(20)]
            del blocks
        threads = [threading.Thread(target=work) for _ in range(2)]
        for t in threads: t.start()
        for t in threads: t.join()
        held = rss_mb()
        release_free_memory()
        print(base, held, rss_mb())
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    base, held, after = (float(v) for v in out.stdout.split())
    # Measured: base 73 MB, held 241-298 MB (how many arenas the threads used varies run to run),
    # after 73-129 MB; without the release it stays at held. At least half of it must come back.
    assert held - base > 100 and after < held - 0.5 * (held - base)


def test_essential_verification_rejects_matches_a_period_apart_on_a_wallpaper() -> None:
    """A wall with repeated texture seen from two cameras 30 degrees apart: 60 true matches on the
    wall, 25 on an object before it, and 60 wall matches one period (0.5 m) off. The shifted ones
    fit a fundamental matrix of the wall's family together with the true wall matches, so F keeps
    them; an essential matrix (focal prior 20% off, scanned) keeps the true matches only."""
    rng = np.random.default_rng(0)
    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    a = np.deg2rad(30)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    t = np.array([-2.0, 0.0, 0.5])

    def project(P: np.ndarray, moved: bool = False) -> np.ndarray:
        q = ((P @ R.T + t) if moved else P) @ K.T
        return q[:, :2] / q[:, 2:]

    wall = np.c_[rng.uniform(-1.5, 1.5, (60, 2)), np.full(60, 4.0)]
    thing = np.c_[rng.uniform(-0.6, 0.6, (25, 2)), rng.uniform(2.0, 3.0, 25)]
    repeat = np.c_[rng.uniform(-1.5, 1.5, (60, 2)), np.full(60, 4.0)]
    pts_s = np.concatenate([project(wall), project(thing), project(repeat)])
    pts_t = np.concatenate([project(wall, True), project(thing, True), project(repeat + [0.5, 0, 0], True)])
    pts_t += rng.normal(0, 0.3, pts_t.shape)
    true = np.r_[np.ones(85, bool), np.zeros(60, bool)]
    _, by_f = verify_fundamental(pts_t, pts_s, 1.0, MatchingConfig())
    assert by_f[~true].sum() >= 55  # the failure: the wrong plane-family geometry
    prior = K.copy()
    prior[:2, :2] *= 0.8
    F, by_e = verify_essential(pts_t, pts_s, 1.0, (prior, prior))
    assert by_e[true].sum() >= 0.85 * true.sum() and by_e[~true].sum() <= 0.25 * (~true).sum()
    # The returned F is the calibrated geometry's: the true matches lie on its epipolar lines.
    assert np.median(sampson_px(F, pts_t[true], pts_s[true])) < 1.0
