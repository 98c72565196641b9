"""The fuse stage: which reference supplies each hole pixel, and how their regions meet.

Every usable reference brings a refined render of the hole (colour-corrected, flow-aligned). Per
reference and pixel a score in (0, 1] multiplies what can be measured there:

- agreement with the target on the known ring around the hole after colour correction, spread
  into the hole so that each part is judged by the ring next to it: ``0.5 ** (error / band_error_scale)``;
- agreement with the other references where three or more cover the pixel (distance to their
  per-pixel median): ``0.5 ** (distance / consensus_scale)``;
- distance to the render's edge, i.e. to a mesh cut or a disocclusion, where depth is least
  reliable: ``min(1, distance / edge_distance_px)``;
- resolution: how much the source's footprint is stretched (the source area one target pixel
  samples, below 1 where the source is magnified): ``min(1, area) ** 0.5``;
- the viewing-angle change at the surface (target ray vs. source ray): ``0.5 ** (angle / angle_scale_deg)``.

With several references, a render is not copied at all where it differs from the target on the
ring next to the pixel by more than ``max_ring_error`` plus ``ring_texture_factor`` times the ring's
own fine texture (:func:`ring_texture`): a render that far off does not line up with the photo
there, and what no reference may supply is painted (``Fusion.refused_mismatch``).

The best-scoring reference wins each pixel. ``seams="graphcut"`` then lets OpenCV's colour-gradient
graph cut (:class:`cv2.detail_GraphCutSeamFinder`, Kwatra et al. 2003) move the boundary between
two references inside the pixels where both score within ``candidate_ratio`` of the best, so seams
run where the two renders agree; ``seams="feather"`` keeps the per-pixel winner. Either way the
regions are blended over ``feather_px``. ``seams="blend"`` instead averages the references that
cover a pixel with weights ``score ** blend_power``. A render is never mixed in where it has no data.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from ..config import FillConfig, FusionConfig
from ..screen.strangers import shifted_min_diff
from ..utils.distance import known_ring
from ..utils.resolution import config_px, odd_px
from ..utils.windows import mask_window
from .vote import cross_strangers

if TYPE_CHECKING:
    from ..pipeline import ReferenceArtifacts

#: Long side (px) at which the graph cut runs; labels are upsampled to the input resolution.
_SEAM_MAX_SIDE = 640
#: Gaussian kernels from this many taps on are applied in the Fourier domain (see gaussian_blur).
_DFT_BLUR_TAPS = 160
#: Sigma (px at a 1280-px long side) of the blur :func:`ring_texture` measures the target's texture by.
_TEXTURE_BLUR_PX = 2.0


@dataclass(frozen=True)
class Fusion:
    """The fused render at target resolution (HxWx3 uint8, zero where ``alpha`` is False), its
    coverage, and ``labels`` (HxW int16): the reference (1-based) that supplies each covered hole
    pixel, 0 elsewhere. ``image``/``alpha`` are None when no reference could help. ``window``: the
    rows and columns outside which ``labels`` is 0 and ``alpha`` False (at 4K the renders cover a
    fifth of the image, and whole-image passes over the labels cost more than the fusion)."""

    image: np.ndarray | None
    alpha: np.ndarray | None
    labels: np.ndarray
    method: str
    scores: tuple[float, ...] = ()  # per used reference (in the order given): mean score where it supplies
    window: tuple[slice, slice] = (slice(None), slice(None))
    #: HxW bool: hole pixels where a reference's render was refused because the other references
    #: covering them show something else there (None: nothing was).
    refused_stranger: np.ndarray | None = None
    #: HxW bool: hole pixels left to the painter because every render covering them differs from the
    #: target on the ring next to them by more than ``max_ring_error`` allows (None: none were).
    refused_mismatch: np.ndarray | None = None
    #: HxW bool: hole pixels copied from a reference whose render there disagrees with every other
    #: render covering them (None: none were): nothing decided which is right, so the user should look.
    disputed: np.ndarray | None = None

    def supplied_fractions(self, hole: np.ndarray, n_references: int) -> list[float]:
        """Fraction of the hole each reference (in the order given) supplies."""
        n = max(int(np.count_nonzero(hole)), 1)
        rows, cols = self.window
        counts = np.bincount(self.labels[rows, cols][hole[rows, cols]].ravel(), minlength=n_references + 1)
        return [float(c) / n for c in counts[1 : n_references + 1]]

    def disputed_fractions(self, hole: np.ndarray, n_references: int) -> list[float]:
        """Fraction of the hole each reference (in the order given) supplies where it is disputed."""
        if self.disputed is None:
            return [0.0] * n_references
        n = max(int(np.count_nonzero(hole)), 1)
        counts = np.bincount(self.labels[self.disputed & hole].ravel(), minlength=n_references + 1)
        return [float(c) / n for c in counts[1 : n_references + 1]]

    def source_map(self, hole: np.ndarray) -> np.ndarray:
        """HxW int16: -1 outside the hole, 0 painted by single-image inpainting, k from reference k."""
        out = np.full(hole.shape, -1, np.int16)
        rows, cols = mask_window(hole, 0)
        out[rows, cols] = np.where(hole[rows, cols], self.labels[rows, cols], -1)
        return out

    def summary(self) -> str:
        if self.alpha is None:
            return "no reference to fuse"
        labels = self.labels[self.window]
        ks = np.unique(labels[labels > 0])
        return f"{self.method}: {len(ks)} reference(s) supply {int(np.count_nonzero(labels))} px"

    def report(self) -> dict[str, Any]:
        out: dict[str, Any] = {"method": self.method, "scores": list(self.scores)}
        if self.refused_stranger is not None:
            out["refused_stranger_px"] = int(np.count_nonzero(self.refused_stranger))
        if self.refused_mismatch is not None:
            out["refused_mismatch_px"] = int(np.count_nonzero(self.refused_mismatch))
        return out


def fuse_references(
    target: np.ndarray, hole: np.ndarray, refs: Sequence[ReferenceArtifacts], cfg: FillConfig
) -> Fusion:
    """Fuse the refined renders of the usable references ``refs`` (see the module docstring)."""
    labels = np.zeros(hole.shape, np.int16)
    if not refs:
        return Fusion(None, None, labels, "none")
    if len(refs) == 1:
        # Its refined render passes through as it is; only the labels are written, in its window.
        r = refs[0].screened
        rows, cols = refs[0].refined.render.window()
        labels[rows, cols][r.alpha[rows, cols] & hole[rows, cols]] = refs[0].index
        return Fusion(r.image, r.alpha, labels, "single reference", window=(rows, cols))
    fc = cfg.fusion
    # A canonical order (by content) so that the order the references were given in cannot change
    # the result: the graph cut visits pairs of references in list order.
    refs = sorted(
        refs, key=lambda r: hashlib.blake2b(np.ascontiguousarray(r.source).data, digest_size=16).digest()
    )  # the buffer itself: tobytes() would copy each source image first
    rows, cols = _window(refs, hole)
    hole_w = hole[rows, cols]
    alphas = np.stack([r.screened.alpha[rows, cols] for r in refs])
    images = np.stack([r.screened.image[rows, cols] for r in refs]).astype(np.float32)
    ring = known_ring(hole_w, config_px(cfg.refine.band_px, hole.shape))
    spread = fc.band_sigma_px * config_px(1.0, hole.shape)
    errors = np.stack(
        [
            _ring_error(images[k], target[rows, cols], ring & alphas[k], spread, 2.0 * fc.band_error_scale)
            for k in range(len(refs))
        ]
    )
    scores = np.stack(
        [reference_score(r, errors[k], alphas[k], rows, cols, hole.shape, fc) for k, r in enumerate(refs)]
    )
    scores *= _consensus(images, alphas, fc.consensus_scale)
    mismatch = None
    if fc.max_ring_error > 0:
        limit = fc.max_ring_error + fc.ring_texture_factor * ring_texture(
            target[rows, cols], hole_w, ring, _TEXTURE_BLUR_PX * config_px(1.0, hole.shape), spread
        )
        found = (errors > limit) & alphas & hole_w
        if found.any():
            alphas &= ~found
            images[found] = 0
            mismatch = np.zeros(hole.shape, bool)
            mismatch[rows, cols] = found.any(axis=0) & ~alphas.any(axis=0)
    refused = None
    if fc.cross_strangers != "off" and cfg.screen.stranger_threshold > 0:
        evidence = np.stack([_in_window(r.screened.refused_stranger, rows, cols) for r in refs])
        # The renders as refined, before the screen: what the screen refused of one reference (a
        # stranger) still contradicts another reference's different stranger at the same place.
        found = cross_strangers(
            np.stack([r.refined.image[rows, cols] for r in refs]).astype(np.float32),
            np.stack([r.refined.alpha[rows, cols] for r in refs]),
            hole_w, target[rows, cols], evidence, hole.shape, cfg.screen, scores, fc.candidate_ratio,
        ) & alphas  # fmt: skip
        if found.any():
            alphas &= ~found
            images[found] = 0
            refused = np.zeros(hole.shape, bool)
            refused[rows, cols] = found.any(axis=0)
    # Every covered pixel must pick a reference that covers it, however low its score.
    scores = np.where(alphas, np.maximum(scores, 1e-6), 0.0)
    best = scores.argmax(axis=0)
    covered = alphas.any(axis=0)
    if fc.seams == "graphcut":
        best = _graphcut_labels(refs, rows, cols, scores, best, covered, fc.candidate_ratio)
    if fc.seams == "blend":
        weights = scores**fc.blend_power
        weights /= np.maximum(weights.sum(axis=0), 1e-12)[None]
    else:
        members = best[None] == np.arange(len(refs))[:, None, None]
        if fc.average_agreement > 0:
            members |= _agreeing(images, alphas, scores, best, hole.shape, fc)
        weights = _feathered_weights(members, alphas, covered, config_px(fc.feather_px, hole.shape))
    fused_w = np.rint(np.einsum("khw,khwc->hwc", weights, images)).clip(0, 255).astype(np.uint8)
    image = np.zeros(target.shape, target.dtype)  # calloc: the pages outside the window stay untouched
    image[rows, cols] = fused_w
    alpha = np.zeros(hole.shape, bool)
    alpha[rows, cols] = covered
    index = np.array([r.index for r in refs], np.int16)
    labels[rows, cols] = np.where(covered & hole_w, index[best], 0)
    supplies = [(best == k) & covered & hole_w for k in range(len(refs))]
    mean_scores = tuple(
        float(scores[k][supplies[k]].mean()) if supplies[k].any() else 0.0
        for k in sorted(range(len(refs)), key=lambda k: index[k])
    )
    method = f"{fc.seams} of {len(refs)} references"
    disputed = None
    if cfg.screen.stranger_threshold > 0:
        box = odd_px(5.0 * config_px(1.0, hole.shape))
        found = _disputed(images, alphas, best, covered & hole_w, box, cfg)
        if found.any():
            disputed = np.zeros(hole.shape, bool)
            disputed[rows, cols] = found
    return Fusion(image, alpha, labels, method, mean_scores, (rows, cols), refused, mismatch, disputed)


def _disputed(
    images: np.ndarray, alphas: np.ndarray, best: np.ndarray, copied: np.ndarray, k: int, cfg: FillConfig
) -> np.ndarray:
    """HxW bool (window): ``copied`` pixels whose winning render (``best``) differs from every other
    render covering them by more than ``screen.stranger_threshold`` (mean absolute difference over a
    ``k``-px box), also with either one shifted by up to 12 px (misalignment is not a dispute)."""
    n = len(images)
    out = np.zeros(copied.shape, bool)
    if n < 2:
        return out
    box = np.ones((k, k), np.uint8)
    inner = np.stack([cv2.erode(a.astype(np.uint8), box) > 0 for a in alphas])
    for w in range(n):
        mine = copied & (best == w) & inner[w]
        others = [j for j in range(n) if j != w and (inner[j] & mine).any()]
        if not others:
            continue
        against = np.ones(copied.shape, bool)
        for j in others:
            diff = cv2.blur(np.abs(images[w] - images[j]).mean(axis=2), (k, k))
            apart = diff > cfg.screen.stranger_threshold
            if apart.any():
                reach = 12.0 * k / 5.0
                apart &= shifted_min_diff(images[w], images[j], k, reach) > cfg.screen.cross_shift_threshold
            against &= apart | ~inner[j]
        out |= mine & against & np.logical_or.reduce([inner[j] for j in others])
    return out


def _in_window(mask: np.ndarray | None, rows: slice, cols: slice) -> np.ndarray:
    """``mask`` (HxW bool or None for none) in the window."""
    if mask is None:
        return np.zeros((rows.stop - rows.start, cols.stop - cols.start), bool)
    return mask[rows, cols]


def reference_score(
    ref: ReferenceArtifacts,
    error: np.ndarray,
    a: np.ndarray,
    rows: slice,
    cols: slice,
    shape: tuple[int, int],
    cfg: FusionConfig,
) -> np.ndarray:
    """Score in [0, 1] of ``ref``'s screened render (coverage ``a``, the window ``rows, cols`` of
    a target of ``shape``) at each pixel of the window, from everything but the other references
    (0 where it has no render). ``error``: its :func:`_ring_error` against the target."""
    refined = ref.refined
    if not a.any():
        return np.zeros(a.shape, np.float32)
    px = config_px(1.0, shape)
    edge = cv2.distanceTransform(a.astype(np.uint8), cv2.DIST_L2, 3)
    edge_w = np.clip(edge / max(cfg.edge_distance_px * px, 1.0), 0.05, 1.0)
    area = _footprint_area(refined.render.map_x[rows, cols], refined.render.map_y[rows, cols], a)
    angle = _viewing_angle_deg(ref, shape, rows, cols)
    s = 0.5 ** (error / cfg.band_error_scale) * edge_w * np.sqrt(np.clip(area, 0.0, 1.0))
    s *= 0.5 ** (angle / cfg.angle_scale_deg)
    return np.where(a, s, 0.0).astype(np.float32)


def _ring_error(
    image: np.ndarray, target: np.ndarray, ring: np.ndarray, sigma: float, fallback: float
) -> np.ndarray:
    """Mean absolute difference (0-255) between ``image`` and ``target`` on ``ring``, spread over
    the window by normalised Gaussian smoothing; far from any ring pixel it tends to the ring's
    mean (``fallback`` when the render covers none of the ring)."""
    w = ring.astype(np.float32)
    if not ring.any():
        return np.full(ring.shape, fallback, np.float32)
    diff = np.abs(image - target.astype(np.float32))
    err = (diff[..., 0] + diff[..., 1] + diff[..., 2]) / 3 * w  # = mean(axis=-1), 3.5x faster
    overall = float(err.sum() / w.sum())
    eps = 1e-3
    num = gaussian_blur(err, sigma)
    den = gaussian_blur(w, sigma)
    return (num + eps * overall) / (den + eps)


def ring_texture(
    target: np.ndarray, hole: np.ndarray, ring: np.ndarray, blur_px: float, spread_px: float
) -> np.ndarray:
    """The target's own fine texture next to each pixel of the window: the mean absolute difference
    (0-255) between ``target`` (HxWx3 uint8) and its Gaussian blur of ``blur_px`` (the hole left
    out) on ``ring``, spread over the window as :func:`_ring_error` spreads a render's error. A
    render misaligned by a pixel or two differs from a textured ring by about this much.

    >>> hole = np.zeros((40, 40), bool); hole[15:25, 15:25] = True
    >>> ring = ~hole & np.pad(np.ones((20, 20), bool), 10)
    >>> stripes = np.zeros((40, 40, 3), np.uint8); stripes[:, ::2] = 100  # a fine texture
    >>> blank = np.full((40, 40, 3), 100, np.uint8); blank[hole] = 0  # flat, the hole blanked
    >>> [round(float(ring_texture(t, hole, ring, 2.0, 8.0)[20, 20])) for t in (stripes, blank)]
    [50, 0]
    """
    known = (~hole).astype(np.float32)
    # Normalised: the hole's own pixels (blank, or the object to remove) must not count as texture.
    smooth = cv2.GaussianBlur(target.astype(np.float32) * known[..., None], (0, 0), blur_px)
    smooth /= np.maximum(cv2.GaussianBlur(known, (0, 0), blur_px), 1e-6)[..., None]
    return _ring_error(smooth, target, ring, spread_px, 0.0)


def gaussian_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """``cv2.GaussianBlur(image, (0, 0), sigma)`` of a float32 image (same kernel, reflect-101
    border), equal to it up to float rounding (1e-6 relative).

    GaussianBlur filters directly, at a cost proportional to the kernel's taps; ``cv2.filter2D``
    convolves in the Fourier domain once a 2-D kernel is large. On a 1253 x 1246 window (a 4K hole's)
    the ring error's sigma of 48 px (385 taps) took 293 vs 56 ms, 193 taps 84 vs 38 ms; at 129 taps
    and below on smaller windows the direct filter is as fast or faster, so it stays there."""
    taps = round(sigma * 8 + 1) | 1  # OpenCV's kernel size for float images
    if taps < _DFT_BLUR_TAPS:
        return cv2.GaussianBlur(image, (0, 0), sigma)
    k = cv2.getGaussianKernel(taps, sigma, cv2.CV_32F)
    return cv2.filter2D(image, -1, k @ k.T, borderType=cv2.BORDER_REFLECT_101)


def _consensus(images: np.ndarray, alphas: np.ndarray, scale: float) -> np.ndarray:
    """(K, H, W) factor ``0.5 ** (distance to the covering references' median / scale)`` where at
    least three references cover a pixel, else 1 (two cannot outvote each other)."""
    out = np.ones(alphas.shape, np.float32)
    many = alphas.sum(axis=0) >= 3
    if not many.any():
        return out
    stack = np.where(alphas[..., None], images, np.nan)[:, many]  # (K, N, 3)
    median = np.nanmedian(stack, axis=0)
    dist = np.abs(stack - median[None]).mean(axis=-1)
    out[:, many] = np.where(np.isfinite(dist), 0.5 ** (dist / scale), 1.0)
    return out


def _window(refs: Sequence[ReferenceArtifacts], hole: np.ndarray) -> tuple[slice, slice]:
    """The smallest window holding the hole and every reference's render window (the pipeline's
    render windows hold the hole already)."""
    rows, cols = mask_window(hole, 0)
    x0, y0, x1, y1 = cols.start, rows.start, cols.stop, rows.stop
    for r in refs:
        roi = r.refined.render.roi or (0, 0, hole.shape[1], hole.shape[0])
        x0, y0, x1, y1 = min(x0, roi[0]), min(y0, roi[1]), max(x1, roi[2]), max(y1, roi[3])
    return slice(y0, y1), slice(x0, x1)


def _footprint_area(map_x: np.ndarray, map_y: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Source pixels sampled per target pixel (|det| of the map's Jacobian); 1 where undefined."""
    dxx, dxy = np.gradient(map_x, axis=1), np.gradient(map_x, axis=0)
    dyx, dyy = np.gradient(map_y, axis=1), np.gradient(map_y, axis=0)
    area = np.abs(dxx * dyy - dxy * dyx)
    # Next to an uncovered pixel the map holds -1: the difference there is meaningless.
    interior = cv2.erode(alpha.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    return np.where(interior, area, 1.0).astype(np.float32)


def _viewing_angle_deg(
    ref: ReferenceArtifacts, shape: tuple[int, int], rows: slice, cols: slice
) -> np.ndarray:
    """Angle (deg) at the rendered surface point between the target's ray and the source's ray."""
    g = ref.geometry
    K = g.K_target.resized(shape[1], shape[0])
    z = ref.refined.render.depth[rows, cols]
    z = np.where(np.isfinite(z), z, np.float32(0.0))
    xs = np.arange(shape[1], dtype=np.float32)[cols][None, :]
    ys = np.arange(shape[0], dtype=np.float32)[rows][:, None]
    # One array per coordinate: sums over a trailing axis of 3 are slow in NumPy (4x at 4K).
    X, Y = (xs - K.cx) / K.fx * z, (ys - K.cy) / K.fy * z
    t = g.T[:3, 3].astype(np.float32)  # the source centre is at t in target coordinates
    sx, sy, sz = X - t[0], Y - t[1], z - t[2]
    norms = np.sqrt(X * X + Y * Y + z * z) * np.sqrt(sx * sx + sy * sy + sz * sz)
    cos = (X * sx + Y * sy + z * sz) / np.maximum(norms, 1e-12)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).astype(np.float32)


def _graphcut_labels(
    refs: Sequence[ReferenceArtifacts],
    rows: slice,
    cols: slice,
    scores: np.ndarray,
    best: np.ndarray,
    covered: np.ndarray,
    ratio: float,
) -> np.ndarray:
    """The per-pixel winners ``best`` with the boundaries between references moved by a
    colour-gradient graph cut inside the pixels where more than one scores near the best."""
    top = scores.max(axis=0)
    candidates = (scores >= ratio * top[None]) & (scores > 0)
    h, w = best.shape
    s = min(1.0, _SEAM_MAX_SIDE / max(h, w))
    size = (max(round(w * s), 1), max(round(h * s), 1))
    images, masks = [], []
    for k, r in enumerate(refs):
        img = r.screened.image[rows, cols].astype(np.float32)
        images.append(cv2.UMat(cv2.resize(img, size, interpolation=cv2.INTER_AREA)))
        m = cv2.resize(candidates[k].astype(np.uint8) * 255, size, interpolation=cv2.INTER_NEAREST)
        masks.append(cv2.UMat(m))
    finder = cv2.detail_GraphCutSeamFinder("COST_COLOR_GRAD")
    found = finder.find(images, [(0, 0)] * len(refs), masks)
    out = best.copy()
    for k, m in enumerate(found):
        full = cv2.resize(m.get(), (w, h), interpolation=cv2.INTER_NEAREST) > 0
        # The cut only re-assigns pixels among references that are good there.
        out[full & candidates[k] & covered] = k
    return out


def _agreeing(
    images: np.ndarray,
    alphas: np.ndarray,
    scores: np.ndarray,
    best: np.ndarray,
    shape: tuple[int, int],
    cfg: FusionConfig,
) -> np.ndarray:
    """(K, H, W) bool: the references that agree with the winner ``best`` at each pixel, and are
    averaged with it: they cover the pixel, score at least ``candidate_ratio`` of the winner, their
    colours differ from the winner's by less than ``average_agreement`` (mean absolute difference
    over a 5-px box, 0-255). Averaging renders that agree cancels their independent
    errors (resampling, colour correction, small misalignment)."""
    take = lambda a: np.take_along_axis(a, best[None], 0)[0]  # noqa: E731 - the winner's value
    win = np.take_along_axis(images, best[None, ..., None], 0)[0]
    k = odd_px(5.0 * config_px(1.0, shape))
    out = alphas & (scores >= cfg.candidate_ratio * take(scores)[None])
    for j in range(len(images)):
        if out[j].any():
            diff = cv2.blur(np.abs(images[j] - win).mean(axis=2), (k, k))
            out[j] &= diff < cfg.average_agreement
    return out


def _feathered_weights(
    members: np.ndarray, alphas: np.ndarray, covered: np.ndarray, feather_px: float
) -> np.ndarray:
    """(K, H, W) float32 blending weights: each reference's region ``members`` (K, H, W bool; the
    regions may overlap, and are then averaged) blurred over ``feather_px``, restricted to where it
    has a render, normalised to sum to 1 where any reference covers."""
    onehot = (members & covered[None]).astype(np.float32)
    if feather_px > 0:
        sigma = feather_px / 2.0
        onehot = np.stack([cv2.GaussianBlur(o, (0, 0), sigma) for o in onehot])
    onehot *= alphas
    total = onehot.sum(axis=0)
    # Where blurring left no weight on a covered pixel (a thin region), fall back to its members.
    empty = covered & (total <= 1e-6)
    if empty.any():
        onehot[:, empty] = members[:, empty]
        total = onehot.sum(axis=0)
    return onehot / np.maximum(total, 1e-6)[None]
