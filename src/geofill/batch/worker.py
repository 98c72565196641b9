"""One batch item in a worker process: read its files, pick or take its references, fill, write
the output atomically and return its record (a JSON-able dict, one line of results.jsonl).

Whatever goes wrong with one item (a missing or corrupt file, a mask of another size, a fill that
raises) is caught here and becomes a ``failed`` record with the reason; the batch goes on.
"""

from __future__ import annotations

import os
import resource
import signal
import time
import traceback
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..composite.inpaint import get_inpainter
from ..composite.merge import merge_fill
from ..config import FillConfig
from ..errors import GeoFillError, InputError
from ..io import (
    LOSSY_SUFFIXES,
    LoadedImage,
    read_image,
    read_mask,
    read_reference_mask,
    validate_pair,
    write_image_atomic,
)
from ..pipeline import fill_loaded
from ..progress import Progress
from .items import BatchItem

#: Thread settings of a worker's libraries, set in its environment before they are imported: a
#: batch runs one single-threaded fill per core, which beats threads inside one fill (most stages
#: are not parallel, and the parallel ones scale poorly past one core).
SINGLE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
}

STATUS_REFERENCE = "reference"
STATUS_SINGLE_IMAGE = "single_image"
STATUS_FAILED = "failed"


@dataclass(frozen=True)
class OutputSpec:
    """Where and how a batch writes its outputs (each item's file name is its own)."""

    folder: str
    #: JPEG/WebP quality (1-100) of the lossy outputs; None: a JPEG target's own quantisation
    #: tables, else 95 (see :func:`geofill.io.write_image_atomic`).
    quality: int | None = None
    strip_metadata: bool = False  # True: no EXIF or ICC profile of the target in its output


@dataclass(frozen=True)
class Filled:
    """What the adapter returns: the image and what it was filled from."""

    image: np.ndarray  # HxWx3 uint8
    status: str  # STATUS_REFERENCE or STATUS_SINGLE_IMAGE
    fallbacks: tuple[str, ...]
    references: tuple[str, ...]  # paths of the references the fill was given
    coverage: float  # fraction of the hole supplied by the references
    notices: tuple[str, ...]
    reference_masks: tuple[str | None, ...] = ()  # per reference, its mask's path or None
    refused: dict[str, float] = field(default_factory=dict)  # FillReport.refused_fraction
    #: The references the fill dropped: {"reference": path, "reason": plain words, "detail": technical}.
    dropped: tuple[dict[str, str], ...] = ()


def fill_from_references(
    target: LoadedImage,
    hole: np.ndarray,
    references: Sequence[LoadedImage],
    cfg: FillConfig,
    prog: Progress,
    masks: Mapping[str, tuple[str, np.ndarray]] | None = None,
) -> Filled:
    """The one place a batch fills (:func:`geofill.pipeline.fill_loaded`, every reference of the item) and
    reads the hole coverage. ``masks``: reference path -> (mask path, HxW bool mask), what must never
    be copied from that reference."""
    # A batch already runs one fill per core: references one after the other inside each.
    cfg = cfg.updated({"fusion.parallel": 1})
    masks = masks or {}
    used = [masks.get(ref.path) for ref in references]
    result = fill_loaded(
        target, hole, references, cfg, source_masks=[None if m is None else m[1] for m in used], progress=prog
    )
    r = result.report
    paths = tuple(ref.path for ref in references)
    dropped = tuple(
        {"reference": paths[a.index - 1], "reason": a.dropped_words, "detail": a.dropped}
        for a in result.references
        if a.dropped
    )
    return Filled(
        result.image,
        r.status,
        tuple(r.fallbacks),
        paths,
        1.0 - float(r.painted_fraction),
        (),
        tuple(None if m is None else m[0] for m in used),
        {k: round(v, 4) for k, v in r.refused_fraction.items()},
        dropped,
    )


def _single_image(target: LoadedImage, hole: np.ndarray, cfg: FillConfig, prog: Progress) -> np.ndarray:
    """The whole hole by single-image inpainting, as the fill's fallback does (hole blanked first)."""
    with prog.stage("composite"):
        blanked = target.pixels.copy()
        blanked[hole] = 0
        return merge_fill(blanked, hole, None, None, get_inpainter(cfg.inpaint))


def init_worker() -> None:
    """Set up a local worker process: one thread per library; Ctrl-C is the parent's to handle
    (it terminates the workers), and termination unwinds so no temporary file is left behind."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _exit_on_terminate)
    single_threaded()


#: Set when this worker process is being terminated: whatever the unwinding raises from then on (a
#: compiled kernel turns the SystemExit into a SystemError) ends the process, it is no item's error.
_terminating = False


def _exit_on_terminate(signum: int, frame: Any) -> None:
    global _terminating
    _terminating = True
    raise SystemExit(128 + signum)


def single_threaded() -> None:
    """One thread for OpenCV and numba in this process (BLAS and OpenMP read the environment the
    runner sets before the worker starts)."""
    import cv2
    import numba

    cv2.setNumThreads(1)
    numba.set_num_threads(1)


def run_item(item: BatchItem, cfg: FillConfig, out: OutputSpec) -> dict[str, Any]:
    """Fill ``item`` with ``cfg`` into ``out.folder`` and return its record; never raises for a
    problem with the item itself (only for an interruption)."""
    t0 = time.perf_counter()
    prog = Progress(quiet=True)
    record: dict[str, Any] = {
        "item": item.name,
        "where": item.where,
        "target": item.target,
        "mask": item.mask,
        "output": str(Path(out.folder) / item.output) if item.output else "",
        "status": STATUS_FAILED,
        "references": [],  # every reference the fill was given (references_dropped: those it could not use)
        "references_dropped": [],
        "reference_masks": [],
        "fallback_reason": None,
        "coverage": None,
        "refused_fraction": None,
        "error": item.error or None,
    }
    if item.candidates:
        record["candidates"] = []
    if not item.error:
        try:
            _fill_item(item, cfg, out, record, prog)
        except GeoFillError as exc:
            record["error"] = str(exc)
        except Exception as exc:  # a fill that raises must not stop the batch: record it
            if _terminating:
                raise SystemExit(128 + signal.SIGTERM) from exc
            where = traceback.extract_tb(exc.__traceback__)[-1]
            record["error"] = (
                f"{item.where}: {type(exc).__name__}: {exc} (at {Path(where.filename).name}:{where.lineno})"
            )
    record["timings_s"] = {k: round(v, 4) for k, v in prog.timings.items()}
    record["time_s"] = round(time.perf_counter() - t0, 4)
    record["worker"] = {"pid": os.getpid(), "peak_rss_mib": round(_peak_rss_mib(), 1)}
    return record


def run_item_on_ray(item: BatchItem, cfg: FillConfig, out: OutputSpec) -> dict[str, Any]:
    """:func:`run_item` as a Ray task: Ray workers are not set up by :func:`init_worker`."""
    single_threaded()
    return run_item(item, cfg, out)


def _fill_item(
    item: BatchItem, cfg: FillConfig, out: OutputSpec, record: dict[str, Any], prog: Progress
) -> None:
    limits = {"max_pixels": cfg.max_pixels, "min_side": cfg.min_side_px}
    notices: list[str] = []
    with prog.stage("read"):
        target = read_image(item.target, **limits)
        mask = read_mask(item.mask, max_pixels=cfg.max_pixels)
        if item.candidates:
            # A photo of the shoot that cannot be read is no candidate; it does not fail the item.
            pool = []
            for path in item.candidates:
                try:
                    pool.append(read_image(path, **limits))
                except GeoFillError as exc:
                    notices.append(f"candidate skipped: {exc}")
            if not pool:
                raise InputError(
                    f"{item.target}: none of the {len(item.candidates)} candidate references can be read"
                )
        else:
            pool = [read_image(path, **limits) for path in item.sources]
        # A reference mask that cannot be read or is not its reference's size fails the item: the
        # user asked that something never be copied, and nothing is filled without knowing what.
        masks = {
            ref.path: (
                item.reference_masks[ref.path],
                read_reference_mask(
                    item.reference_masks[ref.path], ref.pixels, ref.path, max_pixels=cfg.max_pixels
                ),
            )
            for ref in pool
            if ref.path in item.reference_masks
        }
        hole = validate_pair(
            target.pixels,
            mask,
            pool[0].pixels,
            min_side=cfg.min_side_px,
            max_pixels=cfg.max_pixels,
            max_mask_fraction=cfg.max_mask_fraction,
            names=(item.target, item.mask, pool[0].path),
        )
    if item.candidates:
        from .references import pick_references

        with prog.stage("select references"):
            references, scores = pick_references(target.pixels, hole, pool, cfg, item.max_refs, masks)
        record["candidates"] = [s.to_dict() for s in scores]
    else:
        references = pool
    if references:
        filled = fill_from_references(target, hole, references, cfg, prog, masks)
        image, status, fallbacks, coverage = (
            filled.image,
            filled.status,
            list(filled.fallbacks),
            filled.coverage,
        )
        record["references"] = list(filled.references)
        record["references_dropped"] = list(filled.dropped)
        record["reference_masks"] = list(filled.reference_masks)
        record["refused_fraction"] = filled.refused
        notices.extend(filled.notices)
    else:
        image = _single_image(target, hole, cfg, prog)
        status, coverage = STATUS_SINGLE_IMAGE, 0.0
        fallbacks = [
            f"no candidate reference has {cfg.geometry.min_inliers} verified matches near the hole "
            f"(best: {max(s['matches_near_hole'] for s in record['candidates'])})"
        ]
    metadata = target.metadata.stripped() if out.strip_metadata else target.metadata
    if metadata.note:
        notices.append(f"{item.target}: {metadata.note}")
    lossy = Path(item.output).suffix.lower() in LOSSY_SUFFIXES
    with prog.stage("write"):
        write_image_atomic(record["output"], image, metadata=metadata, quality=out.quality if lossy else None)
    record.update(
        status=status,
        fallback_reason="; ".join(fallbacks) or None,
        coverage=round(coverage, 4),
        error=None,
    )
    if notices:
        record["notices"] = notices


def _peak_rss_mib() -> float:
    """Peak resident memory of this process so far (ru_maxrss is in KiB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
