"""Wide baselines: the wide DEV pairs and the towers filled with plain SIFT only (the ladder capped
at its first rung: what a fill did before the ladder), with the ladder without the learned matcher
(``nolearned``: a base install), with the default ladder (``ladder``: with the ``learned`` extra
when it is installed) and with the learned rung cross-checking a verified SIFT geometry too
(``crosscheck``), against the homography baseline, on the evaluation's 100-px brush
holes (seed 0).

    .venv/bin/python benchmarks/quality/wide_results.py [--pairs DIR ...] [--seed 0] [--variants ...]

Per pair and variant: whether the fill used the reference or fell back to single-image inpainting,
the rung its matches came from, verified matches, the joint optimisation's status (``skipped``:
the evidence was too thin, or the pose failed) and its feature matches on the source depth, the
rotation / translation-direction error of the fill's final pose against the ground truth (where
the pair has one), hole PSNR, the learned rung's wall and CPU time (``-`` where it did not run),
and the fill's time (in process, one run: the pairs and variants are interleaved on a shared CPU).
Figures, not a test.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from geofill.camera import pose_errors_deg
from geofill.config import FillConfig, parse_overrides
from geofill.evaluation.baselines import homography_fill_detailed
from geofill.evaluation.metrics import psnr
from geofill.evaluation.pairs import load_pairs, pair_mask
from geofill.pipeline import fill

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS

WIDE = ("dev_wide_", "dev_mast3r_nle_tower_")
VARIANTS = {
    "sift": {"matching.max_rung": "sift", "matching.learned": "off"},
    "nolearned": {"matching.learned": "off"},
    "ladder": {},
    "crosscheck": {"matching.learned_cross_check": True},
}


def _pose_errors(pair, result) -> tuple[float, float]:
    """(rotation, translation direction) error in degrees of the fill's pose; nan without GT or pose."""
    gt = pair.meta.get("T_source_to_target")
    refs = [r for r in result.references if r.usable]
    if gt is None or not refs:
        return math.nan, math.nan
    r, t = pose_errors_deg(refs[0].geometry.T, np.array(gt))
    return float(r), float(t)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--pairs", action="append", help="pair folder(s) (default: the wide DEV pairs and towers)"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--variants", nargs="+", default=["sift", "nolearned", "ladder"], choices=VARIANTS)
    ap.add_argument("--set", action="append", metavar="KEY=VALUE", help="config override of every variant")
    args = ap.parse_args(argv)
    pairs = load_pairs(args.pairs or [str(PAIRS)], exclude=HELD_OUT)
    if not args.pairs:
        pairs = [p for p in pairs if p.id.startswith(WIDE)]
    cfg = FillConfig().updated(parse_overrides(args.set))
    variants = {v: cfg.updated(VARIANTS[v]) for v in args.variants}
    head = (
        "variant",
        "status",
        "rung",
        "verified",
        "optimise",
        "features",
        "R_err",
        "t_err",
        "PSNR_h",
        "homog",
        "learned_s",
        "cpu_s",
        "time_s",
    )
    print(f"{'pair':<38s} " + " ".join(f"{h:>9s}" for h in head))
    summary: dict[str, list[tuple[bool, float, float, float]]] = {v: [] for v in variants}
    for pair in pairs:
        hole = pair_mask(pair, args.seed, 100.0)
        homog = psnr(homography_fill_detailed(pair.target, hole, pair.source).image, pair.target, hole)
        for name, c in variants.items():
            t0 = time.perf_counter()
            result = fill(
                pair.target,
                hole,
                [pair.source],
                c,
                target_exif=pair.exif.target,
                source_exifs=[pair.exif.source],
            )
            took = time.perf_counter() - t0
            match = result.report.references[0].get("match", {})
            opt = result.report.references[0].get("optimize", {})
            learned = [r for r in match.get("rungs", []) if r["rung"] == "learned"]
            l_wall = f"{learned[0]['time_s']:.2f}" if learned else "-"
            l_cpu = f"{learned[0]['cpu_s']:.2f}" if learned else "-"
            fell_back = result.report.status != "reference"
            r_err, t_err = _pose_errors(pair, result)
            score = psnr(result.image, pair.target, hole)
            summary[name].append((fell_back, score, homog, took))
            print(
                f"{pair.id[:38]:<38s} {name:>9s} {'fallback' if fell_back else 'reference':>9s} "
                f"{match.get('rung', '-'):>9s} {match.get('n_verified', 0):>9d} {opt.get('status', '-'):>9s} "
                f"{opt.get('n_features', 0):>9d} {r_err:>9.2f} {t_err:>9.2f} "
                f"{score:>9.2f} {homog:>9.2f} {l_wall:>9s} {l_cpu:>9s} {took:>9.2f}",
                flush=True,
            )
    for name, rows in summary.items():
        if not rows:
            continue
        mine, theirs = statistics.mean(r[1] for r in rows), statistics.mean(r[2] for r in rows)
        print(
            f"{name}: {sum(r[0] for r in rows)}/{len(rows)} fall back; mean hole PSNR {mine:.2f} dB vs "
            f"homography {theirs:.2f} dB; median time {statistics.median(r[3] for r in rows):.2f} s"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
