"""The vote between references: where several references' renders cover the same hole pixels and one
shows what the others do not (a stranger wholly inside the hole's footprint, which the target cannot
expose), it is refused there. Run by the fuse stage on the renders as refined, before the screen, so
that a stranger the screen refused in one reference still contradicts another's."""

from __future__ import annotations

import cv2
import numpy as np

from ..config import ScreenConfig
from ..screen.strangers import shifted_min_diff, watershed_region
from ..utils.distance import known_ring
from ..utils.parts import large_parts
from ..utils.resolution import config_px, odd_px

#: Long side (px) at which the test between references runs: it compares regions tens of pixels wide
#: in every pair of references.
CROSS_TEST_SIDE = 640


def cross_strangers(
    images: np.ndarray,
    alphas: np.ndarray,
    hole: np.ndarray,
    target: np.ndarray,
    evidence: np.ndarray,
    shape: tuple[int, ...],
    sc: ScreenConfig,
    trust: np.ndarray | None = None,
    ratio: float = 0.5,
) -> np.ndarray:
    """(K, H, W) bool: hole pixels of a window where a reference's render shows what the other
    references covering them do not (a stranger wholly inside the hole's footprint, which the
    target cannot expose). ``images`` (K, H, W, 3 float32): the renders, colour-corrected to the
    target; ``alphas``: where they cover; ``target``: the window, hole blanked; ``evidence``
    (K, H, W bool): where the stranger test of :func:`strangers` already refused; ``trust``
    (K, H, W, default all equal): how far each render is to be trusted at each pixel (the fuse
    stage's scores).

    Two renders disagree where their colours differ by more than ``sc.stranger_threshold`` (over a
    5-px box), and by more than ``sc.cross_shift_threshold`` with either one shifted by up to 12 px
    (misalignment is not disagreement).
    Where three or more cover a pixel, a render that disagrees with all the others there, while two
    of them agree with each other and are trusted at least ``ratio`` times as much, is the
    stranger. Where two cover it, the stranger is the render that continues a region the stranger
    test refused in it (``evidence`` within the shift's reach) while the other does not, again
    unless the other is trusted less than ``ratio`` times as much; otherwise the scores choose.
    Found regions are grown over the stranger's render by OpenCV's watershed against its pixels
    that agree with another render or with the target around the hole, as :func:`strangers` grows
    its own. Runs with the long side at most :data:`CROSS_TEST_SIDE`.

    >>> hole = np.zeros((80, 120), bool); hole[10:70, 20:100] = True
    >>> images = np.full((3, 80, 120, 3), 100, np.float32); images[2, 20:60, 30:90] = 230
    >>> target = np.full((80, 120, 3), 100, np.uint8); target[hole] = 0
    >>> alphas = np.ones((3, 80, 120), bool); none = np.zeros((3, 80, 120), bool)
    >>> out = cross_strangers(images, alphas, hole, target, none, (720, 1280), ScreenConfig())
    >>> stranger = out[2, 20:60, 30:90]  # where the third render shows it
    >>> bool(out[:2].any()), round(float(stranger.mean()), 2), int(out[2].sum() - stranger.sum())
    (False, 1.0, 0)
    """
    n, h, w = alphas.shape
    out = np.zeros(alphas.shape, bool)
    if n < 2 or sc.stranger_threshold <= 0:
        return out
    f = min(1.0, CROSS_TEST_SIDE / max(h, w))
    size = (max(round(w * f), 1), max(round(h * f), 1))

    def small(mask: np.ndarray) -> np.ndarray:
        return cv2.resize(mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0

    found = _cross_strangers(
        np.stack([cv2.resize(i, size, interpolation=cv2.INTER_AREA) for i in images]),
        np.stack([small(a) for a in alphas]),
        small(hole),
        cv2.resize(target, size, interpolation=cv2.INTER_AREA).astype(np.float32),
        np.stack([small(e) for e in evidence]),
        config_px(1.0, shape) * f,
        sc,
        np.ones(alphas.shape, np.float32)
        if trust is None
        else np.stack([cv2.resize(t.astype(np.float32), size, interpolation=cv2.INTER_AREA) for t in trust]),
        ratio,
    )
    for k in range(n):
        if found[k].any():
            up = cv2.resize(found[k].astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
            out[k] = up & alphas[k] & hole
    return out


def _cross_strangers(
    images: np.ndarray,
    alphas: np.ndarray,
    hole: np.ndarray,
    target: np.ndarray,
    evidence: np.ndarray,
    px: float,
    sc: ScreenConfig,
    trust: np.ndarray,
    ratio: float,
) -> np.ndarray:
    """:func:`cross_strangers` at the resolution given, ``px`` pixels per config pixel."""
    n = len(images)
    k = odd_px(5.0 * px)
    reach = 12.0 * px
    box = np.ones((k, k), np.uint8)
    # Box means next to a render's border mix in its zeros: compare only where both cover a full box.
    inner = np.stack([cv2.erode(a.astype(np.uint8), box) > 0 for a in alphas])
    disagree = np.zeros((n, n, *hole.shape), bool)
    agree = np.zeros(alphas.shape, bool)
    for i in range(n):
        for j in range(i + 1, n):
            both = inner[i] & inner[j]
            if not (both & hole).any():
                continue
            diff = cv2.blur(np.abs(images[i] - images[j]).mean(axis=2), (k, k))
            apart = both & (diff > sc.stranger_threshold)
            if apart.any():
                apart &= shifted_min_diff(images[i], images[j], k, reach) > sc.cross_shift_threshold
                apart &= shifted_min_diff(images[j], images[i], k, reach) > sc.cross_shift_threshold
            disagree[i, j] = disagree[j, i] = apart
            close = both & (diff < sc.stranger_agreement)
            agree[i] |= close
            agree[j] |= close
    if not disagree.any():
        return np.zeros(alphas.shape, bool)
    covering = inner.sum(axis=0)
    seeds = np.zeros(alphas.shape, bool)
    for i in range(n):
        others = [j for j in range(n) if j != i]
        against = disagree[i].sum(axis=0)
        # Two of the others that cover a pixel and agree there outvote this one.
        pair_agrees = np.zeros(hole.shape, bool)
        for a, b in ((a, b) for x, a in enumerate(others) for b in others[x + 1 :]):
            trusted = (trust[a] >= ratio * trust[i]) & (trust[b] >= ratio * trust[i])
            pair_agrees |= inner[a] & inner[b] & ~disagree[a, b] & trusted
        seeds[i] = hole & inner[i] & (covering >= 3) & (against == covering - 1) & pair_agrees
    two = hole & (covering == 2)
    if two.any():
        _two_way_seeds(inner, disagree, two, evidence, reach, seeds, trust, ratio)
    m = max(3, odd_px(sc.stranger_min_px / 2 * px))
    min_area = (sc.stranger_min_px * px) ** 2
    ring = known_ring(hole, sc.stranger_ring_px * px)
    out = np.zeros(alphas.shape, bool)
    for i in range(n):
        if not seeds[i].any():
            continue
        seeded = large_parts(seeds[i], m, min_area)
        if not seeded.any():
            continue
        # The render's pixels that agree with another render, or with the target around the hole.
        fits = (agree[i] & ~seeded) | (
            ring
            & alphas[i]
            & (cv2.blur(np.abs(images[i] - target).mean(axis=2), (k, k)) < sc.stranger_agreement)
        )
        markers = np.zeros(hole.shape, np.int32)  # no marker where it does not cover, as in :func:`strangers`
        markers[fits] = 2
        markers[seeded] = 1
        # The seam the watershed leaves around the stranger is refused too.
        out[i] = watershed_region(images[i].clip(0, 255).astype(np.uint8), markers) & alphas[i] & hole
    return out


def _two_way_seeds(
    inner: np.ndarray,
    disagree: np.ndarray,
    two: np.ndarray,
    evidence: np.ndarray,
    reach: float,
    seeds: np.ndarray,
    trust: np.ndarray,
    ratio: float,
) -> None:
    """Into ``seeds``: of each region where exactly two renders cover the hole and disagree, the
    render that continues a region the stranger test refused in it (``evidence`` within ``reach``)
    while the other does not, unless the other scores below ``ratio`` of it there."""
    near = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (odd_px(2 * reach + 3),) * 2)
    refused_near = np.stack([cv2.dilate(e.astype(np.uint8), near) > 0 for e in evidence])
    n = len(inner)
    for i in range(n):
        for j in range(i + 1, n):
            region = two & inner[i] & inner[j] & disagree[i, j]
            if not region.any():
                continue
            count, labels = cv2.connectedComponents(region.astype(np.uint8), connectivity=8)
            for c in range(1, count):
                part = labels == c
                ev_i, ev_j = (refused_near[i] & part).any(), (refused_near[j] & part).any()
                if ev_i == ev_j:
                    continue  # nothing tells which one is the stranger: the scores choose
                s, o = (i, j) if ev_i else (j, i)
                if float(trust[o][part].mean()) >= ratio * float(trust[s][part].mean()):
                    seeds[s] |= part
