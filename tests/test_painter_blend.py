"""The painter's structure: a smooth gradient split into two surfaces is continued without a seam or
a plateau."""

from __future__ import annotations

import numpy as np

from geofill.composite.exemplar import complete
from geofill.composite.surfaces import segment


def _ramp(n: int = 160) -> tuple[np.ndarray, np.ndarray]:
    """A colour ramp (1 level/px in x, 0.3 in y; its colours span enough to make two surfaces) and a
    70-px disc hole in its middle."""
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float32)
    v = 40 + 1.0 * xx + 0.3 * yy
    img = np.clip(np.dstack([v, v * 0.8, 255 - v]), 0, 255).astype(np.uint8)
    return img, (yy - n / 2) ** 2 + (xx - n / 2) ** 2 <= 35**2


def test_a_ramp_split_into_two_surfaces_is_continued_without_a_plateau_or_a_seam():
    """Each surface's structure was diffused from its own pixels with a free edge where they meet,
    which turns a ramp into two plateaus (mean error 7.9 levels, at most 23; a sky's gradient split
    by colour does the same). Diffused across the surfaces with only their colour step kept, the
    fill is within 4 levels on average and 12 at most, and across the hole's border it continues
    the ramp: each border pixel within 3 levels of what its known neighbour plus the ramp's step
    gives."""
    img, hole = _ramp()
    assert segment(img.astype(np.float32) / 255.0, hole, 7).max() == 1  # the case: two surfaces
    out = complete(img, hole).astype(float)
    err = np.abs(out - img).max(axis=-1)[hole]
    assert err.mean() <= 4.0, err.mean()
    assert err.max() <= 12.0, err.max()
    # Across the border, left/right neighbours: the fill's step against the truth's.
    inside = hole[:, 1:] & ~hole[:, :-1]
    step = (out[:, 1:] - out[:, :-1])[inside] - (img[:, 1:].astype(float) - img[:, :-1])[inside]
    assert np.abs(step).max() <= 3.0, np.abs(step).max()
