"""The rows of an evaluation (:class:`EvalRow`, one line of results.csv) and the tables made of
them: results.csv and timings.csv, summary.md (scores, wins against the baselines, stage times,
groups, several references), and the hole-size sweep's sweep.csv and sweep.md."""

from __future__ import annotations

import csv
import json
import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .methods import BASELINES


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
    leak: float | None = None  # removal protocols: see metrics.leak
    leaked_px: int | None = None
    distinguishable_px: int | None = None
    leak_all: float | None = None
    ghost: float | None = None  # removal protocols: see metrics.ghost
    time_s: float | None = None
    error: str = ""
    group: str = ""
    info: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.error


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


def write_csv(path: Path, fields: Sequence[str], records: Sequence[Mapping[str, Any]]) -> None:
    """``records`` as CSV with the columns ``fields`` (None empty, floats to 6 digits)."""
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(fields))
        writer.writeheader()
        writer.writerows({k: _cell(v) for k, v in r.items()} for r in records)


#: Extra results.csv columns of the removal protocols.
LEAK_FIELDS = ("leak", "leaked_px", "distinguishable_px", "leak_all", "ghost")


def write_results_csv(path: Path, rows: Sequence[EvalRow], by: str | None, leak: bool = False) -> None:
    """One line per pair x method; a ``by`` column with the group when grouping; with ``leak``
    (the removal protocols) the :data:`LEAK_FIELDS` after the scores."""
    scores = (*_CSV_FIELDS, *(LEAK_FIELDS if leak else ()))
    fields = [*scores, *([by] if by else []), "info"]
    records = []
    for row in rows:
        record = {name: getattr(row, name) for name in scores}
        if by:
            record[by] = row.group
        record["info"] = json.dumps(row.info, sort_keys=True) if row.info else ""
        records.append(record)
    write_csv(path, fields, records)


def write_timings_csv(path: Path, rows: Sequence[EvalRow]) -> None:
    """One line per pair x method x stage (seconds as reported by the method)."""
    fields = ("pair", "method", "stroke_width_720p", "stage", "seconds")
    records = [
        dict(zip(fields, (r.pair, r.method, r.stroke_width_720p, stage, seconds), strict=True))
        for r in rows
        for stage, seconds in r.timings.items()
    ]
    write_csv(path, fields, records)


def ok_values(rows: Sequence[EvalRow], metric: str) -> list[float]:
    """``metric`` of the rows whose method ran and got a score."""
    return [getattr(r, metric) for r in rows if r.ok and getattr(r, metric) is not None]


def mean_or_none(values: Sequence[float]) -> float | None:
    """The mean; None when there are no values."""
    return float(np.mean(values)) if values else None


def fmt_number(value: float | None, digits: int) -> str:
    """``value`` with ``digits`` decimals for a table; '-' for None."""
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
    """The summary.md text: settings, mean/median scores, wins vs. baselines, grouping, failures;
    for a removal protocol (``settings['protocol']``) also the leak, per set, and the sets skipped."""
    hole_ratios = {r.pair: r.hole_ratio for r in rows}
    removal = settings.get("protocol", "restoration") != "restoration"
    mean_ratio = fmt_number(mean_or_none(list(hole_ratios.values())), 3)
    if removal:
        head = [
            f"- protocol: {settings['protocol']}: {settings['protocol_text']}",
            f"- hole: {settings['removal_mask']}",
            f"- sets: {settings['pairs']}, seed {settings['seed']}, mean hole ratio {mean_ratio}",
            f"- leak: {LEAK_TEXT}",
            f"- ghost: {GHOST_TEXT}",
        ]
    else:
        lo, hi = settings["area_range"]
        head = [
            f"- pairs: {settings['pairs']}, mask seed {settings['seed']}, mean brush width "
            f"{settings['stroke_width_720p']:g} px at a 720-px short side (scaled per image), "
            f"hole area window {lo:.0%}-{hi:.0%}, mean hole ratio {mean_ratio}"
        ]
    lines = [
        "# geofill evaluation",
        "",
        *head,
        f"- LPIPS: {settings['lpips']}",
        "- whole-image scores count every pixel (papers' convention); hole scores count hole pixels only",
        "",
        "## Scores (mean / median over pairs the method ran on)",
        "",
    ]
    leaks = (("leak", "leak", 3), ("leak_all", "leak (all)", 3), ("ghost", "ghost", 3))
    metrics = (*_METRICS, ("lpips", "LPIPS", 4), *(leaks if removal else ()))
    header = ["method", "ok", "failed", *(label for _, label, _ in metrics), "median time (s)"]
    body = []
    for m in methods:
        mine = [r for r in rows if r.method == m]
        cells = [m, str(sum(r.ok for r in mine)), str(sum(not r.ok for r in mine))]
        for metric, _, digits in metrics:
            values = ok_values(mine, metric)
            median = float(np.median(values)) if values else None
            cells.append(f"{fmt_number(mean_or_none(values), digits)} / {fmt_number(median, digits)}")
        times = ok_values(mine, "time_s")
        cells.append(fmt_number(statistics.median(times) if times else None, 2))
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
                    + [fmt_number(mean_or_none(ok_values(mine, metric)), d) for metric, _, d in _METRICS]
                )
        lines += _md_table([by, "method", "n ok", *(f"{label} (mean)" for _, label, _ in _METRICS)], body)

    lines += multi_reference_markdown(rows, methods)
    if removal:
        lines += per_set_markdown(rows, methods, settings.get("revealed", {}))
        lines += ["", "## Sets skipped by the protocol", ""]
        lines += [f"- {pid}: {why}" for pid, why in settings.get("skipped", {}).items()] or ["none"]
    failures = [r for r in rows if not r.ok]
    lines += ["", "## Failures", ""]
    lines += [f"- {r.pair} / {r.method}: {r.error}" for r in failures] or ["none"]
    return "\n".join(lines) + "\n"


#: What the summary says the leak is (metrics.leak).
LEAK_TEXT = (
    "fraction of the hole pixels where an object is distinguishable from the truth (RGB distance "
    "> 30) at which the output is nearer to the object than half its distance to the truth; objects: "
    "static, the object as drawn in the target; strangers, each reference's strangers mapped into the "
    "target. leak (all) adds, static: each reference's object mapped into the target as if it were "
    "background; strangers: the target's own cutout. A method that cannot copy (opencv_inpaint) "
    "shows the chance level"
)


#: What the summary says the ghost is (metrics.ghost).
GHOST_TEXT = (
    "fraction of the hole pixels (at a 640-px long side) where the output shows a copy of an object "
    "or passer-by as some view shows it, placed anywhere, rotated or rescaled: SIFT matches to the "
    "object that one similarity transform explains, confirmed pixel by pixel where the output is "
    "at least twice as near the mapped object as the truth (a copy too small for 3 features, and "
    "the flat inside of a one-colour object, are not counted)"
)


def per_set_markdown(
    rows: Sequence[EvalRow], methods: Sequence[str], revealed: Mapping[str, float]
) -> list[str]:
    """Per set and method: the fraction of the hole's background the references see unhidden
    (``revealed``: what a perfect copy could recover), hole PSNR, leak (leaked / distinguishable
    pixels) and leak (all)."""
    order = {m: i for i, m in enumerate(methods)}
    body = []
    for r in sorted(rows, key=lambda r: (r.pair, order.get(r.method, len(order)))):
        seen = fmt_number(revealed.get(r.pair), 3)
        if not r.ok:
            body.append([r.pair, seen, r.method, "FAILED", "-", "-", "-", "-"])
            continue
        body.append(
            [
                r.pair,
                seen,
                r.method,
                fmt_number(r.psnr_hole, 2),
                fmt_number(r.leak, 3),
                f"{r.leaked_px}/{r.distinguishable_px}",
                fmt_number(r.leak_all, 3),
                fmt_number(r.ghost, 3),
            ]
        )
    header = [
        "set", "revealed", "method", "PSNR hole", "leak", "leaked / distinguishable px", "leak (all)", "ghost"
    ]  # fmt: skip
    return ["", "## Per set", "", *_md_table(header, body)]


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
                    fmt_number(primary.psnr_hole, 2),
                    f"{fmt_number(best.psnr_hole, 2)} ({best_name.removeprefix(m) or 'primary'})",
                    fmt_number(together.psnr_hole, 2),
                    f"{fmt_number(cov[0], 3)} -> {fmt_number(cov[1], 3)}",
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
                "mean_hole_ratio": mean_or_none([r.hole_ratio for r in mine]),
            }
            for metric in ("psnr", "ssim", "psnr_hole", "ssim_hole", "lpips"):
                record[f"mean_{metric}"] = mean_or_none(ok_values(mine, metric))
            table.append(record)
    return table


def sweep_markdown(table: Sequence[Mapping[str, Any]], lpips_status: str) -> str:
    """The sweep.md text: :func:`sweep_table` as markdown."""
    lines = ["# Hole-size sweep", "", f"- LPIPS: {lpips_status}", ""]
    header = ["stroke width (px @720p)", "method", "ok", "failed", "hole ratio", "PSNR", "SSIM", "PSNR hole"]
    header += ["SSIM hole", "LPIPS"]
    body = [
        [
            f"{t['stroke_width_720p']:g}",
            t["method"],
            str(t["n_ok"]),
            str(t["n_failed"]),
            fmt_number(t["mean_hole_ratio"], 3),
            fmt_number(t["mean_psnr"], 2),
            fmt_number(t["mean_ssim"], 4),
            fmt_number(t["mean_psnr_hole"], 2),
            fmt_number(t["mean_ssim_hole"], 4),
            fmt_number(t["mean_lpips"], 4),
        ]
        for t in table
    ]
    return "\n".join(lines + _md_table(header, body)) + "\n"
