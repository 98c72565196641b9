"""Picking a target's references from the other photos of a shoot by measured overlap.

A candidate's score is the number of its verified matches (:func:`geofill.match.match_pair`:
SIFT, ratio + mutual tests, fundamental matrix fitted with MAGSAC++) whose target keypoint lies
within :data:`NEAR_HOLE_PX` of the hole. Matches near the hole are what the fill's pose and depth
fit lean on where it matters; matches elsewhere say the photos overlap, not that the source sees
what the hole hides. Matches whose source keypoint lies on what the user masked in the candidate
(its reference mask) do not count: those pixels will never be copied. A candidate below the pose
stage's own minimum (``geometry.min_inliers`` verified matches) would fall back anyway, so it is
never picked.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ..config import FillConfig
from ..io import LoadedImage
from ..match import match_pair
from ..prepare import prepare_views
from ..utils.resolution import resize_mask_any

#: Radius (px at a 1280-px long side, scaled with the working resolution) around the hole in which
#: verified matches count towards a candidate's score.
NEAR_HOLE_PX = 160.0


@dataclass(frozen=True)
class CandidateScore:
    """How well one candidate reference overlaps the target around the hole."""

    path: str
    matches_near_hole: int  # verified matches within NEAR_HOLE_PX of the hole
    matches_verified: int  # all verified matches
    picked: bool
    mask: str | None = None  # the candidate's reference mask, if it has one

    def to_dict(self) -> dict[str, object]:
        out: dict[str, object] = {
            "source": self.path,
            "matches_near_hole": self.matches_near_hole,
            "matches_verified": self.matches_verified,
            "picked": self.picked,
        }
        if self.mask is not None:
            out["mask"] = self.mask
        return out


def score_candidate(
    target: np.ndarray,
    hole: np.ndarray,
    source: np.ndarray,
    cfg: FillConfig,
    exclude: np.ndarray | None = None,
) -> tuple[int, int]:
    """(verified matches near the hole, all verified matches) of ``source`` against ``target``,
    both matched at the working resolution the fill uses; a match whose source keypoint lies in
    ``exclude`` (the candidate's reference mask, HxW bool) is not near the hole."""
    views = prepare_views(target, hole, source, cfg, None, None)
    # Plain SIFT: ranking candidates must not climb the matching ladder (ASIFT) for each of them;
    # the fill itself climbs it for the references picked.
    plain = dataclasses.replace(cfg.matching, max_rung="sift")
    matches = match_pair(views.target_gray, views.source_gray, views.hole, plain, views.px_scale)
    if len(matches) == 0:
        return 0, 0
    # Distance (working px) of every pixel to the nearest hole pixel.
    dist = cv2.distanceTransform(np.where(views.hole, 0, 255).astype(np.uint8), cv2.DIST_L2, 5)
    h, w = dist.shape
    xy = np.rint(matches.pts_target).astype(int)
    near = dist[np.clip(xy[:, 1], 0, h - 1), np.clip(xy[:, 0], 0, w - 1)] <= NEAR_HOLE_PX * views.px_scale
    if exclude is not None:
        masked = resize_mask_any(exclude, cfg.working_max_side)
        sy, sx = masked.shape
        uv = np.rint(matches.pts_source).astype(int)
        near &= ~masked[np.clip(uv[:, 1], 0, sy - 1), np.clip(uv[:, 0], 0, sx - 1)]
    return int(near.sum()), len(matches)


def pick_references(
    target: np.ndarray,
    hole: np.ndarray,
    candidates: Sequence[LoadedImage],
    cfg: FillConfig,
    max_refs: int,
    masks: Mapping[str, tuple[str, np.ndarray]] | None = None,
) -> tuple[list[LoadedImage], list[CandidateScore]]:
    """The best ``max_refs`` candidates by matches near the hole, best first, among those with at
    least ``cfg.geometry.min_inliers`` of them (possibly none), and every candidate's score in the
    given order. ``masks``: candidate path -> (its reference mask's file, the mask as HxW bool)."""
    masks = masks or {}
    scored = [
        (score_candidate(target, hole, c.pixels, cfg, masks[c.path][1] if c.path in masks else None), i)
        for i, c in enumerate(candidates)
    ]
    eligible = sorted(
        (i for (near, _), i in scored if near >= cfg.geometry.min_inliers),
        key=lambda i: (-scored[i][0][0], -scored[i][0][1], i),
    )[:max_refs]
    scores = [
        CandidateScore(
            candidates[i].path, near, total, i in eligible, masks.get(candidates[i].path, (None,))[0]
        )
        for (near, total), i in scored
    ]
    return [candidates[i] for i in eligible], scores
