"""Refinement and merge with known answers: membrane fill, colour models, residual flow, feathered
merge, LaMa ONNX wrapper (with a self-built tiny ONNX network), and the untouched outside of the hole."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from geofill.camera import Intrinsics
from geofill.composite.inpaint import LAMA_WEIGHTS, Inpainter, get_inpainter, inpaint_single
from geofill.composite.lama import crop_window
from geofill.composite.merge import blend_map, merge_fill
from geofill.config import FillConfig, InpaintConfig, RefineConfig
from geofill.errors import InpaintModelError
from geofill.evaluation.metrics import psnr
from geofill.pipeline import fill
from geofill.refine import (
    apply_colour_gain,
    fit_colour_gain,
    poisson_field,
    refine_render,
    robust_band_weights,
    smooth_gain_field,
)
from geofill.render import render_mesh
from geofill.synthetic import make_pair
from geofill.utils.membrane import _solve, membrane_fill


@pytest.fixture(scope="module")
def pair():
    return make_pair(seed=0, width=320, height=240)


def _ring(hole: np.ndarray, width: float) -> np.ndarray:
    dist = cv2.distanceTransform((~hole).astype(np.uint8), cv2.DIST_L2, 3)
    return (dist <= width) & ~hole


# --- membrane fill --------------------------------------------------------------------------------


def test_membrane_fill_reproduces_linear_fields_and_keeps_known_values():
    h, w = 90, 120
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    field = np.dstack([0.5 + 0.01 * xx - 0.02 * yy, -3.0 + 0.05 * yy])
    hole = (xx - 60) ** 2 / 40**2 + (yy - 45) ** 2 / 25**2 < 1
    noisy = field.copy()
    noisy[hole] = 99.0  # must not be read
    out = membrane_fill(noisy, ~hole)
    assert np.abs(out - field)[hole].max() < 1e-4  # harmonic => exact for linear fields
    assert np.array_equal(out[~hole], field[~hole])
    coarse = membrane_fill(noisy, ~hole, max_unknowns=500)  # solved on a grid 3x coarser
    # Partly known blocks are known at their mean: off by up to a block (3 px) at 0.05 per px.
    assert np.abs(coarse - field)[hole].max() < 0.15


def test_membrane_fill_domain_and_unreachable_regions():
    values = np.full((40, 60), 2.0, np.float32)
    known = np.zeros((40, 60), bool)
    known[:, :5] = True
    domain = np.zeros((40, 60), bool)
    domain[:, :30] = True
    domain[:, 40:] = True  # a second region touching no known pixel
    out = membrane_fill(np.where(known, 1.0, 0.0), known, domain, fallback=-7.0)
    assert np.allclose(out[:, 5:30], 1.0, atol=1e-4)  # a free edge: constant extension
    assert np.allclose(out[:, 40:], -7.0, atol=1e-3)  # no known pixel in reach: fallback
    assert np.array_equal(out[:, 30:40], np.zeros((40, 10)))  # outside the domain: untouched
    assert values.shape == out.shape


def _sparse_lu_solve(field, known, unknown, fallback, tikhonov=1e-9):
    """The masked Laplace system solved with SciPy's SuperLU (what membrane.py did before its
    multigrid-preconditioned CG): a reference."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    h, w, c = field.shape
    idx = np.full((h + 2, w + 2), -1)
    ys, xs = np.nonzero(unknown)
    n = ys.size
    idx[ys + 1, xs + 1] = np.arange(n)
    kn = np.zeros((h + 2, w + 2), bool)
    kn[1:-1, 1:-1] = known
    padded = np.zeros((h + 2, w + 2, c))
    padded[1:-1, 1:-1] = field
    degree, rhs = np.full(n, tikhonov), np.tile(tikhonov * fallback, (n, 1))
    rows, cols = [], []
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        ny, nx = ys + 1 + dy, xs + 1 + dx
        nb = idx[ny, nx]
        degree += (nb >= 0) | kn[ny, nx]
        rows.append(np.flatnonzero(nb >= 0))
        cols.append(nb[nb >= 0])
        rhs[kn[ny, nx]] += padded[ny[kn[ny, nx]], nx[kn[ny, nx]]]
    r, cc = np.concatenate(rows), np.concatenate(cols)
    A = sp.csc_matrix(
        (np.concatenate([degree, -np.ones(r.size)]), (np.r_[np.arange(n), r], np.r_[np.arange(n), cc])),
        (n, n),
    )
    out = np.zeros_like(field)
    out[ys, xs] = spla.splu(A).solve(rhs)
    return out


def test_membrane_solve_matches_a_sparse_direct_solve():
    # Irregular unknowns on a 3-channel field: blobs touching the image edge, a thin corridor, an
    # island of known pixels inside a hole, a region cut off from every known pixel, and holes in
    # the domain (pixels neither known nor unknown: free edges).
    rng = np.random.default_rng(0)
    h, w = 150, 200
    yy, xx = np.mgrid[0:h, 0:w]
    field = cv2.GaussianBlur(rng.normal(0.0, 1.0, (h, w, 3)).astype(np.float32), (0, 0), 6) * 20 + 0.5
    unknown = ((xx - 60) ** 2 / 50**2 + (yy - 70) ** 2 / 45**2 < 1) | (
        (xx - 170) ** 2 + (yy - 10) ** 2 < 30**2
    )
    unknown |= (np.abs(yy - 120) <= 1) & (xx > 20) & (xx < 190)
    unknown &= ~((xx - 60) ** 2 + (yy - 70) ** 2 < 6**2)
    outside = ((xx - 40) ** 2 + (yy - 40) ** 2 < 8**2) | ((xx > 130) & (xx < 140) & (yy > 40) & (yy < 100))
    unknown &= ~outside
    cut_off = (xx > 100) & (xx < 125) & (yy > 135)
    known = ~unknown & ~outside & ~cut_off & ~((xx > 95) & (xx < 130) & (yy > 130))
    unknown |= cut_off
    fallback = np.array([1.0, -2.0, 3.0], np.float32)
    ours = _solve(field, known, unknown, fallback)
    ref = _sparse_lu_solve(field, known, unknown, fallback)
    assert np.abs(ours - ref)[unknown].max() < 1e-4 * np.ptp(ref[unknown & ~cut_off])
    assert np.allclose(ours[cut_off], fallback, atol=1e-6)
    # Few unknowns: the finest grid is the coarsest, solved directly.
    small = (xx - 60) ** 2 + (yy - 70) ** 2 < 5**2
    ours, ref = _solve(field, ~small, small, fallback), _sparse_lu_solve(field, ~small, small, fallback)
    assert np.abs(ours - ref)[small].max() < 1e-5


def test_scattered_regions_solved_apart_match_a_sparse_direct_solve():
    # Small regions of unknowns scattered over a large field (what a render leaves uncovered across
    # a hole) are solved each on its own box: the answer is still the whole system's.
    rng = np.random.default_rng(1)
    h, w = 240, 320
    yy, xx = np.mgrid[0:h, 0:w]
    field = cv2.GaussianBlur(rng.normal(0.0, 1.0, (h, w, 3)).astype(np.float32), (0, 0), 5) * 20
    unknown = np.zeros((h, w), bool)
    for cy, cx, r in ((12, 15, 9), (200, 300, 14), (120, 160, 6), (230, 20, 8), (40, 290, 3)):
        unknown |= (yy - cy) ** 2 + (xx - cx) ** 2 < r**2
    unknown |= (np.abs(yy - 80) <= 1) & (xx > 60) & (xx < 70)  # a crack
    known = ~unknown
    fallback = np.zeros(3, np.float32)
    ours = _solve(field, known, unknown, fallback)
    ref = _sparse_lu_solve(field, known, unknown, fallback)
    assert np.abs(ours - ref)[unknown].max() < 1e-4 * np.ptp(ref[unknown])
    assert np.array_equal(ours[known], np.zeros_like(ours[known]))


# --- colour models --------------------------------------------------------------------------------


def test_smooth_gain_recovers_a_known_gain_field(pair):
    """target = g(x) * render + o(y) with a smooth per-channel ramp: the spatially smooth model
    recovers it inside the hole far better than one global gain + offset."""
    render, hole = pair.target, pair.hole
    h, w = hole.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    gain = (0.8 + 0.4 * xx / w)[..., None] * np.array([1.0, 0.9, 1.1], np.float32)
    offset = (0.05 * yy / h)[..., None]
    target = np.clip(np.rint((render / 255.0 * gain + offset) * 255.0), 0, 255).astype(np.uint8)
    band = _ring(hole, 16)
    prior = fit_colour_gain(render, target, band)
    weights = robust_band_weights(render, target, band, prior)
    field = smooth_gain_field(render, target, weights, band | hole, 8.0, prior)
    assert np.abs(field.gain - gain)[hole].mean() < 0.02
    p_smooth = psnr(field.apply(render), target, hole)
    p_global = psnr(apply_colour_gain(render, prior), target, hole)
    assert p_smooth > 45.0 and p_smooth > p_global + 8.0
    assert psnr(render, target, hole) < 25.0


def test_poisson_matches_the_border_and_keeps_the_render_gradients(pair):
    """target = render + a linear offset ramp: the exact Poisson blend (no smoothing) reproduces it,
    i.e. the fill meets the target on the border and keeps the render's gradients inside."""
    render, hole = pair.target, pair.hole
    h, w = hole.shape
    xx = np.mgrid[0:h, 0:w][1].astype(np.float32)
    target = np.clip(np.rint((render / 255.0 + 0.1 * xx[..., None] / w - 0.05) * 255), 0, 255).astype(
        np.uint8
    )
    band = _ring(hole, 8)
    inner = hole & ~cv2.erode(hole.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    clipped = (target == 0) | (target == 255)
    ok = ~clipped.any(axis=2)
    field = poisson_field(
        render, target, band.astype(np.float32), band | hole, 0.0, fit_colour_gain(render, target, band)
    )
    out = field.apply(render).astype(int)
    assert np.abs(out - target)[hole & ok].max() <= 1
    assert np.abs(out - target)[inner & ok].max() <= 1  # the border row meets the target
    grad = np.diff(out.astype(float), axis=1) - np.diff(render.astype(float), axis=1)
    assert np.abs(grad[(hole[:, 1:] & hole[:, :-1]) & ok[:, 1:] & ok[:, :-1]]).mean() < 0.5


# --- residual flow --------------------------------------------------------------------------------


@pytest.mark.parametrize("max_side", [1280, 200])
def test_flow_alignment_repairs_a_slightly_wrong_pose(pair, max_side):
    """Render with the exact depth but the pose turned by 0.4 deg (~1.3 px): the band flow carried
    into the hole brings the hole PSNR up by a clear margin, also when the flow is estimated at a
    lower resolution than the image (``max_side`` 200 for a 320-px image) and applied at full."""
    h, w = pair.hole.shape
    K_s = Intrinsics.from_matrix(pair.K_source, w, h)
    K_t = Intrinsics.from_matrix(pair.K_target, w, h)
    th = np.radians(0.4)
    turn = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    T = pair.T_source_to_target.copy()
    T[:3, :3] = turn @ T[:3, :3]
    rendered = render_mesh(pair.depth_source, K_s, K_t, T, 0.04)
    masked = pair.target.copy()
    masked[pair.hole] = 0
    cfg = RefineConfig(colour="none", max_side=max_side)
    plain = refine_render(masked, pair.hole, pair.source, rendered, replace(cfg, flow=False))
    flowed = refine_render(masked, pair.hole, pair.source, rendered, replace(cfg, flow=True))
    assert flowed.info.flow_applied and 0.5 < flowed.info.flow_median_band_px < 3.0
    both = pair.hole & plain.alpha & flowed.alpha
    assert both.sum() > 0.95 * pair.hole.sum()
    p0, p1 = psnr(plain.image, pair.target, both), psnr(flowed.image, pair.target, both)
    assert p1 > p0 + 2.0, (p0, p1)
    assert flowed.info.band_error_after < 0.7 * flowed.info.band_error_before


def test_colour_correction_in_the_pipeline_fixes_an_exposure_change():
    p = make_pair(seed=1, width=320, height=240, source_gain=1.3)
    # Telea paints the uncovered part (79 % of this hole), so the difference is the colour
    # correction's alone: the exemplar painter's texture adds its own error on this smooth scene.
    base = FillConfig().updated({"refine.flow": False, "inpaint.method": "telea"})
    plain = fill(p.target, p.hole, p.source, base.updated({"refine.colour": "none"}))
    gained = fill(p.target, p.hole, p.source, base)
    assert gained.report.references[0]["refine"]["colour"] == "gain"
    assert psnr(gained.image, p.target, p.hole) > psnr(plain.image, p.target, p.hole) + 3.0


# --- merge ------------------------------------------------------------------------------------------


def test_blend_map_ramps_from_uncovered_regions_and_ignores_cracks():
    hole = np.zeros((60, 80), bool)
    hole[10:50, 10:70] = True
    alpha = np.ones((60, 80), bool)
    alpha[:, 50:] = False  # a large uncovered region
    alpha[30, 20] = False  # a one-pixel crack
    m = blend_map(hole, alpha, 8.0)
    assert m[30, 49] == pytest.approx(1 / 8, abs=0.01) and m[30, 30] == 1.0
    assert m[30, 21] == 1.0 and m[30, 20] == 0.0  # no ramp around the crack
    assert not m[~hole].any() and not m[hole & ~alpha].any()


def test_feathered_merge_leaves_no_seam():
    """The single-image fill disagrees with the render (100 vs 200 grey levels): pasted with hard
    edges the step is 100 levels; with a feathered M_single it is spread over the ramp."""

    def flat(image, region):
        out = image.copy()
        out[region] = 100
        return out

    flat_inpainter = Inpainter("flat", "flat", flat)
    target = np.full((60, 80, 3), 150, np.uint8)
    hole = np.zeros((60, 80), bool)
    hole[10:50, 10:70] = True
    render = np.full_like(target, 200)
    alpha = np.ones((60, 80), bool)
    alpha[:, 45:] = False
    steps = {}
    for feather in (0.0, 10.0):
        out = merge_fill(target, hole, render, alpha, flat_inpainter, feather).astype(int)
        steps[feather] = np.abs(np.diff(out[15:45, 10:70, 0], axis=1)).max()
        assert np.array_equal(out[~hole], target[~hole])
    assert steps[0.0] == 100
    assert steps[10.0] <= 100 / 10 + 1


@pytest.mark.parametrize(
    "overrides",
    [
        {"refine.colour": "none", "refine.flow": False, "refine.feather_px": 0.0},
        {"refine.colour": "global"},
        {"refine.colour": "gain"},
        {"refine.colour": "poisson", "refine.poisson_smooth_px": 0.0},
        {"refine.colour": "poisson", "refine.flow": True, "refine.feather_px": 16.0},
    ],
)
def test_outside_the_hole_is_byte_identical_in_every_path(pair, overrides):
    res = fill(pair.target, pair.hole, pair.source, FillConfig().updated(overrides))
    assert res.report.status == "reference"
    assert np.array_equal(res.image[~pair.hole], pair.target[~pair.hole])


# --- single-image inpainting: LaMa through ONNX Runtime --------------------------------------------


def _tiny_lama(path, size: int = 64, four_channels: bool = False, scale: float = 1.0) -> None:
    """A LaMa-shaped ONNX network whose output encodes where each model pixel is: R = x ramp,
    G = y ramp (0..1 over the model grid), B = the mask it was given; times ``scale``."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    if four_channels:
        inputs = [helper.make_tensor_value_info("input", TensorProto.FLOAT, [1, 4, size, size])]
        nodes = [helper.make_node("Split", ["input", "split"], ["image", "mask"], axis=1)]
        inits = [numpy_helper.from_array(np.array([3, 1], np.int64), "split")]
    else:
        inputs = [
            helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, size, size]),
            helper.make_tensor_value_info("mask", TensorProto.FLOAT, [1, 1, size, size]),
        ]
        nodes, inits = [], []
    ramp = np.arange(size, dtype=np.float32) / (size - 1)
    inits += [
        numpy_helper.from_array(np.tile(ramp[None, :], (size, 1))[None, None].copy(), "rx"),
        numpy_helper.from_array(np.tile(ramp[:, None], (1, size))[None, None].copy(), "ry"),
        numpy_helper.from_array(np.array(scale, np.float32), "s"),
    ]
    nodes += [
        helper.make_node("Concat", ["rx", "ry", "mask"], ["cat"], axis=1),
        helper.make_node("Mul", ["cat", "s"], ["output"]),
    ]
    out = helper.make_tensor_value_info("output", TensorProto.FLOAT, [1, 3, size, size])
    graph = helper.make_graph(nodes, "tiny_lama", inputs, [out], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8)
    onnx.checker.check_model(model)
    onnx.save(model, str(path))


@pytest.mark.needs("onnx", "onnxruntime")
@pytest.mark.parametrize(("four_channels", "scale"), [(False, 1.0), (True, 255.0)])
def test_lama_wrapper_crops_resizes_and_pastes_only_in_the_hole(tmp_path, four_channels, scale):
    path = tmp_path / "tiny_lama.onnx"
    _tiny_lama(path, four_channels=four_channels, scale=scale)
    inp = get_inpainter(InpaintConfig(method="lama", lama_model=str(path)))
    assert inp.name == "lama"
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (200, 300, 3), dtype=np.uint8)
    hole = np.zeros((200, 300), bool)
    hole[80:110, 120:170] = True
    hole[100:140, 160:175] = True
    out = inpaint_single(image, hole, InpaintConfig(method="lama", lama_model=str(path)))
    assert np.array_equal(out[~hole], image[~hole])
    x0, y0, x1, y1 = crop_window(hole, (64, 64))
    assert x1 - x0 == y1 - y0 and x0 <= 120 and x1 >= 175 and y0 <= 80 and y1 >= 140
    ys, xs = np.nonzero(hole)
    # Each hole pixel holds the model-grid coordinate it was resized from (pixel-centre mapping).
    ex = ((xs - x0 + 0.5) * 64 / (x1 - x0) - 0.5) / 63 * 255
    ey = ((ys - y0 + 0.5) * 64 / (y1 - y0) - 0.5) / 63 * 255
    assert np.abs(out[ys, xs, 0] - ex).max() < 1.5
    assert np.abs(out[ys, xs, 1] - ey).max() < 1.5
    assert out[ys, xs, 2].min() > 127  # every hole pixel was a hole for the model


@pytest.mark.needs("onnxruntime")
def test_auto_inpainting_falls_back_to_exemplar_and_says_why(monkeypatch, tmp_path):
    monkeypatch.setenv("GEOFILL_CACHE", str(tmp_path / "cache"))
    inp = get_inpainter(InpaintConfig(method="auto"))  # conftest: offline, nothing cached
    assert inp.name == "exemplar" and "LaMa (ONNX) weights not available" in inp.description
    assert "HF_HUB_OFFLINE" in inp.description
    with pytest.raises(InpaintModelError, match="not available"):
        get_inpainter(InpaintConfig(method="lama"))
    model = tmp_path / "tiny.onnx"
    _tiny_lama(model)
    monkeypatch.setenv(LAMA_WEIGHTS.env_var, str(model))
    assert get_inpainter(InpaintConfig(method="auto")).name == "lama"
    broken = tmp_path / "broken.onnx"
    broken.write_bytes(b"not a model")
    monkeypatch.setenv(LAMA_WEIGHTS.env_var, str(broken))
    inp = get_inpainter(InpaintConfig(method="auto"))
    assert inp.name == "exemplar" and "could not be loaded" in inp.description
    with pytest.raises(InpaintModelError, match="could not be loaded"):  # asked for explicitly
        get_inpainter(InpaintConfig(method="auto", lama_model=str(broken)))


@pytest.mark.needs("onnx", "onnxruntime")
def test_lama_model_resolves_from_the_cache(monkeypatch, tmp_path):
    """The same resolution as the depth networks: a model already in geofill's cache is used."""
    monkeypatch.setenv("GEOFILL_CACHE", str(tmp_path))
    monkeypatch.delenv(LAMA_WEIGHTS.env_var, raising=False)
    cached = LAMA_WEIGHTS.cache_path(tmp_path)
    cached.parent.mkdir(parents=True)
    _tiny_lama(cached)
    inp = get_inpainter(InpaintConfig(method="auto"))
    assert inp.name == "lama" and "from cache" in inp.description and str(cached) in inp.description


def test_pipeline_reports_refinement_and_the_inpainter(pair, monkeypatch, tmp_path):
    monkeypatch.setenv("GEOFILL_CACHE", str(tmp_path))
    res = fill(pair.target, pair.hole, pair.source)
    r = res.report
    assert r.inpaint_method.startswith("exemplar (auto:")
    refine = r.references[0]["refine"]
    assert refine["flow_applied"] and refine["colour"] == "gain"
    assert refine["band_error_after"] < refine["band_error_before"]
    assert "refine" in r.timings_s


@pytest.mark.parametrize(("h", "w"), [(17, 101), (101, 17), (24, 300), (10, 10), (1, 50)])
def test_band_flow_on_thin_and_tiny_windows(h, w):
    """OpenCV's DIS crashed (segfault) on thin strips such as the 17 x 101 render window of a thin
    hole, and raised on tiny ones; the padded flow measures the shift there too."""
    from geofill.utils.residual_flow import band_flow

    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.integers(0, 256, (h, w + 2, 3), dtype=np.uint8), (0, 0), 1.0)
    target, render = np.ascontiguousarray(texture[:, 1:-1]), np.ascontiguousarray(texture[:, 2:])
    hole = np.zeros((h, w), bool)
    hole[h // 2, w // 2] = True
    got = band_flow(render, target, hole, ~hole, max_px=5.0, consistency_px=1.0)
    if h * w >= 500:  # enough trusted vectors: the shift of one pixel to the left is found
        assert got is not None and got.flow.shape == (h, w, 2)
        assert abs(float(np.median(got.flow[~hole][:, 0])) + 1.0) < 0.35
