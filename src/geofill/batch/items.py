"""What a batch is made of: one :class:`BatchItem` per target, found from folders (masks matched by
file stem, or one mask for all) or read from a manifest (CSV or JSONL).

Reference masks (what must never be copied from a reference: a passer-by, a parked car): in a
folder of references, ``<stem>.mask.png`` (any image format) beside ``<stem>.jpg`` is its mask and
never a reference or a target itself; a manifest names them in its ``source_masks`` column.

Problems with the batch as a whole (a folder that does not exist, a manifest without the required
columns, a reference mask in ``--sources DIR`` with no reference of its stem) raise
:class:`geofill.errors.InputError`; a problem with one item (no mask for its stem, a
malformed manifest row, an output name already taken) becomes an item carrying ``error``, which the
runner records as failed without stopping the others.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from ..config import FillConfig, parse_overrides
from ..errors import ConfigError, GeoFillError, InputError
from ..formats import FORMAT_SUFFIXES
from ..io import is_reference_mask, split_reference_masks

#: Files taken as images in folders (the formats :func:`geofill.io.read_image` decodes).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".webp", ".tif", ".tiff")
#: Output formats :func:`geofill.io.write_image_atomic` writes; a batch writes each target's own
#: format by default (:func:`output_name`).
OUTPUT_SUFFIXES = IMAGE_SUFFIXES
MANIFEST_COLUMNS = ("target", "mask", "sources", "source_masks", "output", "set")
_REQUIRED = ("target", "mask", "sources")
#: Separates several sources (and several ``key=value`` overrides) inside one CSV cell.
CSV_LIST_SEPARATOR = ";"


@dataclass(frozen=True)
class BatchItem:
    """One fill of a batch. Paths are as given (relative to the working folder or the manifest).

    ``sources`` are the references to use as they are; ``candidates`` (``--sources DIR``) are
    references to choose from by measured overlap, at most ``max_refs`` of them;
    ``reference_masks`` maps a reference (or candidate) path to its mask's path. ``where`` says
    where the item came from in messages (``images/a.jpg``, ``manifest.csv:7``). An item with an
    ``error`` is not run: it is recorded as failed with that reason."""

    name: str  # unique within the batch: the output's stem
    target: str
    mask: str
    output: str  # file name inside the output folder
    sources: tuple[str, ...] = ()
    candidates: tuple[str, ...] = ()
    max_refs: int = 1
    reference_masks: Mapping[str, str] = field(default_factory=dict)
    overrides: Mapping[str, Any] = field(default_factory=dict)
    where: str = ""
    error: str = ""


def output_name(target: Path, output_format: str | None = None) -> str:
    """The output file name of ``target``: its stem with the extension of ``output_format`` (a
    :data:`FORMAT_SUFFIXES` key) or, by default, its own extension, so that a JPEG stays a JPEG;
    ``.png`` for a format geofill reads but does not write (HEIC)."""
    if output_format is not None:
        return target.stem + FORMAT_SUFFIXES[output_format]
    return target.name if target.suffix.lower() in OUTPUT_SUFFIXES else f"{target.stem}.png"


def image_files(folder: Path) -> list[Path]:
    """The image files directly inside ``folder``, sorted by name (reference masks included)."""
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder")
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def _by_stem(files: Iterable[Path]) -> dict[str, list[Path]]:
    out: dict[str, list[Path]] = {}
    for p in files:
        out.setdefault(p.stem, []).append(p)
    return out


def items_from_folders(
    images: Path,
    masks: Path,
    *,
    sources: Path | None = None,
    sources_per_image: Path | None = None,
    max_refs: int = 1,
    output_format: str | None = None,
) -> list[BatchItem]:
    """One item per image in ``images``. ``masks`` is a folder (the mask with the image's stem) or
    one mask file for every image. References: ``sources`` (every image of that folder but the
    target itself is a candidate; the best ``max_refs`` are picked per target) or
    ``sources_per_image`` (``DIR/<stem>/`` holds the image's references, all used, in name order).
    A reference's mask is ``<stem>.mask.png`` beside it; such files are neither targets nor
    references. Outputs are named by :func:`output_name`."""
    if (sources is None) == (sources_per_image is None):
        raise InputError("give the references with exactly one of --sources, --sources-per-image, --manifest")
    if max_refs < 1:
        raise ConfigError(f"--max-refs must be at least 1, got {max_refs}")
    targets = [p for p in image_files(images) if not is_reference_mask(p)]
    if not targets:
        raise InputError(f"{images}: holds no image ({', '.join(IMAGE_SUFFIXES)})")
    if not masks.exists():
        raise InputError(f"{masks}: no such mask folder or file")
    mask_by_stem = _by_stem(image_files(masks)) if masks.is_dir() else None
    pool, pool_masks = split_reference_masks(image_files(sources)) if sources is not None else ([], {})
    items = []
    for target in targets:
        item = BatchItem(
            name=target.stem,
            target=str(target),
            mask=str(masks),
            output=output_name(target, output_format),
            max_refs=max_refs,
            where=str(target),
        )
        if mask_by_stem is not None:
            found = mask_by_stem.get(target.stem, [])
            if len(found) == 1:
                item = replace(item, mask=str(found[0]))
            else:
                problem = (
                    "no mask" if not found else f"{len(found)} masks ({', '.join(p.name for p in found)})"
                )
                item = replace(
                    item, mask="", error=f"{target}: {problem} with stem '{target.stem}' in {masks}"
                )
        if sources is not None:
            # The target itself is not its own reference (--sources may be the --images folder).
            others = [p for p in pool if p.resolve() != target.resolve()]
            item = replace(
                item,
                candidates=tuple(str(p) for p in others),
                reference_masks={str(p): str(pool_masks[p]) for p in others if p in pool_masks},
            )
            if not others and not item.error:
                item = replace(item, error=f"{target}: {sources} holds no other image to use as a reference")
        else:
            folder = sources_per_image / target.stem
            try:
                found, beside = split_reference_masks(image_files(folder)) if folder.is_dir() else ([], {})
            except InputError as exc:
                found, beside = [], {}
                item = replace(item, error=item.error or f"{target}: {exc}")
            refs = tuple(str(p) for p in found)
            item = replace(item, sources=refs, reference_masks={str(p): str(m) for p, m in beside.items()})
            if not refs and not item.error:
                item = replace(item, error=f"{target}: no reference images in {folder}")
        items.append(item)
    return _unique_outputs(items)


def read_manifest(path: Path, base_config: FillConfig, output_format: str | None = None) -> list[BatchItem]:
    """Items of a manifest: CSV with a header row, or JSONL (one JSON object per line; by suffix
    ``.jsonl``/``.json``). Fields: ``target``, ``mask``, ``sources`` (one or more; in CSV separated
    by ``;``), optional ``source_masks`` (each source's mask, in the order of ``sources``, empty
    (JSONL: null or "") for a source without one; in CSV separated by ``;``; fewer than the
    sources leave the last ones unmasked), optional ``output`` (file name in the output folder, whose
    extension sets the format; default :func:`output_name` of the target) and ``set`` (config
    overrides: in CSV ``key=value`` separated by ``;``, in JSONL an object). Relative paths are
    relative to the manifest's folder. A malformed row becomes an item whose error names
    ``FILE:LINE``; overrides are checked against ``base_config`` here, so a bad key is reported
    with its line too."""
    if not path.is_file():
        raise InputError(f"{path}: manifest not found")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read manifest ({exc})") from exc
    rows = _jsonl_rows(path, text) if path.suffix.lower() in (".jsonl", ".json") else _csv_rows(path, text)
    items = []
    for line, row in rows:
        where = f"{path}:{line}"
        try:
            items.append(_manifest_item(path.parent, where, row, base_config, output_format))
        except GeoFillError as exc:
            items.append(
                BatchItem(name=f"line{line}", target="", mask="", output="", where=where, error=str(exc))
            )
    if not items:
        raise InputError(f"{path}: manifest has no rows")
    return _unique_outputs(items)


def _csv_rows(path: Path, text: str) -> list[tuple[int, dict[str, Any]]]:
    reader = csv.DictReader(text.splitlines())
    header = [h.strip() for h in reader.fieldnames or []]
    missing = [c for c in _REQUIRED if c not in header]
    unknown = [c for c in header if c not in MANIFEST_COLUMNS]
    if missing or unknown:
        problems = ([f"missing column(s) {', '.join(missing)}"] if missing else []) + (
            [f"unknown column(s) {', '.join(unknown)}"] if unknown else []
        )
        raise InputError(f"{path}:1: header {'; '.join(problems)} (columns: {', '.join(MANIFEST_COLUMNS)})")
    reader.fieldnames = header
    rows = []
    for row in reader:
        line = reader.line_num
        if None in row:  # more cells than header columns
            rows.append(
                (line, {"__error__": f"{len(header) + len(row[None])} cells for {len(header)} columns"})
            )
            continue
        cells = {k: (v or "").strip() for k, v in row.items()}
        if not any(cells.values()):
            continue
        cells["sources"] = [s.strip() for s in cells["sources"].split(CSV_LIST_SEPARATOR) if s.strip()]
        # Kept in place, empty ones included: the n-th mask is the n-th source's.
        masks = cells.pop("source_masks", "")
        if masks:
            cells["source_masks"] = [m.strip() for m in masks.split(CSV_LIST_SEPARATOR)]
        overrides = [s.strip() for s in cells.pop("set", "").split(CSV_LIST_SEPARATOR) if s.strip()]
        try:
            cells["set"] = parse_overrides(overrides)
        except ConfigError as exc:
            cells = {"__error__": str(exc)}
        rows.append((line, cells))
    return rows


def _jsonl_rows(path: Path, text: str) -> list[tuple[int, dict[str, Any]]]:
    rows = []
    for line, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip():
            continue
        try:
            row = json.loads(raw)
        except json.JSONDecodeError as exc:
            rows.append((line, {"__error__": f"not valid JSON ({exc.msg} at column {exc.colno})"}))
            continue
        if not isinstance(row, dict):
            rows.append((line, {"__error__": f"expected a JSON object, got {type(row).__name__}"}))
            continue
        unknown = sorted(set(row) - set(MANIFEST_COLUMNS))
        if unknown:
            row = {
                "__error__": f"unknown field(s) {', '.join(unknown)} (fields: {', '.join(MANIFEST_COLUMNS)})"
            }
        elif isinstance(row.get("sources"), str):
            row["sources"] = [row["sources"]]
        rows.append((line, row))
    return rows


def _manifest_item(
    base: Path, where: str, row: dict[str, Any], base_config: FillConfig, output_format: str | None
) -> BatchItem:
    if "__error__" in row:
        raise InputError(f"{where}: {row['__error__']}")
    for key in ("target", "mask"):
        if not isinstance(row.get(key), str) or not row[key].strip():
            raise InputError(f"{where}: '{key}' is missing or empty")
    sources = row.get("sources")
    if not isinstance(sources, list) or not sources or not all(isinstance(s, str) and s for s in sources):
        raise InputError(f"{where}: 'sources' must name one or more reference images")
    masks = row.get("source_masks") or []
    if isinstance(masks, str):
        masks = [masks]
    if not isinstance(masks, list) or not all(m is None or isinstance(m, str) for m in masks):
        raise InputError(f"{where}: 'source_masks' must list a mask file (or nothing) per source")
    if len(masks) > len(sources):
        raise InputError(
            f"{where}: {len(masks)} source masks for {len(sources)} sources "
            "(one per source, in their order; empty for none)"
        )
    overrides = row.get("set") or {}
    if not isinstance(overrides, dict):
        raise InputError(f"{where}: 'set' must be an object of config overrides")
    try:
        base_config.updated(overrides)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    target = _resolve(base, row["target"])
    source_paths = [str(_resolve(base, s)) for s in sources]
    output = row.get("output") or output_name(target, output_format)
    if (
        not isinstance(output, str)
        or Path(output).name != output
        or Path(output).suffix.lower() not in OUTPUT_SUFFIXES
    ):
        raise InputError(
            f"{where}: output {output!r} must be a file name ending in one of {', '.join(OUTPUT_SUFFIXES)}"
        )
    return BatchItem(
        name=Path(output).stem,
        target=str(target),
        mask=str(_resolve(base, row["mask"])),
        output=output,
        sources=tuple(source_paths),
        max_refs=len(sources),
        reference_masks={
            s: str(_resolve(base, m)) for s, m in zip(source_paths, masks, strict=False) if m and m.strip()
        },
        overrides=dict(overrides),
        where=where,
    )


def _resolve(base: Path, name: str) -> Path:
    p = Path(name.strip())
    return p if p.is_absolute() else base / p


def _unique_outputs(items: list[BatchItem]) -> list[BatchItem]:
    """Each output name once: a later item that would overwrite an earlier one's output fails."""
    first: dict[str, str] = {}
    out = []
    for item in items:
        if item.output and not item.error:
            key = item.output.lower()
            if key in first:
                item = replace(
                    item, error=f"{item.where}: output {item.output} is already written by {first[key]}"
                )
            else:
                first[key] = item.where
        out.append(item)
    return out
