"""Free-form brush-stroke holes in the spirit of DeepFillv2 (Yu et al., ICCV 2019), as used by the
GeoFill paper's evaluation.

A hole is a few strokes; each stroke is a polyline of random vertices (segment lengths and turning
angles drawn at random, zig-zagging like DeepFillv2's generator) drawn with one brush width, with
discs at the joints. Sizes are relative to the image: segment lengths scale with its diagonal and
the default mean brush width is the middle of the paper's 90-210 px range at a 720-px short side,
scaled linearly with the short side.

Reproducibility: every random number comes from ``np.random.default_rng`` seeded with
:func:`mask_seed` (SHA-256 of pair id and user seed), and vertices are rounded to integer pixels
before OpenCV rasterises them, so the same (pair id, seed, size) gives the same mask on every
machine and run (Python's ``hash()`` is salted per process and is never used).
"""

from __future__ import annotations

import hashlib
import itertools
from dataclasses import dataclass

import cv2
import numpy as np

#: Short side (px) of the paper's 1280x720 evaluation images; stroke widths are quoted at it.
PAPER_SHORT_SIDE_PX = 720
#: The paper's hole-size study: average stroke widths (px at a 720-px short side).
PAPER_STROKE_WIDTHS_720P = (90.0, 120.0, 150.0, 180.0, 210.0)
#: Default average stroke width (px at a 720-px short side): the middle of the paper's range.
DEFAULT_STROKE_WIDTH_720P = 150.0
#: Default hole-area window (fraction of the image). The paper does not state its hole areas;
#: 10-30 % brackets the middle of the usual free-form benchmarks' 0-60 % bins (e.g. ~18 % mean)
#: while leaving enough known pixels around the hole for matching and the colour fit.
DEFAULT_AREA_RANGE = (0.10, 0.30)

#: Each stroke's brush width is drawn uniformly in ``mean * [1 - spread, 1 + spread]``.
_WIDTH_SPREAD = 0.4
#: Vertices per stroke, as DeepFillv2's generator (4-12).
_VERTICES_RANGE = (4, 13)
#: Turning angle around which consecutive segments zig-zag (DeepFillv2: 2π/5 ± up to 2π/15).
_MEAN_ANGLE = 2.0 * np.pi / 5.0
_ANGLE_RANGE = 2.0 * np.pi / 15.0
#: Unconstrained masks (no area window) get this many strokes (DeepFillv2: 1-3, here up to 4).
_STROKES_RANGE = (1, 5)
#: Segment proposals tried before area control gives up (never reached on sensible sizes).
_MAX_PROPOSALS = 2000


def mask_seed(pair_id: str, seed: int) -> int:
    """64-bit RNG seed for ``pair_id`` under the user's ``seed``, stable across runs and machines."""
    digest = hashlib.sha256(f"geofill-mask\x00{pair_id}\x00{int(seed)}".encode()).digest()
    return int.from_bytes(digest[:8], "little")


def scaled_stroke_width(width_720p: float, height: int, width: int) -> float:
    """Brush width (px of an ``height`` x ``width`` image) equivalent to ``width_720p`` px at a
    720-px short side."""
    return float(width_720p) * min(height, width) / PAPER_SHORT_SIDE_PX


@dataclass(frozen=True)
class Stroke:
    """One brush stroke: a polyline of integer pixel vertices (x, y) and its width relative to the
    mask's mean width."""

    vertices: np.ndarray  # (N, 2) int64, N >= 1
    rel_width: float


@dataclass(frozen=True)
class BrushStrokes:
    """The geometry of a free-form hole, independent of the brush width it is drawn with, so the
    same hole shape can be drawn thicker or thinner (the paper's hole-size study)."""

    height: int
    width: int
    strokes: tuple[Stroke, ...]

    def render(self, mean_width_px: float) -> np.ndarray:
        """HxW bool hole (True = hole) with the strokes drawn at mean width ``mean_width_px``."""
        canvas = np.zeros((self.height, self.width), np.uint8)
        for stroke in self.strokes:
            _draw_stroke(canvas, stroke.vertices, _brush_px(stroke.rel_width, mean_width_px))
        return canvas.astype(bool)


def _brush_px(rel_width: float, mean_width_px: float) -> int:
    return max(1, round(rel_width * mean_width_px))


def _draw_disc(canvas: np.ndarray, xy: np.ndarray, brush_px: int) -> None:
    cv2.circle(canvas, (int(xy[0]), int(xy[1])), brush_px // 2, 1, thickness=-1)


def _draw_segment(canvas: np.ndarray, a: np.ndarray, b: np.ndarray, brush_px: int) -> None:
    cv2.line(canvas, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), 1, thickness=brush_px)
    # A thick cv2.line ends squarely; the disc rounds the joint as a brush would.
    _draw_disc(canvas, b, brush_px)


def _draw_stroke(canvas: np.ndarray, vertices: np.ndarray, brush_px: int) -> None:
    _draw_disc(canvas, vertices[0], brush_px)
    for a, b in itertools.pairwise(vertices):
        _draw_segment(canvas, a, b, brush_px)


class _StrokeSampler:
    """DeepFillv2-style random stroke parameters at one image size."""

    def __init__(self, rng: np.random.Generator, height: int, width: int):
        self.rng, self.height, self.width = rng, height, width
        # DeepFillv2 draws segment lengths around an eighth of the image diagonal.
        self.mean_length = float(np.hypot(height, width)) / 8.0

    def start(self) -> tuple[np.ndarray, float, int, tuple[float, float]]:
        """Start vertex, relative width, vertex count and the stroke's turning-angle interval."""
        rng = self.rng
        xy = np.array([rng.integers(0, self.width), rng.integers(0, self.height)], dtype=np.int64)
        rel_width = float(rng.uniform(1.0 - _WIDTH_SPREAD, 1.0 + _WIDTH_SPREAD))
        n_vertices = int(rng.integers(*_VERTICES_RANGE))
        angles = (_MEAN_ANGLE - rng.uniform(0, _ANGLE_RANGE), _MEAN_ANGLE + rng.uniform(0, _ANGLE_RANGE))
        return xy, rel_width, n_vertices, angles

    def heading(self) -> float:
        """Random initial direction of a stroke (DeepFillv2 flips whole masks instead)."""
        return float(self.rng.uniform(0.0, 2.0 * np.pi))

    def next_vertex(self, xy: np.ndarray, heading: float, index: int, angles: tuple[float, float]):
        """Vertex after ``xy``; odd and even segments turn opposite ways (the zig-zag)."""
        rng = self.rng
        turn = rng.uniform(*angles)
        direction = heading + (turn if index % 2 else -turn)
        length = float(np.clip(rng.normal(self.mean_length, self.mean_length / 2), 0, 2 * self.mean_length))
        x = np.clip(xy[0] + length * np.cos(direction), 0, self.width - 1)
        y = np.clip(xy[1] + length * np.sin(direction), 0, self.height - 1)
        return np.array([round(x), round(y)], dtype=np.int64)


def brush_strokes(
    height: int,
    width: int,
    *,
    seed: int,
    mean_width_px: float | None = None,
    area_range: tuple[float, float] | None = DEFAULT_AREA_RANGE,
) -> BrushStrokes:
    """Random free-form hole geometry for an ``height`` x ``width`` image.

    ``mean_width_px``: average brush width in px of this image (None: 150 px at a 720-px short
    side, scaled). With ``area_range = (lo, hi)`` a target area is drawn uniformly in it and
    strokes are grown one segment at a time until the hole reaches it; a segment that would push
    the hole over ``hi`` is discarded and another one drawn, so the area drawn at ``mean_width_px``
    always lies in ``[lo, hi]``. With ``area_range=None`` 1-4 complete strokes are drawn.
    """
    if mean_width_px is None:
        mean_width_px = scaled_stroke_width(DEFAULT_STROKE_WIDTH_720P, height, width)
    if mean_width_px <= 0:
        raise ValueError(f"mean brush width must be positive, got {mean_width_px}")
    rng = np.random.default_rng(seed)
    sampler = _StrokeSampler(rng, height, width)
    if area_range is None:
        return BrushStrokes(height, width, _free_strokes(sampler))
    lo, hi = area_range
    if not 0.0 < lo <= hi < 1.0:
        raise ValueError(f"hole area range must satisfy 0 < lo <= hi < 1, got {area_range}")
    return BrushStrokes(height, width, _area_controlled_strokes(sampler, mean_width_px, lo, hi))


def _free_strokes(sampler: _StrokeSampler) -> tuple[Stroke, ...]:
    strokes = []
    for _ in range(int(sampler.rng.integers(*_STROKES_RANGE))):
        xy, rel_width, n_vertices, angles = sampler.start()
        heading = sampler.heading()
        vertices = [xy]
        for i in range(n_vertices):
            vertices.append(sampler.next_vertex(vertices[-1], heading, i, angles))
        strokes.append(Stroke(np.array(vertices), rel_width))
    return tuple(strokes)


def _area_controlled_strokes(
    sampler: _StrokeSampler, mean_width_px: float, lo: float, hi: float
) -> tuple[Stroke, ...]:
    n_pixels = sampler.height * sampler.width
    target = float(sampler.rng.uniform(lo, hi)) * n_pixels
    hi_px = hi * n_pixels
    canvas = np.zeros((sampler.height, sampler.width), np.uint8)
    strokes: list[Stroke] = []
    proposals = 0
    while np.count_nonzero(canvas) < target:
        xy, rel_width, n_vertices, angles = sampler.start()
        heading = sampler.heading()
        brush = _brush_px(rel_width, mean_width_px)
        trial = canvas.copy()
        _draw_disc(trial, xy, brush)
        proposals += 1
        if np.count_nonzero(trial) > hi_px:
            _check_proposals(proposals, sampler, mean_width_px, hi)
            continue
        canvas, vertices = trial, [xy]
        for i in range(n_vertices):
            nxt = sampler.next_vertex(vertices[-1], heading, i, angles)
            trial = canvas.copy()
            _draw_segment(trial, vertices[-1], nxt, brush)
            proposals += 1
            area = np.count_nonzero(trial)
            if area > hi_px:
                _check_proposals(proposals, sampler, mean_width_px, hi)
                continue
            canvas = trial
            vertices.append(nxt)
            if area >= target:
                break
        strokes.append(Stroke(np.array(vertices), rel_width))
    return tuple(strokes)


def _check_proposals(proposals: int, sampler: _StrokeSampler, mean_width_px: float, hi: float) -> None:
    if proposals > _MAX_PROPOSALS:
        raise ValueError(
            f"cannot keep a {mean_width_px:.0f}-px brush stroke hole under {hi:.0%} of a "
            f"{sampler.width}x{sampler.height} image; use a thinner brush or a wider area range"
        )


def brush_stroke_mask(
    height: int,
    width: int,
    *,
    seed: int,
    mean_width_px: float | None = None,
    area_range: tuple[float, float] | None = DEFAULT_AREA_RANGE,
) -> np.ndarray:
    """HxW bool free-form brush-stroke hole (True = hole); see :func:`brush_strokes`.

    Defaults: mean brush width 150 px at a 720-px short side (scaled with ``min(height, width)``),
    hole area 10-30 % of the image (:data:`DEFAULT_AREA_RANGE`)."""
    if mean_width_px is None:
        mean_width_px = scaled_stroke_width(DEFAULT_STROKE_WIDTH_720P, height, width)
    hole = brush_strokes(height, width, seed=seed, mean_width_px=mean_width_px, area_range=area_range).render(
        mean_width_px
    )
    if hole.all():
        raise ValueError(f"a {mean_width_px:.0f}-px brush covers the whole {width}x{height} image")
    return hole


#: A removal hole brushed over an object: its margin beyond the object's (closed) silhouette, in
#: px at a 1280-px long side (scaled with the long side), as people brush generously around what
#: they remove (15-45 px); the margin wobbles between these bounds along the outline.
BRUSH_MARGIN_1280 = (15.0, 45.0)
#: The wobble's correlation length, as a fraction of the image's long side.
_WOBBLE_LENGTH = 0.04


def brush_margin_px(height: int, width: int) -> tuple[float, float]:
    """:data:`BRUSH_MARGIN_1280` scaled to an ``height`` x ``width`` image."""
    s = max(height, width) / 1280.0
    return BRUSH_MARGIN_1280[0] * s, BRUSH_MARGIN_1280[1] * s


def closed_silhouette(silhouette: np.ndarray, radius_px: float) -> np.ndarray:
    """HxW bool: ``silhouette`` closed (morphological closing with a disc of ``radius_px``) and its
    holes filled, as a brush passes over the gaps between legs and the notches of an outline."""
    r = max(1, round(radius_px))
    pad = r + 1
    grown = np.pad(silhouette.astype(np.uint8), pad)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    closed = cv2.morphologyEx(grown, cv2.MORPH_CLOSE, disc)[pad:-pad, pad:-pad]
    # Holes: background components not connected to the border (flood from a padded corner).
    canvas = np.pad(closed, 1)
    cv2.floodFill(canvas, None, (0, 0), 2)
    return (canvas[1:-1, 1:-1] != 2) | silhouette


def _margin_field(distance: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """HxW float32 local brush margin (px): a smooth random field (white noise blurred over
    :data:`_WOBBLE_LENGTH` of the long side) stretched over the pixels within reach of the outline
    (``0 < distance <= hi + 1``) to span :func:`brush_margin_px`."""
    h, w = distance.shape
    lo, hi = brush_margin_px(h, w)
    sigma = _WOBBLE_LENGTH * max(h, w)
    noise = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), sigma)
    ring = (distance > 0) & (distance <= hi + 1)
    span = noise[ring] if ring.any() else noise.ravel()
    n_lo, n_hi = float(span.min()), float(span.max())
    unit = (noise - n_lo) / max(n_hi - n_lo, 1e-12)
    return (lo + (hi - lo) * np.clip(unit, 0.0, 1.0)).astype(np.float32)


def _distance_to(region: np.ndarray) -> np.ndarray:
    """HxW float32 Euclidean distance of each pixel to the nearest pixel of ``region`` (0 on it)."""
    return cv2.distanceTransform((~region).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def brushed_hole(silhouette: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """HxW bool: a hole brushed over the object whose HxW bool ``silhouette`` is given.

    The silhouette closed (:func:`closed_silhouette` with the largest margin), then every pixel
    whose distance to it is at most the local margin ``m(p)`` (:func:`_margin_field`), so the
    outline wobbles and its distance to the silhouette stays within 15-45 px at 1280 px (within
    a pixel). The margin shows background: in a removal case the truth there is what the target
    already shows."""
    h, w = silhouette.shape
    closed = closed_silhouette(silhouette, brush_margin_px(h, w)[1])
    distance = _distance_to(closed)
    reach = (closed | (distance <= _margin_field(distance, rng))).astype(np.uint8)
    # A far pixel within its own margin but cut off from the object (the field dips between) is
    # no part of a brushed stroke: keep the components touching the silhouette, holes filled.
    _, labels = cv2.connectedComponents(reach, connectivity=8)
    keep = np.isin(labels, np.unique(labels[closed]))
    return closed_silhouette(keep & (labels > 0), 1)


def brushed_interior(hole: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """HxW bool: what an object brushed over by ``hole`` covers: the pixels of ``hole`` farther
    than the local margin ``m(p)`` (:func:`_margin_field`) from its outside, so that the hole's
    outline lies 15-45 px at 1280 px beyond the object (within a pixel), as with
    :func:`brushed_hole`. Empty where the hole is nowhere that wide."""
    distance = _distance_to(~hole)
    return hole & (distance > _margin_field(distance, rng))
