"""Membrane (Laplace) interpolation: fill unknown pixels of a field smoothly from known ones.

Used to carry quantities measured on the known band around a hole (colour corrections, residual
flow) into the hole: the harmonic interpolant reproduces constant and linear fields exactly and never
overshoots the known values (maximum principle), which is what a correction that must agree with the
hole's border needs. Hand-written because OpenCV's seamless cloning solves only on a rectangle around
the mask with fixed image boundaries and SciPy has no masked Laplace solver. The sparse system is
solved by conjugate gradients preconditioned with a multigrid V-cycle, in NumPy and OpenCV: SciPy's
sparse LU did it before, and importing SciPy's sparse and optimisation modules took ~0.13 s of every
fill, which aims at 2 s (``tests/test_refine.py`` compares the two solutions).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

#: Above this many unknowns the field is solved on a coarser grid and upsampled (a smooth field
#: loses nothing; the limit dates from a sparse LU solve, whose time grew faster than linearly).
MAX_UNKNOWNS = 20_000
#: Pull towards ``fallback`` per pixel: keeps the system non-singular where a region of unknowns
#: touches no known pixel (there it returns ``fallback``), negligible elsewhere.
_TIKHONOV = 1e-9
#: The solve stops when every channel's residual is this fraction of its right-hand side. On the
#: solves of a 1280x720 fill and of berlin_01_02 the answer was then within 2e-5 of the field's
#: range of the exact (sparse LU) one: gains and offsets within 2e-5 (0.005 grey levels), flows
#: within 1e-4 px.
_TOLERANCE = 1e-5
_MAX_ITERATIONS = 200
#: Damped Jacobi smoothing in the V-cycle (2/3: the usual weight for a 5-point Laplacian).
_JACOBI_WEIGHT = 2.0 / 3.0
#: The coarse grids are 2x2 aggregates with the exact (Galerkin) coarse operator; their piecewise
#: constant correction undershoots a smooth error, and scaling it up took the iterations from
#: 17-19 to 13 on those solves. Any positive scale keeps the preconditioner symmetric positive
#: definite.
_COARSE_WEIGHT = 1.5
#: The coarsest grid has at most this many unknowns and is solved exactly (dense inverse).
_COARSEST_UNKNOWNS = 100

_CROSS = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], np.float32)


def membrane_fill(
    values: np.ndarray,
    known: np.ndarray,
    domain: np.ndarray | None = None,
    fallback: np.ndarray | float = 0.0,
    max_unknowns: int = MAX_UNKNOWNS,
) -> np.ndarray:
    """Solve Laplace's equation for the pixels of ``domain`` that are not ``known``.

    ``values``: (H, W) or (H, W, C) float field, read only where ``known`` (H, W bool) is True;
    ``domain`` (default: everything) bounds the solve with a free (Neumann) edge; outside it, and
    at known pixels, the input is returned unchanged. Unknown regions that touch no known pixel take
    ``fallback`` (per channel). Fields with more than ``max_unknowns`` unknowns are solved on a
    coarser grid (block means of the known values) and bilinearly upsampled."""
    field = np.asarray(values, np.float32)
    squeeze = field.ndim == 2
    if squeeze:
        field = field[..., None]
    domain = np.ones(known.shape, bool) if domain is None else domain
    unknown = domain & ~known
    out = field.copy()
    n_unknown = int(unknown.sum())
    if n_unknown:
        fb = np.broadcast_to(np.asarray(fallback, np.float32), (field.shape[2],))
        factor = math.ceil(math.sqrt(n_unknown / max_unknowns)) if n_unknown > max_unknowns else 1
        if factor == 1:
            solved = _solve(field, known & domain, unknown, fb)
        else:
            solved = _solve_coarse(field, known & domain, domain, fb, factor)
        out[unknown] = solved[unknown]
    return out[..., 0] if squeeze else out


def _neighbour_sum(a: np.ndarray) -> np.ndarray:
    """Sum of the 4 neighbours of every pixel of an (h, w) array (zero beyond the image)."""
    return cv2.filter2D(a, -1, _CROSS, borderType=cv2.BORDER_CONSTANT)


def _stacked_neighbour_sum(x: np.ndarray) -> np.ndarray:
    """:func:`_neighbour_sum` of each channel of a channel-first (C, h, w) array, as one filter of
    the channels stacked vertically: right wherever the first and last rows are not needed
    (solver vectors are zero there: :func:`_pcg` pads its box with a row on either side)."""
    c, h, w = x.shape
    return _neighbour_sum(x.reshape(c * h, w)).reshape(c, h, w)


def _solve(field: np.ndarray, known: np.ndarray, unknown: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """4-neighbour Laplace solve on the grid of ``field`` (the system ``(L + t I) u = b + t
    fallback``, t = :data:`_TIKHONOV`). Its regions of unknowns that touch no known pixel are
    exactly ``fallback``; the others are solved on their bounding boxes (see :func:`_groups`)."""
    out = np.zeros_like(field)
    n_labels, labels, stats, _ = cv2.connectedComponentsWithStats(unknown.astype(np.uint8), connectivity=4)
    touching = (cv2.dilate(known.astype(np.uint8), _CROSS.astype(np.uint8)) > 0) & unknown
    reached_label = np.zeros(n_labels, bool)
    reached_label[labels[touching]] = True
    reached_label[0] = False  # the known pixels' label
    reached = reached_label[labels]
    out[unknown & ~reached] = fallback
    for group in _groups(stats, reached_label):
        y0, y1, x0, x1 = _box(stats[group])
        box = (slice(max(y0 - 1, 0), y1 + 1), slice(max(x0 - 1, 0), x1 + 1))
        # A group is one region, or all of them together.
        inside = labels[box] == group[0] if group.size == 1 else reached[box]
        out[box][inside] = _pcg(field[box], known[box], inside, fallback)[inside]
    return out


#: Regions of unknowns are solved on one shared box unless their own boxes together cover at most
#: this share of it.
_SEPARATE_SHARE = 0.5


def _box(stats: np.ndarray) -> tuple[int, int, int, int]:
    """Rows and columns (first, last + 1) of the bounding box of ``cv2.connectedComponentsWithStats``
    rows."""
    x, y = stats[:, cv2.CC_STAT_LEFT], stats[:, cv2.CC_STAT_TOP]
    return (
        int(y.min()),
        int((y + stats[:, cv2.CC_STAT_HEIGHT]).max()),
        int(x.min()),
        int((x + stats[:, cv2.CC_STAT_WIDTH]).max()),
    )


def _groups(stats: np.ndarray, solved: np.ndarray) -> list[np.ndarray]:
    """The labels to solve together: all in one system, or each alone. Regions of unknowns are
    independent systems (4-neighbour Laplacian, not 4-connected: no equation links them), but one
    solve costs its bounding box's area per iteration: scattered regions (what a render leaves
    uncovered across a hole) were solved on a box of the whole image. Each region is solved on its
    own box when those boxes cover at most :data:`_SEPARATE_SHARE` of the shared one, else all
    together on it."""
    labels = np.flatnonzero(solved)
    if labels.size <= 1:
        return [labels] if labels.size else []
    y0, y1, x0, x1 = _box(stats[labels])
    own = stats[labels, cv2.CC_STAT_WIDTH].astype(np.int64) * stats[labels, cv2.CC_STAT_HEIGHT]
    if own.sum() > _SEPARATE_SHARE * (y1 - y0) * (x1 - x0):
        return [labels]
    return [labels[i : i + 1] for i in range(labels.size)]


class _Level:
    """A symmetric 5-point operator on the ``unknown`` pixels of a grid: ``(A x)_p = diag_p x_p -
    sum over the 4 neighbours q of w_pq x_q``, with ``east`` / ``south`` the weights to the next
    pixel in x / y (zero unless both are unknown). Without weights they are 1 between unknowns (the
    finest grid, applied with one OpenCV filter). Vectors are channel-first (C, h, w) float32
    arrays, zero off the unknowns: NumPy's products and per-channel sums over (h, w, C) arrays with
    a short last axis took 2-5x as long."""

    def __init__(
        self,
        unknown: np.ndarray,
        diag: np.ndarray,
        east: np.ndarray | None = None,
        south: np.ndarray | None = None,
    ) -> None:
        self.unknown, self.diag, self.east, self.south = unknown, diag, east, south
        self.mask = unknown.astype(np.float32)
        self.diag32 = diag.astype(np.float32)
        self.inv_diag = np.where(unknown, 1.0 / np.where(unknown, diag, 1.0), 0.0).astype(np.float32)
        if east is not None:
            self.w_e, self.w_s = east.astype(np.float32), south.astype(np.float32)
            self.w_w, self.w_n = np.zeros_like(self.w_e), np.zeros_like(self.w_s)
            self.w_w[:, 1:], self.w_n[1:] = self.w_e[:, :-1], self.w_s[:-1]

    def apply(self, x: np.ndarray) -> np.ndarray:
        if self.east is None:
            return (self.diag32 * x - _stacked_neighbour_sum(x)) * self.mask
        xp = np.pad(x, ((0, 0), (1, 1), (1, 1)))
        return (
            self.diag32 * x
            - self.w_e * xp[:, 1:-1, 2:]
            - self.w_w * xp[:, 1:-1, :-2]
            - self.w_s * xp[:, 2:, 1:-1]
            - self.w_n * xp[:, :-2, 1:-1]
        )

    def weights(self) -> tuple[np.ndarray, np.ndarray]:
        """(east, south) edge weights, also where they are implicit (1 between unknowns)."""
        if self.east is not None:
            return self.east, self.south
        u = self.unknown.astype(np.float32)
        east, south = np.zeros_like(u), np.zeros_like(u)
        east[:, :-1], south[:-1] = u[:, :-1] * u[:, 1:], u[:-1] * u[1:]
        return east, south

    def coarser(self) -> _Level:
        """The Galerkin operator P^T A P of 2x2 aggregates (P: piecewise constant): a coarse
        pixel's diagonal is its block's diagonals less twice the weights inside the block, its
        weight to a neighbour the sum of the fine weights crossing between the blocks."""
        u, diag, east, south = (
            _pad_even(a) for a in (self.unknown.astype(np.float32), self.diag, *self.weights())
        )
        inner = east[0::2, 0::2] + east[1::2, 0::2] + south[0::2, 0::2] + south[0::2, 1::2]
        return _Level(
            _block_sum(u) > 0,
            _block_sum(diag) - 2.0 * inner,
            east[0::2, 1::2] + east[1::2, 1::2],
            south[1::2, 0::2] + south[1::2, 1::2],
        )


def _pad_even(a: np.ndarray) -> np.ndarray:
    """``a`` padded with zeros to even sizes of its last two axes."""
    return np.pad(a, [(0, 0)] * (a.ndim - 2) + [(0, a.shape[-2] % 2), (0, a.shape[-1] % 2)])


def _block_sum(a: np.ndarray) -> np.ndarray:
    """Sums of the 2x2 blocks of the last two axes (even sizes)."""
    return a[..., 0::2, 0::2] + a[..., 1::2, 0::2] + a[..., 0::2, 1::2] + a[..., 1::2, 1::2]


def _hierarchy(finest: _Level) -> tuple[list[_Level], np.ndarray]:
    """The grids down to at most :data:`_COARSEST_UNKNOWNS` unknowns, and the inverse of the
    coarsest operator."""
    levels = [finest]
    while int(levels[-1].unknown.sum()) > _COARSEST_UNKNOWNS:
        levels.append(levels[-1].coarser())
    last = levels[-1]
    ys, xs = np.nonzero(last.unknown)
    index = np.full(last.unknown.shape, -1)
    index[ys, xs] = np.arange(ys.size)
    A = np.diag(last.diag[ys, xs].astype(np.float64))
    for weights, (dy, dx) in zip(last.weights(), ((0, 1), (1, 0)), strict=True):
        ok = (ys + dy < index.shape[0]) & (xs + dx < index.shape[1])
        i, j = np.flatnonzero(ok), index[ys[ok] + dy, xs[ok] + dx]
        i, j, wt = i[j >= 0], j[j >= 0], weights[ys[ok], xs[ok]][j >= 0]
        A[i, j] = A[j, i] = -wt
    return levels, np.linalg.inv(A).astype(np.float32)


def _v_cycle(levels: list[_Level], coarsest_inverse: np.ndarray, b: np.ndarray, k: int = 0) -> np.ndarray:
    """One multigrid V-cycle for ``A_k x = b`` from x = 0: a Jacobi sweep, the coarse-grid
    correction, a Jacobi sweep (the same sweep before and after keeps it symmetric)."""
    level = levels[k]
    if k == len(levels) - 1:
        ys, xs = np.nonzero(level.unknown)
        x = np.zeros_like(b)
        x[:, ys, xs] = b[:, ys, xs] @ coarsest_inverse  # the inverse is symmetric
        return x
    x = _JACOBI_WEIGHT * level.inv_diag * b
    coarse = _v_cycle(levels, coarsest_inverse, _block_sum(_pad_even(b - level.apply(x))), k + 1)
    c, h, w = coarse.shape
    # Piecewise-constant prolongation: 2x nearest-neighbour upsampling of the stacked channels.
    up = cv2.resize(coarse.reshape(c * h, w), (2 * w, 2 * c * h), interpolation=cv2.INTER_NEAREST)
    x += _COARSE_WEIGHT * up.reshape(c, 2 * h, 2 * w)[:, : b.shape[1], : b.shape[2]] * level.mask
    return x + _JACOBI_WEIGHT * level.inv_diag * (b - level.apply(x))


def _pcg(field: np.ndarray, known: np.ndarray, unknown: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """The Laplace solve of :func:`_solve` for unknowns that all reach a known pixel: conjugate
    gradients (float64, one per channel) preconditioned by a V-cycle (float32)."""
    # One row of neither known nor unknown pixels above and below (a free edge, like the image's):
    # channel-first vectors are then zero on each channel's first and last rows.
    unknown, known = np.pad(unknown, ((1, 1), (0, 0))), np.pad(known, ((1, 1), (0, 0)))
    values = np.pad(np.where(known[1:-1, :, None], field, 0.0), ((1, 1), (0, 0), (0, 0)))
    u = unknown.astype(np.float64)
    diag = np.where(unknown, _neighbour_sum((unknown | known).astype(np.float32)) + _TIKHONOV, 0.0)
    levels, coarsest_inverse = _hierarchy(_Level(unknown, diag))
    fb = np.asarray(fallback, np.float64)[:, None, None]
    b = (_stacked_neighbour_sum(values.transpose(2, 0, 1).astype(np.float64)) + _TIKHONOV * fb) * u
    b_norm = np.sqrt(np.einsum("kij,kij->k", b, b))
    b_norm[b_norm == 0] = 1.0

    def precondition(r: np.ndarray) -> np.ndarray:
        return _v_cycle(levels, coarsest_inverse, r.astype(np.float32)).astype(np.float64)

    def ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
        return np.divide(num, den, out=np.zeros_like(num), where=den != 0)[:, None, None]

    x, r = np.zeros_like(b), b.copy()
    z = precondition(r)
    p = z
    rz = np.einsum("kij,kij->k", r, z)
    for _ in range(_MAX_ITERATIONS):
        Ap = (diag * p - _stacked_neighbour_sum(p)) * u
        alpha = ratio(rz, np.einsum("kij,kij->k", p, Ap))
        x += alpha * p
        r -= alpha * Ap
        if np.all(np.sqrt(np.einsum("kij,kij->k", r, r)) <= _TOLERANCE * b_norm):
            break
        z = precondition(r)
        rz_new = np.einsum("kij,kij->k", r, z)
        p = z + ratio(rz_new, rz) * p
        rz = rz_new
    return x[:, 1:-1].transpose(1, 2, 0).astype(np.float32)


def _solve_coarse(
    field: np.ndarray, known: np.ndarray, domain: np.ndarray, fallback: np.ndarray, factor: int
) -> np.ndarray:
    """Solve on a grid ``factor`` times coarser and upsample (bilinear)."""
    h, w = field.shape[:2]
    size = (max(1, math.ceil(w / factor)), max(1, math.ceil(h / factor)))
    kf = known.astype(np.float32)
    weight = cv2.resize(kf, size, interpolation=cv2.INTER_AREA)
    sums = resize_channels(field * kf[..., None], size, cv2.INTER_AREA)
    # A partly known block counts as known; its mean sits up to a block off its centre, which
    # measured no worse on the real pairs than keeping only whole blocks (which thin out a band).
    coarse_known = weight > 0.0
    coarse = sums / np.maximum(weight, 1e-12)[..., None]
    coarse_domain = cv2.resize(domain.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.0
    coarse_unknown = coarse_domain & ~coarse_known
    coarse[coarse_unknown] = _solve(coarse, coarse_known, coarse_unknown, fallback)[coarse_unknown]
    coarse[~coarse_domain] = fallback
    return resize_channels(coarse, (w, h), cv2.INTER_LINEAR)


def resize_channels(field: np.ndarray, size: tuple[int, int], interpolation: int) -> np.ndarray:
    """``cv2.resize`` of an (H, W, C) array to ``size`` = (width, height), any C (OpenCV resizes at
    most 4 channels at once); ``field`` itself when it has that size already (OpenCV would copy it)."""
    if (field.shape[1], field.shape[0]) == tuple(size):
        return field
    parts = [
        cv2.resize(np.ascontiguousarray(field[..., i : i + 4]), size, interpolation=interpolation)
        for i in range(0, field.shape[2], 4)
    ]
    return np.concatenate([p.reshape(size[1], size[0], -1) for p in parts], axis=2)
