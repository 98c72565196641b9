"""Exemplar painting (multi-scale PatchMatch completion): it continues periodic texture and straight
edges where diffusion smears, keeps every pixel outside the hole, and gives the same bytes every run,
and in a reference fill it copies the render's texture into what the render leaves uncovered."""

from __future__ import annotations

import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from geofill.composite import exemplar, surfaces
from geofill.composite.exemplar import ExemplarSettings, complete
from geofill.composite.inpaint import get_inpainter
from geofill.composite.merge import merge_fill
from geofill.config import FillConfig, InpaintConfig
from geofill.errors import ConfigError


def _grad_ratio(img: np.ndarray, hole: np.ndarray, ring_px: int = 10) -> float:
    grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float32)
    mag = np.hypot(cv2.Sobel(grey, cv2.CV_32F, 1, 0), cv2.Sobel(grey, cv2.CV_32F, 0, 1))
    ring = (cv2.dilate(hole.astype(np.uint8), np.ones((2 * ring_px + 1,) * 2, np.uint8)) > 0) & ~hole
    return float(mag[hole].mean() / mag[ring].mean())


def _checks(h: int = 160, w: int = 200, period: int = 10) -> np.ndarray:
    """A colour pattern periodic in x and y (a blurred checkerboard with a diagonal stripe)."""
    yy, xx = np.mgrid[0:h, 0:w]
    board = ((xx // (period // 2) + yy // (period // 2)) % 2).astype(np.float32)
    stripe = ((xx + yy) % period < 3).astype(np.float32)
    img = np.stack([60 + 150 * board, 80 + 120 * stripe, 200 - 100 * board], axis=-1)
    return cv2.GaussianBlur(img, (0, 0), 0.7).round().astype(np.uint8)


def _disc(h: int, w: int, cy: int, cx: int, radius: int) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    return (yy - cy) ** 2 + (xx - cx) ** 2 <= radius**2


@pytest.mark.parametrize(
    ("h", "w"),
    [(160, 200), (200, 1500)],  # the second's finest level is too long to search: matches copied up
)
def test_periodic_texture_is_continued_where_telea_smears(h, w):
    truth = _checks(h, w)
    hole = _disc(h, w, h // 2, w // 2, 32)
    blank = truth.copy()
    blank[hole] = 0
    out = complete(blank, hole)
    telea = cv2.inpaint(blank, hole.astype(np.uint8), 5.0, cv2.INPAINT_TELEA)
    err = np.abs(out.astype(int) - truth)[hole].mean()
    telea_err = np.abs(telea.astype(int) - truth)[hole].mean()
    assert _grad_ratio(truth, hole) == pytest.approx(1.0, abs=0.05)
    assert _grad_ratio(telea, hole) < 0.5  # the smear
    assert _grad_ratio(out, hole) == pytest.approx(1.0, abs=0.15)
    # In phase with the truth: copies of the pattern, not a texture of the right roughness.
    assert err < 0.35 * telea_err, (err, telea_err)
    np.testing.assert_array_equal(out[~hole], blank[~hole])


def test_a_straight_edge_through_the_hole_is_continued():
    h, w = 120, 160
    yy, xx = np.mgrid[0:h, 0:w]
    rng = np.random.default_rng(1)
    grain = rng.normal(0, 6, (h, w, 1))
    edge_row = 50 + 0.25 * xx  # a slanted straight edge
    img = np.where((yy < edge_row)[..., None], [200, 180, 150], [50, 70, 90]) + grain
    img = np.clip(img, 0, 255).astype(np.uint8)
    hole = np.zeros((h, w), bool)
    hole[30:100, 60:110] = True
    blank = img.copy()
    blank[hole] = 0
    out = complete(blank, hole)
    telea = cv2.inpaint(blank, hole.astype(np.uint8), 5.0, cv2.INPAINT_TELEA)

    def offsets(filled: np.ndarray) -> np.ndarray:
        """Per column through the hole: the row where bright turns dark, minus the edge's row."""
        cols = np.arange(62, 108, 5)
        grey = filled[30:100, cols].astype(float).mean(axis=2)
        return 30 + np.argmax(grey < 125, axis=0) - edge_row[0, cols]

    assert np.abs(offsets(out)).max() <= 2.5, offsets(out)
    assert np.abs(offsets(telea)).max() > 5  # diffusion bends it towards the hole's middle


def test_same_bytes_every_run_and_with_any_number_of_threads(monkeypatch):
    truth = _checks(140, 180)
    hole = _disc(140, 180, 70, 90, 30) | _disc(140, 180, 20, 30, 12)
    blank = truth.copy()
    blank[hole] = 0
    first = complete(blank, hole)
    np.testing.assert_array_equal(complete(blank, hole), first)
    monkeypatch.setattr(exemplar, "_workers", lambda: 1)
    np.testing.assert_array_equal(complete(blank, hole), first)
    assert not np.array_equal(complete(blank, hole, ExemplarSettings(seed=1)), first)  # the seed is used


def test_pure_exemplars_copy_the_photo_and_the_structure_scale_is_the_only_difference():
    truth = _checks()
    hole = _disc(*truth.shape[:2], 80, 100, 30)
    blank = truth.copy()
    blank[hole] = 0
    only = complete(blank, hole, ExemplarSettings(structure_sigma=0.0))
    # Without the diffused structure every hole pixel is a pixel of the known image.
    known = {tuple(p) for p in blank[~hole].reshape(-1, 3)}
    assert all(tuple(p) in known for p in only[hole])
    mixed = complete(blank, hole)
    assert not np.array_equal(mixed, only)
    np.testing.assert_array_equal(mixed[~hole], only[~hole])


def test_the_painted_part_of_a_reference_fill_copies_the_render_texture():
    """The render is an exemplar source: a texture only the render shows is continued into what
    the render leaves uncovered, where diffusion would smear it."""
    h, w = 160, 200
    target = np.full((h, w, 3), 128, np.uint8)  # the known target is flat: nothing to copy there
    truth = _checks(h, w)
    hole = np.zeros((h, w), bool)
    hole[30:130, 30:170] = True
    alpha = hole.copy()
    alpha[50:110, 110:160] = False  # a disocclusion inside the covered hole
    painted = hole & ~alpha
    inp = get_inpainter(InpaintConfig(method="exemplar"))
    out = merge_fill(target, hole, truth, alpha, inp, 0.0)
    telea = merge_fill(target, hole, truth, alpha, get_inpainter(InpaintConfig(method="telea")), 0.0)
    err = np.abs(out.astype(int) - truth)[painted].mean()
    telea_err = np.abs(telea.astype(int) - truth)[painted].mean()
    assert err < 0.5 * telea_err, (err, telea_err)
    assert _grad_ratio(out, painted, 5) > 0.8 > 0.5 > _grad_ratio(telea, painted, 5)
    np.testing.assert_array_equal(out[~hole], target[~hole])
    np.testing.assert_array_equal(out[alpha], truth[alpha])


def test_speckles_are_diffused_small_known_areas_use_small_patches_and_bad_settings_fail():
    truth = _checks(60, 60)
    speckle = np.zeros((60, 60), bool)
    speckle[::4, ::4] = True  # 1 px deep: diffused
    speckle[1::2, 30:] = True  # no 3x3 patch known there, and 1 px deep too
    blank = truth.copy()
    blank[speckle] = 0
    telea = cv2.inpaint(blank, speckle.astype(np.uint8), 5.0, cv2.INPAINT_TELEA)
    np.testing.assert_array_equal(complete(blank, speckle), np.where(speckle[..., None], telea, blank))
    hole = np.ones((40, 40), bool)
    hole[:5, :5] = False  # known: a 5x5 corner, too small for 7x7 patches, enough for 5x5 ones
    img = np.zeros((40, 40, 3), np.uint8)
    img[:5, :5] = truth[:5, :5]
    out = complete(img, hole, ExemplarSettings(structure_sigma=0.0))
    np.testing.assert_array_equal(out[~hole], img[~hole])
    assert {tuple(p) for p in out[hole]} <= {tuple(p) for p in img[:5, :5].reshape(-1, 3)}
    for override, message in (
        ({"inpaint.structure_sigma_px": -1.0}, "inpaint.structure_sigma_px: -1.0 is outside"),
        ({"inpaint.patch_radius_px": 0}, "inpaint.patch_radius_px: 0 is outside"),
        ({"inpaint.method": "exemplars"}, "inpaint.method"),
    ):
        with pytest.raises(ConfigError, match=message) as info:
            FillConfig().updated(override)
        assert "\n" not in str(info.value)


@pytest.mark.needs("onnxruntime")
def test_auto_paints_with_exemplars_without_lama(monkeypatch, tmp_path):
    monkeypatch.setenv("GEOFILL_CACHE", str(tmp_path))  # conftest: offline, nothing cached
    inp = get_inpainter(InpaintConfig())
    assert inp.name == "exemplar" and inp.description.startswith("exemplar (auto: LaMa (ONNX) weights")
    assert get_inpainter(FillConfig().preset("telea").inpaint).name == "telea"


_BOUNDED_SCRIPT = """
import resource, sys
import numpy as np
from geofill.composite.exemplar import complete
from geofill.composite.rectify import paint

h, w, budget = (int(a) for a in sys.argv[1:4])
tile = np.random.default_rng(0).integers(0, 256, (16, 16, 3), dtype=np.uint8).repeat(4, 0).repeat(4, 1)
img = np.tile(tile, (h // 64 + 1, w // 64 + 1, 1))[:h, :w].copy()
if sys.argv[4] == "painter":  # the default painter: a wall on a floor, their edge drawn across first
    img = np.where(np.arange(h)[:, None, None] < h // 2, (200, 170, 90), (90, 90, 100))
    img = np.clip(img + np.random.default_rng(0).normal(0, 3, (h, w, 3)), 0, 255).astype(np.uint8)
    complete = lambda image, hole: paint(image, hole, None, None)
hole = np.zeros((h, w), bool)
m = 3 if sys.argv[4] == "painter" else 16  # the edge must run into the hole from the known image
hole[h // m : h - h // m, w // m : w - w // m] = True
warm = np.zeros((300, 300), bool)
warm[20:280, 20:280] = True
complete(img[:300, :300].copy(), warm)  # compiled, its threads and their arenas made
size = next(int(line.split()[1]) * 1024 for line in open("/proc/self/status") if line.startswith("VmSize"))
resource.setrlimit(resource.RLIMIT_AS, (size + budget * h * w, resource.RLIM_INFINITY))
out = complete(img, hole)
resource.setrlimit(resource.RLIMIT_AS, (resource.RLIM_INFINITY, resource.RLIM_INFINITY))  # the checks
assert np.array_equal(out[~hole], img[~hole])
grey = out[hole].astype(float).mean(axis=1)
print(f"{grey.std():.1f}")
"""


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="reads VmSize from /proc")
@pytest.mark.parametrize("painter, h, w, budget", [("complete", 2048, 8192, 32), ("painter", 4096, 4096, 24)])
def test_memory_is_bounded_by_the_searched_levels_not_the_image(tmp_path, painter, h, w, budget):
    """A 16.7 MP image is painted in ``budget`` bytes of address space per pixel beyond what the
    process already holds: the levels above the 1400-px search are never held whole (the old
    completion needed 145 bytes per pixel and ran out: its float copy of the image alone is 12),
    and the default painter finds the surfaces of a wall on a floor, whose edge it draws across
    the hole first, at that size too (it took a float copy of the whole image and found them at
    full size: 48 bytes per pixel were not enough)."""
    script = tmp_path / "bounded.py"
    script.write_text(_BOUNDED_SCRIPT)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    args = [str(h), str(w), str(budget), painter]
    done = subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    assert float(done.stdout) > 20  # a texture was copied in, not a flat colour


def test_out_of_memory_is_one_line_with_its_own_exit_status_and_writes_nothing(tmp_path, monkeypatch, capsys):
    from geofill import cli, pipeline
    from geofill.errors import EXIT_OUT_OF_MEMORY

    img = _checks(240, 320)
    mask = np.zeros((240, 320), np.uint8)
    mask[80:160, 100:220] = 255
    for name, pixels in (("t.png", img), ("s.png", img), ("m.png", mask)):
        cv2.imwrite(str(tmp_path / name), pixels)

    def exhausted(*args, **kwargs):
        raise MemoryError("Unable to allocate 196. MiB for an array with shape (25690112,)")

    monkeypatch.setattr(pipeline, "fill_loaded", exhausted)
    out = tmp_path / "out.png"
    argv = ["fill", "--target", str(tmp_path / "t.png"), "--mask", str(tmp_path / "m.png")]
    code = cli.main([*argv, "--source", str(tmp_path / "s.png"), "-o", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == EXIT_OUT_OF_MEMORY == 8
    assert err == (
        "geofill: error: out of memory: Unable to allocate 196. MiB for an array with shape (25690112,); "
        "nothing was written"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.png", "s.png", "t.png"]


def _wall_and_floor(h: int = 240, w: int = 320) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A brick wall above a tiled floor, both planes seen in perspective (homographies of
    fronto-parallel textures), meeting along a slanted straight line: the image, the floor's
    pixels and the meeting line's row per column."""
    yy, xx = np.mgrid[0:400, 0:600]
    brick = ((yy % 12) >= 2) & (((xx + 13 * ((yy // 12) % 2)) % 26) >= 2)
    wall = np.where(brick[..., None], [170, 70, 50], [200, 190, 180]).astype(np.float32)
    floor = np.where(((xx // 20 + yy // 20) % 2)[..., None] == 1, [60, 90, 140], [150, 170, 200]).astype(
        np.float32
    )

    def line(x):
        return 130 + 0.15 * (x - w / 2)

    square = np.float32([[0, 0], [600, 0], [600, 400], [0, 400]])
    left, right = (-0.2 * w, line(-0.2 * w)), (1.2 * w, line(1.2 * w))
    to_floor = np.float32([left, right, [2.5 * w, 2 * h], [-1.5 * w, 2 * h]])
    to_wall = np.float32([[left[0], left[1] - 260], [right[0], right[1] - 200], right, left])
    floor_img = cv2.warpPerspective(
        floor, cv2.getPerspectiveTransform(square, to_floor), (w, h), flags=cv2.INTER_AREA
    )
    wall_img = cv2.warpPerspective(
        wall, cv2.getPerspectiveTransform(square, to_wall), (w, h), flags=cv2.INTER_AREA
    )
    rows, cols = np.mgrid[0:h, 0:w]
    on_floor = rows >= line(cols)
    img = np.where(on_floor[..., None], floor_img, wall_img)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), on_floor, line(np.arange(w))


@pytest.mark.parametrize("sigma", [0.0, 4.0])
def test_wall_and_floor_are_each_filled_from_themselves_and_their_meeting_line_continues(sigma):
    """A hole across the line where a brick wall meets a tiled floor: no hole pixel more than 3 px
    from the line takes the other surface's colours (the old painter put 120-144 there: wall
    smeared onto the floor), and the line runs on within 2 px of where it is (old: 4-7 px off)."""
    img, on_floor, line = _wall_and_floor()
    h, w = on_floor.shape
    hole = _disc(h, w, 130, 160, 50)
    blank = img.copy()
    blank[hole] = 0
    out = complete(blank, hole, ExemplarSettings(structure_sigma=sigma))
    wallish = out[..., 0].astype(int) > out[..., 2]  # bricks and mortar are red over blue, tiles not
    rows, cols = np.mgrid[0:h, 0:w]
    far = np.abs(rows - line[cols]) > 3
    assert (hole & far & (wallish == on_floor)).sum() == 0
    through = np.arange(120, 201, 10)
    first_floor = np.array([60 + np.flatnonzero(~wallish[60:200, c])[0] for c in through])
    assert np.abs(first_floor - line[through]).max() <= 2.0, first_floor - line[through]
    np.testing.assert_array_equal(out[~hole], blank[~hole])


def test_what_the_hole_shows_does_not_change_the_painted_pixels():
    """The hole's own pixels (in a removal: the object) never reach the painter: a hole blanked and
    the same hole showing a bright object give the same bytes (the surfaces' texture measure read
    the ring's first pixel row through its 3x3 Laplacian, so a red object moved the surfaces)."""
    img, _, _ = _wall_and_floor()
    h, w = img.shape[:2]
    hole = _disc(h, w, 130, 160, 50)
    blank, shown = img.copy(), img.copy()
    blank[hole] = 0
    shown[hole] = (255, 0, 0)
    np.testing.assert_array_equal(complete(blank, hole), complete(shown, hole))


def test_a_surface_on_both_sides_of_a_meeting_line_takes_the_side_the_other_one_leaves():
    """Where two surfaces meet along a line across the hole, each takes its side of it. A shadow
    band above a kerb with 60 % of its ring pixels near the kerb below it (stains on the road) and a
    road wholly below: the band goes above. Its median alone put it below and the road above, up
    the wall (the Lund street's cobbles climbing the yellow wall). A clear split is left as its
    median says."""
    labels = np.repeat([1, 2], 100)
    near = np.ones(200, bool)
    band_and_road = np.concatenate([np.full(40, -3.0), np.full(60, 4.0), np.full(100, 5.0)])
    assert surfaces._side(band_and_road, near, labels, 1, 2) == -1.0
    assert surfaces._side(band_and_road, near, labels, 2, 1) == 1.0
    # Both surfaces spread over both sides: the median decides, as before.
    mixed = np.concatenate([np.full(40, -3.0), np.full(60, 4.0), np.full(30, -5.0), np.full(70, 5.0)])
    assert surfaces._side(mixed, near, labels, 1, 2) == 1.0
    clean = np.concatenate([np.full(100, -3.0), np.full(100, 5.0)])
    assert surfaces._side(clean, near, labels, 1, 2) == -1.0
    assert surfaces._side(clean, near, labels, 2, 1) == 1.0
