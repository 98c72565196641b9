"""Per-stage timing and one-line progress messages on stderr."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TextIO


class Progress:
    """Times named stages; prints ``geofill: <stage> ... <s> s  <note>`` unless quiet."""

    def __init__(self, quiet: bool = False, stream: TextIO | None = None) -> None:
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr
        self.timings: dict[str, float] = {}

    def say(self, message: str) -> None:
        if not self.quiet:
            print(f"geofill: {message}", file=self.stream, flush=True)

    @contextmanager
    def stage(self, name: str) -> Iterator[list[str]]:
        """Context that times ``name``; append strings to the yielded list to print them with it."""
        notes: list[str] = []
        t0 = time.perf_counter()
        yield notes  # a stage that raises is reported by whoever handles the error, not here
        dt = time.perf_counter() - t0
        self.timings[name] = self.timings.get(name, 0.0) + dt
        self.say(f"{name:<14s} {dt:6.2f} s" + (f"  {'; '.join(notes)}" if notes else ""))
