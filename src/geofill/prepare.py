"""The prepare stage: both images at working resolution with their prior intrinsics."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .camera import Intrinsics
from .config import FillConfig
from .intrinsics import ExifLens, resolve_intrinsics
from .io import as_unit_float
from .match import to_gray_u8
from .utils.resolution import px_scale, resize_long, resize_mask_any


@dataclass(frozen=True)
class WorkingViews:
    """Target and one source as float32 RGB in [0, 1] at working resolution (and as 8-bit grey, what
    SIFT reads), the target's hole, and each image's prior intrinsics (flag, EXIF or default) at
    that resolution."""

    target: np.ndarray
    source: np.ndarray
    hole: np.ndarray  # bool, working resolution
    K_target: Intrinsics
    K_source: Intrinsics
    target_shape: tuple[int, int]  # (H, W) of the input target
    ransac_px: float  # inlier threshold of the robust fits at this resolution (MatchingConfig.ransac_px)
    # HxW uint8, from the 8-bit working images: converting the float views back cost 30 ms a fill.
    target_gray: np.ndarray
    source_gray: np.ndarray

    @property
    def px_scale(self) -> float:
        """Working long side / 1280: converts config pixel distances."""
        return px_scale(self.target.shape)

    def summary(self) -> str:
        (ht, wt), (hs, ws) = self.target.shape[:2], self.source.shape[:2]
        return (
            f"working size {wt}x{ht} / {ws}x{hs}, focal prior {self.K_target.origin} / {self.K_source.origin}"
        )

    def report(self) -> dict[str, Any]:
        return {
            "working_size_target": [self.K_target.width, self.K_target.height],
            "working_size_source": [self.K_source.width, self.K_source.height],
        }


def prepare_views(
    target: np.ndarray,
    hole: np.ndarray,
    source: np.ndarray,
    cfg: FillConfig,
    target_exif: ExifLens | None,
    source_exif: ExifLens | None,
) -> WorkingViews:
    """Working-resolution float views and per-image intrinsics (resolved at input size, then
    resized). Any hole pixel of the input makes its working pixel a hole (no object leaks)."""
    ic = cfg.intrinsics
    K_t = resolve_intrinsics(target.shape[1], target.shape[0], ic, target_exif, ic.target)
    K_s = resolve_intrinsics(source.shape[1], source.shape[0], ic, source_exif, ic.source)
    t = resize_long(target, cfg.working_max_side)
    s = resize_long(source, cfg.working_max_side)
    return WorkingViews(
        as_unit_float(t),
        as_unit_float(s),
        resize_mask_any(hole, cfg.working_max_side),
        K_t.resized(t.shape[1], t.shape[0]),
        K_s.resized(s.shape[1], s.shape[0]),
        (target.shape[0], target.shape[1]),
        cfg.matching.ransac_px(px_scale(t.shape)),
        to_gray_u8(t),
        to_gray_u8(s),
    )
