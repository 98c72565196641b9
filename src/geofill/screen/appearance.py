"""Where neither the depth test nor the surface test locates anything: the hole's content located
in the reference by its look.

Geometry cannot tell from the surface an object that moves with the camera (the car ahead, a rider
filmed from a car): its depth is the surface's, and the surface test (:mod:`.surface`) does not find
it where the ring's surface puts it, since it moved with the camera. Its look still finds it: SIFT
matches of the hole's content in the reference, consistent with the pair's epipolar geometry, give a
homography; where the warped content equals the reference, the reference shows it. This refuses the
brushed margin's background along with the object (the margin is in the reference too), which is
why it runs last. It misses an object on a repetitive surface: the Lund manhole's 19 keypoints kept
2 matches against the whole reference's cobbles (the ratio test), short of
``screen.min_object_matches``; the surface test finds it."""

from __future__ import annotations

import cv2
import numpy as np

from ..config import FillConfig
from ..focal import FocalEstimate
from ..match import Matches
from ..match.features import Features, detect_sift, mutual_ratio_matches
from ..match.ladder import sampson_px
from ..pose import PoseEstimate
from ..prepare import WorkingViews
from ..utils.resolution import config_px, odd_px, resize_long
from ..utils.rotations import skew
from ..utils.windows import mask_window

#: Side (px at 1280) of the patches that verify the homography, and the mean absolute difference
#: (0-255) under which the warped hole content and the reference agree there.
_CHECK_PATCH_PX = 9.0
_CHECK_DIFF = 20.0


def locate_by_appearance(
    shown: np.ndarray,
    source: np.ndarray,
    views: WorkingViews,
    matches: Matches,
    focal: FocalEstimate,
    pose: PoseEstimate,
    cfg: FillConfig,
) -> np.ndarray | None:
    """HxW bool at the source's input size where the reference shows the hole's content (as given in
    ``shown``), or None where too few matches locate it."""
    sc, mc = cfg.screen, cfg.matching
    feats_s = matches.source_features
    if feats_s is None:
        return None
    shown_w = resize_long(shown, cfg.working_max_side)
    hole_w = views.hole
    # SIFT on the hole's window only (the whole image would cost as much as the match stage).
    rows, cols = mask_window(hole_w, 16)
    grey_t = cv2.cvtColor(np.ascontiguousarray(shown_w[rows, cols]), cv2.COLOR_RGB2GRAY)
    detect = cv2.dilate(hole_w[rows, cols].astype(np.uint8) * 255, np.ones((3, 3), np.uint8))
    feats_t = detect_sift(grey_t, mc.max_features, detect)
    if len(feats_t) < sc.min_object_matches:
        return None
    feats_t = Features(feats_t.pts + [cols.start, rows.start], feats_t.desc)
    pairs = mutual_ratio_matches(feats_t.desc, feats_s.desc, mc.ratio, True)
    pts_t, pts_s = feats_t.pts[pairs[:, 0]], feats_s.pts[pairs[:, 1]]
    if pose.status == "ok":
        K_t, K_s = focal.K_target.K, focal.K_source.K
        F = np.linalg.inv(K_t).T @ skew(pose.T[:3, 3]) @ pose.T[:3, :3] @ np.linalg.inv(K_s)
        keep = sampson_px(F, pts_t, pts_s) < sc.object_epipolar_px * views.px_scale
        pts_t, pts_s = pts_t[keep], pts_s[keep]
    if len(pts_t) < sc.min_object_matches:
        return None
    H, inliers = cv2.findHomography(pts_t, pts_s, cv2.USAC_MAGSAC, 3.0 * views.ransac_px)
    if H is None or int(inliers.sum()) < sc.min_object_matches // 2:
        return None
    hs, ws = views.source.shape[:2]
    # The hole's content seen from the reference through the homography, and where it lands.
    warped = cv2.warpPerspective(shown_w, H, (ws, hs), flags=cv2.INTER_LINEAR)
    landed = cv2.warpPerspective(hole_w.astype(np.uint8), H, (ws, hs), flags=cv2.INTER_NEAREST) > 0
    source_w = resize_long(source, cfg.working_max_side)
    k = odd_px(config_px(_CHECK_PATCH_PX, views.source.shape))
    diff = cv2.blur(np.abs(warped.astype(np.float32) - source_w.astype(np.float32)).mean(axis=2), (k, k))
    agree = landed & (diff < _CHECK_DIFF)
    r = odd_px(2.0 * config_px(sc.object_margin_px, views.source.shape))
    obj = cv2.dilate(agree.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (r, r)))
    full = cv2.resize(obj, (source.shape[1], source.shape[0]), interpolation=cv2.INTER_NEAREST) > 0
    return full if full.any() else None
