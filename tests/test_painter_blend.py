"""The painter's blending and its search's reuse cost: a smooth gradient split into two surfaces is
continued without a seam or a plateau, and a source region copied twice costs what the settings
say, once costs nothing."""

from __future__ import annotations

import numpy as np

from geofill.composite import exemplar
from geofill.composite.exemplar import ExemplarSettings, complete
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


def test_a_source_region_copied_twice_costs_the_penalty_and_once_nothing():
    """Two 9x9 blocks of the hole copying the same 9x9 source block: each source centre of that
    block is some target's match twice, which costs ``penalty`` x the median patch distance per
    copy beyond the first; a block copied once costs nothing, nor does anything without a
    penalty."""
    h, w, r = 60, 80, 1
    img = np.random.default_rng(0).random((h, w, 3), dtype=np.float32)
    hole = np.zeros((h, w), bool)
    hole[20:40, 30:70] = True
    lev = exemplar._Level.make(img, hole, r, np.zeros((h, w), np.int32))
    side = 2 * r + 1
    nnf = np.full((lev.ty.size, 2), 5, np.int64)  # the rest all copy one corner far off
    by_pos = {(int(y), int(x)): k for k, (y, x) in enumerate(zip(lev.ty, lev.tx, strict=True))}
    for top, left in ((22, 32), (22, 52)):  # two blocks, both copying rows 40.., columns 10..
        for dy in range(9):
            for dx in range(9):
                nnf[by_pos[(top + dy, left + dx)]] = (44 + dy, 10 + dx)
    for dy in range(9):  # a third block copied once
        for dx in range(9):
            nnf[by_pos[(30 + dy, 42 + dx)]] = (44 + dy, 40 + dx)
    dist = np.full(lev.ty.size, 2.0, np.float32)
    cost = exemplar._reuse_cost(lev, nnf, dist, side, 1.5)
    # Centres whose whole 3x3 window is inside the doubly copied block: twice -> 1.5 x 2.0 x 1.
    np.testing.assert_allclose(cost[45:52, 11:18], 3.0, atol=1e-5)
    np.testing.assert_array_equal(cost[45:52, 41:48], 0.0)  # inside the block copied once
    assert cost[30, 10] == 0.0  # a source nobody copies
    assert not exemplar._reuse_cost(lev, nnf, dist, side, 0.0).any()


def test_the_reuse_penalty_changes_the_painting_and_keeps_the_known_pixels():
    """The penalty is in the search: with and without it the same hole is painted differently,
    every known pixel kept."""
    img, hole = _ramp()
    rng = np.random.default_rng(1)
    noisy = np.clip(img + rng.normal(0, 12, img.shape), 0, 255).astype(np.uint8)
    a = complete(noisy, hole, ExemplarSettings(reuse_penalty=0.0))
    b = complete(noisy, hole, ExemplarSettings(reuse_penalty=1.0))
    assert not np.array_equal(a[hole], b[hole])
    np.testing.assert_array_equal(b[~hole], noisy[~hole])
