"""Fix a depth prediction's affine ambiguity with triangulated points (the paper's s^i, b^i).

Where the fit lives: inverse depth by default, whatever the backend's native space, because
(i) learned networks' ambiguity is affine in inverse depth (an offset in depth space cannot express
their shift), (ii) a residual in 1/z is proportional to the pixel displacement it causes for a given
baseline (disparity = f b / z), so least squares there weighs points by what the render sees, and
(iii) measured on the four GT-depth pairs (benchmarks/studies/depth_fit_space.py), it gave a lower AbsRel
(0.068 vs 0.075) and an equal or higher hole PSNR on every pair with the true intrinsics, and +0.9 dB
mean hole PSNR with the default intrinsics guess, since an inverse-depth offset also absorbs
principal-point (stereo ``doffs``) errors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import GeometryConfig
from ..errors import ReferenceUnusable
from ..triangulate import TriangulatedPoints
from ..utils.numerics import robust_linear_fit
from . import DepthPrediction

#: Fewer valid points than this cannot fix two parameters robustly.
MIN_POINTS_AFFINE = 6


@dataclass
class AlignedDepth:
    """Dense source depth z in the units of the pose translation; NaN where invalid."""

    depth: np.ndarray  # (H, W) float32
    scale: float
    offset: float
    space: str  # space of the fit: "depth" or "inverse"
    method: str  # "lstsq", "robust", "scale-only" or "identity"
    n_points: int
    median_rel_error: float  # median |z_fit - z_tri| / z_tri over the points
    negative_fraction: float  # fraction of known pixels whose fitted depth was <= 0 (set invalid)


def sample_at(values: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples (float64) of ``values`` at pixel positions ``uv`` (N, 2), positions clamped to
    the image; NaN where any of the four taps is NaN.

    Written out because this gather at a few thousand points is all that scipy.ndimage (0.2 s to
    import) would be loaded for, and cv2.remap rounds positions to 1/32 px."""
    h, w = values.shape
    x = np.clip(np.asarray(uv[:, 0], np.float64), 0, w - 1)
    y = np.clip(np.asarray(uv[:, 1], np.float64), 0, h - 1)
    x0 = np.minimum(np.floor(x).astype(np.intp), max(w - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.intp), max(h - 2, 0))
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = x - x0, y - y0
    top = values[y0, x0] * (1 - fx) + values[y0, x1] * fx
    bottom = values[y1, x0] * (1 - fx) + values[y1, x1] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float64)


def fit_affine(
    x: np.ndarray, y: np.ndarray, robust: bool, scale_only: bool = False, weights: np.ndarray | None = None
) -> tuple[float, float]:
    """Least-squares ``y ~ s x + b`` (``b = 0`` when ``scale_only``); a Huber M-estimate (loss
    scale: the residuals' MAD) when ``robust``; each sample weighted by ``weights`` (>= 0) when
    given."""
    sw = np.ones_like(x) if weights is None else np.sqrt(np.asarray(weights, dtype=np.float64))
    A = np.stack([x, np.zeros_like(x) if scale_only else np.ones_like(x)], axis=1)
    (s, b), *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
    if robust:
        r = y - (s * x + b)
        mad = 1.4826 * np.median(np.abs(r - np.median(r)))
        f_scale = max(mad, 1e-6 * max(np.abs(y).max(), 1e-12))
        n = 1 if scale_only else 2
        p = robust_linear_fit(A[:, :n] * sw[:, None], y * sw, "huber", f_scale, x0=np.array([s, b])[:n])
        s, b = p[0], (0.0 if scale_only else p[1])
    return float(s), float(b)


def to_depth(values: np.ndarray, space: str, scale: float, offset: float) -> tuple[np.ndarray, float]:
    """Apply ``s v + b`` in ``space`` and convert to z; non-positive results, and those beyond
    float32 (an overflow), become NaN.

    Returns (depth, fraction of finite inputs that became invalid)."""
    with np.errstate(over="ignore", invalid="ignore"):
        a = scale * values.astype(np.float32) + np.float32(offset)
    finite = np.isfinite(a)
    bad = finite & (a <= 0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        z = a if space == "depth" else 1.0 / a
    z = np.where(bad | ~np.isfinite(z), np.nan, z).astype(np.float32)
    return z, float(bad.sum() / max(finite.sum(), 1))


def unit_of(values: np.ndarray) -> float:
    """The power of two nearest the median magnitude of the finite, non-zero ``values`` (1 when
    there are none): dividing by it is exact and brings a map in any unit near 1."""
    v = np.abs(values[np.isfinite(values) & (values != 0)])
    return 1.0 if v.size == 0 else float(2.0 ** np.round(np.log2(np.median(v.astype(np.float64)))))


def align_depth(pred: DepthPrediction, points: TriangulatedPoints, cfg: GeometryConfig) -> AlignedDepth:
    """Scale/offset of ``pred`` fitted to ``points`` (see module docstring for the space)."""
    space = cfg.fit_space
    values = pred.values
    # The fit absorbs any constant factor, so a map in another unit is first brought near 1: in
    # its own unit a depth file of 1e-39 m overflows float32 when inverted (1e39 > 3.4e38).
    unit = 1.0 if pred.in_pose_units else unit_of(values)
    if unit != 1.0 or space != pred.space:
        with np.errstate(divide="ignore", over="ignore"):
            values = (values.astype(np.float64) / unit).astype(np.float32)
            if space != pred.space:
                values = 1.0 / values  # depth <-> inverse depth
        values[np.isinf(values)] = np.nan  # beyond float32 (a wild outlier in that unit): no depth there
    x = sample_at(values, points.uv_source)
    z_tri = points.depth
    y = z_tri if space == "depth" else 1.0 / z_tri
    ok = np.isfinite(x) & np.isfinite(y)
    n = int(ok.sum())
    if pred.in_pose_units:
        s, b, method = 1.0, 0.0, "identity"
    elif n < MIN_POINTS_AFFINE:
        raise ReferenceUnusable(f"only {n} triangulated points fall on valid depth; cannot fit scale/offset")
    else:
        scale_only = pred.metric  # a pure scale is a pure scale in either space
        s, b = fit_affine(x[ok], y[ok], cfg.depth_fit == "robust", scale_only)
        method = "scale-only" if scale_only else cfg.depth_fit
    depth, neg = to_depth(values, space, s, b)
    z_fit, _ = to_depth(x[ok], space, s, b)
    rel = np.abs(z_fit - z_tri[ok]) / z_tri[ok]
    med = float(np.nanmedian(rel)) if n else float("nan")
    # The scale reported applies to the map's own values: s (v / u) in the map's space, s u / v
    # in the other one.
    s_own = s * unit if space != pred.space else s / unit
    return AlignedDepth(depth, s_own, b, space, method, n, med, neg)
