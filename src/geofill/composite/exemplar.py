"""Multi-scale exemplar-based completion: Wexler, Shechtman & Irani (2007) with PatchMatch search
(Barnes et al. 2009), the method behind Photoshop's content-aware fill, with Newson et al.'s (2017)
texture features, each surface around the hole filled from itself, and the large-scale structure
diffused per surface.

The known pixels are first split into surfaces (:mod:`geofill.composite.surfaces`: a wall, the
ground), extended into the hole, the line where two meet continued straight across it. Each hole
pixel is copied from patches of the known image of its own surface (in a reference fill: the
target and the pasted render, see :mod:`geofill.composite.merge`). At every level of an image
pyramid, coarse to fine, a PatchMatch search finds for each patch touching the hole its nearest
known patch, and each hole pixel becomes the similarity-weighted mean of what those patches put on
it (search, vote, repeat). Patches are compared on colour and on texture features (mean absolute
derivatives over a coarsest-pixel window, computed at full resolution): without them coarse
matching, where every region is smooth, settles on flat sources and the fill comes out a smear
again (gradient-energy ratio 0.57 instead of 0.9 on 3 DEV pairs). The coarsest level starts from
Telea; each finer level starts from the coarser one's matches doubled and only refines them (a
14-px search); the finest level's pixels are taken from their own patch's match, not averaged,
which would blur.

Finally each hole pixel is the structure, blurred within its surface at the Gaussian scale
``structure_sigma``, plus the copied pixel's detail: its difference from the mean of its own
surface's known pixels around it at that scale. The structure is one membrane over the hole from
all the known pixels, of the colour less a per-surface offset, the offset added back: the offsets
differ by the colour step where the surfaces meet on the ring, so a wall's colour does not bleed
onto the ground, yet a smooth gradient that the colours split into two surfaces runs on (a
membrane per surface, with a free edge where they met, made it two plateaus). A misplaced exemplar
structure costs twice in error, a diffused one once; detail measured in its own context puts no
light halo round a dark copy, as the difference from the pasted mosaic's own mean did.

Levels longer than 1400 px are not searched, and memory is bounded by the searched levels: the
finer ones are never held whole, the full-resolution result is assembled in row strips.

Hand-written with numba because no library does it within the time bounds: OpenCV contrib's
``xphoto.inpaint`` (SHIFTMAP, FSR) and PyPatchMatch take 5-30 s per 720-px fill (docs/results.md).

Deterministic: the random search draws from a hash of (seed, level, iteration, patch), and the
search runs in fixed row bands (boundaries alternating between iterations so matches propagate
across them), each band on one thread reading only its own matches, so the bytes do not depend on
the number of threads or their timing.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from ..utils.distance import distance_to
from ..utils.jit import njit_cached
from ..utils.membrane import membrane_fill, resize_channels
from .surfaces import segment

#: Rows per search band (one thread's unit of work); odd iterations shift the bands by half of it.
_BAND_ROWS = 24
#: The coarsest level is the first whose hole is at most this many patch widths from the known
#: image and whose long side is at most _COARSE_LONG_SIDE (its search is global, and a thin hole
#: across a large image would otherwise be searched globally at full resolution), or the last one
#: at least _MIN_SIDE_PATCHES patches across.
_COARSE_DEPTH_PATCHES = 1.0
_COARSE_LONG_SIDE = 256
_MIN_SIDE_PATCHES = 6
#: Holes no deeper than this (px from the known image) are diffused, not copied (see complete).
_DIFFUSE_DEPTH_PX = 2.0
#: Weight of the texture features against the colour channels in the patch distance.
_FEATURE_WEIGHT = 60.0
#: Long side (px) above which a level is not searched (see :func:`complete`).
_SEARCH_LONG_SIDE = 1400
#: Random-search radius at the levels below the coarsest, in patch widths.
_REFINE_RADIUS_PATCHES = 2
#: A surface is filled from itself only when it has at least this many known patches per target
#: patch (else from anywhere: a few patches copied over a large area repeat visibly).
_MIN_SURFACE_SOURCES = 0.1
#: Levels with fewer target patches than this run in the calling thread.
_PARALLEL_MIN_TARGETS = 20_000


@dataclass(frozen=True)
class ExemplarSettings:
    """``patch_radius``: patches are (2r + 1)^2 px; ``iterations``: EM iterations at the coarsest
    level (halved, to at least ``min_iterations``, at each finer level); ``structure_sigma``: the
    Gaussian scale (px) above which the fill is Telea's diffusion (0: exemplars only); ``seed``: of
    the search."""

    patch_radius: int = 3
    iterations: int = 8
    min_iterations: int = 1
    structure_sigma: float = 4.0
    seed: int = 0


@njit_cached(inline="always")
def _mix(a, b, c, d):  # pragma: no cover - compiled
    # splitmix64 of the four integers: the random search's draws, independent of scheduling
    h = np.uint64(a) * np.uint64(0x9E3779B97F4A7C15)
    h ^= np.uint64(b) + np.uint64(0xBF58476D1CE4E5B9) + (h << np.uint64(6)) + (h >> np.uint64(2))
    h ^= np.uint64(c) + np.uint64(0x94D049BB133111EB) + (h << np.uint64(6)) + (h >> np.uint64(2))
    h ^= np.uint64(d) + np.uint64(0x9E3779B97F4A7C15) + (h << np.uint64(6)) + (h >> np.uint64(2))
    h ^= h >> np.uint64(30)
    h *= np.uint64(0xBF58476D1CE4E5B9)
    h ^= h >> np.uint64(27)
    h *= np.uint64(0x94D049BB133111EB)
    h ^= h >> np.uint64(31)
    return h


@njit_cached(inline="always")
def _ssd(img, ty, tx, sy, sx, r, bound):  # pragma: no cover - compiled
    # Sum of squared differences between the patches centred at (ty, tx) and (sy, sx); the source
    # patch lies inside the image, the target's may not (its outside pixels are skipped). Stops
    # once past ``bound``.
    h, w = img.shape[0], img.shape[1]
    total = 0.0
    for dy in range(-r, r + 1):
        y = ty + dy
        if y < 0 or y >= h:
            continue
        for dx in range(-r, r + 1):
            x = tx + dx
            if x < 0 or x >= w:
                continue
            for c in range(img.shape[2]):
                d = img[y, x, c] - img[sy + dy, sx + dx, c]
                total += d * d
        if total > bound:
            return total
    return total


@njit_cached(nogil=True, fastmath=True)
def _search(img, valid, slab, tlab, tid, ty, tx, nnf, dist, bands, step, radius, seed, r):  # pragma: no cover
    # One PatchMatch pass over the bands listed in ``bands`` (rows: first, last+1 target index):
    # propagation from the previous neighbour in scan order (left/up for step 1, right/down for
    # step -1, inside the band only), then a random search around the best match at halving radii.
    # A target with a surface (``tlab`` >= 0) takes sources of that surface (``slab``) only.
    h, w = img.shape[0], img.shape[1]
    for b in range(bands.shape[0]):
        lo, hi = bands[b, 0], bands[b, 1]
        n = hi - lo
        for i in range(n):
            k = lo + i if step > 0 else hi - 1 - i
            y, x = ty[k], tx[k]
            tl = tlab[k]
            by, bx, best = nnf[k, 0], nnf[k, 1], dist[k]
            for nb in range(2):
                py, px = (y, x - step) if nb == 0 else (y - step, x)
                if py < 0 or py >= h or px < 0 or px >= w:
                    continue
                j = tid[py, px]
                if j < lo or j >= hi:
                    continue
                cy = nnf[j, 0] + (y - py)
                cx = nnf[j, 1] + (x - px)
                if cy < 0 or cy >= h or cx < 0 or cx >= w or not valid[cy, cx]:
                    continue
                if tl >= 0 and slab[cy, cx] != tl:
                    continue
                if cy == by and cx == bx:
                    continue
                d = _ssd(img, y, x, cy, cx, r, best)
                if d < best:
                    by, bx, best = cy, cx, d
            rad = radius
            t = 0
            while rad >= 1:
                hv = _mix(seed, k, t, 0)
                cy = by + np.int64(hv % np.uint64(2 * rad + 1)) - rad
                cx = bx + np.int64((hv >> np.uint64(32)) % np.uint64(2 * rad + 1)) - rad
                t += 1
                rad = rad // 2
                if cy < 0 or cy >= h or cx < 0 or cx >= w or not valid[cy, cx]:
                    continue
                if tl >= 0 and slab[cy, cx] != tl:
                    continue
                d = _ssd(img, y, x, cy, cx, r, best)
                if d < best:
                    by, bx, best = cy, cx, d
            nnf[k, 0], nnf[k, 1], dist[k] = by, bx, best


@njit_cached(nogil=True, fastmath=True)
def _vote(img, out, tid, nnf, weight, hy, hx, r):  # pragma: no cover - compiled
    # Each hole pixel (hy, hx) in ``out``: the weighted mean of what the matches of the patches
    # covering it put there. Reads only known pixels of ``img`` (sources lie in the known image).
    h, w, nc = img.shape[0], img.shape[1], img.shape[2]
    acc = np.zeros(nc, np.float64)
    for p in range(hy.shape[0]):
        y, x = hy[p], hx[p]
        acc[:] = 0.0
        ws = 0.0
        for dy in range(-r, r + 1):
            cy = y + dy
            if cy < 0 or cy >= h:
                continue
            for dx in range(-r, r + 1):
                cx = x + dx
                if cx < 0 or cx >= w:
                    continue
                j = tid[cy, cx]
                if j < 0:
                    continue
                sy, sx = nnf[j, 0] - dy, nnf[j, 1] - dx
                wt = weight[j]
                for c in range(nc):
                    acc[c] += wt * img[sy, sx, c]
                ws += wt
        if ws > 0:
            for c in range(nc):
                out[y, x, c] = acc[c] / ws


@njit_cached(nogil=True, fastmath=True)
def _distances(img, ty, tx, nnf, dist, lo, hi, r):  # pragma: no cover - compiled
    for k in range(lo, hi):
        dist[k] = _ssd(img, ty[k], tx[k], nnf[k, 0], nnf[k, 1], r, np.inf)


@njit_cached(nogil=True)
def _copy_matches(image, hole, tid, nnf, top, a0, tex, low, detail):  # pragma: no cover - compiled
    # Each hole pixel of rows a0.. (as many as ``tex`` has) from the full-resolution pixel its
    # level-``top`` patch's match points at (a match's patch is known there, so that pixel is too);
    # with ``detail``, added to ``tex`` less ``low`` (level ``top``) there, bilinearly interpolated.
    h, w = hole.shape
    m = (1 << top) - 1
    f = float(1 << top)
    lh, lw = low.shape[0], low.shape[1]
    for i in range(tex.shape[0]):
        y = a0 + i
        for x in range(w):
            if not hole[y, x]:
                continue
            j = tid[y >> top, x >> top]
            sy = min((nnf[j, 0] << top) + (y & m), h - 1)
            sx = min((nnf[j, 1] << top) + (x & m), w - 1)
            if not detail:
                for c in range(tex.shape[2]):
                    tex[i, x, c] = image[sy, sx, c]
                continue
            u = min(max((sy + 0.5) / f - 0.5, 0.0), lh - 1.0)
            v = min(max((sx + 0.5) / f - 0.5, 0.0), lw - 1.0)
            u0, v0 = min(int(u), lh - 2) if lh > 1 else 0, min(int(v), lw - 2) if lw > 1 else 0
            du, dv = u - u0, v - v0
            u1, v1 = min(u0 + 1, lh - 1), min(v0 + 1, lw - 1)
            for c in range(tex.shape[2]):
                mean = (1 - du) * ((1 - dv) * low[u0, v0, c] + dv * low[u0, v1, c]) + du * (
                    (1 - dv) * low[u1, v0, c] + dv * low[u1, v1, c]
                )
                tex[i, x, c] += image[sy, sx, c] - mean


def _workers() -> int:
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(usable or 1, 8))


@dataclass
class _Level:
    """One pyramid level: the image (float32, hole pixels being estimated), the hole, which patch
    centres may be copied (``valid``), the target patches (those touching the hole: ``ty``, ``tx``,
    their index ``tid`` per pixel, -1 elsewhere), the hole pixels (``hy``, ``hx``), each pixel's
    surface (``slab``) and the surface each target copies from (``tlab``; -1: any, where its own
    surface has too few known patches to copy)."""

    img: np.ndarray
    hole: np.ndarray
    valid: np.ndarray
    ty: np.ndarray
    tx: np.ndarray
    tid: np.ndarray
    hy: np.ndarray
    hx: np.ndarray
    slab: np.ndarray
    tlab: np.ndarray

    @classmethod
    def make(cls, img: np.ndarray, hole: np.ndarray, r: int, surfaces: np.ndarray) -> _Level:
        h, w = hole.shape
        kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
        slab = np.ascontiguousarray(cv2.resize(surfaces, (w, h), interpolation=cv2.INTER_NEAREST))
        # A source patch lies wholly on known pixels of some surface.
        usable = (~hole & (slab >= 0)).astype(np.uint8)
        valid = cv2.erode(usable, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0
        touch = cv2.dilate(hole.astype(np.uint8), kernel) > 0
        ty, tx = np.nonzero(touch)
        tid = np.full((h, w), -1, np.int32)
        tid[ty, tx] = np.arange(ty.size, dtype=np.int32)
        hy, hx = np.nonzero(hole)
        tlab = slab[ty, tx]
        sources = np.bincount(slab[valid], minlength=int(slab.max()) + 1)
        targets = np.bincount(tlab[tlab >= 0], minlength=sources.size)
        thin = sources < np.maximum(_MIN_SURFACE_SOURCES * targets, (2 * r + 1) ** 2)
        tlab = np.where((tlab < 0) | thin[np.maximum(tlab, 0)] | (sources.size == 1), -1, tlab).astype(
            np.int32
        )
        return cls(img, hole, valid, ty.astype(np.int32), tx.astype(np.int32), tid, hy, hx, slab, tlab)


def _downsample(img: np.ndarray, hole: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half-size image (mean of the known pixels of each 2x2 block) and hole (any pixel of the
    block unknown)."""
    known = (~hole).astype(np.float32)
    num = _block_sum(img * known[..., None])
    den = _block_sum(known[..., None])[..., 0]
    small = num / np.maximum(den, 1e-6)[..., None]
    return small.astype(np.float32), den < 3.999


def _block_sum(a: np.ndarray) -> np.ndarray:
    """Sums over 2x2 blocks of an HxWxC array (an odd last row or column repeated)."""
    if a.shape[0] % 2 or a.shape[1] % 2:
        a = np.pad(a, ((0, a.shape[0] % 2), (0, a.shape[1] % 2), (0, 0)), mode="edge")
    return a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]


def complete(
    image: np.ndarray,
    hole: np.ndarray,
    settings: ExemplarSettings | None = None,
    surfaces: np.ndarray | None = None,
) -> np.ndarray:
    """``image`` (HxWx3 uint8) with ``hole`` (HxW bool) painted from patches of the rest of the
    image, which is returned unchanged. ``settings.patch_radius`` shrinks (to 1) where no whole
    patch of that size is known; a hole at most 2 px deep, or one leaving no 3x3 patch known, is
    diffused (Telea). ``surfaces`` (HxW int32, every pixel's surface; negative: on none, never
    copied from): given by the caller (:mod:`geofill.composite.rectify`, from the scene's planes),
    else from appearance (:func:`geofill.composite.surfaces.segment`).

    Memory is bounded by the searched levels (at most ``_SEARCH_LONG_SIDE`` px long): the levels
    above them are never held whole; the full-resolution result is assembled in row strips."""
    s = settings or ExemplarSettings()
    r = s.patch_radius
    hole = hole.astype(bool)
    out = image.copy()
    if not hole.any():
        return out
    # A hole that leaves no whole patch known is copied with the largest patch that fits, down to
    # 3x3. A hole no deeper than _DIFFUSE_DEPTH_PX (speckles, cracks) is diffused: there is no
    # texture to continue across a pixel or two, and on speckles every 4 px of a sharp pattern the
    # 3x3 copies were twice as far from the truth as Telea (mean error 42 vs 21 levels).
    # Pixels on no surface are never copied either.
    blocked = hole if surfaces is None else hole | (surfaces < 0)
    while r > 1 and not _has_patch(blocked, 2 * r + 1):
        r -= 1
    side = 2 * r + 1
    if not _deeper_than(hole, _DIFFUSE_DEPTH_PX) or not _has_patch(blocked, side):
        return _diffused(image, hole, out)

    # Levels longer than _SEARCH_LONG_SIDE are not searched: their matches are the searched level's
    # scaled up (at 4K a search would cost seconds and a copied patch there is as sharp), and only
    # their holes are built; ``top`` is the finest searched level.
    holes = [hole]
    while (
        max(holes[-1].shape) > _SEARCH_LONG_SIDE
        and min(hole.shape) >> len(holes) >= _MIN_SIDE_PATCHES * side
        and _has_patch(small := _downsample_hole(holes[-1]), side)
    ):
        holes.append(small)
    top = len(holes) - 1
    # The hole's depth in top-level pixels; a coarser level's is this halved per level.
    depth = float(distance_to(~holes[top]).max())
    imgs = [_downsample_strips(image, hole, top)]
    holes = holes[top:]
    barred = [np.zeros_like(holes[0]) if surfaces is None else _at(surfaces, holes[0].shape) < 0]
    if not _has_patch(holes[0] | barred[0], side):  # the reduced surfaces leave no patch to copy
        return _diffused(image, hole, out)
    # Coarser levels: halve until the hole is about a patch deep, keeping known patches to copy.
    while (
        depth / 2 ** (len(imgs) - 1) > _COARSE_DEPTH_PATCHES * side
        or max(hole.shape) >> (top + len(imgs) - 1) > _COARSE_LONG_SIDE
    ) and min(hole.shape) >> (top + len(imgs)) >= _MIN_SIDE_PATCHES * side:
        small, small_hole = _downsample(imgs[-1], holes[-1])
        small_barred = _downsample_hole(barred[-1])
        if not _has_patch(small_hole | small_barred, side):
            break
        imgs.append(small)
        holes.append(small_hole)
        barred.append(small_barred)

    # Texture features (Newson et al. 2017): mean absolute x and y derivatives over a window as wide
    # as a coarsest-level pixel, computed at the finest searched level and carried down the pyramid,
    # so that coarse matching, where the image itself is smooth, still tells textured from flat.
    # Each hole pixel is copied from its own surface (see surfaces.py), and its structure diffused
    # from that surface's ring only.
    if surfaces is None:
        surfaces = segment(imgs[0], holes[0], side)
    else:
        surfaces = _at(surfaces, holes[0].shape)
    imgs = _with_features(imgs[0], holes)

    # Coarsest level: diffusion for the structure.
    for c in range(0, imgs[-1].shape[2], 3):
        part = np.ascontiguousarray(imgs[-1][..., c : c + 3])
        scale = 255.0 / max(float(part.max()), 1e-6)
        coarse = np.clip(np.rint(part * scale), 0, 255).astype(np.uint8)
        if coarse.shape[2] == 2:
            coarse = np.dstack([coarse, coarse[..., :1]])
        coarse = cv2.inpaint(coarse, holes[-1].astype(np.uint8), 3.0, cv2.INPAINT_TELEA)
        k = part.shape[2]
        imgs[-1][..., c : c + k] = np.where(holes[-1][..., None], coarse[..., :k] / scale, part)

    workers = ThreadPoolExecutor(_workers())
    try:
        nnf = None
        prev: _Level | None = None
        n_levels = len(imgs)
        for li in range(n_levels - 1, -1, -1):
            lev = _Level.make(np.ascontiguousarray(imgs[li]), holes[li], r, surfaces)
            nnf = _init_nnf(lev, prev, nnf, s.seed + top + li)
            prev = lev
            # Small levels in this thread: handing them to the pool costs more than they do.
            pool = workers if lev.ty.size >= _PARALLEL_MIN_TARGETS else None
            if li < n_levels - 1:
                # Start from the coarser level's matches copied at this resolution.
                _vote_parallel(pool, lev, nnf, np.ones(lev.ty.size, np.float32), r)
            dist = np.empty(lev.ty.size, np.float32)
            _distances_parallel(pool, lev, nnf, dist, r)
            iters = max(s.min_iterations, s.iterations >> (n_levels - 1 - li))
            # A global search at the coarsest level; finer levels refine the matches they inherit.
            radius = max(lev.img.shape[:2]) if li == n_levels - 1 else _REFINE_RADIUS_PATCHES * side
            for it in range(iters):
                # Below the coarsest level the finest compares colour only (see _with_features)
                # and sweeps once: its matches are the coarser level's refined within a few
                # patches, where the texture features (means over a coarsest pixel) hardly differ.
                # On the 8 DEV cases: the same hole PSNR to 0.01 dB in a third of that level's time.
                for sweep, step in enumerate((1, -1) if li or n_levels == 1 else (1,)):
                    bands = _bands(lev.ty, (2 * it + sweep) % 2)
                    seed = int(_seed(s.seed, top + li, it, sweep))
                    _search_parallel(pool, lev, nnf, dist, bands, step, radius, seed, r)
                if it == iters - 1:
                    # The next level starts from the matches alone, and the result is assembled
                    # from them: a last vote would paint pixels nothing reads.
                    break
                _vote_parallel(pool, lev, nnf, _weights(dist, r), r)
                _distances_parallel(pool, lev, nnf, dist, r)
    finally:
        workers.shutdown()
    structure = low = None
    if s.structure_sigma > 0:
        # Large-scale structure from diffusion, texture from the exemplars: a misplaced exemplar
        # structure costs twice in error, a diffused one once. The colour less each surface's step
        # is diffused from all known pixels and the steps added back (see the module docstring),
        # so the wall's colour does not bleed onto the ground and a gradient split into surfaces
        # runs on, at the finest searched level (at 4K a full-resolution diffusion alone would
        # cost more than the search). What is copied is each source pixel's
        # detail, its difference from the mean of the known pixels of its surface around it: the
        # mean of the pasted mosaic would put a light halo round a dark copy, and one taken across
        # surfaces would blur the line where they meet.
        colour = prev.img[..., :3] * 255.0
        known = ~holes[0]
        sigma = s.structure_sigma / 2**top
        structure, low = colour.copy(), colour.copy()
        # Pixels on no surface (negative) are never read: neither copied nor diffused from.
        usable = known & (surfaces >= 0)
        steps = _surface_steps(colour, usable, surfaces, side)
        diffused = membrane_fill(colour - steps, usable, fallback=colour[usable].mean(axis=0)) + steps
        for lab in range(int(surfaces.max()) + 1):
            on = surfaces == lab
            if not (on & known).any():
                continue
            structure[on] = _local_mean(diffused, on, sigma)[on]
            low[on] = _local_mean(colour, known & on, sigma)[on]
    _assemble(out, image, hole, prev, nnf, top, structure, low)
    return out


#: Rows per strip of the full-resolution passes (see :func:`_assemble`).
_STRIP_ROWS = 256
#: Stands for "no mean to subtract" in :func:`_copy_matches` (numba wants an array).
_NO_LOW = np.zeros((1, 1, 3), np.float32)


def _diffused(image: np.ndarray, hole: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out`` with ``hole`` diffused from ``image`` (Telea): where there is nothing to copy."""
    np.copyto(out, cv2.inpaint(image, hole.astype(np.uint8), 5.0, cv2.INPAINT_TELEA), where=hole[..., None])
    return out


def _deeper_than(hole: np.ndarray, px: float) -> bool:
    """Whether some hole pixel is more than ``px`` from every known pixel (exact Euclidean, without
    a full-resolution distance map)."""
    n = int(px)
    yy, xx = np.mgrid[-n : n + 1, -n : n + 1]
    disc = (yy * yy + xx * xx <= px * px).astype(np.uint8)
    return bool(cv2.erode(hole.astype(np.uint8), disc, borderType=cv2.BORDER_CONSTANT, borderValue=1).any())


def _downsample_hole(hole: np.ndarray) -> np.ndarray:
    """The hole of :func:`_downsample`: any pixel of the 2x2 block unknown."""
    if hole.shape[0] % 2 or hole.shape[1] % 2:
        hole = np.pad(hole, ((0, hole.shape[0] % 2), (0, hole.shape[1] % 2)), mode="edge")
    return hole[0::2, 0::2] | hole[1::2, 0::2] | hole[0::2, 1::2] | hole[1::2, 1::2]


def _downsample_strips(image: np.ndarray, hole: np.ndarray, times: int) -> np.ndarray:
    """``image`` (uint8) as float32 in [0, 1], halved ``times`` times by :func:`_downsample`, in row
    strips a multiple of ``2**times`` high (the same values as whole, without a full-size float copy)."""
    f = 1 << times
    rows = f * max(1, _STRIP_ROWS // f)
    parts = []
    for a in range(0, image.shape[0], rows):
        part, part_hole = image[a : a + rows].astype(np.float32) / 255.0, hole[a : a + rows]
        for _ in range(times):
            part, part_hole = _downsample(part, part_hole)
        parts.append(part)
    return np.ascontiguousarray(np.vstack(parts))


def _assemble(
    out: np.ndarray,
    image: np.ndarray,
    hole: np.ndarray,
    lev: _Level,
    nnf: np.ndarray,
    top: int,
    structure: np.ndarray | None,
    low: np.ndarray | None,
) -> None:
    """Writes ``out``'s hole pixels: each the known pixel its searched-level patch's match points at
    (scaled up ``2**top``; not averaged over overlapping patches, which would blur what does not line
    up, Newson et al.); with a ``structure`` (0-255, level ``top``), that scaled up plus the copied
    pixel's difference from ``low`` (level ``top``) there. In row strips: at 58 MP whole-image
    float copies cost gigabytes."""
    h, w = hole.shape
    f = 1 << top
    for a in range(0, h, _STRIP_ROWS):
        b = min(a + _STRIP_ROWS, h)
        if not hole[a:b].any():
            continue
        if structure is None:
            tex = np.zeros((b - a, w, 3), np.float32)
            _copy_matches(image, hole, lev.tid, nnf, top, a, tex, _NO_LOW, False)
        else:
            # Scaled up over these rows only, one coarse row either side so that the
            # interpolation is a whole-image resize's.
            c0, c1 = max(a // f - 1, 0), min(-(-b // f) + 1, structure.shape[0])
            tex = cv2.resize(structure[c0:c1], None, fx=f, fy=f, interpolation=cv2.INTER_LINEAR)
            tex = np.ascontiguousarray(tex[a - c0 * f : b - c0 * f, :w])
            _copy_matches(image, hole, lev.tid, nnf, top, a, tex, low, True)
        part = hole[a:b]
        out[a:b][part] = np.clip(np.rint(tex[part]), 0, 255).astype(np.uint8)


#: Width (px) of the bands either side of where two surfaces meet whose colours give the step, and
#: their distance from it (a boundary from averaged appearance can be a few pixels off).
_STEP_BAND_PX = 5
_STEP_GAP_PX = 3


def _band(mask: np.ndarray, inner: int, outer: int) -> np.ndarray:
    """The pixels more than ``inner`` and at most ``outer`` px (chessboard) from ``mask``."""
    m = mask.astype(np.uint8)
    grow = cv2.dilate(m, np.ones((2 * outer + 1,) * 2, np.uint8)) > 0
    return grow & ~(cv2.dilate(m, np.ones((2 * inner + 1,) * 2, np.uint8)) > 0)


def _surface_steps(colour: np.ndarray, known: np.ndarray, surfaces: np.ndarray, ring_px: int) -> np.ndarray:
    """Per pixel (HxWx3), its surface's colour offset: the offsets differ by the colour step where
    the surfaces meet on the known ring ``ring_px`` wide around the hole (the mean colour in the
    bands either side), or, for surfaces that do not meet there, by their mean colours on it
    (least squares over the pairs, the first surface's offset 0)."""
    n = int(surfaces.max()) + 1
    if n == 1:
        return np.zeros_like(colour)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ring_px + 1,) * 2)
    ring = known & (cv2.dilate((~known).astype(np.uint8), disc) > 0)
    on = [ring & (surfaces == lab) for lab in range(n)]
    near = [_band(m, _STEP_GAP_PX, _STEP_GAP_PX + _STEP_BAND_PX) for m in on]
    rows, rhs = [], []
    for a in range(n):
        for b in range(a + 1, n):
            side_a, side_b = on[a] & near[b], on[b] & near[a]
            if side_a.sum() < ring_px or side_b.sum() < ring_px:
                side_a, side_b = on[a], on[b]
            if not side_a.any() or not side_b.any():
                continue
            row = np.zeros(n)
            row[a], row[b] = 1.0, -1.0
            rows.append(row)
            rhs.append(colour[side_a].mean(axis=0) - colour[side_b].mean(axis=0))
    anchor = np.zeros(n)
    anchor[0] = 1.0
    offsets = np.linalg.lstsq(np.array([anchor, *rows]), np.array([np.zeros(3), *rhs]), rcond=None)[0]
    # Pixels on no surface (negative labels) get no offset.
    return np.where((surfaces >= 0)[..., None], offsets.astype(np.float32)[np.maximum(surfaces, 0)], 0.0)


def _local_mean(values: np.ndarray, weight: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian mean (scale ``sigma``) of ``values`` over the pixels where ``weight`` is True.

    At ``sigma`` >= 2 blurred on the image reduced ``sigma // 2`` times and scaled back: a Gaussian
    that wide passes nothing the reduction loses (its response at the reduced Nyquist frequency is
    below 1e-8 at sigma 4 px); the full-size blurs took 42 ms per call at 720p, these 19 ms."""
    f = max(1, int(sigma // 2))
    h, w = weight.shape
    size = (-(-w // f), -(-h // f))
    num = resize_channels(values * weight[..., None], size, cv2.INTER_AREA)
    den = cv2.resize(weight.astype(np.float32), size, interpolation=cv2.INTER_AREA)
    num, den = cv2.GaussianBlur(num, (0, 0), sigma / f), cv2.GaussianBlur(den, (0, 0), sigma / f)
    return resize_channels(num / np.maximum(den, 1e-6)[..., None], (w, h), cv2.INTER_LINEAR)


def _at(surfaces: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``surfaces`` (int32 labels) at ``shape``, nearest neighbour."""
    return cv2.resize(surfaces.astype(np.int32), shape[::-1], interpolation=cv2.INTER_NEAREST)


def _has_patch(hole: np.ndarray, side: int) -> bool:
    """Whether a whole side x side patch of known pixels exists."""
    return bool(cv2.erode((~hole).astype(np.uint8), np.ones((side, side), np.uint8), borderValue=0).any())


def _with_features(colour: np.ndarray, holes: list[np.ndarray]) -> list[np.ndarray]:
    """Each level's image with the texture features appended (scaled by ``_FEATURE_WEIGHT``),
    downsampled like the colour; the finest level, when coarser ones exist, has the colour only
    (see :func:`complete`)."""
    grey = cv2.cvtColor(colour, cv2.COLOR_RGB2GRAY)
    gx = np.abs(cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=1))
    gy = np.abs(cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=1))
    # Derivatives reading a hole pixel are unknown too.
    known = cv2.erode((~holes[0]).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(np.float32)
    n_levels = len(holes)
    size = 2 ** (n_levels - 1) + 1
    num = cv2.boxFilter(np.dstack([gx * known, gy * known]), -1, (size, size), normalize=False)
    den = cv2.boxFilter(known, -1, (size, size), normalize=False)
    feats = num / np.maximum(den, 1e-6)[..., None] * _FEATURE_WEIGHT
    if n_levels == 1:
        return [np.ascontiguousarray(np.dstack([colour, feats]), dtype=np.float32)]
    half = [_downsample(a, holes[0])[0] for a in (colour, feats.astype(np.float32))]
    out = [np.ascontiguousarray(colour, dtype=np.float32), np.ascontiguousarray(np.dstack(half))]
    for li in range(2, n_levels):
        out.append(_downsample(out[-1], holes[li - 1])[0])
    return out


def _seed(seed: int, level: int, it: int, sweep: int) -> int:
    return (seed * 1_000_003 + level * 10_007 + it * 101 + sweep) & 0x7FFFFFFF


def _bands(ty: np.ndarray, shifted: int) -> np.ndarray:
    """(first, last + 1) target indices of each row band (targets are in raster order)."""
    top = int(ty[0]) - (_BAND_ROWS // 2 if shifted else 0)
    edges = np.arange(top, int(ty[-1]) + _BAND_ROWS + 1, _BAND_ROWS)
    idx = np.searchsorted(ty, edges)
    bands = np.stack([idx[:-1], idx[1:]], axis=1)
    return np.ascontiguousarray(bands[bands[:, 1] > bands[:, 0]], dtype=np.int64)


def _weights(dist: np.ndarray, r: int) -> np.ndarray:
    """Wexler's similarity weights exp(-d / 2 sigma^2), sigma^2 the 75th percentile distance."""
    scale = max(float(np.percentile(dist, 75)), 1e-6)
    return np.exp(-dist / (2.0 * scale)).astype(np.float32)


def _init_nnf(lev: _Level, prev: _Level | None, prev_nnf: np.ndarray | None, seed: int) -> np.ndarray:
    """Matches for this level's targets: the coarser level's doubled (where that is a valid source
    of the target's surface here), else a random valid source of its surface."""
    rng = np.random.default_rng(seed)
    nnf = np.empty((lev.ty.size, 2), np.int64)
    for lab in np.unique(lev.tlab):
        vy, vx = np.nonzero(lev.valid & (lev.slab == lab)) if lab >= 0 else np.nonzero(lev.valid)
        mine = np.flatnonzero(lev.tlab == lab)
        pick = rng.integers(0, vy.size, mine.size)
        nnf[mine, 0], nnf[mine, 1] = vy[pick], vx[pick]
    if prev is not None and prev_nnf is not None:
        cy = np.minimum(lev.ty // 2, prev.tid.shape[0] - 1)
        cx = np.minimum(lev.tx // 2, prev.tid.shape[1] - 1)
        j = prev.tid[cy, cx]
        has = j >= 0
        sy = prev_nnf[j[has], 0] * 2 + (lev.ty[has] & 1)
        sx = prev_nnf[j[has], 1] * 2 + (lev.tx[has] & 1)
        h, w = lev.hole.shape
        ok = (sy < h) & (sx < w)
        ok[ok] = lev.valid[sy[ok], sx[ok]]
        tl = lev.tlab[has]
        ok[ok] = (tl[ok] < 0) | (lev.slab[sy[ok], sx[ok]] == tl[ok])
        idx = np.flatnonzero(has)[ok]
        nnf[idx, 0], nnf[idx, 1] = sy[ok], sx[ok]
    return np.ascontiguousarray(nnf)


def _map(pool: ThreadPoolExecutor | None, fn, items) -> None:
    """``fn`` on every item, on the pool's threads or (no pool) in this one."""
    if pool is None:
        for item in items:
            fn(item)
    else:
        list(pool.map(fn, items))


def _search_parallel(pool, lev, nnf, dist, bands, step, radius, seed, r) -> None:
    parts = [bands[i :: 2 * _workers()] for i in range(2 * _workers())]
    _map(
        pool,
        lambda b: _search(
            lev.img,
            lev.valid,
            lev.slab,
            lev.tlab,
            lev.tid,
            lev.ty,
            lev.tx,
            nnf,
            dist,
            b,
            step,
            radius,
            seed,
            r,
        ),
        [p for p in parts if len(p)],
    )


def _distances_parallel(pool, lev: _Level, nnf: np.ndarray, dist: np.ndarray, r: int) -> None:
    edges = np.linspace(0, lev.ty.size, _workers() + 1).astype(np.int64)
    _map(
        pool,
        lambda i: _distances(lev.img, lev.ty, lev.tx, nnf, dist, edges[i], edges[i + 1], r),
        range(_workers()),
    )


def _vote_parallel(pool, lev: _Level, nnf: np.ndarray, weight: np.ndarray, r: int) -> None:
    chunks = np.array_split(np.arange(lev.hy.size), _workers())
    # Reads only known pixels and writes only hole pixels, so in place is safe.
    _map(pool, lambda c: _vote(lev.img, lev.img, lev.tid, nnf, weight, lev.hy[c], lev.hx[c], r), chunks)
