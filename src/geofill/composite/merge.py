"""Merge the refined render with single-image inpainting (the paper's composite equation).

``I_comp = I_t`` outside the hole and ``M_single * I_render + (1 - M_single) * I_single`` inside,
where ``M_single`` is the render's coverage feathered over ``feather_px``: 0 where the render has no
data (disocclusions, outside the source), rising to 1 at ``feather_px`` from them. ``I_single`` is
inpainted over the uncovered pixels *and* that ramp, with the render pasted as context, so the two
meet without a seam and the render's least reliable pixels (next to a cut depth edge) fade out."""

from __future__ import annotations

import cv2
import numpy as np

from ..utils.distance import distance_to
from ..utils.windows import mask_window
from .inpaint import Inpainter
from .planes import SceneDepth


def blend_map(hole: np.ndarray, alpha: np.ndarray, feather_px: float) -> np.ndarray:
    """``M_single`` (HxW float32 in [0, 1]): 0 outside ``hole & alpha``; inside it, the distance to
    the nearest uncovered hole region divided by ``feather_px``, capped at 1. Uncovered specks
    smaller than a ``feather_px`` square (cracks where a mesh edge was cut inside a surface) are
    inpainted without a ramp: feathering around each of them would blur the render wholesale.
    Everything it depends on lies in the hole, so any window holding the hole gives the same map."""
    covered = hole & alpha
    uncovered = hole & ~alpha
    if feather_px <= 0 or not uncovered.any():
        return covered.astype(np.float32)
    _, labels, stats, _ = cv2.connectedComponentsWithStats(uncovered.astype(np.uint8), connectivity=8)
    large = stats[:, cv2.CC_STAT_AREA] >= feather_px * feather_px
    large[0] = False  # background label
    regions = large[labels]
    if not regions.any():
        return covered.astype(np.float32)
    dist = distance_to(regions)
    np.divide(dist, np.float32(feather_px), out=dist)
    np.minimum(dist, 1.0, out=dist)
    dist[~covered] = 0.0
    return dist


def merge_fill(
    target: np.ndarray,
    hole: np.ndarray,
    render: np.ndarray | None,
    alpha: np.ndarray | None,
    inpainter: Inpainter,
    feather_px: float = 0.0,
    depth: SceneDepth | None = None,
) -> np.ndarray:
    """Composite of ``target`` (HxWx3 uint8), the ``render`` (HxWx3 uint8, valid where ``alpha``)
    and single-image inpainting; without a render the whole hole is inpainted. Pixels outside
    ``hole`` are the target's, byte for byte. ``depth``: the scene's (target view), for the
    painter's planes.

    Only the hole's bounding box grown by what the inpainter reads (:attr:`Inpainter.context_px`)
    is worked on: at 4K the full-image maps and copies cost more than the inpainting."""
    if render is None or alpha is None or not hole.any():
        return inpainter.fill(target, hole, depth)
    out = target.copy()
    rows, cols = mask_window(hole, inpainter.context_px)
    hole_w, render_w, view = hole[rows, cols], render[rows, cols], out[rows, cols]
    m = blend_map(hole_w, alpha[rows, cols], feather_px)
    pasted = view.copy()
    np.copyto(pasted, render_w, where=(m > 0)[..., None])
    filled = inpainter.fill(pasted, hole_w & (m < 1.0), depth and depth.window(rows, cols))
    ramp = (m > 0) & (m < 1)
    if ramp.any():
        w = m[ramp][:, None]
        filled[ramp] = np.rint(w * render_w[ramp] + (1.0 - w) * filled[ramp]).astype(np.uint8)
    np.copyto(view, filled, where=hole_w[..., None])
    return out
