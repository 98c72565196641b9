"""Configuration validation, the time budget, the up-front resource checks, optional extras and
``geofill models`` on an offline machine."""

from __future__ import annotations

import dataclasses
import json
import re
import sys
import typing
from pathlib import Path

import numpy as np
import pytest

from geofill import progress as progress_module
from geofill.cli import main
from geofill.config import FillConfig, Length, OptimizeConfig, Range
from geofill.errors import ConfigError, DepthFileError, DepthModelError, MissingExtraError, TimeBudgetError
from geofill.preflight import check_resources
from geofill.progress import Progress


@pytest.mark.parametrize(
    ("override", "message"),
    [
        (
            {"intrinsics.focal_px": float("nan")},
            "config.intrinsics.focal_px: expected a finite number, got nan",
        ),
        (
            {"intrinsics.focal_px": 0},
            "config.intrinsics.focal_px: 0.0 is outside the allowed range (0, 1e+06]",
        ),
        ({"intrinsics.source": [float("inf"), 1, 0, 0]}, "config.intrinsics.source[0]: expected a finite"),
        (
            {"intrinsics.search_steps": 10_000_000},
            "search_steps: 10000000 is outside the allowed range [2, 200]",
        ),
        (
            {"optimize.pyramid_levels": 0},
            "config.optimize.pyramid_levels: 0 is outside the allowed range [1, 8]",
        ),
        (
            {"optimize.pyramid_levels": 6},
            "paper_iterations: 4 values given, allowed 6 to 8 (pyramid_levels = 6)",
        ),
        (
            {"depth.stereo_patch_px": 0},
            "config.depth.stereo_patch_px: 0 is outside the allowed range [3, 63]",
        ),
        ({"working_max_side": 0}, "config.working_max_side: 0 is outside the allowed range [64, 16384]"),
        ({"refine.gain_sigma_px": 1e308}, "config.refine.gain_sigma_px: 1e+308 is outside the allowed range"),
        ({"optimize.threads": 0}, "config.optimize.threads: 0 is outside the allowed range [1, 256]"),
        (
            {"geometry.max_reprojection_px": -1},
            "max_reprojection_px: -1.0 is outside the allowed range (0, 1000]",
        ),
        ({"intrinsics.focal_px": 10**400}, "config.intrinsics.focal_px: expected a finite number, got 1000"),
        ({"time_budget_s": 0}, "config.time_budget_s: 0.0 is outside the allowed range [1, 1e+06]"),
    ],
)
def test_bad_values_name_the_key_and_the_range(override, message):
    with pytest.raises(ConfigError) as info:
        FillConfig().updated(override)
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_sections_built_through_the_api_are_checked_too():
    with pytest.raises(ConfigError, match=r"config\.optimize\.threads: 0 is outside"):
        FillConfig(optimize=OptimizeConfig(threads=0))
    assert FillConfig(optimize=OptimizeConfig(threads=2)).optimize.threads == 2


def test_defaults_are_inside_their_own_bounds_and_every_number_is_bounded():
    """One mechanism for every numeric key: each int/float field declares a Range, and the
    defaults pass it."""
    FillConfig()  # validates the defaults
    unbounded = []
    for name, tp in typing.get_type_hints(FillConfig, include_extras=True).items():
        fields = {name: tp}
        if dataclasses.is_dataclass(tp):
            fields = {f"{name}.{k}": v for k, v in typing.get_type_hints(tp, include_extras=True).items()}
        for key, hint in fields.items():
            text = repr(hint)
            numeric = ("int" in text or "float" in text) and "Literal" not in text
            if numeric and "Range(" not in text:
                unbounded.append(key)
    assert unbounded == []


def test_every_config_field_has_a_description_as_data():
    """Each leaf's description is its ``metadata["help"]``; each section's is its docstring."""
    missing = []
    for top in dataclasses.fields(FillConfig):
        section = typing.get_type_hints(FillConfig)[top.name]
        if dataclasses.is_dataclass(section):
            assert section.__doc__.strip(), section
            leaves = {f"{top.name}.{f.name}": f for f in dataclasses.fields(section)}
        else:
            leaves = {top.name: top}
        for key, f in leaves.items():
            text = f.metadata.get("help")
            if not (isinstance(text, str) and text.strip() and "\n" not in text):
                missing.append(key)
    assert missing == []


def test_list_defaults_are_copied_for_each_config():
    a, b = OptimizeConfig(), OptimizeConfig()
    assert a.edge_blur_kernels == b.edge_blur_kernels == [3, 7, 15, 31]
    a.edge_blur_kernels.append(63)
    assert b.edge_blur_kernels == OptimizeConfig().edge_blur_kernels == [3, 7, 15, 31]
    assert FillConfig().optimize.fast_iterations == [30, 20, 12, 4]


def test_range_and_length_describe_themselves():
    assert str(Range(0, 1, lo_open=True)) == "(0, 1]"
    with pytest.raises(ConfigError, match=r"x: 3 values given, allowed 4 to 4"):
        Length(4, 4).check([1, 2, 3], "x", {})


def test_config_files_that_are_not_json_objects(tmp_path):
    (tmp_path / "latin1.json").write_bytes('{"x": "caf\xe9"}'.encode("latin-1"))
    with pytest.raises(ConfigError, match="not UTF-8 text"):
        FillConfig.from_json(tmp_path / "latin1.json")
    with pytest.raises(ConfigError, match="is a directory"):
        FillConfig.from_json(tmp_path)
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ConfigError, match="not valid JSON"):
        FillConfig.from_json(tmp_path / "deep.json")
    (tmp_path / "ok.json").write_text(json.dumps({"optimize": {"threads": 3}}))
    assert FillConfig.from_json(tmp_path / "ok.json").optimize.threads == 3


def test_time_budget_stops_before_the_next_stage(monkeypatch):
    clock = iter([0.0, 0.0, 0.5, 2.5])
    monkeypatch.setattr(progress_module, "monotonic", lambda: next(clock))
    prog = Progress(quiet=True, time_budget_s=2.0)
    with prog.stage("match"):  # 0.0 s after the start: inside the budget
        pass
    with prog.stage("pose"):  # 0.5 s
        pass
    with pytest.raises(
        TimeBudgetError, match=r"time budget of 2 s exceeded after 2\.5 s, before stage 'depth'"
    ):
        with prog.stage("depth"):
            pass
    assert set(prog.timings) == {"match", "pose"}


def test_cli_time_budget_exceeded_is_one_line_and_writes_nothing(tmp_path, capsys, monkeypatch):
    from fuzz_cases import Corpus

    corpus = Corpus(tmp_path / "c")
    ticks = iter(np.arange(0.0, 100.0, 0.6))  # every clock reading 0.6 s after the previous one
    monkeypatch.setattr(progress_module, "monotonic", lambda: float(next(ticks)))
    out, dbg = tmp_path / "o.png", tmp_path / "dbg"
    argv = ["fill", "--quiet", "--target", str(corpus.f("target.png")), "--mask", str(corpus.f("mask.png")),
            "--source", str(corpus.f("source.png")), "-o", str(out), "--debug-dir", str(dbg),
            "--set", "time_budget_s=1"]  # fmt: skip
    code = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 6 and len(err) == 1, err
    assert err[0].startswith("geofill: error: time budget of 1 s exceeded after 1.2 s, before stage")
    assert not out.exists() and not dbg.exists()


_SOURCE_SIZE = (200, 150)


def _file_cfg(path: Path) -> FillConfig:
    return FillConfig().updated({"depth.backend": "file", "depth.file_path": str(path)})


@pytest.mark.needs("onnxruntime")
def test_preflight_refuses_bad_depth_files_and_missing_weights(tmp_path):
    cfg = FillConfig()
    check_resources(cfg, _SOURCE_SIZE)  # defaults: nothing to check, nothing raised
    np.save(tmp_path / "d.npy", np.full((150, 200), np.nan, np.float32))
    with pytest.raises(DepthFileError, match="no valid depth value"):
        check_resources(
            cfg.updated({"depth.backend": "file", "depth.file_path": str(tmp_path / "d.npy")}), (200, 150)
        )
    np.save(tmp_path / "s.npy", np.ones((10, 10), np.float32))
    with pytest.raises(DepthFileError, match=r"depth map is 10x10 but the image it belongs to is 200x150"):
        check_resources(
            cfg.updated({"depth.backend": "file", "depth.file_path": str(tmp_path / "s.npy")}), (200, 150)
        )
    with pytest.raises(ConfigError, match="needs a depth file"):
        check_resources(cfg.updated({"depth.backend": "file"}), _SOURCE_SIZE)
    with pytest.raises(DepthModelError, match="depth backend 'fused': Depth Anything V2 Small"):
        check_resources(cfg.updated({"depth.backend": "fused"}), _SOURCE_SIZE)


def test_missing_onnxruntime_is_a_stereo_choice_or_a_one_line_hint(monkeypatch):
    from geofill.composite.inpaint import get_inpainter
    from geofill.depth import choose_backend

    monkeypatch.setitem(sys.modules, "onnxruntime", None)
    cfg = FillConfig()
    choice = choose_backend(cfg.depth)
    assert choice.name == "stereo" and "onnxruntime, not installed" in choice.reason
    assert get_inpainter(cfg.inpaint).name == "exemplar"
    with pytest.raises(MissingExtraError, match=r"depth backend 'onnx' needs the optional 'onnx' extra"):
        check_resources(cfg.updated({"depth.backend": "onnx"}), _SOURCE_SIZE)
    with pytest.raises(MissingExtraError, match=r'LaMa inpainting needs .*pip install "geofill\[onnx\]"'):
        get_inpainter(cfg.updated({"inpaint.method": "lama"}).inpaint)


def test_missing_huggingface_hub_skips_the_hub_cache_and_names_the_extra(monkeypatch):
    from geofill.composite.inpaint import LAMA_WEIGHTS
    from geofill.weights import WeightsUnavailable, download, resolve_weights

    monkeypatch.setitem(sys.modules, "huggingface_hub", None)
    got = resolve_weights(LAMA_WEIGHTS, allow_download=False)
    assert isinstance(got, WeightsUnavailable)
    assert 'Hugging Face cache not searched (pip install "geofill[onnx]")' in got.reason
    with pytest.raises(MissingExtraError, match=r"downloading LaMa \(ONNX\) needs the optional 'onnx' extra"):
        download(LAMA_WEIGHTS, LAMA_WEIGHTS.cache_path(Path("/nonexistent")))


def test_models_list_on_an_offline_machine(capsys):
    assert main(["models", "list"]) == 0
    out = capsys.readouterr().out
    names = ("depth-anything-v2-small", "dpt-hybrid", "midas-v2.1-small", "lama", "superpoint-lightglue")
    for name in names:
        assert f"\n{name}: " in out
    assert "sha256 afb6a5c28f3b6bf1618c6e43f02073ef9dfdc70e937502d51603e57b0a1df10c" in out
    assert out.count("not found:") == len(names)  # the test cache is empty
    assert "downloads disabled by HF_HUB_OFFLINE" in out
    assert out.count("no published checksum: cannot be verified") == len(names) - 1


def test_models_verify_hashes_what_it_finds(tmp_path, monkeypatch, capsys):
    model = tmp_path / "lama.onnx"
    model.write_bytes(b"not really a model")
    monkeypatch.setenv("GEOFILL_LAMA_MODEL", str(model))
    assert main(["models", "verify", "lama"]) == 0
    out = capsys.readouterr().out
    assert "lama.onnx (18 bytes, sha256 " in out and "cannot be verified: no published checksum" in out
    monkeypatch.setenv("GEOFILL_DEPTH_ANYTHING_V2_SMALL", str(model))
    assert main(["models", "verify", "depth-anything-v2-small"]) == 2
    assert "MISMATCH: SHA-256" in capsys.readouterr().out


def test_models_download_offline_is_one_line(capsys):
    assert main(["models", "download", "lama"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["geofill: error: lama: downloads disabled by HF_HUB_OFFLINE"]


def test_patchmatch_fills_only_the_hole_and_is_deterministic():
    pytest.importorskip("patchmatch")
    from geofill.composite.inpaint import inpaint_single
    from geofill.config import InpaintConfig
    from geofill.synthetic import make_pair

    p = make_pair(seed=4, width=160, height=120)
    cfg = InpaintConfig(method="patchmatch")
    a, b = inpaint_single(p.target, p.hole, cfg), inpaint_single(p.target, p.hole, cfg)
    assert np.array_equal(a, b)
    assert np.array_equal(a[~p.hole], p.target[~p.hole])
    # Every hole pixel is copied from somewhere: no black left where the hole was blanked.
    blanked = p.target.copy()
    blanked[p.hole] = 0
    filled = inpaint_single(blanked, p.hole, cfg)
    assert filled[p.hole].max(axis=1).min() > 0


def test_patchmatch_without_the_extra_names_it(monkeypatch):
    from geofill.composite.inpaint import get_inpainter
    from geofill.config import InpaintConfig

    monkeypatch.setitem(sys.modules, "patchmatch", None)
    with pytest.raises(MissingExtraError, match=r'PatchMatch inpainting needs .*"geofill\[patchmatch\]"'):
        get_inpainter(InpaintConfig(method="patchmatch"))


#: What a measurement's history looks like in a description: a dB figure, a before -> after pair of
#: numbers, a DEV set or a scene of it, "(was N)", a benchmark script, a speed-up factor.
_HISTORY = re.compile(
    r"\d\s*dB\b|[\d)]\s*(->|→)\s*[\d(]|\bDEV\b|\bwas \d|benchmarks/|\d(\.\d+)?x (faster|slower)|"
    r"\b(fox|tower|berlin|lund|livingroom|living room|apple|kitti|eth3d|terrace|facade|cyprus|red car)\b",
    re.IGNORECASE,
)


def test_config_descriptions_say_what_a_setting_does_not_its_measurements():
    """The page shows every description to users: measurements and their history belong in
    docs/architecture.md, not in a setting's help."""
    found = {}
    for top in dataclasses.fields(FillConfig):
        section = typing.get_type_hints(FillConfig)[top.name]
        leaves = dataclasses.fields(section) if dataclasses.is_dataclass(section) else [top]
        for f in leaves:
            if m := _HISTORY.search(f.metadata["help"]):
                found[f"{top.name}.{f.name}"] = m.group(0)
    assert found == {}
