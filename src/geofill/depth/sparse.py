"""Weight-free depth: dense source depth from the triangulated points by edge-aware interpolation
(:func:`geofill.depth.completion.interpolate_edge_aware` on inverse depth)."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import ReferenceUnusable
from ..utils.resolution import rescale_points
from . import DepthContext, DepthPrediction
from .completion import interpolate_edge_aware, to_uint8


class SparseDepth:
    name = "sparse"

    def predict(self, ctx: DepthContext) -> DepthPrediction:
        pts = ctx.points
        if len(pts) < 3:
            raise ReferenceUnusable(f"sparse depth needs triangulated points; got {len(pts)}")
        h, w = ctx.source.shape[:2]
        s = min(1.0, ctx.cfg.sparse_max_side / max(h, w))
        ws, hs = max(round(w * s), 8), max(round(h * s), 8)
        guide = cv2.resize(to_uint8(ctx.source), (ws, hs), interpolation=cv2.INTER_AREA)
        uv = rescale_points(pts.uv_source, (w, h), (ws, hs))
        inv_dense = interpolate_edge_aware(guide, uv, 1.0 / pts.depth, out_size=(w, h))
        inv_dense[~(inv_dense > 0)] = np.nan
        return DepthPrediction(inv_dense, "inverse", self.name, in_pose_units=True)
