"""A generated corpus of malformed and adversarial ``geofill fill`` invocations, and the runner that
classifies what the CLI did with each (used by tests/test_fuzz.py and benchmarks/quality/fuzz_bench.py).

Families: input files (corrupt, truncated, zero-byte, header-only giants, odd pixel formats, EXIF
orientations, odd paths), image shapes (extreme aspect ratios, the smallest and large sizes,
constant images), references (other sizes and orientations, several at once), masks, depth files,
configuration values and files, output paths, plus valid fills. Every case states the exit status it
must end with; the runner checks the contract of the CLI: a fill (pixels outside the hole
byte-identical for PNG/TIFF output) or exactly one stderr line with that status and nothing written,
never a traceback, never a Python warning or other text on stderr beside the CLI's own lines, never
past a time limit."""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import struct
import sys
import tempfile
import warnings
import zlib
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import tifffile
from PIL import Image

from geofill.extras import available

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
    "raw warning",
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
        self.depth = pair.depth_source.astype(np.float64)  # the source's true depth, in scene units
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

    def pixel_formats(self) -> None:
        """Sample formats every reader must bring to 8-bit RGB (grey, alpha, 16-bit, float, 1-bit)
        and the EXIF orientations not in :meth:`input_files`."""
        t, src, f = self.target, self.source, self.f
        for orientation in (2, 4, 5, 7):
            path = f(f"orient{orientation}.jpg")
            jpeg_with_orientation(path, t, orientation)
            self.add(f"EXIF orientation {orientation} target", "format", 0, target=path)
        for orientation in (6, 3):
            path = f(f"src_orient{orientation}.jpg")
            jpeg_with_orientation(path, src, orientation)
            self.add(f"EXIF orientation {orientation} source", "format", 0, source=path)
        grey = cv2.cvtColor(t, cv2.COLOR_RGB2GRAY)
        cv2.imwrite(str(f("grey16.png")), grey.astype(np.uint16) * 257)
        self.add("16-bit grey PNG target", "format", 0, target=f("grey16.png"))
        rgba16 = np.dstack([cv2.cvtColor(t, cv2.COLOR_RGB2BGR), np.full(t.shape[:2], 255, np.uint8)])
        cv2.imwrite(str(f("rgba16.png")), rgba16.astype(np.uint16) * 257)
        self.add("16-bit RGBA PNG target", "format", 0, target=f("rgba16.png"))
        Image.fromarray(np.dstack([src, np.zeros(src.shape[:2], np.uint8)])).save(f("clear.png"))
        self.add("fully transparent RGBA source", "format", 0, source=f("clear.png"))
        half = np.full(t.shape[:2], 255, np.uint8)
        half[:, : t.shape[1] // 2] = 0
        Image.fromarray(np.dstack([t, half])).save(f("halfclear.png"))
        self.add("RGBA target half transparent", "format", 0, target=f("halfclear.png"))
        Image.fromarray(grey).convert("LA").save(f("la.png"))
        self.add("grey+alpha PNG target", "format", 0, target=f("la.png"))
        Image.fromarray(grey).convert("1").save(f("bilevel.png"))
        self.add("1-bit PNG source", "format", 0, source=f("bilevel.png"))
        write_rgb(f("grey.jpg"), cv2.cvtColor(src, cv2.COLOR_RGB2GRAY), quality=90)
        self.add("grey JPEG source", "format", 0, source=f("grey.jpg"))
        tifffile.imwrite(f("rgb16.tif"), t.astype(np.uint16) * 257, photometric="rgb")
        self.add("16-bit RGB TIFF target", "format", 0, target=f("rgb16.tif"))
        tifffile.imwrite(f("f32_255.tif"), src.astype(np.float32), photometric="rgb")
        self.add("float32 TIFF in 0-255 source", "format", 0, source=f("f32_255.tif"))
        wild = src.astype(np.float32) / 255.0
        wild[::7, ::5] = np.nan
        wild[3::11, ::3] = np.inf
        wild[5::13] = -2.0
        tifffile.imwrite(f("f32_nan.tif"), wild, photometric="rgb")
        self.add("float32 TIFF with NaN, inf, negatives source", "format", -1, source=f("f32_nan.tif"))
        tifffile.imwrite(f("f32_allnan.tif"), np.full(src.shape, np.nan, np.float32), photometric="rgb")
        self.add("all-NaN float TIFF source", "format", -1, source=f("f32_allnan.tif"))
        tifffile.imwrite(f("rgba_f32.tif"), np.dstack([wild, np.ones(src.shape[:2], np.float32)]))
        self.add("float32 RGBA TIFF source", "format", -1, source=f("rgba_f32.tif"))
        Image.fromarray(t).save(f("t.webp"), quality=90)
        self.add("lossy WebP target", "format", 0, target=f("t.webp"))

    def truncations(self) -> None:
        """Every container cut short: an error naming the file, never a partly grey image."""
        t, f = self.target, self.f
        bgr16 = cv2.cvtColor(t, cv2.COLOR_RGB2BGR).astype(np.uint16) * 257
        makers = {
            "t16.png": lambda p: cv2.imwrite(str(p), bgr16),
            "tw.webp": lambda p: Image.fromarray(t).save(p, quality=90),
            "tt.tif": lambda p: tifffile.imwrite(p, t, photometric="rgb"),
            "tp.jpg": lambda p: Image.fromarray(t).save(p, quality=90, progressive=True),
        }
        for name, make in makers.items():
            make(f(name))
            data = f(name).read_bytes()
            for frac in (0.5, 0.97):
                cut = f(f"cut{int(frac * 100)}_{name}")
                cut.write_bytes(data[: int(len(data) * frac)])
                self.add(f"{name} truncated at {int(frac * 100)}%", "input", 2, target=cut)
        self.add("mask truncated", "mask", 2, mask=self._truncated_copy("mask.png"))
        self.add("source truncated", "input", 2, source=self._truncated_copy("source.png"))

    def _truncated_copy(self, name: str) -> Path:
        data = self.f(name).read_bytes()
        path = self.f(f"cut_{name}")
        path.write_bytes(data[: len(data) * 2 // 3])
        return path

    def _scene(self, name: str, size: tuple[int, int], source_size: tuple[int, int] | None = None) -> tuple:
        """The corpus's pair resized to ``size`` (w, h) (the source to ``source_size``), written as
        ``<name>_t.png``, ``<name>_s.png`` and ``<name>_m.png``; returns their paths."""
        t = cv2.resize(self.target, size, interpolation=cv2.INTER_AREA)
        src = cv2.resize(self.source, source_size or size, interpolation=cv2.INTER_AREA)
        hole = cv2.resize(self.hole.astype(np.uint8) * 255, size, interpolation=cv2.INTER_NEAREST)
        if not hole.any():  # a hole thinner than a pixel at this size
            hole[size[1] // 2, size[0] // 2] = 255
        t[hole >= 127] = 0
        paths = self.f(f"{name}_t.png"), self.f(f"{name}_s.png"), self.f(f"{name}_m.png")
        write_rgb(paths[0], t)
        write_rgb(paths[1], src)
        cv2.imwrite(str(paths[2]), hole)
        return paths

    def shapes(self) -> None:
        """Extreme aspect ratios, the smallest accepted and refused sizes, large images, constant
        images. Every rung of the matching ladder that cannot take an image skips with its reason."""
        for w, h in ((4000, 64), (64, 3000), (2000, 64), (64, 64), (65, 1500), (5000, 80), (1200, 70)):
            tp, sp, mp = self._scene(f"shape{w}x{h}", (w, h))
            self.add(f"{w}x{h} target and source", "shape", 0, target=tp, mask=mp, source=sp)
            self.add(
                f"{w}x{h} with --debug-dir",
                "shape",
                0,
                target=tp,
                mask=mp,
                source=sp,
                debug_dir=self.out / f"dbg_{w}x{h}",
            )
        tp, sp, mp = self._scene("wide_vs_tall", (3000, 64), (64, 3000))
        self.add("3000x64 target, 64x3000 source", "shape", 0, target=tp, mask=mp, source=sp)
        for w, h in ((63, 200), (200, 63), (1, 1), (10_000, 8)):
            tp, sp, mp = self._scene(f"small{w}x{h}", (w, h))
            self.add(f"{w}x{h} target (a side under 64 px)", "shape", 2, target=tp, mask=mp, source=sp)
        tp, sp, mp = self._scene("large", (2400, 1800))
        self.add("2400x1800 target and source", "shape", 0, target=tp, mask=mp, source=sp)
        self.add(
            "2400x1800 target, --max-pixels 1000000",
            "shape",
            2,
            target=tp,
            mask=mp,
            source=sp,
            flags=("--max-pixels", "1000000"),
        )
        h, w = self.hole.shape
        for value, name in ((0, "black"), (128, "grey"), (255, "white")):
            write_rgb(self.f(f"const_{name}.png"), np.full((h, w, 3), value, np.uint8))
            self.add(f"{name} constant target", "shape", 0, target=self.f(f"const_{name}.png"))
            self.add(f"{name} constant source", "shape", 0, source=self.f(f"const_{name}.png"))
        self.add(
            "constant target and source",
            "shape",
            0,
            target=self.f("const_grey.png"),
            source=self.f("const_white.png"),
        )
        stripes = np.zeros((h, w, 3), np.uint8)
        stripes[:, ::4] = 255
        write_rgb(self.f("stripes.png"), stripes)
        self.add("periodic stripes source", "shape", 0, source=self.f("stripes.png"))
        noise = self.rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        write_rgb(self.f("noise.png"), noise)
        self.add("white-noise source", "shape", 0, source=self.f("noise.png"))

    def references(self) -> None:
        """References of other sizes and aspects than the target, several at once, one bad among them."""
        f, h, w = self.f, *self.hole.shape
        for name, size in (
            ("x2", (2 * w, 2 * h)),
            ("half", (w // 2 + 1, h // 2 + 1)),
            ("portrait", (h, w)),
            ("wide", (3 * w, h)),
            ("min", (64, 64)),
            ("x8", (8 * w, 8 * h)),
        ):
            write_rgb(f(f"ref_{name}.png"), cv2.resize(self.source, size, interpolation=cv2.INTER_LINEAR))
            self.add(f"source {size[0]}x{size[1]}", "reference", 0, source=f(f"ref_{name}.png"))
        self.add("two sources", "reference", 0, flags=("--source", str(f("ref_x2.png"))))
        more = ("--source", str(f("const_grey.png")), "--source", str(f("ref_half.png")))
        self.add("three sources, one constant", "reference", 0, flags=more)
        self.add("the target as its own source", "reference", 0, source=f("target.png"))
        self.add("two sources, one corrupt", "reference", 2, flags=("--source", str(f("garbage.jpg"))))
        self.add("source mask all masked", "reference", 0, flags=("--source-mask", str(f("m_full.png"))))
        self.add("source mask of another size", "reference", 2, flags=("--source-mask", str(f("m_size.png"))))

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

    def more_masks(self) -> None:
        """Holes at the edges of what is allowed, and masks in every format a reader takes."""
        h, w = self.hole.shape
        f = self.f
        corner = np.zeros((h, w), np.uint8)
        corner[0, 0] = 255
        cv2.imwrite(str(f("m_corner.png")), corner)
        self.add("one-pixel hole in the corner", "mask", 0, mask=f("m_corner.png"))
        cv2.imwrite(str(f("m_126.png")), np.where(self.hole, 126, 0).astype(np.uint8))
        self.add("mask at 126 (no hole)", "mask", 2, mask=f("m_126.png"))
        cv2.imwrite(str(f("m_127.png")), np.where(self.hole, 127, 0).astype(np.uint8))
        self.add("mask at 127 (hole)", "mask", 0, mask=f("m_127.png"))
        almost = np.full((h, w), 255, np.uint8)
        almost[: h // 10 + 2] = 0
        cv2.imwrite(str(f("m_almost.png")), almost)
        self.add("hole of 88% of the photo", "mask", 0, mask=f("m_almost.png"))
        frame = np.full((h, w), 255, np.uint8)
        frame[8:-8, 8:-8] = 0
        cv2.imwrite(str(f("m_frame.png")), frame)
        self.add("hole along every border", "mask", 0, mask=f("m_frame.png"))
        alpha = np.zeros((h, w, 4), np.uint8)
        alpha[..., 3] = self.hole * 255
        Image.fromarray(alpha).save(f("m_alpha.png"))
        self.add("RGBA mask (alpha)", "mask", 0, mask=f("m_alpha.png"))
        Image.fromarray(np.dstack([self.hole * 255] * 3).astype(np.uint8)).save(f("m_rgb.jpg"), quality=70)
        self.add("RGB JPEG mask", "mask", 0, mask=f("m_rgb.jpg"))
        tifffile.imwrite(f("m_f32.tif"), self.hole.astype(np.float32))
        self.add("float TIFF mask", "mask", 0, mask=f("m_f32.tif"))
        jpeg_with_orientation(f("m_orient6.jpg"), np.dstack([self.hole * 255] * 3).astype(np.uint8), 6)
        self.add("mask with EXIF orientation 6", "mask", 0, mask=f("m_orient6.jpg"))
        cv2.imwrite(str(f("m_tall.png")), np.zeros((w, h), np.uint8) + 255)
        self.add("mask transposed", "mask", 2, mask=f("m_tall.png"))

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
        # With the onnx extra these lack their weights (exit 2); without it, the extra (a config
        # error, exit 3): an install with only the learned extra runs these cases too.
        weights = 2 if available("onnxruntime") else 3
        self.add("fused depth without weights", "depth", weights, flags=("--depth", "fused"))
        self.add("onnx depth without weights", "depth", weights, flags=("--depth", "onnx"))
        self.add("missing depth model", "depth", weights, flags=("--depth-model", str(f("none.onnx"))))
        self.add("LaMa without weights", "depth", weights, flags=("--set", "inpaint.method=lama"))

    def depth_units(self) -> None:
        """The source's true depth in units from 1e-40 to 1e35 and with invalid values, as depth
        and as disparity: the fit absorbs any unit, invalid values are left out."""
        h, w = self.source.shape[:2]
        f = self.f
        true = self.depth
        variants = {
            "metres": true,
            "1e-40 m (float32 subnormals)": true * 1e-40,
            "1e-30 m": true * 1e-30,
            "1e35 m": true * 1e35,
            "half NaN": np.where(np.arange(w) < w // 2, true, np.nan),
            "inf and NaN spots": np.where((np.indices((h, w)).sum(0) % 7) == 0, np.inf, true),
            "negative": -true,
            "zeros": np.zeros((h, w)),
            "one valid pixel": np.where(np.indices((h, w))[0] * w + np.indices((h, w))[1] == 77, 3.0, np.nan),
            "float64 huge range": np.exp(self.rng.uniform(-300, 300, (h, w))),
            "float16": true.astype(np.float16),
            "int16": (true * 1000).astype(np.int16),
        }
        no_depth = ("zeros", "one valid pixel", "float64 huge range")  # may be refused up front
        for i, (name, d) in enumerate(variants.items()):
            path = f(f"dvar{i}.npy")
            np.save(
                path, d if d.dtype != np.float64 or name == "float64 huge range" else d.astype(np.float32)
            )
            for kind in ("depth", "disparity"):
                self.add(
                    f"depth file {name} as {kind}",
                    "depth",
                    -1 if name in no_depth else 0,
                    flags=("--depth-file", str(path), "--depth-kind", kind),
                )
        cv2.imwrite(str(f("d16.png")), (true * 1000).astype(np.uint16))
        self.add(
            "16-bit PNG depth in mm",
            "depth",
            0,
            flags=("--depth-file", str(f("d16.png")), "--depth-scale", "0.001"),
        )
        cv2.imwrite(str(f("d16z.png")), np.zeros((h, w), np.uint16))
        self.add("16-bit PNG depth all zero", "depth", 2, flags=("--depth-file", str(f("d16z.png"))))
        tifffile.imwrite(f("dnan.tif"), np.where(true > 5, np.nan, true).astype(np.float32))
        self.add("float TIFF depth with NaN", "depth", -1, flags=("--depth-file", str(f("dnan.tif"))))
        self.add(
            "depth scale 1e-30",
            "depth",
            -1,
            flags=("--depth-file", str(f("dvar0.npy")), "--depth-scale", "1e-30"),
        )
        self.add(
            "depth scale 1e30",
            "depth",
            -1,
            flags=("--depth-file", str(f("dvar0.npy")), "--depth-scale", "1e30"),
        )

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

    def build(self, n_random_config: int = 0, n_mutations: int = 0, extended: bool = True) -> list[Case]:
        """Every family's cases; ``extended``: also the slower ones (image shapes and sizes, more
        references, pixel formats, truncations, masks and depth units), which the benchmark runs."""
        self.input_files()
        self.masks()
        self.depth_files()
        if extended:
            self.pixel_formats()
            self.truncations()
            self.more_masks()
            self.shapes()
            self.references()
            self.depth_units()
        self.config_values(n_random_config)
        self.config_files()
        self.outputs()
        self.mutations(n_mutations)
        return self.cases

    def regressions(self) -> list[Case]:
        """A few cases that once failed with every extra installed, for the unit suite: a
        4000x64 pair (the learned rung's XFeat divided by zero; the debug overview was wider than
        JPEG allows) and a depth file in 1e-40 m (float32 overflow when inverted)."""
        first = len(self.cases)
        tp, sp, mp = self._scene("shape4000x64", (4000, 64))
        self.add(
            "4000x64 with --debug-dir", "shape", 0, target=tp, mask=mp, source=sp, debug_dir=self.out / "dbg"
        )
        tp, sp, mp = self._scene("shape64x3000", (64, 3000))
        self.add("64x3000 target and source", "shape", 0, target=tp, mask=mp, source=sp)
        np.save(self.f("dtiny.npy"), (self.depth * 1e-40).astype(np.float32))
        self.add("depth file in 1e-40 m", "depth", 0, flags=("--depth-file", str(self.f("dtiny.npy"))))
        return self.cases[first:]


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


@contextlib.contextmanager
def _raw_stderr() -> Iterator[io.StringIO]:
    """What is written to file descriptor 2 itself (a C library's message, bypassing Python's
    ``sys.stderr``) while the block runs, in the yielded buffer once it ends."""
    sys.stderr.flush()
    saved = os.dup(2)
    got = io.StringIO()
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield got
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            got.write(tmp.read().decode("utf-8", "replace"))


def run_case(case: Case, timeout_s: int = 120) -> Result:
    """Run ``case`` through ``geofill.cli.main`` in this process (a SIGALRM watchdog bounds it) and
    classify the outcome (see :data:`OUTCOMES`). Every Python warning is recorded (whatever the
    filters would have shown) and counts as a raw warning, as does text written to stderr's file
    descriptor past Python: a user sees only the CLI's own lines."""
    from geofill.cli import main
    from geofill.io import read_image, read_mask

    err = io.StringIO()
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(timeout_s)
    try:
        with (
            _raw_stderr() as raw,
            warnings.catch_warnings(record=True) as heard,
            contextlib.redirect_stderr(err),
            contextlib.redirect_stdout(io.StringIO()),
        ):
            warnings.simplefilter("always")
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
    stray = [f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})" for w in heard]
    stray += [line for line in raw.getvalue().splitlines() if line.strip()]
    stray += [line for line in lines if not line.startswith("geofill")]
    if stray:
        return Result(case, "raw warning", code, "\n".join([*stray, text]))
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
