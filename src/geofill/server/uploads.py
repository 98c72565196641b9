"""Streaming a ``multipart/form-data`` fill request into the server's own folder, with byte limits.

Hand-written around python-multipart's streaming parser (the one Starlette uses) rather than
through FastAPI's ``UploadFile``: Starlette spools every upload over 1 MB to the system's temporary
folder, and the server must write nothing outside its own; here each file goes straight to a
server-chosen name in the job's folder and the limits are checked while the bytes arrive."""

from __future__ import annotations

import re
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from python_multipart.multipart import MultipartParser, parse_options_header

from .worker import MASK_FILE, TARGET_FILE, source_file, source_mask_file

#: Largest text field (the config JSON), bytes.
MAX_FIELD_BYTES = 64 * 1024
#: The form field of reference ``k``'s mask (1-based, the order of the ``sources`` fields).
SOURCE_MASK_FIELD = "source_mask_{}"
_SOURCE_MASK = re.compile(r"source_mask_([1-9][0-9]{0,2})")


class UploadError(Exception):
    """A request the server refuses; ``status`` is the HTTP status to answer with."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


@dataclass
class ParsedUpload:
    """Where each part of the form went: files by role, the config text."""

    files: dict[str, Path] = field(default_factory=dict)  # "target", "mask", "source-1", "source-mask-1", ...
    n_sources: int = 0
    source_masks: set[int] = field(default_factory=set)  # k of each source_mask_k received
    config_text: str | None = None


async def receive_fill_form(
    stream: AsyncIterator[bytes],
    content_type: str,
    folder: Path,
    *,
    max_file_bytes: int,
    max_request_bytes: int,
    max_sources: int,
) -> ParsedUpload:
    """Parse the body of ``POST /api/v1/fill`` into ``folder``; raise UploadError (4xx) on anything
    malformed or over a limit."""
    ctype, params = parse_options_header(content_type)
    boundary = params.get(b"boundary")
    if ctype != b"multipart/form-data" or not boundary:
        raise UploadError(415, "the request must be multipart/form-data with a boundary")
    out = ParsedUpload()
    state: dict = {"headers": {}, "field": b"", "value": b""}
    current: dict = {}

    def on_header_field(data: bytes, start: int, end: int) -> None:
        state["field"] += data[start:end]

    def on_header_value(data: bytes, start: int, end: int) -> None:
        state["value"] += data[start:end]

    def on_header_end() -> None:
        state["headers"][state["field"].lower()] = state["value"]
        state["field"], state["value"] = b"", b""

    def on_headers_finished() -> None:
        _, options = parse_options_header(state["headers"].get(b"content-disposition", b""))
        state["headers"] = {}
        name = options.get(b"name", b"").decode("latin-1")
        is_file = b"filename" in options
        current.clear()
        current.update(name=name, size=0, sink=None, text=b"")
        if name == "config":  # a text field, or a JSON file (curl -F config=@fill.json)
            if out.config_text is not None:
                raise UploadError(400, "the form field 'config' is given twice")
            return
        masked = _SOURCE_MASK.fullmatch(name)
        if name not in ("target", "mask", "sources") and not (masked and int(masked[1]) <= max_sources):
            raise UploadError(
                400,
                f"unknown form field '{name[:40]}' (expected target, mask, sources, "
                f"source_mask_1 ... source_mask_{max_sources}, config)",
            )
        if not is_file:
            raise UploadError(400, f"the form field '{name}' must be a file")
        if masked:
            k = int(masked[1])
            if k in out.source_masks:
                raise UploadError(400, f"the form field '{name}' is given twice")
            out.source_masks.add(k)
            role = source_mask_file(k)
        elif name == "sources":
            if out.n_sources >= max_sources:
                raise UploadError(413, f"too many references: at most {max_sources} (max_sources)")
            out.n_sources += 1
            role = source_file(out.n_sources)
        else:
            role = TARGET_FILE if name == "target" else MASK_FILE
            if role in out.files:
                raise UploadError(400, f"the form field '{name}' is given twice")
        out.files[role] = folder / role  # a name the server chose, never the client's filename
        sink: IO[bytes] = open(out.files[role], "wb")
        current["sink"] = sink
        current["label"] = name if name != "sources" else f"sources[{out.n_sources}]"

    def on_part_data(data: bytes, start: int, end: int) -> None:
        current["size"] += end - start
        if current["sink"] is None:
            if current["size"] > MAX_FIELD_BYTES:
                raise UploadError(413, f"the config field is over {MAX_FIELD_BYTES} bytes")
            current["text"] += data[start:end]
            return
        if current["size"] > max_file_bytes:
            raise UploadError(
                413, f"{current['label']} is larger than the upload limit of {max_file_bytes} bytes"
            )
        current["sink"].write(data[start:end])

    def on_part_end() -> None:
        if current.get("sink") is not None:
            current["sink"].close()
            current["sink"] = None
        elif current.get("name") == "config":
            try:
                out.config_text = current["text"].decode("utf-8")
            except UnicodeDecodeError as exc:
                raise UploadError(422, "config: not UTF-8 text") from exc

    callbacks = {
        "on_header_field": on_header_field,
        "on_header_value": on_header_value,
        "on_header_end": on_header_end,
        "on_headers_finished": on_headers_finished,
        "on_part_data": on_part_data,
        "on_part_end": on_part_end,
    }
    parser = MultipartParser(boundary, callbacks)
    received = 0
    try:
        async for chunk in stream:
            received += len(chunk)
            if received > max_request_bytes:
                raise UploadError(413, f"the request is larger than the limit of {max_request_bytes} bytes")
            parser.write(chunk)
        parser.finalize()
    except UploadError:
        raise
    except (ValueError, UnicodeError) as exc:  # python-multipart's MultipartParseError is a ValueError
        raise UploadError(400, f"malformed multipart body: {exc}") from exc
    finally:
        if current.get("sink") is not None:
            current["sink"].close()
    for role, name in ((TARGET_FILE, "target"), (MASK_FILE, "mask")):
        if role not in out.files:
            raise UploadError(400, f"the form field '{name}' (a file) is missing")
    if out.n_sources == 0:
        raise UploadError(400, "at least one reference photo is needed (form field 'sources')")
    for k in sorted(out.source_masks):
        if k > out.n_sources:
            raise UploadError(
                400,
                f"{SOURCE_MASK_FIELD.format(k)}: a mask for sources[{k}], but {out.n_sources} reference "
                f"photo(s) given",
            )
    return out
