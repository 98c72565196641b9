"""The exact distance transform: SciPy's answer bit for bit, known geometry, no mask."""

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from geofill.utils.distance import distance_to


@pytest.mark.parametrize(
    "shape,density", [((1, 7), 0.3), ((9, 1), 0.3), ((37, 53), 0.01), ((240, 320), 0.001), ((64, 48), 0.5)]
)
def test_equals_scipys_exact_transform_bit_for_bit(shape, density):
    rng = np.random.default_rng(len(shape) + shape[0])
    for _ in range(4):
        mask = rng.random(shape) < density
        mask.flat[rng.integers(mask.size)] = True
        got = distance_to(mask)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, distance_transform_edt(~mask).astype(np.float32))


def test_a_pythagorean_triple_and_a_disc():
    mask = np.zeros((10, 10), bool)
    mask[1, 2] = True
    d = distance_to(mask)
    assert d[5, 5] == 5.0  # 4 down, 3 across
    assert d[1, 2] == 0.0 and d[1, 9] == 7.0
    disc = np.zeros((101, 101), bool)
    yy, xx = np.mgrid[:101, :101]
    disc[(yy - 50) ** 2 + (xx - 50) ** 2 <= 20**2] = True
    d = distance_to(disc)
    outside = ~disc
    # Outside a disc of radius 20 the distance is the radial one less ~20 (pixel-grid boundary).
    radial = np.hypot(yy - 50, xx - 50) - 20
    assert np.abs(d[outside] - radial[outside]).max() < 1.0


def test_no_mask_pixel_means_infinitely_far():
    assert np.isinf(distance_to(np.zeros((3, 4), bool))).all()
    assert (distance_to(np.ones((3, 4), bool)) == 0).all()


def test_rejects_a_mask_that_is_not_2d():
    with pytest.raises(ValueError, match="2-D mask"):
        distance_to(np.zeros((2, 3, 4), bool))
