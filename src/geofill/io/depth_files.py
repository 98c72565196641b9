"""User-supplied depth maps (``--depth-file``): npy, 16/8-bit PNG, TIFF, EXR (the ``exr`` extra).
Each reader checks the size from the file header before decoding."""

from __future__ import annotations

import math
import os
import stat
from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import Image

from ..errors import ConfigError, DepthFileError
from ..extras import require
from .arrays import wxh
from .files import DECODE_ERRORS, one_line, stat_mode


def read_depth_file(
    path: str | os.PathLike, *, expected_size: tuple[int, int], scale: float = 1.0
) -> np.ndarray:
    """Read a user-supplied depth (or inverse-depth / disparity) map as float32 HxW.

    Formats by extension: ``.npy`` (any real dtype), ``.png`` (16-bit or 8-bit grey), ``.tif`` /
    ``.tiff`` (float or integer samples, via tifffile), ``.exr`` (float; needs the optional
    ``geofill[exr]`` extra, the OpenEXR package; channel Z, depth, Y or R, or the only one).
    ``expected_size`` is the (width, height) of the image the map belongs to, checked from the file
    header before decoding. Values are multiplied by ``scale``; 0 and non-finite values become NaN
    (invalid). Raises DepthFileError (missing, unreadable, corrupt, wrong size, more than one
    channel, EXR without the extra); ConfigError for a ``scale`` that is not finite and > 0."""
    p = Path(path)
    if not (math.isfinite(scale) and scale > 0):
        raise ConfigError(f"depth file scale must be a finite number > 0, got {scale}")
    mode = stat_mode(p, DepthFileError)
    if mode is not None and stat.S_ISDIR(mode):
        raise DepthFileError(f"{p}: is a directory, not a depth file")
    if mode is None or not stat.S_ISREG(mode):
        raise DepthFileError(f"{p}: depth file not found")
    reader = _DEPTH_READERS.get(p.suffix.lower())
    if reader is None:
        raise DepthFileError(f"{p}: unsupported depth file extension '{p.suffix}' (use npy, png, tif, exr)")
    width, height = expected_size
    try:
        raw = reader(p, (int(height), int(width)))
    except (*DECODE_ERRORS, Image.DecompressionBombError) as exc:
        raise DepthFileError(f"{p}: cannot read depth map ({one_line(exc)})") from exc
    if raw.ndim == 3 and raw.shape[2] == 1:
        raw = raw[..., 0]
    if raw.ndim != 2:
        raise DepthFileError(f"{p}: expected a single-channel depth map, got array shape {raw.shape}")
    if raw.dtype.kind not in "uif":
        raise DepthFileError(f"{p}: depth values must be numbers, got dtype {raw.dtype}")
    with np.errstate(over="ignore", invalid="ignore"):  # beyond float32 becomes inf, then invalid
        depth = raw.astype(np.float32) * np.float32(scale)
    depth[~np.isfinite(depth) | (depth == 0)] = np.nan
    return depth


def _check_depth_size(path: Path, shape: tuple[int, ...], expected_hw: tuple[int, int]) -> None:
    if len(shape) < 2:
        raise DepthFileError(f"{path}: expected a 2-D depth map, got array shape {tuple(shape)}")
    if tuple(shape[:2]) != expected_hw:
        raise DepthFileError(
            f"{path}: depth map is {wxh(shape)} but the image it belongs to is {wxh(expected_hw)}"
        )


def _depth_npy(path: Path, expected_hw: tuple[int, int]) -> np.ndarray:
    data = np.load(path, mmap_mode="r", allow_pickle=False)  # memory-mapped: header only so far
    _check_depth_size(path, data.shape, expected_hw)
    return np.asarray(data)


def _depth_png(path: Path, expected_hw: tuple[int, int]) -> np.ndarray:
    with Image.open(path, formats=["PNG"]) as img:
        _check_depth_size(path, img.size[::-1], expected_hw)
        if img.mode not in ("I;16", "I;16B", "I", "L"):
            raise DepthFileError(f"{path}: expected a 16-bit or 8-bit grey PNG, got mode {img.mode}")
        return np.asarray(img)


def _depth_tiff(path: Path, expected_hw: tuple[int, int]) -> np.ndarray:
    import tifffile

    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        _check_depth_size(path, page.shape if not page.axes.startswith("S") else page.shape[1:], expected_hw)
        return page.asarray()


def _depth_exr(path: Path, expected_hw: tuple[int, int]) -> np.ndarray:
    # The OpenEXR package rather than OpenCV: cv2 reads EXR only when OPENCV_IO_ENABLE_OPENEXR was set
    # before its first import, which a library imported after cv2 cannot arrange.
    OpenEXR = require("OpenEXR", f"{path}: reading EXR")
    try:
        header = OpenEXR.File(str(path), header_only=True).header()
        low, high = header["dataWindow"]
        _check_depth_size(path, (int(high[1] - low[1] + 1), int(high[0] - low[0] + 1)), expected_hw)
        channels = OpenEXR.File(str(path), separate_channels=True).channels()
    except RuntimeError as exc:  # OpenEXR reports every read failure as RuntimeError
        raise DepthFileError(f"{path}: cannot read EXR ({one_line(exc)})") from exc
    names = list(channels)
    if len(names) != 1:
        wanted = [n for want in ("Z", "DEPTH", "Y", "R") for n in names if n.split(".")[-1].upper() == want]
        if not wanted:
            raise DepthFileError(f"{path}: no depth channel (Z, depth, Y or R) among {names}")
        names = wanted
    return channels[names[0]].pixels


_DEPTH_READERS: dict[str, Callable[[Path, tuple[int, int]], np.ndarray]] = {
    ".npy": _depth_npy,
    ".png": _depth_png,
    ".tif": _depth_tiff,
    ".tiff": _depth_tiff,
    ".exr": _depth_exr,
}
