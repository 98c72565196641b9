"""The matching ladder: plain SIFT first, then a learned matcher when one is installed; while the
verified geometry is weak (too few inliers, or too little of the hole's surroundings
near an inlier), climb to costlier matching, and stop at the first rung whose geometry verifies or
when the time budget is spent. A reference that shows another scene (almost nothing verifies on
the first two rungs) is given up at once instead of climbing.

Rungs (``MatchingConfig.max_rung`` caps the climb):

``sift``: SIFT, RootSIFT descriptors, ratio test + mutual nearest neighbours, fundamental matrix
by a robust estimator (OpenCV USAC MAGSAC++ by default). What every easy pair uses, unchanged.

``learned`` (``matching.learned``: by default whenever the ``learned`` extra is installed):
XFeat + LighterGlue (:mod:`geofill.match.xfeat`) or an ONNX matcher graph
(:mod:`geofill.match.learned`), when SIFT's geometry is weak, and with more keypoints when it
verified but is suspicious: repeated structure gives SIFT many verified but wrong matches (the
fox's wallpaper: 77 verified, a 56-degree pose error), of which only about half fit any calibrated
geometry (:meth:`_Ladder.suspect`; ``matching.learned_cross_check`` runs it after every verified
SIFT). Its matches then are verified by an essential matrix, not F (:func:`verify_essential`).
When both rungs verify, the geometry that more matches around the hole support is kept
(:meth:`_Ladder.choose`), and the report says which and why.

``loose``: more SIFT keypoints and a looser ratio test (more true matches on wide baselines, and
more outliers), verified more strictly: a tighter inlier threshold.

``asift``: affine-simulated SIFT (ASIFT, OpenCV ``AffineFeature``): each image is re-detected under
simulated camera tilts, which recovers the matches that a strong viewpoint change destroys for
SIFT; views run until the budget is spent.

``guided``: with the best fundamental matrix found so far, every keypoint (the richest set
computed) is matched again among the candidates near its epipolar line only, where a looser
ratio test is safe because the wrong candidates elsewhere are gone.

The F-verified set is independent of the intrinsics, which is what the pose stage (with K) and the
focal-length estimation (without K) both start from."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from ..config import MatchingConfig
from .features import (
    Features,
    detect_asift,
    detect_sift_pair,
    epipolar_band,
    keypoint_mask,
    mutual_ratio_matches,
    to_gray_u8,
)

ROBUST_METHODS = {"magsac": cv2.USAC_MAGSAC, "ransac": cv2.RANSAC, "lmeds": cv2.LMEDS}
#: Fewer tentative matches than this cannot support a fundamental matrix fit (8-point + margin).
MIN_MATCHES_FOR_F = 12
#: The rungs in climbing order.
RUNGS = ("sift", "learned", "loose", "asift", "guided")
#: Rungs after which a reference that verified almost nothing is given up (the costly ones follow).
EARLY_RUNGS = ("sift", "learned")
#: Another rung's geometry replaces SIFT's when at least this many times as many matches support it.
SUPPORT_MARGIN = 1.2
#: Focal lengths (multiples of the prior) at which the rungs' geometries are compared.
FOCAL_SCALES = (0.6, 0.8, 1.0, 1.3, 1.7)


@dataclass(frozen=True)
class RungReport:
    """What one rung of the ladder found: its tentative and F-verified matches, the fraction of
    the hole within ``hole_support_radius_px`` of a verified match, its time, and ``weak``: why
    its geometry did not verify (empty when it did)."""

    rung: str
    n_tentative: int
    n_verified: int
    hole_support: float
    time_s: float
    weak: str
    cpu_s: float = 0.0  # the process's CPU time during the rung (all threads)

    @property
    def verified(self) -> bool:
        return not self.weak

    def to_json(self) -> dict[str, Any]:
        return {
            "rung": self.rung,
            "tentative": self.n_tentative,
            "verified": self.n_verified,
            "hole_support": round(self.hole_support, 4),
            "time_s": round(self.time_s, 3),
            "cpu_s": round(self.cpu_s, 3),
            "weak": self.weak,
        }


@dataclass(frozen=True)
class Matches:
    """Verified correspondences between target and source, in working-resolution pixels.

    ``pts_target[i]`` and ``pts_source[i]`` are the same scene point. ``F`` maps source points to
    target epipolar lines (``x_t^T F x_s = 0``); None when it could not be estimated. ``rung`` is
    the ladder rung the matches come from, ``rungs`` every rung tried in order, and ``verified``
    whether that rung's geometry verified (False: the best of the rungs tried, weak).
    """

    pts_target: np.ndarray  # (N, 2) float64
    pts_source: np.ndarray  # (N, 2) float64
    F: np.ndarray | None
    n_keypoints_target: int
    n_keypoints_source: int
    n_tentative: int  # after ratio + mutual tests and de-duplication, before geometric verification
    rung: str = "sift"
    rungs: tuple[RungReport, ...] = ()
    verified: bool = True
    budget_spent: bool = False  # the time budget stopped the ladder
    time_s: float = 0.0
    notes: tuple[str, ...] = field(default=())  # why the ladder climbed or stopped
    #: What produced the matches used: "SIFT", "ASIFT" or the learned matcher's description.
    matcher: str = "SIFT"
    #: Why these matches were preferred when two rungs verified ("" when only one did).
    choice: str = ""
    #: Why the reference shows another scene ("" unless the ladder gave it up early).
    unrelated: str = ""
    #: The source's plain-SIFT keypoints (the first rung's), which the screen stage matches the
    #: hole's content against and the joint registration reuses; None where that rung did not run.
    source_features: Features | None = None
    #: The target's (outside the hole), the same for every reference of a fill.
    target_features: Features | None = None

    def __len__(self) -> int:
        return int(self.pts_target.shape[0])

    @property
    def too_few(self) -> bool:
        """No fundamental matrix could be verified: the pair cannot give a geometry."""
        return self.F is None or len(self) < MIN_MATCHES_FOR_F

    def summary(self) -> str:
        """One line for the progress output and the report."""
        tried = ", ".join(f"{r.rung} {r.n_verified}/{r.n_tentative} {r.time_s:.1f}s" for r in self.rungs)
        state = "verified" if self.verified else "weak"
        line = f"{len(self)} verified of {self.n_tentative} tentative matches from rung {self.rung} ({state})"
        if len(self.rungs) > 1:
            line += f"; rungs: {tried}"
        if self.budget_spent:
            line += "; time budget spent"
        if self.choice:
            line += f"; {self.choice}"
        return line

    def report(self) -> dict[str, Any]:
        """Report fields of the matching stage."""
        return {
            "n_keypoints_target": self.n_keypoints_target,
            "n_keypoints_source": self.n_keypoints_source,
            "rung": self.rung,
            "matcher": self.matcher,
            "verified": self.verified,
            "n_verified": len(self),
            "n_tentative": self.n_tentative,
            "budget_spent": self.budget_spent,
            "time_s": round(self.time_s, 3),
            "rungs": [r.to_json() for r in self.rungs],
            "notes": list(self.notes),
            "choice": self.choice,
            "unrelated": self.unrelated,
        }


def verify_fundamental(
    pts_t: np.ndarray, pts_s: np.ndarray, threshold_px: float, cfg: MatchingConfig
) -> tuple[np.ndarray | None, np.ndarray]:
    """Robust F (``x_t^T F x_s = 0``) and its inlier mask; (None, all False) when the matches
    cannot support one (too few, or degenerate: OpenCV raises on some collinear or repeated sets)."""
    none = np.zeros(len(pts_t), dtype=bool)
    if len(pts_t) < MIN_MATCHES_FOR_F:
        return None, none
    try:
        F, inl = cv2.findFundamentalMat(
            pts_s,
            pts_t,
            ROBUST_METHODS[cfg.robust_method],
            threshold_px,
            cfg.ransac_confidence,
            cfg.ransac_max_iters,
        )
    except cv2.error:
        return None, none
    if F is None or F.shape != (3, 3) or inl is None:
        return None, none
    return F, inl.ravel().astype(bool)


def verify_essential(
    pts_t: np.ndarray, pts_s: np.ndarray, threshold_px: float, K: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray | None, np.ndarray]:
    """The fundamental matrix of the calibrated geometry (MAGSAC++ essential matrix) that most
    matches fit at one of ``FOCAL_SCALES`` times the prior (target, source) intrinsics ``K``, and
    its inlier mask (Sampson distance < ``threshold_px``); (None, all False) when none is found.

    Used to doubt a verified SIFT geometry (:meth:`_Ladder.suspect`) and to verify the learned
    rung's re-check of it: matches on repeated texture (the fox's wallpaper) hold whole clusters
    shifted by a period on one plane, which fit a fundamental matrix of the plane's family as well
    as the true matches do (a 43-49 deg pose in a fill), while an essential matrix cannot take
    that form. The focal length is scanned because the prior can be far off (no EXIF)."""
    best: tuple[int, np.ndarray | None, np.ndarray] = (0, None, np.zeros(len(pts_t), dtype=bool))
    if len(pts_t) < MIN_MATCHES_FOR_F:
        return best[1], best[2]
    for scale in FOCAL_SCALES:
        K_t, K_s = _focal_scaled(K, scale)
        nt, ns = _normalised(pts_t, K_t), _normalised(pts_s, K_s)
        try:
            E, _ = cv2.findEssentialMat(ns, nt, np.eye(3), cv2.USAC_MAGSAC, 0.999, threshold_px / K_t[0, 0])
        except cv2.error:
            continue
        if E is None:
            continue
        for k in range(0, E.shape[0], 3):  # the five-point solver can return several
            keep = sampson_px(E[k : k + 3], nt, ns) * K_t[0, 0] < threshold_px
            if keep.sum() > best[0]:
                F = np.linalg.inv(K_t).T @ E[k : k + 3] @ np.linalg.inv(K_s)
                best = (int(keep.sum()), F / np.linalg.norm(F), keep)
    return best[1], best[2]


def _normalised(pts: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels (x, y) -> normalised image coordinates under ``K`` (no distortion)."""
    return cv2.undistortPoints(np.asarray(pts, np.float64)[:, None], K, None)[:, 0]


def hole_support(hole: np.ndarray, pts: np.ndarray, radius_px: float) -> float:
    """Fraction of the hole's pixels within ``radius_px`` of one of ``pts`` (x, y): how much of the
    hole's surroundings the verified geometry is measured on."""
    if not hole.any():
        return 1.0
    if len(pts) == 0:
        return 0.0
    free = np.full(hole.shape, 255, np.uint8)
    xy = np.clip(np.rint(pts).astype(np.int64), 0, [hole.shape[1] - 1, hole.shape[0] - 1])
    free[xy[:, 1], xy[:, 0]] = 0
    dist = cv2.distanceTransform(free, cv2.DIST_L2, 3)
    return float(np.mean(dist[hole] <= radius_px))


@dataclass
class _Candidate:
    """A rung's matches before they become :class:`Matches`."""

    report: RungReport
    pts_t: np.ndarray
    pts_s: np.ndarray
    F: np.ndarray | None
    n_kp: tuple[int, int]
    tentative: tuple[np.ndarray, np.ndarray]  # (target, source) matches before verification
    threshold: float  # the inlier threshold (px) the rung verified with


class _Ladder:
    """State shared by the rungs of one :func:`match_pair` call: the images, the features already
    computed (later rungs reuse them), the best geometry so far and the deadline."""

    def __init__(self, target, source, hole, cfg: MatchingConfig, scale_px: float, start: float, K=None):
        self.cfg, self.hole, self.scale, self.K = cfg, hole, scale_px, K
        self.gray = (to_gray_u8(target), to_gray_u8(source))
        self.masks = (keypoint_mask(hole, cfg.hole_margin_px * scale_px), None)
        self.threshold = cfg.ransac_px(scale_px)
        self.deadline = start + cfg.time_budget_s
        self.features: dict[str, tuple[Features, Features]] = {}
        self.best: _Candidate | None = None
        self.candidates: list[_Candidate] = []
        self.learned_name = ""
        self.learned_unfit = ""  # why the learned matcher cannot take these images ("" when it can)
        self.suspicious = ""  # why SIFT's verified geometry is doubted ("" when it is not)

    def sift(self, n: int, max_side: int = 0) -> tuple[Features, Features]:
        key = f"sift{n}@{max_side}"
        if key not in self.features:
            self.features[key] = detect_sift_pair(self.gray, n, self.masks, max_side)
        return self.features[key]

    def learned(self) -> tuple[Features, Features, np.ndarray] | str:
        """The learned matcher's matches as one-to-one keypoint sets (no descriptors), or why
        there are none; with the re-check's keypoint budget when SIFT's geometry is suspicious."""
        from .learned import learned_matcher

        cfg = self.cfg
        if self.suspicious:
            cfg = replace(cfg, learned_max_keypoints=cfg.learned_recheck_max_keypoints)
        matcher, why = learned_matcher(cfg)
        if matcher is None:
            return why
        self.learned_unfit = matcher.cannot_take(*self.gray)
        if self.learned_unfit:
            return self.learned_unfit
        self.learned_name = why
        mt, ms, _ = matcher(*self.gray, self.masks[0])
        inside = ~self.hole[
            np.clip(np.rint(mt[:, 1]).astype(int), 0, self.hole.shape[0] - 1),
            np.clip(np.rint(mt[:, 0]).astype(int), 0, self.hole.shape[1] - 1),
        ]
        mt, ms = mt[inside], ms[inside]  # the hole is blanked, but its border is not evidence
        none = np.zeros((len(mt), 0), np.float32)
        return Features(mt, none), Features(ms, none), np.repeat(np.arange(len(mt))[:, None], 2, axis=1)

    def run(self, rung: str) -> _Candidate | str:
        """The rung's verified matches, or why it has nothing to work on (guided matching without a
        first geometry, a learned matcher that is off, does not resolve or cannot take the images)."""
        t0, c0 = time.perf_counter(), time.process_time()
        cfg, strict = self.cfg, self.threshold * self.cfg.strict_threshold_scale
        if rung == "sift":
            ft, fs = self.sift(cfg.max_features, cfg.sift_max_side)
            pairs, thr = mutual_ratio_matches(ft.desc, fs.desc, cfg.ratio, cfg.mutual), self.threshold
        elif rung == "learned":
            got = self.learned()
            if isinstance(got, str):
                return got
            # Keypoints located at learned_max_side: their error grows with the working/learned ratio.
            ft, fs, pairs = got
            thr = self.threshold * max(1.0, max(self.gray[0].shape) / cfg.learned_max_side)
        elif rung == "loose":
            ft, fs = self.sift(cfg.loose_max_features)
            pairs, thr = mutual_ratio_matches(ft.desc, fs.desc, cfg.loose_ratio, False), strict
        elif rung == "asift":
            ft, fs, _ = detect_asift(
                self.gray, self.masks, cfg.asift_max_tilt, cfg.asift_max_side,
                cfg.asift_features_per_view, cfg.asift_max_features, self.deadline,
            )  # fmt: skip
            self.features["asift"] = (ft, fs)
            pairs, thr = mutual_ratio_matches(ft.desc, fs.desc, cfg.asift_ratio, True), strict
        else:  # guided
            if self.best is None or self.best.F is None:
                return "no fundamental matrix to guide it"
            # The richest keypoint sets computed so far (ASIFT's when that rung ran).
            ft, fs = max(self.features.values(), key=lambda f: len(f[0]) * len(f[1]))
            band = epipolar_band(ft.pts, fs.pts, self.best.F, cfg.guided_band_px * max(self.scale, 0.5))
            pairs, thr = mutual_ratio_matches(ft.desc, fs.desc, cfg.guided_ratio, True, band), strict
        mt, ms = ft.pts[pairs[:, 0]], fs.pts[pairs[:, 1]]
        # SIFT emits one keypoint per dominant orientation, so a location can appear 2-3 times (25% of
        # the apple video's keypoints): identical matches would be counted twice by the robust fits.
        _, first = np.unique(np.concatenate([mt, ms], axis=1), axis=0, return_index=True)
        first.sort()
        mt, ms = mt[first], ms[first]
        if rung == "learned" and self.suspicious:
            # The re-check of a wallpaper-like SIFT geometry: F would keep the same plane family.
            # (After a weak SIFT, F is kept: on slambook f1->f2 E gave 1.98 deg against F's 1.50.)
            F, keep = verify_essential(mt, ms, thr, self.K)
        else:
            F, keep = verify_fundamental(mt, ms, thr, cfg)
        tentative = (mt, ms)
        mt, ms = mt[keep], ms[keep]
        support = hole_support(self.hole, mt, cfg.hole_support_radius_px * self.scale)
        weak = []
        if len(mt) < cfg.min_verified:
            weak.append(f"{len(mt)} verified matches < {cfg.min_verified}")
        if support < cfg.min_hole_support:
            weak.append(
                f"{100 * support:.0f}% of the hole near a verified match < {100 * cfg.min_hole_support:.0f}%"
            )
        report = RungReport(
            rung,
            len(first),
            len(mt),
            support,
            time.perf_counter() - t0,
            "; ".join(weak),
            time.process_time() - c0,
        )
        cand = _Candidate(report, mt, ms, F, (len(ft), len(fs)), tentative, thr)
        self.candidates.append(cand)
        if self.best is None or _score(cand) > _score(self.best):
            self.best = cand
        return cand

    def suspect(self, cand: _Candidate) -> str:
        """Why the verified SIFT geometry ``cand`` is suspicious ("" when it is not, or when there
        are no intrinsics to check it with): fewer than ``learned_suspicious_fraction`` of its
        verified matches fit a calibrated geometry (:func:`verify_essential`)."""
        least = self.cfg.learned_suspicious_fraction
        if self.K is None or not least or not cand.report.verified:
            return ""
        _, fit = verify_essential(cand.pts_t, cand.pts_s, cand.threshold, self.K)
        if fit.mean() >= least:
            return ""
        self.suspicious = (
            f"{cand.report.rung} geometry suspicious: {fit.sum()} of its {len(fit)} verified matches fit an "
            f"essential matrix (< {100 * least:.0f}%)"
        )
        return self.suspicious

    def choose(self) -> str:
        """Between rungs that both verified (SIFT and its learned cross-check), keep the geometry
        that more matches around the hole support, SIFT's unless another rung's is supported by
        ``SUPPORT_MARGIN`` times as many. Sets ``best`` and returns why ("" when fewer than two
        rungs verified).

        The support of a rung's geometry is the number of all rungs' tentative matches within
        ``hole_support_radius_px`` of the hole that fit the essential matrix estimated from its
        verified matches with the prior intrinsics. Not F: repeated structure on a plane (the fox's
        wallpaper) gives SIFT matches shifted by whole periods, and those fit an F of the plane's
        family (the epipole at infinity along the period) as well as the right matches on the
        plane do, so F-support cannot tell the geometries apart; a calibrated E cannot take that
        form. Without intrinsics, F-support at the rungs' threshold is used."""
        verified = [c for c in self.candidates if c.report.verified and c.F is not None]
        if len(verified) < 2:
            return ""
        pool_t = np.concatenate([c.tentative[0] for c in self.candidates])
        pool_s = np.concatenate([c.tentative[1] for c in self.candidates])
        near = near_hole(self.hole, pool_t, self.cfg.hole_support_radius_px * self.scale)
        pool_t, pool_s = pool_t[near], pool_s[near]
        thr = max(c.threshold for c in verified)
        if self.K is not None:
            # The prior focal length can be far off (no EXIF): each geometry is scored at its best
            # of a few focal lengths around it.
            support = [
                max(
                    essential_support(*c.tentative, pool_t, pool_s, _focal_scaled(self.K, f), thr)
                    for f in FOCAL_SCALES
                )
                for c in verified
            ]
            kind = "essential matrix, focal prior x " + "/".join(f"{f:g}" for f in FOCAL_SCALES)
        else:
            support = [int((sampson_px(c.F, pool_t, pool_s) < thr).sum()) for c in verified]
            kind = "fundamental matrix"
        k = int(np.argmax(support))
        if support[k] < SUPPORT_MARGIN * support[0]:
            k = 0
        self.best = verified[k]
        tally = ", ".join(f"{c.report.rung} {n}" for c, n in zip(verified, support, strict=True))
        return (
            f"{self.best.report.rung} kept: of {len(pool_t)} matches around the hole, {tally} fit each "
            f"rung's geometry ({kind}, {thr:.2f} px)"
        )


def _focal_scaled(K: tuple[np.ndarray, np.ndarray], f: float) -> tuple[np.ndarray, np.ndarray]:
    """``K`` (target, source) with both focal lengths times ``f``."""
    scaled = [np.array(k, np.float64) for k in K]
    for k in scaled:
        k[0, 0] *= f
        k[1, 1] *= f
    return scaled[0], scaled[1]


def essential_support(
    pts_t: np.ndarray,
    pts_s: np.ndarray,
    pool_t: np.ndarray,
    pool_s: np.ndarray,
    K: tuple[np.ndarray, np.ndarray],
    threshold_px: float,
) -> int:
    """How many ``pool`` matches fit (Sampson distance in target pixels < ``threshold_px``) the
    essential matrix estimated (MAGSAC++) from the matches ``pts_t``/``pts_s`` with the target
    and source intrinsics ``K``; 0 when none can be estimated."""
    K_t, K_s = K
    f = float(K_t[0, 0])
    try:
        E, _ = cv2.findEssentialMat(
            _normalised(pts_s, K_s),
            _normalised(pts_t, K_t),
            np.eye(3),
            cv2.USAC_MAGSAC,
            0.999,
            threshold_px / f,
        )
    except cv2.error:
        return 0
    if E is None or len(pool_t) == 0:
        return 0
    best = 0
    for k in range(0, E.shape[0], 3):  # the five-point solver can return several
        d = sampson_px(E[k : k + 3], _normalised(pool_t, K_t), _normalised(pool_s, K_s)) * f
        best = max(best, int((d < threshold_px).sum()))
    return best


def near_hole(hole: np.ndarray, pts: np.ndarray, radius_px: float) -> np.ndarray:
    """bool per point (x, y): within ``radius_px`` of the hole (outside it)."""
    if not hole.any() or len(pts) == 0:
        return np.ones(len(pts), bool)
    dist = cv2.distanceTransform(np.where(hole, 0, 255).astype(np.uint8), cv2.DIST_L2, 3)
    xy = np.clip(np.rint(pts).astype(np.int64), 0, [hole.shape[1] - 1, hole.shape[0] - 1])
    return dist[xy[:, 1], xy[:, 0]] <= radius_px


def sampson_px(F: np.ndarray, pts_t: np.ndarray, pts_s: np.ndarray) -> np.ndarray:
    """Sampson distance (px) of each match to ``x_t^T F x_s = 0``."""
    xs = np.c_[pts_s, np.ones(len(pts_s))]
    xt = np.c_[pts_t, np.ones(len(pts_t))]
    Fxs, Ftxt = xs @ F.T, xt @ F
    num = np.einsum("ij,ij->i", xt, Fxs)
    den = Fxs[:, 0] ** 2 + Fxs[:, 1] ** 2 + Ftxt[:, 0] ** 2 + Ftxt[:, 1] ** 2
    return np.abs(num) / np.sqrt(np.maximum(den, 1e-30))


def _score(c: _Candidate) -> tuple[bool, bool, int]:
    """Order of preference between rungs: a verified geometry, then any F, then more inliers."""
    return c.report.verified, c.F is not None, c.report.n_verified


def another_scene(reports: list[RungReport], cfg: MatchingConfig, learned_unfit: str = "") -> str:
    """Why a reference whose early rungs found ``reports`` shows another scene than the target, in
    the words of the report ("" when it may show the same one): every rung so far verified fewer than
    ``unrelated_max_verified`` matches. ``learned_unfit``: why the learned rung was skipped, if it was."""
    most = max((r.n_verified for r in reports), default=0)
    if not reports or most >= cfg.unrelated_max_verified:
        return ""
    tried = " and ".join(r.rung for r in reports)
    if learned_unfit:
        tried += f"; learned skipped: {learned_unfit}"
    return (
        f"does not show the same scene as the target: {most} matching points ({tried}), "
        f"{cfg.unrelated_max_verified} needed"
    )


def match_pair(
    target: np.ndarray,
    source: np.ndarray,
    hole: np.ndarray,
    cfg: MatchingConfig,
    scale_px: float = 1.0,
    K: tuple[np.ndarray, np.ndarray] | None = None,
) -> Matches:
    """Match ``target`` (with boolean ``hole``) against ``source``; both RGB at working resolution.

    ``scale_px`` converts the config's pixel distances (given at a 1280-px long side) to this image.
    ``K``: the prior (target, source) intrinsics at working resolution, with which two verified
    rungs' geometries are compared (:meth:`_Ladder.choose`).
    Never raises on valid images: a pair without a verifiable geometry gives :attr:`Matches.too_few`.
    """
    start = time.perf_counter()
    ladder = _Ladder(target, source, hole, cfg, scale_px, start, K)
    reports: list[RungReport] = []
    notes: list[str] = []
    budget_spent = False
    if cfg.learned == "on" or cfg.learned_model:
        from .learned import learned_matcher

        learned_matcher(cfg)  # a required matcher that cannot be used is an error before any work
    unrelated = ""
    for rung in RUNGS[: RUNGS.index(cfg.max_rung) + 1]:
        if rung == "learned" and cfg.learned == "off" and not cfg.learned_model:
            continue
        # A verified geometry ends the climb; only the learned cross-check, when asked for or when
        # SIFT's geometry is suspicious, still runs.
        recheck = rung == "learned" and (cfg.learned_cross_check or ladder.suspicious)
        if any(r.verified for r in reports) and not recheck:
            break
        if rung not in EARLY_RUNGS and (unrelated := another_scene(reports, cfg, ladder.learned_unfit)):
            notes.append(f"given up before rung {rung}: {unrelated}")
            break
        if reports and time.perf_counter() >= ladder.deadline:
            budget_spent = True
            notes.append(f"time budget {cfg.time_budget_s:g} s spent before rung {rung}")
            break
        cand = ladder.run(rung)
        if isinstance(cand, str):
            notes.append(f"rung {rung} skipped: {cand}")
            continue
        reports.append(cand.report)
        if not cand.report.verified:
            notes.append(f"rung {rung} weak: {cand.report.weak}")
        elif rung == "sift" and (cfg.learned != "off" or cfg.learned_model) and ladder.suspect(cand):
            notes.append(ladder.suspicious)
    choice = ladder.choose()
    best = ladder.best
    elapsed = time.perf_counter() - start
    sift = ladder.features.get(f"sift{cfg.max_features}@{cfg.sift_max_side}", (None, None))
    budget_spent = budget_spent or (elapsed >= cfg.time_budget_s and not best.report.verified)
    return Matches(
        best.pts_t,
        best.pts_s,
        best.F,
        best.n_kp[0],
        best.n_kp[1],
        best.report.n_tentative,
        rung=best.report.rung,
        rungs=tuple(reports),
        verified=best.report.verified,
        budget_spent=budget_spent,
        time_s=elapsed,
        notes=tuple(notes),
        matcher=_matcher_name(best.report.rung, ladder.learned_name),
        choice=choice,
        unrelated=unrelated,
        target_features=sift[0],
        source_features=sift[1],
    )


def _matcher_name(rung: str, learned: str) -> str:
    return {"learned": learned, "asift": "ASIFT (OpenCV AffineFeature + SIFT)"}.get(rung, "SIFT (OpenCV)")
