"""Whole-process time of ``geofill fill`` with one reference against all references, on the real
multi-reference sets, as a user runs it.

    .venv/bin/python benchmarks/speed/multiref_process.py [--runs 3] [--sets a,b,...]
        [--set KEY=VALUE ...] [--before REV|SRC]

Per set (``../shared/data/multiview``): the target with the evaluation's stroke hole (seed 0)
blanked, filled from the primary reference alone and from every reference; the runs alternate one,
all, one, all, ... after one unmeasured warm-up of each, so drift in the machine's load hits both
alike. The figure is the median of the per-run ratios all / one (the issue's limit: 2.5x for four
references). ``--before`` also times that code's all-reference fill in every round, with its own
defaults, as its ratio to today's single-reference fill.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import MULTIVIEW, earlier_cli, export_src, timed_child
from whole_process import _byte_compile, _geofill  # this folder is on sys.path when run as a script

DEFAULT_SETS = (
    "dev_mv_instantngp_fox_upper,dev_mv_mast3r_nle_tower,dev_mv_cotracker_apple,dev_mv_slambook_livingroom"
)


def _make_inputs(set_dir: Path, folder: Path) -> None:
    """Runs in a child process: target.png (hole blanked) and mask.png of ``set_dir``."""
    import cv2
    import numpy as np

    from geofill.evaluation.pairs import load_pair, pair_mask

    pair = load_pair(set_dir)
    hole = np.asarray(pair_mask(pair, 0)) > 0
    target = pair.target.copy()
    target[hole] = 0
    cv2.imwrite(str(folder / "target.png"), cv2.cvtColor(target, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(folder / "mask.png"), hole.astype(np.uint8) * 255)


def _commands(set_dir: Path, folder: Path, overrides: list[str], before: str | None) -> dict[str, tuple]:
    sources = sorted(p for p in set_dir.iterdir() if p.stem.startswith("source"))
    io = ["--target", str(folder / "target.png"), "--mask", str(folder / "mask.png"), "--allow-fallback"]
    sets = [x for s in overrides for x in ("--set", s)]
    every = [x for p in sources for x in ("--source", str(p))]
    cmds = {
        "one": (
            [_geofill(), "fill", *io, "--source", str(sources[0]), "-o", str(folder / "1.png"), "-q", *sets],
            None,
        ),
        "all": ([_geofill(), "fill", *io, *every, "-o", str(folder / "a.png"), "-q", *sets], None),
    }
    if before is not None:
        cmd = earlier_cli("fill", *io, *every, "-o", str(folder / "b.png"), "-q")
        cmds["before all"] = (cmd, {**os.environ, "PYTHONPATH": before})
    return cmds


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--sets", default=DEFAULT_SETS)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument(
        "--before", metavar="REV|SRC", help="earlier code to run alongside: a git revision or a src folder"
    )
    ap.add_argument("--make-inputs", nargs=2, metavar=("SET", "DIR"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.make_inputs:
        _make_inputs(Path(args.make_inputs[0]), Path(args.make_inputs[1]))
        return 0
    if not MULTIVIEW.is_dir():
        print(f"skipped: {MULTIVIEW} not found")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        if args.before and not Path(args.before).is_dir():
            args.before = export_src(args.before, Path(tmp))
        print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())} ({os.cpu_count()} cpus)")
        _byte_compile(args.before)
        head = f"{'set':<30s}{'refs':>5s}{'one s':>8s}{'all s':>8s}{'all/one':>9s}"
        print(head + (f"{'before all/one':>16s}" if args.before else ""))
        ratios = []
        for name in filter(None, args.sets.split(",")):
            set_dir = MULTIVIEW / name
            folder = Path(tmp) / name
            folder.mkdir()
            subprocess.run([sys.executable, __file__, "--make-inputs", str(set_dir), str(folder)], check=True)
            cmds = _commands(set_dir, folder, args.set, args.before)
            for cmd, env in cmds.values():
                timed_child(cmd, env)  # warm-up
            times: dict[str, list[float]] = {k: [] for k in cmds}
            for _ in range(args.runs):
                for key, (cmd, env) in cmds.items():
                    times[key].append(timed_child(cmd, env)[0])
            ratio = statistics.median(a / o for a, o in zip(times["all"], times["one"], strict=True))
            ratios.append(ratio)
            n_refs = sum(1 for x in cmds["all"][0] if x == "--source")
            one_s, all_s = statistics.median(times["one"]), statistics.median(times["all"])
            row = f"{name:<30s}{n_refs:>5d}{one_s:8.2f}{all_s:8.2f}{ratio:9.2f}"
            if args.before:
                before = statistics.median(
                    b / o for b, o in zip(times["before all"], times["one"], strict=True)
                )
                row += f"{before:16.2f}"
            print(row, flush=True)
        print(f"median all/one over sets: {statistics.median(ratios):.2f}; load now {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
