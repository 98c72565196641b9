"""A reference whose render does not line up with the photo around the hole, while another's does,
is not used (geofill.fuse.lineup): known textures and shifts, and the NLE tower's set, whose
references 3 and 4 see the tower's other side (../shared/data/multiview, skipped when absent)."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from geofill import FillConfig, fill
from geofill.evaluation.pairs import load_pair, pair_mask
from geofill.fuse.lineup import LineUp, misaligned, ring_correlation
from geofill.render import RenderResult

SIZE = 640


@pytest.fixture(scope="module")
def scene():
    """A textured photo (blurred noise, features a few px wide) with a square hole in its middle."""
    rng = np.random.default_rng(3)
    photo = cv2.GaussianBlur(rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8), (0, 0), 1.5)
    hole = np.zeros((SIZE, SIZE), bool)
    hole[240:400, 220:420] = True
    return photo, hole


def shifted(dx: float, dy: float) -> RenderResult:
    """A render that shows each target pixel's source pixel ``(dx, dy)`` px away (where there is one)."""
    ys, xs = np.mgrid[:SIZE, :SIZE].astype(np.float32)
    mx, my = xs + dx, ys + dy
    inside = (mx >= 0) & (mx <= SIZE - 1) & (my >= 0) & (my <= SIZE - 1)
    return RenderResult(mx, my, np.ones_like(xs), inside)


def test_a_render_that_lines_up_correlates_whatever_its_exposure(scene):
    photo, hole = scene
    darker = np.clip(photo * 0.6 + 30, 0, 255).astype(np.uint8)  # another exposure, same structure
    assert ring_correlation(shifted(0, 0), photo, photo, hole).correlation > 0.99
    assert ring_correlation(shifted(0, 0), darker, photo, hole).correlation > 0.99
    # A pixel off still correlates; a structure of its own (this texture tens of px away) does not.
    assert ring_correlation(shifted(1, 0), photo, photo, hole).correlation > 0.4
    for dx, dy in [(80, 50), (-60, 34), (26, -82)]:
        assert abs(ring_correlation(shifted(dx, dy), photo, photo, hole).correlation) < 0.1


def test_a_flat_ring_or_a_render_that_misses_the_ring_is_not_judged(scene):
    photo, hole = scene
    flat = np.full_like(photo, 128)
    assert np.isnan(ring_correlation(shifted(0, 0), flat, flat, hole).correlation)
    away = shifted(0, 0)
    alpha = np.zeros_like(away.alpha)
    alpha[:, :80] = True  # covers none of the ring
    assert np.isnan(ring_correlation(replace(away, alpha=alpha), photo, photo, hole).correlation)


def test_a_reference_is_dropped_only_against_one_that_lines_up():
    cfg = FillConfig().fusion
    good, off, loose = LineUp(0.6, 9000), LineUp(0.02, 8000), LineUp(0.25, 7000)
    assert list(misaligned({1: good, 2: off, 3: loose}, cfg)) == [2]
    # No reference lines up well (a loosely aligned set, Lund's): nothing is decided.
    assert misaligned({1: loose, 2: off}, cfg) == {}
    assert misaligned({1: good, 2: LineUp(float("nan"), 10)}, cfg) == {}
    assert misaligned({1: good, 2: off}, replace(cfg, misaligned_correlation=-1.0)) == {}


def test_the_towers_other_side_is_not_pasted_into_the_hole(multiview_dir):
    pair = load_pair(multiview_dir / "dev_mv_mast3r_nle_tower")
    hole = pair_mask(pair, 0)
    result = fill(pair.target, hole, pair.sources, FillConfig())
    refs = {r["index"]: r for r in result.report.references}
    # References 3 and 4 see the far side of the tower: their renders do not correlate with the
    # photo around the hole (0.04-0.05) where reference 2's does (0.75).
    assert [i for i, r in refs.items() if r.get("dropped_at") == "line-up"] == [3, 4]
    assert "does not line up" in refs[3]["reason"] and refs[2]["status"] == "used"
