"""Single-image painters on whole stroke holes: quality on the DEV pairs and time at 720p / 4K.

    .venv/bin/python benchmarks/quality/painter.py --out DIR [--painters telea,exemplar,...] [--pairs N]

Quality: the first 8 DEV pairs by id (the wide-baseline ones excluded), each target scaled to a
720-px long side with the evaluation's brush-stroke hole (seed 0) drawn at a mean width of 100 px
there; the painter fills the whole hole (the single-image fallback). Per painter, over the hole:
PSNR and SSIM against the truth; the gradient-energy ratio (mean gradient magnitude in the hole over
that in the known ring 20 px around it: a smear is far below 1, the truth's own ratio is printed
too); the patch distance (RMS, 0-255, of 400 fill patches of 5x5 px to their exact nearest known
patch, sampled every 2 px: a fill made of the photo's own patches is near 0); and the median time.

Time: a 1280x720 and a 3840x2160 crop of a DEV target with a 15 % stroke hole (and at 1280x720 also
30 % and 45 %), each painter alternated with Telea in the same run, medians of ``--repeats``: wall
time and, in brackets, the process's CPU time (all threads; less disturbed by other processes on a
shared machine than the wall time).

Memory (``--memory``): each timed painter in a fresh process on the DEV Berlin photo scaled to
``--memory-size`` (default 7600x7600, 58 MP) with a centred rectangular hole of 89 %: the peak
resident set (ru_maxrss) of the painting process, and the same process's peak before painting.

Removals (``--removals``): the real removals of ``removal_cases.py`` plus a 120-px disc brushed over
Berlin cathedral's carved pediment, each filled with the default configuration (references, then
the painter for what they leave) and painted whole by the painter alone; the crops round the hole
go to ``DIR/removal_<case>.png``. ``--compare DIR2`` puts DIR2's crops (a run with another painter,
e.g. an older checkout) beside them in ``DIR/compare_<case>.png``.

Writes ``DIR/painter.json`` (every number) and ``DIR/painter.md`` (the tables, for
docs/results.md) and, with ``--sheets``, contact sheets (truth | hole | each painter) there.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import HELD_OUT, PAIRS

LONG_SIDE = 720
STROKE_PX = 100.0
RING_PX = 20
PATCH = 5
PATCH_SAMPLES = 400


def _painters() -> dict:
    from geofill.composite.inpaint import get_inpainter
    from geofill.config import InpaintConfig

    def project(method: str):
        inp = get_inpainter(InpaintConfig(method=method))
        return lambda img, hole: inp.fill(img, hole)

    def xphoto(flag: int, lab: bool):
        def run(img, hole):
            src = cv2.cvtColor(img, cv2.COLOR_RGB2Lab) if lab else img
            dst = np.zeros_like(src)
            cv2.xphoto.inpaint(src, (~hole).astype(np.uint8), dst, flag)
            out = img.copy()  # the Lab round trip changes known pixels: only the hole is taken
            out[hole] = (cv2.cvtColor(dst, cv2.COLOR_Lab2RGB) if lab else dst)[hole]
            return out

        return run

    return {
        "telea": project("telea"),
        "exemplar": project("exemplar"),
        "patchmatch": project("patchmatch"),
        "shiftmap": xphoto(cv2.xphoto.INPAINT_SHIFTMAP, lab=True),
        "fsr_fast": xphoto(cv2.xphoto.INPAINT_FSR_FAST, lab=False),
    }


def dev_pairs(n: int) -> list[Path]:
    """The first ``n`` DEV pairs by id, wide-baseline ones excluded."""
    return sorted(
        d
        for d in PAIRS.iterdir()
        if d.is_dir() and not d.name.startswith("dev_wide_") and d.name not in HELD_OUT
    )[:n]


def case(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """The pair's target at a 720-px long side and its seed-0 stroke hole (mean width 100 px)."""
    from geofill.evaluation.masks import brush_strokes, mask_seed
    from geofill.evaluation.pairs import load_pair

    pair = load_pair(folder)
    h, w = pair.target.shape[:2]
    s = LONG_SIDE / max(h, w)
    img = cv2.resize(pair.target, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA)
    hole = brush_strokes(*img.shape[:2], seed=mask_seed(pair.id, 0), mean_width_px=STROKE_PX).render(
        STROKE_PX
    )
    return img, hole


def gradient_ratio(img: np.ndarray, hole: np.ndarray) -> float:
    """Mean gradient magnitude (Sobel, grey) in ``hole`` over that in the known ring around it."""
    grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float32)
    mag = np.hypot(cv2.Sobel(grey, cv2.CV_32F, 1, 0), cv2.Sobel(grey, cv2.CV_32F, 0, 1))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * RING_PX + 1, 2 * RING_PX + 1))
    ring = (cv2.dilate(hole.astype(np.uint8), disc) > 0) & ~hole
    return float(mag[hole].mean() / max(mag[ring].mean(), 1e-6))


def patch_distance(img: np.ndarray, hole: np.ndarray) -> float:
    """RMS distance (0-255) of sampled fill patches (wholly in the hole) to their nearest known patch
    (wholly outside it, every 2 px), exact search."""
    h, w = hole.shape
    r = PATCH // 2
    win = np.lib.stride_tricks.sliding_window_view(img.astype(np.float32), (PATCH, PATCH), axis=(0, 1))
    inside = cv2.erode(hole.astype(np.uint8), np.ones((PATCH, PATCH), np.uint8), borderValue=0) > 0
    outside = cv2.erode((~hole).astype(np.uint8), np.ones((PATCH, PATCH), np.uint8), borderValue=0) > 0
    inside, outside = inside[r : h - r, r : w - r], outside[r : h - r, r : w - r]
    grid = np.zeros_like(outside)
    grid[::2, ::2] = True
    ky, kx = np.nonzero(outside & grid)
    qy, qx = np.nonzero(inside)
    pick = np.random.default_rng(0).choice(qy.size, min(PATCH_SAMPLES, qy.size), replace=False)
    known = win[ky, kx].reshape(ky.size, -1)
    query = win[qy[pick], qx[pick]].reshape(pick.size, -1)
    kk = (known * known).sum(1)
    best = np.full(pick.size, np.inf, np.float32)
    for i in range(0, ky.size, 20000):
        d = kk[i : i + 20000][None] - 2.0 * query @ known[i : i + 20000].T
        best = np.minimum(best, d.min(1))
    best = np.maximum(best + (query * query).sum(1), 0.0)
    return float(np.sqrt(best / known.shape[1]).mean())


def quality(painters: dict, folders: list[Path], sheets: Path | None) -> dict:
    from geofill.evaluation.metrics import psnr, ssim

    rows: dict[str, dict[str, list[float]]] = {name: {} for name in ["truth", *painters]}
    for folder in folders:
        img, hole = case(folder)
        blank = img.copy()
        blank[hole] = 0
        tiles = [img, blank]
        truth = rows["truth"]
        for key, val in (("grad", gradient_ratio(img, hole)), ("patch", patch_distance(img, hole))):
            truth.setdefault(key, []).append(val)
        line = [f"{folder.name} ({100 * hole.mean():.0f} % hole): truth grad {truth['grad'][-1]:.2f}"]
        for name, run in painters.items():
            t0 = time.perf_counter()
            out = run(blank, hole)
            dt = time.perf_counter() - t0
            if not np.array_equal(out[~hole], img[~hole]):
                raise RuntimeError(f"{name} changed pixels outside the hole")
            tiles.append(out)
            res = {
                "psnr": psnr(out, img, hole),
                "ssim": ssim(out, img, hole),
                "grad": gradient_ratio(out, hole),
                "patch": patch_distance(out, hole),
                "time": dt,
            }
            for k, v in res.items():
                rows[name].setdefault(k, []).append(v)
            line.append(f"{name} {res['psnr']:.2f} dB grad {res['grad']:.2f} {dt:.2f} s")
        print(" | ".join(line), flush=True)
        if sheets is not None:
            _sheet(tiles, ["truth", "hole", *painters], sheets / f"{folder.name}.jpg")
    return rows


def _sheet(tiles: list[np.ndarray], names: list[str], path: Path) -> None:
    labelled = []
    for tile, name in zip(tiles, names, strict=True):
        t = cv2.cvtColor(tile, cv2.COLOR_RGB2BGR)
        cv2.putText(t, name, (8, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (0, 0, 0), 4, cv2.LINE_AA)
        cv2.putText(t, name, (8, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 255), 2, cv2.LINE_AA)
        labelled.append(t)
    cols = 4
    while len(labelled) % cols:
        labelled.append(np.full_like(labelled[0], 255))
    grid = np.vstack([np.hstack(labelled[i : i + cols]) for i in range(0, len(labelled), cols)])
    cv2.imwrite(str(path), grid, [cv2.IMWRITE_JPEG_QUALITY, 85])


def timing(painters: dict, repeats: int) -> list[dict]:
    """Median seconds per painter and Telea alternated, at each size and hole share."""
    from geofill.evaluation.masks import brush_strokes
    from geofill.evaluation.pairs import load_pair

    photo = load_pair(PAIRS / "dev_opensfm_berlin_01_02").target
    out = []
    for (w, h), share in (
        ((1280, 720), 0.15),
        ((1280, 720), 0.30),
        ((1280, 720), 0.45),
        ((3840, 2160), 0.15),
    ):
        s = max(w / photo.shape[1], h / photo.shape[0])
        big = cv2.resize(
            photo, (round(photo.shape[1] * s), round(photo.shape[0] * s)), interpolation=cv2.INTER_CUBIC
        )
        img = np.ascontiguousarray(big[:h, :w])
        width = 150.0 * h / 720
        hole = brush_strokes(
            h, w, seed=1, mean_width_px=width, area_range=(share - 0.005, share + 0.005)
        ).render(width)
        times: dict[str, list[float]] = {name: [] for name in painters}
        cpu: dict[str, list[float]] = {name: [] for name in painters}
        for _ in range(repeats):
            for name, run in painters.items():
                t0, c0 = time.perf_counter(), time.process_time()
                run(img, hole)
                times[name].append(time.perf_counter() - t0)
                cpu[name].append(time.process_time() - c0)
        row = {"size": f"{w}x{h}", "hole": round(float(hole.mean()), 3), "load": os.getloadavg()[0]}
        row |= {name: statistics.median(v) for name, v in times.items()}
        row |= {f"{name} cpu": statistics.median(v) for name, v in cpu.items()}
        print(row, flush=True)
        out.append(row)
    return out


_MEMORY_SCRIPT = """
import resource, sys, time
import cv2
import numpy as np
from geofill.composite.inpaint import get_inpainter
from geofill.config import InpaintConfig
from geofill.evaluation.pairs import load_pair

method, side, folder = sys.argv[1], int(sys.argv[2]), sys.argv[3]
inp = get_inpainter(InpaintConfig(method=method))
warm = np.zeros((300, 300), bool)
warm[20:280, 20:280] = True
inp.fill(np.full((300, 300, 3), 128, np.uint8), warm)  # compiled before anything is measured
img = cv2.resize(load_pair(folder).target, (side, side), interpolation=cv2.INTER_CUBIC)
hole = np.zeros((side, side), bool)
m = round(side * (1 - 0.89**0.5) / 2)
hole[m : side - m, m : side - m] = True
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
inp.fill(img, hole)
dt = time.perf_counter() - t0
print(float(hole.mean()), before / 1024, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, dt)
"""


def memory(names: list[str], side: int) -> list[dict]:
    """Peak resident memory (MiB) of each painter on a ``side`` x ``side`` photo with an 89 % hole,
    each in its own process."""
    import subprocess

    rows = []
    for name in names:
        folder = str(PAIRS / "dev_opensfm_berlin_01_02")
        done = subprocess.run(
            [sys.executable, "-c", _MEMORY_SCRIPT, name, str(side), folder],
            capture_output=True,
            text=True,
            check=True,
        )
        share, before, peak, dt = (float(v) for v in done.stdout.split())
        row = {"painter": name, "size": f"{side}x{side}", "hole": share, "rss_before_mib": before}
        row |= {"peak_rss_mib": peak, "time": dt}
        print(row, flush=True)
        rows.append(row)
    return rows


def removals(out: Path, compare: Path | None) -> None:
    """Crops of the real removals' fills and single-image paintings (see the module docstring)."""
    from benchmarks.quality.removal_cases import CASES, _crop, _tile, brushed

    from geofill.composite.inpaint import inpaint_single
    from geofill.config import FillConfig
    from geofill.evaluation.pairs import load_pair
    from geofill.pipeline import fill

    cfg = FillConfig()
    yy, xx = np.mgrid[0:960, 0:1280]
    pediment = (
        "berlin_pediment",
        PAIRS / "dev_opensfm_berlin_01_02",
        (yy - 470) ** 2 + (xx - 672) ** 2 <= 60**2,
    )
    for name, folder, polygons in [*CASES, pediment]:
        pair = load_pair(folder)
        hole = polygons if isinstance(polygons, np.ndarray) else brushed(pair.target.shape, polygons)
        exif = {"target_exif": pair.exif.target, "source_exifs": list(pair.exif.sources)}
        filled = fill(pair.target, hole, pair.sources, cfg, **exif)
        painted = inpaint_single(pair.target, hole, cfg.inpaint)
        shown = pair.target.copy()
        shown[hole] = (0.5 * shown[hole] + [127, 0, 127]).astype(np.uint8)
        print(f"{name}: {100 * filled.report.painted_fraction:.0f} % of the hole painted", flush=True)
        tiles = [_crop(shown, hole), _crop(filled.image, hole), _crop(painted, hole)]
        row = np.concatenate(
            [_tile(t, lab) for t, lab in zip(tiles, ("hole", "fill", "painter alone"), strict=True)], 1
        )
        cv2.imwrite(str(out / f"removal_{name}.png"), cv2.cvtColor(row, cv2.COLOR_RGB2BGR))
        if compare is not None and (compare / f"removal_{name}.png").exists():
            other = cv2.imread(str(compare / f"removal_{name}.png"))
            sheet = np.concatenate([other, cv2.cvtColor(row, cv2.COLOR_RGB2BGR)], 0)
            cv2.imwrite(str(out / f"compare_{name}.png"), sheet)


def markdown(rows: dict, times: list[dict], names: list[str], mem: list[dict] | None = None) -> str:
    lines = [
        "| painter | hole PSNR (dB) | hole SSIM | gradient ratio | patch distance | time (median s) |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    t = rows["truth"]
    lines.append(f"| (truth) | | | {np.mean(t['grad']):.2f} | {np.mean(t['patch']):.1f} | |")
    for name in names:
        r = rows[name]
        lines.append(
            f"| {name} | {np.mean(r['psnr']):.2f} | {np.mean(r['ssim']):.3f} | {np.mean(r['grad']):.2f} | "
            f"{np.mean(r['patch']):.1f} | {statistics.median(r['time']):.2f} |"
        )
    if times:
        timed = [n for n in names if n in times[0]]
        lines += [
            "",
            "| image | hole | load | " + " | ".join(timed) + " |",
            "| --- " * (3 + len(timed)) + "|",
        ]
        for row in times:
            cells = " | ".join(f"{row[n]:.2f} s ({row[n + ' cpu']:.2f} s)" for n in timed)
            lines.append(f"| {row['size']} | {100 * row['hole']:.0f} % | {row['load']:.1f} | {cells} |")
    if mem:
        lines += [
            "",
            "| painter | image | hole | peak RSS before painting (MiB) | peak RSS (MiB) | time (s) |",
            "| --- | --- | --- | --- | --- | --- |",
        ]
        for m in mem:
            lines.append(
                f"| {m['painter']} | {m['size']} | {100 * m['hole']:.0f} % | {m['rss_before_mib']:.0f} | "
                f"{m['peak_rss_mib']:.0f} | {m['time']:.1f} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path, help="folder for painter.json / painter.md")
    ap.add_argument("--painters", default="telea,exemplar,patchmatch,shiftmap,fsr_fast")
    ap.add_argument("--timed", default="telea,exemplar", help="painters timed at 1280x720 and 4K")
    ap.add_argument("--pairs", type=int, default=8, help="first N DEV pairs")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--sheets", action="store_true", help="write contact sheets to --out")
    ap.add_argument("--removals", action="store_true", help="crops of the real removals (see above)")
    ap.add_argument("--compare", type=Path, help="with --removals: a folder of another run's crops")
    ap.add_argument("--memory", action="store_true", help="measure the timed painters' peak RSS")
    ap.add_argument("--memory-size", type=int, default=7600, help="side (px) of the --memory photo")
    args = ap.parse_args(argv)
    available = _painters()
    names = args.painters.split(",")
    timed = [n for n in args.timed.split(",") if n]
    unknown = set(names + timed) - set(available)
    if unknown:
        ap.error(f"unknown painter(s) {sorted(unknown)}; known: {sorted(available)}")
    args.out.mkdir(parents=True, exist_ok=True)
    # Compile the numba kernels (and start OpenCV) before anything is timed.
    warm = np.full((64, 64, 3), 128, np.uint8)
    warm_hole = np.zeros((64, 64), bool)
    warm_hole[20:40, 20:40] = True
    for n in set(names + timed) & {"exemplar"}:
        available[n](warm, warm_hole)
    print(f"load {os.getloadavg()}", flush=True)
    if args.removals:
        removals(args.out, args.compare)
        return 0
    rows = quality({n: available[n] for n in names}, dev_pairs(args.pairs), args.out if args.sheets else None)
    times = timing({n: available[n] for n in timed}, args.repeats) if timed else []
    mem = memory(timed, args.memory_size) if args.memory else []
    numbers = {"quality": rows, "timing": times, "memory": mem}
    (args.out / "painter.json").write_text(json.dumps(numbers, indent=1))
    (args.out / "painter.md").write_text(markdown(rows, times, names, mem))
    print(markdown(rows, times, names, mem))
    return 0


if __name__ == "__main__":
    sys.exit(main())
