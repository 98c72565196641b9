"""The screen's stranger test: a passer-by or a car that moved shows in a reference and not in the
target. Where one reaches beyond the hole, the render disagrees with the target around the hole;
the render content that continues it into the hole is refused, grown from there by OpenCV's
watershed against the render pixels that agree with the target. It runs on every fill, hole blanked
or not."""

from __future__ import annotations

import cv2
import numpy as np

from ..config import ScreenConfig
from ..utils.distance import known_ring
from ..utils.parts import large_parts
from ..utils.resolution import config_px, odd_px

#: Long side (px) at which the stranger test runs: it finds regions tens of pixels wide, and at full
#: resolution its watershed and statistics cost a tenth of a 1280-px fill.
STRANGER_TEST_SIDE = 640
#: Long side (px) at which a stranger's unexplained continuation is found: a k-d tree query per
#: hole patch, and a passer-by's clothes need no finer detail.
NOVELTY_TEST_SIDE = 320
#: Largest share of the hole the render covers that a stranger's unexplained continuation may be.
_CONTINUATION_SHARE = 0.1
#: What the target's hole holds while it is shifted: a level no image has.
_NOWHERE = np.float32(1e4)


def strangers(
    render: np.ndarray,
    target: np.ndarray,
    hole: np.ndarray,
    alpha: np.ndarray,
    shape: tuple[int, ...],
    sc: ScreenConfig,
) -> np.ndarray:
    """Hole pixels of a window (covered by ``alpha``) whose render continues content that the target
    does not show around the hole: regions of the render within ``sc.stranger_ring_px`` of the hole
    that disagree with ``target`` (after the median colour difference there is taken out; over
    ``sc.stranger_threshold``, and over ``sc.stranger_shift_threshold`` with either of the two shifted by
    up to 12 px; wide and large enough, near the hole) are grown into it by the watershed, against
    the pixels that agree with the target (under ``sc.stranger_agreement``). ``shape``: the full
    target's, for pixel scaling. Runs with the window's long side at most :data:`STRANGER_TEST_SIDE`.

    >>> hole = np.zeros((40, 60), bool); hole[10:30, 20:40] = True
    >>> target = np.full((40, 60, 3), 120, np.uint8); target[hole] = 0
    >>> render = np.full((40, 60, 3), 120, np.uint8); render[:, 34:] = 240  # a stranger
    >>> out = strangers(render, target, hole, np.ones((40, 60), bool), (720, 1280), ScreenConfig())
    >>> bool(out[:, 35:].sum() == hole[:, 35:].sum()), bool(out[:, :34].any())  # (the seam: unlabelled)
    (True, False)
    """
    h, w = hole.shape
    f = min(1.0, STRANGER_TEST_SIDE / max(h, w))
    px = config_px(1.0, shape) * f
    if f == 1.0:
        return _strangers(render, target, hole, alpha, px, sc)
    size = (max(round(w * f), 1), max(round(h * f), 1))

    def small(mask: np.ndarray) -> np.ndarray:
        return cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0

    found = _strangers(
        cv2.resize(render, size, interpolation=cv2.INTER_AREA),
        cv2.resize(target, size, interpolation=cv2.INTER_AREA),
        small(hole),
        small(alpha),
        px,
        sc,
    )
    return (cv2.resize(found.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0) & alpha & hole


def stranger_region(
    render: np.ndarray,
    target: np.ndarray,
    hole: np.ndarray,
    alpha: np.ndarray,
    shape: tuple[int, ...],
    sc: ScreenConfig,
    removal: bool,
) -> np.ndarray:
    """:func:`strangers`, grown by :func:`continuation` where ``sc.stranger_unexplained`` and the
    hole shows something to remove (``removal``). Only then: a brush over an object takes in the
    surface the ring shows, so that content the ring does not explain there is more likely an
    occluder, while a hole over the background itself holds what the ring does not show (there it
    cost the multi-reference sets' restoration: docs/architecture.md)."""
    found = strangers(render, target, hole, alpha, shape, sc)
    if removal and sc.stranger_unexplained and found.any():
        found |= continuation(render, target, hole, alpha, found, shape, sc)
    return found


def continuation(
    render: np.ndarray,
    target: np.ndarray,
    hole: np.ndarray,
    alpha: np.ndarray,
    found: np.ndarray,
    shape: tuple[int, ...],
    sc: ScreenConfig,
) -> np.ndarray:
    """The hole pixels of a window (covered by ``alpha``) where ``render`` shows content that the
    ring around the hole does not explain (:func:`~geofill.screen.surface.unexplained`, against the
    ring pixels where the render agrees with ``target``) and that is connected to ``found`` (the
    strangers :func:`strangers` refused): the rest of a passer-by whose white shirt the watershed
    took for the pale steps around it. Run with the long side at most :data:`NOVELTY_TEST_SIDE`.

    >>> hole = np.zeros((60, 100), bool); hole[10:50, 20:80] = True
    >>> target = np.full((60, 100, 3), 120, np.uint8); target[hole] = 0
    >>> render = target.copy(); render[hole] = 120; render[12:40, 48:52] = 20; render[30:34, 25:29] = 230
    >>> found = np.zeros_like(hole); found[12:14, 48:52] = True  # the top of a stranger
    >>> out = continuation(render, target, hole, np.ones_like(hole), found, (720, 1280), ScreenConfig())
    >>> bool(out[14:38, 48:52].all()), bool(out[30:34, 25:29].any())  # his legs; not another thing
    (True, False)
    """
    from .surface import unexplained

    h, w = hole.shape
    f = min(1.0, NOVELTY_TEST_SIDE / max(h, w))
    size = (max(round(w * f), 1), max(round(h * f), 1))

    def small(mask: np.ndarray) -> np.ndarray:
        return cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0

    r = cv2.resize(render, size, interpolation=cv2.INTER_AREA)
    t = cv2.resize(target, size, interpolation=cv2.INTER_AREA)
    s_hole, s_alpha, s_found = small(hole), small(alpha), small(found)
    px = config_px(1.0, shape) * f
    ring = s_alpha & known_ring(s_hole, sc.stranger_ring_px * px)
    if not ring.any():
        return np.zeros(hole.shape, bool)
    level = t.astype(np.float32) + np.median(r[ring].astype(np.float32) - t[ring], axis=0)
    agree = ring & (cv2.blur(np.abs(r - level).mean(axis=2), (3, 3)) < sc.stranger_agreement)
    novel = unexplained(r, s_hole & s_alpha, agree) & ~s_found
    _, labels, stats, _ = cv2.connectedComponentsWithStats(novel.astype(np.uint8), connectivity=8)
    # A passer-by is a small part of what the render shows in the hole: larger unexplained content
    # is the background a reference sees from elsewhere (a wide baseline, a disocclusion), which a
    # disagreeing speck beside it must not take down with it.
    most = _CONTINUATION_SHARE * np.count_nonzero(s_hole & s_alpha)
    near = cv2.dilate(s_found.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    touched = np.unique(labels[near & novel])
    grown = np.zeros(s_hole.shape, bool)
    for i in touched[touched > 0]:
        if stats[i, cv2.CC_STAT_AREA] <= most:
            grown |= labels == i
    return (cv2.resize(grown.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0) & alpha & hole


def _strangers(
    render: np.ndarray, target: np.ndarray, hole: np.ndarray, alpha: np.ndarray, px: float, sc: ScreenConfig
) -> np.ndarray:
    """:func:`strangers` at the resolution given, ``px`` pixels per config pixel."""
    ring = alpha & known_ring(hole, sc.stranger_ring_px * px)
    if not ring.any():
        return np.zeros(hole.shape, bool)
    k = odd_px(5.0 * px)
    # The exposure and white balance of the two photos: the median difference around the hole.
    level = target.astype(np.float32) + np.median(render[ring].astype(np.float32) - target[ring], axis=0)
    raw = np.abs(render - level).mean(axis=2)
    diff = cv2.blur(raw, (k, k))
    # Both the box mean and the pixel itself: the mean alone spreads a stranger's edge outwards. A
    # render that is only misaligned (depth off at an occlusion edge) agrees with the target once
    # either is shifted a little; other content disagrees with one of the two shifted. The render
    # shifted finds the ground beside a stranger narrower than the reach (a passer-by a few pixels
    # wide) and agrees there; the target shifted finds a smooth render's colour somewhere in a
    # textured target. The target's blanked hole matches nothing (a dark stranger at its edge
    # matched its zeros).
    reach = 12.0 * px
    seeds = ring & (diff > sc.stranger_threshold) & (raw > sc.stranger_threshold)
    fixed_target = shifted_min_diff(render, level, k, reach)
    fixed_render = shifted_min_diff(np.where(hole[..., None], _NOWHERE, level), render, k, reach)
    seeds &= np.maximum(fixed_target, fixed_render) > sc.stranger_shift_threshold
    # An opening removes the thin lines that misalignment leaves along edges.
    m = max(3, odd_px(sc.stranger_min_px / 2 * px))
    # Within the shift's reach of the hole: the band a shift explains lies between.
    near = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (odd_px(2 * reach + 3),) * 2)
    touching = cv2.dilate(hole.astype(np.uint8), near) > 0
    seeded = large_parts(seeds, m, (sc.stranger_min_px * px) ** 2, touching)
    agree = ring & (diff < sc.stranger_agreement)
    if not seeded.any() or not agree.any():
        return np.zeros(hole.shape, bool)
    # Watershed (not a colour threshold): the stranger's own edges stop its growth, whatever its colours.
    # Pixels the render does not cover are no marker: as one they flooded the stranger from every gap
    # in the render (cuts at depth edges) and stopped its growth there.
    markers = np.zeros(hole.shape, np.int32)
    markers[agree] = 2
    markers[seeded] = 1
    cv2.watershed(np.ascontiguousarray(render), markers)
    return (markers == 1) & alpha & hole


def shifted_min_diff(moved: np.ndarray, fixed: np.ndarray, k: int, reach_px: float) -> np.ndarray:
    """Per pixel, the smallest box mean (side ``k``) of the absolute difference between ``fixed``
    and ``moved`` shifted by up to ``reach_px`` in each direction (7 x 7 shifts at most): small
    where what ``fixed`` shows around a pixel, ``moved`` shows within reach of it. Computed with the
    long side at most 256 px: telling misalignment from other content needs no fine detail, and 49
    passes at 640 px would cost more than the rest of the screen stage."""
    h, w = moved.shape[:2]
    f = min(1.0, 256 / max(h, w))
    size = (max(round(w * f), 1), max(round(h * f), 1))
    r_img = cv2.resize(moved, size, interpolation=cv2.INTER_AREA).astype(np.float32)
    t_img = cv2.resize(fixed, size, interpolation=cv2.INTER_AREA)
    ks = odd_px(k * f)
    r = max(1, round(reach_px * f))
    step = max(1, round(r / 3))
    padded = cv2.copyMakeBorder(r_img, r, r, r, r, cv2.BORDER_REPLICATE)
    best = np.full(r_img.shape[:2], np.inf, np.float32)
    for dy in range(-r, r + 1, step):
        for dx in range(-r, r + 1, step):
            shifted = padded[r + dy : r + dy + size[1], r + dx : r + dx + size[0]]
            d = np.abs(shifted - t_img)
            # = d.mean(axis=2) to the bit (float32, summed in the same order), 3x faster
            np.minimum(best, cv2.blur((d[..., 0] + d[..., 1] + d[..., 2]) / 3, (ks, ks)), out=best)
    return cv2.resize(best, (w, h), interpolation=cv2.INTER_LINEAR)


def watershed_region(image: np.ndarray, markers: np.ndarray) -> np.ndarray:
    """HxW bool: the region OpenCV's watershed on ``image`` (HxWx3 uint8) grows from the pixels
    ``markers`` labels 1 against those it labels 2 (0: to be decided), with the seam it leaves
    unlabelled (-1) around that region counted in. ``markers`` (int32) is overwritten."""
    cv2.watershed(np.ascontiguousarray(image), markers)
    grown = markers == 1
    return grown | ((markers == -1) & (cv2.dilate(grown.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0))
