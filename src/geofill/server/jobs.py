"""Fill jobs: a bounded queue, a bounded pool of reusable worker processes, per-job folders inside
the server's own temporary folder, cancellation and expiry.

One thread per worker slot takes the oldest queued job, hands it to its worker process and relays
the process's stage messages into the job until it is done; Cancel (or shutdown) terminates the
process, and the slot starts a fresh one."""

from __future__ import annotations

import multiprocessing
import os
import secrets
import shutil
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from multiprocessing.connection import wait
from pathlib import Path
from typing import Any

from ..progress import STAGE_WORDS
from .worker import COVERAGE_FILE, RESULT_AS_UPLOADED, RESULT_FILE, JobSpec, worker_main

#: Stage messages and notes kept per job (a runaway pipeline cannot grow a job without bound).
MAX_NOTES = 200
#: The files a finished job keeps (the client may still download them); its uploads are deleted.
KEPT_FILES = frozenset({RESULT_FILE, COVERAGE_FILE, *RESULT_AS_UPLOADED.values()})
#: Why a request is refused when finished jobs' files cannot make room.
DISK_FULL = "the server's disk space for jobs is full"
#: How often (s) a slot checks for Cancel while its worker is busy (messages wake it at once).
POLL_S = 0.2
#: A slot starts its worker process this long after the server starts, or when the first job comes
#: if sooner: started together, the worker's imports (another process on the same two cores) made
#: the page 0.02 s later (0.29 -> 0.27 s until it is served, `benchmarks/speed/whole_process.py`), and a
#: first fill rarely comes within a second of the start.
WORKER_START_DELAY_S = 1.0


def default_workers() -> int:
    """One fill per 2 cores: the pipeline's OpenCV/numba/torch stages use about two cores each."""
    return max(1, (os.cpu_count() or 2) // 2)


@dataclass(frozen=True)
class ServerSettings:
    """Limits of one server. Sizes in bytes, times in seconds, images in pixels (width x height)."""

    workers: int = field(default_factory=default_workers)
    queue_size: int = 8  # jobs waiting for a worker; more is a 429
    job_ttl_s: float = 3600.0  # a finished job and its files are deleted this long after it ends
    max_upload_bytes: int = 50 * 1024 * 1024  # per uploaded file
    max_request_bytes: int = 200 * 1024 * 1024  # a whole POST body
    max_pixels: int = 40_000_000  # per image (target, mask, each reference)
    max_sources: int = 8
    temp_parent: str | None = None  # where the server's own temporary folder is made (None: system's)
    # The most a request may set each cost key to (``geofill serve --cap``); a key not here is capped
    # at the server's config value (:func:`geofill.server.schema.server_caps`).
    caps: Mapping[str, float] = field(default_factory=dict)
    # Files of all jobs together: over it, the oldest finished jobs' results are deleted; with none
    # left to delete, a new request is a 429. (Uploads still arriving are bounded apart from it, by
    # queue_size x max_request_bytes.)
    disk_cap_bytes: int = 2 * 1024**3


class QueueFullError(Exception):
    """The queue holds ``queue_size`` jobs (or reserved places) already, or the disk cap is reached
    by jobs that are not finished."""


@dataclass
class Job:
    """One fill request and what is known about it; changed only under the manager's lock."""

    id: str
    folder: Path
    spec: JobSpec
    created: float
    state: str = "queued"  # queued | running | done | failed | cancelled
    stage: str = ""
    stages_seen: list[str] = field(default_factory=list)
    fraction: float = 0.0  # of the fill done, from the worker, never decreasing
    notes: list[str] = field(default_factory=list)
    summary: dict[str, Any] | None = None
    error: str | None = None
    error_kind: str | None = None
    finished: float | None = None
    cancel: threading.Event = field(default_factory=threading.Event)
    disk_bytes: int = 0  # of the files in its folder
    evicted: str | None = None  # why its files were deleted before it expired

    def public(self) -> dict[str, Any]:
        """The job as ``GET /api/v1/jobs/{id}`` shows it."""
        progress = 1.0 if self.state == "done" else self.fraction
        out: dict[str, Any] = {
            "id": self.id,
            "state": self.state,
            "stage": self.stage,
            "stage_text": STAGE_WORDS.get(self.stage, self.stage),
            "stages_done": [s for s in self.stages_seen if s != self.stage or self.state != "running"],
            "progress": round(progress, 3),
            "notes": list(self.notes),
            "error": self.error,
            "error_kind": self.error_kind,
            "evicted": self.evicted,
        }
        if self.summary is not None:
            out.update(self.summary)
        return out


def _folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.iterdir()) if folder.is_dir() else 0


class Place:
    """A queue place held for one request (:meth:`JobManager.reserve`): :meth:`submit` turns it into
    a job; :meth:`release` (a no-op after submit) gives it back on any error."""

    def __init__(self, manager: JobManager) -> None:
        self._manager: JobManager | None = manager

    def submit(
        self, folder: Path, n_sources: int, config: dict[str, Any], source_masks: tuple[int, ...] = ()
    ) -> Job:
        """Queue a job whose inputs are in ``folder`` (moved into the job's own folder);
        ``source_masks``: the references (1-based) whose mask was uploaded."""
        assert self._manager is not None, "this place was used already"
        job = self._manager._submit(folder, n_sources, config, source_masks)
        self._manager = None
        return job

    def release(self) -> None:
        if self._manager is not None:
            self._manager._unreserve()
            self._manager = None


class _Worker:
    """A worker process and the parent's end of its pipe."""

    def __init__(self, ctx: multiprocessing.context.BaseContext) -> None:
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=worker_main, args=(child,), daemon=True, name="geofill-fill")
        self.process.start()
        child.close()

    def kill(self) -> None:
        self.process.terminate()
        self.process.join(5)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.conn.close()

    def stop(self) -> None:
        try:
            self.conn.send(None)
        except OSError:
            pass
        self.process.join(2)
        if self.process.is_alive():
            self.kill()
        else:
            self.conn.close()


class JobManager:
    """Queue, workers, job folders under ``root`` (created by the caller, owned by the manager)."""

    def __init__(self, settings: ServerSettings, root: Path, clock: Callable[[], float] = time.monotonic):
        self.settings = settings
        self.root = root
        self.clock = clock
        self._jobs: dict[str, Job] = {}
        self._queue: deque[Job] = deque()
        self._cv = threading.Condition()
        self._stopping = False
        self._stopped = threading.Event()  # wakes the expiry thread at shutdown
        self._ctx = multiprocessing.get_context("spawn")  # fork would copy the server's threads
        self._threads: list[threading.Thread] = []
        self._workers: dict[str, _Worker] = {}  # slot thread name -> its current worker
        self._reserved = 0  # queue places held by requests still uploading

    # ---- lifecycle

    def start(self) -> None:
        for i in range(self.settings.workers):
            t = threading.Thread(target=self._slot_loop, name=f"geofill-slot-{i}", daemon=True)
            t.start()
            self._threads.append(t)
        reaper = threading.Thread(target=self._reap_loop, name="geofill-expiry", daemon=True)
        reaper.start()
        self._threads.append(reaper)

    def stop(self) -> None:
        """Cancel everything, stop the workers, delete every job folder."""
        with self._cv:
            self._stopping = True
            self._stopped.set()
            for job in self._jobs.values():
                job.cancel.set()
            self._cv.notify_all()
        for t in self._threads:
            t.join(10)
        with self._cv:
            for job in list(self._jobs.values()):
                self._delete(job)

    # ---- requests

    def new_folder(self) -> Path:
        """A fresh folder for an upload in progress, named randomly inside the server's folder."""
        folder = self.root / f"upload-{secrets.token_hex(8)}"
        folder.mkdir()
        return folder

    def reserve(self) -> Place:
        """Hold a queue place before the request's body is read: its uploads are stored and decoded
        only once the place is held. QueueFullError when the queue (with the places held) is full,
        or the disk cap is reached with no finished job's files left to delete."""
        with self._cv:
            if self._stopping or len(self._queue) + self._reserved >= self.settings.queue_size:
                raise QueueFullError("the queue is full")
            if not self._make_room():
                raise QueueFullError(DISK_FULL)
            self._reserved += 1
            return Place(self)

    def _unreserve(self) -> None:
        with self._cv:
            self._reserved -= 1

    def _submit(
        self, folder: Path, n_sources: int, config: dict[str, Any], source_masks: tuple[int, ...]
    ) -> Job:
        with self._cv:
            if self._stopping:
                raise QueueFullError("the server is stopping")
            job_id = secrets.token_urlsafe(24)  # 192 random bits: not guessable
            job_folder = self.root / job_id
            folder.rename(job_folder)
            spec = JobSpec(str(job_folder), n_sources, config, source_masks)
            job = Job(job_id, job_folder, spec, self.clock(), disk_bytes=_folder_bytes(job_folder))
            self._jobs[job_id] = job
            if not self._make_room():
                del self._jobs[job_id]
                job_folder.rename(folder)  # the caller deletes it
                raise QueueFullError(DISK_FULL)
            self._queue.append(job)
            self._reserved -= 1
            self._cv.notify_all()
            return job

    def get(self, job_id: str) -> Job | None:
        with self._cv:
            return self._jobs.get(job_id)

    def snapshot(self, job_id: str) -> dict[str, Any] | None:
        with self._cv:
            job = self._jobs.get(job_id)
            return None if job is None else job.public()

    def cancel(self, job_id: str) -> dict[str, Any] | None:
        """Cancel a queued or running job; delete a finished one now. None if unknown."""
        with self._cv:
            job = self._jobs.get(job_id)
            if job is None:
                return None
            if job.state == "queued":
                self._queue.remove(job)
                self._finish(job, "cancelled")
            elif job.state == "running":
                job.cancel.set()  # the slot terminates the worker and marks the job cancelled
                self._cv.wait_for(lambda: job.state != "running", timeout=10)
            else:
                self._delete(job)
            return job.public()

    def expire(self) -> int:
        """Delete jobs that finished ``job_ttl_s`` ago or more; return how many."""
        with self._cv:
            now = self.clock()
            old = [
                j
                for j in self._jobs.values()
                if j.finished is not None and now - j.finished >= self.settings.job_ttl_s
            ]
            for job in old:
                self._delete(job)
            return len(old)

    def disk_bytes(self) -> int:
        """Bytes of every job's files (as the disk cap counts them)."""
        with self._cv:
            return sum(j.disk_bytes for j in self._jobs.values())

    def worker_pids(self) -> list[int]:
        """Process ids of the worker processes alive now."""
        with self._cv:
            return [w.process.pid for w in self._workers.values() if w.process.is_alive()]

    def counts(self) -> dict[str, int]:
        with self._cv:
            out: dict[str, int] = {}
            for job in self._jobs.values():
                out[job.state] = out.get(job.state, 0) + 1
            return out

    # ---- internals (the lock is held by callers of _finish and _delete)

    def _finish(self, job: Job, state: str, error: str | None = None, kind: str | None = None) -> None:
        job.state, job.error, job.error_kind, job.finished = state, error, kind, self.clock()
        # The uploads are read: only what the client may still download (result, coverage) stays.
        for path in job.folder.iterdir() if job.folder.is_dir() else ():
            if path.name not in KEPT_FILES:
                path.unlink(missing_ok=True)
        job.disk_bytes = _folder_bytes(job.folder)
        self._make_room()
        self._cv.notify_all()

    def _make_room(self) -> bool:
        """Delete the oldest finished jobs' files until the disk cap holds; False if it cannot."""
        finished = sorted(
            (j for j in self._jobs.values() if j.finished is not None and j.disk_bytes),
            key=lambda j: j.finished,
        )
        held = sum(j.disk_bytes for j in self._jobs.values())
        for job in finished:
            if held <= self.settings.disk_cap_bytes:
                break
            shutil.rmtree(job.folder, ignore_errors=True)
            held -= job.disk_bytes
            job.disk_bytes = 0
            job.evicted = (
                f"its files were deleted to keep this server's jobs under their disk cap of "
                f"{self.settings.disk_cap_bytes / 2**20:.0f} MiB; run the fill again"
            )
        return held <= self.settings.disk_cap_bytes

    def _delete(self, job: Job) -> None:
        self._jobs.pop(job.id, None)
        shutil.rmtree(job.folder, ignore_errors=True)

    def _take(self) -> Job | None:
        with self._cv:
            self._cv.wait_for(lambda: self._queue or self._stopping)
            if self._stopping:
                return None
            job = self._queue.popleft()
            job.state = "running"
            return job

    def _slot_loop(self) -> None:
        slot = threading.current_thread().name
        with self._cv:  # started ahead of the first job, so that it finds the worker warm
            self._cv.wait_for(lambda: self._queue or self._stopping, timeout=WORKER_START_DELAY_S)
            stopping = self._stopping
        worker: _Worker | None = None if stopping else self._new_worker(slot)
        try:
            while (job := self._take()) is not None:
                worker = worker or self._new_worker(slot)
                worker = self._run(worker, job)
        finally:
            if worker is not None:
                worker.stop()

    def _new_worker(self, slot: str) -> _Worker:
        worker = _Worker(self._ctx)
        with self._cv:
            self._workers[slot] = worker
        return worker

    def _run(self, worker: _Worker, job: Job) -> _Worker | None:
        """Run ``job`` on ``worker``; return the worker if it can take another job."""
        try:
            worker.conn.send(job.spec)
        except OSError:
            pass  # a dead worker shows as such below
        while True:
            if job.cancel.is_set():
                worker.kill()
                with self._cv:
                    self._finish(job, "cancelled")
                return None
            ready = wait([worker.conn, worker.process.sentinel], timeout=POLL_S)
            if worker.conn in ready:
                try:
                    msg = worker.conn.recv()
                except (EOFError, OSError):
                    msg = None
            elif ready:  # the process ended without a word
                msg = None
            else:
                continue
            if msg is None:
                worker.kill()
                with self._cv:
                    code = worker.process.exitcode
                    self._finish(
                        job, "failed", f"the worker process ended unexpectedly (exit {code})", "crash"
                    )
                return None
            if self._relay(job, msg):
                return worker

    def _relay(self, job: Job, msg: tuple) -> bool:
        """Apply one worker message to ``job``; True when the job has ended."""
        kind = msg[0]
        with self._cv:
            if kind == "stage":
                job.stage = msg[1]
                job.stages_seen.append(msg[1])
            elif kind == "progress":
                job.fraction = max(job.fraction, msg[1])
            elif kind == "note" and len(job.notes) < MAX_NOTES:
                job.notes.append(msg[1].replace(f"{job.folder}{os.sep}", ""))
            elif kind == "done":
                job.summary = msg[1]
                job.stage = ""
                self._finish(job, "done")
                return True
            elif kind == "failed":
                self._finish(job, "failed", msg[2].replace(f"{job.folder}{os.sep}", ""), msg[1])
                return True
        return False

    def _reap_loop(self) -> None:
        period = min(max(self.settings.job_ttl_s / 4, 0.05), 30.0)
        while not self._stopped.wait(period):
            self.expire()
