"""What a batch shows while it runs and when it ends: a progress bar on a terminal (tqdm: done,
fell back, failed, rate, ETA), one plain line per item otherwise, and a summary table."""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

from .worker import STATUS_FAILED, STATUS_REFERENCE, STATUS_SINGLE_IMAGE


class BatchDisplay:
    """Progress of ``total`` items on ``stream``; :meth:`update` with each finished item's record."""

    def __init__(self, total: int, stream: TextIO, *, quiet: bool = False) -> None:
        self.total = total
        self.stream = stream
        self.quiet = quiet
        self.counts: Counter[str] = Counter()
        self.t0 = time.perf_counter()
        self.bar = None
        if not quiet and stream.isatty():
            from tqdm import tqdm

            self.bar = tqdm(total=total, file=stream, unit="fill", dynamic_ncols=True, desc="geofill batch")

    def update(self, record: dict[str, Any]) -> None:
        self.counts[record["status"]] += 1
        if self.quiet:
            return
        if self.bar is not None:
            self.bar.set_postfix(
                done=self.counts[STATUS_REFERENCE],
                fell_back=self.counts[STATUS_SINGLE_IMAGE],
                failed=self.counts[STATUS_FAILED],
                refresh=False,
            )
            self.bar.update(1)
            return
        n = sum(self.counts.values())
        print(
            f"geofill: [{n}/{self.total}] {record['item']}: {describe(record)}{self._pace(n)}",
            file=self.stream,
            flush=True,
        )

    def _pace(self, n: int) -> str:
        """`` | <rate>, ETA <time>`` from the items that were filled (an item that failed before any
        work, a missing mask say, takes no time and says nothing about the others); "" before one was."""
        filled = self.counts[STATUS_REFERENCE] + self.counts[STATUS_SINGLE_IMAGE]
        if not filled:
            return ""
        per_fill = (time.perf_counter() - self.t0) / filled
        return f" | {60.0 / per_fill:.1f} fills/min, ETA {_duration(per_fill * (self.total - n))}"

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def describe(record: dict[str, Any]) -> str:
    """One line on how an item ended, in plain words."""
    status = record["status"]
    dropped = record.get("references_dropped") or []
    unused = f"; {len(dropped)} reference(s) not used" if dropped else ""
    if status == STATUS_REFERENCE:
        used = len(record["references"]) - len(dropped)
        return f"{record['coverage']:.0%} of the hole filled from {used} reference(s){unused}"
    if status == STATUS_SINGLE_IMAGE:
        why = "; ".join(f"{Path(d['reference']).name}: {d['reason']}" for d in dropped)
        why = why or record["fallback_reason"]
        return f"no reference could be used, the hole was painted from its surroundings ({why})"
    return f"FAILED: {record['error']}"


def summary_table(
    records: Sequence[dict[str, Any]],
    *,
    total: int,
    skipped: int,
    elapsed_s: float,
    jobs: str,
    results_path: str,
    interrupted: bool,
    stopped_by: str = "Ctrl-C",
) -> str:
    """The end-of-batch summary: counts by status, throughput, and every item that did not fill
    from a reference with its reason. ``records`` are this run's; ``skipped`` were complete already."""
    counts = Counter(r["status"] for r in records)
    ran = len(records)
    filled = counts[STATUS_REFERENCE] + counts[STATUS_SINGLE_IMAGE]
    rate = f"{60.0 * filled / elapsed_s:.1f} fills/min, " if filled and elapsed_s > 0 else ""
    rows = [
        ("filled from a reference", counts[STATUS_REFERENCE]),
        ("fell back to single-image", counts[STATUS_SINGLE_IMAGE]),
        ("failed", counts[STATUS_FAILED]),
        ("skipped (already complete)", skipped),
    ]
    if interrupted:
        rows.append((f"not run (stopped by {stopped_by})", total - ran - skipped))
    width = max(len(name) for name, _ in rows)
    lines = [
        f"geofill batch: {ran} of {total} item(s) run in {_duration(elapsed_s)} "
        f"({rate}{jobs})" + (f" - STOPPED by {stopped_by}" if interrupted else ""),
        *(f"  {name:<{width}}  {n:>5d}" for name, n in rows),
    ]
    problems = [r for r in records if r["status"] != STATUS_REFERENCE]
    if problems:
        lines.append("items not filled from a reference:")
        lines.extend(f"  {r['item']}: {describe(r)}" for r in problems)
    notices = Counter(n for r in records for n in r.get("notices", []))
    lines.extend(f"notice ({k} item(s)): {n}" for n, k in notices.items())
    lines.append(f"results: {results_path}")
    return "\n".join(lines)


def _duration(seconds: float) -> str:
    seconds = max(0.0, seconds)
    if seconds < 60:
        return f"{seconds:.0f}s"
    minutes, secs = divmod(round(seconds), 60)
    return f"{minutes}m{secs:02d}s" if minutes < 60 else f"{minutes // 60}h{minutes % 60:02d}m"
