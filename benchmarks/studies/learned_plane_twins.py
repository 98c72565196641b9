"""Why the learned rung's matches give a wrong pose on a wide pair dominated by one textured plane
(the fox's wallpaper), in a real fill: the hole blanked (the evaluation's seed-0 strokes) and the
fill's own working views and prior intrinsics. Needs the ``learned`` extra.

Per XFeat budget (keypoints, long side) on LighterGlue's tentative matches: how many, the matcher's
wall/CPU time, the rotation error of the MAGSAC essential matrix with the true intrinsics and with
the prior focal times 0.6-1.7 (the scale with the most inliers, as the ladder's ``choose`` scores),
and the rotation errors of the two solution pairs of the calibrated homography of the dominant
plane (true intrinsics) and of a second plane fitted to its outliers. Figures, not a test.

    PYTHONPATH=src <venv with the learned extra>/bin/python benchmarks/studies/learned_plane_twins.py \
        [--pair DIR] [--budgets 2048@1024 4096@1024/0.95 ...]

A budget is KEYPOINTS@LONG_SIDE, optionally /CONFIDENCE (LightGlue's early exit and pruning;
default 0.95).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from geofill.camera import pose_errors_deg
from geofill.config import FillConfig
from geofill.evaluation.pairs import load_pair, pair_mask
from geofill.match.features import keypoint_mask
from geofill.match.ladder import FOCAL_SCALES
from geofill.match.xfeat import XFeatLighterGlue
from geofill.pipeline import ReferenceArtifacts, prepare_fill, run_reference

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import PAIRS


def _scaled(K: np.ndarray, f: float) -> np.ndarray:
    K = np.array(K, np.float64)
    K[:2, :2] *= f
    return K


def _rot_err(R: np.ndarray, T_gt: np.ndarray) -> float:
    T = np.eye(4)
    T[:3, :3] = R
    return float(pose_errors_deg(T, T_gt)[0])


def _essential(pt, ps, K_t, K_s, T_gt, thr_px=1.5) -> tuple[int, float]:
    """(inliers, rotation error) of the MAGSAC essential matrix of the matches under K_t/K_s."""
    a = cv2.undistortPoints(ps[:, None].astype(np.float64), K_s, None)
    b = cv2.undistortPoints(pt[:, None].astype(np.float64), K_t, None)
    E, inl = cv2.findEssentialMat(a, b, np.eye(3), cv2.USAC_MAGSAC, 0.999, thr_px / K_t[0, 0])
    if E is None:
        return 0, float("nan")
    _, R, _, _ = cv2.recoverPose(E[:3], a, b, np.eye(3), mask=inl.copy())
    return int(inl.sum()), _rot_err(R, T_gt)


def _plane_twins(pt, ps, K_t, K_s, T_gt) -> tuple[int, list[float], np.ndarray]:
    """Inliers, rotation errors of the homography's decompositions, and its outlier mask."""
    H, inl = cv2.findHomography(ps, pt, cv2.USAC_MAGSAC, 3.0)
    _, Rs, _, _ = cv2.decomposeHomographyMat(np.linalg.inv(K_t) @ H @ K_s, np.eye(3))
    inl = inl.ravel().astype(bool)
    return int(inl.sum()), sorted({round(_rot_err(R, T_gt), 1) for R in Rs}), ~inl


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pair", default=str(PAIRS / "dev_wide_instantngp_fox_0001_to_0022"))
    ap.add_argument("--budgets", nargs="+", default=["2048@1024", "4096@1024", "4096@768", "3072@768"])
    args = ap.parse_args(argv)
    pair = load_pair(args.pair)
    hole = pair_mask(pair, 0, 100.0)
    cfg = FillConfig()
    ctx = prepare_fill(pair.target, hole, [pair.source], cfg, pair.exif.target)
    ref = ReferenceArtifacts(1, pair.source, pair.exif.source, None)
    views = run_reference(ctx, ref, until="prepare").views
    meta, T_gt = pair.meta, np.array(pair.meta["T_source_to_target"])
    sx = views.target_gray.shape[1] / meta["image_size_wh"][0]
    K_t, K_s = (np.array(meta[k]) * [[sx], [sx], [1]] for k in ("K_target", "K_source"))
    P_t, P_s = np.array(views.K_target.K), np.array(views.K_source.K)
    size = views.target_gray.shape[::-1]
    print(f"{pair.id}: working {size}, prior focal {P_t[0, 0]:.0f}, true {K_t[0, 0]:.0f}")
    mask = keypoint_mask(views.hole, cfg.matching.hole_margin_px * views.px_scale)
    for budget in args.budgets:
        size, _, conf = budget.partition("/")
        kp, side = (int(x) for x in size.split("@"))
        matcher = XFeatLighterGlue(kp, side, confidence=float(conf or 0.95))
        matcher(views.target_gray, views.source_gray, mask)  # load and warm up
        matcher._targets.clear()  # time a new target
        t0, c0 = time.perf_counter(), time.process_time()
        pt, ps, _ = matcher(views.target_gray, views.source_gray, mask)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        keep = ~views.hole[np.rint(pt[:, 1]).astype(int), np.rint(pt[:, 0]).astype(int)]
        pt, ps = pt[keep], ps[keep]
        true_n, true_err = _essential(pt, ps, K_t, K_s, T_gt)
        scan = [(_essential(pt, ps, _scaled(P_t, f), _scaled(P_s, f), T_gt), f) for f in FOCAL_SCALES]
        (scan_n, scan_err), scan_f = max(scan, key=lambda s: s[0][0])
        n1, twins1, out = _plane_twins(pt, ps, K_t, K_s, T_gt)
        n2, twins2, _ = _plane_twins(pt[out], ps[out], K_t, K_s, T_gt)
        print(
            f"{budget:>10s}: {len(pt)} matches, {wall:.2f} s wall / {cpu:.2f} s CPU; E true K: {true_n} inl "
            f"R {true_err:.1f} deg; E prior x{scan_f:g}: {scan_n} inl R {scan_err:.1f} deg "
            f"(all scales: {', '.join(f'{e:.1f}' for (_, e), _ in scan)}); plane 1: {n1} inl R {twins1}; "
            f"plane 2: {n2} inl R {twins2}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
