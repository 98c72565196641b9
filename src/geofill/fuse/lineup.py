"""Which references' renders line up with the photo around the hole.

A render from a wrong geometry (matches on a repeated texture, a view of the scene's other side)
still agrees with the target's colours on the ring around the hole once refinement has corrected
its colours and flowed it into place; its structure does not. As rendered, before refinement, its
zero-mean normalised cross-correlation (ZNCC) with the photo over small windows of the known ring is
near 0, where a render from the right geometry correlates: 0.4-0.96 for the best reference of every
DEV multi-reference set and removal with several references, 0.1-0.3 for right but loosely aligned
ones (Lund's cobbles), -0.03-0.05 for the three references of the NLE tower that see the tower's
other side. The ZNCC's level depends on the ring's texture, so a reference is judged against the
others of the same fill, on the same ring: one that does not correlate while another does is not
used. Written by hand: OpenCV's ``matchTemplate`` gives one window's ZNCC over shifts, not a
per-pixel ZNCC between two aligned images; box filters give that in five passes.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..config import FusionConfig
from ..render import RenderResult
from ..utils.distance import known_ring
from ..utils.resolution import config_px, odd_px
from ..utils.windows import mask_window

#: Width (px at a 1280-px long side) of the known ring compared, and side of the ZNCC's windows.
RING_PX = 30.0
WINDOW_PX = 11.0
#: Grey-level variance (0-255 squared) over a window below which it is flat: its ZNCC is noise.
MIN_VARIANCE = 4.0
#: Textured ring pixels (at a 1280-px long side) below which a render is not judged.
MIN_RING_PX = 500.0


@dataclass(frozen=True)
class LineUp:
    """How a render lines up with the photo on the ring: the median ZNCC over the textured ring
    pixels it covers (nan where fewer than :data:`MIN_RING_PX`), and how many it covers."""

    correlation: float
    ring_px: int


def ring_correlation(
    render: RenderResult, source: np.ndarray, target: np.ndarray, hole: np.ndarray
) -> LineUp:
    """:class:`LineUp` of ``render`` (of ``source``, HxWx3 uint8) against ``target`` (HxWx3 uint8)
    on the known ring around ``hole`` (HxW bool).

    >>> rng = np.random.default_rng(0)
    >>> target = cv2.GaussianBlur(rng.integers(0, 255, (200, 200, 3), dtype=np.uint8), (5, 5), 0)
    >>> hole = np.zeros((200, 200), bool); hole[80:120, 80:120] = True
    >>> ys, xs = np.mgrid[:200, :200].astype(np.float32)
    >>> same = RenderResult(xs, ys, np.ones_like(xs), np.ones((200, 200), bool))
    >>> round(ring_correlation(same, target, target, hole).correlation, 2)
    1.0
    """
    shape = hole.shape
    window = odd_px(WINDOW_PX * config_px(1.0, shape))
    ring_w = config_px(RING_PX, shape)
    rows, cols = mask_window(hole, int(np.ceil(ring_w)) + window)
    alpha = render.alpha[rows, cols]
    # A window that reaches past the render's edge (a mesh cut, the source's border) would compare
    # the photo with zeros.
    inside = cv2.erode(alpha.astype(np.uint8), np.ones((window, window), np.uint8)) > 0
    ring = known_ring(hole[rows, cols], ring_w) & inside
    if not ring.any():
        return LineUp(float("nan"), 0)
    # Zero where the render is empty: no box centred on the eroded ring reaches there.
    a = cv2.cvtColor(render.sample_window(source, (rows, cols)), cv2.COLOR_RGB2GRAY).astype(np.float32)
    b = cv2.cvtColor(target[rows, cols], cv2.COLOR_RGB2GRAY).astype(np.float32)
    box = (window, window)
    mean_a, mean_b = cv2.blur(a, box), cv2.blur(b, box)
    var_a = cv2.blur(a * a, box) - mean_a * mean_a
    var_b = cv2.blur(b * b, box) - mean_b * mean_b
    cov = cv2.blur(a * b, box) - mean_a * mean_b
    textured = ring & (var_a > MIN_VARIANCE) & (var_b > MIN_VARIANCE)
    n = int(textured.sum())
    if n < MIN_RING_PX * config_px(1.0, shape) ** 2:
        return LineUp(float("nan"), n)
    zncc = cov[textured] / np.sqrt(var_a[textured] * var_b[textured])
    return LineUp(float(np.median(zncc)), n)


def misaligned(lineups: dict[int, LineUp], cfg: FusionConfig) -> dict[int, str]:
    """Per reference index whose render does not line up while another's does, why.

    >>> cfg = FusionConfig()
    >>> why = misaligned({1: LineUp(0.6, 9000), 2: LineUp(0.02, 8000), 3: LineUp(0.3, 7000)}, cfg)
    >>> list(why), why[2][-36:]
    ([2], 'correlation 0.02; reference 1: 0.60)')
    >>> misaligned({1: LineUp(0.3, 9000), 2: LineUp(0.02, 8000)}, cfg)
    {}
    """
    judged = {i: lu.correlation for i, lu in lineups.items() if np.isfinite(lu.correlation)}
    if len(judged) < 2:
        return {}
    best = max(judged, key=judged.__getitem__)
    if judged[best] < cfg.aligned_correlation:
        return {}
    return {
        i: f"its render does not line up with the photo around the hole (ring correlation {z:.2f}; "
        f"reference {best}: {judged[best]:.2f})"
        for i, z in sorted(judged.items())
        if z < cfg.misaligned_correlation
    }
