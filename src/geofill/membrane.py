"""Membrane (Laplace) interpolation: fill unknown pixels of a field smoothly from known ones.

Used to carry quantities measured on the known band around a hole (colour corrections, residual
flow) into the hole: the harmonic interpolant reproduces constant and linear fields exactly and never
overshoots the known values (maximum principle), which is what a correction that must agree with the
hole's border needs. Hand-written because OpenCV's seamless cloning solves only on a rectangle around
the mask with fixed image boundaries and SciPy has no masked Laplace solver; the sparse system itself
is solved by SciPy's SuperLU.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

#: Above this many unknowns the field is solved on a coarser grid and upsampled (a smooth field
#: loses nothing; SuperLU time grows faster than linearly: ~0.2 s at 32 k, ~5 s at 185 k unknowns).
MAX_UNKNOWNS = 20_000
#: Pull towards ``fallback`` per pixel: keeps the system non-singular where a region of unknowns
#: touches no known pixel (there it returns ``fallback``), negligible elsewhere.
_TIKHONOV = 1e-9


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


def _solve(field: np.ndarray, known: np.ndarray, unknown: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Exact 4-neighbour Laplace solve on the grid of ``field``."""
    h, w, c = field.shape
    idx = np.full((h + 2, w + 2), -1, np.int64)  # padded: the image edge is a free edge
    ys, xs = np.nonzero(unknown)
    n = ys.size
    idx[ys + 1, xs + 1] = np.arange(n)
    kn = np.zeros((h + 2, w + 2), bool)
    kn[1:-1, 1:-1] = known
    padded = np.zeros((h + 2, w + 2, c), np.float64)
    padded[1:-1, 1:-1] = field
    degree = np.full(n, _TIKHONOV)
    rhs = np.tile(_TIKHONOV * fallback.astype(np.float64), (n, 1))
    rows, cols = [], []
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        ny, nx = ys + 1 + dy, xs + 1 + dx
        nb = idx[ny, nx]
        is_unknown = nb >= 0
        is_known = kn[ny, nx]
        degree += is_unknown | is_known
        rows.append(np.flatnonzero(is_unknown))
        cols.append(nb[is_unknown])
        rhs[is_known] += padded[ny[is_known], nx[is_known]]
    r, cc = np.concatenate(rows), np.concatenate(cols)
    A = sp.csc_matrix(
        (
            np.concatenate([degree, -np.ones(r.size)]),
            (np.concatenate([np.arange(n), r]), np.concatenate([np.arange(n), cc])),
        ),
        shape=(n, n),
    )
    sol = spla.splu(A).solve(rhs)
    out = np.zeros_like(field)
    out[ys, xs] = sol
    return out


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
    most 4 channels at once)."""
    parts = [
        cv2.resize(np.ascontiguousarray(field[..., i : i + 4]), size, interpolation=interpolation)
        for i in range(0, field.shape[2], 4)
    ]
    return np.concatenate([p.reshape(size[1], size[0], -1) for p in parts], axis=2)
