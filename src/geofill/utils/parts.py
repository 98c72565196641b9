"""The large parts of a mask: what the screen tests keep of their seeds once an opening has removed
the thin lines that misalignment leaves along edges."""

from __future__ import annotations

import cv2
import numpy as np


def large_parts(
    mask: np.ndarray, open_px: int, min_area: float, touching: np.ndarray | None = None
) -> np.ndarray:
    """HxW bool: ``mask`` opened by an ``open_px`` square, then its 8-connected parts of at least
    ``min_area`` px (and, with ``touching``, only those with a pixel there).

    >>> m = np.zeros((12, 12), bool); m[1:6, 1:6] = True; m[8, 2:11] = True; m[9:11, 9:11] = True
    >>> int(large_parts(m, 3, 9).sum()), int(large_parts(m, 3, 30).sum())
    (25, 0)
    """
    opened = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, np.ones((open_px, open_px), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(opened, connectivity=8)
    keep = stats[:, cv2.CC_STAT_AREA] >= min_area
    if touching is not None:
        reached = np.zeros(n, bool)
        reached[np.unique(labels[touching & (labels > 0)])] = True
        keep &= reached
    keep[0] = False
    return keep[labels]
