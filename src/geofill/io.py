"""Reading and validating the user's inputs (target, source, mask, optional depth map) and writing
outputs atomically.

Images come back as HxWx3 uint8 RGB with the EXIF orientation applied, masks as HxW bool (True =
hole). Every problem is a named exception of :mod:`geofill.errors` whose one-line message starts
with the file (or array) it is about.

Decoders: Pillow opens every image lazily, so its header gives the size for the pixel-limit check
before any pixel is decoded, and its EXIF gives the orientation and the lens tags. Pillow also
decodes the 8-bit images, except YCbCr and grey JPEGs: simplejpeg decodes those strictly (a scan
cut short is an error, not grey pixels). It reduces 16-bit colour to 8 bits by keeping the high byte (51200 ->
200 where round(51200 / 257) = 199 is right) and cannot decode float or 32-bit TIFF samples, so
16-bit PNGs go through OpenCV (libpng keeps all 16 bits) and deeper-than-8-bit TIFFs through
tifffile.
"""

from __future__ import annotations

import contextlib
import math
import os
import stat
import struct
import uuid
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import IO

import cv2
import numpy as np

# Image.open(formats=...) only tries plugins already registered; Pillow preloads JPEG and PNG but
# not TIFF or WebP, hence the two plugin imports.
from PIL import (
    ExifTags,
    Image,
    ImageOps,
    TiffImagePlugin,  # noqa: F401
    UnidentifiedImageError,
    WebPImagePlugin,  # noqa: F401
)

from .errors import (
    ArrayFormatError,
    ConfigError,
    CorruptImageError,
    DepthFileError,
    EmptyMaskError,
    ImageTooLargeError,
    ImageTooSmallError,
    MaskSizeError,
    MaskTooLargeError,
    MissingFileError,
    OutputError,
    UnreadableFileError,
)
from .extras import require

#: Pillow formats accepted as input. Restricting ``Image.open`` to these keeps Pillow's other
#: plugins (EPS runs Ghostscript, for one) away from user files. The JPEG opener also returns the
#: multi-picture JPEGs many cameras write (format "MPO").
INPUT_FORMATS = ("PNG", "JPEG", "WEBP", "TIFF")
#: ISO-BMFF major brands of HEIF images (HEIC from phones, plain HEIF).
_HEIF_BRANDS = {b"heic", b"heix", b"hevc", b"hevx", b"heim", b"heis", b"mif1", b"msf1"}
#: Mask pixels at or above this 8-bit value are hole (IOPaint's convention).
MASK_THRESHOLD = 127

# What a decoder raises on a damaged file: Pillow (OSError "image file is truncated", SyntaxError,
# ValueError, EOFError, struct.error) and tifffile (TiffFileError is a ValueError).
_DECODE_ERRORS = (OSError, ValueError, SyntaxError, EOFError, struct.error)
_ORIENTATION = ExifTags.Base.Orientation
# EXIF orientations that swap the stored image's width and height.
_TRANSPOSING_ORIENTATIONS = (5, 6, 7, 8)
# FocalPlaneResolutionUnit (0xA210) -> millimetres per unit. EXIF defines 2 = inch (also the
# default when the tag is absent) and 3 = cm; TIFF/EP adds 4 = mm and 5 = um. 1 (no absolute unit)
# gives no physical resolution.
_MM_PER_UNIT = {2: 25.4, 3: 10.0, 4: 1.0, 5: 1e-3}

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


@dataclass
class ExifCamera:
    """What EXIF says about the lens; None where absent or meaningless (0 means unknown in EXIF).

    The focal-plane resolutions and ``original_size`` are given in the orientation of the returned
    pixels: for an image whose EXIF orientation turns it by 90 degrees, x and y are swapped relative
    to the stored tags, so ``pixels.shape[1] / original_size[0]`` is always the horizontal scale."""

    focal_35mm: float | None = None  # FocalLengthIn35mmFilm (mm)
    focal_mm: float | None = None  # FocalLength (mm)
    focal_plane_x_res: float | None = None  # FocalPlaneXResolution, pixels per mm
    focal_plane_y_res: float | None = None  # FocalPlaneYResolution, pixels per mm
    original_size: tuple[int, int] | None = None  # (w, h) the focal-plane resolution refers to
    body: str | None = None  # Make, Model and LensModel, as one string

    @property
    def camera_id(self) -> tuple[str, float | None] | None:
        """Body and lens at the focal length used: equal for photos from the same camera setting
        (None when EXIF does not name the body)."""
        return (self.body, self.focal_mm) if self.body else None


@dataclass(frozen=True)
class ImageMetadata:
    """What an output carries over from its input file: the EXIF block (orientation reset to 1,
    since the pixels are delivered upright) and the ICC colour profile; None where absent.
    ``note`` says why EXIF present in the file could not be carried (never dropped silently)."""

    exif: bytes | None = None
    icc_profile: bytes | None = None
    note: str | None = None


@dataclass
class LoadedImage:
    """An input image as the pipeline sees it."""

    pixels: np.ndarray  # HxWx3 uint8 RGB, EXIF orientation applied
    path: str
    exif: ExifCamera = field(default_factory=ExifCamera)
    metadata: ImageMetadata = field(default_factory=ImageMetadata)


# --------------------------------------------------------------------------------------------
# Public API


#: File name extensions of the image formats geofill reads (``--sources DIR`` picks these).
IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".webp", ".tif", ".tiff", ".heic", ".heif"})


def read_image(path: str | os.PathLike, *, max_pixels: int = 60_000_000, min_side: int = 64) -> LoadedImage:
    """Read a PNG / JPEG / WebP / TIFF image as HxWx3 uint8 RGB with its EXIF orientation applied.

    Grey, grey+alpha, RGBA (alpha dropped), palette, CMYK and 16-bit images are converted; 16-bit
    values are scaled to 8 bits with rounding (``round(v * 255 / 65535)``), float TIFF samples are
    taken as [0, 1]. The pixel count (``max_pixels``) and the shorter side (``min_side``) are checked
    from the file header before any pixel is decoded.

    Raises MissingFileError, UnreadableFileError, CorruptImageError, ImageTooLargeError,
    ImageTooSmallError."""
    native, orientation, camera, metadata = _read_raster(path, max_pixels=max_pixels, min_side=min_side)
    rgb = _apply_orientation(as_rgb_uint8(native, name=str(path)), orientation)
    return LoadedImage(pixels=rgb, path=str(path), exif=camera, metadata=metadata)


def read_mask(path: str | os.PathLike, *, max_pixels: int = 60_000_000) -> np.ndarray:
    """Read a mask image as HxW bool, True = hole, EXIF orientation applied.

    The hole is where the mask's 8-bit value is >= 127 (IOPaint's convention), computed on:

    - the alpha channel, for an image with alpha (RGBA, grey+alpha, palette with transparency),
      unless the alpha is the same everywhere (a fully opaque RGBA export carries no mask in its
      alpha), in which case the colour is used as below;
    - the luminance (ITU-R BT.601, as Pillow's ``convert("L")``) of an RGB mask;
    - the value itself for a grey mask.

    16-bit and float masks are brought to 8 bits first, as in :func:`read_image`. Emptiness and
    coverage are checked by :func:`validate_pair`, which knows the target.

    Raises MissingFileError, UnreadableFileError, CorruptImageError, ImageTooLargeError."""
    native, orientation, _, _ = _read_raster(path, max_pixels=max_pixels, min_side=1)
    return _apply_orientation(_mask_channel(native, name=str(path)), orientation) >= MASK_THRESHOLD


def validate_pair(
    target: np.ndarray,
    mask: np.ndarray,
    source: np.ndarray,
    *,
    min_side: int = 64,
    max_pixels: int = 60_000_000,
    max_mask_fraction: float = 0.9,
    names: tuple[str, str, str] = ("target", "mask", "source"),
) -> np.ndarray:
    """Check the arrays of one fill and return the mask as HxW bool (True = hole).

    ``target`` and ``source`` must be HxWx3 uint8 RGB (see :func:`as_rgb_uint8`); they may differ in
    size and aspect. ``mask`` is HxW bool, or uint8 where >= 127 is hole, the size of the target,
    with at least one hole pixel and at most ``max_mask_fraction`` of the target covered.
    ``names`` label the three in error messages (the CLI passes the file paths).

    Raises ArrayFormatError, ImageTooSmallError, ImageTooLargeError, MaskSizeError, EmptyMaskError,
    MaskTooLargeError; ConfigError for a ``max_mask_fraction`` outside (0, 1]."""
    if not 0.0 < max_mask_fraction <= 1.0:
        raise ConfigError(f"max_mask_fraction must be in (0, 1], got {max_mask_fraction}")
    target_name, mask_name, source_name = names
    for image, name in ((target, target_name), (source, source_name)):
        if not (isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.ndim == 3):
            raise ArrayFormatError(f"{name}: expected an HxWx3 uint8 RGB array, got {_describe(image)}")
        if image.shape[2] != 3:
            raise ArrayFormatError(f"{name}: expected 3 channels (RGB), got {image.shape[2]}")
        _check_size(name, image.shape[1], image.shape[0], max_pixels=max_pixels, min_side=min_side)

    if not (isinstance(mask, np.ndarray) and mask.ndim == 2 and mask.dtype in (np.bool_, np.uint8)):
        raise ArrayFormatError(f"{mask_name}: expected an HxW bool or uint8 array, got {_describe(mask)}")
    hole = mask if mask.dtype == np.bool_ else mask >= MASK_THRESHOLD
    if hole.shape != target.shape[:2]:
        raise MaskSizeError(
            f"{mask_name}: mask is {_wxh(hole.shape)} but the target {target_name} is {_wxh(target.shape)}"
        )
    covered = float(np.count_nonzero(hole)) / hole.size
    if covered == 0.0:
        raise EmptyMaskError(f"{mask_name}: mask marks no hole pixel (hole = value >= {MASK_THRESHOLD})")
    if covered > max_mask_fraction:
        raise MaskTooLargeError(
            f"{mask_name}: mask covers {100 * covered:.1f}% of the target, "
            f"more than the allowed {100 * max_mask_fraction:.1f}%"
        )
    return hole


def as_unit_float(image: np.ndarray) -> np.ndarray:
    """An image as float32 in [0, 1], the pipeline's inside format: uint8 divided by 255 (in place
    in the new array, one full-size temporary fewer than ``image / 255.0``, same values); float
    passed through as float32 (not copied when it already is).

    >>> as_unit_float(np.array([0, 51, 255], np.uint8)).tolist()
    [0.0, 0.20000000298023224, 1.0]
    """
    if image.dtype != np.uint8:
        return image.astype(np.float32, copy=False)
    out = image.astype(np.float32)
    out /= 255.0
    return out


def as_rgb_uint8(image: np.ndarray, *, name: str = "image") -> np.ndarray:
    """Normalise an array to HxWx3 uint8 RGB at the API edge.

    Accepts HxW / HxWx1 grey, HxWx2 grey+alpha, HxWx3 RGB and HxWx4 RGBA (alpha dropped) of dtype
    bool, unsigned integers (scaled from their full range with rounding: uint16 ``round(v / 257)``)
    or float (taken as [0, 1], clipped; NaN -> 0). Raises ArrayFormatError otherwise."""
    a = np.asarray(image)
    if a.ndim == 3 and a.shape[2] in (1, 2):
        a = a[..., 0]
    elif a.ndim == 3 and a.shape[2] == 4:
        a = a[..., :3]
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)):
        raise ArrayFormatError(f"{name}: expected HxW, HxWx1, HxWx2, HxWx3 or HxWx4, got shape {a.shape}")
    a = _to_uint8(a, name)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=2)
    return np.ascontiguousarray(a)


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
    if _stat_mode(p, OutputError) is not None and stat.S_ISDIR(_stat_mode(p, OutputError)):
        raise OutputError(f"{p}: is a directory")


def check_output_dir(path: str | os.PathLike) -> None:
    """Raise OutputError now, before any work, if ``path`` cannot be a folder geofill writes files
    into (``--debug-dir``): an existing file, a name too long, or a nearest existing parent that is
    not a writable folder."""
    p = Path(path)
    mode = _stat_mode(p, OutputError)
    if mode is not None:
        if not stat.S_ISDIR(mode):
            raise OutputError(f"{p}: exists and is not a directory")
        _check_writable_folder(p, p, "folder")
        return
    parent = p.parent
    while _stat_mode(parent, OutputError) is None and parent != parent.parent:
        parent = parent.parent
    _check_writable_folder(p, parent, "parent folder")
    for part in p.parts:
        _check_name_length(p, part)


def _stat_mode(p: Path, error: type[Exception]) -> int | None:
    """``st_mode`` of ``p``, None when it does not exist; ``error`` for any other OS refusal
    (a name too long, permissions), whose message names the path."""
    try:
        return os.stat(p).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:
        raise error(f"{p}: {exc.strerror or _one_line(exc)}") from exc


def _check_writable_folder(p: Path, folder: Path, what: str) -> None:
    mode = _stat_mode(folder, OutputError)
    if mode is None or not stat.S_ISDIR(mode):
        raise OutputError(f"{p}: {what} {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"{p}: {what} {folder} is not writable")


def _check_name_length(p: Path, name: str) -> None:
    folder = next((f for f in p.parents if _stat_mode(f, OutputError) is not None), Path("."))
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
    follows the extension. ``quality`` (1-100, JPEG and WebP only; default 95) sets the lossy
    encoders' quality; ``metadata`` (EXIF, ICC profile) is embedded. Nothing is left behind on
    failure or on an exception raised mid-write (a SIGTERM turned into one by the CLI).
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
        os.replace(tmp, p)
    except OSError as exc:
        raise OutputError(f"{p}: cannot write image ({_one_line(exc)})") from exc
    finally:
        tmp.unlink(missing_ok=True)


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
    mode = _stat_mode(p, DepthFileError)
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
    except (*_DECODE_ERRORS, Image.DecompressionBombError) as exc:
        raise DepthFileError(f"{p}: cannot read depth map ({_one_line(exc)})") from exc
    if raw.ndim == 3 and raw.shape[2] == 1:
        raw = raw[..., 0]
    if raw.ndim != 2:
        raise DepthFileError(f"{p}: expected a single-channel depth map, got array shape {raw.shape}")
    if raw.dtype.kind not in "uif":
        raise DepthFileError(f"{p}: depth values must be numbers, got dtype {raw.dtype}")
    depth = raw.astype(np.float32) * np.float32(scale)
    depth[~np.isfinite(depth) | (depth == 0)] = np.nan
    return depth


# --------------------------------------------------------------------------------------------
# Image files


def _read_raster(
    path: str | os.PathLike, *, max_pixels: int, min_side: int
) -> tuple[np.ndarray, int, ExifCamera, ImageMetadata]:
    """Native-depth pixels (HxW, or HxWxC with C = 2, 3, 4 in RGB(A) order, not yet oriented), the
    EXIF orientation, the lens tags and the metadata to carry into an output; the size is checked
    from the header before decoding."""
    p = _existing_file(path)
    try:
        fh = open(p, "rb")
    except OSError as exc:
        raise UnreadableFileError(f"{p}: cannot open file ({_one_line(exc)})") from exc
    with fh, _pillow_bomb_guard(p, max_pixels):
        formats = INPUT_FORMATS
        if _is_heif(fh):
            require("pillow_heif", f"{p}: reading HEIC/HEIF").register_heif_opener()
            formats = ("HEIF",)
        try:
            img = Image.open(fh, formats=formats)
        except UnidentifiedImageError as exc:
            if _is_tiff(fh):  # float64/float16 or multi-channel float samples: Pillow has no mode
                return _read_tiff_without_pillow(p, max_pixels=max_pixels, min_side=min_side)
            raise CorruptImageError(f"{p}: not a PNG, JPEG, WebP, TIFF or HEIC image, or corrupt") from exc
        except _DECODE_ERRORS as exc:
            raise CorruptImageError(f"{p}: corrupt image header ({_one_line(exc)})") from exc
        _check_size(str(p), *img.size, max_pixels=max_pixels, min_side=min_side)
        try:
            pixels = _decode(img, p, fh)
            # After decoding: for a PNG, Pillow looks for the eXIf chunk by loading the image. Inside
            # the `with`: a TIFF's Exif sub-IFD is read from the still open file.
            exif = img.getexif()
            orientation = exif.get(_ORIENTATION, 1)
            camera = _exif_camera(exif, orientation)
        except _DECODE_ERRORS as exc:
            raise CorruptImageError(
                f"{p}: cannot decode image, truncated or corrupt ({_one_line(exc)})"
            ) from exc
        metadata = _carried_metadata(img, exif, orientation)
    return pixels, orientation, camera, metadata


def _is_tiff(fh: IO[bytes]) -> bool:
    fh.seek(0)
    head = fh.read(4)
    fh.seek(0)
    return head in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")  # classic and BigTIFF


def _read_tiff_without_pillow(
    p: Path, *, max_pixels: int, min_side: int
) -> tuple[np.ndarray, int, ExifCamera, ImageMetadata]:
    """A TIFF Pillow cannot open (float samples other than single-channel float32): size from
    tifffile's header before decoding, then the pixels; orientation from the TIFF tag."""
    import tifffile  # TIFF only: 0.01 s of every other fill's imports

    try:
        with tifffile.TiffFile(p) as tif:
            page = tif.pages[0]
            h, w = (
                (page.shape[1:3] if page.axes.startswith("S") else page.shape[:2])
                if page.ndim > 1
                else (0, 0)
            )
            _check_size(str(p), w, h, max_pixels=max_pixels, min_side=min_side)
            tag = page.tags.get(274)  # Orientation
            orientation = int(tag.value) if tag is not None and int(tag.value) in range(1, 9) else 1
        return _read_tiff(p), orientation, ExifCamera(), ImageMetadata()
    except _DECODE_ERRORS as exc:
        raise CorruptImageError(f"{p}: cannot decode TIFF, truncated or corrupt ({_one_line(exc)})") from exc


def _is_heif(fh: IO[bytes]) -> bool:
    """True for an ISO-BMFF file whose major brand is HEIF/HEIC/AVIF-like (ftyp box first)."""
    fh.seek(4)
    head = fh.read(8)
    fh.seek(0)
    return head[:4] == b"ftyp" and head[4:8] in _HEIF_BRANDS


def _carried_metadata(img: Image.Image, exif: Image.Exif, orientation: int) -> ImageMetadata:
    """The EXIF block (orientation reset to 1, pixel dimensions those of the upright pixels) and
    the ICC profile of an opened image."""
    icc = img.info.get("icc_profile") or None
    if not len(exif):
        return ImageMetadata(icc_profile=icc)
    if _ORIENTATION in exif:
        exif[_ORIENTATION] = 1
    sub = exif.get_ifd(ExifTags.IFD.Exif)
    if orientation in _TRANSPOSING_ORIENTATIONS:
        for tag in (ExifTags.Base.ExifImageWidth, ExifTags.Base.ExifImageHeight):
            sub.pop(tag, None)  # stored for the unrotated image: wrong for the upright output
    try:
        return ImageMetadata(exif=exif.tobytes(), icc_profile=icc)
    except (*_DECODE_ERRORS, TypeError) as exc:  # a tag Pillow can read but not write back
        return ImageMetadata(icc_profile=icc, note=f"EXIF not carried: {_one_line(exc)}")


def _decode(img: Image.Image, path: Path, fh: IO[bytes]) -> np.ndarray:
    """Pixels of an opened image at their native bit depth (see the module docstring for why three
    decoders)."""
    if img.format == "PNG" and _png_bit_depth(fh) == 16:
        data = cv2.imdecode(np.fromfile(path, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if data is None:
            raise ValueError("OpenCV could not decode the 16-bit PNG")
        if data.ndim == 3:
            data = cv2.cvtColor(data, cv2.COLOR_BGRA2RGBA if data.shape[2] == 4 else cv2.COLOR_BGR2RGB)
        return data
    if img.format == "TIFF" and _tiff_is_deep(img):
        return _read_tiff(path)
    if img.format in ("JPEG", "MPO") and img.mode in ("RGB", "L"):
        return _decode_jpeg_strict(path, grey=img.mode == "L")
    return np.array(img.convert("RGBA" if img.has_transparency_data else "RGB"))  # writable


def _decode_jpeg_strict(path: Path, grey: bool) -> np.ndarray:
    """A YCbCr or grey JPEG through simplejpeg (libjpeg-turbo, the same pixels as Pillow) in strict
    mode: libjpeg decodes a scan cut short by an end marker as flat grey with only a warning, which
    Pillow drops, so a 10 kB file whose header claims 7000 x 7000 would come back as 49 MP of grey.
    Strict mode turns that warning into a ValueError (a corrupt image)."""
    import simplejpeg

    pixels = simplejpeg.decode_jpeg(path.read_bytes(), colorspace="GRAY" if grey else "RGB", strict=True)
    return pixels[..., 0] if grey else pixels


def _png_bit_depth(fh: IO[bytes]) -> int:
    # The PNG signature (8 bytes) is followed by the IHDR chunk: length, type, width, height (4 bytes
    # each), then the bit depth; Pillow does not expose it.
    fh.seek(24)
    return fh.read(1)[0]


def _tiff_is_deep(img: Image.Image) -> bool:
    """True for TIFF samples Pillow would truncate or refuse: more than 8 bits, or floats."""
    bits = np.atleast_1d(img.tag_v2.get(258, 1))  # BitsPerSample
    sample_format = np.atleast_1d(img.tag_v2.get(339, 1))  # SampleFormat: 3 = IEEE float
    return bool(bits.max() > 8 or (sample_format == 3).any())


def _read_tiff(path: Path) -> np.ndarray:
    """First page of a TIFF as HxW or HxWxS (samples last) at native depth."""
    import tifffile

    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        if page.photometric not in (tifffile.PHOTOMETRIC.MINISBLACK, tifffile.PHOTOMETRIC.RGB):
            raise ValueError(f"unsupported photometric {page.photometric.name} for a >8-bit TIFF")
        data = page.asarray()
        if page.axes.startswith("S"):  # planar configuration: samples first
            data = np.moveaxis(data, 0, -1)
        return data


def _existing_file(path: str | os.PathLike) -> Path:
    p = Path(path)
    mode = _stat_mode(p, UnreadableFileError)
    if mode is None:
        raise MissingFileError(f"{p}: file not found")
    if stat.S_ISDIR(mode):
        raise MissingFileError(f"{p}: is a directory, not a file")
    if not stat.S_ISREG(mode):
        raise MissingFileError(f"{p}: not a regular file")
    return p


@contextlib.contextmanager
def _pillow_bomb_guard(path: Path, max_pixels: int) -> Iterator[None]:
    """Map Pillow's own decompression-bomb guard, which fires inside ``Image.open`` before our
    header check, to ImageTooLargeError.

    Its warning (over ``Image.MAX_IMAGE_PIXELS``) is an error when that limit is at or above ours
    (then the image is over ours too) and ignored when the caller allows more than Pillow does; its
    hard error (over twice the limit) always stops the read. ``warnings.catch_warnings`` changes
    process-wide state, which is fine for the single-threaded reads here."""
    limit = Image.MAX_IMAGE_PIXELS
    with warnings.catch_warnings():
        action = "error" if limit is None or max_pixels <= limit else "ignore"
        warnings.simplefilter(action, Image.DecompressionBombWarning)
        try:
            yield
        except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
            raise ImageTooLargeError(f"{path}: image too large ({_one_line(exc)})") from exc


def _check_size(name: str, width: int, height: int, *, max_pixels: int, min_side: int) -> None:
    if width * height > max_pixels:
        raise ImageTooLargeError(
            f"{name}: {width}x{height} = {width * height} pixels is over the limit of {max_pixels}"
        )
    if min(width, height) < min_side:
        raise ImageTooSmallError(f"{name}: {width}x{height} has a side under the minimum of {min_side} px")


def _apply_orientation(image: np.ndarray, orientation: int) -> np.ndarray:
    """Turn a uint8 HxW or HxWx3 array as EXIF ``orientation`` says, with Pillow's own table."""
    if orientation == 1:
        return image
    pil = Image.fromarray(image)
    pil.getexif()[_ORIENTATION] = orientation
    return np.array(ImageOps.exif_transpose(pil))  # np.array: a writable copy


def _exif_camera(exif: Image.Exif, orientation: int) -> ExifCamera:
    """Lens tags from the Exif sub-IFD, falling back to IFD0 where TIFF/EP files keep them."""
    sub = exif.get_ifd(ExifTags.IFD.Exif)

    def tag(key: int) -> float | None:
        value = sub.get(key, exif.get(key))
        try:
            number = float(value)
        except (TypeError, ValueError, ZeroDivisionError):
            return None
        return number if math.isfinite(number) and number > 0 else None

    mm_per_unit = _MM_PER_UNIT.get(int(tag(ExifTags.Base.FocalPlaneResolutionUnit) or 2))
    x_res, y_res = (
        (res / mm_per_unit if res is not None and mm_per_unit is not None else None)
        for res in (tag(ExifTags.Base.FocalPlaneXResolution), tag(ExifTags.Base.FocalPlaneYResolution))
    )
    width, height = tag(ExifTags.Base.ExifImageWidth), tag(ExifTags.Base.ExifImageHeight)
    names = [
        sub.get(k, exif.get(k)) for k in (ExifTags.Base.Make, ExifTags.Base.Model, ExifTags.Base.LensModel)
    ]
    body = " ".join(str(n).strip("\x00 ") for n in names if isinstance(n, str) and n.strip("\x00 "))
    camera = ExifCamera(
        focal_35mm=tag(ExifTags.Base.FocalLengthIn35mmFilm),
        focal_mm=tag(ExifTags.Base.FocalLength),
        focal_plane_x_res=x_res,
        focal_plane_y_res=y_res,
        original_size=(int(width), int(height)) if width and height else None,
        body=body or None,
    )
    if orientation in _TRANSPOSING_ORIENTATIONS:
        size = camera.original_size
        camera = replace(
            camera,
            focal_plane_x_res=y_res,
            focal_plane_y_res=x_res,
            original_size=(size[1], size[0]) if size else None,
        )
    return camera


# --------------------------------------------------------------------------------------------
# Arrays


def _to_uint8(a: np.ndarray, name: str) -> np.ndarray:
    if a.dtype == np.uint8:
        return a
    if a.dtype == np.bool_:
        return a.astype(np.uint8) * np.uint8(255)
    if a.dtype == np.uint16:
        # round(v * 255 / 65535) in one pass, ~25x faster than NumPy with an integer intermediate;
        # exact for all 65536 values (v / 257 is never within float error of a .5 tie; tested).
        return cv2.convertScaleAbs(a, alpha=255.0 / 65535.0)
    if a.dtype.kind == "u":
        return np.rint(a * (255.0 / np.iinfo(a.dtype).max)).astype(np.uint8)
    if a.dtype.kind == "f":
        return np.rint(np.clip(np.nan_to_num(a, nan=0.0), 0.0, 1.0) * 255.0).astype(np.uint8)
    raise ArrayFormatError(f"{name}: unsupported dtype {a.dtype} (use uint8, uint16 or float in [0, 1])")


def _mask_channel(native: np.ndarray, name: str) -> np.ndarray:
    """The uint8 HxW channel the hole is read from (see :func:`read_mask`)."""
    a = native[..., 0] if native.ndim == 3 and native.shape[2] == 1 else native
    if a.ndim == 3 and a.shape[2] in (2, 4):
        alpha = a[..., -1]
        if alpha.min() != alpha.max():
            return _to_uint8(alpha, name)
        a = a[..., 0] if a.shape[2] == 2 else a[..., :3]
    a = _to_uint8(a, name)
    return cv2.cvtColor(a, cv2.COLOR_RGB2GRAY) if a.ndim == 3 else a


def _describe(a: object) -> str:
    if isinstance(a, np.ndarray):
        return f"shape {a.shape} dtype {a.dtype}"
    return type(a).__name__


def _wxh(shape: tuple[int, ...]) -> str:
    return f"{shape[1]}x{shape[0]}"


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


# --------------------------------------------------------------------------------------------
# Depth files: each reader checks the size from the header before decoding.


def _check_depth_size(path: Path, shape: tuple[int, ...], expected_hw: tuple[int, int]) -> None:
    if len(shape) < 2:
        raise DepthFileError(f"{path}: expected a 2-D depth map, got array shape {tuple(shape)}")
    if tuple(shape[:2]) != expected_hw:
        raise DepthFileError(
            f"{path}: depth map is {_wxh(shape)} but the image it belongs to is {_wxh(expected_hw)}"
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
        raise DepthFileError(f"{path}: cannot read EXR ({_one_line(exc)})") from exc
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
