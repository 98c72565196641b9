"""Throughput of many fills: a shell loop of ``geofill fill`` against ``geofill batch`` (``--jobs 1``,
``--jobs 2``, ``--ray local``) on the DEV pairs, peak RSS per worker, and the per-item overhead of
the local pool and of Ray.

    .venv/bin/python benchmarks/speed/batch_bench.py [--pairs ../shared/data/pairs] [--limit N] [--rounds R]

Each pair's target and source, with the evaluation hole of ``geofill eval`` (seed 0), become one
batch item (images/<pair>, masks/<pair>.png, refs/<pair>/ in a temporary folder, files linked, not
copied). Every mode runs the same items in the same round, one after the other (order reversed in
odd rounds), so the modes are compared under the same machine load. Throughput counts the command's
whole wall time (start-up, pool or Ray start, every fill). Per-item overhead: batches of
``--overhead-items`` and 5x as many items whose target is not an image (each fails at once in a
worker), the slope of the time spent running the items against their count.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import statistics
import sys
import tempfile
from collections import Counter, defaultdict
from pathlib import Path

import cv2
import numpy as np

from geofill.batch import BatchSettings, items_from_folders, run_batch
from geofill.config import FillConfig
from geofill.errors import EXIT_ITEMS_FAILED
from geofill.evaluation.pairs import load_pair, pair_mask

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS, timed_child

GEOFILL = [sys.executable, "-m", "geofill.cli"]
MODES = {
    "shell loop of fill": None,
    "batch --jobs 1": ["--jobs", "1"],
    "batch --jobs 2": ["--jobs", "2"],
    "batch --ray local --jobs 2": ["--ray", "local", "--jobs", "2"],
}

OVERHEAD_RUNNERS = {
    "local pool (--jobs 2)": {"jobs": 2},
    "Ray (--ray local --jobs 2)": {"jobs": 2, "ray": "local"},
}


def dev_pairs(folder: Path) -> list[Path]:
    """The DEV pairs: every pair folder but the wide-baseline ``dev_wide_`` ones."""
    return sorted(
        p
        for p in folder.iterdir()
        if (p / "meta.json").is_file() and not p.name.startswith("dev_wide_") and p.name not in HELD_OUT
    )


def make_shoot(pairs: list[Path], root: Path) -> list[str]:
    for d in ("images", "masks", "refs"):
        (root / d).mkdir(parents=True)
    for folder in pairs:
        pair = load_pair(folder)
        target = next(folder.glob("target.*"))
        source = next(folder.glob("source.*"))
        (root / "images" / f"{folder.name}{target.suffix}").symlink_to(target.resolve())
        (root / "refs" / folder.name).mkdir()
        (root / "refs" / folder.name / source.name).symlink_to(source.resolve())
        cv2.imwrite(
            str(root / "masks" / f"{folder.name}.png"), pair_mask(pair, seed=0).astype(np.uint8) * 255
        )
    return [p.name for p in pairs]


def run_shell_loop(root: Path, names: list[str], out: Path) -> dict:
    out.mkdir()
    wall, rss = 0.0, []
    for name in names:
        target = next((root / "images").glob(f"{name}.*"))
        source = next((root / "refs" / name).iterdir())
        cmd = [*GEOFILL, "fill", "--target", str(target), "--mask", str(root / "masks" / f"{name}.png")]
        cmd += ["--source", str(source), "-o", str(out / f"{name}.png"), "-q", "--allow-fallback"]
        w, r = timed_child(cmd)
        wall += w
        rss.append(r)
    return {"wall_s": wall, "items": len(names), "peak_rss_mib": max(rss), "workers": len(rss)}


def run_batch_command(root: Path, out: Path, extra: list[str]) -> dict:
    cmd = [*GEOFILL, "batch", "--images", str(root / "images"), "--masks", str(root / "masks")]
    cmd += ["--sources-per-image", str(root / "refs"), "--out", str(out), "-q", "--allow-fallback", *extra]
    wall, _ = timed_child(cmd)
    records = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    per_worker: dict[int, float] = defaultdict(float)
    for r in records:
        per_worker[r["worker"]["pid"]] = max(per_worker[r["worker"]["pid"]], r["worker"]["peak_rss_mib"])
    return {
        "wall_s": wall,
        "items": len(records),
        "peak_rss_mib": max(per_worker.values()),
        "workers": len(per_worker),
        "fill_s": sum(r["time_s"] for r in records),
        "statuses": dict(sorted(Counter(r["status"] for r in records).items())),
    }


def overhead(tmp: Path, n: int, settings: dict) -> float:
    """Seconds of batch time per item of the machinery alone: the slope of the time spent running
    the items (Ray's start-up excluded) from n to 5n items whose target is not an image, each
    failing at once in a worker."""
    walls = []
    for count in (n, 5 * n):
        root = tmp / f"overhead_{count}_{settings.get('ray')}"
        (root / "images").mkdir(parents=True)
        for i in range(count):
            (root / "images" / f"x{i:04d}.png").write_bytes(b"not an image")
        (root / "mask.png").write_bytes(b"")
        items = items_from_folders(root / "images", root / "mask.png", sources=root / "images")
        batch_settings = BatchSettings(out_dir=root / "out", quiet=True, **settings)
        with contextlib.redirect_stdout(io.StringIO()):
            outcome = run_batch(items, FillConfig(), batch_settings, stream=io.StringIO())
        assert outcome.exit_code == EXIT_ITEMS_FAILED and len(outcome.records) == count, (
            f"every item should fail (exit {EXIT_ITEMS_FAILED}): exit {outcome.exit_code}, "
            f"{len(outcome.records)} of {count} records"
        )
        walls.append(outcome.elapsed_s)
    return (walls[1] - walls[0]) / (4 * n)


def print_throughput(
    results: dict[str, list[dict]], modes: list[str], n_pairs: int, rounds: int, load: list[float]
) -> None:
    base = statistics.median(60.0 * r["items"] / r["wall_s"] for r in results[modes[0]])
    print(
        f"{n_pairs} DEV pairs, {rounds} round(s), modes run back to back in each round on a shared "
        f"2-core machine (1-min load average {min(load):.1f}-{max(load):.1f} during the runs).\n"
    )
    print(
        "| mode | fills/min (median) | x first mode | wall s per round | peak RSS per worker, MiB | workers |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    for mode in modes:
        rs = results[mode]
        rate = statistics.median(60.0 * r["items"] / r["wall_s"] for r in rs)
        walls = ", ".join(f"{r['wall_s']:.0f}" for r in rs)
        rss = max(r["peak_rss_mib"] for r in rs)
        print(f"| {mode} | {rate:.2f} | {rate / base:.2f} | {walls} | {rss:.0f} | {rs[0]['workers']} |")
    statuses = {mode: rs[0]["statuses"] for mode, rs in results.items() if "statuses" in rs[0]}
    print(f"\nItem statuses (first round): {json.dumps(statuses)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=Path, default=PAIRS)
    ap.add_argument("--limit", type=int, help="first N DEV pairs only")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--modes", default=",".join(MODES), help="comma-separated subset of: " + ", ".join(MODES))
    ap.add_argument("--overhead-items", type=int, default=40, help="0 = skip the overhead measurement")
    args = ap.parse_args()
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    pairs = dev_pairs(args.pairs)[: args.limit]
    results: dict[str, list[dict]] = defaultdict(list)
    with tempfile.TemporaryDirectory(prefix="batch_bench_") as tmp:
        root = Path(tmp) / "shoot"
        names = make_shoot(pairs, root)
        load = [os.getloadavg()[0]]
        for rnd in range(args.rounds):
            for i, mode in enumerate(modes if rnd % 2 == 0 else modes[::-1]):
                out = Path(tmp) / f"out_{rnd}_{i}"
                extra = MODES[mode]
                res = (
                    run_shell_loop(root, names, out) if extra is None else run_batch_command(root, out, extra)
                )
                results[mode].append(res)
                load.append(os.getloadavg()[0])
                print(f"round {rnd} {mode}: {json.dumps(res)}", file=sys.stderr, flush=True)
        costs = {}
        if args.overhead_items:
            for label, extra in OVERHEAD_RUNNERS.items():
                costs[label] = overhead(Path(tmp), args.overhead_items, extra)
    if modes:
        print_throughput(results, modes, len(names), args.rounds, load)
    if costs:
        n = args.overhead_items
        print(f"\nPer-item overhead (slope of run time from {n} to {5 * n} items that fail at once):\n")
        print("| runner | s per item |")
        print("| --- | --- |")
        for label, cost in costs.items():
            print(f"| {label} | {cost:.3f} |")


if __name__ == "__main__":
    main()
