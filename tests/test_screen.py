"""The screen stage: reference pixels the user masked are never copied, exactly where the render's
correspondence field reads them; a stranger in the reference that reaches beyond the hole is not
copied into it; a hole that shows nothing, in a reference that shows the scene, refuses nothing."""

from __future__ import annotations

import numpy as np
import pytest

from geofill.config import FillConfig
from geofill.errors import MaskSizeError
from geofill.pipeline import fill
from geofill.synthetic import blanked, make_pair


@pytest.fixture(scope="module")
def pair():
    return make_pair(seed=0, width=320, height=240)


@pytest.fixture(scope="module")
def plain(pair):
    return fill(blanked(pair.target, pair.hole), pair.hole, pair.source)


def test_blank_hole_and_no_mask_refuse_nothing(plain):
    screened, refined = plain.references[0].screened, plain.references[0].refined
    assert screened.image is refined.image and screened.alpha is refined.alpha
    assert set(plain.report.refused_fraction.values()) == {0.0} and plain.report.refused_words() == ""
    assert plain.report.references[0]["screen"]["refused_masked_fraction"] == 0.0


def test_masked_reference_pixels_are_refused_where_the_field_reads_them(pair, plain):
    h, w = pair.source.shape[:2]
    mask = np.zeros((h, w), bool)
    split = 230  # the hole's render reads source columns 172-292: both sides of this one
    mask[:, :split] = True
    res = fill(blanked(pair.target, pair.hole), pair.hole, pair.source, source_masks=[mask])
    ref = res.references[0]
    field = ref.refined.render
    covered = ref.refined.alpha & pair.hole
    # Nearest sampling of the mask at the (flow-corrected) correspondence field.
    reads_masked = covered & (np.floor(field.map_x + 0.5) < split)
    assert reads_masked.sum() > 500 and (covered & ~reads_masked).sum() > 500  # both halves land in the hole
    np.testing.assert_array_equal(ref.screened.refused_masked, reads_masked)
    assert not (ref.screened.alpha & reads_masked).any()
    assert (ref.screened.image[reads_masked] == 0).all()
    # What was not masked is the plain fill's render, pixel for pixel.
    keep = covered & ~reads_masked
    np.testing.assert_array_equal(ref.screened.image[keep], plain.references[0].screened.image[keep])
    frac = reads_masked.sum() / pair.hole.sum()
    assert res.report.refused_fraction["masked"] == pytest.approx(frac)
    assert res.report.supplied_fraction[0] == pytest.approx(plain.report.supplied_fraction[0] - frac)
    assert f"{100 * frac:.0f}% of the hole was not copied because it was masked" in res.report.refused_words()


def test_wrong_size_reference_mask_is_one_clear_error(pair):
    with pytest.raises(MaskSizeError, match=r"mask of source 1: mask is 10x10 but its reference is 320x240"):
        fill(blanked(pair.target, pair.hole), pair.hole, pair.source, source_masks=[np.zeros((10, 10), bool)])


def test_a_stranger_reaching_beyond_the_hole_is_not_copied(pair, plain):
    field = plain.references[0].refined.render
    covered = plain.references[0].refined.alpha & pair.hole
    # A red disc in the reference, centred where the render reads a hole pixel 25 px in from the
    # hole's left end: most of it lands in the hole, some around it (where the target disagrees).
    ys, xs = np.nonzero(covered)
    x0 = xs.min() + 25
    y0 = int(np.median(ys[xs == x0]))
    h, w = pair.source.shape[:2]
    yy, xx = np.mgrid[:h, :w]
    disc = (xx - field.map_x[y0, x0]) ** 2 + (yy - field.map_y[y0, x0]) ** 2 < 35**2
    source = pair.source.copy()
    source[disc] = (230, 20, 20)
    rows = np.clip(np.rint(field.map_y), 0, h - 1).astype(int)
    cols = np.clip(np.rint(field.map_x), 0, w - 1).astype(int)
    lands = covered & disc[rows, cols]
    assert lands.sum() > 2000

    def red(image):
        return (image[..., 0].astype(int) - np.maximum(image[..., 1], image[..., 2]) > 60) & pair.hole

    target = blanked(pair.target, pair.hole)
    off = fill(target, pair.hole, source, FillConfig().updated({"screen.stranger_threshold": 0}))
    assert red(off.image).sum() > 0.3 * lands.sum()  # without the test it is pasted in
    on = fill(target, pair.hole, source)
    refused = on.references[0].screened.refused_stranger
    assert (refused & lands).sum() > 0.7 * lands.sum() and (refused & ~lands).sum() < 0.15 * lands.sum()
    assert red(on.image).sum() < 0.15 * red(off.image).sum()
    assert on.report.refused_fraction["stranger"] == pytest.approx(refused.sum() / pair.hole.sum())
    assert "your photo does not show around it" in on.report.refused_words()
