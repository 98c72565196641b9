"""The screen stage: reference pixels the user masked are never copied, exactly where the render's
correspondence field reads them; a hole that shows nothing refuses nothing."""

from __future__ import annotations

import numpy as np
import pytest

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
    assert plain.report.refused_fraction == {} and plain.report.refused_words() == ""
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
