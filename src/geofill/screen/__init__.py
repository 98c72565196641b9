"""The screen stage: what of a reference's refined render may be copied into the hole. One module
per test:

- :mod:`.depth` -- *geometry decides what is the removed object.* What the hole shows is the thing
  the user removes: stereo between it and the reference measures its depth, and what lies in front
  of the surface the ring around the hole gives is the object, located in the reference by
  projection and refused there (and, with several references, left out of the reference's mesh by
  the render stage). Content on that surface is used, however much it looks like the brushed margin.
- :mod:`.strangers` -- a passer-by or a car that moved shows in a reference and not in the target;
  where it reaches beyond the hole, what continues it into the hole is refused. Runs on every fill.
- :mod:`.surface` -- what the hole shows that its ring does not explain (an object flat on the
  surface, or the part of one the depth test did not place), found in the reference where the ring
  surface's homography puts it; and, in every render, content the ring does not explain but that
  hole content does (the object, or a passer-by like it, wherever the render puts it).
- :mod:`.appearance` -- where neither locates anything in a reference (an object that moves with
  the camera), the hole's content located there by its look.
- Reference pixels the user masked (``source_masks``) are never rendered.

A hole that shows nothing (blank or constant) refuses no object. The vote between several
references (a transient seen by one is outvoted) is the fuse stage's (:mod:`geofill.fuse.vote`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..config import FillConfig, ScreenConfig
from ..refine import RefinedRender
from ..render import RenderResult
from ..utils.distance import known_ring
from ..utils.resolution import config_px, odd_px
from .appearance import locate_by_appearance
from .colours import object_colours, wide_ring_shares
from .depth import DepthLocation, locate_by_depth, locate_together
from .strangers import stranger_region, strangers, watershed_region
from .surface import like_the_object, locate_on_surface

__all__ = [
    "DepthLocation",
    "ScreenedRender",
    "locate_by_appearance",
    "locate_by_depth",
    "locate_on_surface",
    "locate_together",
    "object_in_render",
    "screen_render",
    "shows_object",
    "strangers",
]


@dataclass(frozen=True)
class ScreenedRender:
    """The refined render with what may not be copied taken out: ``image`` HxWx3 uint8 (zero where
    ``alpha`` is False) and ``alpha`` at target resolution (the refined render's own arrays where
    nothing was refused); ``refused_object`` / ``refused_masked`` / ``refused_stranger`` (HxW bool or
    None): hole pixels the render covered but that show the removed object again / come from pixels
    the user masked / continue reference content the target does not show around the hole."""

    image: np.ndarray
    alpha: np.ndarray
    refused_object: np.ndarray | None = None
    refused_masked: np.ndarray | None = None
    refused_stranger: np.ndarray | None = None
    location: DepthLocation | None = None  # the depth test's, where the hole shows an object
    hole_pixels: int = 0

    def fraction(self, refused: np.ndarray | None) -> float:
        """Share of the hole in ``refused``."""
        return 0.0 if refused is None else float(np.count_nonzero(refused)) / max(self.hole_pixels, 1)

    def summary(self) -> str:
        parts = []
        if self.refused_object is not None:
            how = self.location.summary() if self.location is not None else "not looked for"
            share = 100 * self.fraction(self.refused_object)
            parts.append(f"refused {share:.1f}% of the hole showing the removed object ({how})")
        if self.refused_masked is not None:
            parts.append(f"{100 * self.fraction(self.refused_masked):.1f}% masked in the reference")
        if self.refused_stranger is not None:
            parts.append(
                f"{100 * self.fraction(self.refused_stranger):.1f}% not in the target around the hole"
            )
        return ", ".join(parts) or "nothing to refuse"

    def report(self) -> dict[str, Any]:
        return {
            "refused_object_fraction": self.fraction(self.refused_object),
            "refused_masked_fraction": self.fraction(self.refused_masked),
            "refused_stranger_fraction": self.fraction(self.refused_stranger),
            "object_located": self.location is not None and self.location.located,
            "object_measured_fraction": 0.0 if self.location is None else self.location.measured,
        }


def shows_object(target: np.ndarray, hole: np.ndarray, min_texture: float) -> bool:
    """Whether the hole of ``target`` (as given, before blanking) shows something to remove: its grey
    values vary by more than ``min_texture`` (standard deviation, 0-255). A blanked or constant hole
    does not.

    >>> img = np.zeros((8, 8, 3), np.uint8); hole = np.ones((8, 8), bool)
    >>> shows_object(img, hole, 2.0), shows_object(np.arange(192, dtype=np.uint8).reshape(8, 8, 3), hole, 2.0)
    (False, True)
    """
    grey = cv2.cvtColor(np.ascontiguousarray(target), cv2.COLOR_RGB2GRAY)[hole]
    return grey.size > 0 and float(grey.std()) > min_texture


def screen_render(
    refined: RefinedRender,
    target: np.ndarray,
    hole: np.ndarray,
    source: np.ndarray,
    shown: np.ndarray | None,
    exclude: np.ndarray | None,
    cfg: FillConfig,
    location: DepthLocation | None = None,
    object_seen: np.ndarray | None = None,
) -> ScreenedRender:
    """Take out of ``refined`` what shows the removed object again, what comes from reference pixels
    the user masked and what continues a stranger. ``target``: the target with its hole blanked
    (HxWx3 uint8); ``shown``: the target as the user gave it when its hole shows something to
    remove, else None; ``exclude``: the reference's own mask (HxW bool at the source's input size,
    True = never copy) or None; ``source``: the reference at input size; ``location``: the render
    stage's :func:`~geofill.screen.depth.locate_by_depth` (needed with ``shown``), and
    ``object_seen`` where it left the object out of the mesh and the object would have shown (counted
    as refused where nothing else covers it)."""
    sc = cfg.screen
    n_hole = int(np.count_nonzero(hole))
    rows, cols = refined.render.window()
    field = refined.render
    covered = refined.alpha[rows, cols] & hole[rows, cols]
    refused_masked = refused_object = refused_stranger = None
    if exclude is not None:
        refused_masked = np.zeros(hole.shape, bool)
        refused_masked[rows, cols] = _sampled(exclude, field, rows, cols) & covered
    if shown is not None:
        if location is None:
            raise ValueError("a hole that shows an object needs the render stage's location of it")
        refused_object = np.zeros(hole.shape, bool)
        if location.located:
            refused_object[rows, cols] = _sampled(location.source, field, rows, cols) & covered
        if object_seen is not None:
            refused_object |= object_seen & ~refined.alpha
        if sc.refuse_like_object:
            refused_object[rows, cols] |= covered & _like_the_object(
                field.sample_window(source), shown[rows, cols], hole[rows, cols], hole.shape, sc
            )
        if sc.refuse_object_colours:
            refused_object[rows, cols] |= object_colours(
                refined.image[rows, cols],
                covered,
                shown[rows, cols],
                hole[rows, cols],
                hole.shape,
                sc,
                wide_ring_shares(shown, hole, hole.shape),
            )
    refused = np.zeros(hole.shape, bool)
    for r in (refused_masked, refused_object):
        if r is not None:
            refused |= r
    if sc.stranger_threshold > 0:
        refused_stranger = np.zeros(hole.shape, bool)
        # The source's own colours at the field: the refine stage's local colour gain is fitted on the
        # ring, so it would fade a stranger exactly where this test looks for it.
        refused_stranger[rows, cols] = stranger_region(
            field.sample_window(source),
            target[rows, cols],
            hole[rows, cols],
            refined.alpha[rows, cols] & ~refused[rows, cols],
            hole.shape,
            sc,
            removal=shown is not None,
        )
        refused |= refused_stranger
    if not refused.any():
        return ScreenedRender(
            refined.image, refined.alpha, refused_object, refused_masked, refused_stranger, location, n_hole
        )
    alpha = refined.alpha & ~refused
    image = refined.image.copy()
    image[refused] = 0
    return ScreenedRender(image, alpha, refused_object, refused_masked, refused_stranger, location, n_hole)


def object_in_render(mask: np.ndarray, field: RenderResult, hole: np.ndarray) -> np.ndarray:
    """HxW bool: the hole pixels where the render ``field`` shows the source pixels of ``mask``."""
    out = np.zeros(hole.shape, bool)
    rows, cols = field.window()
    out[rows, cols] = _sampled(mask, field, rows, cols) & field.alpha[rows, cols] & hole[rows, cols]
    return out


def _sampled(mask: np.ndarray, field: RenderResult, rows: slice, cols: slice) -> np.ndarray:
    """``mask`` (source pixels, input size) read at the correspondence field's window (nearest)."""
    return (
        cv2.remap(
            mask.astype(np.uint8), field.map_x[rows, cols], field.map_y[rows, cols], cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT, borderValue=0,
        )
        > 0
    )  # fmt: skip


#: Long side (px) at which :func:`like_the_object` compares a render with the hole's content: the
#: ring's patch statistics need no finer detail, and the k-d tree queries grow with the hole's area.
LIKE_TEST_SIDE = 320


def _like_the_object(
    render: np.ndarray, shown: np.ndarray, hole: np.ndarray, shape: tuple[int, ...], sc: ScreenConfig
) -> np.ndarray:
    """:func:`~geofill.screen.surface.like_the_object` in a window (``render``, ``shown`` and
    ``hole`` of the same size), run with its long side at most :data:`LIKE_TEST_SIDE` against the
    ring of ``sc.surface_ring_px``; specks under ``sc.stranger_min_px`` are opened away (texture
    the ring happens not to hold) and the rest grown by the watershed. ``shape``: the full
    target's, for pixel scaling."""
    h, w = hole.shape
    f = min(1.0, LIKE_TEST_SIDE / max(h, w))
    size = (max(round(w * f), 1), max(round(h * f), 1))
    px = config_px(1.0, shape) * f
    small = cv2.resize(hole.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    small_render = cv2.resize(render, size, interpolation=cv2.INTER_AREA)
    markers = like_the_object(
        small_render,
        cv2.resize(shown, size, interpolation=cv2.INTER_AREA),
        small,
        known_ring(small, sc.surface_ring_px * px),
    )
    m = max(3, odd_px(sc.stranger_min_px / 2 * px))
    seeds = cv2.morphologyEx((markers == 1).astype(np.uint8), cv2.MORPH_OPEN, np.ones((m, m), np.uint8))
    if not seeds.any():
        return np.zeros(hole.shape, bool)
    # Grown over the render's own edges (OpenCV's watershed) until content the ring explains: the
    # object's blended outline and shading are no longer like its sharp self in the hole.
    markers[markers == 1] = 0
    markers[seeds > 0] = 1
    found = watershed_region(small_render, markers) & small
    return (cv2.resize(found.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0) & hole
