"""Objects for the object-removal protocols that a plane cannot stand for: a solid box placed in
3D and ray-cast into every view (each camera sees other faces in other proportions, as with a
parked car), and a person-shaped cutout (head, torso, arms, legs) that walks between views.

Coordinates: a box lives in the *target camera's* frame (OpenCV axes, the units of the poses);
a view is given by its K and the 4x4 ``view_from_target`` (``X_view = M X_target``, the inverse of
a reference's ``T_source_to_target``). A figure lives in plane coordinates, as the blobs of
:mod:`.cutouts` do, and is drawn with :func:`.cutouts.draw`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .cutouts import SUPERSAMPLE, bilinear

#: Direction *towards* the light in the target camera's frame (up, to the left, towards the
#: camera: y points down), so that the faces of a one-colour box differ a little, as in daylight.
LIGHT = np.array([-0.35, -0.85, -0.4]) / np.linalg.norm([-0.35, -0.85, -0.4])
#: Shade of a face: ``AMBIENT + (1 - AMBIENT) * max(0, n . LIGHT)``.
AMBIENT = 0.62
_MIN_Z = 1e-6


@dataclass(frozen=True)
class Box:
    """A solid box: centre (3,) and axes (3x3, columns = the box's own x, y, z) in the target
    camera's frame, half extents (3,) along its axes, and one texture per face (HxWx3 float32,
    0-255), faces ordered -x, +x, -y, +y, -z, +z; texel (0, 0) at the face's corner of lowest
    coordinates along its two other axes (in axis order)."""

    centre: np.ndarray
    axes: np.ndarray
    half: np.ndarray
    textures: tuple[np.ndarray, ...]

    def corners(self) -> np.ndarray:
        """(8, 3) corners in the target camera's frame."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        return self.centre + (signs * self.half) @ self.axes.T

    def surface_points(self, n: int = 5) -> np.ndarray:
        """(6 n^2, 3) points on a regular n x n grid over each face (target camera's frame)."""
        g = (np.arange(n) + 0.5) / n * 2.0 - 1.0
        u, v = np.meshgrid(g, g)
        pts = []
        for axis in range(3):
            j, k = [a for a in range(3) if a != axis]
            for sign in (-1.0, 1.0):
                local = np.zeros((n * n, 3))
                local[:, axis] = sign * self.half[axis]
                local[:, j] = u.ravel() * self.half[j]
                local[:, k] = v.ravel() * self.half[k]
                pts.append(local)
        return self.centre + np.concatenate(pts) @ self.axes.T

    def moved(self, centre: np.ndarray) -> Box:
        """This box at another centre."""
        return replace(self, centre=np.asarray(centre, float))


def face_shades(axes: np.ndarray) -> np.ndarray:
    """(6,) Lambertian shade of each face (order of :class:`Box`) under :data:`LIGHT`."""
    normals = np.concatenate([[-axes[:, a], axes[:, a]] for a in range(3)])
    return AMBIENT + (1.0 - AMBIENT) * np.clip(normals @ LIGHT, 0.0, None)


def project_points(
    K: np.ndarray, view_from_target: np.ndarray, X: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) target-frame points -> (view pixels (N, 2), view z (N,))."""
    M = np.asarray(view_from_target, float)
    Xv = X @ M[:3, :3].T + M[:3, 3]
    z = Xv[:, 2]
    p = Xv @ np.asarray(K, float).T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = p[:, :2] / np.where(np.abs(z) > _MIN_Z, z, _MIN_Z)[:, None]
    return uv, z


def render_box(
    box: Box,
    K: np.ndarray,
    view_from_target: np.ndarray,
    shape: tuple[int, int],
    depth: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The box ray-cast into a view of ``shape`` (h, w): (colour HxWx3 float32, alpha HxW float32
    in [0, 1], z HxW float32 view z-depth of the nearest hit, inf where none).

    Every pixel is sampled at :data:`SUPERSAMPLE` x :data:`SUPERSAMPLE` sub-pixel rays; each ray is
    cut with the box exactly (slab test in the box's frame: the entering face is the visible one,
    so faces occlude each other correctly), the hit face's texture read bilinearly and shaded by
    :func:`face_shades`. ``alpha`` is the share of rays that hit, ``colour`` their mean. Where
    ``depth`` (the view's scene z-depth, 0 = unknown) is nearer than the hit, the box is hidden.
    A box not wholly in front of the camera is not drawn."""
    h, w = shape
    colour = np.zeros((h, w, 3), np.float32)
    alpha = np.zeros((h, w), np.float32)
    zbuf = np.full((h, w), np.inf, np.float32)
    uv, z = project_points(K, view_from_target, box.corners())
    if np.any(z <= _MIN_Z):
        return colour, alpha, zbuf
    x0, y0 = np.maximum(np.floor(uv.min(axis=0)).astype(int) - 1, 0)
    x1, y1 = np.minimum(np.ceil(uv.max(axis=0)).astype(int) + 1, [w - 1, h - 1])
    if x0 > x1 or y0 > y1:
        return colour, alpha, zbuf
    s = SUPERSAMPLE
    offsets = (np.arange(s) + 0.5) / s - 0.5
    xs = (np.arange(x0, x1 + 1)[:, None] + offsets).ravel()
    ys = (np.arange(y0, y1 + 1)[:, None] + offsets).ravel()
    gx, gy = np.meshgrid(xs, ys)
    rays_view = np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)], axis=1) @ np.linalg.inv(K).T
    # The ray x = C + t d in the box's frame, with d_z = 1 in the view: t is the view's z-depth.
    target_from_view = np.linalg.inv(np.asarray(view_from_target, float))
    origin = box.axes.T @ (target_from_view[:3, 3] - box.centre)
    d = rays_view @ (box.axes.T @ target_from_view[:3, :3]).T
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-box.half - origin) / d
        t2 = (box.half - origin) / d
    t_in = np.nanmax(np.minimum(t1, t2), axis=1)
    t_out = np.nanmin(np.maximum(t1, t2), axis=1)
    hit = (t_in <= t_out) & (t_in > 0)
    face_axis = np.nanargmax(np.minimum(t1, t2), axis=1)
    if depth is not None:
        px = np.clip(np.rint(gx.ravel()).astype(int), 0, w - 1)
        py = np.clip(np.rint(gy.ravel()).astype(int), 0, h - 1)
        scene = depth[py, px]
        hit &= (scene <= 0) | (t_in < scene)
    rows, cols = y1 - y0 + 1, x1 - x0 + 1
    sample_colour = np.zeros((len(hit), 3), np.float32)
    shades = face_shades(box.axes)
    idx = np.flatnonzero(hit)
    p = origin + t_in[idx, None] * d[idx]
    axis = face_axis[idx]
    # The entering face is on the side the ray comes from: -half where it travels towards +.
    positive = d[idx, axis] < 0
    face = 2 * axis + positive
    for f in range(6):
        sel = face == f
        if not sel.any():
            continue
        a = f // 2
        j, k = [b for b in range(3) if b != a]
        tex = box.textures[f]
        th, tw = tex.shape[:2]
        u = (p[sel, j] + box.half[j]) / (2 * box.half[j]) * (tw - 1)
        v = (p[sel, k] + box.half[k]) / (2 * box.half[k]) * (th - 1)
        sample_colour[idx[sel]] = bilinear(tex, u, v) * shades[f]
    hits = hit.reshape(rows, s, cols, s)
    n_hit = hits.sum(axis=(1, 3))
    summed = (sample_colour.reshape(rows, s, cols, s, 3) * hits[..., None]).sum(axis=(1, 3))
    alpha[y0 : y1 + 1, x0 : x1 + 1] = n_hit / (s * s)
    with np.errstate(invalid="ignore", divide="ignore"):
        colour[y0 : y1 + 1, x0 : x1 + 1] = np.where(n_hit[..., None] > 0, summed / n_hit[..., None], 0.0)
    t_min = np.where(hit, t_in, np.inf).reshape(rows, s, cols, s).min(axis=(1, 3))
    zbuf[y0 : y1 + 1, x0 : x1 + 1] = t_min
    return colour, alpha, zbuf


def composite(image: np.ndarray, colour: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """``image`` (HxWx3 uint8) with ``colour`` laid over it by ``alpha``; alpha-0 pixels keep
    their bytes."""
    out = image.copy()
    on = alpha > 0
    a = alpha[on][:, None]
    mixed = a * colour[on] + (1.0 - a) * image[on].astype(np.float32)
    out[on] = np.clip(np.rint(mixed), 0, 255).astype(np.uint8)
    return out


# ---------------------------------------------------------------------------------------------
# A walking figure


def _capsule_distance(xy: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((xy - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(xy - (a + t[:, None] * ab), axis=1)


@dataclass(frozen=True)
class Figure:
    """A person's silhouette standing upright in plane coordinates: ``top`` (x, y) is the crown
    of the head, ``height`` the plane units to the soles; ``stride`` in [-1, 1] is the walking
    phase (how far apart the legs are; its sign, which way the arms swing); ``build``
    scales the widths. Head, torso, arms and legs are discs and capsules of fixed proportions,
    so :meth:`inside` is exact; :func:`.cutouts.draw` draws it like a blob."""

    top: tuple[float, float]
    height: float
    stride: float = 0.0
    build: float = 1.0

    def _parts(self) -> list[tuple[np.ndarray, np.ndarray, float]]:
        H, b, s = self.height, self.build, self.stride
        x, y = self.top

        def at(dx: float, dy: float) -> np.ndarray:
            return np.array([x + dx * H, y + dy * H])

        return [
            (at(0, 0.065), at(0, 0.065), 0.062 * H * b),  # head
            (at(0, 0.13), at(0, 0.16), 0.035 * H * b),  # neck
            (at(0, 0.24), at(0, 0.46), 0.105 * H * b),  # torso
            (at(-0.1 * b, 0.2), at(-0.13 * b - 0.08 * s, 0.5), 0.032 * H * b),  # arms
            (at(0.1 * b, 0.2), at(0.13 * b - 0.08 * s, 0.5), 0.032 * H * b),
            (at(-0.05 * b, 0.5), at(-0.05 * b - 0.14 * abs(s), 0.965), 0.045 * H * b),  # legs
            (at(0.05 * b, 0.5), at(0.05 * b + 0.14 * abs(s), 0.965), 0.045 * H * b),
        ]

    def inside(self, xy: np.ndarray) -> np.ndarray:
        """(N,) bool: the (N, 2) plane points lie inside the silhouette."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        out = np.zeros(len(xy), bool)
        for a, b, r in self._parts():
            out |= _capsule_distance(xy, a, b) < r
        return out

    @property
    def bbox(self) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1) holding the silhouette."""
        pts = [(a, b, r) for a, b, r in self._parts()]
        x0 = min(min(a[0], b[0]) - r for a, b, r in pts)
        x1 = max(max(a[0], b[0]) + r for a, b, r in pts)
        y0 = min(min(a[1], b[1]) - r for a, b, r in pts)
        y1 = max(max(a[1], b[1]) + r for a, b, r in pts)
        return (x0, y0, x1, y1)

    @property
    def width(self) -> float:
        """Width of the silhouette's box (plane units)."""
        x0, _, x1, _ = self.bbox
        return x1 - x0

    def moved(self, top: tuple[float, float] | None = None, stride: float | None = None) -> Figure:
        """The figure at another place and/or walking phase."""
        return replace(
            self,
            top=self.top if top is None else (float(top[0]), float(top[1])),
            stride=self.stride if stride is None else float(stride),
        )
