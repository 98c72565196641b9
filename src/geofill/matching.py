"""Sparse correspondences: OpenCV SIFT on both images, target keypoints near the hole excluded,
ratio test + mutual nearest neighbours, geometric verification of the fundamental matrix with a
robust estimator (OpenCV USAC MAGSAC++ by default).

The F-verified set is independent of the intrinsics, which is what the pose stage (with K) and the
focal-length estimation (without K) both start from."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import torch

from .config import MatchingConfig

ROBUST_METHODS = {"magsac": cv2.USAC_MAGSAC, "ransac": cv2.RANSAC, "lmeds": cv2.LMEDS}
#: Fewer tentative matches than this cannot support a fundamental matrix fit (8-point + margin).
MIN_MATCHES_FOR_F = 12


@dataclass(frozen=True)
class Matches:
    """Verified correspondences between target and source, in working-resolution pixels.

    ``pts_target[i]`` and ``pts_source[i]`` are the same scene point. ``F`` maps source points to
    target epipolar lines (``x_t^T F x_s = 0``); None when it could not be estimated.
    """

    pts_target: np.ndarray  # (N, 2) float64
    pts_source: np.ndarray  # (N, 2) float64
    F: np.ndarray | None
    n_keypoints_target: int
    n_keypoints_source: int
    n_tentative: int  # after ratio + mutual tests and de-duplication, before geometric verification

    def __len__(self) -> int:
        return int(self.pts_target.shape[0])

    def summary(self) -> str:
        return f"{len(self)} verified of {self.n_tentative} tentative matches"

    def report(self) -> dict[str, Any]:
        return {
            "n_keypoints_target": self.n_keypoints_target,
            "n_keypoints_source": self.n_keypoints_source,
            "n_tentative": self.n_tentative,
            "n_verified": len(self),
        }


def to_gray_u8(image: np.ndarray) -> np.ndarray:
    """HxWx3 RGB (uint8 or float in [0, 1]) -> HxW uint8 grey."""
    if image.dtype != np.uint8:
        image = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image


def keypoint_mask(hole: np.ndarray, margin_px: float) -> np.ndarray:
    """uint8 detection mask (255 = allowed) excluding the hole dilated by ``margin_px``."""
    allowed = np.where(hole, 0, 255).astype(np.uint8)
    r = int(np.ceil(margin_px))
    if r > 0:
        allowed = cv2.erode(allowed, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    return allowed


def detect_sift(gray: np.ndarray, max_features: int, mask: np.ndarray | None = None):
    """SIFT keypoints (as (N, 2) float64 positions) and RootSIFT descriptors (N, 128) float32."""
    sift = cv2.SIFT_create(nfeatures=max_features)
    kps, desc = sift.detectAndCompute(gray, mask)
    if desc is None or len(kps) == 0:
        return np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    # RootSIFT (Arandjelovic & Zisserman 2012): L1-normalise, square-root; Euclidean distance on it
    # is the Hellinger kernel, which matches better than raw SIFT at no cost.
    desc = np.sqrt(desc / (np.abs(desc).sum(axis=1, keepdims=True) + 1e-7)).astype(np.float32)
    pts = np.array([kp.pt for kp in kps], dtype=np.float64)
    return pts, desc


def mutual_ratio_matches(desc_a: np.ndarray, desc_b: np.ndarray, ratio: float, mutual: bool) -> np.ndarray:
    """(M, 2) index pairs (i in a, j in b) passing Lowe's ratio test (a->b) and, if asked, the
    mutual nearest-neighbour check. Descriptors must be L2-normalised (RootSIFT is).

    Exact nearest neighbours from one matrix product in torch: 2.4x faster than OpenCV's
    brute-force matcher for 8000x8000 descriptors on 2 cores (0.30 s vs 0.71 s), and exact unlike FLANN.
    """
    if len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    sim = torch.from_numpy(desc_a) @ torch.from_numpy(desc_b).T
    best, idx = sim.topk(2, dim=1)
    # For unit vectors ||a - b||^2 = 2 - 2 a.b: the ratio test on distances, squared.
    d2 = (2.0 - 2.0 * best).clamp_min(0.0)
    keep = d2[:, 0] < (ratio**2) * d2[:, 1]
    if mutual:
        keep &= sim.argmax(dim=0)[idx[:, 0]] == torch.arange(len(desc_a))
    i = torch.nonzero(keep).ravel()
    return torch.stack([i, idx[i, 0]], dim=1).numpy().astype(np.int64)


def match_pair(
    target: np.ndarray, source: np.ndarray, hole: np.ndarray, cfg: MatchingConfig, scale_px: float = 1.0
) -> Matches:
    """Match ``target`` (with boolean ``hole``) against ``source``; both RGB at working resolution.

    ``scale_px`` converts the config's pixel distances (given at a 1280-px long side) to this image.
    """
    gray_t, gray_s = to_gray_u8(target), to_gray_u8(source)
    pts_t, desc_t = detect_sift(gray_t, cfg.max_features, keypoint_mask(hole, cfg.hole_margin_px * scale_px))
    pts_s, desc_s = detect_sift(gray_s, cfg.max_features)
    pairs = mutual_ratio_matches(desc_t, desc_s, cfg.ratio, cfg.mutual)
    mt, ms = pts_t[pairs[:, 0]], pts_s[pairs[:, 1]]
    # SIFT emits one keypoint per dominant orientation, so a location can appear 2-3 times (25% of
    # the apple video's keypoints): identical matches would be counted twice by the robust fits.
    _, first = np.unique(np.concatenate([mt, ms], axis=1), axis=0, return_index=True)
    first.sort()
    mt, ms = mt[first], ms[first]
    F = None
    if len(pairs) >= MIN_MATCHES_FOR_F:
        F, inl = cv2.findFundamentalMat(
            ms,
            mt,
            ROBUST_METHODS[cfg.robust_method],
            cfg.ransac_px(scale_px),
            cfg.ransac_confidence,
            cfg.ransac_max_iters,
        )
        if F is None or F.shape != (3, 3):
            F, keep = None, np.zeros(len(pairs), dtype=bool)
        else:
            keep = inl.ravel().astype(bool)
        mt, ms = mt[keep], ms[keep]
    else:
        mt, ms = mt[:0], ms[:0]
    return Matches(mt, ms, F, len(pts_t), len(pts_s), len(first))
