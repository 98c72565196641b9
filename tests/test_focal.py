"""Focal-length priors (flag / EXIF / default) and estimation from the pair (geofill.focal)."""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from geofill.camera import Intrinsics, default_focal_px, make_pose, pose_errors_deg
from geofill.config import FillConfig, IntrinsicsConfig
from geofill.focal import _EpipolarFit, bougnoux_candidate, bougnoux_focals, estimate_focal
from geofill.intrinsics import resolve_intrinsics
from geofill.io import ExifCamera
from geofill.match import Matches, match_pair
from geofill.pipeline import fill
from geofill.pose import estimate_pose
from geofill.synthetic import make_pair

CFG = FillConfig()


@lru_cache(maxsize=8)  # tests share scenes; nothing mutates them
def synthetic_matches(width, height, focal_scale, motion="orbit", source_focal_scale=None, seed=0):
    """Rendered pair (orbit: 1 unit sideways turning ~9.5 deg back onto the scene centre) and its
    verified SIFT matches. The default 0.5-unit orbit turns only 4.8 deg: its optical axes meet
    almost equidistantly from both centres, which is close to the critical configuration of
    equal-focal two-view calibration (Sturm 2001), and SIFT's localisation bias then moves the
    estimate by up to 10 % (benchmarks/studies/focal_bench.py)."""
    f0 = default_focal_px(width, height)
    pair = make_pair(
        seed=seed,
        width=width,
        height=height,
        focal_px=f0 * focal_scale,
        source_focal_px=None if source_focal_scale is None else f0 * source_focal_scale,
        motion=motion,
        baseline=1.0 if motion == "orbit" else None,
    )
    px_scale = max(width, height) / 1280
    m = match_pair(pair.target / 255.0, pair.source / 255.0, pair.hole, CFG.matching, px_scale)
    return pair, m, CFG.matching.ransac_threshold_px * max(px_scale, 0.5)


def default_prior(width, height):
    return resolve_intrinsics(width, height, CFG.intrinsics, None)


# ---------------------------------------------------------------------------------------------
# Priors


def test_default_prior_scales_with_long_side_and_is_uncertain():
    K = default_prior(720, 1280)  # portrait
    assert K.fx == pytest.approx(750.0) and K.origin == "default"
    assert K.rel_uncertainty == CFG.intrinsics.prior_sigma_default


def test_exif_35mm_equivalent_in_pixels():
    # 26 mm equivalent on a 4:3 image: f = 26 / 43.27 mm x diagonal (5000 px at 4000x3000).
    K = resolve_intrinsics(4000, 3000, CFG.intrinsics, ExifCamera(focal_35mm=26.0))
    assert K.fx == pytest.approx(26.0 * 5000.0 / np.hypot(36.0, 24.0))
    assert K.origin == "exif" and K.rel_uncertainty == CFG.intrinsics.prior_sigma_exif


def test_exif_focal_length_times_focal_plane_resolution_scaled_to_current_size():
    # 4 mm lens, 750 px/mm on a 4000x3000 original; the image was resized to 2000x1500.
    exif = ExifCamera(
        focal_mm=4.0, focal_plane_x_res=750.0, focal_plane_y_res=750.0, original_size=(4000, 3000)
    )
    K = resolve_intrinsics(2000, 1500, CFG.intrinsics, exif)
    assert K.fx == pytest.approx(4.0 * 750.0 * 0.5) and K.origin == "exif"
    # The same photo delivered in portrait (io swaps x/y with the orientation): same focal.
    portrait = ExifCamera(
        focal_mm=4.0, focal_plane_x_res=750.0, focal_plane_y_res=750.0, original_size=(3000, 4000)
    )
    assert resolve_intrinsics(1500, 2000, CFG.intrinsics, portrait).fx == pytest.approx(1500.0)
    # Non-square resolution tags: the mean of both axes.
    skew = replace(exif, focal_plane_y_res=850.0)
    assert resolve_intrinsics(2000, 1500, CFG.intrinsics, skew).fx == pytest.approx(4.0 * 800.0 * 0.5)


def test_exif_priority_and_missing_fields():
    both = ExifCamera(focal_35mm=26.0, focal_mm=4.0, focal_plane_x_res=750.0, original_size=(4000, 3000))
    assert resolve_intrinsics(4000, 3000, CFG.intrinsics, both).fx == pytest.approx(
        26.0 * 5000.0 / 43.2666, 1e-4
    )
    no_size = ExifCamera(focal_mm=4.0, focal_plane_x_res=750.0)  # resolution of an unknown image size
    assert resolve_intrinsics(4000, 3000, CFG.intrinsics, no_size).origin == "default"
    off = IntrinsicsConfig(use_exif=False)
    assert resolve_intrinsics(4000, 3000, off, ExifCamera(focal_35mm=26.0)).origin == "default"


def test_flags_win_and_are_never_estimated():
    cfg = IntrinsicsConfig(focal_px=900.0)
    K = resolve_intrinsics(1280, 720, cfg, ExifCamera(focal_35mm=26.0))
    assert (K.fx, K.origin, K.rel_uncertainty) == (900.0, "flag", 0.0)
    _, m, thr = synthetic_matches(480, 360, 1.5)
    Kf = resolve_intrinsics(480, 360, cfg, None)
    est = estimate_focal(m, Kf, Kf, cfg, thr)
    assert est.status == "given" and est.K_target == Kf and est.K_source == Kf


# ---------------------------------------------------------------------------------------------
# Estimation on rendered scenes


@pytest.mark.parametrize("size", [(480, 360), (360, 480)], ids=["landscape", "portrait"])
@pytest.mark.parametrize("focal_scale", [0.5, 1.0, 2.0])
def test_search_recovers_focal_and_pose(size, focal_scale):
    pair, m, thr = synthetic_matches(*size, focal_scale)
    K0 = default_prior(*size)
    est = estimate_focal(m, K0, K0, CFG.intrinsics, thr)
    assert est.status == "estimated" and est.method == "search"
    true_f = pair.K_target[0, 0]
    assert est.K_target.fx == pytest.approx(true_f, rel=0.05)
    assert est.K_source.fx == pytest.approx(true_f, rel=0.05)
    assert est.K_target.origin == "estimated" and 0.05 < est.K_target.rel_uncertainty < 0.3
    pose = estimate_pose(m, est.K_target, est.K_source, CFG.geometry, CFG.matching)
    r_err, t_err = pose_errors_deg(pose.T, pair.T_source_to_target)
    assert r_err < 0.5 and t_err < 2.0


def test_essential_matrix_fit_reaches_scipys_minimum():
    # The search's per-scale fit (its own trust-region Gauss-Newton) against SciPy's
    # least_squares on the same robust Sampson cost, with SciPy's own parametrisation and
    # finite-difference Jacobian, from the same start.
    _, m, thr = synthetic_matches(640, 480, 1.0)
    K = default_prior(640, 480)
    fit = _EpipolarFit(m, K, K, (True, True), thr, CFG.intrinsics.search_max_matches)
    for scale in (0.7, 1.0, 1.4):
        R0, t0 = fit.initial_pose(scale, m.F)
        cost, res, (R, t) = fit.fit(scale, R0, t0)
        f_t, f_s = fit.focals(scale)
        u, v = np.linalg.svd(t0[None])[2][1:]  # tangent basis at t0

        def pose(x, R0=R0, t0=t0, u=u, v=v):
            w = t0 / np.linalg.norm(t0) + x[3] * u + x[4] * v
            return Rotation.from_rotvec(x[:3]).as_matrix() @ R0, w / np.linalg.norm(w)

        def sampson(x, f_t=f_t, f_s=f_s, pose=pose):
            R_x, t_x = pose(x)
            E = np.array([[0, -t_x[2], t_x[1]], [t_x[2], 0, -t_x[0]], [-t_x[1], t_x[0], 0]]) @ R_x
            return fit.residuals(E[None], f_t, f_s)[0]

        ref = least_squares(sampson, np.zeros(5), loss="soft_l1", f_scale=thr)
        R_ref, t_ref = pose(ref.x)
        assert cost == pytest.approx(2.0 * ref.cost, rel=1e-7)
        assert res == pytest.approx(ref.fun, abs=1e-5)
        errors = pose_errors_deg(make_pose(R, t), make_pose(R_ref, t_ref))
        assert max(errors) < 1e-3


def test_only_the_image_without_a_flag_is_estimated():
    # Target calibrated (flag); the source has its own, unknown focal 1.6x the default.
    pair, m, thr = synthetic_matches(480, 360, 1.0, source_focal_scale=1.6)
    K_t = Intrinsics.from_matrix(pair.K_target, 480, 360, "flag")
    K_t = replace(K_t, rel_uncertainty=0.0)
    est = estimate_focal(m, K_t, default_prior(480, 360), CFG.intrinsics, thr)
    assert est.K_target == K_t
    assert est.K_source.fx == pytest.approx(pair.K_source[0, 0], rel=0.05)


@pytest.mark.parametrize("motion", ["sideways", "forward"])
def test_parallel_optical_axes_keep_the_prior_with_a_reason(motion):
    _, m, thr = synthetic_matches(480, 360, 2.0, motion=motion)
    K0 = default_prior(480, 360)
    est = estimate_focal(m, K0, K0, CFG.intrinsics, thr)
    assert est.status == "prior"
    assert est.K_target == K0 and est.K_source == K0  # 2x off, but unobservable: not moved
    assert "unobservable" in est.reason and "parallel" in est.reason


def test_exif_prior_wins_by_default_is_refined_when_trusted_less_and_kept_when_contradicted():
    pair, m, thr = synthetic_matches(480, 360, 1.0)
    true_f = pair.K_target[0, 0]
    cfg = CFG.intrinsics
    near = Intrinsics.from_focal(1.06 * true_f, 480, 360, "exif", cfg.prior_sigma_exif)
    est = estimate_focal(m, near, near, cfg, thr)
    assert est.status == "prior" and est.K_target == near  # +-5 % EXIF beats the pair's +-10 %
    assert "unobservable" in est.reason
    loose = replace(cfg, prior_sigma_exif=0.3)
    near = replace(near, rel_uncertainty=loose.prior_sigma_exif)
    est = estimate_focal(m, near, near, loose, thr)
    assert est.status == "estimated"
    assert abs(est.K_target.fx / true_f - 1) < 0.03  # moved from +6 % towards the truth
    assert est.K_target.rel_uncertainty < loose.prior_sigma_exif
    wrong = Intrinsics.from_focal(2.0 * true_f, 480, 360, "exif", cfg.prior_sigma_exif)
    est = estimate_focal(m, wrong, wrong, cfg, thr)
    assert est.status == "prior" and est.K_target == wrong
    assert "contradicts the prior" in est.reason


def test_failed_estimation_keeps_the_prior_with_the_reason():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0.0, 400.0, (30, 2))
    pts[3] = np.nan  # least squares refuses non-finite residuals
    K0 = default_prior(640, 480)
    est = estimate_focal(Matches(pts, pts + 5.0, rng.normal(size=(3, 3)), 30, 30, 30), K0, K0, CFG.intrinsics)
    assert est.status == "prior" and est.K_target == K0 and "failed" in est.reason


def test_estimation_off_keeps_the_prior():
    _, m, thr = synthetic_matches(480, 360, 2.0)
    K0 = default_prior(480, 360)
    est = estimate_focal(m, K0, K0, IntrinsicsConfig(estimate="none"), thr)
    assert est.status == "prior" and est.K_target == K0 and "off" in est.reason


# ---------------------------------------------------------------------------------------------
# Bougnoux's closed form


def test_bougnoux_formula_is_exact_for_general_cameras():
    K_t = Intrinsics(800.0, 800.0, 330.0, 250.0, 640, 480)
    K_s = Intrinsics(1250.0, 1250.0, 510.0, 290.0, 1024, 600)
    rng = np.random.default_rng(3)
    for _ in range(3):
        T = make_pose(Rotation.from_rotvec(rng.normal(0.0, 0.2, 3)).as_matrix(), rng.normal(0.0, 1.0, 3))
        t = T[:3, 3]
        E = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]]) @ T[:3, :3]
        F = K_t.K_inv.T @ E @ K_s.K_inv
        f2_t, f2_s = bougnoux_focals(F, (K_t.cx, K_t.cy), (K_s.cx, K_s.cy))
        assert np.sqrt(f2_t) == pytest.approx(800.0, rel=1e-6)
        assert np.sqrt(f2_s) == pytest.approx(1250.0, rel=1e-6)


def test_bougnoux_refuses_parallel_optical_axes():
    _, m, _ = synthetic_matches(480, 360, 2.0, motion="sideways")
    K0 = default_prior(480, 360)
    cand = bougnoux_candidate(m, K0, K0, (True, True), 1.0, CFG.intrinsics)
    assert not cand.ok and "parallel" in cand.reason


# ---------------------------------------------------------------------------------------------
# Pipeline report


def test_fill_reports_focal_origin_uncertainty_and_candidates():
    pair = make_pair(seed=0, width=480, height=360, focal_px=1.6 * default_focal_px(480, 360), baseline=1.0)
    report = fill(pair.target, pair.hole, pair.source).report
    assert report.references[0]["intrinsics_target"]["origin"] == "estimated"
    assert report.references[0]["intrinsics_target"]["fx_px"] == pytest.approx(pair.K_target[0, 0], rel=0.05)
    assert 0.0 < report.references[0]["intrinsics_target"]["rel_uncertainty"] < 0.3
    focal = report.references[0]["focal"]
    assert focal["status"] == "estimated" and focal["method"] == "search"
    assert focal["prior_origin_target"] == "default"
    assert focal["scale_target"] == pytest.approx(1.6, rel=0.05)
    assert len(focal["profile"]) == CFG.intrinsics.search_steps
    assert {"scale", "cost", "inliers", "median_px"} <= set(focal["profile"][0])
    assert focal["candidates"][0]["ok"] and "focal" in report.timings_s
    r_err, t_err = pose_errors_deg(
        np.array(report.references[0]["pose"]["source_to_target"]), pair.T_source_to_target
    )
    assert r_err < 0.5 and t_err < 2.0
