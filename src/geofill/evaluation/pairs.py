"""Evaluation pairs: pair folders and multi-reference sets (or synthetic pairs) with their EXIF
and meta.json, the ``--by`` groups, and the seeded hole each pair is scored with."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..config import FillConfig
from ..errors import InputError, MissingFileError
from ..io import ExifCamera, read_image
from .masks import (
    DEFAULT_AREA_RANGE,
    DEFAULT_STROKE_WIDTH_720P,
    brush_strokes,
    mask_seed,
    scaled_stroke_width,
)


@dataclass(frozen=True)
class PairExif:
    """EXIF lens data of a pair's images, one per reference offered (None: no file, e.g. synthetic)."""

    target: ExifCamera | None = None
    sources: tuple[ExifCamera | None, ...] = (None,)

    @property
    def source(self) -> ExifCamera | None:
        """The primary reference's."""
        return self.sources[0]


@dataclass
class Pair:
    """One evaluation pair or multi-reference set: target (ground truth) and its references
    (primary first), HxWx3 uint8 RGB."""

    id: str
    target: np.ndarray
    sources: list[np.ndarray]
    meta: dict[str, Any]
    path: Path | None
    exif: PairExif = PairExif()

    @property
    def source(self) -> np.ndarray:
        """The primary reference."""
        return self.sources[0]


_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
SYNTHETIC_PREFIX = "synthetic:"
_MIN_SIDE_PX = FillConfig().min_side_px


def _find_image(folder: Path, stem: str) -> Path | None:
    for suffix in _IMAGE_SUFFIXES:
        if (folder / f"{stem}{suffix}").is_file():
            return folder / f"{stem}{suffix}"
    return None


#: Reference file stems of a set, in order: ``source`` (the primary), then ``source2`` ...
_SOURCE_STEMS = ("source", *(f"source{k}" for k in range(2, 10)))


def load_pair(folder: str | Path) -> Pair:
    """A pair folder: ``target.{png,jpg}``, ``source.{png,jpg}``, optional ``meta.json``; a
    multi-reference set adds ``source2``, ``source3``, ... (read in that order)."""
    folder = Path(folder)
    images = {}
    for stem in ("target", *_SOURCE_STEMS):
        path = _find_image(folder, stem)
        if path is None:
            if stem in ("target", "source"):
                raise MissingFileError(f"pair folder {folder} has no {stem}.png/.jpg")
            break
        images[stem] = read_image(path, min_side=_MIN_SIDE_PX)
    meta_path = folder / "meta.json"
    try:
        meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    except json.JSONDecodeError as exc:
        raise InputError(f"{meta_path} is not valid JSON: {exc}") from exc
    t, refs = images.pop("target"), list(images.values())
    exif = PairExif(t.exif, tuple(r.exif for r in refs))
    return Pair(folder.name, t.pixels, [r.pixels for r in refs], meta, folder, exif)


def synthetic_pairs(n: int) -> list[Pair]:
    """``n`` synthetic pairs from :func:`geofill.synthetic.make_pair` (seeds 0..n-1)."""
    from ..synthetic import make_pair

    pairs = []
    for i in range(n):
        sp = make_pair(seed=i)
        pairs.append(
            Pair(f"synthetic_{i:03d}", sp.target, [sp.source], {"kind": "synthetic", "seed": i}, None)
        )
    return pairs


def load_pairs(dirs: Sequence[str | Path]) -> list[Pair]:
    """Pairs from each entry of ``dirs``: a pair folder, a folder of pair folders, or
    ``synthetic:N``. Sorted by id; ids must be unique."""
    pairs: list[Pair] = []
    for entry in dirs:
        text = str(entry)
        if text.startswith(SYNTHETIC_PREFIX):
            count = text[len(SYNTHETIC_PREFIX) :]
            if not count.isdigit() or int(count) < 1:
                raise InputError(f"'{text}': expected {SYNTHETIC_PREFIX}N with N >= 1")
            pairs.extend(synthetic_pairs(int(count)))
            continue
        folder = Path(entry)
        if not folder.is_dir():
            raise MissingFileError(f"pairs folder not found: {folder}")
        if _find_image(folder, "target") is not None:
            pairs.append(load_pair(folder))
            continue
        subdirs = sorted(d for d in folder.iterdir() if d.is_dir() and _find_image(d, "target") is not None)
        if not subdirs:
            raise InputError(f"{folder} holds no pair folders (with target.png/.jpg)")
        pairs.extend(load_pair(d) for d in subdirs)
    ids = [p.id for p in pairs]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise InputError(f"duplicate pair ids {duplicates}")
    return sorted(pairs, key=lambda p: p.id)


def group_value(meta: Mapping[str, Any], key: str) -> str:
    """The ``--by`` group of a pair: ``meta[key]`` (dotted keys reach nested fields). Strings are
    grouped by their first word, since meta.json's ``kind`` is 'category (details)'."""
    value: Any = meta
    for part in key.split("."):
        value = value.get(part) if isinstance(value, Mapping) else None
    if value is None:
        return "n/a"
    if isinstance(value, str):
        return value.split()[0] if value.strip() else "n/a"
    return str(value)


def stroke_width_px(pair: Pair, width_720p: float) -> float:
    """A mean brush width given in px at a 720-px short side, scaled to ``pair``'s target."""
    h, w = pair.target.shape[:2]
    return scaled_stroke_width(width_720p, h, w)


def pair_mask(
    pair: Pair,
    seed: int = 0,
    width_720p: float = DEFAULT_STROKE_WIDTH_720P,
    area_range: tuple[float, float] = DEFAULT_AREA_RANGE,
) -> np.ndarray:
    """The evaluation hole of ``pair`` (bool): the same for the same pair id, seed and width."""
    h, w = pair.target.shape[:2]
    width_px = stroke_width_px(pair, width_720p)
    return brush_strokes(
        h, w, seed=mask_seed(pair.id, seed), mean_width_px=width_px, area_range=area_range
    ).render(width_px)
