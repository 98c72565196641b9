"""Mesh rendering with known geometry: shifts, occlusion, disocclusion, footprint edge cuts, and a
ray-cast synthetic scene rendered with its exact depth and pose."""

from __future__ import annotations

import logging
import os
import stat
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import cv2
import numba
import numpy as np
import pytest

import geofill.render as render_module
import geofill.utils.jit as jit
from geofill.camera import Intrinsics, make_pose
from geofill.evaluation.metrics import psnr
from geofill.render import project_source_grid, render_mesh, render_roi, triangle_masks
from geofill.synthetic import depth_edges, make_pair
from geofill.utils.jit import njit_cached

K = Intrinsics.from_focal(300.0, 160, 120)


def test_fronto_parallel_plane_shifts_by_disparity():
    depth = np.full((120, 160), 10.0, np.float32)
    T = make_pose(np.eye(3), [0.2, 0.0, 0.0])  # disparity f * b / z = 300 * 0.2 / 10 = 6 px
    r = render_mesh(depth, K, K, T, 0.04)
    assert r.alpha[:, 7:159].all() and not r.alpha[:, :5].any()  # left strip has no source
    assert np.abs(r.map_x[:, 10:150] - (np.arange(10, 150)[None] - 6.0)).max() < 1e-4
    np.testing.assert_allclose(r.map_y[5:115, 10], np.arange(5, 115), atol=1e-4)
    assert np.abs(r.depth[r.alpha] - 10.0).max() < 1e-5


def test_slanted_plane_is_perspective_correct():
    """A plane z = 5 + 0.05 x_cam rendered after a rotation: every rendered pixel's source coordinate
    must back-project to the same 3D point as the target ray (exact, not affine interpolation)."""
    jj = np.arange(160, dtype=np.float64)[None].repeat(120, 0)
    n = (jj - K.cx) / K.fx
    z = (5.0 / (1.0 - 0.05 * n)).astype(np.float32)  # z = 5 + 0.05 X with X = n z
    th = np.radians(3.0)
    R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    T = make_pose(R, [0.3, 0.0, 0.2])
    r = render_mesh(z, K, K, T, 0.04)
    ys, xs = np.nonzero(r.alpha)
    # Back-project the rendered source coordinate, transform, and project: must land on (x, y).
    ns = (r.map_x[ys, xs] - K.cx) / K.fx
    zs = 5.0 / (1.0 - 0.05 * ns)
    X = np.stack([ns * zs, (r.map_y[ys, xs] - K.cy) / K.fy * zs, zs], axis=1) @ R.T + T[:3, 3]
    u = K.fx * X[:, 0] / X[:, 2] + K.cx
    v = K.fy * X[:, 1] / X[:, 2] + K.cy
    assert r.alpha.mean() > 0.6
    assert np.abs(u - xs).max() < 1e-3 and np.abs(v - ys).max() < 1e-3


def test_nearer_surface_wins_and_disocclusion_is_marked():
    depth = np.full((120, 160), 20.0, np.float32)
    depth[40:80, 60:100] = 5.0  # a box in front of a wall
    T = make_pose(np.eye(3), [0.5, 0.0, 0.0])  # box moves 30 px right, wall 7.5 px
    r = render_mesh(depth, K, K, T, 0.04)
    # Box pixels land 30 px right and occlude the wall there.
    assert np.abs(r.depth[50:70, 95:125] - 5.0).max() < 1e-4
    assert np.abs(r.map_x[60, 95:125] - (np.arange(95, 125) - 30.0)).max() < 1e-4
    # Left of the box's new position the wall was hidden behind the box in the source: no data.
    assert not r.alpha[50:70, 70:88].any()
    assert np.abs(r.depth[60, 135:159] - 20.0).max() < 1e-4
    assert r.alpha[60, 135:159].all()


def test_footprint_test_cuts_only_discontinuities():
    depth = np.full((10, 10), 10.0, np.float32)
    depth[:, 5:] = 10.3  # 3 % step: kept at eps=0.04
    a, b = triangle_masks(depth, 0.04)
    assert a.all() and b.all()
    depth[:, 5:] = 11.0  # 9.5 % step: cut
    a, b = triangle_masks(depth, 0.04)
    assert not a[:, 4].any() and not b[:, 4].any()
    assert a[:, :4].all() and a[:, 5:].all()
    depth[3, 3] = np.nan  # invalid depth removes its triangles
    a, _ = triangle_masks(depth, 0.04)
    assert not a[3, 3] and not a[2, 3]


def test_roi_limits_rasterisation():
    depth = np.full((120, 160), 10.0, np.float32)
    r = render_mesh(depth, K, K, np.eye(4), 0.04, roi=(20, 30, 60, 70))
    assert r.alpha[30:70, 20:60].all()
    assert r.alpha.sum() == 40 * 40


def test_ray_cast_scene_with_exact_depth_and_pose_reproduces_the_target():
    """Analytic synthetic scene: the source's exact depth and the exact pose must render the target's
    geometry (its ray-cast depth, and the source pixel every target ray hits) and its hole."""
    p = make_pair(seed=3, width=320, height=240)
    h, w = p.depth_target.shape
    K_s = Intrinsics.from_matrix(p.K_source, w, h)
    K_t = Intrinsics.from_matrix(p.K_target, w, h)
    r = render_mesh(p.depth_source, K_s, K_t, p.T_source_to_target, 0.04)
    # Where each target pixel's surface point lands in the source (exact, from the target's depth).
    jj, ii = np.meshgrid(np.arange(w), np.arange(h))
    z = p.depth_target.astype(np.float64)
    X = np.stack([(jj - K_t.cx) / K_t.fx * z, (ii - K_t.cy) / K_t.fy * z, z], axis=-1)
    T_inv = np.linalg.inv(p.T_source_to_target)
    Xs = X @ T_inv[:3, :3].T + T_inv[:3, 3]
    u = K_s.fx * Xs[..., 0] / Xs[..., 2] + K_s.cx
    v = K_s.fy * Xs[..., 1] / Xs[..., 2] + K_s.cy
    # Mesh triangles lie exactly on planar faces; away from depth edges and creases the field is exact.
    edges = depth_edges(p.depth_target, 0.01).astype(np.uint8)
    smooth = r.alpha & ~cv2.dilate(edges, np.ones((5, 5), np.uint8)).astype(bool)
    assert smooth.mean() > 0.4
    err = np.hypot(r.map_x - u, r.map_y - v)[smooth]
    assert np.percentile(err, 99) < 0.01 and err.max() < 0.1
    assert np.abs(r.depth / z - 1.0)[smooth].max() < 2e-3
    covered = p.hole & r.alpha
    assert covered.sum() > 0.95 * p.hole.sum()
    assert psnr(r.sample(p.source), p.target, covered) > 30.0


def test_render_buffers_are_float32_and_empty_outside_the_roi():
    depth = np.full((120, 160), 10.0, np.float32)
    r = render_mesh(depth, K, K, make_pose(np.eye(3), [0.1, 0.0, 0.0]), 0.04, roi=(20, 30, 60, 70))
    assert r.map_x.dtype == r.map_y.dtype == r.depth.dtype == np.float32
    assert r.roi == (20, 30, 60, 70)
    outside = np.ones((120, 160), bool)
    outside[30:70, 20:60] = False
    assert not r.alpha[outside].any() and np.all(r.map_x[outside] == -1.0)
    assert np.isinf(r.depth[outside]).all()
    sampled = r.sample(np.full((120, 160, 3), 77, np.uint8))
    assert (sampled[30:70, 20:60] == 77).all() and not sampled[outside].any()


def _scene_render_inputs(seed: int = 3, width: int = 320, height: int = 240):
    p = make_pair(seed=seed, width=width, height=height)
    K_s = Intrinsics.from_matrix(p.K_source, width, height)
    K_t = Intrinsics.from_matrix(p.K_target, width, height)
    return p, K_s, K_t


def test_tile_culling_renders_the_same_field_as_the_whole_grid(monkeypatch):
    """Only the source tiles that can reach the ROI are rasterised; one tile spanning the whole grid
    (nothing culled) must give the identical buffers, bit for bit, with some vertices invalid."""
    p, K_s, K_t = _scene_render_inputs()
    depth = p.depth_source.copy()
    depth[100:130, 40:90] = np.nan  # no surface there
    roi = render_roi(p.hole, 12)
    culled = render_mesh(depth, K_s, K_t, p.T_source_to_target, 0.04, roi)
    monkeypatch.setattr(render_module, "_TILE", 4096)
    whole = render_mesh(depth, K_s, K_t, p.T_source_to_target, 0.04, roi)
    assert culled.alpha.sum() > 0.9 * p.hole.sum()
    for name in ("map_x", "map_y", "depth", "alpha"):
        np.testing.assert_array_equal(getattr(culled, name), getattr(whole, name))


def test_roi_window_equals_the_whole_view_render_there():
    p, K_s, K_t = _scene_render_inputs(seed=5)
    roi = render_roi(p.hole, 8)
    x0, y0, x1, y1 = roi
    part = render_mesh(p.depth_source, K_s, K_t, p.T_source_to_target, 0.04, roi)
    whole = render_mesh(p.depth_source, K_s, K_t, p.T_source_to_target, 0.04)
    for name in ("map_x", "map_y", "depth"):
        np.testing.assert_array_equal(getattr(part, name)[y0:y1, x0:x1], getattr(whole, name)[y0:y1, x0:x1])


def test_tiles_in_roi_keep_every_tile_with_a_vertex_in_the_roi():
    """The corner bound is conservative (every vertex landing in the ROI is in a kept tile) and
    still drops most of the grid for a hole-sized ROI; a tile reaching behind the target camera is
    kept."""
    p, K_s, K_t = _scene_render_inputs()
    roi = render_roi(p.hole, 12)
    tile = 16
    kept = render_module._tiles_in_roi(p.depth_source, K_s, K_t, p.T_source_to_target, roi, tile)
    u, v, _ = project_source_grid(p.depth_source, K_s, K_t, p.T_source_to_target)
    x0, y0, x1, y1 = roi
    inside = (u > x0 - 1) & (u < x1) & (v > y0 - 1) & (v < y1)
    ii, jj = np.nonzero(inside[:-1, :-1])  # quad corners; their quads' tiles must be kept
    assert kept[ii // tile, jj // tile].all()
    assert kept.mean() < 0.6
    # A pose that puts the left part of the scene behind the target camera.
    T = make_pose(np.eye(3), [12.0, 0.0, 0.0]) @ make_pose(
        cv2.Rodrigues(np.array([0.0, np.pi / 2, 0.0]))[0], [0.0, 0.0, 0.0]
    )
    behind = render_module._tiles_in_roi(p.depth_source, K_s, K_t, T, roi, tile)
    _, _, z = project_source_grid(p.depth_source, K_s, K_t, T)
    ii, jj = np.nonzero(z[:-1, :-1] <= 0)
    assert ii.size and behind[ii // tile, jj // tile].all()


def _add_three(x):
    return x + 3


def _add_four(x):
    return x + 4


@pytest.fixture
def numba_cache_config(monkeypatch, tmp_path):
    """numba's cache settings restored after the test; the temp folder a fresh ``tmp_path``."""
    monkeypatch.setattr(numba.config, "CACHE_DIR", "")
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(jit, "_NO_CACHE_SAID", [])
    return tmp_path


def test_njit_cached_keeps_compiled_code_in_a_private_temp_folder_when_home_is_not_writable(
    monkeypatch, numba_cache_config
):
    """No NUMBA_CACHE_DIR, no writable __pycache__ and no writable home (a read-only install run
    by a user without a home): the kernels are cached in the user's own temp folder, made private,
    with no warning."""
    from numba.core import caching

    for locator in (caching.InTreeCacheLocator, caching.UserWideCacheLocator):
        monkeypatch.setattr(locator, "from_function", classmethod(lambda cls, fn, path: None))
    add = njit_cached()(_add_three)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert add(4) == 7  # numba builds the kernel on its first use
    folder = numba_cache_config / f"geofill-numba-{os.getuid()}"
    assert add._cache.__class__.__name__ == "FunctionCache"
    assert Path(add._cache.cache_path).is_relative_to(folder)
    assert stat.S_IMODE(folder.stat().st_mode) == 0o700
    assert any(folder.rglob("*.nbi"))  # the index numba reads back in the next process


def test_njit_cached_compiles_in_memory_and_says_so_once_when_no_folder_is_writable(
    monkeypatch, numba_cache_config, caplog
):
    # Only the IPython locator, which never serves a file-backed function: numba finds no cache
    # folder at all, the temp one included.
    monkeypatch.setattr(numba.config, "CACHE_LOCATOR_CLASSES", "IPythonCacheLocator")
    kernels = njit_cached()(_add_three), njit_cached()(_add_four)
    with warnings.catch_warnings(), caplog.at_level(logging.WARNING, logger="geofill"):
        warnings.simplefilter("error")
        assert [k(4) for k in kernels] == [7, 8]
    assert [k._cache.__class__.__name__ for k in kernels] == ["NullCache"] * 2
    (said,) = [r.getMessage() for r in caplog.records]
    assert said.startswith("geofill: note: numba found no writable folder") and "NUMBA_CACHE_DIR" in said


def test_private_temp_folder_refuses_a_folder_others_may_write_or_a_link(numba_cache_config):
    folder = numba_cache_config / f"geofill-numba-{os.getuid()}"
    folder.mkdir(mode=0o777)
    folder.chmod(0o777)  # another user could plant pickles numba would load
    assert jit.private_temp_folder("geofill-numba") is None
    folder.rmdir()
    (numba_cache_config / "elsewhere").mkdir(mode=0o700)
    folder.symlink_to(numba_cache_config / "elsewhere")
    assert jit.private_temp_folder("geofill-numba") is None
    folder.unlink()
    assert jit.private_temp_folder("geofill-numba") == folder


def test_njit_cached_uses_the_disk_cache_where_writable():
    add = njit_cached()(_add_three)
    assert add(4) == 7
    assert add._cache.__class__.__name__ == "FunctionCache"


def test_numba_starts_on_first_use_or_in_the_background():
    """Importing the pipeline does not import numba (0.4 s of every process); ``warm_up`` starts it
    in a thread, and a kernel calling an inlined kernel of its module still compiles."""
    code = (
        "import sys, geofill.pipeline, geofill.utils.jit as jit\n"
        "before = 'numba' in sys.modules\n"
        "jit.warm_up(); jit._WARM_UP[0].join()\n"
        "import geofill.render as r\n"
        "print(before, 'numba' in sys.modules, type(r._raster_triangle).__name__)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "True", "Kernel"]
    depth = np.full((120, 160), 5.0, np.float32)
    r = render_mesh(depth, K, K, make_pose(np.eye(3), [0.1, 0.0, 0.0]), 0.04)
    assert r.alpha.any()
    assert type(render_module._raster_triangle).__name__ == "CPUDispatcher"  # replaced on first use


def test_a_cut_object_reveals_the_background_it_hid_from_the_target():
    """A box (depth 5) in front of a wall (depth 20): rendered into a target 0.5 units to the side,
    the box hides wall pixels the source sees. Left out of the mesh, the box no longer hides them."""
    from geofill.config import RenderConfig
    from geofill.optimize.stage import Geometry
    from geofill.render import render_reference

    depth = np.full((120, 160), 20.0, np.float32)
    depth[40:80, 60:100] = 5.0
    T = make_pose(np.eye(3), [0.5, 0.0, 0.0])  # box moves 30 px right, wall 7.5 px
    geometry = Geometry(T, K, K, depth)
    source = np.random.default_rng(0).integers(0, 256, (120, 160, 3), dtype=np.uint8)
    hole = np.zeros((120, 160), bool)
    hole[40:80, 90:130] = True  # the box's place in the target
    box = np.zeros((120, 160), bool)
    box[40:80, 60:100] = True
    kept = render_reference(geometry, source, hole, RenderConfig(), 0.0).render
    cut = render_reference(geometry, source, hole, RenderConfig(), 0.0, box).render
    assert np.abs(kept.depth[50:70, 95:125] - 5.0).max() < 1e-4  # the box's own surface
    # Target x >= 107.5 sees the wall at source x >= 100, right of the box, visible in the source.
    assert np.abs(cut.depth[50:70, 110:128] - 20.0).max() < 1e-4
    assert np.abs(cut.map_x[60, 110:128] - (np.arange(110, 128) - 7.5)).max() < 1e-4
    # Left of it the wall lies behind the box in the source too: nothing to show.
    assert not cut.alpha[50:70, 92:104].any()


def test_the_object_is_cut_from_the_mesh_with_several_references_by_default():
    """The hole shows what the reference shows there (the object to remove): by default a single
    reference is rendered whole; with "always" the object is located first and left out of the mesh,
    and the screen still counts what it would have shown as refused."""
    from geofill.config import FillConfig
    from geofill.pipeline import fill

    sp = make_pair(seed=0, width=200, height=150)
    whole = fill(sp.target, sp.hole, sp.source)
    cut = fill(sp.target, sp.hole, sp.source, FillConfig().updated({"screen.cut_object": "always"}))
    assert whole.references[0].render.object_seen is None  # located, but not cut
    assert whole.references[0].render.located.located
    located = cut.references[0].render.located
    assert located.located and located.object_px > 0
    seen = cut.references[0].render.object_seen
    # The hole shows the scene itself: what of it stands in front of the ring's surface is the object
    # (about half here), what lies on that surface is background.
    assert seen.sum() > 0.3 * sp.hole.sum()
    assert cut.report.refused_fraction["removed_object"] > 0.3
