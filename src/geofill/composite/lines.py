"""Straight edges that cross the hole (a kerb, a step, a window's frame, a painted line), continued
across it before the texture is painted.

Edges are OpenCV's line segment detector's (:func:`cv2.createLineSegmentDetector`) on the known
image. Two segments that end at the hole on either side of it and lie on one line (within 2
degrees and 1.5 px) are one edge the hole interrupts when the image across them is one profile all
along both (a pattern's stripes, crossed by other stripes, are not): that profile, averaged over
both segments' known pixels, is drawn across the hole along the line fitted to both. Those pixels
are then known to the painter, which fills the rest around them: the patches it copies must
agree with the edge, so the texture respects it.
"""

from __future__ import annotations

import cv2
import numpy as np

#: Segments shorter than this many patch widths are texture, not an edge.
_MIN_LENGTH_PATCHES = 2.0
#: A segment ends at the hole when its end is within this many patch widths of it.
_REACH_PATCHES = 1.0
#: Two segments lie on one line within these (degrees; px from each other's line).
_ANGLE_DEG = 2.0
_OFFSET_PX = 1.5
#: Longest side (px) the segments are detected at.
_LONG_SIDE = 1400
#: Half the width (px) of the band drawn across the hole along an edge.
_HALF_WIDTH = 2
#: Least step across an edge (RGB distance between neighbouring offsets of its profile) for it to
#: be continued, and the most its pixels may differ from the profile (RMS RGB distance), as a share
#: of that step.
_MIN_CONTRAST = 20.0
_MAX_SPREAD = 0.5


def continue_lines(image: np.ndarray, hole: np.ndarray, patch_px: int) -> np.ndarray:
    """Where straight edges cross ``hole`` (HxW bool) of ``image`` (HxWx3 uint8), their profile
    drawn across it (in place); returns the hole pixels drawn (HxW bool)."""
    drawn = np.zeros_like(hole)
    known = ~hole
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    # The hole's own pixels (black, or the object in a removal) would be edges: filled with the
    # known pixels' median, the hole's edge is a weak step the contrast test drops.
    grey = np.where(hole, np.uint8(np.median(grey[known])), grey).astype(np.uint8)
    # Detected at most _LONG_SIDE px long (at 4K the detector alone costs a second) and scaled back.
    f = max(1, -(-max(hole.shape) // _LONG_SIDE))
    if f > 1:
        grey = cv2.resize(
            grey, (-(-grey.shape[1] // f), -(-grey.shape[0] // f)), interpolation=cv2.INTER_AREA
        )
    found = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD).detect(grey)[0]
    if found is None:
        return drawn
    found = (found.reshape(-1, 4).astype(np.float64) + 0.5) * f - 0.5
    reach = _REACH_PATCHES * patch_px
    distance = cv2.distanceTransform(known.astype(np.uint8), cv2.DIST_L2, 3)
    # The end nearer the hole must touch it, the other be away from it (a segment along the hole's
    # edge touches it all along). Tested on all segments at once: a cathedral front gives LSD
    # thousands, and one at a time this took 0.8 s of a Berlin fill.
    a, b = found[:, :2], found[:, 2:]
    da, db = _at(distance, a), _at(distance, b)
    keep = (np.linalg.norm(b - a, axis=1) >= _MIN_LENGTH_PATCHES * patch_px) & (
        (np.minimum(da, db) <= reach) & (np.maximum(da, db) >= 2 * reach)
    )
    ends = []
    for k in np.flatnonzero(keep):
        near, far = (a[k], b[k]) if da[k] <= db[k] else (b[k], a[k])
        if not _crosses(hole, near, far):
            ends.append((near, far))
    for i, j in _facing_pairs(ends):
        line = _collinear(ends[i], ends[j])
        if line is None or not _crosses(hole, ends[i][0], ends[j][0]):
            continue
        # Everything below lies within the box round both segments.
        corners = np.array([*ends[i], *ends[j]])
        lo = np.maximum(np.floor(corners.min(0)).astype(int) - _HALF_WIDTH - 1, 0)
        hi = np.minimum(np.ceil(corners.max(0)).astype(int) + _HALF_WIDTH + 2, hole.shape[::-1])
        box = (slice(lo[1], hi[1]), slice(lo[0], hi[0]))
        ys, xs = np.mgrid[box].astype(np.float64)
        point, direction = line
        normal = np.array([-direction[1], direction[0]])
        offset = (xs - point[0]) * normal[0] + (ys - point[1]) * normal[1]
        along = (xs - point[0]) * direction[0] + (ys - point[1]) * direction[1]
        ti = [float((p - point) @ direction) for p in ends[i]]
        tj = [float((p - point) @ direction) for p in ends[j]]
        on = (np.abs(offset) <= _HALF_WIDTH + 0.5) & known[box]
        on &= _between(along, ti) | _between(along, tj)
        band = hole[box] & (np.abs(offset) <= _HALF_WIDTH + 0.5)
        band &= _between(along, [ti[0], tj[0]])
        profile = _profile(image[box], offset, on)
        if profile is None or not band.any():
            continue
        k = np.clip(np.rint(offset[band]).astype(int) + _HALF_WIDTH, 0, 2 * _HALF_WIDTH)
        image[box][band] = profile[k]
        drawn[box] |= band
    return drawn


#: Angle (degrees) of the quick test of all pairs of segments at once, a little wider than
#: _ANGLE_DEG so that every pair :func:`_collinear` accepts passes it (rounding aside).
_PREFILTER_DEG = _ANGLE_DEG + 0.5


def _facing_pairs(ends: list[tuple[np.ndarray, np.ndarray]]) -> list[tuple[int, int]]:
    """The pairs (i < j) of segments (near end, far end) whose directions, each pointing towards
    the other's far end, are within _PREFILTER_DEG: :func:`_collinear` tested every pair one at
    a time, 0.15 s of a Berlin fill for thousands of pairs of which a few are close to parallel."""
    if len(ends) < 2:
        return []
    near = np.array([e[0] for e in ends])
    d = near - np.array([e[1] for e in ends])  # far end -> near end
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # Segment i points far -> near (d_i), segment j near -> far (-d_j): facing when d_i . -d_j ~ 1.
    i, j = np.nonzero(np.triu(-(d @ d.T) >= np.cos(np.radians(_PREFILTER_DEG)), k=1))
    return list(zip(i.tolist(), j.tolist(), strict=True))


def _at(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``a`` at the nearest pixel to each point of ``p`` (Nx2, x then y), clipped to the image."""
    y = np.clip(np.rint(p[:, 1]), 0, a.shape[0] - 1).astype(int)
    x = np.clip(np.rint(p[:, 0]), 0, a.shape[1] - 1).astype(int)
    return a[y, x]


def _crosses(hole: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether the segment from ``a`` to ``b`` runs through the hole (a pixel of it on the way)."""
    n = int(np.ceil(np.linalg.norm(b - a))) + 1
    t = np.linspace(0.0, 1.0, n)[1:-1]
    if not t.size:
        return False
    pts = np.rint(a[None] + t[:, None] * (b - a)[None]).astype(int)
    ok = (pts[:, 0] >= 0) & (pts[:, 0] < hole.shape[1]) & (pts[:, 1] >= 0) & (pts[:, 1] < hole.shape[0])
    return bool(hole[pts[ok, 1], pts[ok, 0]].any())


def _collinear(
    s: tuple[np.ndarray, np.ndarray], t: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray] | None:
    """The line (a point, a unit direction) through both segments (near end, far end) when they
    lie on one line facing each other across the gap, else None."""
    ds, dt = s[0] - s[1], t[1] - t[0]  # both pointing from s's far end towards t's far end
    ds, dt = ds / np.linalg.norm(ds), dt / np.linalg.norm(dt)
    if np.degrees(np.arccos(np.clip(ds @ dt, -1.0, 1.0))) > _ANGLE_DEG:
        return None
    pts = np.array([s[1], s[0], t[0], t[1]], np.float32)
    vx, vy, x0, y0 = cv2.fitLine(pts, cv2.DIST_L2, 0, 0.01, 0.01).ravel()
    direction, point = np.array([vx, vy], np.float64), np.array([x0, y0], np.float64)
    normal = np.array([-direction[1], direction[0]])
    if np.abs((pts - point) @ normal).max() > _OFFSET_PX:
        return None
    return point, direction


def _between(along: np.ndarray, bounds: list[float]) -> np.ndarray:
    return (along >= min(bounds)) & (along <= max(bounds))


def _profile(image: np.ndarray, offset: np.ndarray, on: np.ndarray) -> np.ndarray | None:
    """The mean colour at each whole-pixel offset across the edge (-_HALF_WIDTH.._HALF_WIDTH) over
    the known pixels ``on`` it, or None where an offset has none, the edge is faint (its largest
    step between neighbouring offsets below _MIN_CONTRAST) or it is not one edge all along (the
    pixels differ from the profile by more than _MAX_SPREAD of that step: a line of a texture,
    the stripes of a pattern crossing other stripes, changes along its length)."""
    k = np.rint(offset[on]).astype(int) + _HALF_WIDTH
    colours = image[on].astype(np.float64)
    counts = np.bincount(k, minlength=2 * _HALF_WIDTH + 1)[: 2 * _HALF_WIDTH + 1]
    if (counts == 0).any():
        return None
    sums = np.stack([np.bincount(k, colours[:, c], minlength=2 * _HALF_WIDTH + 1) for c in range(3)], 1)
    profile = sums[: 2 * _HALF_WIDTH + 1] / counts[:, None]
    step = float(np.linalg.norm(np.diff(profile, axis=0), axis=1).max())
    spread = float(np.sqrt(((colours - profile[k]) ** 2).sum(axis=1).mean()))
    if step < _MIN_CONTRAST or spread > _MAX_SPREAD * step:
        return None
    return np.clip(np.rint(profile), 0, 255).astype(np.uint8)
