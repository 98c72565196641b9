"""How a ``geofill batch`` stops on a signal: seconds from the signal to the process's exit, and
whether every output it wrote is recorded in results.jsonl (what ``--resume`` trusts).

16 synthetic 320x240 items, ``--jobs 2``; the signal is sent one second after the first record.
With ``--before REV`` the same runs alternate with that revision's code, in the same rounds.

    .venv/bin/python benchmarks/speed/batch_stop.py --runs 3 --before main
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root
from benchmarks.common import ROOT, export_src

from geofill.synthetic import blanked, make_pair


def _shoot(root: Path) -> None:
    for seed in (3, 5):
        p = make_pair(seed=seed, width=320, height=240)
        for i in range(8):
            name = f"t{seed}_{i}"
            for sub in ("images", "masks", f"refs/{name}"):
                (root / sub).mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(root / "images" / f"{name}.png"), blanked(p.target, p.hole)[..., ::-1])
            cv2.imwrite(str(root / "masks" / f"{name}.png"), p.hole.astype(np.uint8) * 255)
            cv2.imwrite(str(root / "refs" / name / "view.png"), p.source[..., ::-1])


def stop_once(src: str, root: Path, sig: int) -> tuple[float, int, int, int]:
    """(seconds from the signal to the exit, exit status, records, outputs written)."""
    out = root / "out"
    subprocess.run(["rm", "-rf", str(out)], check=True)
    cmd = [sys.executable, "-m", "geofill.cli", "batch", "--images", str(root / "images")]
    cmd += ["--masks", str(root / "masks"), "--sources-per-image", str(root / "refs"), "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": src}
    proc = subprocess.Popen(
        [*cmd, "--jobs", "2"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env
    )
    results = out / "results.jsonl"
    while not (results.is_file() and results.read_text().strip()):
        time.sleep(0.05)
    time.sleep(1.0)
    t0 = time.perf_counter()
    proc.send_signal(sig)
    code = proc.wait()
    stopped = time.perf_counter() - t0
    records = [json.loads(line) for line in results.read_text().splitlines() if line.strip()]
    return stopped, code, len(records), len(list(out.glob("*.png")))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--before", metavar="REV", help="alternate with this revision's code")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="geofill-batch-stop-") as tmp:
        root = Path(tmp)
        _shoot(root / "shoot")
        trees = {"this": str(ROOT / "src")}
        if args.before:
            trees["before"] = export_src(args.before, root)
        print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
        for name, sig in (("SIGTERM", signal.SIGTERM), ("SIGINT", signal.SIGINT)):
            rows: dict[str, list[tuple[float, int, int, int]]] = {t: [] for t in trees}
            for _ in range(args.runs):
                for tree, src in trees.items():
                    rows[tree].append(stop_once(src, root / "shoot", sig))
            for tree, runs in rows.items():
                med = statistics.median(r[0] for r in runs)
                detail = ", ".join(f"exit {c} records {n} outputs {k}" for _, c, n, k in runs)
                print(f"{name:<7s} {tree:<6s} median {med:.2f} s to exit  ({detail})")
        print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
