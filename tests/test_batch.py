"""``geofill batch`` end to end on rendered scenes: fills in worker processes, results.jsonl, resume,
bad items among good ones, exit statuses, Ctrl-C; and the single fill's ``--allow-fallback`` rule."""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from geofill.batch.display import BatchDisplay, summary_table
from geofill.batch.runner import _remove_unrecorded, exit_status
from geofill.cli import main
from geofill.errors import EXIT_FELL_BACK, EXIT_INTERRUPTED, EXIT_ITEMS_FAILED, EXIT_TERMINATED
from geofill.synthetic import blanked, make_pair

SEEDS = (3, 5)


def _write_rgb(path, rgb):
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def _read_rgb(path):
    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def _noise(shape, seed=0):
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


@pytest.fixture(scope="module")
def pairs():
    return {f"t{s}": make_pair(seed=s, width=320, height=240) for s in SEEDS}


def _shoot(root, pairs, names=None):
    """images/, masks/ and refs/<stem>/ for the pairs (under the given names)."""
    names = names or {name: name for name in pairs}
    for name, key in names.items():
        p = pairs[key]
        _write_rgb(root / "images" / f"{name}.png", blanked(p.target, p.hole))
        (root / "masks").mkdir(parents=True, exist_ok=True)
        assert cv2.imwrite(str(root / "masks" / f"{name}.png"), p.hole.astype(np.uint8) * 255)
        _write_rgb(root / "refs" / name / "view.png", p.source)
    return root


def _batch(root, out, *extra):
    argv = ["batch", "--images", root / "images", "--masks", root / "masks", "--out", out, *extra]
    return main([str(a) for a in argv])


def _records(out):
    return [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]


def test_exit_status_precedence():
    ok, fell, failed = "reference", "single_image", "failed"
    assert exit_status([ok, ok], allow_fallback=False, interrupted=False) == 0
    assert exit_status([ok, fell], allow_fallback=False, interrupted=False) == EXIT_FELL_BACK == 5
    assert exit_status([ok, fell], allow_fallback=True, interrupted=False) == 0
    assert exit_status([fell, failed], allow_fallback=True, interrupted=False) == EXIT_ITEMS_FAILED == 7
    assert exit_status([ok], allow_fallback=True, interrupted=True) == EXIT_INTERRUPTED == 130


def test_batch_fills_then_resumes_with_bad_items(pairs, tmp_path, capsys):
    root, out = _shoot(tmp_path, pairs), tmp_path / "out"
    code = _batch(root, out, "--sources-per-image", root / "refs", "--jobs", "2")
    assert code == 0
    first = {r["item"]: r for r in _records(out)}
    assert set(first) == {"t3", "t5"}
    for name, r in first.items():
        p = pairs[name]
        result = _read_rgb(out / f"{name}.png")
        assert np.array_equal(result[~p.hole], p.target[~p.hole])
        assert r["status"] == "reference" and r["error"] is None and r["fallback_reason"] is None
        assert r["references"] == [str(root / "refs" / name / "view.png")]
        assert r["coverage"] > 0.5
        assert {"read", "match", "pose", "render", "composite", "write"} <= set(r["timings_s"])
        assert r["worker"]["pid"] != os.getpid() and r["worker"]["peak_rss_mib"] > 50
    assert "filled from a reference         2" in capsys.readouterr().out
    mtimes = {name: (out / f"{name}.png").stat().st_mtime_ns for name in first}

    # Bad items join the folder: a corrupt file, a mask of another size, an image without a mask.
    (root / "images" / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 50)
    shutil.copy(root / "masks" / "t3.png", root / "masks" / "corrupt.png")
    _write_rgb(root / "refs" / "corrupt" / "view.png", pairs["t3"].source)
    _write_rgb(root / "images" / "small.png", pairs["t3"].target[:200, :300])
    shutil.copy(root / "masks" / "t3.png", root / "masks" / "small.png")
    _write_rgb(root / "refs" / "small" / "view.png", pairs["t3"].source)
    _write_rgb(root / "images" / "nomask.png", pairs["t5"].target)
    code = _batch(root, out, "--sources-per-image", root / "refs", "--jobs", "2", "--resume")
    assert code == EXIT_ITEMS_FAILED
    records = _records(out)
    by = {r["item"]: r for r in records}
    assert len(records) == len(by) == 5  # one line per item
    assert by["t3"] == first["t3"] and by["t5"] == first["t5"]  # kept, not run again
    assert all((out / f"{n}.png").stat().st_mtime_ns == t for n, t in mtimes.items())
    images = root / "images"
    assert by["corrupt"]["status"] == "failed" and by["corrupt"]["error"].startswith(
        f"{images / 'corrupt.png'}:"
    )
    assert by["small"]["error"] == (
        f"{root / 'masks' / 'small.png'}: mask is 320x240 but the target {images / 'small.png'} is 300x200"
    )
    assert by["nomask"]["error"] == f"{images / 'nomask.png'}: no mask with stem 'nomask' in {root / 'masks'}"
    assert not any((out / f"{n}.png").exists() for n in ("corrupt", "small", "nomask"))
    summary = capsys.readouterr().out
    assert "skipped (already complete)      2" in summary and "failed                          3" in summary


def test_batch_fallbacks_exit_5_unless_allowed(pairs, tmp_path):
    p = pairs["t3"]
    root = _shoot(tmp_path, {"t3": p})
    _write_rgb(root / "refs" / "t3" / "view.png", _noise(p.source.shape))  # a useless reference
    out = tmp_path / "out"
    assert _batch(root, out, "--sources-per-image", root / "refs", "--jobs", "1") == EXIT_FELL_BACK
    (r,) = _records(out)
    assert r["status"] == "single_image" and r["fallback_reason"] and r["coverage"] == 0.0
    result = _read_rgb(out / "t3.png")
    assert np.array_equal(result[~p.hole], p.target[~p.hole])
    args = ("--sources-per-image", root / "refs", "--jobs", "1", "--allow-fallback")
    assert _batch(root, tmp_path / "out2", *args) == 0

    # --sources: the only candidate is noise, so none is picked and the hole is inpainted.
    assert _batch(root, tmp_path / "out3", "--sources", root / "refs" / "t3", "--jobs", "1") == EXIT_FELL_BACK
    (r,) = _records(tmp_path / "out3")
    assert r["status"] == "single_image" and r["references"] == []
    assert r["fallback_reason"].startswith("no candidate reference has 20 verified matches near the hole")
    assert r["candidates"][0]["picked"] is False


def test_results_say_which_reference_was_dropped_and_why(pairs, tmp_path, capsys):
    p = pairs["t3"]
    root = _shoot(tmp_path, {"t3": p})
    noise = root / "refs" / "t3" / "zz_noise.png"
    _write_rgb(noise, _noise(p.source.shape))
    out = tmp_path / "out"
    assert _batch(root, out, "--sources-per-image", root / "refs", "--jobs", "1") == 0
    (r,) = _records(out)
    assert r["status"] == "reference"
    assert r["references"] == [str(root / "refs" / "t3" / "view.png"), str(noise)]  # both were given
    (dropped,) = r["references_dropped"]
    assert dropped["reference"] == str(noise)
    assert dropped["reason"] == "it does not show enough of the same scene"  # plain words
    assert dropped["detail"]  # the technical reason, for whoever debugs
    line = capsys.readouterr().err
    assert "of the hole filled from 1 reference(s); 1 reference(s) not used" in line


def test_rate_counts_only_items_that_were_filled():
    stream = io.StringIO()
    display = BatchDisplay(3, stream)
    failed = {"item": "a", "status": "failed", "error": "a.png: no mask with stem 'a'"}
    display.update(failed)  # at once, before any fill: no rate to speak of yet
    assert stream.getvalue() == "geofill: [1/3] a: FAILED: a.png: no mask with stem 'a'\n"
    display.t0 -= 30.0  # as if the next item took 30 s
    display.update({"item": "b", "status": "reference", "references": ["r.png"], "coverage": 0.9})
    assert stream.getvalue().splitlines()[1].endswith("| 2.0 fills/min, ETA 30s")
    table = summary_table(
        [failed], total=3, skipped=0, elapsed_s=0.02, jobs="1 job(s)", results_path="r", interrupted=False
    )
    assert "fills/min" not in table.splitlines()[0]


def test_single_fill_allow_fallback_rule(pairs, tmp_path, capsys):
    p = pairs["t3"]
    _write_rgb(tmp_path / "target.png", p.target)
    _write_rgb(tmp_path / "noise.png", _noise(p.source.shape))
    assert cv2.imwrite(str(tmp_path / "mask.png"), p.hole.astype(np.uint8) * 255)
    argv = ["fill", "--target", tmp_path / "target.png", "--mask", tmp_path / "mask.png"]
    argv += ["--source", tmp_path / "noise.png", "-q"]
    code = main([str(a) for a in [*argv, "-o", tmp_path / "a.png"]])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == EXIT_FELL_BACK
    assert (tmp_path / "a.png").is_file()  # the result is still written
    assert len(err) == 1 and err[0].startswith(
        "geofill: no reference photo could be used, the whole hole was painted from its surroundings "
        "(reference 1 (noise.png) was not used: it does not show enough of the same scene"
    ), err
    assert "exit status 5 (--allow-fallback accepts it)" in err[0]
    assert main([str(a) for a in [*argv, "-o", tmp_path / "b.png", "--allow-fallback"]]) == 0
    assert np.array_equal(_read_rgb(tmp_path / "a.png"), _read_rgb(tmp_path / "b.png"))


HANG = Path(__file__).with_name("batch_hang.py")


def _start_batch(tmp_path, pairs, *extra, out=None):
    """A ``geofill batch`` subprocess of 2 small items and one, ``hang``, that writes its output and
    then never finishes (tests/batch_hang.py), returned once the 2 are recorded and the third's
    output is written: the batch cannot end before a signal, and how many items it recorded is known."""
    names = {f"{key}_0": key for key in pairs} | {"hang": "t3"}
    root = _shoot(tmp_path, pairs, names)
    out = out or tmp_path / "out"
    args = ["batch", "--images", str(root / "images"), "--masks", str(root / "masks")]
    args += ["--sources-per-image", str(root / "refs"), "--out", str(out), "--jobs", "2", *extra]
    # A session of its own, so that a signal can go to the whole process group as a service manager
    # sends it (the workers get it too).
    proc = subprocess.Popen(
        [sys.executable, str(HANG), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    results, hung = out / "results.jsonl", out / "hang.png"
    before = hung.read_bytes() if hung.is_file() else None  # the photo itself when out is --images
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        recorded = len(results.read_text().splitlines()) if results.is_file() else 0
        if recorded == len(names) - 1 and hung.is_file() and hung.read_bytes() != before:
            break
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.1)  # polling for a state the batch cannot leave by itself, not a race
    else:
        proc.kill()
        pytest.fail(f"the batch did not reach its hanging item: {proc.communicate()}")
    return proc, names, out, [sys.executable, "-m", "geofill.cli", *args]


def test_ctrl_c_keeps_finished_items_and_prints_the_summary(pairs, tmp_path):
    proc, names, out, _ = _start_batch(tmp_path, pairs)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == EXIT_INTERRUPTED, stderr
    records = _records(out)
    assert sorted(r["item"] for r in records) == sorted(n for n in names if n != "hang")
    assert "STOPPED by Ctrl-C" in stdout and re.search(r"not run \(stopped by Ctrl-C\) +1\n", stdout)
    for r in records:
        assert r["status"] == "reference"
        p = pairs[names[r["item"]]]
        assert np.array_equal(_read_rgb(r["output"])[~p.hole], p.target[~p.hole])
    # The hanging item's output, written by this run but never recorded, is removed: every file left
    # is results.jsonl or a recorded image.
    assert sorted(f.name for f in out.iterdir()) == sorted(
        ["results.jsonl", *(f"{r['item']}.png" for r in records)]
    )


@pytest.mark.parametrize("to", ["batch", "group"])
def test_sigterm_stops_at_once_keeping_finished_items_for_resume(pairs, tmp_path, to):
    proc, names, out, cmd = _start_batch(tmp_path, pairs)
    t0 = time.monotonic()
    if to == "group":
        os.killpg(proc.pid, signal.SIGTERM)
    else:
        proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)
    stopped_s = time.monotonic() - t0
    assert proc.returncode == EXIT_TERMINATED == 143, stderr
    assert "STOPPED by SIGTERM" in stdout
    # Within the time a worker takes to die, not after the items in flight finish (seconds each).
    assert stopped_s < 3.0, stopped_s
    records = _records(out)
    assert sorted(r["item"] for r in records) == sorted(n for n in names if n != "hang")
    # A worker's fill cut short by the signal is no failed item: every record is a finished fill.
    assert all(r["status"] == "reference" for r in records), records
    # Every output written is recorded, and nothing else is left (no temporary file of a write).
    written = {f.stem for f in out.glob("*.png")}
    assert {r["item"] for r in records} == written
    assert {f.name for f in out.iterdir()} == {"results.jsonl"} | {f"{n}.png" for n in written}
    if to == "group":
        return
    # --resume (the real command, whose items all finish) skips exactly those and runs the other.
    rerun = subprocess.run([*cmd, "--resume"], capture_output=True, text=True, timeout=600)
    assert rerun.returncode == 0, rerun.stderr
    assert f"skipped (already complete)  {len(records):>5d}" in rerun.stdout
    after = {r["item"]: r for r in _records(out)}
    assert set(after) == set(names)
    assert all(after[r["item"]] == r for r in records)  # kept as they were, not run again


def test_a_stop_never_removes_a_file_the_run_did_not_create(pairs, tmp_path):
    """--out the --images folder with --overwrite: the hanging item replaces its target with its
    fill and is stopped before its record. The file was there before the run, so the stop keeps it
    (deciding by modification time, it removed the user's photo)."""
    images = tmp_path / "images"
    proc, names, _, _ = _start_batch(tmp_path, pairs, "--overwrite", out=images)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == EXIT_INTERRUPTED, stderr
    assert sorted(f.name for f in images.glob("*.png")) == sorted(f"{n}.png" for n in names)
    p = pairs["t3"]
    hung = _read_rgb(images / "hang.png")  # the fill, complete, where the photo was
    assert np.array_equal(hung[~p.hole], p.target[~p.hole]) and not np.array_equal(
        hung, blanked(p.target, p.hole)
    )


def test_a_stop_removes_only_an_unrecorded_output_the_run_created(tmp_path):
    """Known by name: the output of an item stopped in flight is removed when no file of its name
    existed before the run, kept otherwise however recently it was written; a write cut short (its
    temporary file) goes either way, and other files stay."""
    out = tmp_path / "a.png"
    out.write_bytes(b"written just now, but over a file that was there")
    (tmp_path / ".a.png.123.tmp").write_bytes(b"half")  # a write cut short
    (tmp_path / "b.png").write_bytes(b"another item")
    _remove_unrecorded(out, created=False)
    assert sorted(f.name for f in tmp_path.iterdir()) == ["a.png", "b.png"]
    _remove_unrecorded(out, created=True)
    assert sorted(f.name for f in tmp_path.iterdir()) == ["b.png"]
    _remove_unrecorded(out, created=True)  # nothing there: nothing to do


@pytest.mark.parametrize("out", ["images", "masks", "refs/t3", "link"])
def test_a_folder_holding_inputs_is_no_output_folder_without_overwrite(pairs, tmp_path, capsys, out):
    root = _shoot(tmp_path, pairs)
    (tmp_path / "link").symlink_to(root / "images")  # the same folder under another name
    before = {f: f.read_bytes() for f in tmp_path.rglob("*") if f.is_file()}
    code = _batch(root, tmp_path / out, "--sources-per-image", root / "refs")
    assert code == 4
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"geofill: error: {tmp_path / out}: the output folder holds input files (")
    assert line.endswith(
        "that the outputs can replace; choose another --out, or give --overwrite to allow it"
    )
    assert {f: f.read_bytes() for f in tmp_path.rglob("*") if f.is_file()} == before  # nothing written


def test_batch_keeps_each_photos_format_tables_and_metadata(pairs, tmp_path):
    """A JPEG target gives a JPEG output at its own quantisation tables and subsampling, with its
    EXIF and ICC profile; a PNG target a PNG. results.jsonl names those files and --resume finds
    them."""
    from PIL import Image, JpegImagePlugin

    root = _shoot(tmp_path, pairs)
    p = pairs["t3"]
    (root / "images" / "t3.png").unlink()
    exif = Image.Exif()
    exif[0x010F] = "geofill-test-camera"  # Make
    icc = b"\x00\x00\x02\x0cfake-profile-bytes" + bytes(500)
    shot = root / "images" / "t3.JPG"
    Image.fromarray(blanked(p.target, p.hole)).save(
        shot, "JPEG", quality=80, subsampling=1, exif=exif.tobytes(), icc_profile=icc
    )
    out = tmp_path / "out"
    assert _batch(root, out, "--sources-per-image", root / "refs", "--jobs", "1") == 0
    assert sorted(f.name for f in out.iterdir()) == ["results.jsonl", "t3.JPG", "t5.png"]
    assert {r["item"]: r["output"] for r in _records(out)} == {
        "t3": str(out / "t3.JPG"),
        "t5": str(out / "t5.png"),
    }
    with Image.open(shot) as src, Image.open(out / "t3.JPG") as img:
        assert img.format == "JPEG"
        assert img.quantization == src.quantization and JpegImagePlugin.get_sampling(img) == 1
        assert img.getexif()[0x010F] == "geofill-test-camera" and img.info["icc_profile"] == icc
        # Outside the hole the pixels are the photo's, re-encoded at its own quality.
        error = np.abs(np.asarray(img, dtype=int) - np.asarray(src, dtype=int))[~p.hole]
        assert error.mean() < 2.0, error.mean()
    with Image.open(out / "t5.png") as img:
        assert img.format == "PNG"
    mtimes = {f.name: f.stat().st_mtime_ns for f in out.glob("t*")}
    assert _batch(root, out, "--sources-per-image", root / "refs", "--resume") == 0
    assert {f.name: f.stat().st_mtime_ns for f in out.glob("t*")} == mtimes  # found, not run again


def test_ray_without_the_extra_is_a_one_line_error(pairs, tmp_path, monkeypatch, capsys):
    root = _shoot(tmp_path, {"t3": pairs["t3"]})
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError, as when not installed
    code = _batch(root, tmp_path / "out", "--sources-per-image", root / "refs", "--ray", "local")
    assert code == 3
    assert capsys.readouterr().err.strip().splitlines() == [
        "geofill: error: --ray needs Ray: pip install 'geofill[ray]'"
    ]
    assert not (tmp_path / "out" / "results.jsonl").exists()


def test_batch_reference_masks_from_folders_and_a_manifest(tmp_path):
    """The same target three times: its reference unmasked, masked by ``view.mask.png`` beside it,
    and with a mask of another size; then the masked one again through a manifest's source_masks."""
    p = make_pair(seed=0, width=320, height=240)
    keep_out = np.zeros(p.hole.shape, np.uint8)
    keep_out[:, 240:] = 255  # the right of the source: where most of the hole comes from
    root = _shoot(tmp_path, {"plain": p, "masked": p, "sized": p})
    refs = root / "refs"
    assert cv2.imwrite(str(refs / "masked" / "view.mask.png"), keep_out)
    assert cv2.imwrite(str(refs / "sized" / "view.mask.png"), keep_out[:100, :100])
    out = tmp_path / "out"
    assert _batch(root, out, "--sources-per-image", refs, "--jobs", "2") == EXIT_ITEMS_FAILED
    by = {r["item"]: r for r in _records(out)}
    plain, masked, sized = by["plain"], by["masked"], by["sized"]
    assert plain["status"] == masked["status"] == "reference"
    assert plain["reference_masks"] == [None] and plain["refused_fraction"]["stranger"] == 0.0
    assert masked["reference_masks"] == [str(refs / "masked" / "view.mask.png")]
    assert masked["refused_fraction"]["masked"] > 0.2
    assert masked["coverage"] < plain["coverage"] - 0.2  # less of the hole from the reference
    hole = p.hole
    a, b = _read_rgb(out / "plain.png"), _read_rgb(out / "masked.png")
    assert np.array_equal(a[~hole], b[~hole]) and not np.array_equal(a[hole], b[hole])
    assert sized["status"] == "failed" and sized["error"] == (
        f"{refs / 'sized' / 'view.mask.png'}: reference mask is 100x100 "
        f"but its reference {refs / 'sized' / 'view.png'} is 320x240"
    )

    manifest = tmp_path / "batch.csv"
    manifest.write_text(
        "target,mask,sources,source_masks,output\n"
        "images/masked.png,masks/masked.png,refs/plain/view.png,refs/masked/view.mask.png,again.png\n"
    )
    assert (
        main([str(a) for a in ("batch", "--manifest", manifest, "--out", tmp_path / "out2", "--jobs", "1")])
        == 0
    )
    (again,) = _records(tmp_path / "out2")
    assert again["reference_masks"] == [str(root / "refs/masked/view.mask.png")]
    assert again["refused_fraction"] == masked["refused_fraction"]
    assert np.array_equal(_read_rgb(tmp_path / "out2" / "again.png"), b)
