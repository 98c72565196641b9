"""Hole-PSNR changes per pair and mask seed between two sets of ``geofill eval`` runs.

    .venv/bin/python benchmarks/compare_seeds.py BEFORE_DIR_{seed} AFTER_DIR_{seed} --seeds 0,1,2

``{seed}`` in each argument is replaced by every seed to find that run's folder (its
``results.csv``). One seed's per-pair changes move by a few tenths of a dB from rounding-level
changes (which mesh cuts a stereo depth makes flips), so a change is judged on several seeds:
this prints the per-pair changes, each seed's mean, and over all pair-seeds the mean change,
its spread and how many moved by more than 0.5 dB.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys


def _scores(path: str, method: str) -> dict[str, float]:
    with open(f"{path}/results.csv", newline="") as f:
        return {r["pair"]: float(r["psnr_hole"]) for r in csv.DictReader(f) if r["method"] == method}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", help="folder pattern with {seed}")
    ap.add_argument("after", help="folder pattern with {seed}")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--method", default="geofill")
    args = ap.parse_args(argv)
    seeds = args.seeds.split(",")
    before = [_scores(args.before.format(seed=s), args.method) for s in seeds]
    after = [_scores(args.after.format(seed=s), args.method) for s in seeds]
    pairs = sorted(set(before[0]).intersection(*before, *after))
    if not pairs:
        print("no pair scored in every run", file=sys.stderr)
        return 2
    print(f"{'pair':<42s}" + "".join(f"{'seed ' + s:>9s}" for s in seeds) + f"{'mean':>8s}")
    changes = []
    for p in pairs:
        d = [a[p] - b[p] for a, b in zip(after, before, strict=True)]
        changes += d
        print(f"{p[:42]:<42s}" + "".join(f"{x:+9.2f}" for x in d) + f"{statistics.fmean(d):+8.2f}")
    for s, b, a in zip(seeds, before, after, strict=True):
        mb, ma = statistics.fmean(b[p] for p in pairs), statistics.fmean(a[p] for p in pairs)
        print(f"seed {s}: mean hole PSNR {mb:.3f} -> {ma:.3f} dB ({ma - mb:+.3f})")
    worse = sum(c < -0.5 for c in changes)
    print(
        f"{len(changes)} pair-seeds: mean change {statistics.fmean(changes):+.3f} dB, "
        f"sd {statistics.pstdev(changes):.3f}, worst {min(changes):+.2f}, best {max(changes):+.2f}, "
        f"worse by > 0.5 dB: {worse}, better by > 0.5 dB: {sum(c > 0.5 for c in changes)}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
