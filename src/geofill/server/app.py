"""The FastAPI application: the REST API under ``/api/v1``, the page at ``/``, OpenAPI at ``/docs``.

Everything the page and the docs need is served by the app itself (no CDN): ``fastapi-offline``
serves the Swagger UI files it ships, the page is plain HTML/JS/CSS in ``static/``."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
import tempfile
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any, Literal

from fastapi import FastAPI, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline
from starlette.requests import ClientDisconnect

from ..config import FillConfig
from ..errors import ConfigError, GeoFillError, ImageTooLargeError
from ..progress import STAGE_WORDS
from .jobs import JobManager, QueueFullError, ServerSettings
from .schema import (
    COMMON_KEYS,
    apply_request_config,
    config_fields,
    config_sections,
    locked_keys,
    server_caps,
    value_at,
    with_config_schema,
)
from .uploads import SOURCE_MASK_FIELD, UploadError, receive_fill_form
from .worker import COVERAGE_FILE, RESULT_FILE, source_file, source_mask_file

#: Media type of each file a finished job serves, by extension.
_MEDIA_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".webp": "image/webp", ".tif": "image/tiff"}

STATIC = Path(__file__).parent / "static"
#: Job ids are ``secrets.token_urlsafe(24)``: anything else is unknown without a lookup.
_JOB_ID = re.compile(r"^[A-Za-z0-9_-]{32}$")
#: Seconds a client told 429 should wait: about one fill of a 1280x720 pair on 2 cores.
RETRY_AFTER_S = 20
#: The page loads nothing from elsewhere; blob: and data: are its own canvases and downloads.
PAGE_CSP = "default-src 'self'; img-src 'self' blob: data:; style-src 'self'; script-src 'self'"


#: The fields of ``POST /api/v1/fill``'s form, as OpenAPI describes them (see :func:`_fill_form`).
_FILL_FIELDS: dict[str, Any] = {
    "target": {"type": "string", "format": "binary", "description": "photo with the hole"},
    "mask": {
        "type": "string",
        "format": "binary",
        "description": "hole mask, target's size: pixel >= 127 (or alpha) is hole",
    },
    "sources": {
        "type": "array",
        "items": {"type": "string", "format": "binary"},
        "description": "reference photos of the same scene (repeat the field); "
        "sources[k] is the k-th one (from 1)",
    },
}
_CONFIG_FIELD: dict[str, Any] = {
    "config": {
        "type": "string",
        "description": "JSON object of FillConfig overrides, nested or dotted "
        '(e.g. {"depth": {"backend": "stereo"}}); see GET /api/v1/config',
    },
}


_NO_SUCH_JOB: dict[str, Any] = {"description": "no such job (never created, expired or deleted)"}
#: The errors of the routes that serve a job's files.
_JOB_FILE_ERRORS: dict[int | str, dict[str, Any]] = {
    404: _NO_SUCH_JOB,
    409: {"description": "the job has no result (queued, running, failed or cancelled)"},
    410: {"description": "the job's files were deleted to keep the server under its disk cap"},
}


def _fill_form(max_sources: int) -> dict[str, Any]:
    """The OpenAPI description of ``POST /api/v1/fill``'s form: one optional ``source_mask_k`` per
    reference this server takes."""
    masks = {
        SOURCE_MASK_FIELD.format(k): {
            "type": "string",
            "format": "binary",
            "description": f"optional mask of sources[{k}], that photo's size: pixel >= 127 (or alpha) "
            "is never copied into the hole (a passer-by, a parked car)",
        }
        for k in range(1, max_sources + 1)
    }
    schema = {
        "type": "object",
        "required": ["target", "mask", "sources"],
        "properties": {**_FILL_FIELDS, **masks, **_CONFIG_FIELD},
    }
    return {"requestBody": {"required": True, "content": {"multipart/form-data": {"schema": schema}}}}


def _error(status: int, message: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"detail": message}, status_code=status, headers=headers)


def _job_id_ok(job_id: str) -> bool:
    return bool(_JOB_ID.fullmatch(job_id))


def _validate_inputs(folder: Path, files: dict[str, Path], cfg: FillConfig, max_pixels: int) -> None:
    """Decode every upload and check the set as the CLI does; GeoFillError names the form field."""
    from ..io import read_image, read_mask, read_reference_mask, validate_pair

    target = read_image(files["target"], max_pixels=max_pixels, min_side=cfg.min_side_px).pixels
    mask = read_mask(files["mask"], max_pixels=max_pixels)
    k = 1
    while source_file(k) in files:
        source = read_image(files[source_file(k)], max_pixels=max_pixels, min_side=cfg.min_side_px).pixels
        validate_pair(
            target,
            mask,
            source,
            min_side=cfg.min_side_px,
            max_pixels=max_pixels,
            max_mask_fraction=cfg.max_mask_fraction,
            names=("target", "mask", f"sources[{k}]"),
        )
        if source_mask_file(k) in files:
            read_reference_mask(files[source_mask_file(k)], source, f"sources[{k}]", max_pixels=max_pixels)
        k += 1


def _field_names(message: str, folder: Path) -> str:
    """A message about a file in ``folder`` with the file named by its form field."""
    for k in range(64, 0, -1):
        message = message.replace(str(folder / source_mask_file(k)), SOURCE_MASK_FIELD.format(k))
        message = message.replace(str(folder / source_file(k)), f"sources[{k}]")
    return message.replace(str(folder / "target"), "target").replace(str(folder / "mask"), "mask")


def create_app(
    settings: ServerSettings | None = None,
    base_config: FillConfig | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> FastAPI:
    """The application; its lifespan owns the temporary folder and the worker pool (``app.state.jobs``
    while it runs). ``clock`` (seconds) dates jobs for their expiry. ConfigError when a cap of
    ``settings.caps`` is not a cost key or not a number."""
    settings = settings or ServerSettings()
    base = (base_config or FillConfig()).updated({"max_pixels": settings.max_pixels})
    base, caps = server_caps(base, settings.caps)
    state: dict[str, Any] = {}

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        root = Path(tempfile.mkdtemp(prefix="geofill-serve-", dir=settings.temp_parent))
        manager = JobManager(settings, root, clock)
        state["manager"] = app.state.jobs = manager
        manager.start()
        try:
            yield
        finally:
            manager.stop()
            shutil.rmtree(root, ignore_errors=True)

    app = FastAPIOffline(
        title="geofill",
        summary="Reference-based image inpainting: fill a hole in a photo from other photos of the scene.",
        version="1",
        lifespan=lifespan,
        redoc_url=None,
    )
    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    def manager() -> JobManager:
        return state["manager"]

    @app.get("/", include_in_schema=False)
    async def page() -> FileResponse:
        return FileResponse(STATIC / "index.html", headers={"Content-Security-Policy": PAGE_CSP})

    # The config's schema is built when the OpenAPI document is first asked for (FastAPI's
    # documented way of extending it): building its pydantic models took 0.05 s of every start.
    generate_openapi = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            app.openapi_schema = with_config_schema(generate_openapi(), "/api/v1/config")
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]

    @app.get("/api/v1/config", summary="The server's default fill config")
    async def get_config() -> dict[str, Any]:
        """Every key a fill request's ``config`` may override, with its default and meaning."""
        return base.to_dict()

    @app.get("/api/v1/config/fields", summary="The fill config as a flat list of fields (for forms)")
    async def get_fields() -> dict[str, Any]:
        """Each key with its kind, default, bounds (``range``: a number's, or each list item's;
        ``length``: a list's item count), this server's ``cap`` of a cost key (the most a request
        may set; ``zero_is_most``: 0 means no limit, over any cap but 0), choices and description;
        ``sections`` describes each section in pipeline order; ``common`` lists the keys a form
        offers first."""
        defaults = base.to_dict()
        rows = []
        for f in config_fields():
            rows.append(
                {
                    "key": f.key,
                    "section": f.section,
                    "kind": f.kind,
                    "default": value_at(defaults, f.key),
                    "optional": f.optional,
                    "choices": list(f.choices),
                    "description": f.description,
                    "locked": f.locked,
                    "range": dataclasses.asdict(f.range) if f.range else None,
                    "length": [f.length.lo, f.length.hi] if f.length else None,
                    "cap": caps.get(f.key),
                    "zero_is_most": bool(f.cost and f.cost.zero_is_most),
                }
            )
        return {
            "fields": rows,
            "sections": [{"key": k, "description": d} for k, d in config_sections()],
            "common": list(COMMON_KEYS),
            "locked": sorted(locked_keys()),
        }

    @app.get("/api/v1/limits", summary="Upload and queue limits of this server")
    async def get_limits() -> dict[str, Any]:
        return {
            "max_upload_bytes": settings.max_upload_bytes,
            "max_request_bytes": settings.max_request_bytes,
            "max_pixels": settings.max_pixels,
            "max_sources": settings.max_sources,
            "queue_size": settings.queue_size,
            "workers": settings.workers,
            "job_ttl_s": settings.job_ttl_s,
            "disk_cap_bytes": settings.disk_cap_bytes,
            "caps": caps,
            "stages": STAGE_WORDS,
        }

    @app.post(
        "/api/v1/fill",
        status_code=202,
        openapi_extra=_fill_form(settings.max_sources),
        summary="Start a fill",
        responses={
            202: {"description": "queued; poll the job"},
            400: {"description": "malformed request or input images"},
            413: {"description": "an upload over a byte or pixel limit (named)"},
            415: {"description": "the body is not multipart/form-data"},
            422: {"description": "bad config, or a cost over this server's cap (the key and cap are named)"},
            429: {"description": "the queue or the server's disk space for jobs is full; see Retry-After"},
        },
    )
    async def post_fill(request: Request) -> JSONResponse:
        """Upload ``target``, ``mask``, one or more ``sources``, an optional mask per source
        (``source_mask_k`` for the k-th ``sources`` file: what must never be copied from it) and an
        optional ``config`` JSON; the fill runs in the background. Poll ``GET /api/v1/jobs/{id}``."""
        jobs = manager()
        busy = {"Retry-After": str(RETRY_AFTER_S)}
        length = request.headers.get("content-length")
        if length is not None and (not length.isdigit() or int(length) > settings.max_request_bytes):
            return _error(413, f"the request is larger than the limit of {settings.max_request_bytes} bytes")
        # The place is held before a byte is stored or decoded, so that at most queue_size
        # requests are ever being read at once; it is given back on every error below.
        try:
            place = jobs.reserve()
        except QueueFullError as exc:
            return _error(429, f"{exc}; try again later", busy)
        folder = jobs.new_folder()
        try:
            form = await receive_fill_form(
                request.stream(),
                request.headers.get("content-type", ""),
                folder,
                max_file_bytes=settings.max_upload_bytes,
                max_request_bytes=settings.max_request_bytes,
                max_sources=settings.max_sources,
            )
            try:
                overrides = json.loads(form.config_text) if form.config_text else {}
            except json.JSONDecodeError as exc:
                raise UploadError(422, f"config: not valid JSON ({exc})") from exc
            cfg = apply_request_config(base, overrides, caps)
            await run_in_threadpool(_validate_inputs, folder, form.files, cfg, settings.max_pixels)
            job = place.submit(folder, form.n_sources, cfg.to_dict(), tuple(sorted(form.source_masks)))
        except UploadError as exc:
            shutil.rmtree(folder, ignore_errors=True)
            return _error(exc.status, str(exc))
        except ConfigError as exc:
            shutil.rmtree(folder, ignore_errors=True)
            return _error(422, str(exc))
        except ImageTooLargeError as exc:
            shutil.rmtree(folder, ignore_errors=True)
            return _error(413, _field_names(str(exc), folder))
        except GeoFillError as exc:
            shutil.rmtree(folder, ignore_errors=True)
            return _error(400, _field_names(str(exc), folder))
        except QueueFullError as exc:
            shutil.rmtree(folder, ignore_errors=True)
            return _error(429, f"{exc}; try again later", busy)
        except ClientDisconnect:
            shutil.rmtree(folder, ignore_errors=True)
            return _error(400, "the client went away during the upload")
        finally:
            place.release()
        return JSONResponse(
            {"id": job.id, "state": job.state, "url": f"/api/v1/jobs/{job.id}"},
            status_code=202,
            headers={"Location": f"/api/v1/jobs/{job.id}"},
        )

    def _unknown() -> JSONResponse:
        return _error(404, "no such job (it may have expired)")

    @app.get(
        "/api/v1/jobs/{job_id}",
        summary="State, stage, progress; the report when done",
        responses={404: _NO_SUCH_JOB},
    )
    async def get_job(job_id: str) -> JSONResponse:
        snap = manager().snapshot(job_id) if _job_id_ok(job_id) else None
        return _unknown() if snap is None else JSONResponse(snap)

    def _job_file(job_id: str, name: str) -> Response:
        job = manager().get(job_id) if _job_id_ok(job_id) else None
        if job is None:
            return _unknown()
        if job.state != "done":
            return _error(409, f"the job is {job.state}, it has no result")
        if job.evicted:
            return _error(410, f"this job's result is gone: {job.evicted}")
        path = job.folder / name
        if not path.is_file():  # expired between the lookup and now
            return _unknown()
        return FileResponse(
            path,
            media_type=_MEDIA_TYPES[path.suffix],
            filename=f"geofill-{path.name}",
            content_disposition_type="inline",
            headers={"Cache-Control": "no-store"},
        )

    @app.get(
        "/api/v1/jobs/{job_id}/result",
        summary="The filled image, full resolution: in the target's own format (a JPEG target at its "
        "own quality, EXIF and ICC kept), or lossless PNG with format=png",
        response_class=FileResponse,
        responses={
            200: {"content": {t: {} for t in sorted(set(_MEDIA_TYPES.values()))}},
            **_JOB_FILE_ERRORS,
        },
    )
    async def get_result(
        job_id: str,
        format: Literal["as_uploaded", "png"] = Query(
            "as_uploaded", description="as_uploaded: the target's own format; png: lossless PNG"
        ),
    ) -> Response:
        job = manager().get(job_id) if _job_id_ok(job_id) else None
        name = RESULT_FILE
        if format == "as_uploaded" and job is not None and job.summary is not None:
            name = job.summary.get("result_file", RESULT_FILE)
        return _job_file(job_id, name)

    @app.get(
        "/api/v1/jobs/{job_id}/coverage",
        summary="Who filled each hole pixel (RGBA PNG: a colour per reference, red = painted)",
        response_class=FileResponse,
        responses={200: {"content": {"image/png": {}}}, **_JOB_FILE_ERRORS},
    )
    async def get_coverage(job_id: str) -> Response:
        return _job_file(job_id, COVERAGE_FILE)

    @app.delete(
        "/api/v1/jobs/{job_id}",
        summary="Cancel a job (or delete a finished one now)",
        responses={404: _NO_SUCH_JOB},
    )
    async def delete_job(job_id: str) -> JSONResponse:
        snap = await run_in_threadpool(manager().cancel, job_id) if _job_id_ok(job_id) else None
        return _unknown() if snap is None else JSONResponse(snap)

    return app
