"""Learned depth fitted to stereo depth over dense pixels (the paper's stated future work).

The paper fixes the monocular network's affine ambiguity with the sparse triangulated points only.
Here the fit uses every pixel the plane sweep is confident about, each weighted by its confidence,
plus the triangulated points: thousands of well-spread samples instead of tens to hundreds, so the
fit no longer hinges on where SIFT happened to fire. The fit is robust (Huber) and lives in
inverse depth, where the network's ambiguity is affine. The result is in pose units (the sweep's).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import ReferenceUnusable
from ..triangulate import TriangulatedPoints
from ..utils.resolution import rescale_points
from . import DepthContext, DepthPrediction
from .align import MIN_POINTS_AFFINE, fit_affine, sample_at
from .onnx import predict_learned
from .stereo import SweepResult, plane_sweep

#: Most stereo pixels in the fit (a regular subsample beyond this): enough for two parameters.
MAX_FIT_PIXELS = 20000


def fit_to_stereo(
    learned: np.ndarray, sweep: SweepResult, points: TriangulatedPoints, min_confidence: float, source_shape
) -> tuple[float, float, int]:
    """Scale/offset (s, b) with ``s * learned + b ~ stereo inverse depth`` and the sample count.

    ``learned`` is at the sweep's resolution; ``points`` are in pixels of a ``source_shape`` (h, w)
    image. Samples: confident sweep pixels (weight = confidence) and the triangulated points
    (weight 1)."""
    ok = (sweep.confidence >= min_confidence) & np.isfinite(sweep.inv_depth) & np.isfinite(learned)
    ys, xs = np.nonzero(ok)
    if len(ys) > MAX_FIT_PIXELS:
        keep = np.linspace(0, len(ys) - 1, MAX_FIT_PIXELS).astype(int)
        ys, xs = ys[keep], xs[keep]
    h, w = learned.shape
    uv = rescale_points(points.uv_source, (source_shape[1], source_shape[0]), (w, h))
    x = np.concatenate([learned[ys, xs], sample_at(learned, uv)]).astype(np.float64)
    y = np.concatenate([sweep.inv_depth[ys, xs], 1.0 / points.depth]).astype(np.float64)
    wgt = np.concatenate([sweep.confidence[ys, xs], np.ones(len(points))]).astype(np.float64)
    good = np.isfinite(x) & np.isfinite(y)
    n = int(good.sum())
    if n < MIN_POINTS_AFFINE:
        raise ReferenceUnusable(f"only {n} stereo/triangulated samples to fit the learned depth to")
    s, b = fit_affine(x[good], y[good], robust=True, weights=wgt[good])
    return s, b, n


class FusedDepth:
    """``fused`` backend: learned inverse depth mapped to pose units by :func:`fit_to_stereo`."""

    name = "fused"

    def predict(self, ctx: DepthContext) -> DepthPrediction:
        learned = predict_learned(ctx.source, ctx.cfg)
        sweep = plane_sweep(ctx)
        h, w = sweep.inv_depth.shape
        small = cv2.resize(learned, (w, h), interpolation=cv2.INTER_AREA)
        s, b, _ = fit_to_stereo(small, sweep, ctx.points, ctx.cfg.stereo_min_confidence, ctx.source.shape[:2])
        return DepthPrediction((s * learned + b).astype(np.float32), "inverse", self.name, in_pose_units=True)
