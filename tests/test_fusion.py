"""The fuse stage's bookkeeping: a single reference passes through untouched, and the labels,
source map and supplied fractions are computed on the renders' window only."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from geofill.composite.inpaint import mask_window
from geofill.config import FillConfig
from geofill.fuse import Fusion, fuse_references, gaussian_blur
from geofill.render import RenderResult
from geofill.utils.distance import known_ring


def _single_reference(index: int = 2):
    h, w = 90, 120
    hole = np.zeros((h, w), bool)
    hole[20:60, 30:80] = True
    hole[85:, :5] = True  # a piece of the hole no render reaches
    roi = (20, 10, 95, 70)
    alpha = np.zeros((h, w), bool)
    alpha[12:68, 22:93] = True
    alpha[40:50, 50:60] = False
    image = np.zeros((h, w, 3), np.uint8)
    image[alpha] = 123
    empty = np.full((h, w), -1.0, np.float32)
    render = RenderResult(empty, empty, np.full((h, w), np.inf, np.float32), alpha, roi)
    refined = SimpleNamespace(image=image, alpha=alpha, render=render)
    return hole, SimpleNamespace(index=index, refined=refined, screened=refined)


def test_single_reference_passes_its_render_through():
    hole, ref = _single_reference()
    target = np.full((*hole.shape, 3), 50, np.uint8)
    fusion = fuse_references(target, hole, [ref], FillConfig())
    assert fusion.image is ref.refined.image and fusion.alpha is ref.refined.alpha
    np.testing.assert_array_equal(fusion.labels, np.where(ref.refined.alpha & hole, 2, 0))
    assert fusion.labels.dtype == np.int16
    expected_map = np.where(hole, np.where(ref.refined.alpha & hole, 2, 0), -1)
    np.testing.assert_array_equal(fusion.source_map(hole), expected_map)
    supplied = (ref.refined.alpha & hole).sum() / hole.sum()
    np.testing.assert_allclose(fusion.supplied_fractions(hole, 3), [0.0, supplied, 0.0])
    assert (
        fusion.summary() == f"single reference: 1 reference(s) supply {(ref.refined.alpha & hole).sum()} px"
    )


def test_no_reference():
    hole, _ = _single_reference()
    fusion = fuse_references(np.zeros((*hole.shape, 3), np.uint8), hole, [], FillConfig())
    assert fusion.image is None and not fusion.labels.any()
    np.testing.assert_array_equal(fusion.source_map(hole), np.where(hole, 0, -1))
    assert fusion.supplied_fractions(hole, 1) == [0.0]


def test_window_defaults_to_the_whole_image():
    labels = np.zeros((4, 5), np.int16)
    labels[3, 4] = 1
    fusion = Fusion(np.zeros((4, 5, 3), np.uint8), labels > 0, labels, "test")
    hole = np.ones((4, 5), bool)
    assert fusion.supplied_fractions(hole, 1) == [1 / 20]


def test_known_ring_of_a_window_holding_the_hole_equals_the_whole_image():
    hole = np.zeros((200, 300), bool)
    hole[50:120, 80:200] = True
    hole[130:135, 60:70] = True
    whole = known_ring(hole, 16.0)
    assert whole.sum() > 0 and not (whole & hole).any()
    for margin in (0, 24):  # the bare bounding box, and one the whole ring fits in
        rows, cols = mask_window(hole, margin)
        np.testing.assert_array_equal(known_ring(hole[rows, cols], 16.0), whole[rows, cols])


@pytest.mark.parametrize("sigma", [3.0, 48.0])  # the direct filter, and the Fourier-domain one
def test_gaussian_blur_equals_opencvs_to_float_rounding(sigma):
    rng = np.random.default_rng(1)
    image = np.zeros((300, 260), np.float32)
    image[100:140, 20:200] = rng.random((40, 180))  # a ring-like band near one border
    ref = cv2.GaussianBlur(image, (0, 0), sigma)
    out = gaussian_blur(image, sigma)
    assert out.dtype == np.float32 and out.shape == image.shape
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-5 * ref.max())
