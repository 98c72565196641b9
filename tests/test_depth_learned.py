"""Learned depth (ONNX) with tiny self-built networks of the real models' I/O, the dense fit to
stereo (``fused``) and the ``auto`` choice. No real weights exist here; nothing is downloaded."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from geofill.config import DepthConfig, FillConfig
from geofill.depth import choose_backend
from geofill.depth.fused import fit_to_stereo
from geofill.depth.onnx import MODELS, input_size, predict_learned, preprocess
from geofill.depth.stereo import Hypotheses, SweepResult
from geofill.errors import DepthModelError, ReferenceUnusable
from geofill.pipeline import fill
from geofill.synthetic import make_pair
from geofill.triangulate import TriangulatedPoints

DA2, DPT, MIDAS = "depth-anything-v2-small", "dpt-hybrid", "midas-v2.1-small"


def save_model(path, graph_nodes, inputs, outputs, initializers=()) -> str:
    import onnx
    from onnx import helper

    graph = helper.make_graph(graph_nodes, "tiny", inputs, outputs, initializer=list(initializers))
    # IR version 8 (onnx 1.10+) so that any onnxruntime of the last years can load it.
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8)
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return str(path)


def red_channel_model(path, in_name="pixel_values", out_name="predicted_depth", hw=("h", "w"), out_4d=False):
    """Outputs the network input's channel 0 (1xHxW, or 1x1xHxW): the preprocessed red channel."""
    from onnx import TensorProto, helper, numpy_helper

    x = helper.make_tensor_value_info(in_name, TensorProto.FLOAT, [1, 3, *hw])
    y = helper.make_tensor_value_info(out_name, TensorProto.FLOAT, [1, 1, *hw] if out_4d else [1, *hw])
    idx = numpy_helper.from_array(np.array([0] if out_4d else 0, np.int64), "idx")
    node = helper.make_node("Gather", [in_name, "idx"], [out_name], axis=1)
    return save_model(path, [node], [x], [y], [idx])


def constant_model(path, values: np.ndarray):
    """Ignores its (fixed-size) input's content and outputs ``values`` (1xHxW)."""
    from onnx import TensorProto, helper, numpy_helper

    h, w = values.shape
    x = helper.make_tensor_value_info("pixel_values", TensorProto.FLOAT, [1, 3, h, w])
    y = helper.make_tensor_value_info("predicted_depth", TensorProto.FLOAT, [1, h, w])
    const = numpy_helper.from_array(values[None].astype(np.float32), "const")
    zero = numpy_helper.from_array(np.array(0.0, np.float32), "zero")
    nodes = [
        helper.make_node("ReduceMean", ["pixel_values"], ["m"], axes=[1], keepdims=0),
        helper.make_node("Mul", ["m", "zero"], ["z"]),
        helper.make_node("Add", ["z", "const"], ["predicted_depth"]),
    ]
    return save_model(path, nodes, [x], [y], [const, zero])


def test_input_size_rules():
    # Depth Anything: scale by the factor closest to 1, sides rounded to multiples of the 14-px patch.
    assert input_size(720, 1280, MODELS[DA2]) == (518, 924)
    assert input_size(1280, 720, MODELS[DA2]) == (924, 518)
    assert input_size(240, 320, MODELS[DA2]) == (392, 518)
    assert all(s % 14 == 0 for s in input_size(333, 777, MODELS[DA2]))
    assert input_size(720, 1280, MODELS[DPT]) == (384, 384)
    assert input_size(480, 640, MODELS[MIDAS]) == (256, 256)


def test_normalisation_per_model():
    red = np.zeros((50, 80, 3), np.float32)
    red[..., 0] = 1.0
    x = preprocess(red, MODELS[DA2])
    assert x.shape == (1, 3, 322, 518) and x.dtype == np.float32  # upscaled by 518/80
    np.testing.assert_allclose(
        x[0, :, 5, 5], [(1 - 0.485) / 0.229, -0.456 / 0.224, -0.406 / 0.225], rtol=1e-5
    )
    grey = np.full((50, 80, 3), 0.5, np.float32)
    np.testing.assert_allclose(preprocess(grey, MODELS[DPT]), 0.0, atol=1e-6)  # mean = std = 0.5
    np.testing.assert_allclose(preprocess(grey, MODELS[MIDAS]), 0.5, atol=1e-6)  # normalised inside the net


@pytest.mark.needs("onnx", "onnxruntime")
@pytest.mark.parametrize(
    ("model", "names", "fixed", "out_4d"),
    [
        (DA2, ("pixel_values", "predicted_depth"), None, False),
        (DPT, ("pixel_values", "predicted_depth"), (384, 384), False),
        (MIDAS, ("0", "797"), (256, 256), True),  # names are read from the file, not assumed
    ],
)
def test_network_output_back_at_source_resolution_and_orientation(tmp_path, model, names, fixed, out_4d):
    h, w = 200, 300
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    image = np.stack([xx / (w - 1), yy / (h - 1), np.full_like(xx, 0.3)], axis=2)
    path = red_channel_model(tmp_path / "m.onnx", *names, hw=fixed or ("h", "w"), out_4d=out_4d)
    cfg = DepthConfig(backend="onnx", model=model, model_path=path)
    out = predict_learned(image, cfg)
    assert out.shape == (h, w)
    spec = MODELS[model]
    expected = (image[..., 0] - spec.mean[0]) / spec.std[0]
    inner = np.s_[8:-8, 8:-8]  # away from the resize's border effects
    np.testing.assert_allclose(out[inner], expected[inner], atol=0.02 / spec.std[0])
    # Left-right and up-down kept: the output follows x, not y.
    assert np.corrcoef(out.ravel(), xx.ravel())[0, 1] > 0.999
    assert abs(np.corrcoef(out.ravel(), yy.ravel())[0, 1]) < 0.01


@pytest.mark.needs("onnx", "onnxruntime")
def test_model_that_cannot_run_is_a_named_error(tmp_path):
    path = red_channel_model(tmp_path / "fixed64.onnx", hw=(64, 64))
    with pytest.raises(DepthModelError, match=r"fixed64\.onnx"):
        predict_learned(np.zeros((100, 150, 3), np.float32), DepthConfig(model=DA2, model_path=path))


def test_missing_weights_are_a_named_error(tmp_path):
    with pytest.raises(DepthModelError, match="not available"):
        predict_learned(
            np.zeros((100, 150, 3), np.float32), DepthConfig(model_path=str(tmp_path / "none.onnx"))
        )


def _sweep(inv: np.ndarray, conf: np.ndarray) -> SweepResult:
    z = np.zeros_like(inv, np.float64)
    return SweepResult(inv, conf, conf, Hypotheses(z, z + 1, 2), None, (0.0, 1.0))


def test_fused_fit_recovers_affine_map_with_confidence_weights():
    rng = np.random.default_rng(0)
    h, w = 120, 160
    learned = rng.uniform(0.5, 3.0, (h, w)).astype(np.float32)
    s_true, b_true = 0.04, 0.01
    stereo = s_true * learned + b_true
    conf = np.ones((h, w), np.float32)
    kind = rng.random((h, w))
    shaky = kind < 0.25  # barely confident and biased by +30 %
    stereo[shaky] *= 1.3
    conf[shaky] = 0.55
    junk = kind > 0.85  # below the threshold: must not count at all
    stereo[junk] = rng.uniform(0, 1, junk.sum())
    conf[junk] = 0.1
    uv = rng.uniform(0, [w - 1, h - 1], (30, 2))
    lv = learned[np.rint(uv[:, 1]).astype(int), np.rint(uv[:, 0]).astype(int)]
    uv = np.rint(uv)
    z = 1.0 / (s_true * lv + b_true)
    pts = TriangulatedPoints(np.c_[uv, z], uv, uv, np.zeros(30), np.ones(30))
    s, b, n = fit_to_stereo(learned, _sweep(stereo.astype(np.float32), conf), pts, 0.5, (h, w))
    assert n > 0.8 * h * w
    assert s == pytest.approx(s_true, rel=0.02) and b == pytest.approx(b_true, abs=0.002)


def test_fused_fit_needs_samples():
    learned = np.ones((20, 20), np.float32)
    pts = TriangulatedPoints(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    with pytest.raises(ReferenceUnusable, match="samples"):
        fit_to_stereo(learned, _sweep(learned, np.zeros_like(learned)), pts, 0.5, (20, 20))


@pytest.fixture(scope="module")
def scene():
    return make_pair(seed=0)


@pytest.fixture(scope="module")
def oracle_model(scene, tmp_path_factory):
    """A 'network' whose output is the scene's true inverse depth up to an unknown affine map, at
    Depth Anything's input size for this image: the learned path must turn it back into depth."""
    h, w = scene.source.shape[:2]
    ih, iw = input_size(h, w, MODELS[DA2])
    inv = cv2.resize(1.0 / scene.depth_source, (iw, ih), interpolation=cv2.INTER_LINEAR)
    return constant_model(tmp_path_factory.mktemp("oracle") / "oracle.onnx", 7.0 * inv + 0.3)


def _abs_rel(res, scene) -> float:
    z = res.references[0].depth.depth * np.linalg.norm(scene.T_source_to_target[:3, 3])
    gt = cv2.resize(scene.depth_source, z.shape[::-1], interpolation=cv2.INTER_NEAREST)
    return float(np.nanmedian(np.abs(z - gt) / gt))


@pytest.mark.needs("onnx", "onnxruntime")
@pytest.mark.parametrize("backend", ["onnx", "fused", "auto"])
def test_learned_backends_in_the_pipeline(scene, oracle_model, backend):
    # The true focal is the default here; estimating it would mix focal error into the depth check.
    overrides = {"depth.backend": backend, "depth.model_path": oracle_model, "intrinsics.estimate": "none"}
    cfg = FillConfig().updated(overrides)
    res = fill(scene.target, scene.hole, scene.source, cfg)
    r = res.report
    assert r.status == "reference"
    depth = r.references[0]["depth"]
    assert depth["backend"] == ("fused" if backend == "auto" else backend)
    # onnx: fitted to the triangulated points; fused: fitted to stereo inside the backend.
    assert depth["method"] == ("robust" if backend == "onnx" else "identity")
    assert _abs_rel(res, scene) < 0.03
    if backend == "auto":
        assert "fused (auto: learned depth" in r.depth_choice and "oracle.onnx" in r.depth_choice


@pytest.mark.needs("onnxruntime")
def test_auto_without_weights_runs_stereo_and_says_why(scene, monkeypatch, tmp_path):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("GEOFILL_CACHE", str(tmp_path))
    choice = choose_backend(DepthConfig())
    assert choice.name == "stereo"
    assert "Depth Anything V2 Small" in choice.reason and "HF_HUB_OFFLINE" in choice.reason
    res = fill(scene.target, scene.hole, scene.source, FillConfig())
    assert res.references[0].depth.backend == "stereo" and res.report.depth_choice == choice.reason


@pytest.mark.needs("onnxruntime")
def test_auto_with_broken_explicit_path_is_an_error(tmp_path):
    with pytest.raises(DepthModelError, match="explicit path"):
        choose_backend(dataclasses.replace(DepthConfig(), model_path=str(tmp_path / "missing.onnx")))


def _cli_inputs(tmp_path, scene):
    for name, rgb in (("target", scene.target), ("source", scene.source)):
        cv2.imwrite(str(tmp_path / f"{name}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(tmp_path / "mask.png"), scene.hole.astype(np.uint8) * 255)
    return [
        "fill",
        *(x for n in ("target", "mask", "source") for x in (f"--{n}", str(tmp_path / f"{n}.png"))),
    ]


@pytest.mark.needs("onnxruntime")
def test_cli_prints_the_depth_choice_and_reports_it(scene, tmp_path, capsys):
    from geofill.cli import main

    args = _cli_inputs(tmp_path, scene)
    # A technical detail: printed with --verbose, and in report.json whatever the flags.
    assert main([*args, "-o", str(tmp_path / "out.png"), "--debug-dir", str(tmp_path / "dbg"), "-v"]) == 0
    err = capsys.readouterr().err
    assert "geofill: depth backend: stereo (auto: Depth Anything V2 Small (ONNX) weights not available" in err
    import json

    report = json.loads((tmp_path / "dbg" / "report.json").read_text())
    assert report["references"][0]["depth"]["backend"] == "stereo"
    assert "HF_HUB_OFFLINE" in report["depth_choice"]


@pytest.mark.needs("onnx", "onnxruntime")
def test_cli_depth_model_flag(scene, oracle_model, tmp_path, capsys):
    from geofill.cli import main

    assert main(["config", "--depth", "fused", "--depth-model", oracle_model]) == 0
    cfg = FillConfig.from_dict(__import__("json").loads(capsys.readouterr().out))
    assert cfg.depth.backend == "fused" and cfg.depth.model_path == oracle_model
    args = _cli_inputs(tmp_path, scene)
    out = tmp_path / "out.png"
    assert main([*args, "-o", str(out), "--depth-model", str(tmp_path / "missing.onnx")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) >= 1 and err[-1].startswith("geofill: error:") and "missing.onnx" in err[-1]
    assert not out.exists()
