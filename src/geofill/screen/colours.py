"""The removed object's own colours, wherever a render brings them back.

The depth, surface and look tests leave pieces of the object they cannot place: on the panel's
apple, slivers of its red from two of the four frames, 9-50 px from what those tests refused (the
patch test runs at 320 px, where a sliver a few pixels wide is a speck it opens away). What such
pieces share is colour: the object's own, which the ring around the hole does not have (the
brushed margin shows the ring's background, so the margin's colours are the ring's). A colour is the
object's when the hole's content has it at least :data:`DISTINCT_RATIO` times as often as the ring
does and the ring hardly has it at all (CIELAB bins: 4 lightness x 16 x 16 chroma, so shade does not
matter; the bins beside it count too, as the same colour in another frame can cross a bin's edge).
Render pixels of those colours, in parts at least half ``screen.stranger_min_px`` across, are the
object coming back. The hole must have the colour :data:`DISTINCT_RATIO` times as often as a wider
ring (:data:`WIDE_RING_PX`) too: a repeating background (the fox's wallpaper roses, behind an orange
cutout with some of their reds) can miss the narrow ring and lie a little farther out, as common
there as in the hole. A cap on the wider ring's share alone, as on the narrow one's, was too blunt:
a textured box's own colour on 2.5 % of the wider ring (a synthetic scene repeats its textures) came
back with it, and over the whole photo the apple's shadow shares the grey of a pasted shoe. A
background the object hid, in a colour not common near the hole, is refused with it: painted, not
copied.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..config import ScreenConfig
from ..utils.distance import known_ring
from ..utils.parts import large_parts
from ..utils.resolution import config_px
from ..utils.windows import mask_window

#: A colour bin is the object's when the hole's content has it this many times as often as the ring
#: around the hole, at least :data:`MIN_SHARE` of the hole's pixels have it and at most
#: :data:`MAX_RING_SHARE` of the ring's: a colour the ring shows at all may be the background the
#: object hides (the lit brick of a doorway behind a pedestrian, 2.7 % of the ring, 16 % of the hole).
DISTINCT_RATIO = 4.0
MIN_SHARE = 0.01
MAX_RING_SHARE = 0.005
#: ... and at least this share of its hole pixels have a 4-neighbour of that colour (a random
#: noise object has each colour on about 1 % of the hole, scattered: 0-6 % have such a neighbour).
COHERENT = 0.5
#: Width of the ring the colours are counted on, and of the wider one (see the module docstring),
#: px at 1280. On the fox's wallpaper the roses' main red is 0.1 % of the narrow ring, 1.5 % of the
#: wider and 2.4 % of the hole; the apple's own reds at most 0.1 % of either ring.
RING_PX = 30.0
WIDE_RING_PX = 90.0
_BINS = 4 * 16 * 16


def _beside_alike(bins: np.ndarray) -> np.ndarray:
    """HxW bool: the pixels with a 4-neighbour in the same bin."""
    out = np.zeros(bins.shape, bool)
    same_x, same_y = bins[:, 1:] == bins[:, :-1], bins[1:] == bins[:-1]
    out[:, 1:] |= same_x
    out[:, :-1] |= same_x
    out[1:] |= same_y
    out[:-1] |= same_y
    return out


def colour_bins(image: np.ndarray) -> np.ndarray:
    """HxW int32: each pixel's CIELAB bin (4 lightness x 16 x 16 chroma) of ``image`` (HxWx3 uint8 RGB).

    >>> colour_bins(np.array([[[255, 0, 0], [0, 0, 255]]], np.uint8)).tolist()
    [[732, 449]]
    """
    lab = cv2.cvtColor(image, cv2.COLOR_RGB2LAB).astype(np.int32)
    return (lab[..., 0] // 64) * 256 + (lab[..., 1] // 16) * 16 + lab[..., 2] // 16


def colour_shares(image: np.ndarray, where: np.ndarray) -> np.ndarray:
    """Per colour bin (:func:`colour_bins`), its share of the ``where`` pixels of ``image``.

    >>> colour_shares(np.array([[[255, 0, 0], [0, 0, 255]]], np.uint8), np.array([[True, False]]))[732]
    np.float64(1.0)
    """
    return np.bincount(colour_bins(image)[where], minlength=_BINS) / max(int(np.count_nonzero(where)), 1)


def wide_ring_shares(shown: np.ndarray, hole: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """:func:`colour_shares` of ``shown``'s known pixels within :data:`WIDE_RING_PX` of ``hole``
    (worked on the hole's box grown by that much). ``shape``: the full image's (for pixel units)."""
    px = config_px(WIDE_RING_PX, shape)
    rows, cols = mask_window(hole, int(np.ceil(px)) + 1)
    return colour_shares(shown[rows, cols], known_ring(hole[rows, cols], px))


def object_colours(
    render: np.ndarray,
    covered: np.ndarray,
    shown: np.ndarray,
    hole: np.ndarray,
    shape: tuple[int, ...],
    sc: ScreenConfig,
    wide: np.ndarray | None = None,
) -> np.ndarray:
    """HxW bool: the ``covered`` hole pixels where ``render`` (HxWx3 uint8, colour-corrected to the
    target) shows the removed object's own colours (see the module docstring). ``shown``: the
    target as given, its hole showing the object; ``shape``: the full image's (for pixel units);
    ``wide``: :func:`wide_ring_shares` of the whole photo when ``shown`` is a window of it that
    may not hold the wider ring (default: found in ``shown``)."""
    ring = known_ring(hole, config_px(RING_PX, shape))
    bins = colour_bins(shown)
    count = np.bincount(bins[hole], minlength=_BINS)
    in_hole = count / max(int(hole.sum()), 1)
    in_ring = np.bincount(bins[ring], minlength=_BINS) / max(int(ring.sum()), 1)
    if wide is None:
        wide = wide_ring_shares(shown, hole, shape)
    rare = in_ring <= MAX_RING_SHARE
    # An object's colour lies in regions; noise puts each colour on scattered pixels.
    together = np.bincount(bins[hole & _beside_alike(bins)], minlength=_BINS) >= COHERENT * count
    distinct = (
        (in_hole >= MIN_SHARE) & (in_hole >= DISTINCT_RATIO * np.maximum(in_ring, wide)) & rare & together
    )
    if not distinct.any():
        return np.zeros(hole.shape, bool)
    # The same colour in another frame can fall in the next chroma bin: the bins beside an object's
    # colour count too, where neither ring has them more than the narrow ring may.
    square = np.ones((3, 3), np.uint8)
    beside = np.stack([cv2.dilate(g, square) for g in distinct.reshape(4, 16, 16).astype(np.uint8)])
    distinct |= beside.ravel().astype(bool) & rare & (wide <= MAX_RING_SHARE)
    found = covered & distinct[colour_bins(render)]
    side = max(3, round(config_px(sc.stranger_min_px, shape) / 2))
    kept = large_parts(found, 3, side * side)
    # The piece's own edge blends it with what lies behind: taken with it.
    grown = cv2.dilate(kept.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))) > 0
    return grown & covered
