"""Weight-free depth: dense source depth from the triangulated points by edge-aware interpolation.

OpenCV's EdgeAwareInterpolator (EpicFlow, Revaud et al. 2015) interpolates sparse values with
locally-affine fits over geodesic (edge-aware) neighbourhoods guided by the source image. We
interpolate inverse depth, which is exactly affine in the image for planar surfaces, so a plane
seen through enough points is reproduced exactly, and depth edges follow image edges.
"""

from __future__ import annotations

import cv2
import numpy as np

from . import DepthContext, DepthPrediction

#: The interpolator carries values as a displacement field; it is tuned for displacements of a few
#: pixels, so values are rescaled to this median magnitude and back.
_VALUE_SCALE_PX = 10.0


class SparseDepth:
    name = "sparse"

    def predict(self, ctx: DepthContext) -> DepthPrediction:
        pts = ctx.points
        if len(pts) < 3:
            raise ValueError(f"sparse depth needs triangulated points; got {len(pts)}")
        h, w = ctx.source.shape[:2]
        s = min(1.0, ctx.cfg.sparse_max_side / max(h, w))
        ws, hs = max(round(w * s), 8), max(round(h * s), 8)
        guide = cv2.resize(
            np.clip(ctx.source * 255.0 + 0.5, 0, 255).astype(np.uint8), (ws, hs), cv2.INTER_AREA
        )
        uv = ((pts.uv_source + 0.5) * [ws / w, hs / h] - 0.5).astype(np.float32)
        uv = np.clip(uv, 0, [ws - 1, hs - 1]).astype(np.float32)
        # SIFT puts several keypoints (orientations) on one spot, so the same point can come twice;
        # the interpolator then reads uninitialised memory (run-to-run different depth, inf/NaN).
        _, first = np.unique(uv, axis=0, return_index=True)
        keep = np.sort(first)
        uv, inv = uv[keep], 1.0 / pts.depth[keep]
        k = _VALUE_SCALE_PX / float(np.median(inv))
        to = uv + np.stack([inv * k, np.zeros_like(inv)], axis=1).astype(np.float32)
        interp = cv2.ximgproc.createEdgeAwareInterpolator()
        # FGS post-smoothing blurs across the affine fits and breaks planes (measured: mean error
        # 0.0003 -> 0.007 on an exact plane), so it is off.
        interp.setUsePostProcessing(False)
        interp.setK(int(min(128, len(uv))))
        flow = interp.interpolate(guide, uv, guide, to.astype(np.float32))
        inv_dense = cv2.resize(flow[..., 0] / k, (w, h), interpolation=cv2.INTER_LINEAR)
        inv_dense[~(inv_dense > 0)] = np.nan
        return DepthPrediction(inv_dense.astype(np.float32), "inverse", self.name, in_pose_units=True)
