"""The painter with the scene's planes: a synthetic floor and wall rendered through a known camera,
so the planes, their meeting line, the tiles' period and their vanishing direction are known
exactly, and a hole across the meeting line is painted with and without the depth."""

from __future__ import annotations

import cv2
import numpy as np

from geofill.composite.exemplar import complete
from geofill.composite.planes import SceneDepth, meeting_line, plane_surfaces
from geofill.composite.rectify import paint

#: Camera: 320x240, f = 300 px; turned 30 degrees to the left and 12 degrees down, 1.5 units above
#: the floor (y = 1.5, OpenCV axes: y down), a wall at z = 6 in front (world frame).
_W, _H, _F = 320, 240, 300.0
_K = np.array([[_F, 0, _W / 2], [0, _F, _H / 2], [0, 0, 1.0]])
_FLOOR_Y, _WALL_Z = 1.5, 6.0
_YAW, _PITCH = np.radians(30.0), np.radians(12.0)
#: Floor: a checkerboard of 0.25-unit squares (period 0.5 along world x and z).
_SQUARE = 0.25
_SUPERSAMPLE = 4


def _rotation() -> np.ndarray:
    """World-to-camera rotation."""
    cy, sy, cp, sp = np.cos(_YAW), np.sin(_YAW), np.cos(_PITCH), np.sin(_PITCH)
    yaw = np.array([[cy, 0, -sy], [0, 1, 0], [sy, 0, cy]])
    pitch = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    return pitch @ yaw


def _cast(xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points, camera depth and whether on the floor, for pixel coordinates ``xs``, ``ys``."""
    R = _rotation()
    cam = np.stack([(xs - _K[0, 2]) / _F, (ys - _K[1, 2]) / _F, np.ones_like(xs)], -1)
    d = cam @ R  # R^T applied to each ray: world directions with camera z = 1
    with np.errstate(divide="ignore"):
        t_floor = np.where(d[..., 1] > 0, _FLOOR_Y / d[..., 1], np.inf)
        t_wall = np.where(d[..., 2] > 0, _WALL_Z / d[..., 2], np.inf)
    floor = t_floor < t_wall
    t = np.minimum(t_floor, t_wall)
    return d * t[..., None], t, floor


def _scene() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rendered image (HxWx3 uint8, supersampled), its depth (camera z) and the floor mask."""
    s = _SUPERSAMPLE
    ys, xs = np.mgrid[0 : _H * s, 0 : _W * s].astype(np.float64)
    pts, _, floor = _cast((xs + 0.5) / s - 0.5, (ys + 0.5) / s - 0.5)
    checker = (np.floor(pts[..., 0] / _SQUARE) + np.floor(pts[..., 2] / _SQUARE)) % 2
    floor_rgb = np.where(checker[..., None] > 0, [200.0, 205, 215], [50.0, 60, 80])
    # Bricks 0.4 x 0.2 units, every other row shifted by half, 0.03-unit mortar.
    row = np.floor(pts[..., 1] / 0.2)
    u = pts[..., 0] / 0.4 + 0.5 * (row % 2)
    mortar = ((pts[..., 1] % 0.2) < 0.03) | ((u % 1.0) < 0.075)
    wall_rgb = np.where(mortar[..., None], [215.0, 200, 180], [170.0, 60, 40])
    rgb = np.where(floor[..., None], floor_rgb, wall_rgb)
    image = rgb.reshape(_H, s, _W, s, 3).mean(axis=(1, 3))
    ys, xs = np.mgrid[0:_H, 0:_W].astype(np.float64)
    _, depth, on_floor = _cast(xs, ys)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8), depth.astype(np.float32), on_floor


def _true_line() -> np.ndarray:
    """The wall's foot (image line a x + b y + c = 0)."""
    R = _rotation()
    # Planes in the camera frame (camera at the world origin): n.X = d.
    n_floor, n_wall = R @ np.array([0, 1.0, 0]), R @ np.array([0, 0, 1.0])
    l = np.linalg.inv(_K).T @ (_FLOOR_Y * n_wall - _WALL_Z * n_floor)
    return l / np.hypot(l[0], l[1])


def _hole(cx: float, cy: float, radius: float) -> np.ndarray:
    ys, xs = np.mgrid[0:_H, 0:_W]
    return (xs - cx) ** 2 + (ys - cy) ** 2 <= radius**2


def _floor_frequencies(out: np.ndarray, region: np.ndarray) -> list[tuple[float, float]]:
    """The checkerboard's two fundamental frequencies in ``out``'s ``region``, read in the floor's
    own coordinates (the image sampled on a world grid, 0.02 units a sample): for each, its
    magnitude's relative error against the truth's (2 cycles per unit along x and z: 2.83 along
    each diagonal) and its direction's error in degrees. Each frequency is the power-weighted mean
    within 0.6 cycles per unit of the spectrum's peak in its quadrant."""

    ys, xs = np.nonzero(region)
    pts, _, _ = _cast(xs.astype(np.float64), ys.astype(np.float64))
    step = 0.02
    x0, z0 = pts[:, 0].min(), pts[:, 2].min()
    nx, nz = int((pts[:, 0].max() - x0) / step) + 1, int((pts[:, 2].max() - z0) / step) + 1
    gz, gx = np.mgrid[0:nz, 0:nx]
    world = np.stack([x0 + gx * step, np.full(gx.shape, _FLOOR_Y), z0 + gz * step], -1)
    px = world @ _rotation().T @ _K.T
    u, v = (px[..., 0] / px[..., 2]).astype(np.float32), (px[..., 1] / px[..., 2]).astype(np.float32)
    grey = cv2.cvtColor(out, cv2.COLOR_RGB2GRAY).astype(np.float32)
    sample = cv2.remap(grey, u, v, cv2.INTER_LINEAR)
    inside = cv2.remap(region.astype(np.float32), u, v, cv2.INTER_NEAREST) > 0
    sample = np.where(inside, sample - sample[inside].mean(), 0.0)
    power = np.abs(np.fft.fft2(sample, (512, 512))) ** 2
    fx, fz = np.meshgrid(np.fft.fftfreq(512, step), np.fft.fftfreq(512, step))
    found = []
    for sign in (1, -1):
        quadrant = np.where((fx > 0) & (sign * fz > 0), power, 0.0)
        i = int(np.argmax(quadrant))
        near = (fx - fx.flat[i]) ** 2 + (fz - fz.flat[i]) ** 2 < 0.6**2
        f = np.array([(quadrant * fx)[near].sum(), (quadrant * fz)[near].sum()]) / quadrant[near].sum()
        found.append((np.linalg.norm(f) / np.sqrt(8.0) - 1.0, np.degrees(np.arctan2(abs(f[1]), f[0])) - 45.0))
    return found


def _case() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, SceneDepth]:
    """The scene, a 55-px disc across the wall's foot blanked, the floor mask and the ring's depth."""
    image, z, on_floor = _scene()
    line = _true_line()
    hole = _hole(170.0, -(line[0] * 170.0 + line[2]) / line[1], 55)
    blank = image.copy()
    blank[hole] = 0
    return image, blank, hole, on_floor, SceneDepth(np.where(hole, np.nan, z).astype(np.float32), _K)


def _line_distance() -> np.ndarray:
    """Every pixel's signed distance (px) to the wall's foot."""
    line = _true_line()
    ys, xs = np.mgrid[0:_H, 0:_W]
    return line[0] * xs + line[1] * ys + line[2]


def test_the_planes_and_their_meeting_line_come_from_the_depth():
    """Two planes are found on the ring, their normals within 1 degree of the floor's and the
    wall's, the meeting line they give is the wall's foot to half a pixel, and every hole pixel
    more than 3 px from it is given to its own plane."""
    image, _, hole, on_floor, scene = _case()
    found = plane_surfaces(image.astype(np.float32) / 255, hole, scene, 7)
    assert found is not None and len(found.planes) == 2
    R = _rotation()
    for truth in (R @ np.array([0, 1.0, 0]), R @ np.array([0, 0, 1.0])):
        cos = max(abs(float(p.normal @ truth)) for p in found.planes)
        assert np.degrees(np.arccos(min(cos, 1.0))) < 1.0
    line = _true_line()
    got = meeting_line(*found.planes, _K)
    got = got / np.hypot(got[0], got[1])
    for x in (120.0, 170.0, 220.0):
        assert abs(got @ [x, -(line[0] * x + line[2]) / line[1], 1.0]) < 0.5
    floor_label = np.bincount(found.labels[on_floor & ~hole]).argmax()
    wrong = (found.labels == floor_label) != on_floor
    assert (wrong & hole & (np.abs(_line_distance()) > 3)).sum() == 0


def test_the_window_moves_the_principal_point_with_it():
    """A window of the depth sees the same rays as the whole image there."""
    from geofill.composite.planes import rays

    scene = SceneDepth(np.ones((_H, _W), np.float32), _K)
    part = scene.window(slice(30, 90), slice(50, 200))
    np.testing.assert_allclose(rays(part.K, (60, 150)), rays(_K, (_H, _W))[30:90, 50:200])


def test_the_floor_is_painted_with_its_period_and_vanishing_direction():
    """Read on the floor's own grid, both of the painted checkerboard's fundamental frequencies are
    within 10 % of the truth's magnitude (its period) and 6 degrees of its direction (the tiles run
    to the vanishing points); measured 3.6 % and 3.7 degrees at most. The truth itself measures
    within 0.3 % and 0.4 degrees; the painter without depth, copying tiles from nearer and farther,
    is 85 % and 12.4 degrees off."""
    _, blank, hole, on_floor, scene = _case()
    out = paint(blank, hole, None, scene)
    for magnitude, direction in _floor_frequencies(out, hole & on_floor & (np.abs(_line_distance()) > 4)):
        assert abs(magnitude) < 0.10 and abs(direction) < 6.0, (magnitude, direction)


def test_wall_and_floor_are_painted_from_themselves_up_to_their_meeting_line():
    """No hole pixel more than 3 px from the wall's foot takes the other surface's colours (the
    painter without depth: 430) and the foot runs on within 2 px of where it is (without: 5 px)."""
    _, blank, hole, on_floor, scene = _case()
    out = paint(blank, hole, None, scene)
    wallish = out[..., 0].astype(int) > out[..., 2]  # bricks and mortar are red over blue, tiles not
    assert (hole & (np.abs(_line_distance()) > 3) & (wallish == on_floor)).sum() == 0
    line = _true_line()
    cols = np.arange(130, 211, 10)
    first_floor = np.array([40 + np.flatnonzero(~wallish[40:200, c])[0] for c in cols])
    assert np.abs(first_floor + (line[0] * cols + line[2]) / line[1]).max() <= 2.0
    np.testing.assert_array_equal(out[~hole], blank[~hole])


def test_without_depth_or_planes_the_painter_is_unchanged():
    """No depth, or depth that shows no plane on the ring (a random field), paints the same bytes
    as the painter alone."""
    _, blank, hole, _, _ = _case()
    alone = complete(blank, hole)
    np.testing.assert_array_equal(paint(blank, hole, None, None), alone)
    noise = np.random.default_rng(0).uniform(1.0, 50.0, hole.shape).astype(np.float32)
    np.testing.assert_array_equal(paint(blank, hole, None, SceneDepth(noise, _K)), alone)


def test_the_exemplar_inpainter_paints_with_the_planes_only_when_asked():
    """``inpaint.planes`` on: the inpainter handed the scene's depth paints as the rectified painter
    on its window (the depth cropped with it); off (the default): as the painter without depth."""
    from geofill.composite.exemplar import ExemplarSettings
    from geofill.composite.inpaint import _context, get_inpainter
    from geofill.config import InpaintConfig

    _, blank, hole, _, scene = _case()
    rows, cols = _context(hole)
    window = paint(blank[rows, cols], hole[rows, cols], ExemplarSettings(), scene.window(rows, cols))
    on = get_inpainter(InpaintConfig(method="exemplar", planes=True)).fill(blank, hole, scene)
    np.testing.assert_array_equal(on[rows, cols], window)
    off = get_inpainter(InpaintConfig(method="exemplar")).fill(blank, hole, scene)
    np.testing.assert_array_equal(off[rows, cols], paint(blank[rows, cols], hole[rows, cols], None, None))


def test_no_patch_on_any_surface_is_diffused_not_an_error():
    """Where the pixels the painter may copy (a surface's, the rest on none) hold no whole patch
    (a plane seen only as a sliver in its rectified canvas), the hole is diffused (the painter
    raised "high <= 0" choosing a random source among none)."""
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (80, 80, 3), dtype=np.uint8)
    hole = _hole(40, 40, 20)[:80, :80]
    ys, xs = np.mgrid[0:80, 0:80]
    ring = ((xs - 40) ** 2 + (ys - 40) ** 2 <= 22**2) & ~hole  # 2 px: no 3x3 patch fits
    surfaces = np.where(hole | ring, 0, -1).astype(np.int32)
    out = complete(image, hole, None, surfaces=surfaces)
    telea = cv2.inpaint(image, hole.astype(np.uint8), 5.0, cv2.INPAINT_TELEA)
    np.testing.assert_array_equal(out[hole], telea[hole])
