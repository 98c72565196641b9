"""Whole-process wall time and peak RSS of ``geofill fill`` as a user runs it, each run paired with
the standalone homography baseline (``benchmarks/speed/homography_baseline.py``) on the same files, and
the start-up time of ``geofill --help``, ``geofill config`` and ``geofill serve`` (until its port
accepts a connection, until its page has been served, and until the files it names have been too).

Runs alternate geofill, baseline, geofill, baseline, ... after one unmeasured warm-up of each (it
fills numba's and the OS's caches), so drift in the machine's load hits both alike: the median of the
per-run ratios is the figure that carries over between machines; the absolute seconds depend on
the load (printed with ``os.getloadavg``). Peak RSS is each child's own (``os.wait4``); inputs are
written by a child process so that the parent stays small.

Cases: ``720p`` (the synthetic ray-cast scene at 1280x720 with its object hole), ``berlin`` (the DEV
pair dev_opensfm_berlin_01_02 at its own 1280x960 with the evaluation's stroke hole, seed 0),
``4k`` (the synthetic scene at 3840x2160). Time vs pixels: the exponent of 720p -> 4k.

    .venv/bin/python benchmarks/speed/whole_process.py [--runs 5] [--cases 720p,berlin,4k]
        [--set KEY=VALUE ...] [--before REV|SRC]

geofill's modules are byte-compiled first, as ``pip install`` does (see ``_byte_compile``).

``--before REV`` (a git revision of this checkout, exported to a temporary folder) or ``--before SRC``
(a source folder) also runs that code's ``geofill fill`` in every round, with its own defaults, and
its own ratio to the baseline: a before/after comparison in one run.
"""

from __future__ import annotations

import argparse
import compileall
import importlib.util
import math
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import PAIRS, earlier_cli, export_src, timed_child

HERE = Path(__file__).resolve().parent
BERLIN = "dev_opensfm_berlin_01_02"
SYNTHETIC_SIZES = {"720p": (1280, 720), "4k": (3840, 2160)}


def _make_inputs(case: str, folder: Path) -> None:
    """Runs in a child process: writes target.png, source.png, mask.png for ``case``."""
    from speed import write_inputs, write_pair_files  # this folder is on sys.path when run as a script

    if case == "berlin":
        from geofill.evaluation.pairs import load_pair, pair_mask

        pair = load_pair(PAIRS / BERLIN)
        write_pair_files(folder, pair.target, pair.source, pair_mask(pair, 0))
    else:
        write_inputs(SYNTHETIC_SIZES[case], None, folder)


def _serve_start(port: int) -> tuple[float, float, float]:
    """Seconds from starting ``geofill serve`` until its port accepts a TCP connection, until its
    page (``GET /``) has been served whole, and until the files the page names (script, style,
    icon) have been served too: what a person opening the address waits for."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([_geofill(), "serve", "--port", str(port)], stderr=subprocess.DEVNULL)
    accepted = None
    try:
        while True:
            if proc.poll() is not None:
                raise RuntimeError(
                    f"geofill serve exited with {proc.returncode} (is the server extra installed?)"
                )
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.05).close()
                accepted = accepted or time.perf_counter() - t0
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5) as resp:
                    page = resp.read().decode()
                page_s = time.perf_counter() - t0
                for path in re.findall(r'(?:href|src)="(/static/[^"]+)"', page):
                    with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as resp:
                        resp.read()
                return accepted, page_s, time.perf_counter() - t0
            except OSError:
                time.sleep(0.005)
    finally:
        proc.terminate()
        proc.wait()


def _geofill() -> str:
    return str(Path(sys.executable).parent / "geofill")


def _paired(folder: Path, runs: int, overrides: list[str], before: str | None) -> dict[str, list[float]]:
    """Per run: geofill, the baseline and (with ``before``, another source tree) the earlier code,
    one after the other on the same files."""
    io = ["--target", str(folder / "target.png"), "--mask", str(folder / "mask.png")]
    io += ["--source", str(folder / "source.png")]
    sets = [x for s in overrides for x in ("--set", s)]
    cmds = {
        "geofill": [_geofill(), "fill", *io, "-o", str(folder / "geofill.png"), "--quiet", *sets],
        "baseline": [sys.executable, str(HERE / "homography_baseline.py"), *io, "-o", str(folder / "b.png")],
    }
    envs: dict[str, dict[str, str] | None] = {name: None for name in cmds}
    if before is not None:
        cmds["before"] = earlier_cli("fill", *io, "-o", str(folder / "p.png"), "--quiet")
        envs["before"] = {**os.environ, "PYTHONPATH": before}
    for name, cmd in cmds.items():
        timed_child(cmd, envs[name])  # warm-up
    out: dict[str, list[float]] = {}
    for _ in range(runs):
        for name, cmd in cmds.items():
            wall, rss = timed_child(cmd, envs[name])
            out.setdefault(name, []).append(wall)
            out.setdefault(f"{name} rss", []).append(rss)
        out.setdefault("ratio", []).append(out["geofill"][-1] / out["baseline"][-1])
        if before is not None:
            out.setdefault("before ratio", []).append(out["before"][-1] / out["baseline"][-1])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--cases", default="720p,berlin,4k")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument(
        "--before", metavar="REV|SRC", help="earlier code to run alongside: a git revision or a src folder"
    )
    ap.add_argument("--make-inputs", nargs=2, metavar=("CASE", "DIR"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.make_inputs:
        _make_inputs(args.make_inputs[0], Path(args.make_inputs[1]))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        if args.before and not Path(args.before).is_dir():
            args.before = export_src(args.before, Path(tmp))
        return _run(args)


def _byte_compile(src: str | None) -> None:
    """Byte-compile geofill's modules (and those of the ``--before`` tree), as pip does when it
    installs a package: an editable install run with PYTHONDONTWRITEBYTECODE=1 (this workplace
    sets it) otherwise compiles every module from source in every process, ~0.1 s of a fill."""
    spec = importlib.util.find_spec("geofill")
    folders = [Path(spec.origin).parent] + ([Path(src) / "geofill"] if src else [])
    for folder in folders:
        compileall.compile_dir(str(folder), quiet=1)
    print("bytecode: compiled for " + ", ".join(str(f) for f in folders))


def _run(args: argparse.Namespace) -> int:
    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())} ({os.cpu_count()} cpus)")
    _byte_compile(args.before)
    for name, cmd in (("geofill --help", [_geofill(), "--help"]), ("geofill config", [_geofill(), "config"])):
        timed_child(cmd)
        times = [timed_child(cmd)[0] for _ in range(args.runs)]
        print(f"{name:<16s} median {statistics.median(times):.3f} s  (runs {args.runs})")
    if importlib.util.find_spec("uvicorn") is None:
        print(f"{'geofill serve':<16s} skipped: the server extra is not installed in this environment")
    else:
        starts = [_serve_start(8765 + i) for i in range(args.runs + 1)][1:]
        port_s, page_s, files_s = (statistics.median(s[i] for s in starts) for i in (0, 1, 2))
        print(
            f"{'geofill serve':<16s} median {port_s:.3f} s until the port accepts, "
            f"{page_s:.3f} s until the page is served, {files_s:.3f} s with its files (runs {args.runs})"
        )
    medians: dict[str, float] = {}
    head = f"{'case':<8s}{'geofill s':>11s}{'baseline s':>12s}{'ratio':>8s}"
    head += f"{'peak RSS MB':>13s}{'base RSS MB':>13s}"
    if args.before:
        head += f"{'before s':>10s}{'ratio':>7s}{'RSS MB':>8s}"
    print(head + "  geofill runs")
    for case in filter(None, args.cases.split(",")):
        if case == "berlin" and not (PAIRS / BERLIN).is_dir():
            print(f"{case:<8s} skipped: {PAIRS / BERLIN} not found")
            continue
        with tempfile.TemporaryDirectory() as tmp:
            subprocess.run([sys.executable, __file__, "--make-inputs", case, tmp], check=True)
            r = _paired(Path(tmp), args.runs, args.set, args.before)
        med = {k: statistics.median(v) for k, v in r.items()}
        medians[case] = med["geofill"]
        row = (
            f"{case:<8s}{med['geofill']:11.3f}{med['baseline']:12.3f}{med['ratio']:8.2f}"
            f"{med['geofill rss']:13.0f}{med['baseline rss']:13.0f}"
        )
        if args.before:
            row += f"{med['before']:10.3f}{med['before ratio']:7.2f}{med['before rss']:8.0f}"
        print(f"{row}  {' '.join(f'{t:.2f}' for t in r['geofill'])}")
    if "720p" in medians and "4k" in medians:
        exponent = math.log(medians["4k"] / medians["720p"]) / math.log(9.0)
        print(f"time grows as pixels^{exponent:.2f} (720p -> 4k, 9x the pixels)")
    print(f"load average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
