"""The surfaces around a hole, from the image: which known pixels belong to the same surface (a wall,
the ground, the sky) and where each surface runs inside the hole, so that the painter fills every
hole pixel from its own surface only and the line where two surfaces meet continues across it.

Surfaces are clusters of the known pixels by their local appearance (CIELAB colour and texture
energy averaged over a few patch widths), with as many clusters (one to three) as make a clear gain
(Lloyd's k-means, hand-written: it is deterministic and a few lines, where ``cv2.kmeans`` draws
from OpenCV's global generator); a cluster that is only the blend of two others where they meet is
not a surface. Inside the hole each pixel takes the surface of the nearest known
pixel; where two surfaces meet along a straight line on the known ring (a wall on the ground, a
kerb) the hole is split along that line instead, so the meeting line continues straight.
"""

from __future__ import annotations

import cv2
import numpy as np

#: Most clusters tried, and the share of the squared error one more cluster must remove to be kept.
_MAX_SURFACES = 3
_GAIN = 0.45
#: Least distance between two surfaces' mean appearance (CIELAB units): a texture's own light and
#: dark parts, averaged over a few patch widths, come closer than this.
_SEPARATION = 15.0
#: A cluster whose centre is within this share of the gap between two others from the segment
#: joining them is their blend (see _has_blend).
_BLEND = 0.25
#: Known pixels sampled to fit the clusters.
_SAMPLES = 20_000
#: Weight of the texture energy (mean absolute Laplacian of L, 0-100 scale) against colour.
_TEXTURE_WEIGHT = 1.5
#: A meeting line is straight when this share of the boundary pixels lies within _LINE_PX of it
#: (the rest: where the boundary turns, or runs along the hole's edge).
_LINE_INLIERS = 0.4
_LINE_PX = 2.0
#: Share of a surface's ring pixels near the line on one side of it that makes that side its own.
_SIDE_SHARE = 0.75
#: Lines tried (through two boundary pixels each) in the search for the dominant one.
_LINE_TRIALS = 200
_LINE_POINTS = 4000
#: Longest side (px) the surfaces are found at: a larger image is reduced to it and the labels
#: scaled back (per-pixel features and distances to each cluster cost gigabytes at 58 MP). The
#: painter searches at most this long a level, so it never sees finer labels.
LONG_SIDE = 1400


def unit(image: np.ndarray) -> np.ndarray:
    """``image`` as float32 in [0, 1]: an HxWx3 uint8 image converted (one float copy, not the two
    ``image / 255.0`` makes), a float one returned as it is."""
    if image.dtype != np.uint8:
        return image
    out = image.astype(np.float32)
    out /= 255.0
    return out


def reduced(image: np.ndarray, hole: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """``image`` (HxWx3, uint8 or float32 in [0, 1]) and ``hole`` reduced (area averaging; a pixel
    touching the hole is in it) by the least integer factor that makes them at most
    :data:`LONG_SIDE` long: the factor, the image as float32 in [0, 1], the hole."""
    f = max(1, -(-max(hole.shape) // LONG_SIDE))
    if f == 1:
        return 1, unit(image), hole
    size = (-(-hole.shape[1] // f), -(-hole.shape[0] // f))
    small_hole = cv2.resize(hole.astype(np.uint8), size, interpolation=cv2.INTER_AREA) > 0
    return f, unit(cv2.resize(image, size, interpolation=cv2.INTER_AREA)), small_hole


def segment(image: np.ndarray, hole: np.ndarray, patch_px: int) -> np.ndarray:
    """Surface labels (HxW int32, 0..k-1) of every pixel, known or in the hole, of ``image``
    (HxWx3 RGB, uint8 or float32 in [0, 1]) around ``hole`` (HxW bool); all 0 when the known pixels
    form one surface. ``patch_px``: the painter's patch width, the scale the appearance is averaged
    over. Above :data:`LONG_SIDE` px found on the image reduced to that and scaled back."""
    f, small, small_hole = reduced(image, hole)
    if f == 1:
        return _segment(small, hole, patch_px)
    labels = _segment(small, small_hole, max(3, patch_px // f))
    return cv2.resize(labels, hole.shape[::-1], interpolation=cv2.INTER_NEAREST)


def _segment(image: np.ndarray, hole: np.ndarray, patch_px: int) -> np.ndarray:
    known = ~hole
    feats = _appearance(image, known, 2.0 * patch_px)
    labels = np.zeros(hole.shape, np.int32)
    samples = feats[known]
    if samples.shape[0] > _SAMPLES:
        samples = samples[np.random.default_rng(0).choice(samples.shape[0], _SAMPLES, replace=False)]
    centres = _clusters(samples)
    if len(centres) == 1:
        return labels
    dist = ((feats[:, :, None, :] - centres[None, None]) ** 2).sum(-1)
    labels = np.argmin(dist, axis=2).astype(np.int32)
    # A few pixels' worth of label noise would put single source patches on the wrong surface.
    labels = cv2.medianBlur(labels.astype(np.uint8), 5).astype(np.int32)
    extend(labels, hole)
    _straighten(labels, hole, image, 4 * patch_px)
    return labels


def _appearance(image: np.ndarray, known: np.ndarray, sigma: float) -> np.ndarray:
    """Per pixel: CIELAB colour and texture energy, averaged over the known pixels within ``sigma``."""
    lab = cv2.cvtColor(image, cv2.COLOR_RGB2Lab)
    # The Laplacian of the ring's first row reads the hole: it sees the hole as black, whatever the
    # hole shows (in a removal, the object), so the object cannot shape the surfaces.
    lightness = np.where(known, lab[..., 0], 0.0).astype(np.float32)
    energy = np.abs(cv2.Laplacian(lightness, cv2.CV_32F, ksize=3)) * _TEXTURE_WEIGHT
    w = known.astype(np.float32)
    # Blurred at a quarter of the scale on an image reduced as much (a blur this wide keeps nothing
    # the reduction loses), then scaled back: a full-size blur of 5 channels cost a second at 720p.
    f = max(1, int(sigma // 4))
    h, wd = known.shape

    def blur(a: np.ndarray) -> np.ndarray:
        small = cv2.resize(a, (-(-wd // f), -(-h // f)), interpolation=cv2.INTER_AREA)
        return cv2.resize(cv2.GaussianBlur(small, (0, 0), sigma / f), (wd, h), interpolation=cv2.INTER_LINEAR)

    num = blur(np.dstack([lab, energy]) * w[..., None])
    return num / np.maximum(blur(w), 1e-6)[..., None]


def _clusters(samples: np.ndarray) -> np.ndarray:
    """Cluster centres of ``samples`` (N x d): the fewest (1.._MAX_SURFACES) such that one more
    would not remove _GAIN of the squared error or would lie within _SEPARATION of another."""
    best = samples.mean(axis=0, keepdims=True)
    err = float(((samples - best) ** 2).sum())
    for k in range(2, _MAX_SURFACES + 1):
        centres, new_err = _lloyd(samples, k)
        gaps = np.sqrt(((centres[:, None] - centres[None]) ** 2).sum(-1))[np.triu_indices(k, 1)]
        if new_err > (1.0 - _GAIN) * err or gaps.min() < _SEPARATION or _has_blend(centres):
            break
        best, err = centres, new_err
    return best


def _has_blend(centres: np.ndarray) -> bool:
    """Whether a centre lies near the segment between two others: the band where two surfaces'
    averaged appearance blends into each other, not a surface."""
    k = len(centres)
    for m in range(k):
        for a in range(k):
            for b in range(a + 1, k):
                if m in (a, b):
                    continue
                ab = centres[b] - centres[a]
                t = np.clip(np.dot(centres[m] - centres[a], ab) / max(np.dot(ab, ab), 1e-9), 0.0, 1.0)
                if np.linalg.norm(centres[a] + t * ab - centres[m]) < _BLEND * np.linalg.norm(ab):
                    return True
    return False


def _lloyd(samples: np.ndarray, k: int, iterations: int = 15) -> tuple[np.ndarray, float]:
    """k-means from farthest-point seeds (deterministic): centres and squared error."""
    centres = [samples.mean(axis=0)]
    for _ in range(k):
        d = np.min([((samples - c) ** 2).sum(1) for c in centres], axis=0)
        centres.append(samples[int(np.argmax(d))])
    centres = np.array(centres[1:])
    for _ in range(iterations):
        assign = np.argmin(((samples[:, None] - centres[None]) ** 2).sum(-1), axis=1)
        for j in range(k):
            if (assign == j).any():
                centres[j] = samples[assign == j].mean(axis=0)
    d = ((samples[:, None] - centres[None]) ** 2).sum(-1)
    return centres, float(d.min(axis=1).sum())


def extend(labels: np.ndarray, hole: np.ndarray) -> None:
    """In place: each hole pixel takes the label of its nearest known pixel."""
    _, nearest = cv2.distanceTransformWithLabels(
        hole.astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    lookup = np.zeros(int(nearest.max()) + 1, np.int32)
    lookup[nearest[~hole]] = labels[~hole]
    labels[hole] = lookup[nearest[hole]]


def _straighten(labels: np.ndarray, hole: np.ndarray, image: np.ndarray, ring_px: int) -> None:
    """In place: where two surfaces meet along a straight line on the ring ``ring_px`` wide around
    the hole, the line is moved (by up to half that) to the strongest colour step across it on the
    ring (averaged appearance places a boundary a few pixels off), and their ring pixels within
    ``ring_px`` of it, and all of their hole pixels, are split by it."""
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ring_px + 1,) * 2)
    near = cv2.dilate(hole.astype(np.uint8), disc)
    ring = (near > 0) & ~hole
    cross = np.ones((3, 3), np.uint8)
    n = int(labels.max()) + 1
    yy, xx = np.mgrid[0 : labels.shape[0], 0 : labels.shape[1]]
    for a in range(n):
        for b in range(a + 1, n):
            edge = ring & (labels == a) & (cv2.dilate((labels == b).astype(np.uint8), cross) > 0)
            ys, xs = np.nonzero(edge)
            if ys.size < 2 * ring_px:
                continue
            line = _dominant_line(xs, ys)
            if line is None:
                continue
            vx, vy, x0, y0 = line
            pair = (labels == a) | (labels == b)
            dist = (xx - x0) * vy - (yy - y0) * vx
            band = ring & pair & (np.abs(dist) <= ring_px)
            bd, bc = dist[band], image[band]
            shift = max(np.arange(-ring_px / 2, ring_px / 2 + 0.5, 0.5), key=lambda d: _step(bd, bc, d))
            dist -= shift
            near_line = ring & (np.abs(dist) <= ring_px)
            side_a = _side(dist, near_line, labels, a, b)
            if side_a == 0:
                continue
            redo = pair & (hole | near_line)
            labels[redo] = np.where(np.sign(dist[redo]) == side_a, a, b)


def _side(dist: np.ndarray, near: np.ndarray, labels: np.ndarray, a: int, b: int) -> float:
    """The side (sign of ``dist``) of the line that surface ``a`` takes: the side of the median of
    its pixels of ``near``, unless surface ``b``'s pixels lie on that same side more consistently
    (at least :data:`_SIDE_SHARE` of them, and a larger share than ``a``'s): then the other one.
    0 where ``a`` has no such pixels or their median is on the line. (On the Lund street the
    plinth's shadow lay on both sides of the kerb, the cobbles below it: the shadow's median alone
    put the cobbles above the kerb, up the wall.)"""
    da, db = dist[near & (labels == a)], dist[near & (labels == b)]
    side = float(np.sign(np.median(da))) if da.size else 0.0
    if side == 0 or not db.size:
        return side
    own_a, same_b = float(np.mean(np.sign(da) == side)), float(np.mean(np.sign(db) == side))
    return -side if same_b >= max(_SIDE_SHARE, own_a) else side


def _dominant_line(xs: np.ndarray, ys: np.ndarray) -> tuple[float, float, float, float] | None:
    """The line (direction vx, vy through x0, y0) through most of the points, refined on those
    within _LINE_PX of it, or None when it holds less than _LINE_INLIERS of them. RANSAC with a
    fixed seed: the same answer every run."""
    rng = np.random.default_rng(0)
    if xs.size > _LINE_POINTS:  # scored on a sample: trials x points distances
        pick = rng.choice(xs.size, _LINE_POINTS, replace=False)
        xs, ys = xs[pick], ys[pick]
    i, j = rng.integers(0, xs.size, (2, _LINE_TRIALS))
    keep = (xs[i] != xs[j]) | (ys[i] != ys[j])
    i, j = i[keep], j[keep]
    dx, dy = (xs[j] - xs[i]).astype(np.float64), (ys[j] - ys[i]).astype(np.float64)
    norm = np.hypot(dx, dy)
    # Distance of every point to every trial line, one trial per row.
    off = (
        np.abs((xs[None] - xs[i, None]) * dy[:, None] - (ys[None] - ys[i, None]) * dx[:, None])
        / norm[:, None]
    )
    near = off <= _LINE_PX
    best = int(np.argmax(near.sum(axis=1))) if near.size else 0
    if not near.size or near[best].mean() < _LINE_INLIERS:
        return None
    pts = np.stack([xs[near[best]], ys[near[best]]], axis=1).astype(np.float32)
    vx, vy, x0, y0 = cv2.fitLine(pts, cv2.DIST_L2, 0, 0.01, 0.01).ravel()
    return float(vx), float(vy), float(x0), float(y0)


def _step(dist: np.ndarray, colour: np.ndarray, at: float) -> float:
    """Colour difference between the pixels just either side (3 px) of signed distance ``at``."""
    lo = (dist > at - 3) & (dist <= at)
    hi = (dist > at) & (dist <= at + 3)
    if not lo.any() or not hi.any():
        return 0.0
    return float(np.linalg.norm(colour[lo].mean(axis=0) - colour[hi].mean(axis=0)))
