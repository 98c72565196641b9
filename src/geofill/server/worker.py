"""What runs inside a worker process: read one job's files, fill, write the result and coverage.

Fills run in worker processes rather than threads so that Cancel (and shutdown) can stop a fill
at once, in the middle of any stage (a slow solver included), by terminating the process, and so
that a fill's memory returns to the system when a worker is replaced. The processes are started
once and reused, so a fill pays no interpreter start-up (see docs/results.md for the overhead).

The one fill and every read of its coverage are in :func:`run_fill`."""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..progress import Progress

if TYPE_CHECKING:  # numpy is imported where used: the server process starts without it
    import numpy as np

    from ..io import LoadedImage

#: Coverage colours (RGB): painted by single-image inpainting, then reference 1, 2, ... (cycled).
PAINTED_RGB = (230, 60, 60)
REFERENCE_RGB = ((40, 170, 90), (50, 120, 220), (240, 170, 30), (170, 80, 200), (30, 190, 200))
#: Opacity (0-255) of the coverage overlay inside the hole; outside it is transparent.
COVERAGE_ALPHA = 170

TARGET_FILE, MASK_FILE, RESULT_FILE, COVERAGE_FILE = "target", "mask", "result.png", "coverage.png"
#: The result in the target's own format (JPEG at the target's quantisation tables, EXIF and ICC
#: kept), written beside the lossless PNG when the target was uploaded as one of these: a
#: photographer's 2 MB JPEG comes back as a JPEG of about its size, not an 8 MB PNG.
RESULT_AS_UPLOADED = {"JPEG": "result.jpg", "MPO": "result.jpg", "WEBP": "result.webp", "TIFF": "result.tif"}


def source_file(k: int) -> str:
    """File name of reference ``k`` (1-based) in a job folder; never a user-supplied name."""
    return f"source-{k}"


def source_mask_file(k: int) -> str:
    """File name of reference ``k``'s mask (what must never be copied from it) in a job folder."""
    return f"source-mask-{k}"


@dataclass(frozen=True)
class JobSpec:
    """What a worker needs for one fill (sent to the process, so plain values only)."""

    folder: str
    n_sources: int
    config: dict[str, Any]  # FillConfig.to_dict()
    source_masks: tuple[int, ...] = ()  # the references (1-based) that come with a mask


@dataclass(frozen=True)
class FillOutcome:
    """A fill reduced to what the server keeps: the image, who filled each hole pixel, the report."""

    image: np.ndarray  # HxWx3 uint8
    source_map: np.ndarray  # HxW int16: -1 outside the hole, 0 painted, k >= 1 from reference k
    report: dict[str, Any]
    status: str  # "reference" | "single_image"
    fallbacks: tuple[str, ...]  # in plain words (the technical reasons are in the report)
    notices: tuple[str, ...]  # what the user should know about how their request was used
    refused: str = ""  # what was not copied from the references, in plain words


class StageProgress(Progress):
    """Progress that sends each stage's start, each plain message and the done fraction to the
    server instead of printing (the technical details are logged only)."""

    def __init__(self, send: Callable[[tuple], None]) -> None:
        super().__init__(quiet=True)
        self._send = send

    def say(self, message: str) -> None:
        super().say(message)  # logged only: this progress is quiet
        self._send(("note", message))

    def on_fraction(self, before: float, now: float) -> None:
        self._send(("progress", now))

    @contextmanager
    def stage(self, name: str) -> Iterator[list[str]]:
        self._send(("stage", name))
        with super().stage(name) as notes:
            yield notes


def run_fill(
    target: LoadedImage,
    hole: np.ndarray,
    sources: Sequence[LoadedImage],
    config,
    progress: Progress,
    source_masks: Sequence[np.ndarray | None] | None = None,
) -> FillOutcome:
    """The server's one fill (:func:`geofill.pipeline.fill_loaded`), and its one read of the coverage."""
    from ..pipeline import fill_loaded

    result = fill_loaded(target, hole, sources, config, source_masks=source_masks, progress=progress)
    r = result.report
    dropped = tuple(r.dropped_words())
    return FillOutcome(result.image, result.source_map, r.to_dict(), r.status, dropped, (), r.refused_words())


def coverage_rgba(source_map: np.ndarray) -> np.ndarray:
    """HxWx4 uint8 overlay: each hole pixel coloured by who filled it, transparent outside."""
    import numpy as np

    out = np.zeros((*source_map.shape, 4), np.uint8)
    out[source_map == 0, :3] = PAINTED_RGB
    for k in range(1, int(source_map.max(initial=0)) + 1):
        out[source_map == k, :3] = REFERENCE_RGB[(k - 1) % len(REFERENCE_RGB)]
    out[source_map >= 0, 3] = COVERAGE_ALPHA
    return out


def coverage_summary(source_map: np.ndarray, n_sources: int) -> list[dict[str, Any]]:
    """Fraction of the hole per filler (references in order, then painted), with its overlay colour."""
    hole = max(int((source_map >= 0).sum()), 1)
    rows = []
    for k in range(1, n_sources + 1):
        rgb = REFERENCE_RGB[(k - 1) % len(REFERENCE_RGB)]
        rows.append({"label": f"reference {k}", "reference": k, "fraction": (source_map == k).sum() / hole})
        rows[-1]["colour"] = _hex(rgb)
    rows.append({"label": "painted", "reference": 0, "fraction": (source_map == 0).sum() / hole})
    rows[-1]["colour"] = _hex(PAINTED_RGB)
    for row in rows:
        row["fraction"] = float(row["fraction"])
    return rows


def _hex(rgb: tuple[int, int, int]) -> str:
    return "#" + "".join(f"{c:02x}" for c in rgb)


def plain_summary(rows: Sequence[dict[str, Any]]) -> str:
    """ "94 % from reference 2, 6 % painted" (fillers with under 0.5 % of the hole left out)."""
    parts = [
        f"{round(100 * r['fraction'])} % {'painted' if r['reference'] == 0 else 'from ' + r['label']}"
        for r in sorted(rows, key=lambda r: -r["fraction"])
        if r["fraction"] >= 0.005
    ]
    return ", ".join(parts)


def execute(spec: JobSpec, send: Callable[[tuple], None]) -> dict[str, Any]:
    """Run one job; write its result and coverage PNGs into its folder; return the summary."""
    from PIL import Image

    from ..config import FillConfig
    from ..io import read_image, read_mask, read_reference_mask, write_image_atomic

    folder = Path(spec.folder)
    cfg = FillConfig.from_dict(spec.config)
    prog = StageProgress(send)
    started = prog.wall_s()
    with prog.stage("read inputs"):
        target = read_image(folder / TARGET_FILE, max_pixels=cfg.max_pixels, min_side=cfg.min_side_px)
        hole = read_mask(folder / MASK_FILE, max_pixels=cfg.max_pixels)
        sources = [
            read_image(folder / source_file(k), max_pixels=cfg.max_pixels, min_side=cfg.min_side_px)
            for k in range(1, spec.n_sources + 1)
        ]
        masks = [
            read_reference_mask(
                folder / source_mask_file(k), s.pixels, f"sources[{k}]", max_pixels=cfg.max_pixels
            )
            if k in spec.source_masks
            else None
            for k, s in enumerate(sources, 1)
        ]
        with Image.open(folder / TARGET_FILE) as probe:  # reads the header only
            as_uploaded = RESULT_AS_UPLOADED.get(probe.format or "", RESULT_FILE)
    outcome = run_fill(target, hole, sources, cfg, prog, masks)
    with prog.stage("write result"):
        # With the target's EXIF, as the command line writes it: the lens it names is the focal
        # prior of a fill that starts again from this result.
        write_image_atomic(folder / RESULT_FILE, outcome.image, metadata=target.metadata)
        if as_uploaded != RESULT_FILE:
            write_image_atomic(folder / as_uploaded, outcome.image, metadata=target.metadata)
        # RGBA, which write_image_atomic (RGB outputs) does not write; the job is not done before
        # this returns, so nobody reads a half-written file.
        Image.fromarray(coverage_rgba(outcome.source_map)).save(folder / COVERAGE_FILE, compress_level=3)
    rows = coverage_summary(outcome.source_map, spec.n_sources)
    return {
        "status": outcome.status,
        "fallbacks": list(outcome.fallbacks),
        "notices": list(outcome.notices),
        "coverage": rows,
        "source_masks": list(spec.source_masks),
        "summary": "; ".join(filter(None, (plain_summary(rows), outcome.refused))),
        "result_file": as_uploaded,
        "report": outcome.report,
        "timings_s": dict(prog.timings),
        "wall_s": prog.wall_s() - started,
    }


def worker_main(conn: Connection) -> None:
    """Process entry point: import the pipeline once, then run jobs sent over ``conn`` until None
    or until the server goes away."""
    # Ctrl-C in the server's terminal reaches the whole process group: the server stops its
    # workers itself, so they must not die half-way with a traceback of their own.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from ..errors import GeoFillError
    from ..pipeline import fill  # noqa: F401  (imported now so that the first job does not pay for it)

    conn.send(("ready",))
    while True:
        try:
            spec = conn.recv()
        except EOFError:
            return
        if spec is None:
            return
        try:
            conn.send(("done", execute(spec, conn.send)))
        except GeoFillError as exc:
            conn.send(("failed", type(exc).__name__, str(exc)))
        except Exception as exc:  # reported to the client as a failed job; the worker carries on
            conn.send(("failed", "internal error", f"{type(exc).__name__}: {exc}"))
