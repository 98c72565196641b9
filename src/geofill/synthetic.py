"""Synthetic two-view scenes with exact ground truth: the test oracle of every pipeline stage.

The scene
    A closed room (an axis-aligned cuboid seen from inside: floor, ceiling, back, front and side
    walls) holding several boxes standing on the floor at different depths and yaw angles, thin
    free-standing panels and sometimes a floor-to-ceiling pillar, so views have real depth
    discontinuities and occlusions. The cameras are inside the room, so every ray hits a surface:
    no background holes. World axes follow OpenCV (x right, y down, z forward); the target camera
    sits at the origin, 1.5 units above the floor, looking at :attr:`Scene.center`.

Textures
    Each face has its own texture: a random crop of one of scikit-image's bundled photos (random
    flip/transpose, grey photos tinted by a random colour ramp) blended with multi-octave value
    noise, and a constant Lambertian shade per face, so no two faces look alike and SIFT finds
    plenty of distinctive blobs. Texture density is fixed in texels per scene unit
    (:data:`TEXELS_PER_UNIT`); each texture carries a Gaussian pyramid and lookups are trilinear
    (bilinear in the face's (u, v), linear between pyramid levels chosen from each sample's
    footprint), so distant and grazing surfaces do not alias. Shading is view-independent, so a
    surface point has the same colour in every view.

Rendering
    Analytic ray casting, vectorised over all rays: the room's exit distance (slabs from inside)
    and, for every box, the slab test in its local frame; the nearest positive hit wins. Ray
    directions are ``R K^-1 [x, y, 1]``, whose camera z is exactly 1, so the ray parameter *is*
    the z-depth. Colour is cast at ``supersample`` x ``supersample`` sub-pixel positions and
    area-averaged (``cv2.INTER_AREA``); depth is cast once at pixel centres.

Exactness guarantees
    ``depth`` is the float64 z-depth of the first surface hit through each pixel centre (pixel
    (0, 0) centred at (0, 0)), rounded to float32; ``T_source_to_target`` maps source camera
    coordinates to target camera coordinates (``X_t = R X_s + t``) exactly as the cameras were
    placed. Unprojecting a target pixel centre with its depth and mapping it with the inverse pose
    lands on the very surface point the source sees there (up to float64 rounding), which
    ``tests/test_synthetic.py`` checks by casting the source ray through the projected point.
    Colours are not exact in that sense (texture filtering depends on the view), but agree to a
    few grey levels away from depth edges. Optional photometric knobs (``source_gain``,
    ``noise_sigma``) change only the images, never the ground truth.

Everything is drawn from ``np.random.default_rng(seed)``: the same seed gives identical arrays.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np
from skimage import data as skdata

from .camera import Intrinsics, default_focal_px

#: scikit-image photos bundled with the package (no download), used as texture material.
PHOTOS = (
    "astronaut",
    "coffee",
    "chelsea",
    "rocket",
    "hubble_deep_field",
    "immunohistochemistry",
    "brick",
    "grass",
    "gravel",
    "camera",
    "moon",
    "page",
    "text",
    "coins",
    "clock",
)
#: Texture resolution on every surface (texels per scene unit).
TEXELS_PER_UNIT = 80.0
#: Camera height above the floor (scene units); the floor is the plane y = CAMERA_HEIGHT.
CAMERA_HEIGHT = 1.5
#: The ceiling is the plane y = CEILING_Y (world y points down).
CEILING_Y = -2.4
#: Rays per vectorised batch (bounds the temporaries to a few MB each).
_CHUNK = 1 << 18
#: Light direction (towards the light) for the per-face Lambertian shade: from above-left-front.
_LIGHT = np.array([-0.35, -0.85, -0.4]) / np.linalg.norm([-0.35, -0.85, -0.4])
#: cv2.remap refuses maps with a side of SHRT_MAX or more; lookups go through rows of this width.
_REMAP_ROW = 4096
MOTIONS = ("orbit", "forward", "sideways", "rotate")


@dataclass(frozen=True)
class _Cuboid:
    """An oriented box: ``world = center + rotation @ local``, ``|local| <= half`` per axis."""

    center: np.ndarray
    rotation: np.ndarray
    half: np.ndarray


@dataclass(frozen=True)
class _Face:
    """One planar textured face of a cuboid, perpendicular to its local ``axis``."""

    cuboid: _Cuboid
    axis: int
    pyramid: tuple[np.ndarray, ...]


def _tangent_axes(axis: int) -> tuple[int, int]:
    """Texture (u, v) axes of a face; v is y (image rows down) on vertical faces, z on horizontal ones."""
    return {0: (2, 1), 1: (0, 2), 2: (0, 1)}[axis]


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """4x4 camera-to-world pose of a camera at ``eye`` looking at ``target``, no roll (world y down)."""
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    pose[:3, 3] = eye
    return pose


def _yaw(angle_rad: float) -> np.ndarray:
    """Rotation about +y (OpenCV down axis): positive turns the optical axis towards +x."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


class Scene:
    """A textured room with boxes; render it from any pinhole camera."""

    def __init__(self, room: _Cuboid, boxes: list[_Cuboid], faces: list[_Face], center: np.ndarray):
        self.room = room
        self.boxes = boxes
        #: Faces 0-5 are the room's, then six per box in ``boxes`` order: id = 6 * cuboid + 2 * axis
        #: + side, side 1 being the face on the local +axis.
        self.faces = faces
        #: The point both default cameras look at (world coordinates, scene units).
        self.center = center

    def target_pose(self) -> np.ndarray:
        """Camera-to-world pose of the default target camera: at the origin, looking at :attr:`center`."""
        return look_at(np.zeros(3), self.center)

    def contains_camera(self, centre: np.ndarray) -> bool:
        """True when a camera at ``centre`` (world) is inside the room and outside every box, which
        the ray caster needs (every ray then leaves through a wall)."""

        def inside(box: _Cuboid) -> bool:
            return bool(np.all(np.abs(box.rotation.T @ (centre - box.center)) < box.half))

        return inside(self.room) and not any(inside(box) for box in self.boxes)

    def render(
        self, K: np.ndarray, cam_to_world: np.ndarray, width: int, height: int, supersample: int = 2
    ) -> tuple[np.ndarray, np.ndarray]:
        """(HxWx3 uint8 RGB, HxW float32 z-depth) seen by a pinhole camera.

        ``K`` uses the pixel-centre convention; ``cam_to_world`` is 4x4 (OpenCV camera axes).
        Colour averages ``supersample``^2 samples per pixel; depth is exact at pixel centres.
        """
        if supersample < 1:
            raise ValueError(f"supersample must be >= 1, got {supersample}")
        s = int(supersample)
        K_ss = Intrinsics.from_matrix(K, width, height).resized(width * s, height * s).K
        xs, ys = np.meshgrid(np.arange(width * s, dtype=np.float64), np.arange(height * s, dtype=np.float64))
        colour, depth = self._cast(K_ss, cam_to_world, np.stack([xs.ravel(), ys.ravel()], 1), shade=True)
        colour = colour.reshape(height * s, width * s, 3)
        if s > 1:
            colour = cv2.resize(colour, (width, height), interpolation=cv2.INTER_AREA)
            depth = self.depth_at(K, cam_to_world, _pixel_grid(width, height))
        rgb = np.clip(np.rint(colour * 255.0), 0, 255).astype(np.uint8)
        return rgb, depth.reshape(height, width).astype(np.float32)

    def depth_map(self, K: np.ndarray, cam_to_world: np.ndarray, width: int, height: int) -> np.ndarray:
        """(H, W) float32 z-depth at the pixel centres: the depth :meth:`render` returns, without
        the colour."""
        return (
            self.depth_at(K, cam_to_world, _pixel_grid(width, height))
            .reshape(height, width)
            .astype(np.float32)
        )

    def depth_at(self, K: np.ndarray, cam_to_world: np.ndarray, pixels: np.ndarray) -> np.ndarray:
        """Exact float64 z-depth of the first surface through each (N, 2) sub-pixel position (x, y)."""
        pixels = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        return self._cast(K, cam_to_world, pixels, shade=False)[1]

    def _cast(
        self, K: np.ndarray, cam_to_world: np.ndarray, pixels: np.ndarray, shade: bool
    ) -> tuple[np.ndarray | None, np.ndarray]:
        rot, origin = cam_to_world[:3, :3], cam_to_world[:3, 3]
        if not self.contains_camera(origin):
            raise ValueError(f"camera centre {origin} is outside the room or inside a box")
        # World directions R K^-1 [x, y, 1]: their camera z is 1, so the hit parameter is the z-depth.
        to_world = (rot @ np.linalg.inv(K)).T
        focal = float(np.sqrt(K[0, 0] * K[1, 1]))
        bounds = [_screen_bounds(box, K, cam_to_world) for box in self.boxes]
        depth = np.empty(len(pixels))
        colour = np.empty((len(pixels), 3), np.float32) if shade else None
        for start in range(0, len(pixels), _CHUNK):
            chunk = slice(start, start + _CHUNK)
            pix = pixels[chunk]
            dirs = _times(np.concatenate([pix, np.ones((len(pix), 1))], axis=1), to_world)
            t, face = self._intersect(origin, dirs, pix, bounds)
            depth[chunk] = t
            if shade:
                colour[chunk] = self._shade(origin, dirs, t, face, focal)
        return colour, depth

    def _intersect(
        self, origin: np.ndarray, dirs: np.ndarray, pixels: np.ndarray, bounds: list[np.ndarray | None]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Nearest hit parameter and face id of each ray ``origin + t dirs`` (world frame); a box is
        only tested against the rays whose pixel lies in its ``bounds`` (x0, y0, x1, y1; None: all)."""
        room = self.room
        # The room is seen from inside: each axis contributes the distance to the wall the ray
        # heads for; the first one reached is the exit. |d| = 0 gives +inf, never a false hit.
        o_l = room.rotation.T @ (origin - room.center)
        d_l = _times(dirs, room.rotation)
        toward_hi = d_l > 0
        with np.errstate(divide="ignore"):
            t_axes = np.where(toward_hi, room.half - o_l, room.half + o_l) / np.abs(d_l)
        axis = _argext(t_axes, np.minimum)
        rows = np.arange(len(dirs))
        t_best = t_axes[rows, axis]
        face = 2 * axis + toward_hi[rows, axis]
        for k, (box, box_bounds) in enumerate(zip(self.boxes, bounds, strict=True), start=1):
            if box_bounds is None:
                idx = rows
            else:
                x0, y0, x1, y1 = box_bounds
                px, py = pixels[:, 0], pixels[:, 1]
                idx = np.flatnonzero((px >= x0) & (px <= x1) & (py >= y0) & (py <= y1))
            if len(idx) == 0:
                continue
            o_l = box.rotation.T @ (origin - box.center)
            d_l = _times(dirs[idx], box.rotation)
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / d_l
                t1 = (-box.half - o_l) * inv
                t2 = (box.half - o_l) * inv
            t_in, t_out = np.minimum(t1, t2), np.maximum(t1, t2)
            t_near = np.maximum(np.maximum(t_in[:, 0], t_in[:, 1]), t_in[:, 2])
            t_far = np.minimum(np.minimum(t_out[:, 0], t_out[:, 1]), t_out[:, 2])
            hit = (t_near <= t_far) & (t_near > 0) & (t_near < t_best[idx])
            idx, t_near, t_in, d_l = idx[hit], t_near[hit], t_in[hit], d_l[hit]
            axis = _argext(t_in, np.maximum)
            t_best[idx] = t_near
            # A ray entering through the -axis face travels towards +axis.
            face[idx] = 6 * k + 2 * axis + (d_l[np.arange(len(idx)), axis] < 0)
        return t_best, face

    def _shade(
        self, origin: np.ndarray, dirs: np.ndarray, t: np.ndarray, face: np.ndarray, focal: float
    ) -> np.ndarray:
        """Trilinear texture colour (float32 RGB in [0, 1]) of each hit."""
        out = np.empty((len(t), 3), np.float32)
        order = np.argsort(face, kind="stable")
        ids, starts = np.unique(face[order], return_index=True)
        for fid, idx in zip(ids, np.split(order, starts[1:]), strict=True):
            f = self.faces[fid]
            box = f.cuboid
            d_l = _times(dirs[idx], box.rotation)
            p_l = box.rotation.T @ (origin - box.center) + t[idx, None] * d_l
            a1, a2 = _tangent_axes(f.axis)
            u = (p_l[:, a1] + box.half[a1]) * TEXELS_PER_UNIT
            v = (p_l[:, a2] + box.half[a2]) * TEXELS_PER_UNIT
            # Texels covered by one sample: the sample spans about z / f scene units across the
            # ray, stretched by 1/cos on an oblique face (sqrt: an isotropic compromise between
            # aliasing along the stretched direction and blurring across it).
            cos = np.abs(d_l[:, f.axis]) / np.linalg.norm(d_l, axis=1)
            footprint = TEXELS_PER_UNIT * t[idx] / (focal * np.sqrt(np.maximum(cos, 0.02)))
            level = np.clip(np.log2(np.maximum(footprint, 1.0)), 0.0, len(f.pyramid) - 1.0)
            out[idx] = _sample_trilinear(f.pyramid, u, v, level)
        return out


def _times(rows: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """``rows @ matrix`` for (N, 3) x (3, 3) without BLAS: multithreaded BLAS on such skinny
    products is no faster and, on a busy machine, its spinning threads made rendering 2-4x slower."""
    return np.einsum("ij,jk->ik", rows, matrix)


def _argext(values: np.ndarray, pick) -> np.ndarray:
    """Column index of the row-wise ``pick`` (np.minimum / np.maximum) of an (N, 3) array; faster
    than argmin/argmax along a 3-wide axis, which numpy does not vectorise."""
    best = pick(pick(values[:, 0], values[:, 1]), values[:, 2])
    return np.where(values[:, 0] == best, 0, np.where(values[:, 1] == best, 1, 2))


def _screen_bounds(box: _Cuboid, K: np.ndarray, cam_to_world: np.ndarray) -> np.ndarray | None:
    """Pixel rectangle (x0, y0, x1, y1) holding the box's projection, 1 px margin; None when a corner
    is not in front of the camera (then every ray is tested)."""
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    corners = box.center + (signs * box.half) @ box.rotation.T
    cam = (corners - cam_to_world[:3, 3]) @ cam_to_world[:3, :3]
    if np.any(cam[:, 2] <= 1e-6):
        return None
    proj = cam @ K.T
    xy = proj[:, :2] / proj[:, 2:]
    return np.concatenate([xy.min(axis=0) - 1.0, xy.max(axis=0) + 1.0])


def _pixel_grid(width: int, height: int) -> np.ndarray:
    xs, ys = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return np.stack([xs.ravel(), ys.ravel()], axis=1)


def _bilinear(texture: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(N, 3) bilinear lookups at texel coordinates (texel (0, 0) centred at (0, 0))."""
    n = len(x)
    pad = -n % _REMAP_ROW
    mx = np.pad(x.astype(np.float32), (0, pad)).reshape(-1, _REMAP_ROW)
    my = np.pad(y.astype(np.float32), (0, pad)).reshape(-1, _REMAP_ROW)
    return cv2.remap(texture, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(-1, 3)[:n]


def _sample_trilinear(pyramid: tuple[np.ndarray, ...], u: np.ndarray, v: np.ndarray, level: np.ndarray):
    """Blend of the two pyramid levels around ``level``; cv2.pyrDown keeps texel 2i of level L as
    texel i of level L+1, so level-L coordinates are level-0 coordinates / 2^L."""
    base = np.floor(level).astype(np.int64)
    frac = (level - base).astype(np.float32)[:, None]
    out = np.empty((len(u), 3), np.float32)
    for lev in np.unique(base):
        sel = base == lev
        scale = 0.5**lev
        colour = _bilinear(pyramid[lev], u[sel] * scale, v[sel] * scale)
        if lev + 1 < len(pyramid):
            upper = _bilinear(pyramid[lev + 1], u[sel] * scale * 0.5, v[sel] * scale * 0.5)
            colour += frac[sel] * (upper - colour)
        out[sel] = colour
    return out


@cache
def _photo(name: str) -> np.ndarray:
    """A bundled scikit-image photo as float32 in [0, 1]: HxW (grey) or HxWx3 (colour)."""
    image = np.asarray(getattr(skdata, name)())
    if image.ndim == 3:
        image = image[..., :3]
    out = image.astype(np.float32) / 255.0
    out.setflags(write=False)
    return out


def _value_noise(rng: np.random.Generator, width: int, height: int, finest: float = 3.0, octaves: int = 7):
    """Multi-octave value noise (HxW float32, zero mean, unit std): random grids upsampled bicubically,
    wavelengths ``finest`` * 2^k texels, amplitude growing slowly with wavelength so that fine
    detail (what SIFT responds to) stays strong."""
    total = np.zeros((height, width), np.float32)
    for k in range(octaves):
        wavelength = finest * 2**k
        grid = rng.random((int(np.ceil(height / wavelength)) + 2, int(np.ceil(width / wavelength)) + 2))
        total += wavelength**0.35 * cv2.resize(
            grid.astype(np.float32), (width, height), interpolation=cv2.INTER_CUBIC
        )
    return (total - total.mean()) / (total.std() + 1e-6)


def _colour_ramp(rng: np.random.Generator, values: np.ndarray) -> np.ndarray:
    """Map HxW values in about [0, 1] onto a line between two random colours (HxWx3)."""
    dark = rng.uniform(0.0, 0.45, 3).astype(np.float32)
    light = rng.uniform(0.55, 1.0, 3).astype(np.float32)
    return dark + values[..., None].astype(np.float32) * (light - dark)


def _texture(rng: np.random.Generator, width: int, height: int, shade: float) -> np.ndarray:
    """HxWx3 float32 texture in [0, 1]: a random photo crop mixed with value noise, times ``shade``."""
    photo = _photo(PHOTOS[rng.integers(len(PHOTOS))])
    if rng.random() < 0.5:
        photo = np.swapaxes(photo, 0, 1)
    if rng.random() < 0.5:
        photo = photo[:, ::-1]
    ph, pw = photo.shape[:2]
    aspect = width / height
    crop_h = min(ph, pw / aspect) * rng.uniform(0.5, 1.0)
    crop_w = crop_h * aspect
    y0, x0 = int(rng.uniform(0, ph - crop_h)), int(rng.uniform(0, pw - crop_w))
    crop = np.ascontiguousarray(photo[y0 : y0 + max(int(crop_h), 2), x0 : x0 + max(int(crop_w), 2)])
    interp = cv2.INTER_AREA if crop.shape[1] > width else cv2.INTER_CUBIC
    base = cv2.resize(crop, (width, height), interpolation=interp)
    if base.ndim == 2:
        base = _colour_ramp(rng, base)
    else:
        base = base * rng.uniform(0.7, 1.15, 3).astype(np.float32)
    # Crisp-edged blots (a saturated noise field) and a fine grain give SIFT blobs and corners at
    # every scale, different on every face.
    blots = _colour_ramp(rng, 0.5 + 0.5 * np.tanh(1.5 * _value_noise(rng, width, height)))
    grain = _value_noise(rng, width, height, finest=2.0, octaves=4)
    mix = rng.uniform(0.3, 0.55)
    texture = ((1.0 - mix) * base + mix * blots) * (1.0 + 0.2 * grain[..., None])
    return np.clip(texture * shade, 0.0, 1.0).astype(np.float32)


def _pyramid(texture: np.ndarray) -> tuple[np.ndarray, ...]:
    levels = [texture]
    while min(levels[-1].shape[:2]) >= 8:
        levels.append(cv2.pyrDown(levels[-1]))
    return tuple(levels)


def _faces(rng: np.random.Generator, cuboid: _Cuboid, inside: bool) -> list[_Face]:
    """The six textured faces of a cuboid, lit from :data:`_LIGHT` (normals point into the room
    for the room itself, outwards for boxes)."""
    faces = []
    for axis in range(3):
        a1, a2 = _tangent_axes(axis)
        width = int(np.ceil(2 * cuboid.half[a1] * TEXELS_PER_UNIT)) + 2
        height = int(np.ceil(2 * cuboid.half[a2] * TEXELS_PER_UNIT)) + 2
        for side in (0, 1):
            normal = cuboid.rotation[:, axis] * (1.0 if side else -1.0) * (-1.0 if inside else 1.0)
            shade = 0.5 + 0.5 * max(0.0, float(normal @ _LIGHT))
            faces.append(_Face(cuboid, axis, _pyramid(_texture(rng, width, height, shade))))
    return faces


def _place_boxes(rng: np.random.Generator, back_z: float, half_width: float) -> list[_Cuboid]:
    """Boxes standing on the floor, thin panels and maybe a pillar, inside the default view, not
    overlapping (footprint circles) and well away from the cameras."""
    floor, ceiling = CAMERA_HEIGHT, CEILING_Y
    specs = []  # (half extents, bottom height above the floor)
    for _ in range(rng.integers(4, 7)):
        specs.append((rng.uniform([0.3, 0.25, 0.25], [0.75, 0.8, 0.6]), 0.0))
    for _ in range(rng.integers(1, 3)):  # panels: sign boards, some raised off the floor
        specs.append((np.array([rng.uniform(0.4, 0.8), rng.uniform(0.3, 0.6), 0.025]), rng.uniform(0.0, 0.9)))
    if rng.random() < 0.6:
        specs.append((np.array([0.2, (floor - ceiling) / 2, 0.2]), 0.0))
    boxes: list[_Cuboid] = []
    placed: list[tuple[np.ndarray, float]] = []
    for half, lift in specs:
        radius = float(np.hypot(half[0], half[2]))
        for _ in range(200):
            z = rng.uniform(2.8, back_z - 1.2)
            x = rng.uniform(-0.45, 0.45) * z
            if abs(x) + radius > half_width - 0.1:
                continue
            if all(np.hypot(x - px, z - pz) > radius + pr + 0.05 for (px, pz), pr in placed):
                break
        else:
            continue  # no room left for this one
        placed.append(((x, z), radius))
        centre = np.array([x, floor - lift - half[1], z])
        boxes.append(_Cuboid(centre, _yaw(np.radians(rng.uniform(-35.0, 35.0))), half))
    return boxes


def make_scene(seed: int = 0) -> Scene:
    """A procedural room with boxes, drawn from ``np.random.default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    back_z = rng.uniform(8.5, 10.0)
    half_width = rng.uniform(4.0, 5.5)
    front = -3.0
    room = _Cuboid(
        np.array([0.0, (CAMERA_HEIGHT + CEILING_Y) / 2, (back_z + front) / 2]),
        np.eye(3),
        np.array([half_width, (CAMERA_HEIGHT - CEILING_Y) / 2, (back_z - front) / 2]),
    )
    boxes = _place_boxes(rng, back_z, half_width)
    faces = _faces(rng, room, inside=True)
    for box in boxes:
        faces += _faces(rng, box, inside=False)
    center = np.array([0.0, 0.45, 0.5 * (3.0 + back_z)])
    return Scene(room, boxes, faces, center)


@dataclass
class SyntheticPair:
    """A rendered target/source pair with exact ground truth (see the module docstring)."""

    target: np.ndarray  # (H, W, 3) uint8 RGB
    source: np.ndarray  # (Hs, Ws, 3) uint8 RGB
    depth_target: np.ndarray  # (H, W) float32 z-depth, scene units, > 0
    depth_source: np.ndarray  # (Hs, Ws) float32
    K_target: np.ndarray  # 3x3 float64, pixel-centre convention
    K_source: np.ndarray  # 3x3 float64
    T_source_to_target: np.ndarray  # 4x4 float64, X_t = R X_s + t (OpenCV axes)
    hole: np.ndarray  # (H, W) bool, True = hole; visible in the source, crosses a depth edge
    scene: Scene
    target_to_world: np.ndarray  # 4x4 camera-to-world pose of the target camera
    source_to_world: np.ndarray  # 4x4 camera-to-world pose of the source camera


def blanked(image: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """A copy of ``image`` with the ``hole`` pixels set to 0: the restoration input (a hole that shows
    nothing, so no reference content is refused as the removed object).

    >>> blanked(np.full((1, 2, 3), 9, np.uint8), np.array([[True, False]]))[..., 0].tolist()
    [[0, 9]]
    """
    out = image.copy()
    out[hole] = 0
    return out


def relative_pose(
    motion: str = "orbit",
    baseline: float | None = None,
    rotation_deg: float | None = None,
    center_distance: float = 6.0,
) -> np.ndarray:
    """4x4 source->target pose ``T`` (``X_t = R X_s + t``) of a source camera moved from the target.

    ``t`` is the source centre in target camera coordinates and ``R`` a yaw about the target's y
    axis (positive turns the optical axis towards +x). ``orbit``: the centre moves ``baseline``
    (default 0.5) along x and the camera turns back towards the point ``center_distance`` ahead of
    the target (by ``rotation_deg`` when given, else exactly onto it); ``sideways`` / ``forward``:
    ``baseline`` (default 0.5) along x / z, yaw ``rotation_deg`` (default 0: pure translation);
    ``rotate``: yaw ``rotation_deg`` (default 5) about the centre, translation ``baseline``
    (default 0) along x.
    """
    if motion not in MOTIONS:
        raise ValueError(f"motion must be one of {MOTIONS}, got {motion!r}")
    if baseline is None:
        baseline = 0.0 if motion == "rotate" else 0.5
    if motion == "orbit":
        turn = np.arctan2(baseline, center_distance) if rotation_deg is None else np.radians(rotation_deg)
        yaw = -np.sign(baseline) * abs(turn)
    else:
        yaw = np.radians(rotation_deg if rotation_deg is not None else (5.0 if motion == "rotate" else 0.0))
    T = np.eye(4)
    T[:3, :3] = _yaw(yaw)
    T[:3, 3] = [0.0, 0.0, baseline] if motion == "forward" else [baseline, 0.0, 0.0]
    return T


def covisible(
    scene: Scene,
    K_target: np.ndarray,
    target_to_world: np.ndarray,
    depth_target: np.ndarray,
    K_source: np.ndarray,
    source_to_world: np.ndarray,
    source_size: tuple[int, int],
) -> np.ndarray:
    """(H, W) bool: the surface point at each target pixel centre is seen by the source camera
    (projects inside the source image and is the first hit of the source ray through it)."""
    h, w = depth_target.shape
    pix = _pixel_grid(w, h)
    x_t = _times(np.concatenate([pix, np.ones((len(pix), 1))], 1), np.linalg.inv(K_target).T)
    x_t *= depth_target.reshape(-1, 1).astype(np.float64)
    world = _times(x_t, target_to_world[:3, :3].T) + target_to_world[:3, 3]
    x_s = _times(world - source_to_world[:3, 3], source_to_world[:3, :3])
    z_s = x_s[:, 2]
    proj = _times(x_s, K_source.T)
    uv = proj[:, :2] / np.where(z_s > 0, z_s, 1.0)[:, None]
    ws, hs = source_size
    inside = (z_s > 0) & np.all((uv >= -0.5) & (uv < np.array([ws, hs]) - 0.5), axis=1)
    seen = np.zeros(len(pix), bool)
    # depth_target is float32, so the unprojected point carries ~1e-7 relative error.
    z_first = scene.depth_at(K_source, source_to_world, uv[inside])
    seen[inside] = np.abs(z_first - z_s[inside]) <= 1e-5 * z_s[inside]
    return seen.reshape(h, w)


def depth_edges(depth: np.ndarray, rel_jump: float = 0.05) -> np.ndarray:
    """(H, W) bool: pixels with a 4-neighbour whose depth differs by more than ``rel_jump`` (relative)."""
    edges = np.zeros(depth.shape, bool)
    for axis in (0, 1):
        a, b = np.moveaxis(depth, axis, 0)[:-1], np.moveaxis(depth, axis, 0)[1:]
        jump = np.abs(a - b) > rel_jump * np.minimum(a, b)
        e = np.moveaxis(edges, axis, 0)
        e[:-1] |= jump
        e[1:] |= jump
    return edges


def _blob(shape: tuple[int, int], centre: np.ndarray, radius: float, rng: np.random.Generator) -> np.ndarray:
    """(H, W) bool blob: an ellipse of area ~ pi radius^2 whose radius wobbles with a few low harmonics."""
    angle, aspect = rng.uniform(0, np.pi), rng.uniform(0.6, 1.0)
    amps, phases = rng.uniform(0.0, 0.12, 3), rng.uniform(0, 2 * np.pi, 3)
    # The wobble adds at most 36 %, so the blob fits in this box; only the box is evaluated.
    reach = int(np.ceil(1.36 * radius)) + 1
    h, w = shape
    x0, x1 = max(int(centre[0]) - reach, 0), min(int(centre[0]) + reach + 1, w)
    y0, y1 = max(int(centre[1]) - reach, 0), min(int(centre[1]) + reach + 1, h)
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float64)
    dx, dy = xs - centre[0], ys - centre[1]
    a = dx * np.cos(angle) + dy * np.sin(angle)
    b = (-dx * np.sin(angle) + dy * np.cos(angle)) / aspect
    theta = np.arctan2(b, a)
    harmonics = zip(amps, phases, (2, 3, 5), strict=True)
    wobble = 1.0 + sum(amp * np.cos(k * theta + ph) for amp, ph, k in harmonics)
    mask = np.zeros(shape, bool)
    mask[y0:y1, x0:x1] = np.hypot(a, b) < radius * np.sqrt(aspect) * wobble
    return mask


def place_hole(
    rng: np.random.Generator, depth: np.ndarray, visible: np.ndarray, area_range=(0.07, 0.12), tries: int = 40
) -> np.ndarray:
    """A blob hole centred on a depth edge whose pixels are (almost) all ``visible`` in the source.

    Among ``tries`` random candidates the first with >= 98 % visible pixels and an area inside
    ``area_range`` (fraction of the image) wins; failing that, the most visible candidate.
    """
    h, w = depth.shape
    edges = depth_edges(depth)
    margin = int(0.12 * min(h, w))
    edges[:margin] = edges[-margin:] = False
    edges[:, :margin] = edges[:, -margin:] = False
    cand = np.argwhere(edges)
    if len(cand) == 0:  # no depth edge away from the border: fall back to the image centre
        cand = np.array([[h // 2, w // 2]])
    best, best_score = None, -1.0
    for _ in range(tries):
        cy, cx = cand[rng.integers(len(cand))]
        radius = np.sqrt(rng.uniform(*area_range) * h * w / np.pi)
        mask = _blob((h, w), np.array([cx, cy], float), radius, rng)
        area = mask.mean()
        score = visible[mask].mean() if mask.any() else 0.0
        if area_range[0] * 0.8 <= area <= area_range[1] * 1.2 and score > best_score:
            best, best_score = mask, score
            if score >= 0.98:
                break
    if best is None:
        raise RuntimeError("could not place a hole in the synthetic target")
    return best


def make_pair(
    seed: int = 0,
    width: int = 320,
    height: int = 240,
    focal_px: float | None = None,
    source_size: tuple[int, int] | None = None,
    source_focal_px: float | None = None,
    motion: str = "orbit",
    baseline: float | None = None,
    rotation_deg: float | None = None,
    supersample: int = 2,
    source_gain: float = 1.0,
    noise_sigma: float = 0.0,
) -> SyntheticPair:
    """Render a target/source pair of :func:`make_scene` ``(seed)`` with exact depth and pose.

    ``focal_px`` defaults to :func:`geofill.camera.default_focal_px` of the target size;
    ``source_size`` is (width, height) (default: the target's) and ``source_focal_px`` defaults to
    ``focal_px`` for a same-size source, else to the default rule for the source size. ``motion``,
    ``baseline`` (scene units; the back wall is 8.5-10 units away) and ``rotation_deg`` are as in
    :func:`relative_pose`; the default is a handheld-like orbit: 0.5 units sideways, turning ~5 deg
    back onto the scene centre. ``source_gain`` scales the source's exposure and ``noise_sigma``
    (8-bit grey levels) adds Gaussian noise to both images; neither touches the ground truth.
    """
    scene = make_scene(seed)
    ws, hs = source_size if source_size is not None else (width, height)
    f_t = float(focal_px) if focal_px is not None else default_focal_px(width, height)
    if source_focal_px is not None:
        f_s = float(source_focal_px)
    else:
        f_s = f_t if source_size is None else default_focal_px(ws, hs)
    K_t = Intrinsics.from_focal(f_t, width, height).K
    K_s = Intrinsics.from_focal(f_s, ws, hs).K
    pose_t = scene.target_pose()
    # Built directly (not as inv(pose_t) @ pose_s) so that it is exact: e.g. t == 0 for "rotate".
    T = relative_pose(motion, baseline, rotation_deg, float(np.linalg.norm(scene.center - pose_t[:3, 3])))
    pose_s = pose_t @ T
    target, depth_t = scene.render(K_t, pose_t, width, height, supersample)
    source, depth_s = scene.render(K_s, pose_s, ws, hs, supersample)
    # Separate streams: the photometric knobs must not move the hole.
    noise_rng = np.random.default_rng([seed, 2])
    source = _photometric(source, source_gain, noise_sigma, noise_rng)
    target = _photometric(target, 1.0, noise_sigma, noise_rng)
    visible = covisible(scene, K_t, pose_t, depth_t, K_s, pose_s, (ws, hs))
    hole = place_hole(np.random.default_rng([seed, 1]), depth_t, visible)
    return SyntheticPair(target, source, depth_t, depth_s, K_t, K_s, T, hole, scene, pose_t, pose_s)


def _photometric(image: np.ndarray, gain: float, sigma: float, rng: np.random.Generator) -> np.ndarray:
    if gain == 1.0 and sigma == 0.0:
        return image
    out = image.astype(np.float32) * gain
    if sigma > 0:
        out += rng.normal(0.0, sigma, image.shape).astype(np.float32)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


@dataclass
class SyntheticViews:
    """A target and several references of one :func:`make_scene` with exact ground truth; what
    each reference sees of the target is in ``visible`` (per reference, target pixels)."""

    target: np.ndarray  # (H, W, 3) uint8 RGB
    depth_target: np.ndarray  # (H, W) float32
    K: np.ndarray  # 3x3, shared by every camera (pixel-centre convention)
    sources: list[np.ndarray]  # (H, W, 3) uint8 RGB each
    T_source_to_target: list[np.ndarray]  # 4x4 each
    visible: list[np.ndarray]  # (H, W) bool each: the target's surface point is seen by that reference
    scene: Scene


def make_views(
    seed: int = 0,
    width: int = 320,
    height: int = 240,
    motions: Sequence[tuple[str, float, float | None]] = (("sideways", -0.6, -12.0), ("sideways", 0.6, 12.0)),
    supersample: int = 2,
    focal_px: float | None = None,
) -> SyntheticViews:
    """Render the target of :func:`make_pair` ``(seed)`` and one reference per ``(motion, baseline,
    rotation_deg)`` of ``motions`` (as :func:`relative_pose`). The default: one reference stepped
    left and turned left, one stepped right and turned right, so each misses what the other sees
    at the opposite border. One camera for all (``focal_px``, default :func:`default_focal_px`)."""
    scene = make_scene(seed)
    K = Intrinsics.from_focal(focal_px or default_focal_px(width, height), width, height).K
    pose_t = scene.target_pose()
    target, depth_t = scene.render(K, pose_t, width, height, supersample)
    centre = float(np.linalg.norm(scene.center - pose_t[:3, 3]))
    sources, Ts, visible = [], [], []
    for motion, baseline, rotation in motions:
        T = relative_pose(motion, baseline, rotation, centre)
        pose_s = pose_t @ T
        sources.append(scene.render(K, pose_s, width, height, supersample)[0])
        Ts.append(T)
        visible.append(covisible(scene, K, pose_t, depth_t, K, pose_s, (width, height)))
    return SyntheticViews(target, depth_t, K, sources, Ts, visible, scene)
