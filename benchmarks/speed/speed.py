"""End-to-end speed and memory: per-stage and total wall time and peak RSS of a fill at several sizes
(default 960x540, 1280x720, 1920x1080, 3840x2160), and how time grows with pixel count.

Each size runs in a fresh Python process that reads the images from files and writes the result, as
the CLI does, so its peak RSS is that of one real fill. Peak RSS is VmHWM from /proc/self/status
(Linux): ru_maxrss would carry the parent's high-water mark over fork+exec. Inputs are a synthetic ray-cast
pair (default) or a real pair resized to each size (``--pair DIR``). ``--runs N`` reports per-stage
medians of N measured processes per size; ``--warm`` times a second fill in each process (the
stages' own cost, without numba's start-up and other first-use costs). ``--baseline REV|SRC`` runs
other code (a git revision of this checkout, exported to a temporary folder, or a ``src`` folder)
on the same inputs, alternating with this one run by run so that load from other jobs falls on
both alike, and adds its medians and the ratio (this / baseline).

    .venv/bin/python benchmarks/speed/speed.py [--sizes 1280x720,3840x2160] [--pair ../shared/data/pairs/X]
    [--runs 3] [--warm] [--baseline REV|SRC] [--set key=value ...]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import export_src

DEFAULT_SIZES = "960x540,1280x720,1920x1080,3840x2160"


def _peak_rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM in /proc/self/status (this benchmark needs Linux)")


def _child(folder: Path, overrides: list[str], warm: bool) -> None:
    """Runs in the subprocess: one timed fill from files (after an untimed one if ``warm``); prints
    a JSON line."""
    baseline_mb = _peak_rss_mb()
    from geofill.config import FillConfig, parse_overrides
    from geofill.io import read_image, read_mask, write_image_atomic
    from geofill.pipeline import fill

    import_mb = _peak_rss_mb()
    cfg = FillConfig().updated(parse_overrides(overrides))
    if warm:
        fill(
            read_image(folder / "target.png").pixels,
            read_mask(folder / "mask.png"),
            read_image(folder / "source.png").pixels,
            cfg,
        )
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
    """target.png, source.png (RGB in) and mask.png (255 = hole) in ``folder``, the target's hole
    blanked: the reference fill is what is timed. A hole showing the true background would be an
    object the references show again, refused and painted (another job, and not what older trees
    did with the same files)."""
    from geofill.synthetic import blanked

    target = blanked(target, hole)
    cv2.imwrite(str(folder / "target.png"), cv2.cvtColor(target, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(folder / "source.png"), cv2.cvtColor(source, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(folder / "mask.png"), hole.astype(np.uint8) * 255)


def write_inputs(size: tuple[int, int], pair_dir: str | None, folder: Path) -> None:
    """The pair files of one size: the synthetic scene, or the real pair ``pair_dir`` resized."""
    from geofill.evaluation.pairs import load_pair, pair_mask
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


def _measure(folder: Path, overrides: list[str], src: str | None, warm: bool = False) -> dict:
    """One fill in a fresh process (``src`` first on its path when given); its JSON record."""
    cmd = [sys.executable, __file__, "--child", str(folder), *(x for s in overrides for x in ("--set", s))]
    cmd += ["--warm"] if warm else []
    env = {**os.environ, "PYTHONPATH": src} if src else None
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout
    return json.loads(out.strip().splitlines()[-1])


def _median(records: list[dict]) -> dict:
    """Per-stage, total and peak-RSS medians of several records of one size and tree."""
    stages = list(dict.fromkeys(s for r in records for s in r["stages"]))
    out = dict(records[0])
    out["stages"] = {
        s: statistics.median(r["stages"][s] for r in records if s in r["stages"]) for s in stages
    }
    for key in ("total", "peak_rss_mb", "after_import_rss_mb"):
        out[key] = statistics.median(r[key] for r in records)
    out["peak_rss_max_mb"] = max(r["peak_rss_mb"] for r in records)
    return out


def _table(results: list[dict], baseline: list[dict] | None) -> None:
    cols = []
    for i, r in enumerate(results):
        cols.append((r["size"], r))
        if baseline is not None:
            cols.append((f"{r['size']} base", baseline[i]))
    stages = list(dict.fromkeys(s for _, r in cols for s in r["stages"]))
    # (label, value of a record, decimals)
    rows = [(s, lambda r, s=s: r["stages"].get(s, float("nan")), 3) for s in stages]
    rows += [("total", lambda r: r["total"], 3), ("peak RSS (MB)", lambda r: r["peak_rss_mb"], 0)]
    if any(r["peak_rss_max_mb"] != r["peak_rss_mb"] for _, r in cols):
        rows.append(("max RSS (MB)", lambda r: r["peak_rss_max_mb"], 0))
    rows.append(("after import", lambda r: r["after_import_rss_mb"], 0))
    width = max(14, *(len(name) + 2 for name, _ in cols))
    print(f"{'stage (s)':<14s}" + "".join(f"{name:>{width}s}" for name, _ in cols))
    for label, get, decimals in rows:
        print(f"{label:<14s}" + "".join(f"{get(r):{width}.{decimals}f}" for _, r in cols))
    print(f"{'status':<14s}" + "".join(f"{r['status']:>{width}s}" for _, r in cols))
    if baseline is not None:
        print("ratio this / baseline (medians):")
        for r, b in zip(results, baseline, strict=True):
            parts = [f"{s} {r['stages'][s] / b['stages'][s]:.2f}" for s in r["stages"] if b["stages"].get(s)]
            print(f"  {r['size']}: total {r['total'] / b['total']:.2f}, peak RSS "
                  f"{r['peak_rss_mb'] / b['peak_rss_mb']:.2f}; " + ", ".join(parts))  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=DEFAULT_SIZES)
    ap.add_argument("--pair", help="a real pair folder, resized to each size (default: synthetic scene)")
    ap.add_argument("--runs", type=int, default=1, help="measured processes per size (medians)")
    ap.add_argument(
        "--baseline",
        metavar="REV|SRC",
        help="other code to run alternately: a git revision of this checkout or a src folder",
    )
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument(
        "--warm",
        action="store_true",
        help="time a second fill in each process: the stages without a fresh process's first-use costs",
    )
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        _child(Path(args.child), args.set, args.warm)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        if args.baseline and not Path(args.baseline).is_dir():
            args.baseline = export_src(args.baseline, Path(tmp))
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    trees = [None] if args.baseline is None else [None, str(Path(args.baseline).resolve())]
    results: list[list[dict]] = [[] for _ in trees]
    for w, h in sizes:
        with tempfile.TemporaryDirectory() as tmp:
            write_inputs((w, h), args.pair, Path(tmp))
            for src in trees:  # one warm-up run each so numba's on-disk JIT cache is filled
                _measure(Path(tmp), args.set, src)
            records: list[list[dict]] = [[] for _ in trees]
            for _ in range(max(1, args.runs)):
                for k, src in enumerate(trees):
                    records[k].append(_measure(Path(tmp), args.set, src, args.warm))
        for k in range(len(trees)):
            r = _median(records[k])
            r["size"], r["pixels"] = f"{w}x{h}", w * h
            results[k].append(r)
    _table(results[0], results[1] if args.baseline else None)
    if len(results[0]) >= 2:
        px = np.log([r["pixels"] for r in results[0]])
        t = np.log([r["total"] for r in results[0]])
        slope = np.polyfit(px, t, 1)[0]
        print(f"time grows as pixels^{slope:.2f} (least-squares slope of log time vs log pixels)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
