"""The real removal panel: objects and passers-by brushed out of real photos and video frames
(``benchmarks/panel/cases.json``), each filled by geofill (default settings, every reference),
OpenCV's Telea (no reference) and the single-homography warp of the first reference. Writes one
contact sheet per case (the input with the brush outline and the three fills, then the same around
the hole at about 2x) and prints, per case and method, three automatic proxies of how much of the
removed object came back, and where geofill's hole pixels came from.

    .venv/bin/python benchmarks/quality/real_panel.py [--out docs/img/panel] [--only a,b]

The sheets are what the panel is judged on (docs/results.md scores them 0-3 by eye); the proxies
only flag the object coming back:

* ``back``: :func:`geofill.evaluation.metrics.leak` with the object's own pixels (the hand-drawn
  silhouette inside the brush) against a smooth background estimate (OpenCV Navier-Stokes
  inpainting of the brush on a blurred copy): of the object pixels that differ from that estimate,
  the share where the output is much closer to the object than to the estimate. It misses an object
  copied a few pixels off its place, and a textured fill can come close to a bright or dark object
  by chance.
* ``echo``: the object's appearance anywhere near the hole: the best masked match (squared
  difference) of the object's patch over the output within the brush's box, as
  ``1 - best / (object against the background estimate)``, floored at 0: 1 = the object is there
  (moved or not), 0 = nothing nearer to it than the smooth background. A person who walked a step in
  the reference and is copied back counts here and not in ``back``; a fill with the same colours as
  the object (a dark doorway behind a dark coat) counts too; a copy at another size does not.
* ``tint``: the object's own colours anywhere in the hole at any size (:func:`tint`): hole pixels in
  the colour bins the object has 4x more often than a ring around the brush, relative to the
  input's count (1 = as many as the object had). It sees a car that comes back smaller or a
  skirt's blue in pieces; it is n/a for an object coloured like its surroundings and blind to
  shape, and a fill that pulls the object's colours in from elsewhere counts too.

Neither says whether the background is right (there is no ground truth): that is the eye's job.
Data: folders of ``../shared/data`` are read in place; a case from a public repository is read from
a git snapshot of it under ``--mirrors`` (``owner+name/repo``, at the recorded commit). A case whose
data is absent is skipped with one line saying so.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import zlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from geofill.config import FillConfig
from geofill.evaluation.baselines import BaselineError, homography_fill, opencv_inpaint
from geofill.evaluation.metrics import leak
from geofill.evaluation.pairs import load_pair
from geofill.pipeline import FillReport, fill
from geofill.screen.colours import colour_bins

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root: benchmarks.common
from benchmarks.common import ROOT
from benchmarks.quality.removal_cases import CASES as BRUSHED_CASES
from benchmarks.quality.removal_cases import brushed

MANIFEST = ROOT / "benchmarks" / "panel" / "cases.json"
SHARED = ROOT.parent / "shared" / "data"
#: Where ``fetch`` puts git snapshots of public repositories (``owner+name/repo``).
MIRRORS = ROOT.parents[1] / ".mirror"
_LONG_SIDE_PX = 1280.0
#: Contact-sheet tile size (px); the crop row shows a hole box of half this at 2x when it fits.
TILE_W, TILE_H = 400, 300
_BRUSH_RGB = (255, 0, 255)
#: The methods each case is filled with, in the sheets' and tables' order.
METHODS = ("geofill", "telea", "homography")


@dataclass(frozen=True)
class Case:
    """One panel case: the target, its references, the object's own pixels and the brushed hole."""

    name: str
    what: str
    target: np.ndarray  # HxWx3 uint8 RGB
    references: list[np.ndarray]
    object_mask: np.ndarray  # HxW bool, the object's silhouette inside the brush
    hole: np.ndarray  # HxW bool, the brush
    source: str  # repository @ commit, licence


class DataAbsent(Exception):
    """The case's images are not on this machine."""


def _polygons_mask(shape: tuple[int, ...], polygons: list[list[list[int]]]) -> np.ndarray:
    return brushed(shape, [[tuple(p) for p in poly] for poly in polygons])


def wobbly_brush(object_mask: np.ndarray, margin_px: tuple[float, float], seed: int) -> np.ndarray:
    """The object grown by a margin that wanders smoothly between ``margin_px`` (min, max, at a
    1280-px long side, scaled to the image) around it, as a hand-held brush does."""
    h, w = object_mask.shape
    scale = max(h, w) / _LONG_SIDE_PX
    lo, hi = margin_px[0] * scale, margin_px[1] * scale
    distance = cv2.distanceTransform((~object_mask).astype(np.uint8), cv2.DIST_L2, 5)
    # A smooth random field (white noise blurred over ~20 px) stretched to [0, 1] over the band the
    # brush's edge can reach, so that its edge wanders over the whole range around any object.
    noise = cv2.GaussianBlur(np.random.default_rng(seed).random((h, w), np.float32), (0, 0), 20 * scale)
    band = noise[distance <= hi]
    noise = np.clip((noise - band.min()) / max(float(band.max() - band.min()), 1e-6), 0, 1)
    return distance <= lo + (hi - lo) * noise


def _git_image(mirrors: Path, repo: str, commit: str, path: str) -> np.ndarray:
    git_dir = mirrors / repo.replace("/", "+") / "repo"
    if not git_dir.is_dir():
        raise DataAbsent(f"no snapshot of {repo} under {mirrors}")
    blob = subprocess.run(
        ["git", "--git-dir", str(git_dir), "show", f"{commit}:{path}"], capture_output=True, check=False
    )
    if blob.returncode:
        raise DataAbsent(f"{repo}@{commit[:10]} has no {path}")
    bgr = cv2.imdecode(np.frombuffer(blob.stdout, np.uint8), cv2.IMREAD_COLOR)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def load_case(entry: dict, entries: dict[str, dict], mirrors: Path) -> Case:
    """A manifest entry's images and masks; raises :class:`DataAbsent` when its data is not here."""
    data = entry["data"]
    if "shared" in data:
        folder = SHARED / data["shared"]
        if not folder.is_dir():
            raise DataAbsent(f"{folder} is absent")
        pair = load_pair(folder)
        target, references = pair.target, list(pair.sources)
    else:
        target = _git_image(mirrors, data["repo"], data["commit"], data["target"])
        references = [_git_image(mirrors, data["repo"], data["commit"], p) for p in data["references"]]
    # The same object as another case (with other references) is brushed the same way.
    owner = entry["object"] if isinstance(entry["object"], str) else entry["name"]
    silhouette = _polygons_mask(target.shape, entries[owner]["object"])
    if entry.get("brush") == "removal_cases":
        hole = brushed(target.shape, next(p for n, _, p in BRUSHED_CASES if n == entry["name"]))
    else:
        hole = wobbly_brush(silhouette, tuple(entry["margin_px"]), zlib.crc32(owner.encode()))
    source = f"{data['repo']} @ {data['commit'][:10]} ({data['licence']})"
    return Case(entry["name"], entry["what"], target, references, silhouette & hole, hole, source)


def background_estimate(target: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """A smooth guess of what the hole hides: the brush filled by OpenCV's Navier-Stokes
    inpainting on a blurred, quarter-size copy (only the ring's colours, no texture)."""
    h, w = hole.shape
    small = cv2.resize(
        cv2.GaussianBlur(target, (0, 0), 2.0), (max(w // 4, 1), max(h // 4, 1)), cv2.INTER_AREA
    )
    small_hole = cv2.resize(hole.astype(np.uint8), small.shape[1::-1], interpolation=cv2.INTER_NEAREST)
    small_hole = cv2.dilate(small_hole, np.ones((3, 3), np.uint8))
    filled = cv2.inpaint(small, small_hole, 3, cv2.INPAINT_NS)
    return np.where(hole[..., None], cv2.resize(filled, (w, h), interpolation=cv2.INTER_LINEAR), target)


def echo(output: np.ndarray, case: Case, background: np.ndarray) -> float:
    """How strongly the object's appearance is found anywhere in the brush's box of ``output``
    (see the module docstring): 1 - best masked SSD / SSD of the object against ``background``."""
    ys, xs = np.nonzero(case.object_mask)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    patch = case.target[y0:y1, x0:x1].astype(np.float32)
    weight = case.object_mask[y0:y1, x0:x1].astype(np.float32)
    reference = float((weight[..., None] * (patch - background[y0:y1, x0:x1]) ** 2).sum())
    hy, hx = np.nonzero(case.hole)
    area = output[hy.min() : hy.max() + 1, hx.min() : hx.max() + 1].astype(np.float32)
    best = float(cv2.matchTemplate(area, patch, cv2.TM_SQDIFF, mask=np.dstack([weight] * 3)).min())
    return max(0.0, 1.0 - best / max(reference, 1e-6))


def tint(output: np.ndarray, case: Case) -> float | None:
    """The object's own colours back anywhere in the hole, at any size: the number of hole pixels of
    ``output`` in the object's distinctive colour bins (4x more frequent in the object than in a
    ring around the brush), over the number the input's hole has; None when under 10 % of the
    object has distinctive colours (a grey car on grey asphalt)."""
    h, w = case.hole.shape
    width = max(2, round(30 * max(h, w) / _LONG_SIDE_PX))
    ring = (
        cv2.dilate(case.hole.astype(np.uint8), np.ones((2 * width + 1,) * 2, np.uint8)).astype(bool)
        & ~case.hole
    )
    bins_in = colour_bins(case.target)
    n_bins = 4 * 256
    in_object = np.bincount(bins_in[case.object_mask], minlength=n_bins) / case.object_mask.sum()
    in_ring = np.bincount(bins_in[ring], minlength=n_bins) / max(int(ring.sum()), 1)
    distinctive = in_object > 4 * in_ring
    before = int(distinctive[bins_in[case.hole]].sum())
    if before < 0.1 * case.object_mask.sum():
        return None
    return float(distinctive[colour_bins(output)[case.hole]].sum()) / before


def where_from(report: FillReport) -> str:
    """Where geofill's hole pixels came from: each reference, painted, refused (and why)."""
    parts = [f"ref {i} {100 * f:.0f}%" for i, f in enumerate(report.supplied_fraction, 1) if f >= 0.005]
    parts.append(f"painted {100 * report.painted_fraction:.0f}% ({report.inpaint_method.split()[0]})")
    refused = [f"{k} {100 * v:.0f}%" for k, v in report.refused_fraction.items() if v >= 0.005]
    dropped = [w.replace(" was not used", "") for w in report.dropped_words()]
    return ", ".join(parts) + "".join(
        f"; {t}" for t in (f"refused: {', '.join(refused)}" if refused else "", *dropped) if t
    )


def _label(tile: np.ndarray, text: str) -> np.ndarray:
    cv2.rectangle(tile, (0, 0), (tile.shape[1], 20), (0, 0, 0), -1)
    cv2.putText(tile, text, (4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return tile


def _fit(image: np.ndarray) -> np.ndarray:
    """``image`` scaled to fit a tile, centred on black."""
    h, w = image.shape[:2]
    s = min(TILE_W / w, TILE_H / h)
    small = cv2.resize(
        image, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_CUBIC
    )
    tile = np.zeros((TILE_H, TILE_W, 3), np.uint8)
    y, x = (TILE_H - small.shape[0]) // 2, (TILE_W - small.shape[1]) // 2
    tile[y : y + small.shape[0], x : x + small.shape[1]] = small
    return tile


def crop_box(hole: np.ndarray) -> tuple[int, int, int, int, float]:
    """(y0, y1, x0, x1, zoom): a box of the tile's aspect centred on the hole, half the tile's size
    (zoom 2) when the hole and a 15 % margin fit in it, else as large as that needs up to the
    tile's size (zoom 1: a large hole's middle, the full views show the rest)."""
    ys, xs = np.nonzero(hole)
    cy, cx = (ys.min() + ys.max()) / 2, (xs.min() + xs.max()) / 2
    need_w = max((xs.max() - xs.min()) * 1.3, (ys.max() - ys.min()) * 1.3 * TILE_W / TILE_H)
    bw = float(np.clip(need_w, TILE_W / 2, TILE_W))
    bw, bh = min(bw, hole.shape[1]), min(bw * TILE_H / TILE_W, hole.shape[0])
    x0 = int(np.clip(cx - bw / 2, 0, hole.shape[1] - bw))
    y0 = int(np.clip(cy - bh / 2, 0, hole.shape[0] - bh))
    return y0, y0 + int(bh), x0, x0 + int(bw), min(TILE_W / bw, TILE_H / bh)


def contact_sheet(case: Case, outputs: dict[str, np.ndarray | str]) -> np.ndarray:
    """Row 1: the input with the brush outline and each method's fill; row 2: the same around the
    hole at about 2x. A method that failed shows its reason on a black tile."""
    shown = case.target.copy()
    contours, _ = cv2.findContours(case.hole.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    thick = max(1, round(max(shown.shape[:2]) / 640))
    cv2.drawContours(shown, contours, -1, _BRUSH_RGB, thick)
    y0, y1, x0, x1, zoom = crop_box(case.hole)
    top, bottom = (
        [_label(_fit(shown), f"{case.name}: input + brush")],
        [_label(_fit(shown[y0:y1, x0:x1]), f"input {zoom:.1f}x")],
    )
    for method, image in outputs.items():
        if isinstance(image, str):
            blank = _label(np.zeros((TILE_H, TILE_W, 3), np.uint8), f"{method}: failed")
            cv2.putText(blank, image[:60], (4, 40), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (255, 255, 255), 1)
            top.append(blank)
            bottom.append(blank.copy())
            continue
        top.append(_label(_fit(image), method))
        bottom.append(_label(_fit(image[y0:y1, x0:x1]), f"{method} {zoom:.1f}x"))
    return np.concatenate([np.concatenate(top, axis=1), np.concatenate(bottom, axis=1)], axis=0)


def run_case(case: Case, out: Path, fills: Path | None = None) -> dict:
    """Fill ``case`` with each method, write its sheet (and with ``fills`` each fill, full size),
    and return its record: where geofill's hole pixels came from and each method's proxies (or
    why it failed)."""
    t0 = time.perf_counter()
    # A fill that raises is one case's result (shown on its sheet and in the table), not the end
    # of the panel: the other cases still say how the revision does.
    try:
        result = fill(case.target, case.hole, case.references, FillConfig())
        geofill: np.ndarray | str = result.image
        where = where_from(result.report)
    except Exception as exc:
        geofill = where = f"{type(exc).__name__}: {exc}"
    t_geofill = time.perf_counter() - t0
    outputs: dict[str, np.ndarray | str] = {
        "geofill": geofill,
        "telea": opencv_inpaint(case.target, case.hole),
    }
    try:
        outputs["homography"] = homography_fill(case.target, case.hole, case.references[0])
    except BaselineError as exc:
        outputs["homography"] = str(exc)
    background = background_estimate(case.target, case.hole)
    methods: dict[str, dict] = {}
    for method, image in outputs.items():
        if isinstance(image, str):
            methods[method] = {"failed": image}
            continue
        back = leak(image, background, [(case.target, case.object_mask)], case.hole).fraction
        methods[method] = {"back": back, "echo": echo(image, case, background), "tint": tint(image, case)}
    for method, image in outputs.items():
        if fills is not None and not isinstance(image, str):
            cv2.imwrite(str(fills / f"{case.name}_{method}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    sheet = contact_sheet(case, outputs)
    cv2.imwrite(
        str(out / f"{case.name}.jpg"), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 80]
    )
    h, w = case.hole.shape
    return {
        "what": case.what,
        "source": case.source,
        "references": len(case.references),
        "size": f"{w}x{h}",
        "hole_share": float(case.hole.mean()),
        "object_share_of_hole": float(case.object_mask.sum() / case.hole.sum()),
        "geofill_where": where,
        "geofill_s": t_geofill,
        "methods": methods,
    }


def _proxies(got: dict) -> str:
    if "failed" in got:
        return f"failed: {got['failed']}"
    shown = {k: "n/a" if got[k] is None else f"{got[k]:.2f}" for k in ("back", "echo", "tint")}
    return ", ".join(f"{k} {v}" for k, v in shown.items())


def describe(name: str, record: dict) -> list[str]:
    """A case's record as the lines the run prints."""
    hole, share = 100 * record["hole_share"], 100 * record["object_share_of_hole"]
    return [
        f"{name}: {record['what']}; {record['references']} ref(s); hole {hole:.1f}% of {record['size']}, "
        f"object {share:.0f}% of the hole; {record['source']}",
        f"  geofill ({record['geofill_s']:.0f} s): {record['geofill_where']}",
        *(f"  {m:10s} {_proxies(got)}" for m, got in record["methods"].items()),
    ]


def _revision() -> str:
    """The last commit that changed ``src`` (the geofill that filled), and whether ``src`` has
    uncommitted changes."""
    git = ["git", "-C", str(ROOT)]
    rev = subprocess.run([*git, "log", "-1", "--format=%h", "--", "src"], capture_output=True, text=True)
    dirty = subprocess.run([*git, "status", "--porcelain", "src"], capture_output=True, text=True)
    return rev.stdout.strip() + (" + uncommitted src changes" if dirty.stdout.strip() else "")


def score_table(scores_path: Path) -> str:
    """Markdown: per scored run, each case's by-eye scores (0-3) with what is seen and the
    proxies of that run's record, then each method's mean, share scoring >= 2 and count of 0."""
    runs = json.loads(scores_path.read_text())["runs"]
    text = []
    for run in runs:
        record = json.loads((ROOT / run["record"]).read_text())
        text += [
            f"#### {run['name']}: geofill at {record['revision']} (sheets: {run['sheets']})",
            "",
            "| case | refs | geofill | Telea | homography | geofill's hole |",
            "| --- | --- | --- | --- | --- | --- |",
        ]
        totals: dict[str, list[int]] = {m: [] for m in METHODS}
        for name, scored in run["cases"].items():
            got = record["cases"][name]
            cells = []
            for method in METHODS:
                score, seen = scored[method]
                totals[method].append(score)
                cells.append(f"**{score}** {seen} ({_proxies(got['methods'][method])})")
            text.append(f"| {name} | {got['references']} | {' | '.join(cells)} | {got['geofill_where']} |")
        text.append("")
        for method, s in totals.items():
            text.append(
                f"- {method}: mean {np.mean(s):.2f} over {len(s)} cases, {sum(v >= 2 for v in s)} score >= 2 "
                f"({100 * np.mean([v >= 2 for v in s]):.0f} %), {sum(v == 0 for v in s)} score 0"
            )
        text.append("")
    return "\n".join(text)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "panel", help="folder for <case>.jpg")
    ap.add_argument("--only", default="", help="comma-separated case names (default: all)")
    ap.add_argument("--mirrors", type=Path, default=MIRRORS, help="folder of git snapshots (owner+name/repo)")
    ap.add_argument("--manifest", type=Path, default=MANIFEST, help="the panel's cases (JSON)")
    ap.add_argument("--fills", type=Path, help="also write every fill here, full size (<case>_<method>.png)")
    ap.add_argument(
        "--record", type=Path, help="also write the run's proxies and sources here (JSON; --only updates it)"
    )
    ap.add_argument(
        "--table",
        type=Path,
        metavar="SCORES",
        help="only print the by-eye scores of SCORES with their runs' proxies",
    )
    ap.add_argument("--table-md", type=Path, help="with --table, also write it to this markdown file")
    args = ap.parse_args(argv)
    if args.table:
        table = score_table(args.table)
        print(table)
        if args.table_md:
            args.table_md.write_text(table + "\n")
        return 0
    entries = {e["name"]: e for e in json.loads(args.manifest.read_text())["cases"]}
    wanted = [n for n in args.only.split(",") if n] or list(entries)
    unknown = sorted(set(wanted) - set(entries))
    if unknown:
        ap.error(f"unknown case(s) {', '.join(unknown)}; the manifest has {', '.join(entries)}")
    for folder in (args.out, args.fills):
        if folder is not None:
            folder.mkdir(parents=True, exist_ok=True)
    records = {}
    for name in wanted:
        try:
            case = load_case(entries[name], entries, args.mirrors)
        except DataAbsent as exc:
            print(f"{name}: skipped, {exc}")
            continue
        records[name] = run_case(case, args.out, args.fills)
        print("\n".join(describe(name, records[name])), flush=True)
    if args.record:
        revision = _revision()
        if args.record.is_file():  # a partial run (--only) updates the cases of a run of the same src
            earlier = json.loads(args.record.read_text())
            if earlier["revision"] == revision:
                records = {**earlier["cases"], **records}
        args.record.write_text(json.dumps({"revision": revision, "cases": records}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
