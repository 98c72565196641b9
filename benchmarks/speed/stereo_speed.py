"""Time of the ``stereo`` depth backend at 1280x720 (the issue's budget: <= 2 s on this 2-core machine).

Inputs: a synthetic scene rendered at 1280x720 and the real pairs of about that size; the pipeline
runs up to the triangulated points once, then the backend alone is timed (median of ``--repeat``
runs, after one warm-up), split into the sweep (cost volume, aggregation, winner-take-all,
confidence) and the completion, with the backend's CPU time beside its wall time (the CPU time of
the process, OpenCV's worker threads included: steadier than wall time on a shared machine). The
first backend call of the process is timed apart: it loads the compiled kernels from numba's
cache (or compiles them, on a cold cache). Timings on a shared machine are provisional.

    .venv/bin/python benchmarks/speed/stereo_speed.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from geofill.config import FillConfig
from geofill.depth import DepthContext
from geofill.depth.stereo import StereoDepth, complete, plane_sweep
from geofill.evaluation.pairs import load_pairs, pair_mask
from geofill.pipeline import fill
from geofill.synthetic import make_pair

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS

REAL = ("dev_cotracker_apple_video", "dev_opensfm_berlin_01_02", "dev_mast3r_nle_tower_a")


def context(target: np.ndarray, hole: np.ndarray, source: np.ndarray, cfg: FillConfig) -> DepthContext:
    res = fill(target, hole, source, cfg.updated({"depth.backend": "sparse"}))
    a = res.references[0]
    v, K = a.views, a.focal
    return DepthContext(
        v.source, v.target, v.hole, K.K_source, K.K_target, a.pose, a.points, (0, 0), cfg.depth
    )


def timed(fn, repeat: int) -> tuple[float, float, object]:
    """Median wall and CPU seconds of ``fn`` over ``repeat`` runs after a warm-up, and its output."""
    out = fn()  # warm-up
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu), out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    cfg = FillConfig()
    cases = []
    sp = make_pair(seed=0, width=1280, height=720)
    cases.append(("synthetic 1280x720", sp.target, sp.hole, sp.source))
    if PAIRS.is_dir():
        for pair in load_pairs([PAIRS], exclude=HELD_OUT):
            if pair.id in REAL:
                hole = pair_mask(pair, 0)
                cases.append(
                    (pair.id, np.where(hole[..., None], 0, pair.target).astype(np.uint8), hole, pair.source)
                )
    cols = ("size", 10), ("sweep px", 9), ("planes", 6), ("sweep", 7), ("complete", 8), ("backend", 8)
    cols += (("cpu", 7),)
    print(f"{'input':<34s} " + " ".join(f"{c:>{n}s}" for c, n in cols))
    for name, target, hole, source in cases:
        ctx = context(target, hole, source, cfg)
        t_sweep, _, sweep = timed(lambda ctx=ctx: plane_sweep(ctx), args.repeat)
        t_comp, _, _ = timed(lambda ctx=ctx, sweep=sweep: complete(sweep, ctx), args.repeat)
        t_all, c_all, _ = timed(lambda ctx=ctx: StereoDepth().predict(ctx), args.repeat)
        h, w = ctx.source.shape[:2]
        hs, ws = sweep.inv_depth.shape
        print(
            f"{name:<34s} {f'{w}x{h}':>10s} {f'{ws}x{hs}':>9s} {sweep.hyp.count:6d} "
            f"{t_sweep:6.3f}s {t_comp:7.3f}s {t_all:7.3f}s {c_all:6.3f}s",
            flush=True,
        )
    print(f"(median of {args.repeat} after a warm-up; {cv2.getNumThreads()} OpenCV threads; shared machine)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
