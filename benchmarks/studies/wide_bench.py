"""The matching ladder per pair: plain SIFT (``matching.max_rung=sift``) against the ladder,
interleaved in one run (paired timings on a shared CPU), with the rung used, verified matches,
hole support, and the rotation error of the essential matrix fitted with the true K where the
pair has a ground-truth pose.

    .venv/bin/python benchmarks/studies/wide_bench.py [--pairs DIR ...] [--repeats 3] [--seed 0]

Holes are the evaluation's brush strokes (100 px at 720p, seed 0). Figures, not a test.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from geofill.camera import pose_errors_deg
from geofill.config import FillConfig
from geofill.evaluation.pairs import load_pairs, pair_mask
from geofill.match import match_pair
from geofill.prepare import prepare_views

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS


def rotation_error_deg(pair, m, views) -> float:
    """Rotation error (deg) of the pose from ``m``'s matches with the pair's true K (nan without GT)."""
    K, T = pair.meta.get("K_target"), pair.meta.get("T_source_to_target")
    if K is None or T is None or len(m) < 8:
        return float("nan")
    s = views.target.shape[1] / pair.target.shape[1]

    def scaled(k):  # pixel-centre convention, as the pairs README
        k = np.array(k, float)
        k[:2] *= s
        k[:2, 2] += 0.5 * s - 0.5
        return k

    K_t, K_s = scaled(K), scaled(pair.meta.get("K_source", K))
    n_t = cv2.undistortPoints(m.pts_target.reshape(-1, 1, 2), K_t, None).reshape(-1, 2)
    n_s = cv2.undistortPoints(m.pts_source.reshape(-1, 1, 2), K_s, None).reshape(-1, 2)
    E, inl = cv2.findEssentialMat(n_s, n_t, np.eye(3), cv2.USAC_MAGSAC, 0.9999, 1.0 / K_t[0, 0])
    if E is None or E.shape != (3, 3):
        return float("nan")
    _, R, t, _ = cv2.recoverPose(E, n_s, n_t, np.eye(3), mask=inl)
    est = np.eye(4)
    est[:3, :3], est[:3, 3] = R, t.ravel()
    return pose_errors_deg(est, np.array(T))[0]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", action="append", help="pair folder(s) (default: every DEV pair)")
    ap.add_argument("--repeats", type=int, default=3, help="interleaved repeats per variant")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    cfg = FillConfig()
    variants = {"sift": cfg.updated({"matching.max_rung": "sift"}), "ladder": cfg}
    head = ("variant", "rung", "verified", "support", "R_err", "time_s")
    print(f"{'pair':<40s} " + " ".join(f"{h:>8s}" for h in head))
    ratios = []
    for pair in load_pairs(args.pairs or [str(PAIRS)], exclude=HELD_OUT):
        hole = pair_mask(pair, args.seed, 100.0)
        views = prepare_views(pair.target, hole, pair.source, cfg, pair.exif.target, pair.exif.source)
        target = views.target.copy()
        target[views.hole] = 0  # as the pipeline: the hole is blanked before matching
        times: dict[str, list[float]] = {v: [] for v in variants}
        result = {}
        for _ in range(args.repeats):
            for name, c in variants.items():
                t0 = time.perf_counter()
                result[name] = match_pair(target, views.source, views.hole, c.matching, views.px_scale)
                times[name].append(time.perf_counter() - t0)
        for name, m in result.items():
            support = m.rungs[-1].hole_support if m.rungs else float("nan")
            print(
                f"{pair.id[:40]:<40s} {name:>8s} {m.rung:>8s} {len(m):>8d} {support:>8.2f} "
                f"{rotation_error_deg(pair, m, views):>8.2f} {statistics.median(times[name]):>8.2f}",
                flush=True,
            )
        if result["ladder"].rung == "sift":
            ratios.append(statistics.median(times["ladder"]) / statistics.median(times["sift"]))
    if ratios:
        r = statistics.median(ratios)
        print(f"pairs on plain SIFT: ladder / sift median time ratio {r:.3f} ", end="")
        print(f"(range {min(ratios):.3f}-{max(ratios):.3f}, {len(ratios)} pairs)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
