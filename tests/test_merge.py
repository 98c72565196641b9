"""Composite and single-image inpainting on windows: the hole's bounding box (plus what the
inpainter reads) must give the same pixels as working on the whole image."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from geofill.composite.inpaint import Inpainter, get_inpainter
from geofill.composite.merge import blend_map, merge_fill
from geofill.config import InpaintConfig
from geofill.utils.windows import mask_window


def _scene(h: int = 240, w: int = 320, seed: int = 0):
    rng = np.random.default_rng(seed)
    # Smooth colour gradients plus texture, so Telea's result depends on what it reads.
    yy, xx = np.mgrid[0:h, 0:w]
    base = np.stack([xx * 255 / w, yy * 255 / h, (xx + yy) * 127 / (w + h)], axis=-1)
    target = np.clip(base + rng.normal(0, 20, (h, w, 3)), 0, 255).astype(np.uint8)
    render = np.clip(base[..., ::-1] + rng.normal(0, 20, (h, w, 3)), 0, 255).astype(np.uint8)
    hole = np.zeros((h, w), bool)
    hole[60:170, 90:230] = True
    hole[0:30, 300:] = True  # a second piece at the image border
    alpha = np.ones((h, w), bool)
    alpha[80:140, 150:200] = False  # a disocclusion: ramp and inpainting
    alpha[100, 100:104] = False  # a crack: inpainted without a ramp
    alpha[0:15, 300:] = False
    return target, hole, render, alpha


@pytest.mark.parametrize("method", ["telea", "ns"])
def test_windowed_opencv_inpainting_equals_the_whole_image(method):
    target, hole, _, _ = _scene()
    inp = get_inpainter(InpaintConfig(method=method))
    assert inp.context_px == 7  # ceil(radius 5) + 2
    whole = cv2.inpaint(
        target, hole.astype(np.uint8), 5.0, cv2.INPAINT_TELEA if method == "telea" else cv2.INPAINT_NS
    )
    np.testing.assert_array_equal(inp.fill(target, hole), whole)


def test_blend_map_of_a_window_holding_the_hole_equals_the_whole_map():
    _, hole, _, alpha = _scene()
    hole[0:30, 300:] = False
    full = blend_map(hole, alpha, 8.0)
    assert 0 < (full[hole] < 1).sum() < hole.sum()  # there is a ramp
    rows, cols = mask_window(hole, 3)
    np.testing.assert_array_equal(blend_map(hole[rows, cols], alpha[rows, cols], 8.0), full[rows, cols])
    assert not full[~hole].any()


def test_windowed_merge_equals_the_whole_image_merge():
    """The same inpainter told it may read anywhere (context None: no window) gives the same bytes."""
    target, hole, render, alpha = _scene()
    telea = get_inpainter(InpaintConfig(method="telea"))
    unwindowed = Inpainter("telea", "telea", telea.run, context_px=None)
    out = merge_fill(target, hole, render, alpha, telea, 8.0)
    np.testing.assert_array_equal(out, merge_fill(target, hole, render, alpha, unwindowed, 8.0))
    np.testing.assert_array_equal(out[~hole], target[~hole])
    covered = hole & alpha & (blend_map(hole, alpha, 8.0) == 1.0)
    np.testing.assert_array_equal(out[covered], render[covered])


def test_mask_window():
    mask = np.zeros((50, 60), bool)
    mask[10:20, 55:58] = True
    assert mask_window(mask, 4) == (slice(6, 24), slice(51, 60))
    assert mask_window(mask, None) == (slice(0, 50), slice(0, 60))
    assert mask_window(np.zeros((5, 6), bool), 2) == (slice(0, 5), slice(0, 6))
