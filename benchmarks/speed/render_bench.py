"""Time the mesh renderer at 1280x720 (the issue's budget: <= 0.5 s) on a ray-cast synthetic pair
rendered with its exact depth and pose, and check what it reproduces.

    .venv/bin/python benchmarks/speed/render_bench.py [--width 1280 --height 720 --repeat 5]

Prints, for the whole target view and for the hole's window (what the pipeline rasterises): the
median wall time of ``render_mesh`` (numba compiled beforehand), of ``RenderResult.sample``, the
fraction of the hole covered and the hole PSNR of the render against the ray-cast target. Figures,
not a test.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from geofill.camera import Intrinsics
from geofill.config import FillConfig
from geofill.evaluation.metrics import psnr
from geofill.pipeline import render_margin_px
from geofill.render import render_mesh, render_roi
from geofill.synthetic import make_pair


def _median_time(fn, repeat: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    p = make_pair(seed=args.seed, width=args.width, height=args.height)
    cast_s = time.perf_counter() - t0
    print(f"synthetic pair {args.width}x{args.height} (seed {args.seed}) cast in {cast_s:.1f} s")
    K_s = Intrinsics.from_matrix(p.K_source, p.source.shape[1], p.source.shape[0])
    K_t = Intrinsics.from_matrix(p.K_target, p.target.shape[1], p.target.shape[0])
    margin = int(render_margin_px(FillConfig()) * max(args.width, args.height) / 1280)
    render_mesh(p.depth_source[:8, :8], K_s.resized(8, 8), K_t, p.T_source_to_target, 0.04)  # compile
    print(
        f"{'window':<14s}{'pixels':>10s}{'render_s':>10s}{'sample_s':>10s}{'coverage':>10s}{'psnr_hole':>10s}"
    )
    for name, roi in (("whole view", None), ("hole + margin", render_roi(p.hole, margin))):
        t_render, r = _median_time(
            lambda roi=roi: render_mesh(p.depth_source, K_s, K_t, p.T_source_to_target, 0.04, roi),
            args.repeat,
        )
        t_sample, warped = _median_time(lambda r=r: r.sample(p.source), args.repeat)
        covered = p.hole & r.alpha
        x0, y0, x1, y1 = r.roi
        print(
            f"{name:<14s}{(x1 - x0) * (y1 - y0):>10d}{t_render:>10.3f}{t_sample:>10.3f}"
            f"{covered.sum() / p.hole.sum():>10.3f}{psnr(warped, p.target, covered):>10.2f}"
        )
    print(f"(median of {args.repeat} runs; {np.prod(p.depth_source.shape[:2]) * 2 / 1e6:.1f} M triangles)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
