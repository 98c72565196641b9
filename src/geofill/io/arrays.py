"""Arrays at the API edge: normalising images to HxWx3 uint8 RGB, the pipeline's float views, and
the checks of one fill's target, mask and source (:func:`validate_pair`)."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import (
    ArrayFormatError,
    ConfigError,
    EmptyMaskError,
    ImageTooLargeError,
    ImageTooSmallError,
    MaskSizeError,
    MaskTooLargeError,
)

#: Mask pixels at or above this 8-bit value are hole (IOPaint's convention).
MASK_THRESHOLD = 127


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
        check_size(name, image.shape[1], image.shape[0], max_pixels=max_pixels, min_side=min_side)

    if not (isinstance(mask, np.ndarray) and mask.ndim == 2 and mask.dtype in (np.bool_, np.uint8)):
        raise ArrayFormatError(f"{mask_name}: expected an HxW bool or uint8 array, got {_describe(mask)}")
    hole = mask if mask.dtype == np.bool_ else mask >= MASK_THRESHOLD
    if hole.shape != target.shape[:2]:
        which = "the target" if target_name == "target" else f"the target {target_name}"
        raise MaskSizeError(f"{mask_name}: mask is {wxh(hole.shape)} but {which} is {wxh(target.shape)}")
    covered = float(np.count_nonzero(hole)) / hole.size
    if covered == 0.0:
        raise EmptyMaskError(f"{mask_name}: mask marks no hole pixel (hole = value >= {MASK_THRESHOLD})")
    if covered > max_mask_fraction:
        raise MaskTooLargeError(
            f"{mask_name}: mask covers {100 * covered:.1f}% of the target, "
            f"more than the allowed {100 * max_mask_fraction:.1f}%"
        )
    return hole


def as_source_mask(mask: np.ndarray, source: np.ndarray, name: str = "source mask") -> np.ndarray:
    """A reference's mask (what must never be copied from it) as HxW bool: a bool array, or uint8
    where >= 127 is masked, the size of its ``source``. Raises ArrayFormatError, MaskSizeError.

    >>> as_source_mask(np.array([[0, 200]], np.uint8), np.zeros((1, 2, 3), np.uint8)).tolist()
    [[False, True]]
    """
    if not (isinstance(mask, np.ndarray) and mask.ndim == 2 and mask.dtype in (np.bool_, np.uint8)):
        raise ArrayFormatError(f"{name}: expected an HxW bool or uint8 array, got {_describe(mask)}")
    if mask.shape != source.shape[:2]:
        raise MaskSizeError(f"{name}: mask is {wxh(mask.shape)} but its reference is {wxh(source.shape)}")
    return mask if mask.dtype == np.bool_ else mask >= MASK_THRESHOLD


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


def too_large(name: str, size: str, max_pixels: int) -> str:
    """The message for an image of ``size`` (words) over ``max_pixels``.

    >>> too_large("a.png", "9000x9000 = 81000000 pixels", 40_000_000)
    'a.png: 9000x9000 = 81000000 pixels is over the limit of 40000000 pixels (max_pixels)'
    """
    return f"{name}: {size} is over the limit of {max_pixels} pixels (max_pixels)"


def check_size(name: str, width: int, height: int, *, max_pixels: int, min_side: int) -> None:
    """Raise ImageTooLargeError / ImageTooSmallError for an image ``name`` of this size (px)."""
    if width * height > max_pixels:
        raise ImageTooLargeError(too_large(name, f"{width}x{height} = {width * height} pixels", max_pixels))
    if min(width, height) < min_side:
        raise ImageTooSmallError(f"{name}: {width}x{height} has a side under the minimum of {min_side} px")


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


def mask_channel(native: np.ndarray, name: str) -> np.ndarray:
    """The uint8 HxW channel the hole is read from (see :func:`~geofill.io.images.read_mask`)."""
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


def wxh(shape: tuple[int, ...]) -> str:
    """An array shape (H, W, ...) as the "WxH" that messages use.

    >>> wxh((480, 640, 3))
    '640x480'
    """
    return f"{shape[1]}x{shape[0]}"
