"""What ``geofill batch`` writes for a shoot of JPEGs, before and after outputs kept their input's
format, and what flushing a written image to disk costs.

    .venv/bin/python benchmarks/speed/output_files.py [--pairs ../shared/data/pairs] [--before main]
        [--limit N] [--jobs 2] [--write-runs 9]

Sizes: the DEV pairs whose target is a JPEG (the ``dev_wide_`` ones left out) become one batch
(images/<pair>.jpg, masks/<pair>.png, refs/<pair>/, files linked as ``batch_bench.py`` does), run
by the ``--before`` revision's ``geofill batch`` and by this checkout's, each into its own folder.
Per pair: the input's size, each output's name and size, and whether this checkout's JPEG output
has the input's quantisation tables and subsampling (read with Pillow).

Flush: on the PNG ``write_image_atomic`` makes of a 1280x720 image (a smooth gradient plus noise),
in a folder of this checkout (a real disk, not a tmpfs), the median time of the rename step with
the file and folder ``fsync``s (:func:`geofill.io.replace_durably`) and without them (a plain
``os.replace``), the two alternating run by run; the whole write's time for scale.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image, JpegImagePlugin

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import PAIRS, ROOT, earlier_cli, export_src, timed_child
from benchmarks.speed.batch_bench import dev_pairs, make_shoot

from geofill.io import output as io_output


def run_batches(pairs: list[Path], before: str, jobs: int, tmp: Path) -> tuple[Path, Path, Path]:
    """(images folder, before's output folder, this checkout's output folder)."""
    root = tmp / "shoot"
    make_shoot(pairs, root)
    args = ["batch", "--images", str(root / "images"), "--masks", str(root / "masks")]
    args += ["--sources-per-image", str(root / "refs"), "--jobs", str(jobs), "-q", "--allow-fallback"]
    outs = {}
    (tmp / "before").mkdir()
    for label, src in (("before", export_src(before, tmp / "before")), ("after", str(ROOT / "src"))):
        outs[label] = tmp / f"out_{label}"
        wall, _ = timed_child(
            [*earlier_cli(*args, "--out", str(outs[label]))], env=os.environ | {"PYTHONPATH": src}
        )
        print(f"{label}: {len(pairs)} items in {wall:.0f} s")
    return root / "images", outs["before"], outs["after"]


def tables(path: Path) -> tuple[dict, int] | None:
    with Image.open(path) as img:
        if img.format != "JPEG":
            return None
        return {k: list(v) for k, v in img.quantization.items()}, JpegImagePlugin.get_sampling(img)


def print_sizes(images: Path, before: Path, after: Path) -> None:
    mb = 1e6
    rows, same = [], 0
    totals = np.zeros(3)
    for image in sorted(images.iterdir()):
        (b,) = before.glob(f"{image.stem}.*")
        (a,) = after.glob(f"{image.stem}.*")
        sizes = np.array([image.stat().st_size, b.stat().st_size, a.stat().st_size]) / mb
        totals += sizes
        kept = tables(a) == tables(image.resolve())
        same += kept
        rows.append((image.stem, *sizes, b.suffix, a.suffix, sizes[1] / sizes[0], sizes[2] / sizes[0], kept))
    head = f"{'pair':42s} {'input MB':>8s} {'before MB':>9s} {'after MB':>8s}"
    print(f"\n{head}  before/in after/in  tables kept")
    for name, i, b, a, bs, as_, rb, ra, kept in rows:
        print(f"{name:42s} {i:8.3f} {b:8.3f}{bs:<4s} {a:7.3f}{as_:<4s} {rb:7.2f}x {ra:7.2f}x  {kept}")
    i, b, a = totals
    print(f"{'total':42s} {i:8.3f} {b:8.3f}     {a:7.3f}     {b / i:7.2f}x {a / i:7.2f}x  {same}/{len(rows)}")


def time_writes(runs: int) -> None:
    """The rename step of a write, with and without the fsyncs, on the file a 1280x720 fill makes;
    then the whole write for scale. The rename step is timed alone: encoding is CPU work whose time
    swings with the machine's load, the flush is disk work."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:720, 0:1280]
    smooth = np.dstack([xx * 255 // 1279, yy * 255 // 719, (xx + yy) * 255 // 1998])
    rgb = np.clip(smooth + rng.normal(0, 6, smooth.shape), 0, 255).astype(np.uint8)
    steps = {"with fsync": io_output.replace_durably, "without fsync": os.replace}
    times: dict[str, list[float]] = {label: [] for label in steps}
    whole = []
    with tempfile.TemporaryDirectory(dir=ROOT) as folder:
        dest, tmp = Path(folder) / "out.png", Path(folder) / ".out.png.tmp"
        io_output.write_image_atomic(dest, rgb)
        data = dest.read_bytes()
        for run in range(runs):
            for label in sorted(steps, reverse=run % 2 == 1):  # alternating which goes first
                tmp.write_bytes(data)
                t0 = time.perf_counter()
                steps[label](tmp, dest)
                times[label].append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            io_output.write_image_atomic(dest, rgb)
            whole.append(time.perf_counter() - t0)
    print(f"\n1280x720 PNG ({len(data) / 1e6:.2f} MB), {runs} runs, median (min-max) ms:")
    for label, ts in times.items():
        ms = np.array(ts) * 1e3
        print(f"  rename step {label:14s} {statistics.median(ms):7.2f} ({ms.min():.2f}-{ms.max():.2f})")
    ms = np.array(whole) * 1e3
    print(f"  whole write_image_atomic   {statistics.median(ms):7.1f} ({ms.min():.1f}-{ms.max():.1f})")
    extra = statistics.median(times["with fsync"]) - statistics.median(times["without fsync"])
    share = extra / statistics.median(whole)
    print(f"  fsync adds {extra * 1e3:.2f} ms per image (median), {share:.1%} of a whole write")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=Path, default=PAIRS)
    ap.add_argument("--before", default="main", help="git revision whose batch is 'before' (default main)")
    ap.add_argument("--limit", type=int, help="only the first N JPEG pairs")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--write-runs", type=int, default=9, help="timed writes with and without fsync")
    ap.add_argument("--skip-sizes", action="store_true", help="only the fsync timing")
    args = ap.parse_args()
    if not args.skip_sizes:
        pairs = [p for p in dev_pairs(args.pairs) if (p / "target.jpg").is_file()][: args.limit]
        with tempfile.TemporaryDirectory() as tmp:
            print_sizes(*run_batches(pairs, args.before, args.jobs, Path(tmp)))
    time_writes(args.write_runs)


if __name__ == "__main__":
    main()
