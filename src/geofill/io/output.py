"""Writing outputs: the checks made before any work (:func:`check_output_path`,
:func:`check_output_dir`, :func:`file_ids` to keep an output off its inputs) and the atomic,
durable write of an image (:func:`write_image_atomic`, :func:`replace_durably`)."""

from __future__ import annotations

import os
import stat
import uuid
from collections.abc import Iterable
from glob import escape as glob_escape
from pathlib import Path

import numpy as np
from PIL import Image

from ..errors import ConfigError, OutputError
from .arrays import as_rgb_uint8
from .files import one_line, stat_mode
from .images import ImageMetadata

_WRITE_FORMATS: dict[str, tuple[str, dict]] = {
    # zlib level 1: on a 3840x2160 fill 0.39 s against 0.61 s at level 3 and 1.86 s at Pillow's
    # default 6 (1280x720: 0.05 / 0.07 / 0.26 s), for 9 % (23 %) more bytes than level 3 (6).
    ".png": ("PNG", {"compress_level": 1}),
    ".jpg": ("JPEG", {"quality": 95}),
    ".jpeg": ("JPEG", {"quality": 95}),
    ".webp": ("WEBP", {"quality": 95}),
    ".tif": ("TIFF", {"compression": "tiff_adobe_deflate"}),
    ".tiff": ("TIFF", {"compression": "tiff_adobe_deflate"}),
}

#: Output extensions whose encoders are lossy (and take a quality): the pixels outside the hole
#: change too.
LOSSY_SUFFIXES = frozenset(ext for ext, (_, options) in _WRITE_FORMATS.items() if "quality" in options)

FileId = tuple[int, int]


def file_id(path: str | os.PathLike) -> FileId | None:
    """(device, inode) of what ``path`` names, links followed; None when it does not exist. Equal
    ids are the same file however it is spelt (``./a.png``, ``d/../a.png``, a link, another case
    of the name on a case-insensitive file system)."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def file_ids(paths: Iterable[str | os.PathLike]) -> dict[FileId, Path]:
    """The ids of the existing ``paths``, each to the first path given for it."""
    ids: dict[FileId, Path] = {}
    for p in paths:
        key = file_id(p)
        if key is not None:
            ids.setdefault(key, Path(p))
    return ids


def check_output_path(path: str | os.PathLike) -> None:
    """Raise OutputError now, before any work, if ``path`` cannot be written: unsupported extension
    (png, jpg, jpeg, webp, tif, tiff), missing or non-writable folder, a directory in its place, or
    a name too long for the folder's file system once the temporary-file affixes are added."""
    p = Path(path)
    if p.suffix.lower() not in _WRITE_FORMATS:
        known = ", ".join(ext.lstrip(".") for ext in _WRITE_FORMATS)
        raise OutputError(f"{p}: unsupported output extension '{p.suffix}' (use one of {known})")
    _check_writable_folder(p, p.parent, "output folder")
    _check_name_length(p, _temp_path(p).name)
    if stat_mode(p, OutputError) is not None and stat.S_ISDIR(stat_mode(p, OutputError)):
        raise OutputError(f"{p}: is a directory")


def check_output_dir(path: str | os.PathLike) -> None:
    """Raise OutputError now, before any work, if ``path`` cannot be a folder geofill writes files
    into (``--debug-dir``): an existing file, a name too long, or a nearest existing parent that is
    not a writable folder."""
    p = Path(path)
    mode = stat_mode(p, OutputError)
    if mode is not None:
        if not stat.S_ISDIR(mode):
            raise OutputError(f"{p}: exists and is not a directory")
        _check_writable_folder(p, p, "folder")
        return
    parent = p.parent
    while stat_mode(parent, OutputError) is None and parent != parent.parent:
        parent = parent.parent
    _check_writable_folder(p, parent, "parent folder")
    for part in p.parts:
        _check_name_length(p, part)


def _check_writable_folder(p: Path, folder: Path, what: str) -> None:
    mode = stat_mode(folder, OutputError)
    if mode is None or not stat.S_ISDIR(mode):
        raise OutputError(f"{p}: {what} {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"{p}: {what} {folder} is not writable")


def _check_name_length(p: Path, name: str) -> None:
    folder = next((f for f in p.parents if stat_mode(f, OutputError) is not None), Path("."))
    try:
        name_max = os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        name_max = 255  # the limit of every common file system
    if len(os.fsencode(name)) > name_max:
        raise OutputError(
            f"{p}: file name too long ({len(os.fsencode(p.name))} bytes; the limit here is "
            f"{name_max - (len(os.fsencode(name)) - len(os.fsencode(p.name)))} bytes)"
        )


def _temp_path(p: Path) -> Path:
    # A hidden name unique to this call; short affixes leave the longest possible output name.
    return p.with_name(f".{p.name}.{uuid.uuid4().hex[:12]}.tmp")


def remove_partial_writes(path: str | os.PathLike) -> None:
    """Delete the temporary files of writes of ``path`` that a killed process left behind (a write
    that only raised removes its own)."""
    p = Path(path)
    for tmp in p.parent.glob(f".{glob_escape(p.name)}.*.tmp"):
        tmp.unlink(missing_ok=True)


def write_image_atomic(
    path: str | os.PathLike,
    rgb: np.ndarray,
    *,
    metadata: ImageMetadata | None = None,
    quality: int | None = None,
) -> None:
    """Write an image so that ``path`` holds either its old content or the complete new image.

    The image (any array :func:`as_rgb_uint8` accepts) is encoded into a temporary file in the same
    folder, then moved over ``path`` with ``os.replace`` (atomic within a file system); the format
    follows the extension. ``quality`` (1-100, JPEG and WebP only) sets the lossy encoders'
    quality; without it a JPEG is written with the quantisation tables and subsampling of
    ``metadata.jpeg_tables`` (those of a JPEG input) where given, else at quality 95 like a WebP.
    ``metadata``'s EXIF and ICC profile are embedded. The file and its folder are flushed to disk
    (:func:`replace_durably`), so the new image survives a power cut once this returns. Nothing is
    left behind on failure or on an exception raised mid-write (a SIGTERM turned into one by the
    CLI).
    Raises OutputError, ConfigError for a ``quality`` the format does not take (and
    ArrayFormatError for an unsupported array)."""
    check_output_path(path)
    p = Path(path)
    pil_format, options = _WRITE_FORMATS[p.suffix.lower()]
    if quality is not None:
        if "quality" not in options:
            raise ConfigError(f"{p}: --quality applies to JPEG and WebP output only, not {pil_format}")
        if not 1 <= quality <= 100:
            raise ConfigError(f"{p}: quality must be in [1, 100], got {quality}")
        options = options | {"quality": quality}
    elif pil_format == "JPEG" and metadata is not None and metadata.jpeg_tables is not None:
        tables = metadata.jpeg_tables
        options = {"qtables": [list(t) for t in tables.qtables], "subsampling": tables.subsampling}
    if metadata is not None:
        options = options | {
            k: v for k, v in (("exif", metadata.exif), ("icc_profile", metadata.icc_profile)) if v
        }
    image = Image.fromarray(as_rgb_uint8(rgb, name=str(p)))
    # "xb" refuses to reuse an existing file and, unlike tempfile.mkstemp (mode 0600), creates it
    # with the permissions the umask gives a normal file.
    tmp = _temp_path(p)
    try:
        with open(tmp, "xb") as fh:
            image.save(fh, format=pil_format, **options)
        replace_durably(tmp, p)
    except OSError as exc:
        raise OutputError(f"{p}: cannot write image ({one_line(exc)})") from exc
    finally:
        tmp.unlink(missing_ok=True)


def replace_durably(tmp: Path, dest: Path) -> None:
    """Move the complete file ``tmp`` over ``dest`` so that a power cut leaves one or the other.

    ``os.replace`` alone survives a killed process, not a power cut: the file system may commit the
    rename before the file's data, leaving ``dest`` empty or torn. So the data is flushed to disk
    first, and the folder (which holds the name) after the rename. The cost, measured in
    docs/architecture.md, is a few milliseconds per file on a local disk."""
    fd = os.open(tmp, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, dest)
    folder = os.open(dest.parent, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(folder)
    finally:
        os.close(folder)
