"""Per-stage timing and one-line progress messages on stderr."""

from __future__ import annotations

import sys
import threading
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
        self.prefix = ""
        self.parent: Progress | None = None
        self._lock = threading.RLock()  # shared with children, which may run in threads

    def child(self, prefix: str) -> Progress:
        """A progress for one part of the work (one reference): its own timings, also added to
        this one's, and its lines prefixed with ``prefix``."""
        sub = type(self).__new__(type(self))
        sub.__dict__.update(self.__dict__)
        sub.timings, sub.parent = {}, self
        sub.prefix = f"{self.prefix}{prefix}: " if prefix else self.prefix
        return sub

    def say(self, message: str) -> None:
        if not self.quiet:
            print(f"geofill: {self.prefix}{message}", file=self.stream, flush=True)

    def _add(self, name: str, seconds: float) -> None:
        with self._lock:
            self.timings[name] = self.timings.get(name, 0.0) + seconds
            if self.parent is not None:
                self.parent._add(name, seconds)

    @contextmanager
    def stage(self, name: str) -> Iterator[list[str]]:
        """Context that times ``name``; append strings to the yielded list to print them with it."""
        notes: list[str] = []
        t0 = time.perf_counter()
        yield notes  # a stage that raises is reported by whoever handles the error, not here
        dt = time.perf_counter() - t0
        self._add(name, dt)
        self.say(f"{name:<14s} {dt:6.2f} s" + (f"  {'; '.join(notes)}" if notes else ""))
