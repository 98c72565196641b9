"""Whether a pair's matches can tell its focal length: the ground-truth camera configuration, the
focal stage's profile on the fill's own matches, and the same profile on ideal matches of the same
scene and motion. Needs the ``learned`` extra for the fox pair's matches to be right.

    PYTHONPATH=src <venv>/bin/python benchmarks/studies/focal_observability.py [--pair DIR ...]
                                                                               [--noise-px 0 0.5]

Per pair (default: the fox pair, whose focal the fill cannot pin down, and two wide pairs whose
focal it can, for contrast):

1. The ground-truth configuration. Two views leave one unknown focal unobservable when the optical
   axes meet at a point equidistant from both centres (Sturm, "On focal length calibration from
   two views", CVPR 2001): printed are the angle between the axes, the gap between them at their
   closest approach (as a fraction of the baseline) and the distances from each centre to that
   closest approach.
2. The fill's verified matches (the evaluation's seed-0 hole blanked, the fill's ladder and focal
   prior): per scale of the prior focal on the focal stage's grid, the search's robust Sampson cost
   (:func:`geofill.focal.search_focal`), its inliers, and the rotation error against the ground
   truth of the pose of the essential matrix fitted at that focal; then the search's answer and
   Bougnoux's closed form (:func:`geofill.focal.bougnoux_candidate`).
3. Ideal matches: the verified matches triangulated with the true K and pose and projected back,
   with Gaussian noise of ``--noise-px`` (the same points, the same motion, no matching error, no
   lens distortion); the same profile and answer.
4. Where meta.json gives the lens distortion (``dist_coeffs_opencv``): the fill's matches and
   XFeat + LighterGlue's at costlier ``--budgets`` (KEYPOINTS@LONG_SIDE, essential-verified as the
   ladder's re-check does), as they are and undistorted with the true coefficients (which a fill
   without calibration does not know; the learned matches are verified after undistortion, the
   fill's as they were selected); the same profile and answer.

A profile that is flat (the cost within a few percent of its minimum) over a range of focal lengths
says the pair cannot tell them apart. Figures, not a test.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from geofill.camera import Intrinsics, pose_errors_deg
from geofill.config import FillConfig
from geofill.evaluation.pairs import load_pair, pair_mask
from geofill.focal import bougnoux_candidate, prior_sigma, search_focal
from geofill.match.features import keypoint_mask, to_gray_u8
from geofill.match.ladder import verify_essential
from geofill.match.xfeat import XFeatLighterGlue
from geofill.pipeline import ReferenceArtifacts, prepare_fill, run_reference

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import PAIRS

DEFAULT_PAIRS = (
    "dev_wide_instantngp_fox_0001_to_0022",
    "dev_wide_icl_livingroom_f3_to_f1",
    "dev_wide_slambook_livingroom_f1_to_f2",
)


def axes_configuration(T: np.ndarray) -> tuple[float, float, float, float]:
    """(angle between the optical axes in deg, their gap at the closest approach / baseline,
    distance of that approach from the target centre, from the source centre) of the pose ``T``
    (source -> target)."""
    R, t = T[:3, :3], T[:3, 3]
    z, d = np.array([0.0, 0.0, 1.0]), R[:, 2]  # the axes in target coordinates: a z and t + b d
    angle = float(np.degrees(np.arccos(np.clip(z @ d, -1.0, 1.0))))
    a, b = np.linalg.lstsq(np.array([[1.0, -(z @ d)], [z @ d, -1.0]]), np.array([t @ z, t @ d]), rcond=None)[
        0
    ]
    gap = float(np.linalg.norm(a * z - (t + b * d)) / np.linalg.norm(t))
    return angle, gap, float(a), float(b)


def _scaled(K: Intrinsics, s: float) -> Intrinsics:
    return replace(K, fx=K.fx * s, fy=K.fy * s)


def _rotation_error(pt, ps, K_t: Intrinsics, K_s: Intrinsics, T_gt, thr_px: float) -> float:
    a = cv2.undistortPoints(ps[:, None].astype(np.float64), K_s.K, None)
    b = cv2.undistortPoints(pt[:, None].astype(np.float64), K_t.K, None)
    E, inl = cv2.findEssentialMat(a, b, np.eye(3), cv2.USAC_MAGSAC, 0.999, thr_px / K_t.fx)
    if E is None:
        return float("nan")
    _, R, _, _ = cv2.recoverPose(E[:3], a, b, np.eye(3), mask=inl.copy())
    T = np.eye(4)
    T[:3, :3] = R
    return float(pose_errors_deg(T, T_gt)[0])


def _profile(name, matches, K_t, K_s, true_scale, T_gt, cfg, thr) -> None:
    sigma = max(prior_sigma(K_t, cfg.intrinsics), prior_sigma(K_s, cfg.intrinsics))
    cand, prof = search_focal(matches, K_t, K_s, (True, True), sigma, cfg.intrinsics, thr)
    c_min = prof.cost.min()
    print(f"  {name}: {len(matches)} matches; true focal = prior x{true_scale:.3f}")
    print(f"    {'scale':>6s} {'/true':>6s} {'cost':>9s} {'/min':>6s} {'inliers':>7s} {'R_err':>6s}")
    for s, c, n in zip(prof.scales, prof.cost, prof.n_inliers, strict=True):
        r = _rotation_error(
            matches.pts_target, matches.pts_source, _scaled(K_t, s), _scaled(K_s, s), T_gt, thr
        )
        print(f"    {s:6.3f} {s / true_scale:6.3f} {c:9.2f} {c / c_min:6.3f} {n:7d} {r:6.1f}")
    flat = prof.scales[prof.cost <= 1.05 * c_min]
    print(
        f"    cost within 5% of its minimum for scales {flat.min():.3f}-{flat.max():.3f} "
        f"(x{flat.min() / true_scale:.2f}-x{flat.max() / true_scale:.2f} of the true focal); search: "
        + (
            f"x{cand.scale:.3f} +-{100 * cand.rel_uncertainty:.0f}% (true x{true_scale:.3f})"
            if cand.ok
            else f"not used: {cand.reason}"
        ),
    )
    bg = bougnoux_candidate(matches, K_t, K_s, (True, True), sigma, cfg.intrinsics)
    print(
        f"    Bougnoux: x{bg.scale:.3f}"
        + (f" +-{100 * bg.rel_uncertainty:.0f}%" if bg.ok else f" not used: {bg.reason}")
        if bg.scale is not None
        else f"    Bougnoux: not used: {bg.reason}",
        flush=True,
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pair", action="append", help="pair folder(s) (default: see the docstring)")
    ap.add_argument("--noise-px", type=float, nargs="+", default=[0.0, 0.5])
    ap.add_argument("--budgets", nargs="*", default=["8192@1280"], help="learned budgets of part 4")
    args = ap.parse_args(argv)
    cfg = FillConfig()
    rng = np.random.default_rng(0)
    for path in args.pair or [str(PAIRS / p) for p in DEFAULT_PAIRS]:
        pair = load_pair(path)
        meta = pair.meta
        T_gt = np.array(meta["T_source_to_target"])
        angle, gap, d_t, d_s = axes_configuration(T_gt)
        print(
            f"{pair.id}: optical axes {angle:.1f} deg apart; closest approach {gap:.3f} baselines apart, "
            f"{d_t:.2f} from the target centre and {d_s:.2f} from the source's (ratio {d_t / d_s:.3f}; "
            "Sturm's degenerate case: gap 0, ratio 1)"
        )
        hole = pair_mask(pair, 0, 100.0)
        ctx = prepare_fill(pair.target, hole, [pair.source], cfg, pair.exif.target)
        art = run_reference(ctx, ReferenceArtifacts(1, pair.source, pair.exif.source, None), until="match")
        m, v = art.matches, art.views
        K_t, K_s = v.K_target, v.K_source
        true_t = Intrinsics.from_matrix(np.array(meta["K_target"]), *pair.target.shape[1::-1])
        true_t = true_t.resized(K_t.width, K_t.height)
        true_s = Intrinsics.from_matrix(np.array(meta["K_source"]), *pair.source.shape[1::-1])
        true_s = true_s.resized(K_s.width, K_s.height)
        true_scale = true_t.fx / K_t.fx
        thr = cfg.matching.ransac_px(v.px_scale)
        print(f"  matches: {m.summary()}")
        _profile("the fill's matches", m, K_t, K_s, true_scale, T_gt, cfg, thr)
        # Ideal matches of the same points: triangulated with the truth, projected back.
        P_t = true_t.K @ np.eye(4)[:3]
        P_s = true_s.K @ np.linalg.inv(T_gt)[:3]
        X = cv2.triangulatePoints(P_t, P_s, m.pts_target.T, m.pts_source.T)
        X = X[:3] / X[3]
        Xs = np.linalg.inv(T_gt)[:3] @ np.vstack([X, np.ones(X.shape[1])])
        front = (X[2] > 0) & (Xs[2] > 0)
        for noise in args.noise_px:
            pt = (P_t @ np.vstack([X, np.ones(X.shape[1])]))[:, front]
            ps = (P_s @ np.vstack([X, np.ones(X.shape[1])]))[:, front]
            pt, ps = (pt[:2] / pt[2]).T, (ps[:2] / ps[2]).T
            pt, ps = pt + rng.normal(0, noise, pt.shape), ps + rng.normal(0, noise, ps.shape)
            F, _ = cv2.findFundamentalMat(ps, pt, cv2.FM_8POINT)
            ideal = replace(m, pts_target=pt, pts_source=ps, F=F)
            _profile(f"ideal matches, noise {noise:g} px", ideal, K_t, K_s, true_scale, T_gt, cfg, thr)
        if "dist_coeffs_opencv" not in meta:
            continue
        dist = np.array(meta["dist_coeffs_opencv"], np.float64)

        def undistorted(pt, ps, K=(true_t.K, true_s.K), dist=dist):
            return tuple(
                cv2.undistortPoints(q[:, None], k, dist, P=k)[:, 0] for q, k in zip((pt, ps), K, strict=True)
            )

        # The fill's verified matches (their selection was made on the distorted positions).
        ut, us = undistorted(m.pts_target, m.pts_source)
        F, _ = cv2.findFundamentalMat(us, ut, cv2.FM_8POINT)
        und = replace(m, pts_target=ut, pts_source=us, F=F)
        _profile("the fill's matches, undistorted", und, K_t, K_s, true_scale, T_gt, cfg, thr)
        mask = keypoint_mask(v.hole, cfg.matching.hole_margin_px * v.px_scale)
        gray = to_gray_u8(v.target_gray), to_gray_u8(v.source_gray)
        for budget in args.budgets:
            kp, side = (int(x) for x in budget.split("@"))
            pt, ps, _ = XFeatLighterGlue(kp, side)(*gray, mask)
            out = v.hole[np.rint(pt[:, 1]).astype(int), np.rint(pt[:, 0]).astype(int)]
            thr_l = thr * max(1.0, max(gray[0].shape) / side)
            # Tentative matches verified as the ladder's re-check does, before and after undistortion.
            for name, (qt, qs) in (
                ("", (pt[~out], ps[~out])),
                (", undistorted", undistorted(pt[~out], ps[~out])),
            ):
                F, keep = verify_essential(qt, qs, thr_l, (K_t.K, K_s.K))
                ms = replace(m, pts_target=qt[keep], pts_source=qs[keep], F=F)
                _profile(f"XFeat+LighterGlue {budget}{name}", ms, K_t, K_s, true_scale, T_gt, cfg, thr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
