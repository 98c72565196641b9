"""Per-stage timing, one-line progress messages, and the fill's time budget.

Every message is a record of the ``geofill`` :mod:`logging` logger at INFO level, whether or not it
is printed, so that a program embedding geofill shows, filters or silences them with the standard
logging machinery (they are invisible by default: a logger without handlers shows warnings and
above only). A progress that is not quiet also prints each message to its stream: that is the
command line's output."""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from time import monotonic
from typing import TextIO

from .errors import TimeBudgetError

#: The package logger every progress message goes through.
LOGGER = logging.getLogger("geofill")


class Progress:
    """Times named stages; logs ``<stage> ... <s> s  <note>`` and prints it (after ``geofill: ``)
    unless quiet.

    ``time_budget_s`` bounds the whole run from this object's creation: every stage runs inside
    :meth:`stage`, which raises :class:`TimeBudgetError` when a stage would start past the deadline
    (a stage already running is not interrupted: the budget is a bound on when work starts)."""

    def __init__(
        self, quiet: bool = False, stream: TextIO | None = None, time_budget_s: float | None = None
    ) -> None:
        self.quiet = quiet
        self.stream = stream if stream is not None else sys.stderr
        self.timings: dict[str, float] = {}
        self.prefix = ""
        self.parent: Progress | None = None
        self._lock = threading.RLock()  # shared with children, which may run in threads
        self.time_budget_s = time_budget_s
        self._start = monotonic()

    def child(self, prefix: str) -> Progress:
        """A progress for one part of the work (one reference): its own timings, also added to
        this one's, and its lines prefixed with ``prefix``."""
        sub = type(self).__new__(type(self))
        sub.__dict__.update(self.__dict__)
        sub.timings, sub.parent = {}, self
        sub.prefix = f"{self.prefix}{prefix}: " if prefix else self.prefix
        return sub

    def say(self, message: str) -> None:
        """Log ``message`` (with this progress's prefix) and print it unless quiet."""
        text = f"{self.prefix}{message}"
        LOGGER.info(text)
        if not self.quiet:
            print(f"geofill: {text}", file=self.stream, flush=True)

    def _add(self, name: str, seconds: float) -> None:
        with self._lock:
            self.timings[name] = self.timings.get(name, 0.0) + seconds
            if self.parent is not None:
                self.parent._add(name, seconds)

    def check_deadline(self, next_stage: str) -> None:
        """Raise TimeBudgetError when the budget is spent (``next_stage`` is named in the message)."""
        if self.time_budget_s is None:
            return
        elapsed = monotonic() - self._start
        if elapsed > self.time_budget_s:
            raise TimeBudgetError(
                f"time budget of {self.time_budget_s:g} s exceeded after {elapsed:.1f} s, before stage "
                f"'{next_stage}' (raise it with --set time_budget_s=SECONDS)"
            )

    @contextmanager
    def stage(self, name: str) -> Iterator[list[str]]:
        """Context that times ``name``; append strings to the yielded list to print them with it."""
        self.check_deadline(name)
        notes: list[str] = []
        t0 = time.perf_counter()
        yield notes  # a stage that raises is reported by whoever handles the error, not here
        dt = time.perf_counter() - t0
        self._add(name, dt)
        self.say(f"{name:<14s} {dt:6.2f} s" + (f"  {'; '.join(notes)}" if notes else ""))
