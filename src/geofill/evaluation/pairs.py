"""Evaluation pairs: pair folders and multi-reference sets (or synthetic pairs) with their EXIF
and meta.json, the ``--by`` groups, and the seeded hole each pair is scored with."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
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


@dataclass(frozen=True)
class PairGeometry:
    """Known camera geometry of a pair, as far as it is known (the removal protocols use it).

    ``K_sources[k]`` / ``T_source_to_target[k]`` (4x4, ``X_t = R X_s + t``, OpenCV axes) are None
    where unknown; ``depth_sources[k]`` is a reference's ground-truth z-depth (same units as T; 0 =
    invalid) or None. Synthetic scenes add the exact target depth and the scene itself with the
    target's camera-to-world pose (for exact visibility)."""

    K_target: np.ndarray | None
    K_sources: tuple[np.ndarray | None, ...]
    T_source_to_target: tuple[np.ndarray | None, ...]
    depth_sources: tuple[np.ndarray | None, ...] = ()
    depth_target: np.ndarray | None = None
    scene: Any = None  # geofill.synthetic.Scene
    target_to_world: np.ndarray | None = None

    @property
    def posed(self) -> bool:
        """Every reference has K and a pose, and the target has K."""
        return (
            self.K_target is not None
            and all(K is not None for K in self.K_sources)
            and all(T is not None for T in self.T_source_to_target)
        )

    def depth_source(self, k: int) -> np.ndarray | None:
        """Reference ``k``'s ground-truth depth, if known."""
        return self.depth_sources[k] if k < len(self.depth_sources) else None


@dataclass
class Pair:
    """One evaluation pair or multi-reference set: target (ground truth) and its references
    (primary first), HxWx3 uint8 RGB; ``geometry`` is set for synthetic scenes (real sets carry
    theirs in ``meta``: see :func:`pair_geometry`)."""

    id: str
    target: np.ndarray
    sources: list[np.ndarray]
    meta: dict[str, Any]
    path: Path | None
    exif: PairExif = PairExif()
    geometry: PairGeometry | None = None

    @property
    def source(self) -> np.ndarray:
        """The primary reference."""
        return self.sources[0]


_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
SYNTHETIC_PREFIX = "synthetic:"
SYNTHETIC_VIEWS_PREFIX = "synthetic-views:"
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
        geometry = PairGeometry(
            sp.K_target,
            (sp.K_source,),
            (sp.T_source_to_target,),
            (sp.depth_source,),
            sp.depth_target,
            sp.scene,
            sp.target_to_world,
        )
        meta = {"kind": "synthetic", "seed": i}
        pairs.append(Pair(f"synthetic_{i:03d}", sp.target, [sp.source], meta, None, geometry=geometry))
    return pairs


def synthetic_view_sets(n: int) -> list[Pair]:
    """``n`` synthetic multi-reference sets from :func:`geofill.synthetic.make_views` (seeds
    0..n-1: the target of ``synthetic_<seed>`` with a reference stepped left and one stepped right)."""
    from ..synthetic import make_views

    sets = []
    for i in range(n):
        sv = make_views(seed=i)
        h, w = sv.target.shape[:2]
        pose_t = sv.scene.target_pose()
        depths = tuple(sv.scene.depth_map(sv.K, pose_t @ T, w, h) for T in sv.T_source_to_target)
        n_refs = len(sv.sources)
        geometry = PairGeometry(
            sv.K, (sv.K,) * n_refs, tuple(sv.T_source_to_target), depths, sv.depth_target, sv.scene, pose_t
        )
        meta = {"kind": "synthetic (views)", "seed": i}
        exif = PairExif(None, (None,) * n_refs)
        sets.append(Pair(f"synthetic_views_{i:03d}", sv.target, list(sv.sources), meta, None, exif, geometry))
    return sets


def load_pairs(dirs: Sequence[str | Path], exclude: Sequence[str] = ()) -> list[Pair]:
    """Pairs from each entry of ``dirs``: a pair folder, a folder of pair folders, or
    ``synthetic:N``. Sorted by id; ids must be unique. The pair folders named in ``exclude`` are
    left out of a folder of pair folders without being read."""
    pairs: list[Pair] = []
    for entry in dirs:
        text = str(entry)
        for prefix, make in (
            (SYNTHETIC_PREFIX, synthetic_pairs),
            (SYNTHETIC_VIEWS_PREFIX, synthetic_view_sets),
        ):
            if text.startswith(prefix):
                count = text[len(prefix) :]
                if not count.isdigit() or int(count) < 1:
                    raise InputError(f"'{text}': expected {prefix}N with N >= 1")
                pairs.extend(make(int(count)))
                break
        else:
            pairs.extend(_load_folder(Path(entry), frozenset(exclude)))
    ids = [p.id for p in pairs]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise InputError(f"duplicate pair ids {duplicates}")
    return sorted(pairs, key=lambda p: p.id)


def _load_folder(folder: Path, exclude: frozenset[str]) -> list[Pair]:
    """A pair folder, or a folder of pair folders (those named in ``exclude`` left out)."""
    if not folder.is_dir():
        raise MissingFileError(f"pairs folder not found: {folder}")
    if _find_image(folder, "target") is not None:
        return [load_pair(folder)]
    subdirs = sorted(
        d
        for d in folder.iterdir()
        if d.is_dir() and d.name not in exclude and _find_image(d, "target") is not None
    )
    if not subdirs:
        raise InputError(f"{folder} holds no pair folders (with target.png/.jpg)")
    return [load_pair(d) for d in subdirs]


def _matrix(value: Any, shape: tuple[int, int]) -> np.ndarray | None:
    if value is None:
        return None
    m = np.asarray(value, dtype=np.float64)
    return m if m.shape == shape and np.all(np.isfinite(m)) else None


def pair_geometry(pair: Pair) -> PairGeometry:
    """What is known of ``pair``'s cameras: its own :attr:`Pair.geometry` (synthetic scenes), else
    meta.json's ``K_target`` and, per entry of ``sources``, ``K``, ``T_source_to_target`` and the
    GT ``depth`` file (16-bit PNG, metres = value / 1000) when present."""
    if pair.geometry is not None:
        return pair.geometry
    entries = pair.meta.get("sources")
    entries = entries if isinstance(entries, list) and len(entries) == len(pair.sources) else []
    entries += [{}] * (len(pair.sources) - len(entries))
    depths: list[np.ndarray | None] = []
    for entry, image in zip(entries, pair.sources, strict=True):
        name = entry.get("depth") if isinstance(entry, dict) else None
        path = pair.path / name if pair.path is not None and isinstance(name, str) else None
        depth = None
        if path is not None and path.is_file():
            raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if raw is not None and raw.shape[:2] == image.shape[:2]:
                depth = raw.astype(np.float32) / 1000.0
        depths.append(depth)
    return PairGeometry(
        _matrix(pair.meta.get("K_target"), (3, 3)),
        tuple(_matrix(e.get("K") if isinstance(e, dict) else None, (3, 3)) for e in entries),
        tuple(_matrix(e.get("T_source_to_target") if isinstance(e, dict) else None, (4, 4)) for e in entries),
        tuple(depths),
    )


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
