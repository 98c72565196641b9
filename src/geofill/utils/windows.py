"""The window of an image a stage works in: the hole's bounding box grown by a margin.

Shared by the stages that work near the hole only (render, screen, fuse, composite), so that none
of them imports another stage for it.
"""

from __future__ import annotations

import numpy as np


def mask_window(mask: np.ndarray, margin: int | None) -> tuple[slice, slice]:
    """Rows and columns of ``mask``'s bounding box grown by ``margin`` px and clipped to the image
    (the whole image when ``margin`` is None or the mask is empty).

    >>> m = np.zeros((10, 10), bool); m[4:6, 2:3] = True
    >>> mask_window(m, 1)
    (slice(3, 7, None), slice(1, 4, None))
    """
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if margin is None or not rows.size:
        return slice(0, mask.shape[0]), slice(0, mask.shape[1])
    return (
        slice(max(int(rows[0]) - margin, 0), min(int(rows[-1]) + margin + 1, mask.shape[0])),
        slice(max(int(cols[0]) - margin, 0), min(int(cols[-1]) + margin + 1, mask.shape[1])),
    )
