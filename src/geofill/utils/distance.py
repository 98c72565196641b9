"""Exact Euclidean distance to the pixels of a mask, the same in every run.

Written by hand (Felzenszwalb & Huttenlocher's lower envelope of parabolas, "Distance Transforms of
Sampled Functions", 2012) because neither library transform fits a fill:

- OpenCV's exact mode (``cv2.distanceTransform`` with ``DIST_MASK_PRECISE``) is not deterministic:
  on one 320x240 hole it returned two results in turn within a process, and a third with two
  threads, ~1e-5 px apart. The joint optimisation's hole weight W_h turned that into poses 5e-6
  apart, and two runs of the same fill differed by coverage flips of up to 38 grey levels.
- SciPy's exact transform (``scipy.ndimage.distance_transform_edt``) gives one answer, but importing
  ``scipy.ndimage`` parses every docstring of the package (0.08-0.09 s of a 2 s fill); nothing else
  on the fill's path imports it.

Squared distances are integers below 2^53, so every step is exact in float64 and the result equals
SciPy's bit for bit (tested); the square root is taken once, in float64, as SciPy does.
"""

from __future__ import annotations

import cv2
import numpy as np

from .jit import njit_cached


def known_ring(hole: np.ndarray, width_px: float) -> np.ndarray:
    """Known pixels within ``width_px`` of the hole (the same in any window holding the hole: the
    two-pass chamfer distance to a pixel is reached by a path inside their bounding box)."""
    dist = cv2.distanceTransform((~hole).astype(np.uint8), cv2.DIST_L2, 3)
    return ~hole & (dist <= max(width_px, 1.0))


def distance_to(mask: np.ndarray) -> np.ndarray:
    """(H, W) float32: each pixel's Euclidean distance (px) to the nearest True pixel of ``mask``
    (0 on them; infinite everywhere when ``mask`` has none).

    >>> distance_to(np.array([[True, False, False]])).tolist()
    [[0.0, 1.0, 2.0]]
    """
    if mask.ndim != 2:
        raise ValueError(f"distance_to needs a 2-D mask, got shape {mask.shape}")
    if not mask.any():
        return np.full(mask.shape, np.inf, np.float32)
    squared = np.where(mask, 0.0, np.inf)
    _lower_envelope_rows(squared.T)  # along the columns, then along the rows: the 2-D transform
    _lower_envelope_rows(squared)
    out = np.empty(mask.shape, np.float32)
    np.sqrt(squared, out=out, casting="same_kind")
    return out


@njit_cached(nogil=True)
def _lower_envelope_rows(a):  # pragma: no cover - compiled
    """In place, each row of ``a`` (any strides): ``a[r, q] <- min_p (q - p)^2 + a[r, p]`` over the
    finite ``a[r, p]`` (inf where none is finite)."""
    h, w = a.shape
    f = np.empty(w)  # the row being transformed (the row itself is overwritten)
    v = np.empty(w, np.int64)  # vertices of the parabolas on the lower envelope
    z = np.empty(w + 1)  # where each of them takes over from the one before
    for r in range(h):
        for q in range(w):
            f[q] = a[r, q]
        k = -1
        for q in range(w):
            if f[q] == np.inf:
                continue  # never the lowest; leaving it out keeps the arithmetic finite
            s = -np.inf
            while k >= 0:
                p = v[k]
                s = ((f[q] + q * q) - (f[p] + p * p)) / (2.0 * (q - p))
                if s > z[k]:
                    break
                k -= 1  # never below 0: z[0] is -inf
            k += 1
            v[k] = q
            z[k] = s
            z[k + 1] = np.inf
        if k < 0:
            continue  # no finite value: the row stays inf
        j = 0
        for q in range(w):
            while z[j + 1] < q:
                j += 1
            p = v[j]
            a[r, q] = (q - p) * (q - p) + f[p]
