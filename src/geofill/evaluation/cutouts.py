"""Photo cutouts for the object-removal protocols: a crop of a photo of another scene with a
non-rectangular (blob) silhouette, lying on a plane and drawn into any view of that plane.

A cutout lives in *plane coordinates*: for the ``static`` protocol the target's pixel coordinates
(the plane is fronto-parallel to the target camera), for the ``strangers`` protocol a reference's
pixel coordinates. A view sees the plane through a homography ``G`` (plane coordinates -> view
pixels); :func:`draw` casts every view pixel back through ``G^-1`` and takes

* the silhouette's exact coverage of the pixel (the analytic :meth:`Blob.inside` at 4 x 4
  sub-pixel positions), so the edge is anti-aliased and the same in every view up to the
  projection, and
* the colour by bilinear lookup of the crop at the pixel centre's plane position.

The photos are scikit-image's bundled colour photos (:data:`CUTOUT_PHOTOS`: no download, the same
on every machine), none of them a view of an evaluated scene; every choice comes from the
``np.random.Generator`` it is given, so a seed fixes the cutout.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cache

import cv2
import numpy as np
from skimage import data as skdata

#: scikit-image photos the cutouts are cropped from (bundled with the package).
CUTOUT_PHOTOS = ("astronaut", "coffee", "chelsea", "rocket", "motorcycle")
#: Sub-pixel samples per axis for a silhouette's coverage of a pixel.
SUPERSAMPLE = 4
#: Harmonics of a blob's radius wobble, and the largest amplitude of each.
_HARMONICS = (2, 3, 5)
_MAX_AMPLITUDE = 0.12


@dataclass(frozen=True)
class Blob:
    """A silhouette in plane coordinates: an ellipse with semi-axes ``radius * sqrt(aspect)`` (along
    ``angle``) and ``radius / sqrt(aspect)``, whose radius wobbles by ``1 + sum(amp_k cos(k theta +
    phase_k))`` for k = 2, 3, 5 (a soft, potato-like shape rather than a rectangle).

    >>> b = Blob((10.0, 20.0), 5.0, 1.0, 0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    >>> b.inside(np.array([[10.0, 20.0], [14.9, 20.0], [15.1, 20.0]])).tolist()
    [True, True, False]
    """

    centre: tuple[float, float]
    radius: float
    aspect: float
    angle: float
    amps: tuple[float, float, float]
    phases: tuple[float, float, float]

    def inside(self, xy: np.ndarray) -> np.ndarray:
        """(N,) bool: the (N, 2) plane points (x, y) lie inside the silhouette."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        dx, dy = xy[:, 0] - self.centre[0], xy[:, 1] - self.centre[1]
        c, s = np.cos(self.angle), np.sin(self.angle)
        r = max(self.radius, 1e-12)
        a = (dx * c + dy * s) / (r * np.sqrt(self.aspect))
        b = (-dx * s + dy * c) / (r / np.sqrt(self.aspect))
        theta = np.arctan2(b, a)
        wobble = 1.0 + sum(
            amp * np.cos(k * theta + ph)
            for amp, ph, k in zip(self.amps, self.phases, _HARMONICS, strict=True)
        )
        return np.hypot(a, b) < wobble

    @property
    def reach(self) -> float:
        """Largest distance of a silhouette point from the centre."""
        return self.radius * max(np.sqrt(self.aspect), 1.0 / np.sqrt(self.aspect)) * (1.0 + sum(self.amps))

    @property
    def bbox(self) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1) holding the silhouette (plane coordinates)."""
        r = self.reach
        return (self.centre[0] - r, self.centre[1] - r, self.centre[0] + r, self.centre[1] + r)

    @property
    def mean_area(self) -> float:
        """The silhouette's area: pi r^2 (1 + sum(amp^2) / 2)."""
        return float(np.pi * self.radius**2 * (1.0 + 0.5 * sum(a * a for a in self.amps)))

    def moved(self, centre: tuple[float, float] | None = None, radius: float | None = None) -> Blob:
        """This shape at another centre and/or radius."""
        return replace(
            self,
            centre=self.centre if centre is None else (float(centre[0]), float(centre[1])),
            radius=self.radius if radius is None else float(radius),
        )


def random_blob(
    rng: np.random.Generator, centre: tuple[float, float] = (0.0, 0.0), radius: float = 1.0
) -> Blob:
    """A blob of random aspect (0.55-1.8), orientation and wobble at ``centre``."""
    return Blob(
        (float(centre[0]), float(centre[1])),
        float(radius),
        float(np.exp(rng.uniform(np.log(0.55), np.log(1.8)))),
        float(rng.uniform(0.0, np.pi)),
        tuple(float(a) for a in rng.uniform(0.0, _MAX_AMPLITUDE, 3)),
        tuple(float(p) for p in rng.uniform(0.0, 2.0 * np.pi, 3)),
    )


@cache
def _photo(name: str) -> np.ndarray:
    image = skdata.stereo_motorcycle()[0] if name == "motorcycle" else getattr(skdata, name)()
    out = np.ascontiguousarray(np.asarray(image)[..., :3]).astype(np.float32)
    out.setflags(write=False)
    return out


def photo_crop(rng: np.random.Generator, width: int, height: int, grey: bool = False) -> np.ndarray:
    """(height, width, 3) float32 crop (0-255) of a random :data:`CUTOUT_PHOTOS` photo: a random
    window of that aspect covering 40-90 % of the largest that fits, maybe mirrored, resized;
    ``grey`` gives its luminance in all three channels (for grey scenes)."""
    photo = _photo(CUTOUT_PHOTOS[int(rng.integers(len(CUTOUT_PHOTOS)))])
    if rng.random() < 0.5:
        photo = photo[:, ::-1]
    ph, pw = photo.shape[:2]
    width, height = max(int(width), 1), max(int(height), 1)
    fit = min(ph, pw * height / width)
    ch = max(2.0, fit * rng.uniform(0.4, 0.9))
    cw = max(2.0, ch * width / height)
    y0, x0 = int(rng.uniform(0, ph - ch + 1)), int(rng.uniform(0, pw - cw + 1))
    crop = np.ascontiguousarray(photo[y0 : y0 + int(ch), x0 : x0 + int(cw)])
    interp = cv2.INTER_AREA if crop.shape[1] > width else cv2.INTER_CUBIC
    out = np.clip(cv2.resize(crop, (width, height), interpolation=interp), 0.0, 255.0)
    if grey:
        lum = out @ np.array([0.299, 0.587, 0.114], np.float32)
        out = np.repeat(lum[..., None], 3, axis=2)
    return out.astype(np.float32)


@dataclass(frozen=True)
class Cutout:
    """A photo crop with a blob silhouette on a plane; texel (i, j) of ``texture`` sits at plane
    point ``origin + (j, i)``."""

    blob: Blob
    texture: np.ndarray  # (h, w, 3) float32, 0-255
    origin: tuple[float, float]


def make_cutout(rng: np.random.Generator, blob: Blob, grey: bool = False) -> Cutout:
    """A random photo crop (:func:`photo_crop`) covering ``blob``'s bounding box, one texel per
    plane unit."""
    x0, y0, x1, y1 = blob.bbox
    origin = (float(np.floor(x0)) - 1.0, float(np.floor(y0)) - 1.0)
    w, h = int(np.ceil(x1 - origin[0])) + 2, int(np.ceil(y1 - origin[1])) + 2
    return Cutout(blob, photo_crop(rng, w, h, grey), origin)


#: cv2.remap refuses maps with a side of SHRT_MAX or more; lookups go through rows of this width.
_REMAP_ROW = 4096


def bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(N, C) float32 bilinear lookups of an HxWxC image at pixel positions (pixel (0, 0) centred
    at (0, 0)); positions outside read the nearest edge pixel."""
    n = len(x)
    pad = -n % _REMAP_ROW
    mx = np.pad(np.asarray(x, np.float32), (0, pad)).reshape(-1, _REMAP_ROW)
    my = np.pad(np.asarray(y, np.float32), (0, pad)).reshape(-1, _REMAP_ROW)
    src = np.asarray(image, np.float32)
    out = cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, src.shape[2] if src.ndim == 3 else 1)[:n]


def _apply(G: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) points through the homography ``G``; also the homogeneous w (> 0: in front)."""
    p = xy @ G[:, :2].T + G[:, 2]
    w = p[:, 2]
    safe = np.where(np.abs(w) < 1e-12, 1e-12, w)
    return p[:, :2] / safe[:, None], w


def view_bbox(blob: Blob, G: np.ndarray, shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """Integer pixel window (x0, y0, x1, y1), clipped to an image of ``shape`` (h, w), holding
    ``blob`` seen through ``G``; None when it is off the image or not entirely in front."""
    x0, y0, x1, y1 = blob.bbox
    corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    xy, w = _apply(G, corners)
    if np.any(w <= 0):
        return None
    h, wd = shape
    lo = np.floor(xy.min(axis=0)).astype(int) - 1
    hi = np.ceil(xy.max(axis=0)).astype(int) + 1
    bx0, by0 = max(lo[0], 0), max(lo[1], 0)
    bx1, by1 = min(hi[0], wd - 1), min(hi[1], h - 1)
    if bx0 > bx1 or by0 > by1:
        return None
    return int(bx0), int(by0), int(bx1), int(by1)


def coverage(blob: Blob, G: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(h, w) float32 in [0, 1]: the fraction of each pixel of a view of ``shape`` covered by
    ``blob`` seen through ``G`` (plane coordinates -> view pixels), from 4 x 4 sub-pixel samples
    (pixel (0, 0) centred at (0, 0))."""
    out = np.zeros(shape, np.float32)
    box = view_bbox(blob, G, shape)
    if box is None:
        return out
    x0, y0, x1, y1 = box
    s = SUPERSAMPLE
    offsets = (np.arange(s) + 0.5) / s - 0.5
    xs = (np.arange(x0, x1 + 1)[:, None] + offsets[None, :]).ravel()
    ys = (np.arange(y0, y1 + 1)[:, None] + offsets[None, :]).ravel()
    gx, gy = np.meshgrid(xs, ys)
    plane, _ = _apply(np.linalg.inv(G), np.stack([gx.ravel(), gy.ravel()], axis=1))
    hits = blob.inside(plane).reshape(y1 - y0 + 1, s, x1 - x0 + 1, s)
    out[y0 : y1 + 1, x0 : x1 + 1] = hits.mean(axis=(1, 3))
    return out


def draw(
    image: np.ndarray, cutout: Cutout, G: np.ndarray | None = None, front: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``image`` (HxWx3 uint8) with ``cutout`` drawn through ``G`` (plane -> image pixels; None:
    the identity) over it, and the alpha used (HxW float32: :func:`coverage`, zero where the bool
    ``front`` says the cutout is behind the scene). Pixels with alpha 0 keep their bytes."""
    h, w = image.shape[:2]
    G = np.eye(3) if G is None else np.asarray(G, dtype=np.float64)
    alpha = coverage(cutout.blob, G, (h, w))
    if front is not None:
        alpha[~front] = 0.0
    out = image.copy()
    ys, xs = np.nonzero(alpha > 0)
    if len(xs) == 0:
        return out, alpha
    plane, _ = _apply(np.linalg.inv(G), np.stack([xs, ys], axis=1).astype(np.float64))
    colour = bilinear(cutout.texture, plane[:, 0] - cutout.origin[0], plane[:, 1] - cutout.origin[1])
    a = alpha[ys, xs][:, None]
    mixed = a * colour + (1.0 - a) * image[ys, xs].astype(np.float32)
    out[ys, xs] = np.clip(np.rint(mixed), 0, 255).astype(np.uint8)
    return out, alpha
