"""End-to-end speed and memory: per-stage and total wall time and peak RSS of a fill at several sizes
(default 960x540, 1280x720, 1920x1080, 3840x2160), and how time grows with pixel count.

Each size runs in a fresh Python process that reads the images from files and writes the result, as
the CLI does, so its peak RSS is that of one real fill. Peak RSS is VmHWM from /proc/self/status
(Linux): ru_maxrss would carry the parent's high-water mark over fork+exec. Inputs are a synthetic ray-cast
pair (default) or a real pair resized to each size (``--pair DIR``).

    .venv/bin/python benchmarks/speed.py [--sizes 1280x720,3840x2160] [--pair ../shared/data/pairs/X]
    [--set key=value ...]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

DEFAULT_SIZES = "960x540,1280x720,1920x1080,3840x2160"


def _peak_rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM in /proc/self/status (this benchmark needs Linux)")


def _child(folder: Path, overrides: list[str]) -> None:
    """Runs in the subprocess: one timed fill from files; prints a JSON line."""
    baseline_mb = _peak_rss_mb()
    from geofill.config import FillConfig, parse_overrides
    from geofill.io import read_image, read_mask, write_image_atomic
    from geofill.pipeline import fill

    import_mb = _peak_rss_mb()
    cfg = FillConfig().updated(parse_overrides(overrides))
    t0 = time.perf_counter()
    target = read_image(folder / "target.png", max_pixels=cfg.max_pixels)
    source = read_image(folder / "source.png", max_pixels=cfg.max_pixels)
    mask = read_mask(folder / "mask.png", max_pixels=cfg.max_pixels)
    t_read = time.perf_counter() - t0
    res = fill(target.pixels, mask, source.pixels, cfg)
    t1 = time.perf_counter()
    write_image_atomic(folder / "out.png", res.image)
    t_write = time.perf_counter() - t1
    stages = {"read": t_read, **res.report.timings_s, "write": t_write}
    print(
        json.dumps(
            {
                "stages": stages,
                "total": time.perf_counter() - t0,
                "peak_rss_mb": _peak_rss_mb(),
                "after_import_rss_mb": import_mb,
                "interpreter_rss_mb": baseline_mb,
                "status": res.report.status,
            }
        )
    )


def write_pair_files(folder: Path, target: np.ndarray, source: np.ndarray, hole: np.ndarray) -> None:
    """target.png, source.png (RGB in) and mask.png (255 = hole) in ``folder``, as a user would pass them."""
    cv2.imwrite(str(folder / "target.png"), cv2.cvtColor(target, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(folder / "source.png"), cv2.cvtColor(source, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(folder / "mask.png"), hole.astype(np.uint8) * 255)


def write_inputs(size: tuple[int, int], pair_dir: str | None, folder: Path) -> None:
    """The pair files of one size: the synthetic scene, or the real pair ``pair_dir`` resized."""
    from geofill.evaluation.runner import load_pair, pair_mask
    from geofill.synthetic import make_pair

    w, h = size
    if pair_dir:
        pair = load_pair(pair_dir)
        target = cv2.resize(pair.target, (w, h), interpolation=cv2.INTER_CUBIC)
        source = cv2.resize(pair.source, (w, h), interpolation=cv2.INTER_CUBIC)
        pair.target = target
        hole = pair_mask(pair, 0)
    else:
        sp = make_pair(seed=0, width=w, height=h, supersample=1 if w * h > 3e6 else 2)
        target, source = sp.target, sp.source
        hole = cv2.resize(sp.hole.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
    write_pair_files(folder, target, source, hole)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=DEFAULT_SIZES)
    ap.add_argument("--pair", help="a real pair folder, resized to each size (default: synthetic scene)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        _child(Path(args.child), args.set)
        return 0
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    results = []
    for w, h in sizes:
        with tempfile.TemporaryDirectory() as tmp:
            write_inputs((w, h), args.pair, Path(tmp))
            cmd = [sys.executable, __file__, "--child", tmp, *(x for s in args.set for x in ("--set", s))]
            # One warm-up run so numba's on-disk JIT cache is filled; the second run is measured.
            subprocess.run(cmd, check=True, capture_output=True)
            out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
        r = json.loads(out.strip().splitlines()[-1])
        r["size"] = f"{w}x{h}"
        r["pixels"] = w * h
        results.append(r)
    stages = list(dict.fromkeys(s for r in results for s in r["stages"]))
    print(f"{'stage (s)':<14s}" + "".join(f"{r['size']:>12s}" for r in results))
    for s in stages:
        print(f"{s:<14s}" + "".join(f"{r['stages'].get(s, float('nan')):12.3f}" for r in results))
    print(f"{'total':<14s}" + "".join(f"{r['total']:12.3f}" for r in results))
    print(f"{'peak RSS (MB)':<14s}" + "".join(f"{r['peak_rss_mb']:12.0f}" for r in results))
    print(f"{'after import':<14s}" + "".join(f"{r['after_import_rss_mb']:12.0f}" for r in results))
    print(f"{'status':<14s}" + "".join(f"{r['status']:>12s}" for r in results))
    if len(results) >= 2:
        px = np.log([r["pixels"] for r in results])
        t = np.log([r["total"] for r in results])
        slope = np.polyfit(px, t, 1)[0]
        print(f"time grows as pixels^{slope:.2f} (least-squares slope of log time vs log pixels)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
