"""Edge-aware densification of sparse values, guided by the source image.

OpenCV's EdgeAwareInterpolator (EpicFlow, Revaud et al. 2015) interpolates sparse values with
locally-affine fits over geodesic (edge-aware) neighbourhoods of the guide image. Used on inverse
depth, which is exactly affine in the image for planar surfaces, a plane seen through enough seeds
is reproduced exactly (and extrapolated across gaps), and depth edges follow image edges. Both the
``sparse`` backend (seeds: triangulated points) and the ``stereo`` backend (seeds: confident sweep
pixels) complete their maps with it.
"""

from __future__ import annotations

import cv2
import numpy as np

#: The interpolator carries values as a displacement field; it is tuned for displacements of a few
#: pixels, so values are rescaled to this median magnitude and back.
_VALUE_SCALE_PX = 10.0


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Float RGB in [0, 1] -> uint8 (rounded)."""
    return np.clip(image * 255.0 + 0.5, 0, 255).astype(np.uint8)


def interpolate_edge_aware(
    guide: np.ndarray,
    uv: np.ndarray,
    values: np.ndarray,
    k: int = 128,
    out_size: tuple[int, int] | None = None,
) -> np.ndarray:
    """Dense (H, W) float32 map from ``values`` (N,) at pixel positions ``uv`` (N, 2) of ``guide``.

    ``guide``: uint8 RGB image the interpolation runs on (its size sets the work); ``k``: seeds per
    local affine fit; ``out_size``: (w, h) to resize the result to (bilinear), default the guide's.
    ``values`` should be positive with a meaningful median (inverse depths are)."""
    h, w = guide.shape[:2]
    uv = np.clip(uv, 0, [w - 1, h - 1]).astype(np.float32)
    # Repeated seed positions (SIFT puts one keypoint per orientation on a spot) also make the
    # interpolator read uninitialised memory (run-to-run different depth, inf/NaN): keep the first.
    _, first = np.unique(uv, axis=0, return_index=True)
    first.sort()
    uv, values = uv[first], np.asarray(values)[first]
    scale = _VALUE_SCALE_PX / float(np.median(np.abs(values)))
    to = uv + np.stack([values * scale, np.zeros_like(values)], axis=1).astype(np.float32)
    interp = cv2.ximgproc.createEdgeAwareInterpolator()
    # FGS post-smoothing blurs across the affine fits and breaks planes (measured: mean error
    # 0.0003 -> 0.007 on an exact plane), so it is off.
    interp.setUsePostProcessing(False)
    # With K close to the number of seeds the interpolator reads uninitialised memory (measured:
    # different results, even NaN, from run to run with 36 seeds and K = 35 or 36); half is stable.
    interp.setK(int(min(k, max(len(values) // 2, 3))))
    flow = interp.interpolate(guide, uv, guide, to.astype(np.float32))
    dense = flow[..., 0] / scale
    if out_size is not None and out_size != (w, h):
        dense = cv2.resize(dense, out_size, interpolation=cv2.INTER_LINEAR)
    return dense.astype(np.float32)
