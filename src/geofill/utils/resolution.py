"""Resolution conventions, in one place.

Every pixel distance in the configuration is given at the paper's 1280-px long side and scaled
with the image's long side; images are shrunk to a working long side with area resampling; points
move between resolutions with the pixel-centre convention (``x' = s (x + 0.5) - 0.5``), the same
one :meth:`geofill.camera.Intrinsics.resized` uses for the principal point.

>>> px_scale((720, 1280))
1.0
>>> round(config_px(48, (1080, 1920)), 1)
72.0
>>> rescale_points(np.array([[0.0, 0.0]]), (100, 50), (200, 100)).tolist()
[[0.5, 0.5]]
"""

from __future__ import annotations

import cv2
import numpy as np

#: Long side (px) at which the paper states its pixel distances (1280x720).
PAPER_LONG_SIDE_PX = 1280


def px_scale(shape: tuple[int, ...]) -> float:
    """Factor from config pixels (at a 1280-px long side) to pixels of an image of ``shape`` (H, W, ...)."""
    return max(shape[0], shape[1]) / PAPER_LONG_SIDE_PX


def config_px(value_px: float, shape: tuple[int, ...]) -> float:
    """``value_px`` (config pixels) in pixels of an image of ``shape``."""
    return value_px * px_scale(shape)


def resize_long(image: np.ndarray, max_side: int) -> np.ndarray:
    """``image`` shrunk (area resampling, aspect kept) so its long side is at most ``max_side``;
    returned unchanged when already small enough. Works on bool-as-float masks too."""
    h, w = image.shape[:2]
    s = max_side / max(h, w)
    if s >= 1.0:
        return image
    size = (max(round(w * s), 1), max(round(h * s), 1))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def resize_mask_any(mask: np.ndarray, max_side: int) -> np.ndarray:
    """Bool mask shrunk like :func:`resize_long`; a pixel is set where any input pixel under it is."""
    return resize_long(mask.astype(np.float32), max_side) > 0


def rescale_points(points: np.ndarray, from_wh: tuple[int, int], to_wh: tuple[int, int]) -> np.ndarray:
    """(N, 2) pixel coordinates of an image of size ``from_wh`` (W, H) in an image of size ``to_wh``."""
    s = np.array([to_wh[0] / from_wh[0], to_wh[1] / from_wh[1]])
    return (points + 0.5) * s - 0.5


def odd_px(px: float) -> int:
    """``px`` rounded to an odd integer of at least 1 (rounding down from an even one): the side of a
    centred box filter."""
    return max(1, round(px) // 2 * 2 + 1)
