"""Baselines the geofill pipeline is compared with, implemented here so they run offline:

* ``opencv_inpaint``: single-image inpainting (OpenCV's Telea fast marching), no source used;
* ``homography_fill``: the classic reference-based fill GeoFill improves on - one robust homography
  from SIFT matches outside the hole, the source warped into the target, colour-matched, pasted
  into the hole; hole pixels the warp does not reach are inpainted as above.

Both return the target byte-for-byte outside the hole and raise :class:`BaselineError` when they
cannot run on a pair."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..config import InpaintConfig, MatchingConfig
from ..errors import GeoFillError
from ..match import match_pair
from ..refine import ColourGain, apply_colour_gain, fit_colour_gain

#: Fewer homography inliers than this and the fit is not trusted.
MIN_HOMOGRAPHY_INLIERS = 12
#: MAGSAC++ inlier threshold (px at a 1280-px long side, scaled). Looser than the F threshold:
#: one plane only approximates a 3D scene, and the fit should follow its dominant part.
HOMOGRAPHY_THRESHOLD_PX = 3.0
#: Width of the ring of known pixels around the hole the colour map is fitted on (px at a
#: 1280-px long side, scaled).
COLOUR_BAND_PX = 32.0
_LONG_SIDE_PX = 1280.0


class BaselineError(GeoFillError):
    """A baseline cannot run on this pair (e.g. too few matches for a homography)."""


def _check_inputs(target: np.ndarray, hole: np.ndarray, source: np.ndarray | None = None) -> None:
    if target.dtype != np.uint8 or target.ndim != 3 or target.shape[2] != 3:
        raise ValueError(f"target must be HxWx3 uint8, got {target.dtype} {target.shape}")
    if hole.dtype != bool or hole.shape != target.shape[:2]:
        raise ValueError(
            f"hole must be a bool mask of shape {target.shape[:2]}, got {hole.dtype} {hole.shape}"
        )
    if source is not None and (source.dtype != np.uint8 or source.ndim != 3 or source.shape[2] != 3):
        raise ValueError(f"source must be HxWx3 uint8, got {source.dtype} {source.shape}")


def _composite(target: np.ndarray, hole: np.ndarray, filled: np.ndarray) -> np.ndarray:
    """``filled`` inside the hole, ``target`` (unchanged bytes) outside."""
    return np.where(hole[..., None], filled, target)


def _telea(image: np.ndarray, region: np.ndarray, radius_px: float) -> np.ndarray:
    return cv2.inpaint(image, region.astype(np.uint8), radius_px, cv2.INPAINT_TELEA)


def opencv_inpaint(target: np.ndarray, hole: np.ndarray, radius_px: float | None = None) -> np.ndarray:
    """Fill ``hole`` (HxW bool) of ``target`` (HxWx3 uint8 RGB) from its surroundings with OpenCV's
    Telea inpainting; ``radius_px`` defaults to :class:`InpaintConfig`'s."""
    _check_inputs(target, hole)
    radius = InpaintConfig().radius_px if radius_px is None else radius_px
    return _composite(target, hole, _telea(target, hole, radius))


@dataclass(frozen=True)
class HomographyFill:
    """Result of :func:`homography_fill_detailed`."""

    image: np.ndarray  # HxWx3 uint8, the filled target
    H: np.ndarray  # 3x3 float64, source pixels -> target pixels
    n_matches: int  # F-verified matches outside the hole
    n_inliers: int  # homography inliers among them
    hole_coverage: float  # fraction of the hole the warped source covers
    colour: ColourGain


def homography_fill_detailed(
    target: np.ndarray,
    hole: np.ndarray,
    source: np.ndarray,
    *,
    matching: MatchingConfig | None = None,
    colour_offset: bool = True,
    radius_px: float | None = None,
) -> HomographyFill:
    """Single-homography reference fill of ``hole`` in ``target`` from ``source`` (HxWx3 uint8 RGB;
    the source may differ in size). See the module docstring; ``colour_offset`` chooses a gain +
    offset colour map over a gain alone. Raises :class:`BaselineError` without enough matches."""
    _check_inputs(target, hole, source)
    h, w = hole.shape
    scale = max(h, w) / _LONG_SIDE_PX
    matches = match_pair(target, source, hole, matching or MatchingConfig(), scale_px=scale)
    if len(matches) < MIN_HOMOGRAPHY_INLIERS:
        raise BaselineError(
            f"homography baseline: only {len(matches)} verified matches outside the hole "
            f"(need {MIN_HOMOGRAPHY_INLIERS})"
        )
    H, inliers = cv2.findHomography(
        matches.pts_source, matches.pts_target, cv2.USAC_MAGSAC, HOMOGRAPHY_THRESHOLD_PX * max(scale, 0.5)
    )
    n_inliers = 0 if inliers is None else int(inliers.sum())
    if H is None or n_inliers < MIN_HOMOGRAPHY_INLIERS:
        raise BaselineError(
            f"homography baseline: robust fit kept {n_inliers} of {len(matches)} matches "
            f"(need {MIN_HOMOGRAPHY_INLIERS})"
        )
    warped = cv2.warpPerspective(source, H, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    valid = cv2.warpPerspective(
        np.ones(source.shape[:2], np.uint8), H, (w, h), flags=cv2.INTER_NEAREST, borderValue=0
    )
    # Bilinear samples on the warp's outer edge mix in the black border: drop one pixel.
    valid = cv2.erode(valid, np.ones((3, 3), np.uint8)).astype(bool)

    band_r = max(2, round(COLOUR_BAND_PX * scale))
    ring = cv2.dilate(
        hole.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band_r + 1,) * 2)
    )
    known = ring.astype(bool) & ~hole & valid
    colour = fit_colour_gain(warped, target, known, offset=colour_offset)

    pasted = target.copy()
    covered = hole & valid
    pasted[covered] = apply_colour_gain(warped, colour)[covered]
    uncovered = hole & ~valid
    if uncovered.any():
        radius = InpaintConfig().radius_px if radius_px is None else radius_px
        pasted = _telea(pasted, uncovered, radius)
    coverage = float(covered.sum() / max(1, hole.sum()))
    return HomographyFill(_composite(target, hole, pasted), H, len(matches), n_inliers, coverage, colour)


def homography_fill(target: np.ndarray, hole: np.ndarray, source: np.ndarray) -> np.ndarray:
    """The filled target of :func:`homography_fill_detailed` with default settings."""
    return homography_fill_detailed(target, hole, source).image
