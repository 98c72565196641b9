"""CPU seconds (user + system, all threads, ``os.wait4``) of whole ``geofill fill`` processes, this
checkout and an earlier revision alternated on the same files: on a shared machine the wall times
of ``whole_process.py`` swing with the load by more than a stage's gain, CPU time much less.

    .venv/bin/python benchmarks/speed/fill_cpu.py --before REV|SRC [--runs 6] --target t.png
        --mask m.png --source s.png

Prints each side's median, its runs, and in how many rounds this checkout used less CPU.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import child_usage, earlier_cli, export_src


def _cpu_s(cmd: list[str], env: dict[str, str] | None) -> float:
    usage = child_usage(cmd, env)[1]
    return usage.ru_utime + usage.ru_stime


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", required=True, metavar="REV|SRC")
    ap.add_argument("--runs", type=int, default=6)
    for name in ("target", "mask", "source"):
        ap.add_argument(f"--{name}", required=True)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        before = args.before if Path(args.before).is_dir() else export_src(args.before, Path(tmp))
        io = ["--target", args.target, "--mask", args.mask, "--source", args.source, "--quiet"]
        cmds = {
            "this": ([str(Path(sys.executable).parent / "geofill"), "fill", *io, "-o", f"{tmp}/a.png"], None),
            "before": (earlier_cli("fill", *io, "-o", f"{tmp}/b.png"), {**os.environ, "PYTHONPATH": before}),
        }
        cpu: dict[str, list[float]] = {name: [] for name in cmds}
        for round_ in range(args.runs + 1):  # the first round warms the caches, unmeasured
            for name, (cmd, env) in cmds.items():
                seconds = _cpu_s(cmd, env)
                if round_:
                    cpu[name].append(seconds)
    for name, values in cpu.items():
        runs = " ".join(f"{v:.2f}" for v in values)
        print(f"{name:<7s} median {statistics.median(values):.2f} s CPU  (runs {runs})")
    less = sum(a < b for a, b in zip(cpu["this"], cpu["before"], strict=True))
    print(f"this checkout used less CPU in {less} of {args.runs} rounds; load {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
