"""Straight edges across the hole are continued before the texture is painted."""

from __future__ import annotations

import cv2
import numpy as np

from geofill.composite import lines
from geofill.composite.lines import continue_lines
from geofill.composite.rectify import paint


def _wall_with_a_bar(width: int = 3, ends_at: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """A 240x320 plaster-like wall (smooth value noise, 150-200 grey) crossed by a dark bar
    ``width`` px wide at 20 degrees (up to column ``ends_at``), and the bar's centre line (signed
    distance, px, per pixel)."""
    rng = np.random.default_rng(3)
    h, w = 240, 320
    noise = rng.normal(0.0, 1.0, (h // 8 + 2, w // 8 + 2))
    wall = cv2.resize(noise, (w + 16, h + 16), interpolation=cv2.INTER_CUBIC)[8 : 8 + h, 8 : 8 + w]
    wall = 175 + 12 * wall + rng.normal(0.0, 4.0, (h, w))
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    angle = np.radians(20.0)
    dist = (xs - 160) * np.sin(angle) - (ys - 120) * np.cos(angle)
    grey = np.where((np.abs(dist) <= width / 2) & (xs < ends_at), 40.0, wall)
    return np.clip(np.rint(np.dstack([grey, grey * 0.97, grey * 0.92])), 0, 255).astype(np.uint8), dist


def _disc(cx: float, cy: float, r: float) -> np.ndarray:
    ys, xs = np.mgrid[0:240, 0:320]
    return (xs - cx) ** 2 + (ys - cy) ** 2 <= r * r


def test_a_bar_across_the_hole_runs_on_through_it():
    """A dark bar on a wall, a 45-px disc over it: every hole pixel on the bar's centre line is
    painted dark (below 100, the bar is 40, the wall 150-200), and no hole pixel more than 4 px
    from it is (the painter without the bar's continuation: 23 % of the centre line dark, the bar
    broken)."""
    image, dist = _wall_with_a_bar()
    hole = _disc(160, 120, 45)
    blank = image.copy()
    blank[hole] = 0
    out = paint(blank, hole, None, None)
    grey = out[..., 0].astype(int)
    centre = hole & (np.abs(dist) <= 0.5)
    assert (grey[centre] < 100).all()
    assert not (grey[hole & (np.abs(dist) > 4)] < 100).any()
    np.testing.assert_array_equal(out[~hole], blank[~hole])


def test_edges_that_do_not_cross_the_hole_are_left_alone():
    """A bar that ends in the hole (nothing of it on the far side) is not continued, nor are the
    hole's own edges taken for lines."""
    image, _ = _wall_with_a_bar(ends_at=160)
    hole = _disc(160, 120, 45)
    blank = image.copy()
    blank[hole] = 0
    assert not continue_lines(blank.copy(), hole, 7).any()


def test_pairs_tested_at_once_keep_every_collinear_pair():
    # Many segments, some in nearly collinear pairs across a gap: the quick all-pairs test must keep
    # every pair the exact test accepts (the painter would otherwise lose an edge).
    rng = np.random.default_rng(3)
    ends = []
    for _ in range(60):
        near = rng.uniform(0, 300, 2)
        angle = rng.uniform(0, 2 * np.pi)
        d = np.array([np.cos(angle), np.sin(angle)])
        ends.append((near, near - rng.uniform(15, 60) * d))
        # Its partner across a gap along the same line, turned by up to 3 degrees.
        turn = np.radians(rng.uniform(-3, 3))
        rot = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
        start = near + rng.uniform(10, 40) * d + rng.normal(0, 0.5, 2)
        ends.append((start, start + rng.uniform(15, 60) * (rot @ d)))
    exact = {
        (i, j)
        for i in range(len(ends))
        for j in range(i + 1, len(ends))
        if lines._collinear(ends[i], ends[j]) is not None
    }
    quick = lines._facing_pairs(ends)
    assert len(exact) >= 20
    assert exact <= set(quick)
    assert len(quick) < 0.05 * len(ends) * (len(ends) - 1) / 2
