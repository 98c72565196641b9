"""Per-image pinhole intrinsics before estimation: calibration flag > focal flag > EXIF > default.

EXIF: FocalLengthIn35mmFilm (diagonal rule, :func:`geofill.camera.focal_from_35mm`), else the
FocalLength in mm times the focal-plane resolution (px per mm of the original image), scaled to the
image's current size. The default is the paper's 750 px at a 1280-px long side, scaled by the
image's LONG side (scaling by width would give a portrait phone photo half the focal of the same
camera held landscape).

Each result carries ``rel_uncertainty``, the prior 1-sigma of log(focal): 0 for a flag (never
estimated), ``prior_sigma_exif`` for EXIF and ``prior_sigma_default`` for the default; the focal
estimation (:mod:`geofill.focal`) uses it as the weight of the prior.
"""

from __future__ import annotations

from typing import Protocol

from .camera import Intrinsics, default_focal_px, focal_from_35mm
from .config import IntrinsicsConfig
from .errors import ConfigError


class ExifLens(Protocol):
    """The EXIF lens fields used here (:class:`geofill.io.ExifCamera` has them)."""

    focal_35mm: float | None
    focal_mm: float | None
    focal_plane_x_res: float | None  # px per mm, in the orientation of the delivered pixels
    focal_plane_y_res: float | None
    original_size: tuple[int, int] | None  # (w, h) the focal-plane resolution refers to


def focal_from_focal_plane(exif: ExifLens, width: int, height: int) -> float | None:
    """Focal length (px of a ``width`` x ``height`` image) from EXIF FocalLength (mm) and the
    focal-plane resolution (px per mm of the ``original_size`` image); None when a field is missing.

    Both axes are used when both are present (their mean: square pixels are assumed downstream)."""
    if not exif.focal_mm or exif.original_size is None:
        return None
    ow, oh = exif.original_size
    per_axis = [
        exif.focal_mm * res * size / orig
        for res, size, orig in ((exif.focal_plane_x_res, width, ow), (exif.focal_plane_y_res, height, oh))
        if res and orig
    ]
    return sum(per_axis) / len(per_axis) if per_axis else None


def exif_focal_px(exif: ExifLens, width: int, height: int) -> float | None:
    """Focal length (px) from EXIF: the 35 mm-equivalent when present (phones write it reliably),
    else focal length x focal-plane resolution; None when EXIF has neither."""
    if exif.focal_35mm:
        return focal_from_35mm(exif.focal_35mm, width, height)
    return focal_from_focal_plane(exif, width, height)


def resolve_intrinsics(
    width: int,
    height: int,
    cfg: IntrinsicsConfig,
    exif: ExifLens | None,
    calibration: list[float] | None = None,
) -> Intrinsics:
    """Intrinsics of a ``width`` x ``height`` image: ``calibration`` [fx, fy, cx, cy] when given, else
    a focal from the flag, EXIF or the default with the principal point at the centre."""
    if calibration is not None:
        if len(calibration) != 4 or min(calibration[0], calibration[1]) <= 0:
            raise ConfigError(
                f"intrinsics must be [fx, fy, cx, cy] with positive focal lengths, got {calibration}"
            )
        fx, fy, cx, cy = (float(v) for v in calibration)
        return Intrinsics(fx, fy, cx, cy, width, height, origin="flag", rel_uncertainty=0.0)
    if cfg.focal_px is not None:
        return Intrinsics.from_focal(cfg.focal_px, width, height, "flag", 0.0)
    focal = exif_focal_px(exif, width, height) if cfg.use_exif and exif is not None else None
    if focal is not None:
        return Intrinsics.from_focal(focal, width, height, "exif", cfg.prior_sigma_exif)
    return Intrinsics.from_focal(
        default_focal_px(width, height), width, height, "default", cfg.prior_sigma_default
    )
