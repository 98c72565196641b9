"""Per-image pinhole intrinsics: explicit flag > EXIF 35 mm-equivalent focal > default.

The default is the paper's 750 px at a 1280-px long side, scaled by the image's LONG side (scaling
by width would give a portrait phone photo half the focal of the same camera held landscape)."""

from __future__ import annotations

from typing import Protocol

from .camera import Intrinsics, default_focal_px, focal_from_35mm
from .config import IntrinsicsConfig


class HasFocal35(Protocol):
    focal_35mm: float | None


def resolve_intrinsics(width: int, height: int, cfg: IntrinsicsConfig, exif: HasFocal35 | None) -> Intrinsics:
    """Intrinsics of a ``width`` x ``height`` image (principal point at the centre)."""
    if cfg.focal_px is not None:
        return Intrinsics.from_focal(cfg.focal_px, width, height, origin="flag")
    if cfg.use_exif and exif is not None and exif.focal_35mm:
        return Intrinsics.from_focal(focal_from_35mm(exif.focal_35mm, width, height), width, height, "exif")
    return Intrinsics.from_focal(default_focal_px(width, height), width, height, origin="default")
