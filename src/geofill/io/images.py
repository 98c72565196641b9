"""Reading image and mask files: HxWx3 uint8 RGB with the EXIF orientation applied, masks as HxW
bool (True = hole), the EXIF lens tags and the metadata an output carries over.

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
import re
import stat
import struct
import warnings
import zlib
from collections.abc import Iterator
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
    JpegImagePlugin,
    TiffImagePlugin,  # noqa: F401
    UnidentifiedImageError,
    WebPImagePlugin,  # noqa: F401
)

from ..errors import CorruptImageError, ImageTooLargeError, MissingFileError, UnreadableFileError
from ..extras import require
from .arrays import MASK_THRESHOLD, as_rgb_uint8, check_size, mask_channel, too_large
from .files import DECODE_ERRORS, one_line, stat_mode

#: Pillow formats accepted as input. Restricting ``Image.open`` to these keeps Pillow's other
#: plugins (EPS runs Ghostscript, for one) away from user files. The JPEG opener also returns the
#: multi-picture JPEGs many cameras write (format "MPO").
INPUT_FORMATS = ("PNG", "JPEG", "WEBP", "TIFF")


#: ISO-BMFF major brands of HEIF images (HEIC from phones, plain HEIF).
_HEIF_BRANDS = {b"heic", b"heix", b"hevc", b"hevx", b"heim", b"heis", b"mif1", b"msf1"}


_ORIENTATION = ExifTags.Base.Orientation


# EXIF orientations that swap the stored image's width and height.
_TRANSPOSING_ORIENTATIONS = (5, 6, 7, 8)


# FocalPlaneResolutionUnit (0xA210) -> millimetres per unit. EXIF defines 2 = inch (also the
# default when the tag is absent) and 3 = cm; TIFF/EP adds 4 = mm and 5 = um. 1 (no absolute unit)
# gives no physical resolution.
_MM_PER_UNIT = {2: 25.4, 3: 10.0, 4: 1.0, 5: 1e-3}


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
class JpegTables:
    """How a JPEG file was encoded: its quantisation tables (64 values each, in Pillow's order, the
    one ``Image.save(qtables=...)`` takes) and its chroma subsampling (Pillow's code: 0 = 4:4:4,
    1 = 4:2:2, 2 = 4:2:0; -1 = the encoder's default), so that a JPEG output can be written at
    the input's own quality rather than at a guessed one."""

    qtables: tuple[tuple[int, ...], ...]
    subsampling: int = -1


@dataclass(frozen=True)
class ImageMetadata:
    """What an output carries over from its input file: the EXIF block (orientation reset to 1,
    since the pixels are delivered upright), the ICC colour profile and, for a JPEG, its encoding
    tables; None where absent. ``note`` says why EXIF present in the file could not be carried
    (never dropped silently); ``unread`` what Pillow warned it could not read in the file (a
    corrupt EXIF block, say)."""

    exif: bytes | None = None
    icc_profile: bytes | None = None
    note: str | None = None
    unread: str | None = None
    jpeg_tables: JpegTables | None = None

    def stripped(self) -> ImageMetadata:
        """The same without EXIF (GPS included) and ICC profile: only how the file was encoded."""
        return ImageMetadata(jpeg_tables=self.jpeg_tables)


@dataclass
class LoadedImage:
    """An input image as the pipeline sees it."""

    pixels: np.ndarray  # HxWx3 uint8 RGB, EXIF orientation applied
    path: str
    exif: ExifCamera = field(default_factory=ExifCamera)
    metadata: ImageMetadata = field(default_factory=ImageMetadata)


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
    coverage are checked by :func:`~geofill.io.arrays.validate_pair`, which knows the target.

    Raises MissingFileError, UnreadableFileError, CorruptImageError, ImageTooLargeError."""
    native, orientation, _, _ = _read_raster(path, max_pixels=max_pixels, min_side=1)
    return _apply_orientation(mask_channel(native, name=str(path)), orientation) >= MASK_THRESHOLD


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
        raise UnreadableFileError(f"{p}: cannot open file ({one_line(exc)})") from exc
    with fh, _pillow_guard(p, max_pixels) as heard:
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
        except DECODE_ERRORS as exc:
            raise CorruptImageError(f"{p}: corrupt image header ({one_line(exc)})") from exc
        check_size(str(p), *img.size, max_pixels=max_pixels, min_side=min_side)
        try:
            pixels = _decode(img, p, fh)
            # After decoding: for a PNG, Pillow looks for the eXIf chunk by loading the image. Inside
            # the `with`: a TIFF's Exif sub-IFD is read from the still open file.
            exif = img.getexif()
            orientation = exif.get(_ORIENTATION, 1)
            camera = _exif_camera(exif, orientation)
        except DECODE_ERRORS as exc:
            raise CorruptImageError(
                f"{p}: cannot decode image, truncated or corrupt ({one_line(exc)})"
            ) from exc
        metadata = replace(_carried_metadata(img, exif, orientation), jpeg_tables=_jpeg_tables(img))
    if heard:  # said once, as a note on the file, rather than as Python warnings
        said = "; ".join(dict.fromkeys(one_line(w.message) for w in heard))
        metadata = replace(metadata, unread=f"part of its metadata could not be read ({said})")
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
            check_size(str(p), w, h, max_pixels=max_pixels, min_side=min_side)
            tag = page.tags.get(274)  # Orientation
            orientation = int(tag.value) if tag is not None and int(tag.value) in range(1, 9) else 1
        return _read_tiff(p), orientation, ExifCamera(), ImageMetadata()
    except DECODE_ERRORS as exc:
        raise CorruptImageError(f"{p}: cannot decode TIFF, truncated or corrupt ({one_line(exc)})") from exc


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
    except (*DECODE_ERRORS, TypeError) as exc:  # a tag Pillow can read but not write back
        return ImageMetadata(icc_profile=icc, note=f"EXIF not carried: {one_line(exc)}")


def _jpeg_tables(img: Image.Image) -> JpegTables | None:
    """The quantisation tables and subsampling of an opened JPEG (None for other formats). A grey
    JPEG has one table; its luma table serves the chroma of the RGB output too."""
    if not isinstance(img, JpegImagePlugin.JpegImageFile) or not img.quantization:
        return None
    tables = tuple(tuple(img.quantization[k]) for k in sorted(img.quantization))
    return JpegTables(tables if len(tables) > 1 else tables * 2, JpegImagePlugin.get_sampling(img))


def _decode(img: Image.Image, path: Path, fh: IO[bytes]) -> np.ndarray:
    """Pixels of an opened image at their native bit depth (see the module docstring for why three
    decoders)."""
    if img.format == "PNG":
        _check_png_rows(fh)  # before libpng (16-bit PNGs), which prints its error to stderr
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


#: Samples per pixel of each PNG colour type (grey, RGB, palette, grey+alpha, RGBA).
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
#: Adam7 passes: (first column, first row, column step, row step).
_ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2))


def _check_png_rows(fh: IO[bytes]) -> None:
    """Raise ValueError when a PNG's image data holds fewer rows than its header says.

    Pillow decodes a complete zlib stream that ends early as an image whose last rows are black,
    without a word; libpng would refuse it, but only OpenCV wraps libpng and it prints its error to
    stderr. So the stream is inflated here, in bounded pieces, and its length compared with the one
    the header implies (a filter byte and the packed samples per row, per Adam7 pass if interlaced)."""
    fh.seek(8)
    width, height, depth, colour, _, _, interlaced = struct.unpack(">IIBBBBB", fh.read(25)[8:21])
    bits = depth * _PNG_CHANNELS.get(colour, 4)
    passes = _ADAM7 if interlaced else ((0, 0, 1, 1),)
    expected = 0
    for x0, y0, dx, dy in passes:
        cols, rows = -(-(width - x0) // dx), -(-(height - y0) // dy)
        if cols > 0 and rows > 0:
            expected += rows * (1 + -(-(cols * bits) // 8))
    inflate, got = zlib.decompressobj(), 0
    fh.seek(8)
    while got < expected and not inflate.eof:
        head = fh.read(8)
        if len(head) < 8:
            break
        length, kind = struct.unpack(">I4s", head)
        data = fh.read(length)
        fh.seek(4, os.SEEK_CUR)  # CRC
        if kind == b"IEND":
            break
        if kind != b"IDAT":
            continue
        while data and got < expected:
            try:
                got += len(inflate.decompress(data, 1 << 20))
            except zlib.error as exc:  # Pillow decodes without checking, so this is news
                raise ValueError(f"its image data is corrupt ({exc})") from exc
            data = inflate.unconsumed_tail
    if got < expected:
        raise ValueError(
            f"its image data stops at {100 * got / expected:.0f}% of its {width}x{height} pixels"
        )


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
    mode = stat_mode(p, UnreadableFileError)
    if mode is None:
        raise MissingFileError(f"{p}: file not found")
    if stat.S_ISDIR(mode):
        raise MissingFileError(f"{p}: is a directory, not a file")
    if not stat.S_ISREG(mode):
        raise MissingFileError(f"{p}: not a regular file")
    return p


@contextlib.contextmanager
def _pillow_guard(path: Path, max_pixels: int) -> Iterator[list[warnings.WarningMessage]]:
    """Map Pillow's own decompression-bomb guard, which fires inside ``Image.open`` before our
    header check, to ImageTooLargeError with our limit; collect Pillow's other warnings (a corrupt
    EXIF block, say) in the yielded list instead of letting Python print them.

    Its warning (over ``Image.MAX_IMAGE_PIXELS``) is an error when that limit is at or above ours
    (then the image is over ours too) and ignored when the caller allows more than Pillow does; its
    hard error (over twice the limit) always stops the read. ``warnings.catch_warnings`` changes
    process-wide state, which is fine for the single-threaded reads here."""
    limit = Image.MAX_IMAGE_PIXELS
    with warnings.catch_warnings(record=True) as heard:
        warnings.simplefilter("always")
        action = "error" if limit is None or max_pixels <= limit else "ignore"
        warnings.simplefilter(action, Image.DecompressionBombWarning)
        try:
            yield heard
        except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
            # Pillow's words name its own limit; the size is the one number worth keeping.
            found = re.search(r"\((\d+) pixels\)", str(exc))
            size = f"{found[1]} pixels" if found else "the image"
            if isinstance(exc, Image.DecompressionBombError) and limit is not None and max_pixels > 2 * limit:
                message = f"{path}: {size} is over the most Pillow decodes ({2 * limit} pixels)"
            else:
                message = too_large(str(path), size, max_pixels)
            raise ImageTooLargeError(message) from exc


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
