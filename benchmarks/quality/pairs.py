"""Run the fill on every real pair and print, per pair: verified matches, pose inliers, pose error
against the ground-truth pose where meta.json has one, hole PSNR, and per-stage wall time; then medians.

    .venv/bin/python benchmarks/quality/pairs.py [--pairs ../shared/data/pairs] [--set key=value ...]

Holes are the evaluation's deterministic brush-stroke masks (seed 0). Figures, not a test.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

from geofill.camera import pose_errors_deg
from geofill.config import FillConfig, parse_overrides
from geofill.evaluation.metrics import psnr
from geofill.evaluation.pairs import load_pairs, pair_mask
from geofill.pipeline import fill

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS

STAGES = ("match", "pose", "triangulate", "depth", "render", "composite")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", default=str(PAIRS))
    ap.add_argument("--set", action="append", metavar="KEY=VALUE", help="config override (repeatable)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    cfg = FillConfig().updated(parse_overrides(args.set))
    pairs = load_pairs([args.pairs], exclude=HELD_OUT)
    cols = ["pair", "matches", "inliers", "R_err", "t_err", "psnr_hole", *STAGES, "total"]
    print(" ".join(f"{c:>10s}" if i else f"{c:<34s}" for i, c in enumerate(cols)))
    rows = []
    for pair in pairs:
        hole = pair_mask(pair, args.seed)
        res = fill(
            pair.target, hole, pair.source, cfg, target_exif=pair.exif.target, source_exifs=[pair.exif.source]
        )
        r, ref = res.report, res.references[0]
        T_gt = pair.meta.get("T_source_to_target")
        r_err, t_err = (
            pose_errors_deg(ref.pose.T, np.array(T_gt))
            if T_gt is not None and ref.pose is not None
            else (float("nan"), float("nan"))
        )
        row = {
            "pair": pair.id,
            "matches": len(ref.matches) if ref.matches is not None else 0,
            "inliers": ref.pose.n_inliers if ref.pose is not None else 0,
            "R_err": r_err,
            "t_err": t_err,
            "psnr_hole": psnr(res.image, pair.target, hole),
            **{s: r.timings_s.get(s, float("nan")) for s in STAGES},
            "total": sum(r.timings_s.values()),
        }
        rows.append(row)
        flag = "" if r.status == "reference" else f"  [{r.status}: {r.fallbacks[-1]}]"
        print(_fmt(row, cols) + flag, flush=True)
    med = {c: statistics.median([x for x in (row[c] for row in rows) if np.isfinite(x)] or [np.nan])
           for c in cols[1:]}  # fmt: skip
    print(_fmt({"pair": "MEDIAN"} | med, cols))
    print(f"({len(rows)} pairs; pose errors over {sum(np.isfinite(r['R_err']) for r in rows)} GT pairs)")
    return 0


def _fmt(row: dict, cols: list[str]) -> str:
    out = [f"{row['pair']:<34s}"]
    for c in cols[1:]:
        v = row[c]
        out.append(f"{v:>10d}" if isinstance(v, int) else f"{v:>10.2f}")
    return " ".join(out)


if __name__ == "__main__":
    sys.exit(main())
