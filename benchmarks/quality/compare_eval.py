"""Hole-PSNR changes per pair between two sets of ``geofill eval`` runs, over one or several mask seeds.

    .venv/bin/python benchmarks/quality/compare_eval.py BEFORE AFTER [--seeds 0,1,2] [--method geofill]

BEFORE and AFTER are eval output folders (or their ``results.csv``); ``{seed}`` in them is replaced by
every seed of ``--seeds`` to find that seed's run (without it, the one run is compared). One seed's
per-pair changes move by a few tenths of a dB from rounding-level changes (which mesh cuts a stereo
depth makes flip), so a change is judged on several seeds: this prints the per-pair changes, each
seed's mean, over all pair-seeds the mean change, its spread and how many moved by more than
0.5 dB, and the pairs that were not filled from a reference in either set.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
from pathlib import Path


def _rows(pattern: str, seed: str, method: str) -> dict[str, dict[str, str]]:
    path = Path(pattern.format(seed=seed))
    with open(path if path.suffix == ".csv" else path / "results.csv", newline="") as f:
        return {r["pair"]: r for r in csv.DictReader(f) if r["method"] == method and r["psnr_hole"]}


def _status(row: dict[str, str]) -> str:
    if row.get("error"):
        return "failed"
    try:
        return json.loads(row.get("info") or "{}").get("status", "?")
    except json.JSONDecodeError:
        return "?"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", help="eval folder or results.csv; {seed} is replaced by each seed")
    ap.add_argument("after", help="eval folder or results.csv; {seed} is replaced by each seed")
    ap.add_argument("--seeds", default="0,1,2", help="used where the paths hold {seed}")
    ap.add_argument("--method", default="geofill")
    args = ap.parse_args(argv)
    seeds = args.seeds.split(",") if "{seed}" in args.before + args.after else ["-"]
    before = [_rows(args.before, s, args.method) for s in seeds]
    after = [_rows(args.after, s, args.method) for s in seeds]
    pairs = sorted(set(before[0]).intersection(*before, *after))
    if not pairs:
        print(f"no pair scored by {args.method!r} in every run", file=sys.stderr)
        return 2
    print(f"{'pair':<42s}" + "".join(f"{'seed ' + s:>9s}" for s in seeds) + f"{'mean':>8s}")
    changes = []
    for p in pairs:
        d = [float(a[p]["psnr_hole"]) - float(b[p]["psnr_hole"]) for a, b in zip(after, before, strict=True)]
        changes += d
        print(f"{p[:42]:<42s}" + "".join(f"{x:+9.2f}" for x in d) + f"{statistics.fmean(d):+8.2f}")
    for s, b, a in zip(seeds, before, after, strict=True):
        mb = statistics.fmean(float(b[p]["psnr_hole"]) for p in pairs)
        ma = statistics.fmean(float(a[p]["psnr_hole"]) for p in pairs)
        print(f"seed {s}: mean hole PSNR {mb:.3f} -> {ma:.3f} dB ({ma - mb:+.3f})")
    worse, better = sum(c < -0.5 for c in changes), sum(c > 0.5 for c in changes)
    print(
        f"{len(changes)} pair-seeds: mean change {statistics.fmean(changes):+.3f} dB, "
        f"sd {statistics.pstdev(changes):.3f}, worst {min(changes):+.2f}, best {max(changes):+.2f}, "
        f"worse by > 0.5 dB: {worse}, better by > 0.5 dB: {better}"
    )
    for name, runs in (("before", before), ("after", after)):
        fell = sorted({p for run in runs for p in pairs if _status(run[p]) != "reference"})
        print(f"not filled from a reference {name}: {', '.join(fell) if fell else 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
