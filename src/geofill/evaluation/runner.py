"""The evaluation protocol: cut a brush-stroke hole into each pair's target, run every method on the
same masked target, score against the original target, and write the tables and pictures.

Methods are registered by name in :mod:`.methods`, pairs read by :mod:`.pairs`; the files are
written by :mod:`.tables` and :mod:`.figures`.

Files written to ``out_dir`` by :func:`run_eval`: ``results.csv`` (one row per pair x method),
``timings.csv`` (per-stage seconds), ``summary.md``, ``contact_<pair>.jpg`` and the masks used
(``masks/<pair>.png``); with a removal protocol (:func:`run_removal_eval`) also the leak columns
and ``cases.json``; by :func:`sweep`: ``sweep_results.csv``, ``sweep.csv``, ``sweep.md`` and
``sweep.png``."""

from __future__ import annotations

import importlib.util
import json
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .figures import plot_sweep, write_contact_sheet, write_removal_contact_sheet
from .masks import (
    DEFAULT_AREA_RANGE,
    DEFAULT_STROKE_WIDTH_720P,
    PAPER_STROKE_WIDTHS_720P,
    brush_strokes,
    mask_seed,
)
from .methods import MULTI_REFERENCE, Method, MethodOutput, resolve_methods
from .metrics import LpipsScorer, LpipsUnavailable, ghost, leak, load_lpips, psnr, ssim
from .pairs import Pair, PairExif, group_value, pair_mask, stroke_width_px
from .removal import (
    MASK_TEXT,
    PROTOCOL_TEXT,
    PROTOCOLS,
    REMOVAL_MASKS,
    REMOVAL_PROTOCOLS,
    ProtocolSkip,
    RemovalCase,
    make_case,
)
from .tables import (
    EvalRow,
    fmt_number,
    summary_markdown,
    sweep_markdown,
    sweep_table,
    write_csv,
    write_results_csv,
    write_timings_csv,
)

#: ``--references`` choices: which references a multi-reference set's methods are run with.
REFERENCE_MODES = ("primary", "each", "all")


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


def _run_method(
    method: Method, pair: Pair, hole: np.ndarray, refs: Sequence[int], blank: bool = True
) -> MethodOutput:
    """``method`` on ``pair`` offered the references ``refs`` (0-based indices); the target's hole
    zeroed when ``blank`` (the restoration protocol: it shows the truth), else as it is (the
    removal protocols: it shows the object)."""
    target = pair.target
    masked = target.copy()
    if blank:
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
    case: RemovalCase | None = None,
) -> list[tuple[EvalRow, np.ndarray | None]]:
    """Run and score every method on ``pair`` with ``hole`` (on a multi-reference set, with the
    references ``modes`` asks for: see :func:`reference_runs`); each row with the composited
    output (None when the method failed). With a removal ``case`` (whose ``pair`` this is) the
    target is not blanked, scores are against ``case.truth`` and the leak is measured."""
    truth = pair.target if case is None else case.truth
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
            out = _run_method(method, pair, hole.mask, refs, blank=case is None)
            row.time_s = time.perf_counter() - t0
            image = np.where(hole.mask[..., None], out.image, pair.target)
            row.timings, row.info = dict(out.timings), dict(out.info)
            row.psnr, row.ssim = psnr(image, truth), ssim(image, truth)
            row.psnr_hole = psnr(image, truth, hole.mask)
            row.ssim_hole = ssim(image, truth, hole.mask)
            if case is not None:
                found = leak(image, truth, case.objects, hole.mask)
                row.leak, row.leaked_px = found.fraction, found.leaked
                row.distinguishable_px = found.distinguishable
                row.leak_all = leak(image, truth, [*case.objects, *case.extra_objects], hole.mask).fraction
                row.ghost = ghost(image, truth, hole.mask, case.appearances).fraction
            row.lpips_status = lpips.status
            if lpips.scorer is not None:
                try:
                    row.lpips = lpips.scorer(image, truth)
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
            if row.distinguishable_px is not None:
                tail += f" leak={fmt_number(row.leak, 3)} (all {fmt_number(row.leak_all, 3)})"
                tail += f" ghost={fmt_number(row.ghost, 3)}"
        else:
            tail = f"FAILED {row.error}"
        print(f"{head}: {tail}", file=sys.stderr, flush=True)


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
    protocol: str = "restoration",
    removal_mask: str = REMOVAL_MASKS[0],
) -> list[EvalRow]:
    """Evaluate ``methods`` (registry names, a name -> method mapping, or None for all registered)
    on ``pairs`` and write the results to ``out_dir`` (see the module docstring).

    ``protocol``: ``restoration`` (a brush-stroke hole in the background, blanked) or one of the
    object-removal protocols (:data:`.removal.REMOVAL_PROTOCOLS`, with the hole ``removal_mask``;
    see :func:`run_removal_eval`).

    Masks: seeded by (pair id, ``seed``); mean brush width ``stroke_width_720p`` px at a 720-px
    short side (default 150), scaled to each image; hole area in ``area_range``. ``by`` names a
    meta.json field to group the summary by. On multi-reference sets each method also runs with
    each reference alone and, if it can, with all of them (``references``; see
    :func:`reference_runs`). Returns the rows of results.csv."""
    methods = methods if isinstance(methods, Mapping) else resolve_methods(methods)
    width_720p = DEFAULT_STROKE_WIDTH_720P if stroke_width_720p is None else float(stroke_width_720p)
    if protocol != "restoration":
        return run_removal_eval(
            pairs,
            methods,
            out_dir,
            protocol,
            seed,
            width_720p,
            by,
            area_range=area_range,
            lpips_model=lpips_model,
            contact_sheets=contact_sheets,
            references=references,
            mask=removal_mask,
        )
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
        width_px = stroke_width_px(pair, width_720p)
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


def run_removal_eval(
    pairs: Sequence[Pair],
    methods: Mapping[str, Method],
    out_dir: str | Path,
    protocol: str,
    seed: int = 0,
    stroke_width_720p: float = DEFAULT_STROKE_WIDTH_720P,
    by: str | None = None,
    *,
    area_range: tuple[float, float] = DEFAULT_AREA_RANGE,
    lpips_model: str | Path | None = None,
    contact_sheets: bool = True,
    references: Sequence[str] = REFERENCE_MODES,
    mask: str = REMOVAL_MASKS[0],
) -> list[EvalRow]:
    """An object-removal protocol (:data:`.removal.REMOVAL_PROTOCOLS`, holes drawn as ``mask``
    says: :data:`.removal.REMOVAL_MASKS`): each pair gets
    its case (objects drawn into the target and the references; pairs the protocol cannot use are
    skipped with the reason), every method fills the target *as it shows the object* (not blanked),
    and is scored against the clean target, with the leak (:func:`.metrics.leak`) and the ghost
    (:func:`.metrics.ghost`).

    Writes what :func:`run_eval` writes, results.csv with the leak columns, and ``cases.json``
    (how each case was made: placement, depths, coverage, mappings)."""
    if protocol not in REMOVAL_PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r}; expected one of {', '.join(PROTOCOLS)}")
    out = Path(out_dir)
    (out / "masks").mkdir(parents=True, exist_ok=True)
    lpips = _Lpips.load(lpips_model)
    cases, skipped = [], {}
    for pair in pairs:
        try:
            cases.append(make_case(protocol, pair, seed, stroke_width_720p, area_range, mask))
        except ProtocolSkip as exc:
            skipped[pair.id] = str(exc)
            print(f"{pair.id}: skipped by the {protocol} protocol: {exc}", file=sys.stderr, flush=True)
    progress = _Progress(
        sum(
            len(reference_runs(len(c.pair.sources), m in MULTI_REFERENCE, references))
            for c in cases
            for m in methods
        )
    )
    rows: list[EvalRow] = []
    for case in cases:
        pair = case.pair
        group = group_value(pair.meta, by) if by else ""
        hole = _Hole(case.hole, case.stroke_width_720p, case.stroke_width_px, group)
        cv2.imwrite(str(out / "masks" / f"{pair.id}.png"), hole.mask.astype(np.uint8) * 255)
        results = _evaluate_pair(pair, hole, methods, lpips, progress, references, case)
        rows.extend(r for r, _ in results)
        if contact_sheets:
            write_removal_contact_sheet(out / f"contact_{pair.id}.jpg", case, results)
    write_results_csv(out / "results.csv", rows, by, leak=True)
    write_timings_csv(out / "timings.csv", rows)
    (out / "cases.json").write_text(
        json.dumps(
            {c.pair.id: c.info for c in cases} | {k: {"skipped": v} for k, v in skipped.items()}, indent=1
        )
    )
    settings = {
        "protocol": protocol,
        "protocol_text": PROTOCOL_TEXT[protocol],
        "removal_mask": f"{mask}: {MASK_TEXT[mask]}",
        "pairs": len(cases),
        "seed": seed,
        "lpips": lpips.description,
        "skipped": skipped,
        "revealed": {c.pair.id: c.info["hole_revealed"] for c in cases},
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
            mean_width_px=stroke_width_px(pair, DEFAULT_STROKE_WIDTH_720P),
            area_range=area_range,
        )
        for width_720p in widths_720p:
            width_px = stroke_width_px(pair, width_720p)
            hole = _Hole(shape.render(width_px), float(width_720p), width_px)
            rows.extend(r for r, _ in _evaluate_pair(pair, hole, methods, lpips, progress, ("primary",)))
    write_results_csv(out / "sweep_results.csv", rows, None)
    table = sweep_table(rows, list(methods), widths_720p)
    write_csv(out / "sweep.csv", list(table[0]) if table else [], table)
    (out / "sweep.md").write_text(sweep_markdown(table, lpips.description))
    if importlib.util.find_spec("matplotlib") is None:
        print(
            "sweep.png not drawn: matplotlib is not installed (pip install 'geofill[eval]')", file=sys.stderr
        )
    else:
        plot_sweep(out / "sweep.png", rows, list(methods), widths_720p)
    return rows
