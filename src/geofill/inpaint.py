"""Single-image inpainting for hole pixels the source cannot supply (and whole holes on fallback)."""

from __future__ import annotations

import cv2
import numpy as np

from .config import InpaintConfig

_METHODS = {"telea": cv2.INPAINT_TELEA, "ns": cv2.INPAINT_NS}


def inpaint_single(image: np.ndarray, hole: np.ndarray, cfg: InpaintConfig) -> np.ndarray:
    """Fill ``hole`` (bool) of an HxWx3 uint8 image from its surroundings; other pixels unchanged."""
    if not hole.any():
        return image.copy()
    out = cv2.inpaint(image, hole.astype(np.uint8), cfg.radius_px, _METHODS[cfg.method])
    out[~hole] = image[~hole]
    return out
