"""Reference masks: what must never be copied from a reference photo (a passer-by, a parked car),
one mask per reference, shared by every front end.

A reference mask is read like the target's hole mask (:func:`~geofill.io.images.read_mask`: alpha,
else luminance, >= 127 = masked) and must be the size of its reference. In a folder of
references the mask of ``street.jpg`` is ``street.mask.png`` beside it (any image format: the
file's stem is the reference's stem plus ``.mask``); such files are masks, never references."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..errors import InputError, MaskSizeError
from .arrays import wxh
from .images import read_mask

#: What a reference mask's file stem ends with: ``street.mask.png`` masks ``street.jpg``.
MASK_STEM_SUFFIX = ".mask"


def is_reference_mask(path: str | os.PathLike) -> bool:
    """Whether a file in a folder of references is a reference's mask (its stem ends in ``.mask``).

    >>> is_reference_mask("refs/street.mask.png"), is_reference_mask("refs/street.jpg")
    (True, False)
    """
    return Path(path).stem.lower().endswith(MASK_STEM_SUFFIX)


def split_reference_masks(files: Iterable[Path]) -> tuple[list[Path], dict[Path, Path]]:
    """The image files of one folder split into references (in the given order) and each
    reference's mask, matched by stem (``b.mask.png`` masks ``b.jpg``). Raises InputError naming
    the file for a mask with no reference of its stem, two masks for one reference, or a mask
    whose stem names two references (``b.jpg`` and ``b.png``).

    >>> refs, masks = split_reference_masks([Path("a.jpg"), Path("b.mask.png"), Path("b.jpg")])
    >>> [str(p) for p in refs], {str(k): str(v) for k, v in masks.items()}
    (['a.jpg', 'b.jpg'], {'b.jpg': 'b.mask.png'})
    """
    files = list(files)
    references = [p for p in files if not is_reference_mask(p)]
    by_stem: dict[str, list[Path]] = {}
    for p in references:
        by_stem.setdefault(p.stem.lower(), []).append(p)
    masks: dict[Path, Path] = {}
    for m in (p for p in files if is_reference_mask(p)):
        stem = m.stem[: -len(MASK_STEM_SUFFIX)]
        owners = by_stem.get(stem.lower(), [])
        if not owners:
            raise InputError(f"{m}: reference mask without a reference: no image named {stem}.* beside it")
        if len(owners) > 1:
            raise InputError(f"{m}: reference mask of which reference? {', '.join(p.name for p in owners)}")
        if owners[0] in masks:
            raise InputError(f"{m}: {owners[0].name} has another mask already ({masks[owners[0]].name})")
        masks[owners[0]] = m
    return references, masks


def read_reference_mask(
    path: str | os.PathLike, source: np.ndarray, source_name: str, *, max_pixels: int = 60_000_000
) -> np.ndarray:
    """Read the mask of the reference ``source`` (HxWx3, named ``source_name`` in messages) as HxW
    bool, True = never copy. Raises what :func:`read_mask` raises, and MaskSizeError naming both
    files when the sizes differ."""
    mask = read_mask(path, max_pixels=max_pixels)
    if mask.shape != source.shape[:2]:
        raise MaskSizeError(
            f"{path}: reference mask is {wxh(mask.shape)} "
            f"but its reference {source_name} is {wxh(source.shape)}"
        )
    return mask
