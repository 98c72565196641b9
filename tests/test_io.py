"""Reading, validating and writing the user's files (geofill.io), on files made in tmp_path."""

from __future__ import annotations

import os
import stat
import struct
import sys
import warnings
import zlib
from io import BytesIO
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
from PIL import ExifTags, Image, ImageFile, TiffImagePlugin

from geofill import io
from geofill.errors import (
    ArrayFormatError,
    ConfigError,
    CorruptImageError,
    DepthFileError,
    EmptyMaskError,
    ImageTooLargeError,
    ImageTooSmallError,
    InputError,
    MaskSizeError,
    MaskTooLargeError,
    MissingExtraError,
    MissingFileError,
    OutputError,
    UnreadableFileError,
)

# 16-bit values whose 8-bit conversion is known: round(v * 255 / 65535). 51200 is where keeping
# the high byte (Pillow's way) would give 200 instead of 199.
V16 = np.array([0, 300, 32767, 51200, 65535], dtype=np.uint16)
V8 = np.array([0, 1, 127, 199, 255], dtype=np.uint8)


def _rng_rgb(h: int = 70, w: int = 90, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _save(path: Path, array: np.ndarray, **kwargs) -> Path:
    Image.fromarray(array).save(path, **kwargs)
    return path


def _strip16(h: int = 64) -> np.ndarray:
    """h x 5 uint16 grey whose columns are V16."""
    return np.tile(V16, (h, 1))


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _png_declaring(path: Path, width: int, height: int) -> Path:
    """A few-byte PNG whose header claims width x height RGB pixels but whose data is garbage:
    any attempt to decode it fails, so an ImageTooLargeError proves the check used the header."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    data = (
        _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IDAT", zlib.compress(b"\0" * 16)) + _png_chunk(b"IEND", b"")
    )
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + data)
    return path


# --------------------------------------------------------------------------------------------
# read_image: formats and conversions


@pytest.mark.parametrize("ext", ["png", "webp", "tif"])
def test_lossless_formats_round_trip_exactly(tmp_path, ext):
    rgb = _rng_rgb()
    options = {"lossless": True} if ext == "webp" else {}
    loaded = io.read_image(_save(tmp_path / f"a.{ext}", rgb, **options))
    assert loaded.pixels.dtype == np.uint8 and loaded.pixels.shape == (70, 90, 3)
    np.testing.assert_array_equal(loaded.pixels, rgb)
    assert loaded.path == str(tmp_path / f"a.{ext}")
    assert loaded.pixels.flags.writeable


def test_grey_image_becomes_three_equal_channels(tmp_path):
    grey = _rng_rgb()[..., 0]
    pixels = io.read_image(_save(tmp_path / "g.png", grey)).pixels
    assert pixels.shape == (70, 90, 3)
    for c in range(3):
        np.testing.assert_array_equal(pixels[..., c], grey)


def test_rgba_image_drops_alpha(tmp_path):
    rgba = np.dstack([_rng_rgb(), np.full((70, 90), 10, np.uint8)])
    pixels = io.read_image(_save(tmp_path / "a.png", rgba)).pixels
    np.testing.assert_array_equal(pixels, rgba[..., :3])


def test_palette_image_is_expanded(tmp_path):
    rgb = np.zeros((64, 64, 3), np.uint8)
    rgb[:, 32:] = (200, 30, 90)
    pal = Image.fromarray(rgb).quantize(colors=2)
    pal.save(tmp_path / "p.png")
    assert Image.open(tmp_path / "p.png").mode == "P"
    np.testing.assert_array_equal(io.read_image(tmp_path / "p.png").pixels, rgb)


def test_16bit_colour_png_is_scaled_with_rounding(tmp_path):
    rgb16 = np.dstack([_strip16(), _strip16()[:, ::-1], np.full((64, 5), 65535, np.uint16)])
    cv2.imwrite(str(tmp_path / "c16.png"), rgb16[..., ::-1])  # OpenCV writes BGR
    pixels = io.read_image(tmp_path / "c16.png", min_side=5).pixels
    np.testing.assert_array_equal(pixels[0, :, 0], V8)
    np.testing.assert_array_equal(pixels[0, :, 1], V8[::-1])
    np.testing.assert_array_equal(pixels[0, :, 2], 255)


def test_16bit_grey_png_is_scaled_with_rounding(tmp_path):
    cv2.imwrite(str(tmp_path / "g16.png"), _strip16())
    pixels = io.read_image(tmp_path / "g16.png", min_side=5).pixels
    np.testing.assert_array_equal(pixels[0], np.repeat(V8[:, None], 3, axis=1))


@pytest.mark.parametrize("planar", [False, True])
def test_16bit_rgb_tiff_is_scaled_with_rounding(tmp_path, planar):
    rgb16 = np.dstack([_strip16(), _strip16()[:, ::-1], np.zeros((64, 5), np.uint16)])
    if planar:
        tifffile.imwrite(
            tmp_path / "c16.tif", np.moveaxis(rgb16, -1, 0), photometric="rgb", planarconfig="separate"
        )
    else:
        tifffile.imwrite(tmp_path / "c16.tif", rgb16, photometric="rgb")
    pixels = io.read_image(tmp_path / "c16.tif", min_side=5).pixels
    np.testing.assert_array_equal(pixels[0, :, 0], V8)
    np.testing.assert_array_equal(pixels[0, :, 1], V8[::-1])
    np.testing.assert_array_equal(pixels[0, :, 2], 0)


def test_16bit_grey_and_float_tiff(tmp_path):
    tifffile.imwrite(tmp_path / "g16.tif", _strip16())
    np.testing.assert_array_equal(io.read_image(tmp_path / "g16.tif", min_side=5).pixels[0, :, 1], V8)
    tifffile.imwrite(tmp_path / "f.tif", np.tile(np.float32([-0.5, 0.0, 0.5, 1.0, 2.0]), (64, 1)))
    np.testing.assert_array_equal(
        io.read_image(tmp_path / "f.tif", min_side=5).pixels[0, :, 0], [0, 0, 128, 255, 255]
    )


def _quadrants(h: int, w: int) -> np.ndarray:
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[: h // 2, : w // 2] = (255, 0, 0)
    rgb[: h // 2, w // 2 :] = (0, 255, 0)
    rgb[h // 2 :, : w // 2] = (0, 0, 255)
    rgb[h // 2 :, w // 2 :] = (255, 255, 0)
    return rgb


def _exif(orientation: int | None = None, **exif_ifd) -> Image.Exif:
    exif = Image.Exif()
    if orientation is not None:
        exif[ExifTags.Base.Orientation] = orientation
    sub = exif.get_ifd(ExifTags.IFD.Exif)
    for name, value in exif_ifd.items():
        sub[getattr(ExifTags.Base, name)] = value
    return exif


def test_exif_orientation_6_rotates_clockwise(tmp_path):
    stored = _quadrants(64, 96)  # stored landscape; orientation 6 = display turned 90 deg clockwise
    path = _save(tmp_path / "o.jpg", stored, exif=_exif(6), quality=95)
    pixels = io.read_image(path).pixels
    assert pixels.shape == (96, 64, 3)
    expected = np.rot90(stored, k=-1)
    assert np.abs(pixels.astype(int) - expected).mean() < 3.0  # JPEG noise at colour edges only
    # the stored top-left (red) quadrant is now top-right
    np.testing.assert_allclose(pixels[10, 50], (255, 0, 0), atol=8)


# --------------------------------------------------------------------------------------------
# ExifCamera


def test_exif_camera_fields_from_jpeg(tmp_path):
    tags = {
        "FocalLength": 4.25,
        "FocalLengthIn35mmFilm": 26,
        "FocalPlaneXResolution": 1000.0,
        "FocalPlaneYResolution": 2000.0,
        "FocalPlaneResolutionUnit": 3,  # per cm
        "ExifImageWidth": 4000,
        "ExifImageHeight": 3000,
    }
    cam = io.read_image(_save(tmp_path / "e.jpg", _rng_rgb(64, 96), exif=_exif(1, **tags))).exif
    assert cam.focal_mm == pytest.approx(4.25)
    assert cam.focal_35mm == pytest.approx(26.0)
    assert cam.focal_plane_x_res == pytest.approx(100.0)  # 1000 / cm = 100 / mm
    assert cam.focal_plane_y_res == pytest.approx(200.0)
    assert cam.original_size == (4000, 3000)

    # An image displayed turned by 90 degrees gets x and y swapped, like its pixels.
    cam = io.read_image(_save(tmp_path / "r.jpg", _rng_rgb(64, 96), exif=_exif(6, **tags))).exif
    assert (cam.focal_plane_x_res, cam.focal_plane_y_res) == (pytest.approx(200.0), pytest.approx(100.0))
    assert cam.original_size == (3000, 4000)


def test_exif_camera_from_tiff_sub_ifd(tmp_path):
    info = TiffImagePlugin.ImageFileDirectory_v2()
    info[ExifTags.Base.Orientation] = 8
    info[ExifTags.IFD.Exif] = {ExifTags.Base.FocalLength: 4.25, ExifTags.Base.FocalLengthIn35mmFilm: 26}
    Image.fromarray(_quadrants(64, 96)).save(tmp_path / "e.tif", tiffinfo=info)
    loaded = io.read_image(tmp_path / "e.tif")
    assert (loaded.exif.focal_mm, loaded.exif.focal_35mm) == (pytest.approx(4.25), pytest.approx(26.0))
    np.testing.assert_array_equal(loaded.pixels, np.rot90(_quadrants(64, 96)))  # 8: 90 deg anticlockwise


def test_exif_camera_inch_default_unit_zero_and_absent(tmp_path):
    tags = {"FocalPlaneXResolution": 2540.0, "FocalLengthIn35mmFilm": 0}  # unit absent = inch; 0 = unknown
    cam = io.read_image(_save(tmp_path / "e.jpg", _rng_rgb(64, 96), exif=_exif(None, **tags))).exif
    assert cam.focal_plane_x_res == pytest.approx(100.0)
    assert cam.focal_35mm is None and cam.focal_mm is None and cam.original_size is None
    assert io.read_image(_save(tmp_path / "n.png", _rng_rgb())).exif == io.ExifCamera()


# --------------------------------------------------------------------------------------------
# read_image / read_mask errors


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(MissingFileError, match=r"nope\.png: file not found"):
        io.read_image(tmp_path / "nope.png")
    with pytest.raises(MissingFileError, match="is a directory"):
        io.read_mask(tmp_path)


def test_unreadable_file(tmp_path, monkeypatch):
    path = _save(tmp_path / "a.png", _rng_rgb())
    path.chmod(0)
    if os.access(path, os.R_OK):  # root ignores permissions: make the open itself fail

        def denied(*args, **kwargs):
            raise PermissionError(13, "Permission denied")

        monkeypatch.setattr(io.images, "open", denied, raising=False)
    with pytest.raises(UnreadableFileError, match=r"a\.png: cannot open file.*Permission denied"):
        io.read_image(path)


def test_non_image_and_unsupported_format(tmp_path):
    (tmp_path / "text.png").write_text("hello, not an image\n" * 20)
    with pytest.raises(CorruptImageError, match=r"text\.png: not a PNG, JPEG, WebP, TIFF or HEIC image"):
        io.read_image(tmp_path / "text.png")
    _save(tmp_path / "b.bmp", _rng_rgb())  # a real image, in a format we do not accept
    with pytest.raises(CorruptImageError, match=r"b\.bmp"):
        io.read_image(tmp_path / "b.bmp")


@pytest.mark.parametrize("ext", ["png", "jpg", "tif"])
def test_truncated_image(tmp_path, ext):
    path = _save(tmp_path / f"t.{ext}", _rng_rgb(200, 200))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(CorruptImageError, match=rf"t\.{ext}: cannot decode image, truncated or corrupt"):
        io.read_image(path)


def test_truncated_16bit_png(tmp_path, capfd):
    """Refused with one message, and libpng (which OpenCV's 16-bit decoding wraps) never gets to
    print its own error on stderr."""
    rgb16 = np.random.default_rng(1).integers(0, 65535, (100, 100, 3)).astype(np.uint16)
    cv2.imwrite(str(tmp_path / "t.png"), rgb16)
    data = (tmp_path / "t.png").read_bytes()
    (tmp_path / "t.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(CorruptImageError, match=r"t\.png: cannot decode image, truncated or corrupt \(its"):
        io.read_image(tmp_path / "t.png")
    assert capfd.readouterr().err == ""


def test_too_small(tmp_path):
    io.read_image(_save(tmp_path / "ok.png", _rng_rgb(64, 200)))  # exactly min_side is fine
    with pytest.raises(ImageTooSmallError, match=r"small\.png: 200x63 has a side under the minimum of 64"):
        io.read_image(_save(tmp_path / "small.png", _rng_rgb(63, 200)))


def test_too_large_is_refused_from_header_alone(tmp_path):
    # 9000 x 9000 = 81 M pixels: over our 60 M default, under Pillow's own ~89 M warning limit.
    path = _png_declaring(tmp_path / "big.png", 9000, 9000)
    with pytest.raises(ImageTooLargeError, match=r"big\.png: 9000x9000 = 81000000 pixels is over the limit"):
        io.read_image(path)
    with pytest.raises(ImageTooLargeError, match=r"big\.png"):
        io.read_mask(path)
    # With a higher limit the same file is decoded, and fails as the garbage it is.
    with pytest.raises(CorruptImageError):
        io.read_image(path, max_pixels=100_000_000)


def test_pixel_data_is_never_decoded_for_a_too_large_image(tmp_path, monkeypatch):
    def no_decoding(*args, **kwargs):
        raise AssertionError("pixels decoded")

    monkeypatch.setattr(ImageFile.ImageFile, "load", no_decoding)
    monkeypatch.setattr(cv2, "imdecode", no_decoding)
    monkeypatch.setattr(tifffile.TiffPage, "asarray", no_decoding)
    _save(tmp_path / "a.png", _rng_rgb(100, 100))
    cv2.imwrite(str(tmp_path / "b.png"), np.zeros((100, 100, 3), np.uint16))
    tifffile.imwrite(tmp_path / "c.tif", np.zeros((100, 100, 3), np.uint16), photometric="rgb")
    for name in ("a.png", "b.png", "c.tif"):
        with pytest.raises(ImageTooLargeError, match="10000 pixels is over the limit of 9999"):
            io.read_image(tmp_path / name, max_pixels=9999)


def test_pillow_decompression_bomb_guard_maps_to_too_large(tmp_path, monkeypatch):
    path = _save(tmp_path / "a.png", _rng_rgb(100, 100))  # 10000 pixels
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 6000)  # Pillow warns over 6000, errors over 12000
    # One limit in the message, ours, not Pillow's words with its own limits.
    with pytest.raises(
        ImageTooLargeError, match=r"a\.png: 10000 pixels is over the limit of 6000 pixels \(max_pixels\)$"
    ):
        io.read_image(path, max_pixels=6000)  # Pillow's warning fires first
    assert io.read_image(path, max_pixels=20000).pixels.shape == (100, 100, 3)  # we allow more: ignored
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 4000)
    with pytest.raises(
        ImageTooLargeError, match=r"a\.png: 10000 pixels is over the most Pillow decodes \(8000 pixels\)$"
    ):
        io.read_image(path, max_pixels=20000)  # Pillow's hard error
    # a header declaring 10^10 pixels trips Pillow's error with its default limit
    monkeypatch.undo()
    with pytest.raises(
        ImageTooLargeError, match=r"huge\.png: 10000000000 pixels is over the limit of 60000000 pixels"
    ):
        io.read_image(_png_declaring(tmp_path / "huge.png", 100_000, 100_000))


# --------------------------------------------------------------------------------------------
# read_mask


def test_mask_threshold_is_127(tmp_path):
    grey = np.zeros((64, 64), np.uint8)
    grey[:, 0], grey[:, 1], grey[:, 2], grey[:, 3] = 126, 127, 128, 255
    mask = io.read_mask(_save(tmp_path / "m.png", grey))
    assert mask.dtype == np.bool_ and mask.shape == (64, 64)
    np.testing.assert_array_equal(mask[0, :5], [False, True, True, True, False])
    assert mask.sum() == 3 * 64


def test_rgba_mask_uses_alpha(tmp_path):
    rgba = np.zeros((64, 64, 4), np.uint8)
    rgba[..., :3] = 255  # white colour everywhere: a luminance reading would be all hole
    rgba[:10, :10, 3] = 127
    rgba[10:20, :10, 3] = 126
    mask = io.read_mask(_save(tmp_path / "m.png", rgba))
    assert mask.sum() == 100 and mask[:10, :10].all()


def test_opaque_rgba_mask_falls_back_to_luminance(tmp_path):
    rgba = np.zeros((64, 64, 4), np.uint8)
    rgba[..., 3] = 255
    rgba[:10, :10, :3] = 255
    mask = io.read_mask(_save(tmp_path / "m.png", rgba))
    assert mask.sum() == 100 and mask[:10, :10].all()


def test_rgb_mask_uses_luminance(tmp_path):
    rgb = np.zeros((64, 64, 3), np.uint8)
    rgb[:, 0] = (0, 255, 0)  # luminance 150: hole
    rgb[:, 1] = (0, 0, 255)  # luminance 29: not hole
    rgb[:, 2] = (255, 0, 0)  # luminance 76: not hole
    rgb[:, 3] = (127, 127, 127)
    mask = io.read_mask(_save(tmp_path / "m.png", rgb))
    np.testing.assert_array_equal(mask[0, :5], [True, False, False, True, False])


def test_16bit_mask_is_scaled_before_threshold(tmp_path):
    grey = np.zeros((64, 64), np.uint16)
    grey[:, 0] = 126 * 257 + 129  # / 257 = 126.502 -> 127: hole
    grey[:, 1] = 126 * 257 + 128  # / 257 = 126.498 -> 126: not hole
    cv2.imwrite(str(tmp_path / "m16.png"), grey)
    np.testing.assert_array_equal(io.read_mask(tmp_path / "m16.png")[0, :3], [True, False, False])


def test_mask_exif_orientation(tmp_path):
    grey = np.zeros((64, 96), np.uint8)
    grey[:8, :8] = 255  # stored top-left
    mask = io.read_mask(_save(tmp_path / "m.jpg", grey, exif=_exif(6), quality=100))
    assert mask.shape == (96, 64)
    assert mask[:8, -8:].all() and mask.sum() == 64  # displayed top-right


# --------------------------------------------------------------------------------------------
# validate_pair and as_rgb_uint8


def _pair(h: int = 80, w: int = 100):
    mask = np.zeros((h, w), bool)
    mask[20:40, 30:60] = True
    return _rng_rgb(h, w, 1), mask, _rng_rgb(120, 90, 2)


def test_validate_pair_accepts_bool_and_uint8_masks():
    target, mask, source = _pair()
    np.testing.assert_array_equal(io.validate_pair(target, mask, source), mask)
    as_u8 = np.where(mask, 127, 126).astype(np.uint8)
    np.testing.assert_array_equal(io.validate_pair(target, as_u8, source), mask)


def test_validate_pair_mask_errors():
    target, mask, source = _pair()
    with pytest.raises(MaskSizeError, match=r"^m\.png: mask is 99x80 but the target t\.png is 100x80$"):
        io.validate_pair(target, mask[:, :99], source, names=("t.png", "m.png", "s.png"))
    with pytest.raises(
        MaskSizeError, match=r"^mask: mask is 99x80 but the target is 100x80$"
    ):  # not "target target"
        io.validate_pair(target, mask[:, :99], source)
    with pytest.raises(EmptyMaskError, match=r"^mask: mask marks no hole pixel"):
        io.validate_pair(target, np.zeros_like(mask), source)
    big = np.ones_like(mask)
    big[0, :40] = False  # 7960 / 8000 = 99.5 %
    with pytest.raises(MaskTooLargeError, match=r"covers 99\.5% of the target, more than the allowed 90\.0%"):
        io.validate_pair(target, big, source)
    assert io.validate_pair(target, big, source, max_mask_fraction=1.0).sum() == 7960
    with pytest.raises(ConfigError):
        io.validate_pair(target, mask, source, max_mask_fraction=0.0)


def test_validate_pair_image_errors():
    target, mask, source = _pair()
    with pytest.raises(ArrayFormatError, match=r"^source: expected an HxWx3 uint8 RGB array"):
        io.validate_pair(target, mask, source.astype(np.float32))
    with pytest.raises(ArrayFormatError, match="expected 3 channels"):
        io.validate_pair(np.dstack([target, target[..., :1]]), mask, source)
    with pytest.raises(ArrayFormatError, match=r"^mask: expected an HxW bool or uint8 array"):
        io.validate_pair(target, mask.astype(np.float32), source)
    with pytest.raises(ImageTooSmallError, match=r"^source: 90x50 has a side under the minimum of 64 px$"):
        io.validate_pair(target, mask, source[:50])
    with pytest.raises(ImageTooLargeError, match=r"^target: 100x80 = 8000 pixels is over the limit of 7999"):
        io.validate_pair(target, mask, source, max_pixels=7999)


def test_as_rgb_uint8_conversions():
    grey = np.arange(12, dtype=np.uint8).reshape(3, 4)
    for a in (grey, grey[..., None], np.dstack([grey, grey * 0])):
        out = io.as_rgb_uint8(a)
        assert out.shape == (3, 4, 3) and out.dtype == np.uint8
        np.testing.assert_array_equal(out[..., 2], grey)
    rgba = np.dstack([_rng_rgb(3, 4), np.zeros((3, 4), np.uint8)])
    np.testing.assert_array_equal(io.as_rgb_uint8(rgba), rgba[..., :3])
    np.testing.assert_array_equal(io.as_rgb_uint8(V16[None])[0, :, 0], V8)
    every16 = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    np.testing.assert_array_equal(io.as_rgb_uint8(every16)[..., 0], np.floor(every16 / 257.0 + 0.5))
    floats = np.array([[np.nan, -1.0, 0.5, 1.0, 3.0]], np.float32)
    np.testing.assert_array_equal(io.as_rgb_uint8(floats)[0, :, 1], [0, 0, 128, 255, 255])
    np.testing.assert_array_equal(io.as_rgb_uint8(np.array([[True, False]]))[0, :, 0], [255, 0])
    with pytest.raises(ArrayFormatError, match="unsupported dtype int64"):
        io.as_rgb_uint8(np.zeros((3, 4), np.int64))
    with pytest.raises(ArrayFormatError, match=r"got shape \(2, 3, 4, 3\)"):
        io.as_rgb_uint8(np.zeros((2, 3, 4, 3), np.uint8))


# --------------------------------------------------------------------------------------------
# Writing


@pytest.mark.parametrize("ext", ["png", "tif", "tiff", "webp", "jpg", "jpeg"])
def test_write_image_atomic_round_trip(tmp_path, ext):
    rgb = _quadrants(64, 96)
    path = tmp_path / f"out.{ext.upper()}"  # extension case does not matter
    io.write_image_atomic(path, rgb)
    back = io.read_image(path).pixels
    if ext in ("png", "tif", "tiff"):
        np.testing.assert_array_equal(back, rgb)
    else:
        assert np.abs(back.astype(int) - rgb).mean() < 3.0
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temp file left


def test_write_image_atomic_replaces_existing(tmp_path):
    path = tmp_path / "out.png"
    io.write_image_atomic(path, _rng_rgb(seed=1))
    io.write_image_atomic(path, _rng_rgb(seed=2))
    np.testing.assert_array_equal(io.read_image(path).pixels, _rng_rgb(seed=2))
    assert [p.name for p in tmp_path.iterdir()] == ["out.png"]


def test_write_image_atomic_failure_leaves_old_file_and_no_temp(tmp_path, monkeypatch):
    path = tmp_path / "out.png"
    io.write_image_atomic(path, _rng_rgb(seed=1))
    before = path.read_bytes()

    def broken_save(self, fp, *args, **kwargs):
        fp.write(b"partial")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Image.Image, "save", broken_save)
    with pytest.raises(OutputError, match=r"out\.png: cannot write image.*No space left"):
        io.write_image_atomic(path, _rng_rgb(seed=2))
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["out.png"]


def test_write_image_atomic_flushes_the_file_then_the_folder_around_the_rename(tmp_path, monkeypatch):
    """A power cut after the rename must find the new image: its data reaches the disk before the
    rename, the folder's new entry after it."""
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append("fsync folder" if stat.S_ISDIR(os.fstat(fd).st_mode) else "fsync file")
        real_fsync(fd)

    def replace(src, dst):
        events.append(f"rename {Path(src).name[:9]} -> {Path(dst).name}")
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    io.write_image_atomic(tmp_path / "out.png", _rng_rgb())
    assert events == ["fsync file", "rename .out.png. -> out.png", "fsync folder"]
    np.testing.assert_array_equal(io.read_image(tmp_path / "out.png").pixels, _rng_rgb())


def _jpeg_tables(path):
    from PIL import JpegImagePlugin

    with Image.open(path) as img:
        return {k: list(v) for k, v in img.quantization.items()}, JpegImagePlugin.get_sampling(img)


def test_jpeg_output_keeps_the_inputs_quantisation_tables(tmp_path):
    """A JPEG input's tables and subsampling (quality 70, 4:4:4 here) are those of its JPEG output,
    whatever Pillow's default quality would be; --quality replaces them; a PNG input gives 95."""
    rgb = _quadrants(96, 128)
    Image.fromarray(rgb).save(tmp_path / "in.jpg", quality=70, subsampling=0)
    tables, sampling = _jpeg_tables(tmp_path / "in.jpg")
    assert sampling == 0 and len(tables) == 2
    loaded = io.read_image(tmp_path / "in.jpg")
    io.write_image_atomic(tmp_path / "out.jpg", loaded.pixels, metadata=loaded.metadata)
    assert _jpeg_tables(tmp_path / "out.jpg") == (tables, 0)
    io.write_image_atomic(tmp_path / "q90.jpg", loaded.pixels, metadata=loaded.metadata, quality=90)
    Image.fromarray(rgb).save(tmp_path / "pillow90.jpg", quality=90)
    assert _jpeg_tables(tmp_path / "q90.jpg") == _jpeg_tables(tmp_path / "pillow90.jpg")
    # The tables are how the file was encoded, not metadata: stripping EXIF and ICC keeps them.
    io.write_image_atomic(tmp_path / "bare.jpg", loaded.pixels, metadata=loaded.metadata.stripped())
    assert _jpeg_tables(tmp_path / "bare.jpg") == (tables, 0)
    png = io.read_image(_save(tmp_path / "in.png", rgb))
    assert png.metadata.jpeg_tables is None
    io.write_image_atomic(tmp_path / "from_png.jpg", png.pixels, metadata=png.metadata)
    Image.fromarray(rgb).save(tmp_path / "pillow95.jpg", quality=95)
    assert _jpeg_tables(tmp_path / "from_png.jpg") == _jpeg_tables(tmp_path / "pillow95.jpg")
    # A grey JPEG has one table: it serves the chroma of the RGB output too.
    Image.fromarray(rgb[..., 0]).save(tmp_path / "grey.jpg", quality=60)
    grey = io.read_image(tmp_path / "grey.jpg")
    io.write_image_atomic(tmp_path / "grey_out.jpg", grey.pixels, metadata=grey.metadata)
    grey_tables, _ = _jpeg_tables(tmp_path / "grey.jpg")
    assert list(grey_tables) == [0]
    assert _jpeg_tables(tmp_path / "grey_out.jpg")[0] == {0: grey_tables[0], 1: grey_tables[0]}


def test_write_image_atomic_refuses_bad_paths_and_writes_nothing(tmp_path):
    rgb = _rng_rgb()
    with pytest.raises(OutputError, match=r"out\.gif: unsupported output extension '\.gif'"):
        io.write_image_atomic(tmp_path / "out.gif", rgb)
    with pytest.raises(OutputError, match="does not exist"):
        io.write_image_atomic(tmp_path / "missing" / "out.png", rgb)
    (tmp_path / "taken.png").mkdir()
    with pytest.raises(OutputError, match=r"taken\.png: is a directory"):
        io.write_image_atomic(tmp_path / "taken.png", rgb)
    assert [p.name for p in tmp_path.iterdir()] == ["taken.png"]
    assert list((tmp_path / "taken.png").iterdir()) == []


def test_check_output_path(tmp_path, monkeypatch):
    io.check_output_path(tmp_path / "fine.jpeg")
    with pytest.raises(OutputError, match="unsupported output extension ''"):
        io.check_output_path(tmp_path / "noext")
    with pytest.raises(OutputError, match=r"nowhere.*does not exist"):
        io.check_output_path(tmp_path / "nowhere" / "a.png")
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(OutputError, match="does not exist"):  # a file where the folder should be
        io.check_output_path(tmp_path / "file.txt" / "a.png")
    monkeypatch.setattr(os, "access", lambda *args, **kwargs: False)  # root can write anywhere
    with pytest.raises(OutputError, match="is not writable"):
        io.check_output_path(tmp_path / "a.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]


# --------------------------------------------------------------------------------------------
# Depth files


def _depth_values() -> np.ndarray:
    depth = np.linspace(1.0, 5.0, 6 * 8, dtype=np.float32).reshape(6, 8)
    depth[0, 0] = 0.0
    depth[0, 1] = np.inf
    depth[0, 2] = np.nan
    return depth


def _check_depth(got: np.ndarray, want: np.ndarray, rtol: float = 1e-6) -> None:
    assert got.dtype == np.float32 and got.shape == want.shape
    assert np.isnan(got[0, :3]).all()
    np.testing.assert_allclose(got[0, 3:], want[0, 3:], rtol=rtol)
    np.testing.assert_allclose(got[1:], want[1:], rtol=rtol)


def test_depth_npy_with_scale(tmp_path):
    np.save(tmp_path / "d.npy", _depth_values().astype(np.float64))
    _check_depth(io.read_depth_file(tmp_path / "d.npy", expected_size=(8, 6), scale=2.0), 2 * _depth_values())
    np.save(tmp_path / "d1.npy", _depth_values()[..., None])  # HxWx1 is fine
    _check_depth(io.read_depth_file(tmp_path / "d1.npy", expected_size=(8, 6)), _depth_values())


def test_depth_16bit_png_in_millimetres(tmp_path):
    mm = np.arange(48, dtype=np.uint16).reshape(6, 8) * 1000
    mm[0, 5] = 65535
    cv2.imwrite(str(tmp_path / "d.png"), mm)
    depth = io.read_depth_file(tmp_path / "d.png", expected_size=(8, 6), scale=0.001)
    assert np.isnan(depth[0, 0]) and np.isfinite(depth.ravel()[1:]).all()
    np.testing.assert_allclose(depth.ravel()[1:], mm.ravel()[1:] * 0.001, rtol=1e-6)
    assert depth[0, 5] == pytest.approx(65.535)


def test_depth_tiff_float_and_uint16(tmp_path):
    tifffile.imwrite(tmp_path / "d.tif", _depth_values())
    _check_depth(
        io.read_depth_file(tmp_path / "d.tif", expected_size=(8, 6), scale=0.5), 0.5 * _depth_values()
    )
    tifffile.imwrite(tmp_path / "u.tiff", np.full((6, 8), 1234, np.uint16))
    np.testing.assert_allclose(io.read_depth_file(tmp_path / "u.tiff", expected_size=(8, 6)), 1234.0)


def test_depth_values_beyond_float32_are_invalid_without_a_warning(tmp_path):
    d = np.full((6, 8), 2.0)
    d[0, :3] = [1e300, -1e300, 1e-300]  # float64 values float32 cannot hold: inf, -inf, 0
    np.save(tmp_path / "d.npy", d)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = io.read_depth_file(tmp_path / "d.npy", expected_size=(8, 6))
    assert np.isnan(got[0, :3]).all() and (got[0, 3:] == 2.0).all() and (got[1:] == 2.0).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = io.read_depth_file(
            tmp_path / "d.npy", expected_size=(8, 6), scale=1e38
        )  # 2e38 fits, 2 * 1e38 ...
    assert np.isnan(got[0, :3]).all() and np.isfinite(got[1:]).all()


def test_depth_exr(tmp_path):
    openexr = pytest.importorskip("OpenEXR")
    header = {"compression": openexr.ZIP_COMPRESSION, "type": openexr.scanlineimage}
    openexr.File(header, {"Z": _depth_values()}).write(str(tmp_path / "z.exr"))
    _check_depth(io.read_depth_file(tmp_path / "z.exr", expected_size=(8, 6), scale=3.0), 3 * _depth_values())
    # several channels: depth taken from R; half floats are widened
    rgb = np.dstack([_depth_values(), np.ones((6, 8), np.float32), np.ones((6, 8), np.float32)])
    openexr.File(header, {"RGB": rgb.astype(np.float16)}).write(str(tmp_path / "rgb.exr"))
    _check_depth(io.read_depth_file(tmp_path / "rgb.exr", expected_size=(8, 6)), _depth_values(), rtol=1e-3)
    with pytest.raises(DepthFileError, match=r"z\.exr: depth map is 8x6 but the image it belongs to is 6x8"):
        io.read_depth_file(tmp_path / "z.exr", expected_size=(6, 8))
    (tmp_path / "bad.exr").write_bytes(b"not an exr file" * 10)
    with pytest.raises(DepthFileError, match=r"bad\.exr: cannot read EXR"):
        io.read_depth_file(tmp_path / "bad.exr", expected_size=(8, 6))


def test_depth_exr_without_the_extra(tmp_path, monkeypatch):
    (tmp_path / "d.exr").write_bytes(b"\x76\x2f\x31\x01")
    monkeypatch.setitem(sys.modules, "OpenEXR", None)  # makes `import OpenEXR` fail
    with pytest.raises(MissingExtraError, match=r"d\.exr: reading EXR needs the optional 'exr' extra"):
        io.read_depth_file(tmp_path / "d.exr", expected_size=(8, 6))


def test_depth_errors(tmp_path):
    with pytest.raises(DepthFileError, match=r"none\.npy: depth file not found"):
        io.read_depth_file(tmp_path / "none.npy", expected_size=(8, 6))
    with pytest.raises(DepthFileError, match="is a directory"):
        io.read_depth_file(tmp_path, expected_size=(8, 6))
    np.save(tmp_path / "d.npy", np.ones((6, 8), np.float32))
    with pytest.raises(
        DepthFileError, match=r"d\.npy: depth map is 8x6 but the image it belongs to is 16x12"
    ):
        io.read_depth_file(tmp_path / "d.npy", expected_size=(16, 12))
    with pytest.raises(DepthFileError, match=r"d\.bin: unsupported depth file extension"):
        (tmp_path / "d.bin").write_bytes(b"1234")
        io.read_depth_file(tmp_path / "d.bin", expected_size=(8, 6))
    for name in ("c.npy", "c.png", "c.tif"):
        (tmp_path / name).write_bytes(b"garbage" * 20)
        with pytest.raises(DepthFileError, match=rf"{name}: cannot read depth map"):
            io.read_depth_file(tmp_path / name, expected_size=(8, 6))
    np.save(tmp_path / "rgb.npy", np.ones((6, 8, 3), np.float32))
    with pytest.raises(DepthFileError, match=r"rgb\.npy: expected a single-channel depth map"):
        io.read_depth_file(tmp_path / "rgb.npy", expected_size=(8, 6))
    _save(tmp_path / "rgb.png", _rng_rgb(6, 8))
    with pytest.raises(DepthFileError, match=r"rgb\.png: expected a 16-bit or 8-bit grey PNG"):
        io.read_depth_file(tmp_path / "rgb.png", expected_size=(8, 6))
    with pytest.raises(ConfigError, match="scale"):
        io.read_depth_file(tmp_path / "d.npy", expected_size=(8, 6), scale=0.0)


def test_heic_input_through_the_extra(tmp_path):
    pillow_heif = pytest.importorskip("pillow_heif")
    yy, xx = np.mgrid[0:80, 0:96]
    rgb = np.dstack([xx * 2, yy * 3, 255 - xx - yy]).astype(np.uint8)  # smooth: survives chroma subsampling
    heif = pillow_heif.from_bytes(mode="RGB", size=(96, 80), data=rgb.tobytes())
    heif.save(tmp_path / "p.heic", quality=95)
    got = io.read_image(tmp_path / "p.heic").pixels
    assert got.shape == (80, 96, 3)
    assert np.abs(got.astype(int) - rgb).mean() < 3


def test_heic_without_the_extra_names_it(tmp_path, monkeypatch):
    (tmp_path / "p.heic").write_bytes(b"\x00\x00\x00\x18ftypheic\x00\x00\x00\x00mif1heic" + bytes(64))
    monkeypatch.setitem(sys.modules, "pillow_heif", None)
    with pytest.raises(
        MissingExtraError, match=r'p\.heic: reading HEIC/HEIF needs .*pip install "geofill\[heif\]"'
    ):
        io.read_image(tmp_path / "p.heic")


def test_float_tiffs_pillow_cannot_open(tmp_path):
    rng = np.random.default_rng(1)
    rgb = rng.random((70, 90, 3))
    tifffile.imwrite(tmp_path / "f64.tif", rgb, photometric="rgb")
    tifffile.imwrite(tmp_path / "f16.tif", rgb[..., 0].astype(np.float16))
    assert np.array_equal(io.read_image(tmp_path / "f64.tif").pixels, np.rint(rgb * 255).astype(np.uint8))
    grey = io.read_image(tmp_path / "f16.tif").pixels
    assert np.abs(grey[..., 0].astype(int) - np.rint(rgb[..., 0] * 255)).max() <= 1  # float16 rounding


def test_jpeg_cut_short_before_its_end_marker_is_corrupt(tmp_path):
    """A JPEG whose frame header claims 7000 x 7000 over a small scan that ends early (with an end
    marker, so libjpeg only warns) is refused, not decoded as 49 MP of grey."""
    buf = BytesIO()
    Image.fromarray(np.random.default_rng(2).integers(0, 256, (100, 100, 3), dtype=np.uint8)).save(
        buf, "JPEG"
    )
    data = bytearray(buf.getvalue())
    at = data.find(b"\xff\xc0")
    struct.pack_into(">HH", data, at + 5, 7000, 7000)
    (tmp_path / "claim.jpg").write_bytes(bytes(data))
    with pytest.raises(CorruptImageError, match=r"claim\.jpg: .*premature end of data segment"):
        io.read_image(tmp_path / "claim.jpg")


def test_zero_dimensional_npy_depth(tmp_path):
    np.save(tmp_path / "d.npy", np.float32(2.0))
    with pytest.raises(DepthFileError, match=r"d\.npy: expected a 2-D depth map, got array shape \(\)"):
        io.read_depth_file(tmp_path / "d.npy", expected_size=(8, 6))


def test_long_names_are_errors_not_crashes(tmp_path):
    with pytest.raises(UnreadableFileError, match="File name too long"):
        io.read_image(tmp_path / ("a" * 300 + ".png"))
    with pytest.raises(OutputError, match=r"file name too long \(304 bytes; the limit here is 237"):
        io.check_output_path(tmp_path / ("a" * 300 + ".png"))
    # Short enough for the file system, too long once the temporary file's affixes are added.
    with pytest.raises(OutputError, match=r"file name too long \(244 bytes; the limit here is 237 bytes\)"):
        io.check_output_path(tmp_path / ("a" * 240 + ".png"))
    io.check_output_path(tmp_path / ("a" * 233 + ".png"))
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputError, match="exists and is not a directory"):
        io.check_output_dir(tmp_path / "f")
    io.check_output_dir(tmp_path / "new" / "deeper")
    assert not (tmp_path / "new").exists()  # a check creates nothing


def test_reference_masks_in_a_folder_are_matched_by_stem():
    refs, masks = io.split_reference_masks(
        [Path("d/a.jpg"), Path("d/B.MASK.png"), Path("d/b.png"), Path("d/c.tif"), Path("d/c.mask.jpg")]
    )
    assert refs == [Path("d/a.jpg"), Path("d/b.png"), Path("d/c.tif")]
    assert masks == {Path("d/b.png"): Path("d/B.MASK.png"), Path("d/c.tif"): Path("d/c.mask.jpg")}
    with pytest.raises(
        InputError, match=r"^d/x\.mask\.png: reference mask without a reference: no image named x\.\*"
    ):
        io.split_reference_masks([Path("d/a.jpg"), Path("d/x.mask.png")])
    with pytest.raises(
        InputError, match=r"^d/a\.mask\.png: reference mask of which reference\? a\.jpg, a\.png$"
    ):
        io.split_reference_masks([Path("d/a.jpg"), Path("d/a.png"), Path("d/a.mask.png")])
    with pytest.raises(
        InputError, match=r"^d/a\.mask\.png: a\.jpg has another mask already \(a\.mask\.jpg\)$"
    ):
        io.split_reference_masks([Path("d/a.jpg"), Path("d/a.mask.jpg"), Path("d/a.mask.png")])
