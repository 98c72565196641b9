"""Fuzz suite: a generated corpus of malformed and adversarial inputs through the CLI (see
tests/fuzz_cases.py). Every case ends in a fill (outside-hole pixels byte-identical for PNG/TIFF)
or exactly one stderr line with its exit status and nothing written; no traceback, no hang, no
Python warning or other raw text on stderr; the same inputs give the same bytes.
benchmarks/quality/fuzz_bench.py runs a larger corpus (with every extra installed, see there)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from fuzz_cases import Corpus, run_case
from geofill.cli import main
from geofill.io import read_image


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    return Corpus(tmp_path_factory.mktemp("fuzz"), seed=0)


@pytest.fixture(scope="module")
def cases(corpus):
    corpus.build(n_random_config=12, n_mutations=9, extended=False)
    corpus.regressions()
    return corpus.cases


def test_corpus_covers_every_family(cases):
    families = {c.family for c in cases}
    assert families == {"input", "format", "mask", "depth", "config", "output", "shape"}
    assert len(cases) >= 90


def test_every_case_is_a_fill_or_one_clean_error(cases):
    results = [run_case(c, timeout_s=180) for c in cases]
    bad = [f"{r.case.name}: {r.outcome} (exit {r.code}, expected {r.case.expect}): {r.stderr.strip()[-300:]}"
           for r in results if r.outcome not in ("fill", "error")]  # fmt: skip
    assert bad == []
    fills = [r for r in results if r.outcome == "fill"]
    assert len(fills) >= 20  # the corpus keeps valid fills among the bad inputs
    for r in results:
        if r.outcome == "error":
            assert r.stderr.strip().startswith("geofill: error:"), r.case.name


def _fill_argv(corpus, out, target=None, *flags):
    return ["fill", "--target", str(target or corpus.f("target.png")), "--mask", str(corpus.f("mask.png")),
            "--source", str(corpus.f("source.png")), "-o", str(out), *flags]  # fmt: skip


def test_same_inputs_give_the_same_bytes(corpus, tmp_path):
    outputs = []
    for i in range(2):
        out = tmp_path / f"run{i}.png"
        assert main(_fill_argv(corpus, out, None, "--quiet")) == 0
        outputs.append(out.read_bytes())
    assert outputs[0] == outputs[1]


def test_sigterm_during_the_output_write_leaves_nothing(corpus, tmp_path, monkeypatch, capsys):
    """A real SIGTERM delivered while the encoder writes: exit 143, no output, no temp file."""
    real_save = Image.Image.save

    def save_then_terminate(self, fp, *args, **kwargs):
        real_save(self, fp, *args, **kwargs)
        fp.flush()
        assert any(p.name.endswith(".tmp") for p in tmp_path.iterdir())  # the temp file exists now
        os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(Image.Image, "save", save_then_terminate)
    assert main(_fill_argv(corpus, tmp_path / "out.png", None, "--quiet")) == 143
    assert capsys.readouterr().err.strip() == "geofill: terminated"
    assert list(tmp_path.iterdir()) == []


def test_exif_and_icc_are_carried_and_orientation_reset(corpus, tmp_path):
    """The target's EXIF (with orientation 6) and ICC profile reach the PNG output, orientation 1;
    --strip-metadata drops both."""
    icc = b"\x00\x00\x02\x0cfake-profile-bytes" + bytes(500)
    target = tmp_path / "t.jpg"
    upright = corpus.target
    stored = np.ascontiguousarray(np.rot90(upright, 1))  # orientation 6 turns it back clockwise
    exif = Image.Exif()
    exif[0x0112] = 6
    exif[0x010F] = "geofill-test-camera"  # Make
    Image.fromarray(stored).save(target, "JPEG", quality=95, exif=exif.tobytes(), icc_profile=icc)
    kept, stripped = tmp_path / "kept.png", tmp_path / "stripped.png"
    assert main(_fill_argv(corpus, kept, target, "--quiet")) == 0
    assert main(_fill_argv(corpus, stripped, target, "--quiet", "--strip-metadata")) == 0
    with Image.open(kept) as img:
        assert img.info.get("icc_profile") == icc
        assert img.getexif()[0x0112] == 1 and img.getexif()[0x010F] == "geofill-test-camera"
        assert img.size == (upright.shape[1], upright.shape[0])
    with Image.open(stripped) as img:
        assert "icc_profile" not in img.info and len(img.getexif()) == 0
    # Upright pixels outside the hole are the decoded target's, byte for byte.
    hole = corpus.hole
    assert np.array_equal(read_image(kept).pixels[~hole], read_image(target).pixels[~hole])
    # A JPEG output of this JPEG target: its quantisation tables, EXIF and ICC profile.
    jpeg = tmp_path / "kept.jpg"
    assert main(_fill_argv(corpus, jpeg, target, "--quiet")) == 0
    with Image.open(target) as src, Image.open(jpeg) as img:
        assert img.quantization == src.quantization
        assert img.info.get("icc_profile") == icc and img.getexif()[0x010F] == "geofill-test-camera"


def test_lossy_output_says_it_re_encodes(corpus, tmp_path, capsys):
    out = tmp_path / "o.jpg"
    assert main(_fill_argv(corpus, out, None, "--quality", "60")) == 0
    assert "re-encodes every pixel, those outside the hole too" in capsys.readouterr().err
    small = out.stat().st_size
    assert main(_fill_argv(corpus, out, None, "--quality", "98")) == 0
    assert out.stat().st_size > small  # the quality reached the encoder
    with Image.open(out) as img:
        assert img.format == "JPEG"


def test_cli_usage_errors_and_help_in_a_fresh_interpreter(tmp_path):
    """Through the installed entry point: a usage error is one line with status 2; --help works."""
    cmd = [sys.executable, "-m", "geofill.cli"]
    r = subprocess.run([*cmd, "fill", "--target"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "Traceback" not in r.stderr
    r = subprocess.run([*cmd, "--help"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and "models" in r.stdout
