"""Evaluation building blocks: brush-stroke masks, metrics, baselines, methods, pairs, runner, CLI."""

from __future__ import annotations

import csv
import hashlib
import json
import math
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import ExifTags, Image
from skimage import data
from skimage.morphology import skeletonize

from geofill.errors import ConfigError, InputError
from geofill.evaluation.baselines import (
    BaselineError,
    homography_fill,
    homography_fill_detailed,
    opencv_inpaint,
)
from geofill.evaluation.cli import main_eval
from geofill.evaluation.masks import (
    DEFAULT_AREA_RANGE,
    brush_stroke_mask,
    brush_strokes,
    mask_seed,
    scaled_stroke_width,
)
from geofill.evaluation.methods import METHODS, MethodOutput, register_method, resolve_methods
from geofill.evaluation.metrics import LPIPS_ENV, load_lpips, lpips_available, psnr, ssim
from geofill.evaluation.pairs import Pair, group_value, load_pairs
from geofill.evaluation.runner import run_eval, sweep
from geofill.evaluation.tables import wins
from geofill.refine import ColourGain, apply_colour_gain, fit_colour_gain

REAL_PAIRS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "pairs"


# ---------------------------------------------------------------------------------------------
# Test scenes


def planar_pair(
    h: int = 240, w: int = 320, *, gain: float = 1.0, offset: float = 0.0, angle_deg: float = 6.0
):
    """Two views of a flat photo: target and source images (HxWx3 uint8) and the true homography
    mapping source pixels to target pixels. The source may get a colour change ``gain * x + offset``."""
    scene = cv2.GaussianBlur(data.astronaut(), (0, 0), 1.0)
    scene_to_target = np.array([[0.75, 0.0, -20.0], [0.0, 0.75, -50.0], [0.0, 0.0, 1.0]])
    a = np.deg2rad(angle_deg)
    # Target pixels -> source pixels: zoom out, rotate and tilt about the image centre.
    tilt = np.array([[0.9 * np.cos(a), -0.9 * np.sin(a), 0.0], [0.9 * np.sin(a), 0.9 * np.cos(a), 0.0]])
    tilt = np.vstack([tilt, [2e-4, 1e-4, 1.0]])
    centre = np.array([[1.0, 0.0, w / 2], [0.0, 1.0, h / 2], [0.0, 0.0, 1.0]])
    target_to_source = centre @ tilt @ np.linalg.inv(centre)
    target = cv2.warpPerspective(scene, scene_to_target, (w, h), flags=cv2.INTER_LINEAR)
    source = cv2.warpPerspective(scene, target_to_source @ scene_to_target, (w, h), flags=cv2.INTER_LINEAR)
    source = np.clip(np.rint(source * gain + offset), 0, 255).astype(np.uint8)
    return target, source, np.linalg.inv(target_to_source)


def planar_pairs(n: int) -> list[Pair]:
    pairs = []
    for i in range(n):
        target, source, _ = planar_pair(angle_deg=4.0 + 3.0 * i)
        pairs.append(Pair(f"planar_{i}", target, [source], {"kind": f"synthetic{i % 2} (planar)"}, None))
    return pairs


def masked(target: np.ndarray, hole: np.ndarray) -> np.ndarray:
    out = target.copy()
    out[hole] = 0
    return out


# ---------------------------------------------------------------------------------------------
# Masks


def test_mask_seed_is_a_fixed_function_of_pair_id_and_seed():
    # SHA-256 based, so this value is the same on every machine and Python process.
    expected = int.from_bytes(hashlib.sha256(b"geofill-mask\x00pair_a\x007").digest()[:8], "little")
    assert mask_seed("pair_a", 7) == expected
    assert len({mask_seed("pair_a", 0), mask_seed("pair_b", 0), mask_seed("pair_a", 1)}) == 3


def test_masks_are_deterministic_and_depend_on_pair_and_seed():
    a = brush_stroke_mask(240, 320, seed=mask_seed("p", 0))
    b = brush_stroke_mask(240, 320, seed=mask_seed("p", 0))
    assert a.dtype == bool and a.shape == (240, 320)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, brush_stroke_mask(240, 320, seed=mask_seed("q", 0)))
    assert not np.array_equal(a, brush_stroke_mask(240, 320, seed=mask_seed("p", 1)))


def test_mask_golden_checksum():
    # Guards cross-machine reproducibility: a change in the generator, NumPy's Generator streams
    # or OpenCV's rasteriser changes every published evaluation mask and must be deliberate.
    hole = brush_stroke_mask(120, 160, seed=mask_seed("golden", 0))
    assert int(hole.sum()) == GOLDEN_MASK_AREA
    assert hashlib.sha256(np.packbits(hole).tobytes()).hexdigest()[:16] == GOLDEN_MASK_SHA


GOLDEN_MASK_AREA = 4635
GOLDEN_MASK_SHA = "45d8a60b8801ba29"


@pytest.mark.parametrize(
    ("h", "w", "n_seeds"), [(64, 64, 20), (240, 320, 20), (376, 1241, 6), (1280, 720, 4), (720, 1280, 4)]
)
def test_mask_area_stays_in_range(h, w, n_seeds):
    lo, hi = DEFAULT_AREA_RANGE
    ratios = [brush_stroke_mask(h, w, seed=mask_seed(f"pair{i}", 0)).mean() for i in range(n_seeds)]
    assert all(lo <= r <= hi for r in ratios), ratios
    assert max(ratios) - min(ratios) > 0.02  # the target area is drawn within the window, not pinned


def test_mask_custom_area_range_and_impossible_request():
    ratios = [brush_stroke_mask(240, 320, seed=s, area_range=(0.02, 0.05)).mean() for s in range(10)]
    assert all(0.02 <= r <= 0.05 for r in ratios), ratios
    with pytest.raises(ValueError, match="brush"):
        brush_stroke_mask(64, 64, seed=0, mean_width_px=200.0)
    with pytest.raises(ValueError, match="area range"):
        brush_stroke_mask(64, 64, seed=0, area_range=(0.3, 0.1))


def test_unconstrained_mask_is_a_partial_hole():
    for s in range(10):
        hole = brush_stroke_mask(240, 320, seed=s, area_range=None)
        assert 0.0 < hole.mean() < 1.0


def _median_brush_width(hole: np.ndarray) -> float:
    """Twice the distance to the hole's border along its skeleton: the local stroke width."""
    dist = cv2.distanceTransform(hole.astype(np.uint8), cv2.DIST_L2, 5)
    return float(np.median(2.0 * dist[skeletonize(hole)]))


def test_default_width_is_150px_at_720p_scaled_with_the_short_side():
    assert scaled_stroke_width(150, 720, 1280) == 150.0
    assert scaled_stroke_width(150, 1280, 720) == 150.0
    assert scaled_stroke_width(150, 240, 320) == 50.0
    # The default is exactly the scaled paper width...
    assert np.array_equal(
        brush_stroke_mask(240, 320, seed=3), brush_stroke_mask(240, 320, seed=3, mean_width_px=50.0)
    )
    # ...and the drawn strokes have about that width (overlaps and joints make them a bit wider).
    for h, w in [(240, 320), (480, 640)]:
        requested = scaled_stroke_width(150, h, w)
        measured = np.mean([_median_brush_width(brush_stroke_mask(h, w, seed=s)) for s in range(8)])
        assert 0.9 * requested < measured < 1.4 * requested, (h, w, requested, measured)


def test_same_hole_shape_at_wider_brush_grows():
    shape = brush_strokes(240, 320, seed=mask_seed("p", 0), mean_width_px=50.0)
    thin, thick = shape.render(30.0), shape.render(70.0)
    assert thin.mean() < shape.render(50.0).mean() < thick.mean()
    assert (thin & thick).sum() / thin.sum() > 0.99  # same centre lines
    assert _median_brush_width(thick) > 1.8 * _median_brush_width(thin)


# ---------------------------------------------------------------------------------------------
# Metrics


def test_psnr_constant_error_matches_hand_value():
    a = np.full((8, 9, 3), 100, np.uint8)
    b = np.full((8, 9, 3), 110, np.uint8)
    assert psnr(a, b) == pytest.approx(20 * math.log10(255 / 10), abs=1e-9)
    assert psnr(a, a) == math.inf


def test_hole_psnr_uses_only_hole_pixels():
    a = np.full((10, 10, 3), 100, np.uint8)
    b = a.copy()
    region = np.zeros((10, 10), bool)
    region[2:5, 3:7] = True  # 12 pixels
    b[region] = 110  # error 10 inside
    b[~region] = 150  # error 50 outside
    assert psnr(a, b, region) == pytest.approx(20 * math.log10(255 / 10), abs=1e-9)
    mse = (12 * 10**2 + 88 * 50**2) / 100
    assert psnr(a, b) == pytest.approx(10 * math.log10(255**2 / mse), abs=1e-9)


def test_ssim_of_constant_images_is_the_luminance_term():
    a = np.full((16, 16, 3), 100, np.uint8)
    b = np.full((16, 16, 3), 110, np.uint8)
    c1 = (0.01 * 255) ** 2
    expected = (2 * 100 * 110 + c1) / (100**2 + 110**2 + c1)  # variances are 0: no contrast/structure term
    assert ssim(a, b) == pytest.approx(expected, abs=1e-6)
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-9)


def test_hole_ssim_averages_the_ssim_map_over_the_hole():
    a = np.full((40, 40, 3), 100, np.uint8)
    b = a.copy()
    b[:, :20] = 110  # left half off by 10, right half exact
    c1 = (0.01 * 255) ** 2
    left = (2 * 100 * 110 + c1) / (100**2 + 110**2 + c1)
    far_left = np.zeros((40, 40), bool)
    far_left[:, :13] = True  # more than the 11x11 window's radius from the edge at column 20
    far_right = np.zeros((40, 40), bool)
    far_right[:, 27:] = True
    assert ssim(a, b, far_left) == pytest.approx(left, abs=1e-6)
    assert ssim(a, b, far_right) == pytest.approx(1.0, abs=1e-6)


def test_ssim_drops_for_structure_changes():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)
    assert ssim(a, 255 - a) < 0.0 < ssim(a, np.clip(a.astype(int) + 5, 0, 255).astype(np.uint8)) < 1.0


def test_metric_inputs_are_checked():
    a = np.zeros((8, 8, 3), np.uint8)
    with pytest.raises(ValueError, match="shape"):
        psnr(a, np.zeros((8, 9, 3), np.uint8))
    with pytest.raises(ValueError, match="empty"):
        psnr(a, a, np.zeros((8, 8), bool))


def test_lpips_unavailable_without_a_model(monkeypatch, tmp_path):
    monkeypatch.delenv(LPIPS_ENV, raising=False)
    ok, reason = lpips_available()
    assert not ok and LPIPS_ENV in reason
    ok, reason = lpips_available(tmp_path / "missing.onnx")
    assert not ok and "not found" in reason
    (tmp_path / "junk.onnx").write_bytes(b"not a model")
    ok, reason = lpips_available(tmp_path / "junk.onnx")
    assert not ok and "cannot load" in reason


class _MeanAbs:
    """Not LPIPS: a model with the LPIPS file contract (two 1x3xHxW inputs in [-1, 1] -> distance)
    returning the mean absolute difference, to check how the scorer feeds and reads a model file."""

    @staticmethod
    def module():
        import torch

        class MeanAbs(torch.nn.Module):
            def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
                return (x - y).abs().mean(dim=(1, 2, 3), keepdim=True)

        return MeanAbs()

    @classmethod
    def torchscript(cls, path: Path) -> Path:
        import torch

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            torch.jit.script(cls.module()).save(str(path))
        return path

    @classmethod
    def exported(cls, path: Path) -> Path:
        import torch

        x, y = torch.zeros(1, 3, 16, 16), torch.ones(1, 3, 16, 16)
        h, w = torch.export.Dim("H", min=8, max=4096), torch.export.Dim("W", min=8, max=4096)
        dynamic = ({2: h, 3: w}, {2: h, 3: w})
        torch.export.save(torch.export.export(cls.module(), (x, y), dynamic_shapes=dynamic), str(path))
        return path

    @staticmethod
    def onnx(path: Path) -> Path:
        from onnx import TensorProto, helper, save

        inputs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, [1, 3, "H", "W"]) for n in ("x", "y")]
        output = helper.make_tensor_value_info("d", TensorProto.FLOAT, [])
        nodes = [
            helper.make_node("Sub", ["x", "y"], ["diff"]),
            helper.make_node("Abs", ["diff"], ["absdiff"]),
            helper.make_node("ReduceMean", ["absdiff"], ["d"], keepdims=0),
        ]
        graph = helper.make_graph(nodes, "mean_abs", inputs, [output])
        # IR version 9: what onnxruntime releases of the last years all read.
        save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], ir_version=9), str(path))
        return path


@pytest.mark.parametrize(
    ("make", "suffix", "backend"),
    [
        pytest.param(_MeanAbs.onnx, ".onnx", "onnx", marks=pytest.mark.needs("onnx", "onnxruntime")),
        pytest.param(_MeanAbs.exported, ".pt2", "torch.export", marks=pytest.mark.needs("torch")),
        pytest.param(_MeanAbs.torchscript, ".pt", "torchscript", marks=pytest.mark.needs("torch")),
    ],
)
def test_lpips_scorer_feeds_minus_one_to_one_rgb(tmp_path, make, suffix, backend):
    path = make(tmp_path / f"standin{suffix}")
    a = np.full((20, 30, 3), 100, np.uint8)
    b = np.full((20, 30, 3), 110, np.uint8)
    scorer = load_lpips(path)
    assert scorer.backend == backend
    assert scorer(a, b) == pytest.approx(10 / 127.5, rel=1e-5)
    assert lpips_available(path) == (True, f"{backend} model {path}")


# ---------------------------------------------------------------------------------------------
# Colour fit


def test_colour_gain_recovers_gain_and_offset_despite_outliers():
    rng = np.random.default_rng(1)
    source = rng.uniform(0.1, 0.8, (60, 80, 3)).astype(np.float32)
    gain, offset = np.array([0.8, 1.1, 1.25]), np.array([0.05, -0.02, 0.0])
    target = (source * gain + offset).astype(np.float32)
    outliers = rng.random((60, 80)) < 0.05
    target[outliers] = rng.uniform(0, 1, (outliers.sum(), 3))
    fit = fit_colour_gain(source, target, np.ones((60, 80), bool))
    np.testing.assert_allclose(fit.gain, gain, atol=0.006)
    np.testing.assert_allclose(fit.offset, offset, atol=0.004)
    # Ordinary least squares is pulled further by the same outliers.
    ols = np.polyfit(source[..., 0].ravel(), target[..., 0].ravel(), 1)
    assert abs(ols[0] - gain[0]) > 2 * abs(fit.gain[0] - gain[0])
    assert fit.n_samples == 60 * 80
    only_gain = fit_colour_gain(
        source, (source * gain).astype(np.float32), np.ones((60, 80), bool), offset=False
    )
    np.testing.assert_allclose(only_gain.gain, gain, atol=1e-3)
    assert not only_gain.offset.any()


def test_colour_gain_identity_without_samples_and_uint8_apply():
    img = np.full((4, 4, 3), 100, np.uint8)
    fit = fit_colour_gain(img, img, np.zeros((4, 4), bool))
    assert np.array_equal(apply_colour_gain(img, fit), img)
    brighter = ColourGain(np.full(3, 1.5), np.zeros(3), 0)
    assert apply_colour_gain(img, brighter).dtype == np.uint8
    assert np.all(apply_colour_gain(img, brighter) == 150)
    assert np.all(apply_colour_gain(np.full((2, 2, 3), 200, np.uint8), brighter) == 255)  # clipped


# ---------------------------------------------------------------------------------------------
# Baselines


def test_opencv_inpaint_fills_a_smooth_image_and_keeps_known_pixels():
    yy, xx = np.mgrid[0:120, 0:160]
    target = np.dstack([xx, yy, (xx + yy) // 2]).astype(np.uint8)
    hole = brush_stroke_mask(120, 160, seed=2)
    out = opencv_inpaint(masked(target, hole), hole)
    assert np.array_equal(out[~hole], target[~hole])
    flat = masked(target, hole)
    flat[hole] = target[~hole].mean(axis=0).astype(np.uint8)
    # A ramp is what inpainting from the surroundings restores; a flat fill is ~15 dB worse.
    assert psnr(out, target, hole) > 27.0
    assert psnr(out, target, hole) > psnr(flat, target, hole) + 10.0


def test_homography_baseline_on_a_planar_pair_beats_inpainting():
    target, source, h_true = planar_pair()
    for seed in range(2):
        hole = brush_stroke_mask(240, 320, seed=seed)
        fill = homography_fill_detailed(masked(target, hole), hole, source)
        assert np.array_equal(fill.image[~hole], target[~hole])
        corners = np.array([[0, 0, 1], [319, 0, 1], [0, 239, 1], [319, 239, 1]], float).T
        est, true = fill.H @ corners, h_true @ corners
        assert np.abs(est[:2] / est[2] - true[:2] / true[2]).max() < 1.0
        assert fill.hole_coverage == 1.0
        hole_psnr = psnr(fill.image, target, hole)
        assert hole_psnr > 30.0
        assert hole_psnr > psnr(opencv_inpaint(masked(target, hole), hole), target, hole) + 10.0


def test_homography_baseline_matches_colour():
    target, source, _ = planar_pair(gain=0.8, offset=20.0)
    hole = brush_stroke_mask(240, 320, seed=0)
    fill = homography_fill_detailed(masked(target, hole), hole, source)
    np.testing.assert_allclose(fill.colour.gain, 1 / 0.8, atol=0.03)
    np.testing.assert_allclose(fill.colour.offset, -20 / 255 / 0.8, atol=0.01)
    assert psnr(fill.image, target, hole) > 30.0
    plain = homography_fill_detailed(masked(target, hole), hole, source, colour_offset=False)
    assert psnr(plain.image, target, hole) < psnr(fill.image, target, hole) - 3.0


def test_homography_baseline_refuses_a_pair_without_matches():
    target, _, _ = planar_pair()
    hole = brush_stroke_mask(240, 320, seed=0)
    with pytest.raises(BaselineError, match="matches"):
        homography_fill(masked(target, hole), hole, np.full_like(target, 128))


# ---------------------------------------------------------------------------------------------
# Runner


def _broken(target, hole, source, exif) -> MethodOutput:
    raise RuntimeError("deliberate failure")


def _read_csv(path: Path) -> list[dict[str, str]]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


def test_run_eval_records_failures_and_writes_everything(tmp_path, monkeypatch):
    monkeypatch.delenv(LPIPS_ENV, raising=False)
    pairs = planar_pairs(2)
    methods = {**resolve_methods(["opencv_inpaint", "homography"]), "broken": _broken}
    rows = run_eval(pairs, methods, tmp_path, seed=0, by="kind")

    table = _read_csv(tmp_path / "results.csv")
    assert [(r["pair"], r["method"]) for r in table] == [
        (p.id, m) for p in pairs for m in ("opencv_inpaint", "homography", "broken")
    ]
    broken = [r for r in table if r["method"] == "broken"]
    assert all(r["error"] == "RuntimeError: deliberate failure" and r["psnr"] == "" for r in broken)
    for r in table:
        assert r["kind"] == ("synthetic0" if r["pair"] == "planar_0" else "synthetic1")
        if r["method"] != "broken":
            assert r["error"] == "" and float(r["psnr_hole"]) > 0 and float(r["ssim"]) > 0.5
            assert r["lpips"] == "" and r["lpips_status"].startswith("unavailable:")
    homography = {r.pair: r for r in rows if r.method == "homography"}
    inpaint = {r.pair: r for r in rows if r.method == "opencv_inpaint"}
    for p in pairs:
        hole = cv2.imread(str(tmp_path / "masks" / f"{p.id}.png"), cv2.IMREAD_GRAYSCALE) > 0
        assert np.array_equal(hole, brush_stroke_mask(240, 320, seed=mask_seed(p.id, 0)))
        assert homography[p.id].hole_ratio == pytest.approx(hole.mean())
        assert homography[p.id].psnr_hole > 30.0 > inpaint[p.id].psnr_hole
        assert (
            json.loads(next(r["info"] for r in table if r["pair"] == p.id and r["method"] == "homography"))[
                "n_inliers"
            ]
            >= 12
        )
        sheet = cv2.imread(str(tmp_path / f"contact_{p.id}.jpg"))
        assert sheet.shape[0] == 2 * (300 + 24) and sheet.shape[1] == 3 * 400  # 6 tiles of 400x300 + labels
    assert wins(rows, "homography", "opencv_inpaint") == (2, 2)

    stages = _read_csv(tmp_path / "timings.csv")
    assert {(s["method"], s["stage"]) for s in stages} == {
        ("opencv_inpaint", "total"),
        ("homography", "total"),
    }
    summary = (tmp_path / "summary.md").read_text()
    assert "LPIPS: unavailable:" in summary
    assert "- planar_0 / broken: RuntimeError: deliberate failure" in summary
    assert "| homography | 2/2 | - |" in summary
    assert "## By kind" in summary and "| synthetic1 | homography | 1 |" in summary


@pytest.mark.needs("onnx", "onnxruntime")
def test_run_eval_scores_lpips_with_a_model(tmp_path):
    model = _MeanAbs.onnx(tmp_path / "standin.onnx")
    rows = run_eval(
        planar_pairs(1), ["opencv_inpaint"], tmp_path / "out", lpips_model=model, contact_sheets=False
    )
    (row,) = rows
    assert row.lpips_status == "ok" and 0.0 < row.lpips < 1.0
    assert f"LPIPS: available (onnx model {model})" in (tmp_path / "out" / "summary.md").read_text()


def test_methods_must_return_a_full_uint8_image(tmp_path):
    def wrong_size(target, hole, source, exif):
        return MethodOutput(target[:10])

    (row,) = run_eval(planar_pairs(1), {"wrong": wrong_size}, tmp_path, contact_sheets=False)
    assert row.error.startswith("ValueError: method returned") and row.psnr is None


def test_method_registry():
    assert {"opencv_inpaint", "homography"} <= set(METHODS)
    with pytest.raises(ValueError, match="already registered"):
        register_method("homography", _broken)
    with pytest.raises(ConfigError, match="unknown method"):
        resolve_methods(["nope"])


@pytest.mark.needs("matplotlib")
def test_hole_size_sweep_keeps_the_shape_and_widens_the_brush(tmp_path):
    rows = sweep(planar_pairs(1), ["opencv_inpaint", "homography"], tmp_path, widths_720p=(90.0, 210.0))
    table = _read_csv(tmp_path / "sweep.csv")
    assert [(float(t["stroke_width_720p"]), t["method"]) for t in table] == [
        (90.0, "opencv_inpaint"),
        (90.0, "homography"),
        (210.0, "opencv_inpaint"),
        (210.0, "homography"),
    ]
    thin, thick = (float(t["mean_hole_ratio"]) for t in table[::2])
    assert thick > 1.5 * thin
    assert {r.stroke_width_px for r in rows} == {30.0, 70.0}  # 90 and 210 px at 720p, scaled to 240 px
    assert (tmp_path / "sweep.png").stat().st_size > 10_000
    assert "| 210 | homography | 1 | 0 |" in (tmp_path / "sweep.md").read_text()


def test_group_value_reads_meta_fields():
    meta = {"kind": "handheld-video (indoor)", "frame_difference": 6, "gt": {"K": None}}
    assert group_value(meta, "kind") == "handheld-video"
    assert group_value(meta, "frame_difference") == "6"
    assert group_value(meta, "gt.K") == "n/a"
    assert group_value(meta, "missing") == "n/a"


# ---------------------------------------------------------------------------------------------
# Pair loading and CLI


def _write_pair_folder(folder: Path, pair: Pair) -> None:
    folder.mkdir(parents=True)
    cv2.imwrite(str(folder / "target.png"), cv2.cvtColor(pair.target, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(folder / "source.jpg"), cv2.cvtColor(pair.source, cv2.COLOR_RGB2BGR))
    (folder / "meta.json").write_text(json.dumps(pair.meta))


def test_cli_runs_on_a_folder_of_pairs(tmp_path):
    for p in planar_pairs(2):
        _write_pair_folder(tmp_path / "pairs" / p.id, p)
    code = main_eval(
        [
            *("--pairs", str(tmp_path / "pairs"), "--out", str(tmp_path / "out")),
            *("--methods", "opencv_inpaint", "--by", "kind", "--limit", "1", "--seed", "3"),
        ]
    )
    assert code == 0
    (row,) = _read_csv(tmp_path / "out" / "results.csv")
    assert row["pair"] == "planar_0" and row["kind"] == "synthetic0" and row["error"] == ""
    hole = cv2.imread(str(tmp_path / "out" / "masks" / "planar_0.png"), cv2.IMREAD_GRAYSCALE) > 0
    assert np.array_equal(hole, brush_stroke_mask(240, 320, seed=mask_seed("planar_0", 3)))


def test_pair_exif_reaches_the_methods(tmp_path):
    # A user's files carry EXIF; the evaluation must give it to geofill as the CLI does.
    p = planar_pairs(1)[0]
    _write_pair_folder(tmp_path / "pairs" / p.id, p)
    exif = Image.Exif()
    exif[ExifTags.IFD.Exif] = {ExifTags.Base.FocalLengthIn35mmFilm: 52}
    Image.fromarray(p.target).save(tmp_path / "pairs" / p.id / "target.jpg", exif=exif, quality=95)
    (tmp_path / "pairs" / p.id / "target.png").unlink()
    (pair,) = load_pairs([tmp_path / "pairs"])
    assert pair.exif.target.focal_35mm == 52 and pair.exif.source.focal_35mm is None
    seen = []

    def spy(target, hole, source, exif):
        seen.append(exif)
        return MethodOutput(target)

    methods = {"spy": spy, **resolve_methods(["geofill_fixed_focal"])}
    _, geo_row = run_eval([pair], methods, tmp_path / "out", contact_sheets=False)
    assert seen == [pair.exif]
    # The EXIF focal (52 mm of a 43.27 mm diagonal) is the target's; geofill_fixed_focal ignores
    # EXIF by design (the paper's 750 px at a 1280-px long side), so compare with geofill proper.
    (row,) = run_eval([pair], resolve_methods(["geofill"]), tmp_path / "out2", contact_sheets=False)
    assert row.info["focal_origin"] == "exif"
    assert row.info["focal_px"] == pytest.approx(52 / 43.27 * 400, rel=0.01)
    assert geo_row.info["focal_origin"] == "default"
    assert geo_row.info["focal_px"] == pytest.approx(750 * 320 / 1280, rel=0.01)


def test_cli_reports_bad_input(tmp_path, capsys):
    assert main_eval(["--pairs", str(tmp_path / "none"), "--out", str(tmp_path / "o")]) == 2
    assert "not found" in capsys.readouterr().err
    assert main_eval(["--pairs", "synthetic:1", "--out", str(tmp_path / "o"), "--methods", "nope"]) == 3
    assert main_eval(["--pairs", "x", "--out", "o", "--sweep", "hole-size", "--by", "kind"]) == 2


def test_load_pairs_rejects_duplicates_and_empty_folders(tmp_path):
    p = planar_pairs(1)[0]
    _write_pair_folder(tmp_path / "a" / p.id, p)
    _write_pair_folder(tmp_path / "b" / p.id, p)
    with pytest.raises(InputError, match="duplicate"):
        load_pairs([tmp_path / "a", tmp_path / "b"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no pair folders"):
        load_pairs([tmp_path / "empty"])
    (loaded,) = load_pairs([tmp_path / "a" / p.id])
    assert np.array_equal(loaded.target, p.target) and loaded.meta == p.meta


def test_excluded_pair_folders_are_left_out_unread(tmp_path):
    kept, held = planar_pairs(2)
    _write_pair_folder(tmp_path / "set" / kept.id, kept)
    _write_pair_folder(tmp_path / "set" / held.id, held)
    (tmp_path / "set" / held.id / "target.png").write_bytes(b"not an image")  # reading it would fail
    (loaded,) = load_pairs([tmp_path / "set"], exclude=[held.id])
    assert loaded.id == kept.id
    with pytest.raises(InputError):
        load_pairs([tmp_path / "set"])


def test_synthetic_pairs_load():
    pairs = load_pairs(["synthetic:2"])
    assert [p.id for p in pairs] == ["synthetic_000", "synthetic_001"]
    assert pairs[0].target.dtype == np.uint8 and pairs[0].target.shape == pairs[0].source.shape


@pytest.mark.skipif(not REAL_PAIRS.is_dir(), reason=f"real pairs not found at {REAL_PAIRS}")
def test_real_pairs_load_with_meta():
    pairs = load_pairs([REAL_PAIRS])
    assert len(pairs) >= 18
    for p in pairs:
        assert p.target.dtype == np.uint8 and p.target.ndim == 3 and p.source.shape == p.target.shape
        # meta.json's kind is 'category (details)'; "photo sequence (...)" groups as "photo"
        assert group_value(p.meta, "kind") in {"rgbd", "stereo", "video", "handheld-video", "photos", "photo"}


def test_eval_of_geofill_on_synthetic_scenes(tmp_path):
    """The whole protocol with the real pipeline in the loop: geofill beats Telea on exact-GT scenes,
    its stage timings are recorded and a config override reaches the method."""
    out = tmp_path / "out"
    argv = ["--pairs", "synthetic:2", "--out", str(out), "--methods", "opencv_inpaint,geofill"]
    assert main_eval([*argv, "--set", "matching.max_features=3000"]) == 0
    rows = _read_csv(out / "results.csv")
    assert {(r["pair"], r["method"]) for r in rows} == {
        (p, m) for p in ("synthetic_000", "synthetic_001") for m in ("opencv_inpaint", "geofill")
    }
    by = {(r["pair"], r["method"]): r for r in rows}
    for p in ("synthetic_000", "synthetic_001"):
        assert by[(p, "geofill")]["error"] == ""
        assert json.loads(by[(p, "geofill")]["info"])["status"] == "reference"
        assert float(by[(p, "geofill")]["psnr_hole"]) > float(by[(p, "opencv_inpaint")]["psnr_hole"]) + 2.0
    stages = {r["stage"] for r in _read_csv(out / "timings.csv") if r["method"] == "geofill"}
    assert {"match", "pose", "depth", "render"} <= stages
    assert "geofill" in (out / "summary.md").read_text()
    assert main_eval([*argv, "--set", "matching.nope=1"]) == 3
