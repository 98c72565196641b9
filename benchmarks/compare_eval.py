"""Per-pair hole-PSNR changes between two ``geofill eval`` runs (their ``results.csv``), for one method.

    .venv/bin/python benchmarks/compare_eval.py BEFORE/results.csv AFTER/results.csv [--method geofill]

Prints every pair's hole PSNR before and after and the change, then the mean change, the worst and
best pair, and each run's fallbacks (``status`` other than ``reference``). A speed change is meant to
keep the mean within 0.1 dB and no pair worse by more than 0.5 dB; this prints the figures, it does
not judge them.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys


def _rows(path: str, method: str) -> dict[str, dict[str, str]]:
    with open(path, newline="") as f:
        return {r["pair"]: r for r in csv.DictReader(f) if r["method"] == method}


def _status(row: dict[str, str]) -> str:
    if row.get("error"):
        return "failed"
    try:
        return json.loads(row.get("info") or "{}").get("status", "?")
    except json.JSONDecodeError:
        return "?"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--method", default="geofill")
    args = ap.parse_args(argv)
    before, after = _rows(args.before, args.method), _rows(args.after, args.method)
    common = [p for p in before if p in after and before[p]["psnr_hole"] and after[p]["psnr_hole"]]
    if not common:
        print(f"no pair scored by {args.method!r} in both files", file=sys.stderr)
        return 2
    print(f"{'pair':<42s} {'before':>8s} {'after':>8s} {'change':>8s}  status")
    changes = {}
    for p in common:
        b, a = float(before[p]["psnr_hole"]), float(after[p]["psnr_hole"])
        changes[p] = a - b
        st = f"{_status(before[p])} -> {_status(after[p])}"
        print(f"{p[:42]:<42s} {b:8.2f} {a:8.2f} {a - b:+8.2f}  {st}")
    worst, best = min(changes, key=changes.get), max(changes, key=changes.get)
    mean_b = statistics.fmean(float(before[p]["psnr_hole"]) for p in common)
    mean_a = statistics.fmean(float(after[p]["psnr_hole"]) for p in common)
    print(f"pairs {len(common)}: mean hole PSNR {mean_b:.3f} -> {mean_a:.3f} dB ({mean_a - mean_b:+.3f})")
    print(f"worst {worst} {changes[worst]:+.2f} dB; best {best} {changes[best]:+.2f} dB")
    print(f"within 0.005 dB: {sum(abs(c) < 0.005 for c in changes.values())} pairs")
    for name, rows in (("before", before), ("after", after)):
        fell = [p for p in common if _status(rows[p]) != "reference"]
        print(f"not from a reference {name}: {', '.join(fell) if fell else 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
