"""The command line: a successful fill with debug output, and every bad input refused with a
one-line message, a non-zero exit status and nothing written."""

from __future__ import annotations

import argparse
import json
import re
import struct
import subprocess
import sys
import time
import typing
import zlib

import cv2
import numpy as np
import pytest
from PIL import ExifTags, Image

from geofill.cli import build_parser, main
from geofill.config import DepthConfig, FillConfig, choices
from geofill.synthetic import blanked, make_pair


def _write_rgb(path, rgb):
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("inputs")
    p = make_pair(seed=3, width=320, height=240)
    _write_rgb(d / "target.png", p.target)
    _write_rgb(d / "source.png", p.source)
    cv2.imwrite(str(d / "mask.png"), p.hole.astype(np.uint8) * 255)
    return d, p


def run(argv, capsys):
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    return code, err


def fill_args(d, out, **over):
    paths = {"target": d / "target.png", "mask": d / "mask.png", "source": d / "source.png"} | over
    return ["fill", "-o", out, *(x for k in ("target", "mask", "source") for x in (f"--{k}", paths[k]))]


def test_fill_writes_output_and_debug(files, tmp_path, capsys):
    d, p = files
    out, dbg = tmp_path / "out.png", tmp_path / "dbg"
    t0 = time.perf_counter()
    code, err = run([*fill_args(d, out), "--debug-dir", dbg], capsys)
    wall = time.perf_counter() - t0
    assert code == 0
    # The default output is plain: the done fraction, then the line a user needs, with the time the
    # command took (not the stages' times summed); the stage details are for --verbose.
    assert not any(re.match(r"geofill: (ref \d+: )?match ", line) for line in err), err
    *steps, last = err
    assert steps == [f"geofill: {pct}% done" for pct in (25, 50, 75)]
    said = re.fullmatch(
        rf"geofill: wrote {re.escape(str(out))} in (\d+\.\d) s: (\d+)% of the hole from source.png, .*", last
    )
    assert said, last
    assert 0 < float(said[1]) <= wall + 0.05, (said[1], wall)
    result = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    assert np.array_equal(result[~p.hole], p.target[~p.hole])
    assert not np.array_equal(result[p.hole], np.zeros_like(result[p.hole]))
    names = {f.name for f in dbg.iterdir()}
    expected = {"matches_1.jpg", "depth_1.png", "depth_1.npy", "warped_1.png", "refined_1.png"}
    assert expected | {"coverage.png", "overview.jpg", "report.json"} <= names
    report = json.loads((dbg / "report.json").read_text())
    assert report["status"] == "reference"
    ref = report["references"][0]
    assert ref["pose"]["n_inliers"] > 50 and len(ref["pose"]["source_to_target"]) == 4
    # The focal used is the default prior (750 px at a 1280-px long side) times the focal stage's scale.
    focal = ref["focal"]
    assert focal["prior_origin_target"] == "default" and focal["status"] in ("estimated", "prior")
    assert ref["intrinsics_target"]["fx_px"] == pytest.approx(750 * 320 / 1280 * focal["scale_target"])
    assert set(report["timings_s"]) >= {"match", "pose", "depth", "render", "fuse"}
    assert report["config"]["render"]["edge_threshold"] == 0.04


def test_debug_overview_of_a_photo_of_extreme_aspect_is_written(tmp_path, capsys):
    """A 4000x64 photo: its tiles scaled to the sheet's 300-px height were 18750 px wide each, a
    sheet past JPEG's 65500-px limit, and the overview's write failed after the fill was written.
    Now each tile is at most three heights wide."""
    rng = np.random.default_rng(0)
    strip = cv2.GaussianBlur((rng.random((64, 4000, 3)) * 255).astype(np.uint8), (0, 0), 2)
    hole = np.zeros((64, 4000), np.uint8)
    hole[20:44, 1300:1500] = 255
    _write_rgb(tmp_path / "target.png", strip)
    _write_rgb(tmp_path / "source.png", np.roll(strip, 3, axis=1))
    cv2.imwrite(str(tmp_path / "mask.png"), hole)
    out, dbg = tmp_path / "o.png", tmp_path / "dbg"
    flags = ("--debug-dir", dbg, "--preset", "telea", "--allow-fallback")
    code, err = run([*fill_args(tmp_path, out), *flags], capsys)
    assert code == 0, err
    sheet = cv2.imread(str(dbg / "overview.jpg"))
    assert sheet.shape[:2] == (300, 4 * 900)  # target, reference, fill, coverage: 900 x 300 each
    # The strip lies under its label, not behind it: 900 px wide, 14 px high, from row 28.
    assert sheet[28:42, 900:1800].mean() > 60 and sheet[44:, 900:1800].max() < 40


def test_verbose_prints_every_stage_with_its_details(files, tmp_path, capsys):
    d, _ = files
    code, err = run([*fill_args(d, tmp_path / "o.png"), "--verbose"], capsys)
    assert code == 0
    stages = [m[1] for line in err if (m := re.match(r"geofill: (\w+(?: \w+)?) +\d+\.\d\d s", line))]
    assert stages[:3] == ["check inputs", "prepare", "match"] and stages[-2:] == ["fuse", "composite"]
    assert any("verified" in line and "matches" in line for line in err)  # the match stage's summary
    assert err[-1].startswith(f"geofill: wrote {tmp_path / 'o.png'} in ")


def test_quiet_prints_nothing(files, tmp_path, capsys):
    d, _ = files
    code, err = run([*fill_args(d, tmp_path / "o.jpg"), "--quiet"], capsys)
    assert code == 0 and err == []


def _corrupt(path):
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 20)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _truncated_png(path, rgb):
    """A PNG of ``rgb`` whose image data is a complete zlib stream holding its first third of rows."""
    h, w = rgb.shape[:2]
    rows = b"".join(b"\0" + rgb[y].tobytes() for y in range(h // 3))
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    data = _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IDAT", zlib.compress(rows)) + _png_chunk(b"IEND", b"")
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + data)


@pytest.mark.parametrize(
    ("case", "expected_code", "needle"),
    [
        ("missing", 2, "not found"),
        ("corrupt", 2, "corrupt"),
        ("truncated", 2, "truncated or corrupt (its image data stops at 33% of its 320x240 pixels)"),
        ("mask_size", 2, "mask is 100x100 but the target"),
        ("empty_mask", 2, "no hole pixel"),
        ("full_mask", 2, "%"),
        ("tiny", 2, "64"),
        ("too_many_pixels", 2, "pixels"),
        ("bad_extension", 4, ".gif"),
        ("bad_config_key", 3, "depth.nope"),
    ],
)
def test_bad_input_is_one_line_error_and_writes_nothing(files, tmp_path, capsys, case, expected_code, needle):
    d, p = files
    out, dbg = tmp_path / "out.png", tmp_path / "dbg"
    extra: list = ["--debug-dir", dbg]
    over = {}
    if case == "missing":
        over["source"] = tmp_path / "nope.png"
    elif case == "corrupt":
        _corrupt(tmp_path / "bad.png")
        over["target"] = tmp_path / "bad.png"
    elif case == "truncated":
        _truncated_png(tmp_path / "cut.png", p.target)
        over["target"] = tmp_path / "cut.png"
    elif case == "mask_size":
        cv2.imwrite(str(tmp_path / "m.png"), np.full((100, 100), 255, np.uint8))
        over["mask"] = tmp_path / "m.png"
    elif case == "empty_mask":
        cv2.imwrite(str(tmp_path / "m.png"), np.zeros(p.hole.shape, np.uint8))
        over["mask"] = tmp_path / "m.png"
    elif case == "full_mask":
        cv2.imwrite(str(tmp_path / "m.png"), np.full(p.hole.shape, 255, np.uint8))
        over["mask"] = tmp_path / "m.png"
    elif case == "tiny":
        _write_rgb(tmp_path / "s.png", p.source[:40, :40])
        over["source"] = tmp_path / "s.png"
    elif case == "too_many_pixels":
        extra += ["--max-pixels", "50000"]
    elif case == "bad_extension":
        out = tmp_path / "out.gif"
    elif case == "bad_config_key":
        extra += ["--set", "depth.nope=1"]
    code, err = run([*fill_args(d, out, **over), *extra], capsys)
    assert code == expected_code
    assert len(err) == 1 and err[0].startswith("geofill: error:")
    assert needle in err[0]
    assert not out.exists() and not dbg.exists()
    assert sorted(f.name for f in tmp_path.iterdir()) == sorted(
        f.name for f in tmp_path.iterdir() if f.suffix != ".tmp" and not f.name.startswith(".")
    )


@pytest.mark.parametrize(
    ("role", "spelling"),
    [
        ("target", "dotted"),  # -o sub/../target.png
        ("target", "link"),  # -o a symbolic link to the target
        ("mask", "same"),
        ("source", "same"),
        ("source-mask", "same"),
    ],
)
def test_an_output_that_is_an_input_is_refused_before_any_work(files, tmp_path, capsys, role, spelling):
    """However the output path is spelt, the photo it names is not replaced without --overwrite."""
    d, p = files
    for name in ("target.png", "mask.png", "source.png"):
        (tmp_path / name).write_bytes((d / name).read_bytes())
    cv2.imwrite(str(tmp_path / "source_mask.png"), np.zeros(p.source.shape[:2], np.uint8))
    (tmp_path / "sub").mkdir()
    victim = tmp_path / ("source_mask.png" if role == "source-mask" else f"{role}.png")
    out = {"dotted": tmp_path / "sub" / ".." / victim.name, "link": tmp_path / "link.png"}.get(
        spelling, victim
    )
    if spelling == "link":
        out.symlink_to(victim)
    before = {f.name: f.read_bytes() for f in tmp_path.iterdir() if f.is_file()}
    argv = [*fill_args(tmp_path, out), "--source-mask", tmp_path / "source_mask.png"]
    code, err = run(argv, capsys)
    assert code == 4
    flag = f"--{role} {victim}"
    assert err == [
        f"geofill: error: {out}: is the {flag}; the output would replace it "
        "(give another -o, or --overwrite to replace it)"
    ]
    assert {f.name: f.read_bytes() for f in tmp_path.iterdir() if f.is_file()} == before


def test_overwrite_lets_the_output_replace_the_target(files, tmp_path, capsys):
    d, _ = files
    for name in ("target.png", "mask.png", "source.png"):
        (tmp_path / name).write_bytes((d / name).read_bytes())
    target, elsewhere = tmp_path / "target.png", tmp_path / "elsewhere" / "fill.png"
    elsewhere.parent.mkdir()
    assert run([*fill_args(tmp_path, elsewhere), "-q"], capsys) == (0, [])
    assert run([*fill_args(tmp_path, target), "--overwrite", "-q"], capsys) == (0, [])
    # The target now holds the fill, the same as written elsewhere; nothing else was left.
    assert np.array_equal(cv2.imread(str(target)), cv2.imread(str(elsewhere)))
    assert not np.array_equal(cv2.imread(str(target)), cv2.imread(str(d / "target.png")))
    assert sorted(f.name for f in tmp_path.iterdir()) == ["elsewhere", "mask.png", "source.png", "target.png"]


def test_a_corrupt_exif_block_is_a_note_not_a_python_warning(files, tmp_path):
    d, p = files
    exif = Image.Exif()
    exif[ExifTags.Base.Make], exif[ExifTags.Base.Model] = "Apple", "iPhone 4S"
    exif.get_ifd(ExifTags.IFD.Exif)[ExifTags.Base.FocalLength] = 4.28
    target = tmp_path / "t.jpg"
    Image.fromarray(p.target).save(target, quality=95, exif=exif.tobytes()[:40])  # cut inside an IFD
    argv = [*fill_args(d, tmp_path / "o.png", target=target), "--allow-fallback"]
    run = subprocess.run(
        [sys.executable, "-m", "geofill.cli", *map(str, argv)], capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr
    assert "Warning" not in run.stderr and ".py:" not in run.stderr, run.stderr
    assert run.stderr.splitlines()[0] == (
        f"geofill: note: {target}: part of its metadata could not be read (Truncated File Read)"
    )


def test_config_dump_roundtrip_and_overrides(tmp_path, capsys):
    assert main(["config", "--set", "matching.ratio=0.7", "--depth", "file"]) == 0
    text = capsys.readouterr().out
    cfg = FillConfig.from_dict(json.loads(text))
    assert cfg.matching.ratio == 0.7 and cfg.depth.backend == "file"
    path = tmp_path / "cfg.json"
    path.write_text(text)
    assert main(["config", "--config", str(path)]) == 0
    assert FillConfig.from_dict(json.loads(capsys.readouterr().out)) == cfg


def _option(command: str, flag: str, parser: argparse.ArgumentParser | None = None) -> argparse.Action:
    parser = parser or build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]
    return next(a for a in sub._actions if flag in a.option_strings)


@pytest.mark.parametrize("command", ["fill", "batch", "config"])
def test_flag_choices_are_the_config_literals(command):
    hints = typing.get_type_hints(DepthConfig)
    assert _option(command, "--depth").choices == typing.get_args(hints["backend"])
    assert _option(command, "--depth-kind").choices == typing.get_args(hints["file_kind"])


def test_a_value_added_to_the_literal_is_offered(monkeypatch):
    monkeypatch.setitem(DepthConfig.__annotations__, "backend", 'Literal["auto", "stereo", "lidar"]')
    assert choices(DepthConfig, "backend") == ("auto", "stereo", "lidar")
    assert _option("fill", "--depth").choices == ("auto", "stereo", "lidar")
    with pytest.raises(TypeError, match=r"DepthConfig\.file_scale is not a Literal field"):
        choices(DepthConfig, "file_scale")


def test_a_value_outside_the_literal_is_refused_naming_the_choices(capsys):
    with pytest.raises(SystemExit) as info:
        main(["config", "--depth", "lidar"])
    err = capsys.readouterr().err.strip()
    assert info.value.code == 2 and len(err.splitlines()) == 1
    assert err.startswith("geofill: error: config: argument --depth: invalid choice: 'lidar' (choose from ")
    assert all(repr(value) in err for value in choices(DepthConfig, "backend"))


def test_demo_writes_side_by_side_and_numbers(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "demo"), "--quiet"]) == 0
    numbers = json.loads((tmp_path / "demo" / "numbers.json").read_text())
    g, s = numbers["geofill"], numbers["single_image_inpainting"]
    assert g["status"] == "reference"
    assert g["rotation_error_deg"] < 0.5 and g["translation_direction_error_deg"] < 2.0
    assert g["psnr_hole_db"] > s["psnr_hole_db"] + 3.0
    img = cv2.imread(str(tmp_path / "demo" / "side_by_side.png"))
    assert img.shape == (480, 5 * 640, 3)


@pytest.mark.parametrize("command", ["", "fill", "batch", "serve", "demo", "config", "models", "eval"])
def test_help_is_plain_text(command, capsys):
    with pytest.raises(SystemExit) as stop:
        main([*filter(None, [command]), "--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith("usage: geofill")
    assert not re.search(r"``|:(func|class|mod|data):`", text), text


def test_command_exits_with_mains_status(files, tmp_path):
    """``geofill`` (``cli.run``) ends the process with :func:`main`'s status, output flushed."""
    import subprocess
    import sys

    d, _ = files
    ok = subprocess.run([sys.executable, "-m", "geofill.cli", "config"], capture_output=True, text=True)
    assert ok.returncode == 0 and json.loads(ok.stdout)["depth"]["backend"] == "auto"
    args = ["fill", "--target", str(d / "missing.png"), "--mask", str(d / "mask.png")]
    args += ["--source", str(d / "source.png"), "-o", str(tmp_path / "out.png")]
    bad = subprocess.run([sys.executable, "-m", "geofill.cli", *args], capture_output=True, text=True)
    assert bad.returncode == main(args) != 0
    assert bad.stderr.strip().startswith("geofill: error:") and "missing.png" in bad.stderr


@pytest.fixture(scope="module")
def masked_files(tmp_path_factory):
    """A pair whose hole shows nothing, the source's mask over the right of it (where most of the
    hole comes from), one of another size, and the source with its mask beside it in refs/."""
    d = tmp_path_factory.mktemp("masked")
    p = make_pair(seed=0, width=320, height=240)
    _write_rgb(d / "target.png", blanked(p.target, p.hole))
    _write_rgb(d / "source.png", p.source)
    cv2.imwrite(str(d / "mask.png"), p.hole.astype(np.uint8) * 255)
    keep_out = np.zeros(p.hole.shape, np.uint8)
    keep_out[:, 240:] = 255
    cv2.imwrite(str(d / "keep_out.png"), keep_out)
    cv2.imwrite(str(d / "small.png"), keep_out[:100, :100])
    (d / "refs").mkdir()
    _write_rgb(d / "refs" / "view.png", p.source)
    cv2.imwrite(str(d / "refs" / "view.mask.png"), keep_out)
    return d


def _report(dbg) -> dict:
    return json.loads((dbg / "report.json").read_text())


def test_source_mask_pixels_are_never_copied(masked_files, tmp_path, capsys):
    """The same fill with and without --source-mask: the masked one refuses part of the hole and
    takes less of it from the reference; --sources DIR finds view.mask.png beside view.png."""
    d = masked_files
    base = ["fill", "--target", d / "target.png", "--mask", d / "mask.png", "-o"]
    code, err = run(
        [*base, tmp_path / "plain.png", "--source", d / "source.png", "--debug-dir", tmp_path / "p"], capsys
    )
    assert code == 0
    plain = _report(tmp_path / "p")
    masked_args = [
        "--source",
        d / "source.png",
        "--source-mask",
        d / "keep_out.png",
        "--debug-dir",
        tmp_path / "m",
    ]
    code, err = run([*base, tmp_path / "masked.png", *masked_args], capsys)
    assert code == 0
    masked = _report(tmp_path / "m")
    assert plain["refused_fraction"].get("masked", 0.0) == 0.0
    assert masked["refused_fraction"]["masked"] > 0.2
    assert masked["supplied_fraction"][0] < plain["supplied_fraction"][0] - 0.2
    assert f"geofill: {d / 'source.png'}: 25% of it is never copied (masked by {d / 'keep_out.png'})" in err
    # The painted part, broken down: masked, and what no reference sees (they add up to it).
    assert "% of the hole was not copied because it was masked in the references, " in err[-1]
    assert err[-1].endswith("% no reference sees")
    # the hole pixels differ where the reference was refused; the rest of the image is the target's
    hole = cv2.imread(str(d / "mask.png"), cv2.IMREAD_GRAYSCALE) > 127
    a, b = cv2.imread(str(tmp_path / "plain.png")), cv2.imread(str(tmp_path / "masked.png"))
    assert np.array_equal(a[~hole], b[~hole]) and not np.array_equal(a[hole], b[hole])

    code, err = run(
        [*base, tmp_path / "folder.png", "--sources", d / "refs", "--debug-dir", tmp_path / "f"], capsys
    )
    assert code == 0
    folder = _report(tmp_path / "f")
    assert len(folder["references"]) == 1  # view.mask.png is no reference
    assert folder["refused_fraction"] == masked["refused_fraction"]
    assert np.array_equal(cv2.imread(str(tmp_path / "folder.png")), b)


@pytest.mark.parametrize(
    ("case", "code", "needle"),
    [
        ("wrong_size", 2, "small.png: reference mask is 100x100 but its reference {d}/source.png is 320x240"),
        ("before_source", 2, "--source-mask: {d}/keep_out.png: no --source before it"),
        ("two_for_one", 2, "--source {d}/source.png has a mask already ({d}/keep_out.png)"),
        (
            "no_reference",
            2,
            "{d}/orphans/street.mask.png: reference mask without a reference: no image named street.*",
        ),
        ("folder_wrong_size", 2, "{d}/sized/view.mask.png: reference mask is 100x100 but its reference"),
    ],
)
def test_bad_source_masks_are_one_line_naming_the_file(masked_files, tmp_path, capsys, case, code, needle):
    d = masked_files
    args = ["fill", "--target", d / "target.png", "--mask", d / "mask.png", "-o", tmp_path / "out.png"]
    args += {
        "wrong_size": ["--source", d / "source.png", "--source-mask", d / "small.png"],
        "before_source": ["--source-mask", d / "keep_out.png", "--source", d / "source.png"],
        "two_for_one": [
            "--source",
            d / "source.png",
            "--source-mask",
            d / "keep_out.png",
            "--source-mask",
            d / "small.png",
        ],
        "no_reference": ["--source", d / "source.png", "--sources", d / "orphans"],
        "folder_wrong_size": ["--sources", d / "sized"],
    }[case]
    (d / "orphans").mkdir(exist_ok=True)
    _write_rgb(d / "orphans" / "view.png", cv2.imread(str(d / "source.png"))[..., ::-1])
    cv2.imwrite(str(d / "orphans" / "street.mask.png"), np.zeros((240, 320), np.uint8))
    (d / "sized").mkdir(exist_ok=True)
    _write_rgb(d / "sized" / "view.png", cv2.imread(str(d / "source.png"))[..., ::-1])
    cv2.imwrite(str(d / "sized" / "view.mask.png"), np.zeros((100, 100), np.uint8))
    try:
        got, err = run(args, capsys)
    except SystemExit as exc:  # argparse's usage errors
        got, err = exc.code, capsys.readouterr().err.strip().splitlines()
    assert got == code
    assert len(err) == 1 and err[0].startswith("geofill: error:")
    assert needle.format(d=d) in err[0], err[0]
    assert not (tmp_path / "out.png").exists()
