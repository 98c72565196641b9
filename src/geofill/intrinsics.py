"""Per-image pinhole intrinsics: explicit flag > EXIF 35 mm-equivalent focal > default.

The default is the paper's 750 px at a 1280-px long side, scaled by the image's LONG side (scaling
by width would give a portrait phone photo half the focal of the same camera held landscape)."""

from __future__ import annotations

from typing import Protocol

from .camera import Intrinsics, default_focal_px, focal_from_35mm
from .config import IntrinsicsConfig
from .errors import ConfigError


class HasFocal35(Protocol):
    focal_35mm: float | None


def resolve_intrinsics(
    width: int,
    height: int,
    cfg: IntrinsicsConfig,
    exif: HasFocal35 | None,
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
        return Intrinsics(fx, fy, cx, cy, width, height, origin="flag")
    if cfg.focal_px is not None:
        return Intrinsics.from_focal(cfg.focal_px, width, height, origin="flag")
    if cfg.use_exif and exif is not None and exif.focal_35mm:
        return Intrinsics.from_focal(focal_from_35mm(exif.focal_35mm, width, height), width, height, "exif")
    return Intrinsics.from_focal(default_focal_px(width, height), width, height, origin="default")
