"""The evaluation protocol: cut a brush-stroke hole into each pair's target, run every method on the
same masked target, score against the original target, and write the tables and pictures.

A method is any ``(target, hole, sources, exif) -> MethodOutput`` callable registered under a name
(``sources``: the reference images offered, primary first; single-reference methods use the first);
the target it receives has its hole pixels zeroed, so no method can see the ground truth, and
``exif`` holds the images' EXIF lens data (what the CLI would read from the same files). Its output
is composited (its pixels inside the hole, the target's outside) before scoring, as in the papers.
A method that raises is recorded with its error and the run goes on.

Files written to ``out_dir`` by :func:`run_eval`: ``results.csv`` (one row per pair x method),
``timings.csv`` (per-stage seconds), ``summary.md``, ``contact_<pair>.jpg`` and the masks used
(``masks/<pair>.png``); by :func:`sweep`: ``sweep_results.csv``, ``sweep.csv``, ``sweep.md`` and
``sweep.png``."""

from __future__ import annotations

import csv
import importlib.util
import json
import math
import statistics
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..composite.inpaint import inpaint_single
from ..config import PRESETS, FillConfig, InpaintConfig
from ..errors import ConfigError, InputError, MissingFileError
from ..io import ExifCamera, read_image
from .baselines import homography_fill_detailed, opencv_inpaint
from .masks import (
    DEFAULT_AREA_RANGE,
    DEFAULT_STROKE_WIDTH_720P,
    PAPER_STROKE_WIDTHS_720P,
    brush_strokes,
    mask_seed,
    scaled_stroke_width,
)
from .metrics import LpipsScorer, LpipsUnavailable, load_lpips, psnr, ssim


@dataclass
class MethodOutput:
    """What a method returns: the filled target (HxWx3 uint8), per-stage seconds, and optional
    scalar diagnostics (written as JSON in the results' ``info`` column)."""

    image: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class PairExif:
    """EXIF lens data of a pair's images, one per reference offered (None: no file, e.g. synthetic)."""

    target: ExifCamera | None = None
    sources: tuple[ExifCamera | None, ...] = (None,)

    @property
    def source(self) -> ExifCamera | None:
        """The primary reference's."""
        return self.sources[0]


#: ``method(masked_target, hole, sources, exif) -> MethodOutput``; uint8 RGB images, bool hole.
Method = Callable[[np.ndarray, np.ndarray, Sequence[np.ndarray], PairExif], MethodOutput]

#: Methods selectable by name (``--methods``).
METHODS: dict[str, Method] = {}
#: Methods that use several references at once (the others are offered one at a time).
MULTI_REFERENCE: set[str] = set()
#: ``--references`` choices: which references a multi-reference set's methods are run with.
REFERENCE_MODES = ("primary", "each", "all")
#: Names of the project's baselines; the summary counts every method's wins against each.
BASELINES = ("opencv_inpaint", "homography")


def register_method(
    name: str, method: Method, *, replace: bool = False, multi_reference: bool = False
) -> None:
    """Make ``method`` selectable as ``name``; re-registering a name needs ``replace=True``.
    ``multi_reference``: it fills from all the references it is given, not just the first."""
    if not name or "," in name:
        raise ValueError(f"invalid method name {name!r}")
    if name in METHODS and not replace:
        raise ValueError(f"method '{name}' is already registered")
    METHODS[name] = method
    if multi_reference:
        MULTI_REFERENCE.add(name)
    else:
        MULTI_REFERENCE.discard(name)


def _opencv_method(
    target: np.ndarray, hole: np.ndarray, sources: Sequence[np.ndarray], exif: PairExif
) -> MethodOutput:
    t0 = time.perf_counter()
    image = opencv_inpaint(target, hole)
    return MethodOutput(image, {"total": time.perf_counter() - t0})


def _homography_method(
    target: np.ndarray, hole: np.ndarray, sources: Sequence[np.ndarray], exif: PairExif
) -> MethodOutput:
    t0 = time.perf_counter()
    fill = homography_fill_detailed(target, hole, sources[0])
    info = {
        "n_matches": fill.n_matches,
        "n_inliers": fill.n_inliers,
        "hole_coverage": round(fill.hole_coverage, 4),
    }
    return MethodOutput(fill.image, {"total": time.perf_counter() - t0}, info)


def _patchmatch_method(
    target: np.ndarray, hole: np.ndarray, sources: Sequence[np.ndarray], exif: PairExif
) -> MethodOutput:
    t0 = time.perf_counter()
    image = inpaint_single(target, hole, InpaintConfig(method="patchmatch"))
    return MethodOutput(image, {"total": time.perf_counter() - t0})


register_method("opencv_inpaint", _opencv_method)
register_method("patchmatch_inpaint", _patchmatch_method)
register_method("homography", _homography_method)

#: What ``--methods`` defaults to: the baselines and geofill as configured (presets by name,
#: ``geofill_<preset>``: see :data:`geofill.config.PRESETS`).
DEFAULT_METHODS = (*BASELINES, "geofill")


def geofill_method(cfg: FillConfig) -> Method:
    """The full pipeline with ``cfg`` as an evaluation method (all references it is given)."""
    from ..pipeline import fill

    def run(
        target: np.ndarray, hole: np.ndarray, sources: Sequence[np.ndarray], exif: PairExif
    ) -> MethodOutput:
        res = fill(target, hole, list(sources), cfg, target_exif=exif.target, source_exifs=list(exif.sources))
        r = res.report
        ref = r.references[0]
        opt = ref.get("optimize", {})
        info = {
            "status": r.status,
            "fallbacks": r.fallbacks,
            "pose_status": ref.get("pose", {}).get("status", ""),
            "n_pose_inliers": ref.get("pose", {}).get("n_inliers", 0),
            "hole_coverage": round(1.0 - r.painted_fraction, 4),
            "supplied_fraction": [round(f, 4) for f in r.supplied_fraction],
            "focal_px": round(float(ref.get("intrinsics_target", {}).get("fx_px", math.nan)), 1),
            "focal_origin": ref.get("intrinsics_target", {}).get("origin"),
            "optimize": ": ".join(filter(None, (opt.get(k, "") for k in ("status", "reason")))),
        }
        return MethodOutput(res.image, dict(r.timings_s), info)

    return run


def register_geofill_methods(base: FillConfig | None = None) -> None:
    """(Re-)register every geofill variant on top of ``base`` (default config when None)."""
    base = base or FillConfig()
    register_method("geofill", geofill_method(base), replace=True, multi_reference=True)
    for name in PRESETS:
        register_method(
            f"geofill_{name}", geofill_method(base.preset(name)), replace=True, multi_reference=True
        )


register_geofill_methods()


def resolve_methods(names: Sequence[str] | None) -> dict[str, Method]:
    """Registered methods by name, in the given order (None: :data:`DEFAULT_METHODS`)."""
    if names is None:
        names = DEFAULT_METHODS
    unknown = [n for n in names if n not in METHODS]
    if unknown:
        raise ConfigError(f"unknown method(s) {unknown}; registered: {sorted(METHODS)}")
    return {n: METHODS[n] for n in names}


# ---------------------------------------------------------------------------------------------
# Pairs


@dataclass
class Pair:
    """One evaluation pair or multi-reference set: target (ground truth) and its references
    (primary first), HxWx3 uint8 RGB."""

    id: str
    target: np.ndarray
    sources: list[np.ndarray]
    meta: dict[str, Any]
    path: Path | None
    exif: PairExif = PairExif()

    @property
    def source(self) -> np.ndarray:
        """The primary reference."""
        return self.sources[0]


_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
SYNTHETIC_PREFIX = "synthetic:"
_MIN_SIDE_PX = FillConfig().min_side_px


def _find_image(folder: Path, stem: str) -> Path | None:
    for suffix in _IMAGE_SUFFIXES:
        if (folder / f"{stem}{suffix}").is_file():
            return folder / f"{stem}{suffix}"
    return None


#: Reference file stems of a set, in order: ``source`` (the primary), then ``source2`` ...
_SOURCE_STEMS = ("source", *(f"source{k}" for k in range(2, 10)))


def load_pair(folder: str | Path) -> Pair:
    """A pair folder: ``target.{png,jpg}``, ``source.{png,jpg}``, optional ``meta.json``; a
    multi-reference set adds ``source2``, ``source3``, ... (read in that order)."""
    folder = Path(folder)
    images = {}
    for stem in ("target", *_SOURCE_STEMS):
        path = _find_image(folder, stem)
        if path is None:
            if stem in ("target", "source"):
                raise MissingFileError(f"pair folder {folder} has no {stem}.png/.jpg")
            break
        images[stem] = read_image(path, min_side=_MIN_SIDE_PX)
    meta_path = folder / "meta.json"
    try:
        meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    except json.JSONDecodeError as exc:
        raise InputError(f"{meta_path} is not valid JSON: {exc}") from exc
    t, refs = images.pop("target"), list(images.values())
    exif = PairExif(t.exif, tuple(r.exif for r in refs))
    return Pair(folder.name, t.pixels, [r.pixels for r in refs], meta, folder, exif)


def synthetic_pairs(n: int) -> list[Pair]:
    """``n`` synthetic pairs from :func:`geofill.synthetic.make_pair` (seeds 0..n-1)."""
    from ..synthetic import make_pair

    pairs = []
    for i in range(n):
        sp = make_pair(seed=i)
        pairs.append(
            Pair(f"synthetic_{i:03d}", sp.target, [sp.source], {"kind": "synthetic", "seed": i}, None)
        )
    return pairs


def load_pairs(dirs: Sequence[str | Path]) -> list[Pair]:
    """Pairs from each entry of ``dirs``: a pair folder, a folder of pair folders, or
    ``synthetic:N``. Sorted by id; ids must be unique."""
    pairs: list[Pair] = []
    for entry in dirs:
        text = str(entry)
        if text.startswith(SYNTHETIC_PREFIX):
            count = text[len(SYNTHETIC_PREFIX) :]
            if not count.isdigit() or int(count) < 1:
                raise InputError(f"'{text}': expected {SYNTHETIC_PREFIX}N with N >= 1")
            pairs.extend(synthetic_pairs(int(count)))
            continue
        folder = Path(entry)
        if not folder.is_dir():
            raise MissingFileError(f"pairs folder not found: {folder}")
        if _find_image(folder, "target") is not None:
            pairs.append(load_pair(folder))
            continue
        subdirs = sorted(d for d in folder.iterdir() if d.is_dir() and _find_image(d, "target") is not None)
        if not subdirs:
            raise InputError(f"{folder} holds no pair folders (with target.png/.jpg)")
        pairs.extend(load_pair(d) for d in subdirs)
    ids = [p.id for p in pairs]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise InputError(f"duplicate pair ids {duplicates}")
    return sorted(pairs, key=lambda p: p.id)


def group_value(meta: Mapping[str, Any], key: str) -> str:
    """The ``--by`` group of a pair: ``meta[key]`` (dotted keys reach nested fields). Strings are
    grouped by their first word, since meta.json's ``kind`` is 'category (details)'."""
    value: Any = meta
    for part in key.split("."):
        value = value.get(part) if isinstance(value, Mapping) else None
    if value is None:
        return "n/a"
    if isinstance(value, str):
        return value.split()[0] if value.strip() else "n/a"
    return str(value)


# ---------------------------------------------------------------------------------------------
# Scoring


@dataclass
class EvalRow:
    """One method on one pair with one hole. Scores are None when the method failed."""

    pair: str
    method: str
    stroke_width_720p: float
    stroke_width_px: float
    hole_ratio: float
    psnr: float | None = None
    ssim: float | None = None
    psnr_hole: float | None = None
    ssim_hole: float | None = None
    lpips: float | None = None
    lpips_status: str = ""
    time_s: float | None = None
    error: str = ""
    group: str = ""
    info: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.error


@dataclass
class _Lpips:
    scorer: LpipsScorer | None
    status: str  # per row: "ok" or "unavailable: <reason>"

    @classmethod
    def load(cls, model_path: str | Path | None) -> _Lpips:
        try:
            return cls(load_lpips(model_path), "ok")
        except LpipsUnavailable as exc:
            return cls(None, f"unavailable: {exc}")

    @property
    def description(self) -> str:
        """The summary's LPIPS line."""
        if self.scorer is None:
            return self.status
        return f"available ({self.scorer.backend} model {self.scorer.path})"


def _error_text(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}".replace("\n", " ")


def _run_method(method: Method, pair: Pair, hole: np.ndarray, refs: Sequence[int]) -> MethodOutput:
    """``method`` on ``pair`` offered the references ``refs`` (0-based indices)."""
    target = pair.target
    masked = target.copy()
    masked[hole] = 0
    exif = PairExif(pair.exif.target, tuple(pair.exif.sources[k] for k in refs))
    out = method(masked, hole.copy(), [pair.sources[k].copy() for k in refs], exif)
    if not isinstance(out, MethodOutput):
        raise TypeError(f"method returned {type(out).__name__}, not MethodOutput")
    if out.image.dtype != np.uint8 or out.image.shape != target.shape:
        raise ValueError(
            f"method returned {out.image.dtype} {out.image.shape}, expected uint8 {target.shape}"
        )
    return out


@dataclass(frozen=True)
class _Hole:
    """A hole cut into one pair, with how it was made."""

    mask: np.ndarray  # HxW bool
    width_720p: float
    width_px: float
    group: str = ""


def _evaluate_pair(
    pair: Pair,
    hole: _Hole,
    methods: Mapping[str, Method],
    lpips: _Lpips,
    progress: Callable[[EvalRow], None],
    modes: Sequence[str] = REFERENCE_MODES,
) -> list[tuple[EvalRow, np.ndarray | None]]:
    """Run and score every method on ``pair`` with ``hole`` (on a multi-reference set, with the
    references ``modes`` asks for: see :func:`reference_runs`); each row with the composited
    output (None when the method failed)."""
    results = []
    ratio = float(hole.mask.mean())
    runs = [
        (f"{name}{label}", method, refs)
        for name, method in methods.items()
        for label, refs in reference_runs(len(pair.sources), name in MULTI_REFERENCE, modes)
    ]
    for name, method, refs in runs:
        row = EvalRow(pair.id, name, hole.width_720p, hole.width_px, ratio, group=hole.group)
        image = None
        t0 = time.perf_counter()
        try:
            out = _run_method(method, pair, hole.mask, refs)
            row.time_s = time.perf_counter() - t0
            image = np.where(hole.mask[..., None], out.image, pair.target)
            row.timings, row.info = dict(out.timings), dict(out.info)
            row.psnr, row.ssim = psnr(image, pair.target), ssim(image, pair.target)
            row.psnr_hole = psnr(image, pair.target, hole.mask)
            row.ssim_hole = ssim(image, pair.target, hole.mask)
            row.lpips_status = lpips.status
            if lpips.scorer is not None:
                try:
                    row.lpips = lpips.scorer(image, pair.target)
                except Exception as exc:  # a broken LPIPS model must not lose the other scores
                    row.lpips_status = f"failed: {_error_text(exc)}"
        except Exception as exc:  # the protocol records a failing method and goes on
            row.time_s = row.time_s if row.time_s is not None else time.perf_counter() - t0
            row.error = _error_text(exc)
            image = None
        progress(row)
        results.append((row, image))
    return results


def reference_runs(n: int, multi_reference: bool, modes: Sequence[str]) -> list[tuple[str, list[int]]]:
    """(method-name suffix, reference indices) of each run of one method on a set of ``n``
    references: the primary alone (no suffix) always; with ``each`` every other reference alone
    (``[ref k]``); with ``all`` (multi-reference methods only) all of them (``[all]``)."""
    runs: list[tuple[str, list[int]]] = [("", [0])]
    if n > 1 and "each" in modes:
        runs += [(f"[ref {k + 1}]", [k]) for k in range(1, n)]
    if n > 1 and "all" in modes and multi_reference:
        runs.append(("[all]", list(range(n))))
    return runs


class _Progress:
    """One line per pair x method on stderr."""

    def __init__(self, total: int):
        self.total, self.done = total, 0

    def __call__(self, row: EvalRow) -> None:
        self.done += 1
        head = f"[{self.done}/{self.total}] {row.pair} {row.method} (hole {row.hole_ratio:.1%})"
        if row.ok:
            tail = f"psnr_hole={row.psnr_hole:.2f} ssim_hole={row.ssim_hole:.3f} {row.time_s:.2f}s"
        else:
            tail = f"FAILED {row.error}"
        print(f"{head}: {tail}", file=sys.stderr, flush=True)


def _width_px(pair: Pair, width_720p: float) -> float:
    h, w = pair.target.shape[:2]
    return scaled_stroke_width(width_720p, h, w)


def pair_mask(
    pair: Pair,
    seed: int = 0,
    width_720p: float = DEFAULT_STROKE_WIDTH_720P,
    area_range: tuple[float, float] = DEFAULT_AREA_RANGE,
) -> np.ndarray:
    """The evaluation hole of ``pair`` (bool): the same for the same pair id, seed and width."""
    h, w = pair.target.shape[:2]
    width_px = _width_px(pair, width_720p)
    return brush_strokes(
        h, w, seed=mask_seed(pair.id, seed), mean_width_px=width_px, area_range=area_range
    ).render(width_px)


# ---------------------------------------------------------------------------------------------
# Main entry points


def run_eval(
    pairs: Sequence[Pair],
    methods: Mapping[str, Method] | Sequence[str] | None,
    out_dir: str | Path,
    seed: int = 0,
    stroke_width_720p: float | None = None,
    by: str | None = None,
    *,
    area_range: tuple[float, float] = DEFAULT_AREA_RANGE,
    lpips_model: str | Path | None = None,
    contact_sheets: bool = True,
    references: Sequence[str] = REFERENCE_MODES,
) -> list[EvalRow]:
    """Evaluate ``methods`` (registry names, a name -> method mapping, or None for all registered)
    on ``pairs`` and write the results to ``out_dir`` (see the module docstring).

    Masks: seeded by (pair id, ``seed``); mean brush width ``stroke_width_720p`` px at a 720-px
    short side (default 150), scaled to each image; hole area in ``area_range``. ``by`` names a
    meta.json field to group the summary by. On multi-reference sets each method also runs with
    each reference alone and, if it can, with all of them (``references``; see
    :func:`reference_runs`). Returns the rows of results.csv."""
    methods = methods if isinstance(methods, Mapping) else resolve_methods(methods)
    width_720p = DEFAULT_STROKE_WIDTH_720P if stroke_width_720p is None else float(stroke_width_720p)
    out = Path(out_dir)
    (out / "masks").mkdir(parents=True, exist_ok=True)
    lpips = _Lpips.load(lpips_model)
    progress = _Progress(
        sum(
            len(reference_runs(len(p.sources), m in MULTI_REFERENCE, references))
            for p in pairs
            for m in methods
        )
    )
    rows: list[EvalRow] = []
    for pair in pairs:
        width_px = _width_px(pair, width_720p)
        mask = pair_mask(pair, seed, width_720p, area_range)
        hole = _Hole(mask, width_720p, width_px, group_value(pair.meta, by) if by else "")
        cv2.imwrite(str(out / "masks" / f"{pair.id}.png"), hole.mask.astype(np.uint8) * 255)
        results = _evaluate_pair(pair, hole, methods, lpips, progress, references)
        rows.extend(r for r, _ in results)
        if contact_sheets:
            write_contact_sheet(out / f"contact_{pair.id}.jpg", pair, hole.mask, results)
    write_results_csv(out / "results.csv", rows, by)
    write_timings_csv(out / "timings.csv", rows)
    settings = {
        "pairs": len(pairs),
        "seed": seed,
        "stroke_width_720p": width_720p,
        "area_range": area_range,
        "lpips": lpips.description,
    }
    names = list(dict.fromkeys(r.method for r in rows))
    (out / "summary.md").write_text(summary_markdown(rows, names, settings, by))
    return rows


def sweep(
    pairs: Sequence[Pair],
    methods: Mapping[str, Method] | Sequence[str] | None,
    out_dir: str | Path,
    seed: int = 0,
    widths_720p: Sequence[float] = PAPER_STROKE_WIDTHS_720P,
    *,
    area_range: tuple[float, float] = DEFAULT_AREA_RANGE,
    lpips_model: str | Path | None = None,
) -> list[EvalRow]:
    """The paper's hole-size study: per pair, one hole shape (drawn at the default 150 px width
    within ``area_range``) rendered at each mean brush width of ``widths_720p`` (px at a 720-px
    short side, scaled), every method run on each. Writes sweep_results.csv, sweep.csv, sweep.md
    and sweep.png; returns the rows."""
    methods = methods if isinstance(methods, Mapping) else resolve_methods(methods)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    lpips = _Lpips.load(lpips_model)
    progress = _Progress(len(pairs) * len(methods) * len(widths_720p))
    rows: list[EvalRow] = []
    for pair in pairs:
        h, w = pair.target.shape[:2]
        shape = brush_strokes(
            h,
            w,
            seed=mask_seed(pair.id, seed),
            mean_width_px=_width_px(pair, DEFAULT_STROKE_WIDTH_720P),
            area_range=area_range,
        )
        for width_720p in widths_720p:
            width_px = _width_px(pair, width_720p)
            hole = _Hole(shape.render(width_px), float(width_720p), width_px)
            rows.extend(r for r, _ in _evaluate_pair(pair, hole, methods, lpips, progress, ("primary",)))
    write_results_csv(out / "sweep_results.csv", rows, None)
    table = sweep_table(rows, list(methods), widths_720p)
    _write_csv(out / "sweep.csv", list(table[0]) if table else [], table)
    (out / "sweep.md").write_text(_sweep_markdown(table, lpips.description))
    if importlib.util.find_spec("matplotlib") is None:
        print(
            "sweep.png not drawn: matplotlib is not installed (pip install 'geofill[eval]')", file=sys.stderr
        )
    else:
        plot_sweep(out / "sweep.png", rows, list(methods), widths_720p)
    return rows


# ---------------------------------------------------------------------------------------------
# Tables


_CSV_FIELDS = (
    "pair",
    "method",
    "stroke_width_720p",
    "stroke_width_px",
    "hole_ratio",
    "psnr",
    "ssim",
    "psnr_hole",
    "ssim_hole",
    "lpips",
    "lpips_status",
    "time_s",
    "error",
)


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, float):
        return "inf" if math.isinf(value) else f"{value:.6g}"
    return value


def _write_csv(path: Path, fields: Sequence[str], records: Sequence[Mapping[str, Any]]) -> None:
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(fields))
        writer.writeheader()
        writer.writerows({k: _cell(v) for k, v in r.items()} for r in records)


def write_results_csv(path: Path, rows: Sequence[EvalRow], by: str | None) -> None:
    """One line per pair x method; a ``by`` column with the group when grouping."""
    fields = [*_CSV_FIELDS, *([by] if by else []), "info"]
    records = []
    for row in rows:
        record = {name: getattr(row, name) for name in _CSV_FIELDS}
        if by:
            record[by] = row.group
        record["info"] = json.dumps(row.info, sort_keys=True) if row.info else ""
        records.append(record)
    _write_csv(path, fields, records)


def write_timings_csv(path: Path, rows: Sequence[EvalRow]) -> None:
    """One line per pair x method x stage (seconds as reported by the method)."""
    fields = ("pair", "method", "stroke_width_720p", "stage", "seconds")
    records = [
        dict(zip(fields, (r.pair, r.method, r.stroke_width_720p, stage, seconds), strict=True))
        for r in rows
        for stage, seconds in r.timings.items()
    ]
    _write_csv(path, fields, records)


def _values(rows: Sequence[EvalRow], metric: str) -> list[float]:
    return [getattr(r, metric) for r in rows if r.ok and getattr(r, metric) is not None]


def _mean(values: Sequence[float]) -> float | None:
    return float(np.mean(values)) if values else None


def _fmt(value: float | None, digits: int) -> str:
    if value is None:
        return "-"
    return "inf" if math.isinf(value) else f"{value:.{digits}f}"


_METRICS = (
    ("psnr", "PSNR", 2),
    ("ssim", "SSIM", 4),
    ("psnr_hole", "PSNR hole", 2),
    ("ssim_hole", "SSIM hole", 4),
)


def _md_table(header: Sequence[str], body: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join("---" for _ in header) + " |"]
    lines += ["| " + " | ".join(cells) + " |" for cells in body]
    return lines


def wins(rows: Sequence[EvalRow], method: str, baseline: str, metric: str = "psnr_hole") -> tuple[int, int]:
    """(pairs where ``method`` scores higher than ``baseline`` on ``metric``, pairs both ran on)."""
    by_pair: dict[tuple[str, float], dict[str, float]] = {}
    for r in rows:
        if r.ok and r.method in (method, baseline):
            by_pair.setdefault((r.pair, r.stroke_width_720p), {})[r.method] = getattr(r, metric)
    both = [v for v in by_pair.values() if len(v) == 2]
    return sum(v[method] > v[baseline] for v in both), len(both)


def summary_markdown(
    rows: Sequence[EvalRow], methods: Sequence[str], settings: Mapping[str, Any], by: str | None
) -> str:
    """The summary.md text: settings, mean/median scores, wins vs. baselines, grouping, failures."""
    hole_ratios = {r.pair: r.hole_ratio for r in rows}
    lo, hi = settings["area_range"]
    lines = [
        "# geofill evaluation",
        "",
        f"- pairs: {settings['pairs']}, mask seed {settings['seed']}, mean brush width "
        f"{settings['stroke_width_720p']:g} px at a 720-px short side (scaled per image), "
        f"hole area window {lo:.0%}-{hi:.0%}, mean hole ratio "
        f"{_fmt(_mean(list(hole_ratios.values())), 3)}",
        f"- LPIPS: {settings['lpips']}",
        "- whole-image scores count every pixel (papers' convention); hole scores count hole pixels only",
        "",
        "## Scores (mean / median over pairs the method ran on)",
        "",
    ]
    header = ["method", "ok", "failed", *(label for _, label, _ in _METRICS), "LPIPS", "median time (s)"]
    body = []
    for m in methods:
        mine = [r for r in rows if r.method == m]
        cells = [m, str(sum(r.ok for r in mine)), str(sum(not r.ok for r in mine))]
        for metric, _, digits in (*_METRICS, ("lpips", "LPIPS", 4)):
            values = _values(mine, metric)
            median = float(np.median(values)) if values else None
            cells.append(f"{_fmt(_mean(values), digits)} / {_fmt(median, digits)}")
        times = _values(mine, "time_s")
        cells.append(_fmt(statistics.median(times) if times else None, 2))
        body.append(cells)
    lines += _md_table(header, body)

    baselines = [b for b in BASELINES if b in methods]
    if baselines:
        lines += [
            "",
            "## Wins on hole PSNR (pairs where the row method scores higher / pairs both ran on)",
            "",
        ]
        body = []
        for m in methods:
            body.append([m, *("-" if m == b else "{}/{}".format(*wins(rows, m, b)) for b in baselines)])
        lines += _md_table(["method", *(f"vs {b}" for b in baselines)], body)

    stage_lines = _stage_table(rows, methods)
    if stage_lines:
        lines += ["", "## Median stage times (s)", "", *stage_lines]

    if by:
        lines += ["", f"## By {by}", ""]
        body = []
        for g in sorted({r.group for r in rows}):
            for m in methods:
                mine = [r for r in rows if r.group == g and r.method == m]
                body.append(
                    [g, m, str(sum(r.ok for r in mine))]
                    + [_fmt(_mean(_values(mine, metric)), d) for metric, _, d in _METRICS]
                )
        lines += _md_table([by, "method", "n ok", *(f"{label} (mean)" for _, label, _ in _METRICS)], body)

    lines += multi_reference_markdown(rows, methods)
    failures = [r for r in rows if not r.ok]
    lines += ["", "## Failures", ""]
    lines += [f"- {r.pair} / {r.method}: {r.error}" for r in failures] or ["none"]
    return "\n".join(lines) + "\n"


def multi_reference_markdown(rows: Sequence[EvalRow], methods: Sequence[str]) -> list[str]:
    """Per multi-reference set and method: hole PSNR with the primary reference alone, the best
    single reference, all references, and the hole fraction the references supplied; wins of
    all references over the best single one. Empty when no method ran with ``[all]``."""
    lines: list[str] = []
    for m in [m for m in methods if f"{m}[all]" in methods]:
        sets = sorted({r.pair for r in rows if r.method == f"{m}[all]"})
        body, gains, wins_best, covered = [], [], 0, []
        for pid in sets:
            mine = {r.method: r for r in rows if r.pair == pid and r.ok and r.method.startswith(m)}
            singles = {k: r for k, r in mine.items() if k == m or k.startswith(f"{m}[ref ")}
            primary, together = mine.get(m), mine.get(f"{m}[all]")
            if primary is None or together is None or not singles:
                continue
            best_name, best = max(singles.items(), key=lambda kv: kv[1].psnr_hole)
            gains.append((primary.psnr_hole, best.psnr_hole, together.psnr_hole))
            wins_best += together.psnr_hole >= best.psnr_hole
            cov = (primary.info.get("hole_coverage"), together.info.get("hole_coverage"))
            covered.append(cov)
            body.append(
                [
                    pid,
                    _fmt(primary.psnr_hole, 2),
                    f"{_fmt(best.psnr_hole, 2)} ({best_name.removeprefix(m) or 'primary'})",
                    _fmt(together.psnr_hole, 2),
                    f"{_fmt(cov[0], 3)} -> {_fmt(cov[1], 3)}",
                ]
            )
        if not body:
            continue
        mean = np.mean(np.array(gains), axis=0)
        body.append(["**mean**", *(f"**{v:.2f}**" for v in mean), ""])
        lines += ["", f"## Several references: {m} (hole PSNR, dB)", ""]
        lines += _md_table(
            ["set", "primary alone", "best single reference", "all references", "supplied"], body
        )
        lines += [
            "",
            f"- all references vs. primary alone: {mean[2] - mean[0]:+.2f} dB mean; all references >= "
            f"the best single reference on {wins_best}/{len(body) - 1} sets",
            "- supplied: fraction of the hole filled from references (the rest painted), primary -> all",
        ]
    return lines


def _stage_table(rows: Sequence[EvalRow], methods: Sequence[str]) -> list[str]:
    body = []
    for m in methods:
        stages: dict[str, list[float]] = {}
        for r in rows:
            if r.method == m and r.ok:
                for stage, seconds in r.timings.items():
                    stages.setdefault(stage, []).append(seconds)
        body += [[m, stage, f"{statistics.median(v):.3f}"] for stage, v in stages.items()]
    return _md_table(["method", "stage", "median (s)"], body) if body else []


def sweep_table(
    rows: Sequence[EvalRow], methods: Sequence[str], widths_720p: Sequence[float]
) -> list[dict[str, Any]]:
    """Per stroke width x method: counts, mean hole ratio and mean scores."""
    table = []
    for width in widths_720p:
        for m in methods:
            mine = [r for r in rows if r.method == m and r.stroke_width_720p == float(width)]
            record: dict[str, Any] = {
                "stroke_width_720p": float(width),
                "method": m,
                "n_ok": sum(r.ok for r in mine),
                "n_failed": sum(not r.ok for r in mine),
                "mean_hole_ratio": _mean([r.hole_ratio for r in mine]),
            }
            for metric in ("psnr", "ssim", "psnr_hole", "ssim_hole", "lpips"):
                record[f"mean_{metric}"] = _mean(_values(mine, metric))
            table.append(record)
    return table


def _sweep_markdown(table: Sequence[Mapping[str, Any]], lpips_status: str) -> str:
    lines = ["# Hole-size sweep", "", f"- LPIPS: {lpips_status}", ""]
    header = ["stroke width (px @720p)", "method", "ok", "failed", "hole ratio", "PSNR", "SSIM", "PSNR hole"]
    header += ["SSIM hole", "LPIPS"]
    body = [
        [
            f"{t['stroke_width_720p']:g}",
            t["method"],
            str(t["n_ok"]),
            str(t["n_failed"]),
            _fmt(t["mean_hole_ratio"], 3),
            _fmt(t["mean_psnr"], 2),
            _fmt(t["mean_ssim"], 4),
            _fmt(t["mean_psnr_hole"], 2),
            _fmt(t["mean_ssim_hole"], 4),
            _fmt(t["mean_lpips"], 4),
        ]
        for t in table
    ]
    return "\n".join(lines + _md_table(header, body)) + "\n"


def plot_sweep(
    path: Path, rows: Sequence[EvalRow], methods: Sequence[str], widths_720p: Sequence[float]
) -> None:
    """Mean whole-image and hole PSNR per method vs. stroke width, and (as in the paper's figure)
    each method's mean per-pair PSNR gain over the homography baseline when it was run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    reference = "homography" if "homography" in methods else None
    panels = [("psnr", "PSNR (dB), whole image"), ("psnr_hole", "PSNR (dB), hole only")]
    fig, axes = plt.subplots(1, len(panels) + (reference is not None), figsize=(5 * (len(panels) + 1), 4))
    widths = [float(w) for w in widths_720p]
    for ax, (metric, title) in zip(axes, panels, strict=False):
        for m in methods:
            means = [
                _mean(_values([r for r in rows if r.method == m and r.stroke_width_720p == w], metric))
                for w in widths
            ]
            ax.plot(widths, [np.nan if v is None else v for v in means], marker="o", label=m)
        ax.set_title(title)
    if reference is not None:
        ax = axes[-1]
        for m in methods:
            if m == reference:
                continue
            gains = []
            for w in widths:
                at_w = [r for r in rows if r.stroke_width_720p == w]
                ref = {r.pair: r.psnr for r in at_w if r.method == reference and r.ok}
                diffs = [r.psnr - ref[r.pair] for r in at_w if r.method == m and r.ok and r.pair in ref]
                gains.append(np.mean(diffs) if diffs else np.nan)
            ax.plot(widths, gains, marker="o", label=m)
        ax.axhline(0.0, color="grey", lw=0.8)
        ax.set_title(f"PSNR gain over {reference} (dB)")
    for ax in axes:
        ax.set_xlabel("mean stroke width (px at 720p)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# ---------------------------------------------------------------------------------------------
# Contact sheets

#: Long side (px) of each tile of a contact sheet.
_TILE_LONG_SIDE = 400
_LABEL_H = 24
_SHEET_COLUMNS = 3
_HOLE_COLOUR = (255, 0, 255)


def _tile(image: np.ndarray, label: str, cell_hw: tuple[int, int]) -> np.ndarray:
    ch, cw = cell_hw
    h, w = image.shape[:2]
    s = min(ch / h, cw / w)
    nh, nw = max(1, round(h * s)), max(1, round(w * s))
    tile = np.full((ch + _LABEL_H, cw, 3), 255, np.uint8)
    resized = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_AREA)
    y0, x0 = _LABEL_H + (ch - nh) // 2, (cw - nw) // 2
    tile[y0 : y0 + nh, x0 : x0 + nw] = resized
    cv2.putText(tile, label, (4, _LABEL_H - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return tile


def contact_sheet(
    pair: Pair, hole: np.ndarray, results: Sequence[tuple[EvalRow, np.ndarray | None]]
) -> np.ndarray:
    """RGB grid: ground truth, masked target (hole in magenta), source, then each method's output
    labelled with its hole PSNR (or FAILED)."""
    h, w = pair.target.shape[:2]
    s = _TILE_LONG_SIDE / max(h, w)
    cell = (max(1, round(h * s)), max(1, round(w * s)))
    masked = pair.target.copy()
    masked[hole] = _HOLE_COLOUR
    tiles = [
        _tile(pair.target, f"{pair.id} (ground truth)", cell),
        _tile(masked, f"masked target, hole {hole.mean():.1%}", cell),
        _tile(pair.source, "source", cell),
    ]
    for row, image in results:
        if image is None:
            tiles.append(_tile(np.full_like(pair.target, 128), f"{row.method}: FAILED", cell))
        else:
            label = f"{row.method}: hole PSNR {_fmt(row.psnr_hole, 2)} dB"
            tiles.append(_tile(image, label, cell))
    while len(tiles) % _SHEET_COLUMNS:
        tiles.append(np.full_like(tiles[0], 255))
    rows = [np.hstack(tiles[i : i + _SHEET_COLUMNS]) for i in range(0, len(tiles), _SHEET_COLUMNS)]
    return np.vstack(rows)


def write_contact_sheet(
    path: Path, pair: Pair, hole: np.ndarray, results: Sequence[tuple[EvalRow, np.ndarray | None]]
) -> None:
    """:func:`contact_sheet` as a JPEG."""
    sheet = contact_sheet(pair, hole, results)
    cv2.imwrite(str(path), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90])
