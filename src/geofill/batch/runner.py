"""Running a batch: local worker processes or a Ray cluster, results.jsonl, resume, Ctrl-C, and
the exit status.

Workers write the outputs (atomically, :func:`geofill.io.write_image_atomic`); the parent alone
writes results.jsonl, one line per item as it finishes, so the file is never half a line and an
item retried by Ray is recorded once. ``--resume`` keeps the records of items whose output is
complete and runs the others. Ctrl-C and SIGTERM stop a batch the same way: workers terminated,
every item that finished recorded, the summary printed. A batch never writes into a folder that
holds its inputs unless told to (``--overwrite``), and a stop removes only files this run created.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any, TextIO

from PIL import Image

from ..config import FillConfig
from ..errors import (
    EXIT_FELL_BACK,
    EXIT_INTERRUPTED,
    EXIT_ITEMS_FAILED,
    EXIT_TERMINATED,
    ConfigError,
    OutputError,
    Terminated,
)
from ..io import file_id, file_ids, remove_partial_writes, replace_durably
from .display import BatchDisplay, summary_table
from .items import BatchItem
from .worker import (
    SINGLE_THREAD_ENV,
    STATUS_FAILED,
    STATUS_REFERENCE,
    STATUS_SINGLE_IMAGE,
    OutputSpec,
    init_worker,
    run_item,
    run_item_on_ray,
)

RESULTS_NAME = "results.jsonl"
#: Seconds a terminated worker has to unwind before it is killed.
TERMINATE_GRACE_S = 0.5
#: Times Ray runs a task again after its worker process died (Ray's own retry).
RAY_MAX_RETRIES = 3

Task = tuple[BatchItem, FillConfig]
OnRecord = Callable[[dict[str, Any]], None]
Execute = Callable[[Sequence[Task], OutputSpec, OnRecord], None]
#: What stops a batch from outside: Ctrl-C, and SIGTERM (which the command line raises as Terminated).
STOPPED = (KeyboardInterrupt, Terminated)


@dataclass(frozen=True)
class BatchSettings:
    """How to run a batch (the command line's flags)."""

    out_dir: Path
    jobs: int = 1
    resume: bool = False
    allow_fallback: bool = False
    ray: str | None = None  # "local", "auto" or a cluster address; None = local worker processes
    quiet: bool = False
    quality: int | None = None  # of JPEG/WebP outputs; None: a JPEG target's own tables, else 95
    strip_metadata: bool = False
    overwrite: bool = False  # allow out_dir to be a folder that holds input files


@dataclass(frozen=True)
class BatchOutcome:
    """What a batch did: this run's records, the records kept by ``--resume``, and the exit status."""

    records: list[dict[str, Any]]
    kept: list[dict[str, Any]] = field(default_factory=list)
    interrupted: bool = False  # by Ctrl-C or SIGTERM
    exit_code: int = 0
    elapsed_s: float = 0.0  # running the items (after Ray connected; local workers start within it)


def exit_status(
    statuses: Sequence[str], *, allow_fallback: bool, interrupted: bool, terminated: bool = False
) -> int:
    """0 when every item was filled from a reference; failed items win over fallbacks."""
    if terminated:
        return EXIT_TERMINATED
    if interrupted:
        return EXIT_INTERRUPTED
    if STATUS_FAILED in statuses:
        return EXIT_ITEMS_FAILED
    if STATUS_SINGLE_IMAGE in statuses and not allow_fallback:
        return EXIT_FELL_BACK
    return 0


def run_batch(
    items: Sequence[BatchItem], base_config: FillConfig, settings: BatchSettings, stream: TextIO | None = None
) -> BatchOutcome:
    """Fill every item, write ``{out_dir}/results.jsonl`` and print progress and the summary.

    A problem with one item is recorded and the batch goes on; Ctrl-C or SIGTERM stops it with the
    finished items kept (their outputs and records), nothing half-written, and the summary printed.
    An ``out_dir`` that holds input files is refused (OutputError) unless ``settings.overwrite``."""
    stream = stream or sys.stderr
    if settings.jobs < 1:
        raise ConfigError(f"--jobs must be at least 1, got {settings.jobs}")
    out = settings.out_dir
    if not settings.overwrite:
        _check_inputs_spared(items, out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot create the output folder ({exc.strerror})") from exc
    if not os.access(out, os.W_OK | os.X_OK):
        raise OutputError(f"{out}: output folder is not writable")
    with _executor(settings) as execute:  # Ray connects (or fails) before anything is written
        return _run(items, base_config, settings, stream, execute)


def _run(
    items: Sequence[BatchItem],
    base_config: FillConfig,
    settings: BatchSettings,
    stream: TextIO,
    execute: Execute,
) -> BatchOutcome:
    out = settings.out_dir
    spec = OutputSpec(str(out), settings.quality, settings.strip_metadata)
    results = out / RESULTS_NAME
    kept = _complete_records(items, out, results) if settings.resume else {}
    _rewrite_results(results, list(kept.values()))
    todo = [item for item in items if item.output.lower() not in kept or item.error]
    configs = {}
    tasks: list[Task] = []
    records: list[dict[str, Any]] = []
    display = BatchDisplay(len(todo), stream, quiet=settings.quiet)

    with results.open("a", encoding="utf-8") as fh:

        def on_record(record: dict[str, Any]) -> None:
            fh.write(json.dumps(record) + "\n")
            fh.flush()
            records.append(record)
            display.update(record)

        for item in todo:
            if item.error:  # nothing to run: recorded here, not sent to a worker
                on_record(run_item(item, base_config, spec))
                continue
            key = json.dumps(dict(item.overrides), sort_keys=True)
            if key not in configs:
                configs[key] = base_config.updated(dict(item.overrides)) if item.overrides else base_config
            tasks.append((item, configs[key]))
        t0 = time.perf_counter()
        stopped: BaseException | None = None
        try:
            execute(tasks, spec, on_record)
        except STOPPED as exc:
            stopped = exc
        finally:
            display.close()
    interrupted, terminated = stopped is not None, isinstance(stopped, Terminated)
    elapsed = time.perf_counter() - t0
    where = f"Ray {settings.ray}" if settings.ray else f"{settings.jobs} job(s)"
    print(
        summary_table(
            records,
            total=len(items),
            skipped=len(kept),
            elapsed_s=elapsed,
            jobs=where,
            results_path=str(results),
            interrupted=interrupted,
            stopped_by="SIGTERM" if terminated else "Ctrl-C",
        ),
        flush=True,
    )
    statuses = [r["status"] for r in [*kept.values(), *records]]
    code = exit_status(
        statuses, allow_fallback=settings.allow_fallback, interrupted=interrupted, terminated=terminated
    )
    return BatchOutcome(records, list(kept.values()), interrupted, code, elapsed)


def _check_inputs_spared(items: Sequence[BatchItem], out: Path) -> None:
    """Raise OutputError when ``out`` is a folder that holds an input file of ``items``: an output
    of the same name would replace it (a target, with its format kept, always does). Folders are
    compared as files (:func:`geofill.io.file_id`), both where a path names an input and where its
    links lead."""
    out_id = file_id(out)
    if out_id is None:
        return
    # A set: with --sources DIR every item names every photo of the shoot as a candidate.
    named = {
        p
        for item in items
        for p in (item.target, item.mask, *item.sources, *item.candidates, *item.reference_masks.values())
        if p
    }
    inputs = sorted(Path(p) for p in named)
    folders = file_ids(f for p in inputs for f in (p.parent, p.resolve().parent))
    if out_id in folders:
        held = next(p for p in inputs if out_id in (file_id(p.parent), file_id(p.resolve().parent)))
        raise OutputError(
            f"{out}: the output folder holds input files ({held} among them) that the outputs can "
            "replace; choose another --out, or give --overwrite to allow it"
        )


def _complete_records(items: Sequence[BatchItem], out: Path, results: Path) -> dict[str, dict[str, Any]]:
    """Records (by lower-case output name) of this batch's items that a previous run finished:
    recorded as filled in results.jsonl, with an output file that decodes to the end."""
    if not results.is_file():
        return {}
    wanted = {item.output.lower() for item in items if item.output and not item.error}
    done: dict[str, dict[str, Any]] = {}
    for line in results.read_text(encoding="utf-8").splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue  # a line cut by a crash: its item is simply run again
        name = Path(record.get("output") or "").name.lower()
        if name in wanted and record.get("status") in (STATUS_REFERENCE, STATUS_SINGLE_IMAGE):
            done[name] = record
    return {name: r for name, r in done.items() if _decodes(out / Path(r["output"]).name)}


def _decodes(path: Path) -> bool:
    try:
        with Image.open(path) as img:
            img.load()
    except (OSError, ValueError, SyntaxError):
        return False
    return True


def _rewrite_results(results: Path, records: list[dict[str, Any]]) -> None:
    """Start results.jsonl with ``records`` (replaced atomically, so a crash keeps the old file)."""
    tmp = results.with_name(f".{results.name}.tmp")
    tmp.write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")
    replace_durably(tmp, results)


@contextmanager
def _environment(values: dict[str, str]) -> Iterator[None]:
    """``values`` in os.environ for the block: spawned workers inherit them before importing
    anything (the thread pools of OpenMP, MKL and numba are sized at import)."""
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextmanager
def _executor(settings: BatchSettings) -> Iterator[Execute]:
    """What runs the tasks: local worker processes, or Ray tasks in a Ray session open for the block."""
    if settings.ray is None:
        yield partial(_run_local, jobs=settings.jobs)
        return
    with _ray_session(settings.ray, settings.jobs) as ray:
        yield partial(_run_ray, ray)


def _run_local(tasks: Sequence[Task], out: OutputSpec, on_record: OnRecord, *, jobs: int) -> None:
    """``jobs`` spawned worker processes, one item each at a time. A worker that dies (killed, out
    of memory) fails the items in flight, which ``--resume`` runs again; the pool is replaced."""
    pending = list(reversed(tasks))
    # And whether this run creates its output: true when no file of that name existed as it went
    # to a worker.
    running: dict[Future, tuple[Task, bool]] = {}
    ctx = multiprocessing.get_context("spawn")  # fork would copy the parent's torch/OpenMP threads state
    with _environment(SINGLE_THREAD_ENV):
        pool = ProcessPoolExecutor(jobs, mp_context=ctx, initializer=init_worker)
        try:
            while pending or running:
                while pending and len(running) < jobs:
                    task = pending.pop()
                    created = not (Path(out.folder) / task[0].output).exists()
                    running[pool.submit(run_item, *task, out)] = task, created
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                broken = False
                for future in done:
                    (item, cfg), _ = running.pop(future)
                    try:
                        on_record(future.result())
                    except BrokenProcessPool:
                        broken = True
                        on_record(_failed(item, cfg, out, "a worker process died (killed or out of memory)"))
                if broken:
                    pool.shutdown(wait=True)
                    pool = ProcessPoolExecutor(jobs, mp_context=ctx, initializer=init_worker)
        except STOPPED:
            _terminate_workers(pool)
            for future, ((item, _), created) in running.items():
                # Items that finished while the signal came: their outputs are written, record them.
                if future.done() and not future.cancelled() and future.exception() is None:
                    on_record(future.result())
                else:
                    _remove_unrecorded(Path(out.folder) / item.output, created)
            raise
        pool.shutdown(wait=True)


def _remove_unrecorded(output: Path, created: bool) -> None:
    """Remove what an item stopped in flight wrote: a worker killed mid-write leaves its temporary
    file, and one killed after its write but before its result reached this process leaves an
    output that no record names, which ``--resume`` would run again anyway. That output is removed
    only when this run ``created`` it (no file of its name existed before): a file that was there
    (an earlier run's output, an input the user let the batch replace) is never deleted, and
    modification times, which another process or a coarse clock can make lie, are not consulted."""
    remove_partial_writes(output)
    if created:
        output.unlink(missing_ok=True)


def _terminate_workers(pool: ProcessPoolExecutor) -> None:
    """Stop at once: queued items are cancelled, running ones terminated. Their SIGTERM handler
    unwinds (the atomic writer removes its temporary file), but only once the compiled call it
    lands in returns, which can take seconds: a worker still alive after :data:`TERMINATE_GRACE_S`
    is killed, and the caller removes what its write left."""
    pool.shutdown(wait=False, cancel_futures=True)
    children = multiprocessing.active_children()
    for p in children:
        p.terminate()
    deadline = time.monotonic() + TERMINATE_GRACE_S
    for p in children:
        p.join(timeout=max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join()


def _failed(item: BatchItem, cfg: FillConfig, out: OutputSpec, reason: str) -> dict[str, Any]:
    """The record of an item that no worker could finish."""
    return run_item(replace(item, error=f"{item.where}: {reason}"), cfg, out)


@contextmanager
def _ray_session(address: str, jobs: int) -> Iterator[Any]:
    """The ``ray`` module, connected to ``address`` (``local``: a new instance with ``jobs`` CPUs);
    a session this opened is shut down after the block."""
    try:
        import ray
    except ImportError as exc:
        raise ConfigError("--ray needs Ray: pip install 'geofill[ray]'") from exc
    if ray.is_initialized():
        yield ray
        return
    runtime_env = {"env_vars": SINGLE_THREAD_ENV}
    if address == "local":
        ray.init(num_cpus=jobs, runtime_env=runtime_env, include_dashboard=False, log_to_driver=False)
    else:
        try:
            ray.init(address=address, runtime_env=runtime_env, log_to_driver=False)
        except ConnectionError as exc:
            raise ConfigError(f"--ray {address}: no Ray cluster to connect to ({exc})") from exc
    try:
        yield ray
    finally:
        ray.shutdown()


def _run_ray(ray: Any, tasks: Sequence[Task], out: OutputSpec, on_record: OnRecord) -> None:
    """Every item as a Ray task (Ray schedules them and runs a task again when its worker dies);
    worker processes are reused between tasks, so imports and compiled kernels stay warm. Workers
    read the inputs from their paths and write the outputs themselves: the paths must be reachable
    from every node (a shared file system)."""
    remote = ray.remote(num_cpus=1, max_retries=RAY_MAX_RETRIES)(run_item_on_ray)
    refs = {remote.remote(item, cfg, out): (item, cfg) for item, cfg in tasks}
    pending = list(refs)
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                try:
                    record = ray.get(ref)
                except ray.exceptions.RayError as exc:  # retries used up
                    item, cfg = refs[ref]
                    record = _failed(item, cfg, out, f"Ray task failed: {str(exc).splitlines()[0]}")
                on_record(record)
    except STOPPED:
        for ref in pending:
            ray.cancel(ref)
        raise
