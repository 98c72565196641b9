"""Residual spatial alignment of a render: dense optical flow on the known band around the hole,
carried smoothly into the hole, composed with the render's correspondence field.

What remains misaligned after pose and depth (a slightly wrong scale, a tilted plane, lens
distortion) shows on the known pixels around the hole as a smooth displacement between the render
and the target. OpenCV's DIS flow measures it there; a membrane (Laplace) interpolation carries it
into the hole, where the target is unknown; and it is applied to the target -> source field
(``map(x + f(x))``) rather than to the rendered colours, so the source is resampled once.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .membrane import membrane_fill

_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}
#: Fewer trusted band vectors than this and no flow is applied.
MIN_FLOW_SAMPLES = 50


@dataclass
class BandFlow:
    """Residual flow target -> render at one resolution: ``render(x + flow(x)) ≈ target(x)``.

    ``flow``: (h, w, 2) float32 px, filled into the hole (zero outside ``hole`` ∪ band);
    ``n_trusted``: band pixels whose vectors were kept; ``median_band_px``: their median length."""

    flow: np.ndarray
    n_trusted: int
    median_band_px: float


def _gray(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


#: Smallest side (px) an image given to OpenCV's DIS flow is padded to.
_DIS_MIN_SIDE = 32


def _dis_flow(dis: cv2.DISOpticalFlow, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """DIS flow a -> b (HxW uint8) on copies padded by edge replication so that the short side is
    at least half the long side and at least 32 px. DIS sizes its pyramid from the long side, so
    on a thin strip (17 x 101 px, a render window around a thin hole) its coarsest level has fewer
    rows than a patch and OpenCV 4.x crashes (segfault) or raises."""
    h, w = a.shape
    side = max(_DIS_MIN_SIDE, (max(h, w) + 1) // 2)
    pad_h, pad_w = max(0, side - h), max(0, side - w)
    if pad_h or pad_w:
        a, b = (cv2.copyMakeBorder(x, 0, pad_h, 0, pad_w, cv2.BORDER_REPLICATE) for x in (a, b))
    return dis.calc(a, b, None)[:h, :w]


def band_flow(
    render: np.ndarray,
    target: np.ndarray,
    hole: np.ndarray,
    band: np.ndarray,
    *,
    preset: str = "fast",
    max_px: float = 24.0,
    consistency_px: float = 1.0,
) -> BandFlow | None:
    """Flow from ``target`` to ``render`` (HxWx3 uint8, same size) measured on ``band`` (HxW bool,
    known target pixels where the render is valid) and membrane-filled into ``hole``.

    Vectors longer than ``max_px`` or whose backward flow does not return within ``consistency_px``
    are dropped. Returns None when fewer than :data:`MIN_FLOW_SAMPLES` vectors are trusted."""
    t_gray, r_gray = _gray(target), _gray(render)
    # Each image shows the other where it has no data, so neither holds an artificial edge (the
    # hole's border) that would pull the flow of the band pixels next to it.
    t_gray[hole] = r_gray[hole]
    dis = cv2.DISOpticalFlow.create(_PRESETS[preset])
    fwd = _dis_flow(dis, t_gray, r_gray)
    bwd = _dis_flow(dis, r_gray, t_gray)
    sx, sy = _displaced_grid(fwd)
    back = cv2.remap(bwd, sx, sy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    length = np.linalg.norm(fwd, axis=2)
    trusted = band & (length <= max_px) & (np.linalg.norm(fwd + back, axis=2) <= consistency_px)
    n = int(trusted.sum())
    if n < MIN_FLOW_SAMPLES:
        return None
    domain = band | hole
    values = np.where(trusted[..., None], fwd, 0.0).astype(np.float32)
    flow = membrane_fill(values, trusted, domain)
    flow[~domain] = 0.0
    return BandFlow(flow, n, float(np.median(length[trusted])))


def _displaced_grid(flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x + flow_x, y + flow_y) per pixel of ``flow`` (HxWx2 float32), as float32 remap maps; the
    pixel grid is broadcast, not built (an int64 ``mgrid`` of the window took 6 ms a call)."""
    h, w = flow.shape[:2]
    sx = flow[..., 0] + np.arange(w, dtype=np.float32)
    sy = flow[..., 1] + np.arange(h, dtype=np.float32)[:, None]
    return sx, sy


def compose_maps(
    map_x: np.ndarray, map_y: np.ndarray, alpha: np.ndarray, flow: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``map(x + flow(x))`` for a target -> source field (all HxW, flow HxWx2 in px of the same
    grid). A pixel keeps ``alpha`` only if all four field samples it interpolates are valid."""
    sx, sy = _displaced_grid(flow)
    new_x = cv2.remap(map_x, sx, sy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    new_y = cv2.remap(map_y, sx, sy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    valid = cv2.remap(alpha.astype(np.float32), sx, sy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    new_alpha = valid > 0.999
    new_x[~new_alpha] = -1.0
    new_y[~new_alpha] = -1.0
    return new_x, new_y, new_alpha
