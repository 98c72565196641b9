"""Plane-sweep stereo and its completion on synthetic scenes with exact depth and pose."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from geofill.camera import Intrinsics, make_pose
from geofill.config import FillConfig
from geofill.depth import DepthContext
from geofill.depth.stereo import (
    Hypotheses,
    aggregate,
    complete,
    displacement_span,
    hypotheses,
    inverse_depth_bounds,
    occluded_in_target,
    plane_count,
    plane_sweep,
    sweep_ncc,
    winner_take_all,
)
from geofill.pipeline import fill
from geofill.render import project_source_grid, project_source_points, source_pixel_grid
from geofill.synthetic import make_pair


def hole_projecting(sp) -> np.ndarray:
    """Source pixels whose true surface point lands in the target hole (the ones the fill needs)."""
    gt = sp.depth_source
    K_s = Intrinsics.from_matrix(sp.K_source, gt.shape[1], gt.shape[0])
    K_t = Intrinsics.from_matrix(sp.K_target, sp.hole.shape[1], sp.hole.shape[0])
    u, v, _ = project_source_grid(gt, K_s, K_t, sp.T_source_to_target)
    ui, vi = np.rint(u).astype(int), np.rint(v).astype(int)
    inside = (ui >= 0) & (ui < sp.hole.shape[1]) & (vi >= 0) & (vi < sp.hole.shape[0])
    out = np.zeros(gt.shape, bool)
    out[inside] = sp.hole[vi[inside], ui[inside]]
    return out


@pytest.fixture(
    scope="module",
    params=[
        # handheld-like orbit, with the source 40 % brighter and noise on both: NCC must not care
        {"seed": 0, "source_gain": 1.4, "noise_sigma": 2.0},
        # walking forward: no rectification, the epipole inside the image
        {"seed": 1, "motion": "forward", "baseline": 0.8},
    ],
    ids=["orbit-exposure", "forward"],
)
def case(request):
    sp = make_pair(**request.param)
    res = fill(sp.target, sp.hole, sp.source, FillConfig().updated({"depth.backend": "stereo"}))
    a = res.references[0]
    v, K = a.views, a.focal
    ctx = DepthContext(
        v.source, v.target, v.hole, K.K_source, K.K_target, a.pose, a.points, (0, 0), FillConfig().depth
    )
    sweep = plane_sweep(ctx)
    return sp, res, ctx, sweep


def rel_error(inv_depth: np.ndarray, sp) -> np.ndarray:
    z = np.linalg.norm(sp.T_source_to_target[:3, 3]) / inv_depth  # pose units -> scene units
    return np.abs(z - sp.depth_source) / sp.depth_source


def test_confident_pixels_are_accurate(case):
    sp, _, _, sweep = case
    conf = sweep.confidence >= 0.5
    rel = rel_error(sweep.inv_depth, sp)
    # measured: 69-71 % confident, median error 0.9-1.1 %, 1.6-2.2 % off by more than 10 %
    assert conf.mean() > 0.5
    assert np.median(rel[conf]) < 0.02
    assert np.mean(rel[conf] > 0.1) < 0.05


def test_hole_projecting_pixels_are_never_confident_but_completed(case):
    sp, _, ctx, sweep = case
    hp = hole_projecting(sp)
    assert hp.sum() > 2000
    # their match is hidden by the hole: the sweep must not claim it (measured: 0 of ~9-10k)
    assert np.mean(sweep.confidence[hp] >= 0.5) < 0.01
    completed = complete(sweep, ctx)
    assert np.isfinite(completed).all()
    assert sweep.bounds[0] <= completed.min() and completed.max() <= sweep.bounds[1]
    # edge-aware completion from the surroundings (measured median 5 %; the sweep's own WTA there ~30-90 %)
    assert np.median(rel_error(completed, sp)[hp]) < 0.12


def test_pipeline_uses_stereo_depth_in_pose_units(case):
    sp, res, _, _ = case
    r = res.report
    assert r.status == "reference" and r.references[0]["depth"]["backend"] == "stereo"
    assert r.references[0]["depth"]["method"] == "identity"  # no refit: the sweep used the pose itself
    assert np.nanmedian(rel_error(1.0 / res.references[0].depth.depth, sp)) < 0.02


def test_depth_bounds_cover_and_widen_the_points():
    inv = np.linspace(0.1, 0.5, 200)
    lo, hi = inverse_depth_bounds(inv)
    assert lo < 0.1 and hi > 0.5
    assert lo >= 0.02 * hi > 0


def test_hypotheses_window_around_prior_when_the_range_is_long():
    """Forward motion over a deep range moves peripheral pixels hundreds of px: those get a window
    of one-px steps centred on the prior; central pixels (near the epipole) the global range."""
    K = Intrinsics.from_focal(300.0, 200, 150)
    T = make_pose(np.eye(3), [0.0, 0.0, 1.0])
    span = displacement_span((150, 200), K, K, T, 0.02, 1.0)
    assert span[2, 2] > 32 > span[75, 100]
    hyp = hypotheses(span, np.full((150, 200), 0.3), 0.02, 1.0, 32)
    step_px = []
    for xi, yi in ((2, 2), (100, 75)):  # corner, centre
        a, b = hyp.at(10)[yi, xi], hyp.at(11)[yi, xi]
        u0, v0, _ = project_source_points(float(xi), float(yi), 1 / a, K, K, T)
        u1, v1, _ = project_source_points(float(xi), float(yi), 1 / b, K, K, T)
        step_px.append(float(np.hypot(u1 - u0, v1 - v0)))
    assert hyp.lo[2, 2] <= 0.3 <= hyp.at(31)[2, 2]  # the window contains the prior
    # window width: the share of the range that moves the match by 32 px
    assert hyp.at(31)[2, 2] - hyp.lo[2, 2] == pytest.approx(0.98 * 32 / span[2, 2])
    assert 0.3 < step_px[0] < 3.0  # about one px per step
    assert hyp.lo[75, 100] == pytest.approx(0.02) and hyp.at(31)[75, 100] == pytest.approx(1.0)


def test_winner_take_all_parabola_is_exact_on_a_parabola():
    D, true_k = 20, 7.3
    k = np.arange(D, dtype=np.float64)[:, None, None]
    score = (1.0 - 0.01 * (k - true_k) ** 2) * np.ones((1, 3, 4))
    hyp = Hypotheses(np.full((3, 4), 0.1), np.full((3, 4), 0.01), D)
    inv, _, rival, best = winner_take_all(score.astype(np.float32), hyp)
    np.testing.assert_allclose(inv, 0.1 + 0.01 * true_k, rtol=1e-5)
    assert (best == 7).all() and np.all(rival == -1.0)  # a single peak: no rival


def test_nearer_winner_hides_farther_one_in_target():
    K = Intrinsics.from_focal(100.0, 40, 30)
    T = make_pose(np.eye(3), [0.0, 0.0, 0.0])  # same camera: every pixel maps onto itself
    inv = np.full((30, 40), 0.5)
    hidden = occluded_in_target(inv, K, K, T, (30, 40))
    assert not hidden.any()
    T = make_pose(np.eye(3), [0.2, 0.0, 0.0])
    inv[:, 20:] = 0.5
    inv[:, :20] = 1.5  # left half nearer: moves 30 px in the target and covers the right half's spots
    hidden = occluded_in_target(inv, K, K, T, (30, 40))
    assert hidden[:, 20:].mean() > 0.3 and not hidden[:, :20].any()


def _reference_ncc(src, tgt, tgt_invalid, K_s, K_t, T, hyp, patch):
    """The NCC volume the straightforward way: float64 reprojection of each plane, one remap of
    the target and one of its invalid mask, single-channel box filters."""
    h, w = src.shape
    ht, wt = tgt.shape
    x, y = source_pixel_grid(h, w)

    def box(a):
        return cv2.boxFilter(a, -1, (patch, patch), borderType=cv2.BORDER_REFLECT)

    mu_s = box(src)
    var_s = np.maximum(box(src * src) - mu_s * mu_s, 0.0)
    ncc = np.empty((hyp.count, h, w), np.float32)
    valid = np.empty((hyp.count, h, w), bool)
    for i in range(hyp.count):
        u, v, z = project_source_points(x, y, 1.0 / hyp.at(i), K_s, K_t, T)
        inside = (z > 0) & (u >= 0) & (u <= wt - 1) & (v >= 0) & (v <= ht - 1)
        mu, mv = np.where(inside, u, -1).astype(np.float32), np.where(inside, v, -1).astype(np.float32)
        warped = cv2.remap(tgt, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        hit = cv2.remap(tgt_invalid.astype(np.float32), mu, mv, cv2.INTER_LINEAR, borderValue=1)
        ok = (inside & (hit == 0)).astype(np.float32)
        warped *= ok
        mu_t = box(warped)
        var_t = np.maximum(box(warped * warped) - mu_t * mu_t, 0.0)
        ncc[i] = (box(src * warped) - mu_s * mu_t) / np.sqrt(var_s * var_t + 1e-6)
        valid[i] = box(ok) > 0.999
    ncc[~valid] = 0.0
    return ncc, valid


def test_sweep_ncc_matches_the_reference_computation():
    sp = make_pair(seed=2, width=160, height=120)
    grey = [cv2.cvtColor(im.astype(np.float32) / 255, cv2.COLOR_RGB2GRAY) for im in (sp.source, sp.target)]
    K_s = Intrinsics.from_matrix(sp.K_source, 160, 120)
    K_t = Intrinsics.from_matrix(sp.K_target, 160, 120)
    T = sp.T_source_to_target
    lo, hi = inverse_depth_bounds(1.0 / sp.depth_source.ravel())
    span = displacement_span((120, 160), K_s, K_t, T, lo, hi)
    hyp = hypotheses(span, None, lo, hi, plane_count(span, 48))
    args = (*grey, sp.hole, K_s, K_t, T, hyp, 7)
    ncc, valid = sweep_ncc(*args)
    ref_ncc, ref_valid = _reference_ncc(*args)
    assert 0.3 < valid.mean() < 0.95
    # measured: no window differs in validity, NCC agrees to 3e-5 (float32 reprojection, summation
    # order); a tap on the hole edge with a weight below remap's 1/32 px step may flip validity
    assert np.mean(valid != ref_valid) < 1e-4
    both = valid & ref_valid
    assert np.abs(ncc - ref_ncc)[both].max() < 1e-3
    assert np.percentile(np.abs(ncc - ref_ncc)[both], 99.9) < 1e-4
    assert not ncc[~valid].any()


@pytest.mark.parametrize("count", [6, 7])
def test_aggregate_is_the_guided_filter(count):
    rng = np.random.default_rng(count)
    guide = cv2.GaussianBlur(rng.random((50, 70), dtype=np.float32), (0, 0), 2.0)
    cost = rng.random((count, 50, 70), dtype=np.float32) * 2 - 1
    gf = cv2.ximgproc.createGuidedFilter(guide, 4, 1e-3)
    expected = np.stack([gf.filter(c) for c in cost])
    # measured: max difference 9e-6
    np.testing.assert_allclose(aggregate(cost.copy(), guide, 4), expected, atol=5e-5)


def _reference_winner_take_all(score, hyp):
    """Winner-take-all by whole-volume NumPy passes (argmax, peak mask, masked max, parabola)."""
    D = hyp.count
    best = np.argmax(score, axis=0)
    s1 = np.take_along_axis(score, best[None], 0)[0]
    peak = np.ones(score.shape, bool)
    peak[1:] &= score[1:] >= score[:-1]
    peak[:-1] &= score[:-1] >= score[1:]
    idx = np.arange(D)[:, None, None]
    rival = np.where(peak & (np.abs(idx - best[None]) > 2), score, -np.inf).max(axis=0)
    rival = np.maximum(rival, -1.0)
    k = np.clip(best, 1, D - 2)
    a, b, c = (np.take_along_axis(score, (k + d)[None], 0)[0] for d in (-1, 0, 1))
    curv = a - 2 * b + c
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where(curv < 0, 0.5 * (a - c) / curv, 0.0)
    off = np.where((best >= 1) & (best <= D - 2), np.clip(off, -0.5, 0.5), 0.0)
    return hyp.at(best + off).astype(np.float32), s1, rival, best


def test_winner_take_all_equals_the_volume_passes_exactly():
    rng = np.random.default_rng(3)
    D, h, w = 24, 30, 40
    # smooth along the planes so that peaks have shoulders, quantised so that ties occur (28 % of
    # the pixels have a tied best score)
    score = cv2.GaussianBlur(rng.random((D, h * w), dtype=np.float32), (1, 0), sigmaX=0.1, sigmaY=1.5)
    score = (np.round(score.reshape(D, h, w) * 64) / 64).astype(np.float32)
    hyp = Hypotheses(0.1 + 0.01 * rng.random((h, w)), np.full((h, w), 0.004), D)
    for got, want in zip(winner_take_all(score, hyp), _reference_winner_take_all(score, hyp), strict=True):
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)
