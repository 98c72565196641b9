"""Each planar surface painted in its own rectified (fronto-parallel) coordinates.

Seen in perspective, a tiled floor's tiles shrink and turn towards the vanishing point: a patch
copied from nearer the camera into the hole carries tiles too large and turned the wrong way. So
each plane around the hole (:mod:`geofill.composite.planes`, from the pipeline's depth) is viewed
head on first: the image is warped by the homography of a camera turned to face the plane
(``K' R K^-1``, ``R`` taking the plane's normal to the optical axis, ``K'`` scaled so that no hole
pixel is shrunk), where every tile has one size and one direction; the plane's part of the hole is painted
there from the plane's own known pixels only (:func:`geofill.composite.exemplar.complete`, the
other surfaces a separate surface it never copies from), and warped back. What lies on no plane is
painted in the image as before, from its own appearance surface.
"""

from __future__ import annotations

import cv2
import numpy as np

from .exemplar import ExemplarSettings, complete
from .lines import continue_lines
from .planes import Plane, SceneDepth, plane_surfaces
from .surfaces import segment

#: A plane's part of the hole is painted unrectified when its rectified bounding box is longer than
#: this many times its bounding box in the image (a plane seen at a grazing angle, near its
#: horizon, is stretched without bound there).
_MAX_STRETCH = 4.0
#: Most a source pixel may be enlarged (linear) in the rectified coordinates and still be copied.
_MAX_ENLARGE = 1.5
#: Longest rectified canvas, as a multiple of the image's long side.
_MAX_CANVAS = 1.5
#: Context kept around the hole's rectified bounding box, as a fraction of its longer side (at least
#: 32 px), as the exemplar painter keeps around the hole (see inpaint._context).
_CONTEXT = 1.0


def paint(
    image: np.ndarray, hole: np.ndarray, settings: ExemplarSettings | None, scene: SceneDepth | None
) -> np.ndarray:
    """``image`` (HxWx3 uint8) with ``hole`` (HxW bool) painted, each plane that ``scene``'s depth
    shows around it in its own rectified coordinates, the rest by
    :func:`geofill.composite.exemplar.complete` from its appearance surface, after the straight
    edges that cross the hole are drawn across it (:mod:`geofill.composite.lines`). Without
    ``scene``, or without a plane on the ring, the rest is ``complete`` alone."""
    s = settings or ExemplarSettings()
    side = 2 * s.patch_radius + 1
    if not hole.any():
        return image.copy()
    # Straight edges across the hole first: the texture is painted around them. The surfaces are
    # found from the known pixels alone, the edges drawn then made a surface of their own: the
    # structure diffused around them does not take their colour (a dark edge cast a dark shadow).
    image = image.copy()
    drawn = continue_lines(image, hole, side)
    # The surfaces take the uint8 image: at 58 MP a float copy of it alone is 0.7 GB.
    surfaces = None if scene is None else plane_surfaces(image, hole, scene, side)
    if surfaces is None:
        labels = segment(image, hole, side) if drawn.any() else None
        if labels is not None:
            labels[drawn] = labels.max() + 1
        return complete(image, hole & ~drawn, s, surfaces=labels)
    hole = hole & ~drawn
    out = image.copy()
    left = hole.copy()
    for i, plane in enumerate(surfaces.planes):
        part = hole & (surfaces.labels == i)
        if not part.any():
            continue
        filled = fill_rectified(image, hole, surfaces.labels == i, plane, scene.K, s)
        if filled is not None:
            np.copyto(out, filled, where=part[..., None])
            left &= ~part
    if left.any():
        labels = surfaces.labels.copy()
        labels[drawn] = labels.max() + 1
        out = complete(out, left, s, surfaces=labels)
    return out


def rectifying_homography(plane: Plane, K: np.ndarray) -> np.ndarray:
    """``R K^-1`` (3x3): image pixels to the normalised image of a camera at the same centre turned
    to look along the plane's normal (head on: there the plane is seen up to a similarity)."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(plane.normal, z)
    angle = np.arctan2(np.linalg.norm(axis), float(plane.normal @ z))
    if np.linalg.norm(axis) < 1e-12:
        R = np.eye(3)
    else:
        R = cv2.Rodrigues(axis / np.linalg.norm(axis) * angle)[0]
    return R @ np.linalg.inv(K)


def fill_rectified(
    image: np.ndarray,
    hole: np.ndarray,
    on: np.ndarray,
    plane: Plane,
    K: np.ndarray,
    settings: ExemplarSettings,
) -> np.ndarray | None:
    """``image`` (HxWx3 uint8) with the plane's part of the hole (``hole & on``) painted in the
    plane's rectified coordinates from its known pixels (``on & ~hole``) only, warped back (valid
    at those hole pixels only); None where the part is too stretched to rectify (_MAX_STRETCH)."""
    part = hole & on
    ys, xs = np.nonzero(part)
    H0 = rectifying_homography(plane, K)
    p = H0 @ np.stack([xs, ys, np.ones_like(xs)]).astype(np.float64)
    if (p[2] <= 0).any():
        return None
    uv = p[:2] / p[2]
    # No hole pixel is shrunk: where the plane is nearest (its texture largest) one rectified pixel
    # is one image pixel, and farther parts are enlarged (a homography's area scale at pixel x is
    # det(H) / w(x)^3). Shrinking the near part would leave only blurred texture to copy.
    scale = float(np.sqrt((p[2] ** 3).max() / abs(np.linalg.det(H0))))
    # ... unless the canvas would then be longer than _MAX_CANVAS times the image: memory and time.
    span = float((uv.max(1) - uv.min(1)).max())
    scale = min(scale, _MAX_CANVAS * max(image.shape[:2]) / ((1.0 + 2.0 * _CONTEXT) * max(span, 1e-12)))
    lo, hi = uv.min(1) * scale, uv.max(1) * scale
    extent = float((hi - lo).max())
    if extent > _MAX_STRETCH * max(xs.max() - xs.min() + 1, ys.max() - ys.min() + 1):
        return None
    pad = max(32.0, _CONTEXT * extent)
    # No wider than the plane's pixels reach in the image: beyond them the canvas would be empty.
    oy, ox = np.nonzero(on)
    q = H0 @ np.stack([ox, oy, np.ones_like(ox)]).astype(np.float64)
    q = q[:2, q[2] > 0] / q[2, q[2] > 0] * scale
    origin = np.maximum(lo - pad, q.min(1) - 1.0)
    end = np.minimum(hi + pad, q.max(1) + 1.0)
    size = (int(np.ceil(end[0] - origin[0])) + 1, int(np.ceil(end[1] - origin[1])) + 1)
    Hs = np.array([[scale, 0, -origin[0]], [0, scale, -origin[1]], [0, 0, 1]]) @ H0

    def warp(a: np.ndarray, flags: int) -> np.ndarray:
        return cv2.warpPerspective(a, Hs, size, flags=flags, borderMode=cv2.BORDER_CONSTANT)

    canvas = warp(image, cv2.INTER_LINEAR)
    # The rectified hole: every canvas pixel the part's pixels reach (a pixel either side, so the
    # bilinear warp back reads painted pixels only).
    target = cv2.dilate(
        (warp(part.astype(np.uint8) * 255, cv2.INTER_LINEAR) > 0).astype(np.uint8), np.ones((3, 3))
    )
    target = target > 0
    # Sources: canvas pixels wholly from the plane's known pixels (a linear warp of the mask at 255
    # there); everything else (another surface, beyond the image) is on no surface, never copied.
    # Parts of the plane enlarged more than _MAX_ENLARGE are not copied from: they are blurred, and
    # the search favours blurred sources (they match the diffused start of the hole best).
    ry, rx = np.nonzero(on & ~hole)
    w = H0[2, 0] * rx + H0[2, 1] * ry + H0[2, 2]
    sharp = np.zeros_like(on)
    sharp[ry, rx] = scale**2 * abs(np.linalg.det(H0)) / np.maximum(w, 1e-12) ** 3 <= _MAX_ENLARGE**2
    source = warp(sharp.astype(np.uint8) * 255, cv2.INTER_LINEAR) == 255
    if not source.any():
        return None
    labels = np.where(source | target, 0, -1).astype(np.int32)
    painted = complete(_nearest_source(canvas, source), target, settings, surfaces=labels)
    return cv2.warpPerspective(
        painted,
        Hs,
        image.shape[1::-1],
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_REPLICATE,
    )


def _nearest_source(canvas: np.ndarray, source: np.ndarray) -> np.ndarray:
    """``canvas`` with every pixel outside ``source`` the colour of its nearest source pixel: the
    patches at the plane's edge, and the coarse levels' averages, then see the plane, not black
    beyond the image or another surface (which would be copied in with them)."""
    _, nearest = cv2.distanceTransformWithLabels(
        (~source).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    ys, xs = np.nonzero(source)
    lookup = np.zeros((int(nearest.max()) + 1, 3), canvas.dtype)
    lookup[nearest[ys, xs]] = canvas[ys, xs]
    out = canvas.copy()
    out[~source] = lookup[nearest[~source]]
    return out
