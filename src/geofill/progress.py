"""Per-stage timing, one-line progress messages, the fill's done fraction and its time budget.

Messages are of two kinds: what a user needs in plain words (:meth:`Progress.say`) and the technical
details (:meth:`Progress.detail`: every stage's time and summary). Both are records of the
``geofill`` :mod:`logging` logger at INFO level, whether or not they are printed, so that a program
embedding geofill shows, filters or silences them with the standard logging machinery (they are
invisible by default: a logger without handlers shows warnings and above only). A progress that is
not quiet also prints the plain messages to its stream, and the details too when verbose: that is
the command line's output.

The done fraction is counted in stages: the fill plans how many it will run (:meth:`Progress.plan`)
and every stage that ends, or that a dropped reference will no longer run, counts one; references
run in parallel threads share the count, so the fraction only grows."""

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

#: What each stage does, in the words the command line and the web page show.
STAGE_WORDS: dict[str, str] = {
    "read inputs": "Reading the photos",
    "check inputs": "Checking the inputs",
    "prepare": "Preparing working images",
    "match": "Matching features between the photos",
    "focal": "Estimating the focal length",
    "pose": "Estimating the camera positions",
    "triangulate": "Triangulating matched points",
    "depth": "Estimating depth",
    "optimize": "Refining camera pose and depth",
    "render": "Projecting the reference into the photo",
    "refine": "Aligning and matching colours",
    "screen": "Checking what the reference shows in the hole",
    "shared focal": "Estimating one focal length for all photos",
    "fuse": "Choosing the best reference for each pixel",
    "composite": "Blending the fill",
    "write result": "Saving the result",
}

#: A progress that prints only plain messages shows the done fraction at these steps (percent).
PERCENT_STEP = 25


class _Work:
    """Stages planned and done, shared by a progress and its children (under their lock)."""

    def __init__(self) -> None:
        self.planned = 0
        self.done = 0
        self.fraction = 0.0


class Progress:
    """Times named stages; logs ``<stage> ... <s> s  <note>`` and prints it (after ``geofill: ``)
    when verbose, and plain messages and the done fraction unless quiet.

    ``time_budget_s`` bounds the whole run from this object's creation: every stage runs inside
    :meth:`stage`, which raises :class:`TimeBudgetError` when a stage would start past the deadline
    (a stage already running is not interrupted: the budget is a bound on when work starts)."""

    def __init__(
        self,
        quiet: bool = False,
        stream: TextIO | None = None,
        time_budget_s: float | None = None,
        verbose: bool = False,
    ) -> None:
        self.quiet = quiet
        self.verbose = verbose
        self.stream = stream if stream is not None else sys.stderr
        self.timings: dict[str, float] = {}
        self.prefix = ""
        self.parent: Progress | None = None
        self._lock = threading.RLock()  # shared with children, which may run in threads
        self._work = _Work()  # shared with children too
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
        """Log ``message`` (what a user needs, in plain words) and print it unless quiet."""
        LOGGER.info(message)
        if not self.quiet:
            print(f"geofill: {message}", file=self.stream, flush=True)

    def detail(self, message: str) -> None:
        """Log a technical ``message`` (with this progress's prefix); print it only when verbose."""
        text = f"{self.prefix}{message}"
        LOGGER.info(text)
        if self.verbose and not self.quiet:
            print(f"geofill: {text}", file=self.stream, flush=True)

    @property
    def fraction(self) -> float:
        """Done fraction of the planned stages, 0 to 1, never decreasing."""
        return self._work.fraction

    def plan(self, stages: int) -> None:
        """Expect ``stages`` more stages before the work is done."""
        with self._lock:
            self._work.planned += stages

    def advance(self, stages: int = 1) -> None:
        """Count ``stages`` as done (ended, or never to run); nothing before a plan exists."""
        with self._lock:
            work = self._work
            if not work.planned or stages <= 0:
                return
            before = work.fraction
            work.done += stages
            work.fraction = max(before, min(1.0, work.done / work.planned))
            if work.fraction > before:
                self.on_fraction(before, work.fraction)

    def on_fraction(self, before: float, now: float) -> None:
        """The done fraction grew from ``before`` to ``now``: a progress that prints plain
        messages only says so at each :data:`PERCENT_STEP`."""
        if self.quiet or self.verbose:
            return
        step = int(100 * now) // PERCENT_STEP * PERCENT_STEP
        if 0 < step < 100 and step > int(100 * before) // PERCENT_STEP * PERCENT_STEP:
            print(f"geofill: {step}% done", file=self.stream, flush=True)

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
        self.detail(f"{name:<14s} {dt:6.2f} s" + (f"  {'; '.join(notes)}" if notes else ""))
        self.advance()

    def wall_s(self) -> float:
        """Seconds since this progress (or the one it is a child of) was created."""
        return monotonic() - self._start
