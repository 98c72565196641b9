"""A generated corpus of malformed and adversarial ``geofill fill`` invocations, and the runner that
classifies what the CLI did with each (used by tests/test_fuzz.py and benchmarks/quality/fuzz_bench.py).

Families: input files (corrupt, truncated, zero-byte, header-only giants, odd pixel formats, EXIF
orientations, odd paths), masks, depth files, configuration values and files, output paths, plus
valid fills. Every case states the exit status it must end with; the runner checks the contract of
the CLI: a fill (pixels outside the hole byte-identical for PNG/TIFF output) or exactly one stderr
line with that status and nothing written, never a traceback, never past a time limit."""

from __future__ import annotations

import contextlib
import io
import json
import signal
import struct
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import tifffile
from PIL import Image

#: Exit statuses of a run that writes its output: 0, and 5 where the fill fell back to single-image
#: inpainting without --allow-fallback (written all the same).
FILL_CODES = (0, 5)
#: What the runner reports for each case.
OUTCOMES = (
    "fill",
    "error",
    "traceback",
    "hang",
    "partial output",
    "changed outside hole",
    "multi-line error",
    "unexpected status",
    "invalid config accepted",
)
SIZE = (200, 150)  # (w, h) of the synthetic scene: big enough to match, small enough to be quick


@dataclass(frozen=True)
class Case:
    """One invocation: ``argv`` after ``geofill``; ``expect`` the exit status it must end with."""

    name: str
    family: str
    argv: tuple[str, ...]
    expect: int
    output: Path
    debug_dir: Path | None = None
    lossless: bool = True  # output format keeps pixels exactly (PNG/TIFF)
    extra: dict = field(default_factory=dict, compare=False)


# ---------------------------------------------------------------------------------------------
# File makers


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png_header_only(path: Path, width: int, height: int) -> None:
    """A PNG with a valid IHDR claiming ``width`` x ``height`` and no pixel data."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IEND", b""))


def jpeg_claiming(path: Path, rgb: np.ndarray, width: int, height: int) -> None:
    """A small JPEG whose frame header is patched to claim ``width`` x ``height``."""
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, "JPEG", quality=90)
    data = bytearray(buf.getvalue())
    at = data.find(b"\xff\xc0")
    struct.pack_into(">HH", data, at + 5, height, width)
    path.write_bytes(bytes(data))


def jpeg_with_orientation(path: Path, upright: np.ndarray, orientation: int) -> None:
    """A JPEG whose stored pixels, turned as EXIF ``orientation`` says, give ``upright``."""
    # exif_transpose applies the orientation; its inverse maps upright -> stored.
    inverse = {1: 1, 2: 2, 3: 3, 4: 4, 5: 5, 6: 8, 7: 7, 8: 6}[orientation]
    img = Image.fromarray(upright)
    exif = img.getexif()
    exif[0x0112] = inverse
    from PIL import ImageOps

    stored = ImageOps.exif_transpose(img)
    out = Image.fromarray(np.asarray(stored))
    e = out.getexif()
    e[0x0112] = orientation
    out.save(path, "JPEG", quality=95, exif=e.tobytes())


def write_rgb(path: Path, rgb: np.ndarray, **options) -> None:
    Image.fromarray(rgb).save(path, **options)


# ---------------------------------------------------------------------------------------------
# The corpus


class Corpus:
    """Writes the files of every case under ``root`` and returns the cases."""

    def __init__(self, root: Path, seed: int = 0) -> None:
        from geofill.synthetic import blanked, make_pair

        self.root = root
        root.mkdir(parents=True, exist_ok=True)
        self.rng = np.random.default_rng(seed)
        pair = make_pair(seed=seed, width=SIZE[0], height=SIZE[1])
        # The hole blanked: these cases test the inputs, not what a hole showing an object refuses.
        self.target, self.source, self.hole = blanked(pair.target, pair.hole), pair.source, pair.hole
        self.files = root / "files"
        self.files.mkdir(exist_ok=True)
        self.out = root / "out"
        self.out.mkdir(exist_ok=True)
        write_rgb(self.files / "target.png", self.target)
        write_rgb(self.files / "source.png", self.source)
        cv2.imwrite(str(self.files / "mask.png"), self.hole.astype(np.uint8) * 255)
        self.cases: list[Case] = []

    def f(self, name: str) -> Path:
        return self.files / name

    def add(
        self,
        name: str,
        family: str,
        expect: int,
        *,
        target: Path | None = None,
        mask: Path | None = None,
        source: Path | None = None,
        output: Path | None = None,
        debug_dir: Path | None = None,
        flags: tuple[str, ...] = (),
    ) -> None:
        out = output or self.out / f"{len(self.cases):04d}_{name}.png"
        argv = [
            "fill",
            "--quiet",
            "--target",
            str(target or self.f("target.png")),
            "--mask",
            str(mask or self.f("mask.png")),
            "--source",
            str(source or self.f("source.png")),
            "-o",
            str(out),
        ]
        if debug_dir is not None:
            argv += ["--debug-dir", str(debug_dir)]
        lossless = out.suffix.lower() in (".png", ".tif", ".tiff")
        self.cases.append(Case(name, family, (*argv, *flags), expect, out, debug_dir, lossless))

    # -- families ------------------------------------------------------------------------------

    def input_files(self) -> None:
        t, f = self.target, self.f
        f("zero.png").write_bytes(b"")
        self.add("zero-byte target", "input", 2, target=f("zero.png"))
        f("garbage.jpg").write_bytes(self.rng.integers(0, 256, 4000, dtype=np.uint8).tobytes())
        self.add("garbage target", "input", 2, target=f("garbage.jpg"))
        data = f("target.png").read_bytes()
        f("trunc.png").write_bytes(data[: len(data) // 2])
        self.add("truncated PNG target", "input", 2, target=f("trunc.png"))
        write_rgb(f("full.jpg"), t, quality=90)
        jpg = f("full.jpg").read_bytes()
        f("trunc.jpg").write_bytes(jpg[: len(jpg) // 3])
        self.add("truncated JPEG source", "input", 2, source=f("trunc.jpg"))
        png_header_only(f("giant.png"), 100_000, 100_000)
        self.add("header-only 10 GP PNG", "input", 2, target=f("giant.png"))
        jpeg_claiming(f("claim7000.jpg"), t, 7000, 7000)
        self.add("JPEG header claiming 7000x7000", "input", 2, source=f("claim7000.jpg"))
        f("text.png").write_text("not an image\n" * 50)
        self.add("text file as PNG", "input", 2, source=f("text.png"))
        self.add("directory as target", "input", 2, target=self.files)
        self.add("missing source", "input", 2, source=f("nope.png"))
        self.add("300-byte target name", "input", 2, target=f("t" * 300 + ".png"))
        write_rgb(f("tiny.png"), t[:40, :40])
        self.add("target under 64 px", "input", 2, target=f("tiny.png"))
        f("fake.heic").write_bytes(b"\x00\x00\x00\x18ftypheic\x00\x00\x00\x00mif1heic" + b"\x00" * 64)
        self.add("corrupt HEIC source", "input", -1, source=f("fake.heic"))  # 2, or 3 without the extra
        tifffile.imwrite(f("int32.tif"), t[..., 0].astype(np.int32))
        self.add("int32 TIFF source", "input", 2, source=f("int32.tif"))
        # Pixel formats that must be read and filled.
        cv2.imwrite(str(f("rgb16.png")), cv2.cvtColor(t, cv2.COLOR_RGB2BGR).astype(np.uint16) * 257)
        self.add("16-bit PNG target", "format", 0, target=f("rgb16.png"))
        write_rgb(f("grey.png"), cv2.cvtColor(self.source, cv2.COLOR_RGB2GRAY))
        self.add("grey source", "format", 0, source=f("grey.png"))
        Image.fromarray(self.source).convert("P").save(f("palette.png"))
        self.add("palette source", "format", 0, source=f("palette.png"))
        Image.fromarray(t).convert("CMYK").save(f("cmyk.jpg"), quality=95)
        self.add("CMYK JPEG target", "format", 0, target=f("cmyk.jpg"))
        tifffile.imwrite(f("f64.tif"), t.astype(np.float64) / 255.0, photometric="rgb")
        self.add("float64 RGB TIFF target", "format", 0, target=f("f64.tif"))
        tifffile.imwrite(f("f16.tif"), (self.source[..., 1] / 255.0).astype(np.float16))
        self.add("float16 grey TIFF source", "format", 0, source=f("f16.tif"))
        rgba = np.dstack([t, np.full(t.shape[:2], 200, np.uint8)])
        Image.fromarray(rgba).save(f("rgba.webp"), lossless=True)
        self.add("RGBA WebP target", "format", 0, target=f("rgba.webp"))
        for orientation in (3, 6, 8):
            path = f(f"orient{orientation}.jpg")
            jpeg_with_orientation(path, t, orientation)
            self.add(f"EXIF orientation {orientation} target", "format", 0, target=path)

    def masks(self) -> None:
        h, w = self.hole.shape
        f = self.f
        cv2.imwrite(str(f("m_empty.png")), np.zeros((h, w), np.uint8))
        self.add("empty mask", "mask", 2, mask=f("m_empty.png"))
        cv2.imwrite(str(f("m_full.png")), np.full((h, w), 255, np.uint8))
        self.add("full mask", "mask", 2, mask=f("m_full.png"))
        cv2.imwrite(str(f("m_size.png")), np.full((h + 1, w), 255, np.uint8))
        self.add("mask of another size", "mask", 2, mask=f("m_size.png"))
        one = np.zeros((h, w), np.uint8)
        one[h // 2, w // 2] = 255
        cv2.imwrite(str(f("m_one.png")), one)
        self.add("one-pixel hole", "mask", 0, mask=f("m_one.png"))
        border = np.zeros((h, w), np.uint8)
        border[:, : w // 5] = 255
        cv2.imwrite(str(f("m_border.png")), border)
        self.add("hole on the border", "mask", 0, mask=f("m_border.png"))
        speckle = (self.rng.random((h, w)) < 0.2).astype(np.uint8) * 255
        cv2.imwrite(str(f("m_speckle.png")), speckle)
        self.add("speckle hole 20 %", "mask", 0, mask=f("m_speckle.png"))
        cv2.imwrite(str(f("m_16.png")), self.hole.astype(np.uint16) * 65535)
        self.add("16-bit mask", "mask", 0, mask=f("m_16.png"))
        f("m_bad.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 30)
        self.add("corrupt mask", "mask", 2, mask=f("m_bad.png"))

    def depth_files(self) -> None:
        h, w = self.source.shape[:2]
        f = self.f
        np.save(f("d0.npy"), np.float32(3.0))
        self.add("0-d npy depth", "depth", 2, flags=("--depth-file", str(f("d0.npy"))))
        np.save(f("dsize.npy"), np.ones((h + 3, w), np.float32))
        self.add("depth of another size", "depth", 2, flags=("--depth-file", str(f("dsize.npy"))))
        np.save(f("dnan.npy"), np.full((h, w), np.nan, np.float32))
        self.add("all-NaN depth", "depth", 2, flags=("--depth-file", str(f("dnan.npy"))))
        np.save(f("dobj.npy"), np.array([{"a": 1}], dtype=object), allow_pickle=True)
        self.add("pickled npy depth", "depth", 2, flags=("--depth-file", str(f("dobj.npy"))))
        np.save(f("drgb.npy"), np.ones((h, w, 3), np.float32))
        self.add("3-channel depth", "depth", 2, flags=("--depth-file", str(f("drgb.npy"))))
        f("d.txt").write_text("1 2 3")
        self.add("depth with a .txt name", "depth", 2, flags=("--depth-file", str(f("d.txt"))))
        self.add("missing depth file", "depth", 2, flags=("--depth-file", str(f("none.npy"))))
        np.save(f("dok.npy"), np.full((h, w), 4.0, np.float32))
        self.add("constant depth file", "depth", 0, flags=("--depth-file", str(f("dok.npy"))))
        self.add("fused depth without weights", "depth", 2, flags=("--depth", "fused"))
        self.add("onnx depth without weights", "depth", 2, flags=("--depth", "onnx"))
        self.add("missing depth model", "depth", 2, flags=("--depth-model", str(f("none.onnx"))))
        self.add("LaMa without weights", "depth", 2, flags=("--set", "inpaint.method=lama"))

    def config_values(self, n_random: int = 0) -> None:
        for flags in (
            ("--focal", "0"),
            ("--focal", "nan"),
            ("--focal", "-5"),
            ("--focal", "inf"),
            ("--source-intrinsics", "inf,inf,0,0"),
            ("--target-intrinsics", "500,500,nan,75"),
            ("--working-max-side", "0"),
            ("--max-pixels", "-1"),
            ("--depth-scale", "0"),
            ("--set", "intrinsics.search_steps=10000000"),
            ("--set", "optimize.pyramid_levels=0"),
            ("--set", "optimize.pyramid_levels=50"),
            ("--set", "depth.stereo_patch_px=0"),
            ("--set", "optimize.threads=0"),
            ("--set", "refine.gain_sigma_px=1e308"),
            ("--set", "render.edge_threshold=-1"),
            ("--set", "optimize.fast_iterations=[]"),
            ("--set", "max_mask_fraction=NaN"),
            ("--set", "time_budget_s=0"),
            ("--set", "nosuch.key=1"),
            ("--set", "depth.backend=magic"),
            ("--set", "noequals"),
        ):
            self.add(f"config {' '.join(flags)}", "config", 3, flags=flags)
        keys = _numeric_keys()
        bad_values = ["nan", "Infinity", "-Infinity", "-1e9", "1e308", "100000000000000000000", '"x"', "[1]"]
        for i in range(n_random):
            key = keys[int(self.rng.integers(len(keys)))]
            value = bad_values[int(self.rng.integers(len(bad_values)))]
            self.add(f"random config {key}={value} #{i}", "config", 3, flags=("--set", f"{key}={value}"))

    def config_files(self) -> None:
        f = self.f
        self.add("--config a directory", "config", 3, flags=("--config", str(self.files)))
        f("latin1.json").write_bytes('{"working_max_side": 640, "x": "caf\xe9"}'.encode("latin-1"))
        self.add("--config not UTF-8", "config", 3, flags=("--config", str(f("latin1.json"))))
        f("bad.json").write_text("{not json")
        self.add("--config invalid JSON", "config", 3, flags=("--config", str(f("bad.json"))))
        f("list.json").write_text("[1, 2]")
        self.add("--config a JSON list", "config", 3, flags=("--config", str(f("list.json"))))
        f("deep.json").write_text("[" * 100_000 + "]" * 100_000)
        self.add("--config nested 100000 deep", "config", 3, flags=("--config", str(f("deep.json"))))
        f("range.json").write_text(json.dumps({"optimize": {"pyramid_levels": 9}}))
        self.add("--config value out of range", "config", 3, flags=("--config", str(f("range.json"))))
        self.add("--config missing", "config", 3, flags=("--config", str(f("none.json"))))

    def outputs(self) -> None:
        o = self.out
        self.add("300-byte output name", "output", 4, output=o / ("o" * 300 + ".png"))
        self.add("output name too long with temp affixes", "output", 4, output=o / ("o" * 240 + ".png"))
        self.add("output folder missing", "output", 4, output=o / "nope" / "x.png")
        self.add("output extension .gif", "output", 4, output=o / "x.gif")
        (o / "adir.png").mkdir(exist_ok=True)
        self.add("output is a directory", "output", 4, output=o / "adir.png")
        (o / "afile").write_text("x")
        self.add("--debug-dir an existing file", "output", 4, debug_dir=o / "afile")
        self.add("--debug-dir 300-byte name", "output", 4, debug_dir=o / ("d" * 300))
        self.add("--quality with PNG", "output", 3, flags=("--quality", "80"))
        self.add("--quality 0", "output", 2, output=o / "q0.jpg", flags=("--quality", "0"))
        self.add("JPEG output quality 80", "output", 0, output=o / "q80.jpg", flags=("--quality", "80"))
        self.add("WebP output", "output", 0, output=o / "w.webp")
        self.add("TIFF output", "output", 0, output=o / "t.tif")
        self.add("output with debug dir", "output", 0, debug_dir=o / "dbg_ok")
        self.add("metadata stripped", "output", 0, flags=("--strip-metadata",))

    def mutations(self, n: int) -> None:
        """Random damage to valid files (byte flips, truncation at a random point) and random
        masks; each must end in a fill or a clean input error (status 2)."""
        h, w = self.hole.shape
        write_rgb(self.f("full.jpg"), self.target, quality=90)
        originals = {name: self.f(name).read_bytes() for name in ("target.png", "full.jpg")}
        for i in range(n):
            kind = ("flip", "truncate", "mask")[i % 3]
            if kind == "mask":
                m = np.zeros((h, w), np.uint8)
                for _ in range(int(self.rng.integers(1, 6))):
                    x0, x1 = sorted(self.rng.integers(0, w, 2))
                    y0, y1 = sorted(self.rng.integers(0, h, 2))
                    m[y0 : y1 + 1, x0 : x1 + 1] = 255
                path = self.f(f"rand_mask_{i}.png")
                cv2.imwrite(str(path), m)
                self.add(f"random mask #{i}", "mask", -1, mask=path)
                continue
            name = ("target.png", "full.jpg")[int(self.rng.integers(2))]
            data = bytearray(originals[name])
            if kind == "flip":
                for at in self.rng.integers(8, len(data), int(self.rng.integers(1, 9))):
                    data[at] = int(self.rng.integers(256))
            else:
                data = data[: int(self.rng.integers(8, len(data)))]
            path = self.f(f"{kind}_{i}{Path(name).suffix}")
            path.write_bytes(bytes(data))
            self.add(f"{kind} {name} #{i}", "input", -1, target=path)

    def build(self, n_random_config: int = 0, n_mutations: int = 0) -> list[Case]:
        self.input_files()
        self.masks()
        self.depth_files()
        self.config_values(n_random_config)
        self.config_files()
        self.outputs()
        self.mutations(n_mutations)
        return self.cases


def _numeric_keys() -> list[str]:
    """Dotted keys of every numeric setting."""
    from geofill.config import FillConfig

    keys = []

    def walk(d: dict, prefix: str) -> None:
        for k, v in d.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            elif isinstance(v, int | float) and not isinstance(v, bool):
                keys.append(f"{prefix}{k}")

    walk(FillConfig().to_dict(), "")
    return keys


# ---------------------------------------------------------------------------------------------
# Running a case


class _Hang(BaseException):
    pass


def _alarm(signum, frame) -> None:
    raise _Hang


@dataclass(frozen=True)
class Result:
    case: Case
    outcome: str
    code: int | None
    stderr: str


def run_case(case: Case, timeout_s: int = 120) -> Result:
    """Run ``case`` through ``geofill.cli.main`` in this process (a SIGALRM watchdog bounds it) and
    classify the outcome (see :data:`OUTCOMES`)."""
    from geofill.cli import main
    from geofill.io import read_image, read_mask

    err = io.StringIO()
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(timeout_s)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                code = main(list(case.argv))
            except SystemExit as exc:  # argparse
                code = exc.code if isinstance(exc.code, int) else 1
    except _Hang:
        return Result(case, "hang", None, err.getvalue())
    except Exception as exc:
        return Result(case, "traceback", None, f"{err.getvalue()}{type(exc).__name__}: {exc}")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    text = err.getvalue()
    lines = [line for line in text.splitlines() if line.strip()]
    leftovers = [p for p in case.output.parent.glob(f".{case.output.name[:50]}*.tmp")]
    if "Traceback" in text:
        return Result(case, "traceback", code, text)
    if code in FILL_CODES:
        if case.expect not in (*FILL_CODES, -1):
            outcome = "invalid config accepted" if case.expect == 3 else "unexpected status"
            return Result(case, outcome, code, text)
        if not _is_file(case.output) or leftovers:
            return Result(case, "partial output", code, text)
        if case.lossless:
            argv = list(case.argv)
            target = read_image(argv[argv.index("--target") + 1]).pixels
            hole = read_mask(argv[argv.index("--mask") + 1])
            out = read_image(case.output).pixels
            if not np.array_equal(out[~hole], target[~hole]):
                return Result(case, "changed outside hole", code, text)
        return Result(case, "fill", code, text)
    wrote = _is_file(case.output) or leftovers
    if case.debug_dir is not None and _is_dir(case.debug_dir) and any(case.debug_dir.iterdir()):
        wrote = True
    if wrote:
        return Result(case, "partial output", code, text)
    if len(lines) != 1 or not lines[0].startswith("geofill"):
        return Result(case, "multi-line error", code, text)
    if code != case.expect and not (case.expect == -1 and code in (2, 3)):
        return Result(case, "unexpected status", code, text)
    return Result(case, "error", code, text)


def _is_file(p: Path) -> bool:
    try:
        return p.is_file()
    except OSError:  # a name too long to exist
        return False


def _is_dir(p: Path) -> bool:
    try:
        return p.is_dir()
    except OSError:
        return False


def summarise(results: list[Result]) -> Counter:
    return Counter(r.outcome for r in results)
