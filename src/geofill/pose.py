"""Relative pose from verified matches and known intrinsics, with degeneracy detection.

We estimate the essential matrix E directly (OpenCV USAC MAGSAC++ on intrinsics-normalised points)
instead of the paper's F + normalised 8-point route: with K fixed the two are equivalent
(E = K_t^T F K_s), but fitting E enforces its two-equal-singular-values structure inside the
robust loop (5-point minimal solver), so fewer points are needed and the pose is more stable;
``recoverPose`` then picks the (R, t) with most points in front of both cameras (cheirality).

Near-pure rotation is detected from the parallax of the inliers: the translation direction of E is
then meaningless, but the pair is still useful, since a rotation-only homography maps source to target
exactly whatever the depth. In that case R is taken from a robust homography fit.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from .camera import Intrinsics, make_pose
from .config import GeometryConfig, MatchingConfig
from .match import ROBUST_METHODS, Matches

#: Minimal set sizes for a meaningful estimate (5-point E, 4-point H) with a safety factor.
MIN_POINTS_E = 8


@dataclass(frozen=True)
class PoseEstimate:
    """Result of the pose stage.

    ``status``: ``ok``; ``rotation_only`` (near-pure rotation: ``T`` has zero translation and
    R from the rotation homography); ``failed`` (``T`` is identity and must not be used).
    """

    T: np.ndarray  # 4x4 source->target, unit-norm translation (zero when rotation_only)
    inliers: np.ndarray  # (N,) bool over the input matches
    status: str
    reason: str
    median_parallax_deg: float

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())

    @property
    def usable(self) -> bool:
        return self.status != "failed"

    def summary(self) -> str:
        return f"{self.status}, {self.n_inliers} inliers, median parallax {self.median_parallax_deg:.2f} deg"

    def report(self) -> dict[str, Any]:
        return {
            "status": self.status,
            "reason": self.reason,
            "source_to_target": self.T.tolist(),
            "n_inliers": self.n_inliers,
            "median_parallax_deg": self.median_parallax_deg,
        }


def normalise(points_px: np.ndarray, K: Intrinsics) -> np.ndarray:
    """Pixel coordinates -> normalised image coordinates (z = 1 plane)."""
    return (points_px - [K.cx, K.cy]) / [K.fx, K.fy]


def bearing(points_px: np.ndarray, K: Intrinsics) -> np.ndarray:
    """Unit rays (N, 3) through pixels, in that camera's frame."""
    n = normalise(points_px, K)
    rays = np.concatenate([n, np.ones((len(n), 1))], axis=1)
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def parallax_deg(pts_t: np.ndarray, pts_s: np.ndarray, K_t: Intrinsics, K_s: Intrinsics, R: np.ndarray):
    """Angle (deg) between each target ray and the rotated source ray: zero for pure rotation,
    independent of the (unknown) translation magnitude."""
    cos = np.sum(bearing(pts_t, K_t) * (bearing(pts_s, K_s) @ R.T), axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _rotation_from_homography(
    pts_t: np.ndarray, pts_s: np.ndarray, K_t: Intrinsics, K_s: Intrinsics, thr_px: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """R from the infinite homography H = K_t R K_s^-1 (closest rotation by SVD), and H's inliers."""
    if len(pts_t) < 4:
        return None
    H, inl = cv2.findHomography(pts_s, pts_t, cv2.USAC_MAGSAC, thr_px)
    if H is None:
        return None
    M = K_t.K_inv @ H @ K_s.K
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = -R
    return R, inl.ravel().astype(bool)


def estimate_pose(
    matches: Matches,
    K_t: Intrinsics,
    K_s: Intrinsics,
    cfg: GeometryConfig,
    match_cfg: MatchingConfig,
    px_scale: float = 1.0,
) -> PoseEstimate:
    """Source->target pose from ``matches`` (target/source pixels at the resolution of ``K_t``/``K_s``,
    ``px_scale`` times the 1280-px reference that config pixel distances are given at)."""
    n = len(matches)
    none = np.zeros(n, dtype=bool)
    if n < max(cfg.min_inliers, MIN_POINTS_E):
        return PoseEstimate(
            np.eye(4), none, "failed", f"too few verified matches ({n} < {cfg.min_inliers})", 0.0
        )
    pn_t = normalise(matches.pts_target, K_t)
    pn_s = normalise(matches.pts_source, K_s)
    focal = 0.5 * (np.sqrt(K_t.fx * K_t.fy) + np.sqrt(K_s.fx * K_s.fy))
    thr_px = match_cfg.ransac_px(px_scale)
    thr = thr_px / focal
    E, inl = cv2.findEssentialMat(
        pn_s,
        pn_t,
        np.eye(3),
        method=ROBUST_METHODS[match_cfg.robust_method],
        prob=match_cfg.ransac_confidence,
        threshold=thr,
        maxIters=match_cfg.ransac_max_iters,
    )
    if E is None or E.shape != (3, 3):
        return PoseEstimate(np.eye(4), none, "failed", "essential matrix estimation failed", 0.0)
    inl = inl.ravel().astype(bool)
    _, R, t, cheir = cv2.recoverPose(E, pn_s, pn_t, np.eye(3), mask=inl.astype(np.uint8).copy())
    inliers = inl & (cheir.ravel() > 0)
    n_in = int(inliers.sum())
    par = parallax_deg(matches.pts_target[inliers], matches.pts_source[inliers], K_t, K_s, R)
    med_par = float(np.median(par)) if n_in else 0.0
    if n_in >= cfg.min_inliers and med_par >= cfg.min_median_parallax_deg:
        t = t.ravel() / np.linalg.norm(t)
        return PoseEstimate(make_pose(R, t), inliers, "ok", "", med_par)
    # Too few E inliers or too little parallax: try the rotation-only model, which needs no depth.
    rot = _rotation_from_homography(matches.pts_target, matches.pts_source, K_t, K_s, thr_px * 2.0)
    if rot is not None and rot[1].sum() >= cfg.min_inliers:
        R_h, inl_h = rot
        par_h = parallax_deg(matches.pts_target[inl_h], matches.pts_source[inl_h], K_t, K_s, R_h)
        med_h = float(np.median(par_h))
        if med_h < cfg.min_median_parallax_deg:
            reason = (
                f"near-pure rotation (median parallax {med_h:.2f} deg < {cfg.min_median_parallax_deg} deg): "
                "translation is unobservable; using the rotation-only homography (exact for any depth)"
            )
            return PoseEstimate(make_pose(R_h, np.zeros(3)), inl_h, "rotation_only", reason, med_h)
    return PoseEstimate(
        np.eye(4),
        inliers,
        "failed",
        f"pose not reliable: {n_in} essential-matrix inliers (need {cfg.min_inliers}), "
        f"median parallax {med_par:.2f} deg",
        med_par,
    )
