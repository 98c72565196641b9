"""Focal length from the pair itself, between matching and pose.

The F-verified matches do not depend on the intrinsics; an essential matrix exists only for the
right focal lengths (E = K_t^T F K_s must have two equal singular values), so the matches carry
information about the focal. Two estimators:

``search`` (default): a 1-D profile over a focal *scale* applied to the prior focal of the free
image(s). For each scale on a log grid the best essential matrix is fitted by robust (soft-L1)
Gauss-Newton on the Sampson errors in pixels, warm-started from the neighbouring scale; the best
scale is refined between its grid neighbours. The profile is read as a likelihood of log(focal)
(deflated by ``search_variance_inflation``, floored at ``model_error``) and multiplied by the
log-normal prior of the focal; the uncertainty is the wider of the local posterior and the
profile's own 1-sigma interval.

``bougnoux``: Bougnoux's closed form (1998) of both focal lengths from F with the principal points
at the image centres; its sensitivity is measured by re-fitting F on bootstrap resamples of the
matches. Singular whenever the optical axes are coplanar, which includes every yaw-only motion.

``auto``: the precision-weighted mean of whichever of the two succeed.

Measured (benchmarks/studies/focal_bench.py): the search is the most accurate on the GT pairs and the
rendered scenes; Bougnoux is biased on real pairs and fails on coplanar axes.

Two views determine the focal only when the motion allows it: parallel optical axes (rectified
stereo, pure sideways or forward translation) leave it unobservable, and optical axes meeting at
a point equidistant from both centres (a small orbit around an object) nearly so (Sturm, "On
focal length calibration from two views", CVPR 2001). This is detected, not assumed: when the
data leave too much uncertainty (``max_uncertainty``, ``max_uncertainty_ratio``) or contradict the prior
(``max_prior_conflict``), the prior focal is kept and the report says why.

Which images are estimated: a focal given by a flag never moves; otherwise the image(s) with the
weakest prior (largest ``rel_uncertainty``: default > EXIF) move, by one shared scale when both do
(same camera or not, one scale on two priors keeps the search 1-D).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from .camera import Intrinsics, rotation_from_rotvec
from .config import IntrinsicsConfig
from .match import MIN_MATCHES_FOR_F, Matches
from .utils.numerics import minimize_bounded, robust_least_squares
from .utils.rotations import SKEW_GENERATORS, left_jacobian, skew

#: Step (in log focal) of the finite-difference curvature at the optimum.
_CURVATURE_STEP = 0.02
#: Optical axes closer than this (deg) count as parallel: Bougnoux's formula is refused and an
#: unobservable search says so (KITTI / Middlebury stereo and KITTI driving: 0.1-0.6 deg; the
#: observable GT pairs: 2.4 deg and more).
_PARALLEL_AXES_DEG = 2.0
#: Bootstrap resamples that must give a real focal for Bougnoux's formula to count as stable.
_MIN_VALID_FRACTION = 0.8


@dataclass(frozen=True)
class FocalCandidate:
    """One estimator's answer. ``scale`` multiplies the prior focal of the free image(s);
    ``rel_uncertainty`` is the 1-sigma of log(focal) (prior included); ``ok`` is False when the
    estimator failed or the focal is unobservable with it, with the reason."""

    method: str
    ok: bool
    scale: float | None = None
    rel_uncertainty: float | None = None
    reason: str = ""

    def to_json(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "ok": self.ok,
            "scale": self.scale,
            "rel_uncertainty": self.rel_uncertainty,
            "reason": self.reason,
        }


@dataclass(frozen=True)
class FocalProfile:
    """The search's scored candidates: per focal scale, the best essential matrix's robust Sampson
    cost (px^2), its inliers (Sampson error under the threshold) and median Sampson error (px)."""

    scales: np.ndarray
    cost: np.ndarray
    n_inliers: np.ndarray
    median_px: np.ndarray
    optical_axes_deg: float  # angle between the optical axes fitted at the prior focal

    def to_json(self) -> list[dict[str, float]]:
        return [
            {
                "scale": round(float(s), 4),
                "cost": round(float(c), 4),
                "inliers": int(n),
                "median_px": round(float(m), 4),
            }
            for s, c, n, m in zip(self.scales, self.cost, self.n_inliers, self.median_px, strict=True)
        ]


@dataclass(frozen=True)
class FocalEstimate:
    """Result of the focal stage: the intrinsics the pose uses, and how they were decided.

    ``status``: ``estimated`` (at least one focal moved), ``prior`` (kept the prior: estimation
    off, failed or unobservable; ``reason`` says which) or ``given`` (all focal lengths from flags)."""

    K_target: Intrinsics
    K_source: Intrinsics
    status: str
    method: str
    reason: str
    prior_target: Intrinsics
    prior_source: Intrinsics
    candidates: list[FocalCandidate]
    profile: FocalProfile | None = None

    @property
    def scales(self) -> tuple[float, float]:
        """(target, source) focal divided by its prior."""
        return self.K_target.fx / self.prior_target.fx, self.K_source.fx / self.prior_source.fx

    def summary(self) -> str:
        """One line for the progress output."""
        if self.status == "estimated":
            st, ss = self.scales
            unc = max(self.K_target.rel_uncertainty or 0.0, self.K_source.rel_uncertainty or 0.0)
            return (
                f"estimated by {self.method}: x{st:.3f} / x{ss:.3f} of the {self.prior_target.origin} / "
                f"{self.prior_source.origin} focal (target / source), +-{100 * unc:.1f}%"
            )
        return f"{self.status}: {self.reason}"

    def report(self) -> dict[str, Any]:
        """Report fields; the focal lengths themselves (input pixels) are in the reference
        report's ``intrinsics_target`` / ``intrinsics_source``."""
        st, ss = self.scales
        return {
            "status": self.status,
            "method": self.method,
            "reason": self.reason,
            "scale_target": st,
            "scale_source": ss,
            "origin_target": self.K_target.origin,
            "origin_source": self.K_source.origin,
            "rel_uncertainty_target": self.K_target.rel_uncertainty,
            "rel_uncertainty_source": self.K_source.rel_uncertainty,
            "prior_origin_target": self.prior_target.origin,
            "prior_origin_source": self.prior_source.origin,
            "optical_axes_deg": self.profile.optical_axes_deg if self.profile is not None else None,
            "candidates": [c.to_json() for c in self.candidates],
            "profile": self.profile.to_json() if self.profile is not None else [],
        }


# ---------------------------------------------------------------------------------------------
# Public API


def prior_sigma(K: Intrinsics, cfg: IntrinsicsConfig) -> float:
    """Prior 1-sigma of log(focal) of ``K``: its ``rel_uncertainty``, else by its origin."""
    if K.rel_uncertainty is not None:
        return float(K.rel_uncertainty)
    return {"flag": 0.0, "given": 0.0, "exif": cfg.prior_sigma_exif}.get(K.origin, cfg.prior_sigma_default)


def estimate_focal(
    matches: Matches, K_t: Intrinsics, K_s: Intrinsics, cfg: IntrinsicsConfig, threshold_px: float = 1.0
) -> FocalEstimate:
    """Focal lengths of target and source from verified ``matches`` (working-resolution pixels of
    ``K_t`` / ``K_s``, which hold the priors). ``threshold_px`` is the matching's inlier threshold
    at this resolution: the scale of the robust loss and of the inlier counts."""
    sig_t, sig_s = prior_sigma(K_t, cfg), prior_sigma(K_s, cfg)
    sigma = max(sig_t, sig_s)
    free = (sig_t == sigma and sigma > 0, sig_s == sigma and sigma > 0)

    def keep(status: str, reason: str, candidates=(), profile=None) -> FocalEstimate:
        return FocalEstimate(K_t, K_s, status, cfg.estimate, reason, K_t, K_s, list(candidates), profile)

    if cfg.estimate == "none":
        return keep("prior", "focal estimation off (intrinsics.estimate = none)")
    if not any(free):
        return keep("given", "focal lengths given by flags")
    if matches.F is None or len(matches) < MIN_MATCHES_FOR_F:
        return keep("prior", f"too few verified matches ({len(matches)}) to estimate the focal")
    if not matches.verified:
        # The ladder's best rung did not verify: its matches hold a pose at best, not a focal.
        return keep(
            "prior", f"matches from an unverified {matches.rung} rung: too thin to estimate the focal"
        )

    candidates: list[FocalCandidate] = []
    profile = None
    try:
        if cfg.estimate in ("search", "auto"):
            cand, profile = search_focal(matches, K_t, K_s, free, sigma, cfg, threshold_px)
            candidates.append(cand)
        if cfg.estimate in ("bougnoux", "auto"):
            candidates.append(bougnoux_candidate(matches, K_t, K_s, free, sigma, cfg))
    except (ValueError, np.linalg.LinAlgError, cv2.error) as exc:
        # A focal that cannot be estimated is no reason to give up the pair: keep the prior.
        return keep("prior", f"focal estimation failed ({exc}); kept the prior", candidates, profile)
    ok = [c for c in candidates if c.ok]
    if not ok:
        return keep("prior", "; ".join(c.reason for c in candidates), candidates, profile)
    if len(ok) == 1:
        best = ok[0]
    else:  # auto: precision-weighted mean in log focal (each candidate already includes the prior)
        w = np.array([1.0 / c.rel_uncertainty**2 for c in ok])
        log_s = float(np.sum(w * np.log([c.scale for c in ok])) / w.sum())
        best = FocalCandidate("auto", True, float(np.exp(log_s)), float(1.0 / np.sqrt(w.sum())))
    K_t_new, K_s_new = (
        _scaled(K, best.scale, best.rel_uncertainty) if f else K for K, f in ((K_t, free[0]), (K_s, free[1]))
    )
    return FocalEstimate(K_t_new, K_s_new, "estimated", best.method, "", K_t, K_s, candidates, profile)


def search_focal(
    matches: Matches,
    K_t: Intrinsics,
    K_s: Intrinsics,
    free: tuple[bool, bool],
    sigma: float,
    cfg: IntrinsicsConfig,
    threshold_px: float = 1.0,
) -> tuple[FocalCandidate, FocalProfile]:
    """1-D search over a focal scale of the ``free`` images (prior log-sigma ``sigma``)."""
    fit = _EpipolarFit(matches, K_t, K_s, free, threshold_px, cfg.search_max_matches)
    grid = _scale_grid(cfg)
    n = len(grid)
    cost, n_in, med, poses = _grid_profile(fit, grid, matches.F)
    axes_deg = optical_axes_deg(matches, K_t, K_s)
    profile = FocalProfile(grid, cost, n_in, med, axes_deg)

    # Refine the data-only minimum between the grid neighbours of the best grid point; every
    # evaluation joins the profile used for the uncertainty below.
    i = int(np.argmin(cost))
    log_grid = np.log(grid)
    seen = dict(zip(log_grid, cost, strict=True))
    fitted = dict(zip(log_grid, poses, strict=True))

    def data_cost(log_s: float) -> float:
        seen[log_s] = fit.fit_from_nearest(log_s, fitted)
        return seen[log_s]

    lo, hi = log_grid[max(i - 1, 0)], log_grid[min(i + 1, n - 1)]
    best_x, best_cost = minimize_bounded(data_cost, lo, hi, xatol=3e-3)
    log_d = float(best_x) if best_cost < cost[i] else float(log_grid[i])
    c_min = max(min(seen.values()), 1e-12)
    h = _CURVATURE_STEP
    curv_data = (data_cost(log_d + h) + data_cost(log_d - h) - 2.0 * seen[log_d]) / h**2

    # Likelihood of the focal: the Sampson cost read as a Gaussian log-likelihood (residual variance
    # c_min / N) with its information divided by search_variance_inflation, since SIFT errors are
    # correlated; the data's uncertainty never drops under model_error (pinhole violations).
    # Combined with the log-normal prior as a product of Gaussians, and checked against the whole
    # profile, which catches flat or one-sided curves that the local curvature misses.
    temper = len(fit.d_t) / (cfg.search_variance_inflation * c_min)
    sd_stat = 1.0 / np.sqrt(curv_data * temper) if curv_data > 0 else np.inf
    sd_data = float(np.hypot(sd_stat, cfg.model_error))
    precision = 1.0 / sd_data**2 + 1.0 / sigma**2
    log_s = float(log_d / sd_data**2 / precision)
    xs = np.array(sorted(seen))
    nll = np.array([0.5 * (seen[x] - c_min) * temper + 0.5 * (x / sigma) ** 2 for x in xs])
    sd = float(max(1.0 / np.sqrt(precision), _half_width(xs, nll, nll.min() + 0.5)))
    data_scale = float(np.exp(log_d))
    conflict = abs(log_d) / np.hypot(sd_data, sigma)
    if conflict > cfg.max_prior_conflict:
        reason = (
            f"the pair's best focal (x{data_scale:.2f} +-{100 * sd_data:.0f}%) contradicts the prior "
            f"(+-{100 * sigma:.0f}%) by {conflict:.1f} sigma: kept the prior"
        )
        return FocalCandidate("search", False, data_scale, sd_data, reason), profile
    if sd > min(cfg.max_uncertainty, cfg.max_uncertainty_ratio * sigma):
        reason = (
            f"focal unobservable from this pair: +-{100 * sd:.0f}% (prior +-{100 * sigma:.0f}%, "
            f"at most +-{100 * cfg.max_uncertainty:.0f}% used; best fit alone x{data_scale:.2f} "
            f"+-{100 * min(sd_data, 9.99):.0f}%)"
        )
        if axes_deg < _PARALLEL_AXES_DEG:
            reason += (
                f"; fitted optical axes {axes_deg:.1f} deg apart (parallel axes: stereo, sideways or "
                "forward motion hide the focal)"
            )
        return FocalCandidate("search", False, float(np.exp(log_s)), sd, reason), profile
    return FocalCandidate("search", True, float(np.exp(log_s)), sd), profile


def _scale_grid(cfg: IntrinsicsConfig) -> np.ndarray:
    return np.exp(np.linspace(np.log(cfg.search_min_scale), np.log(cfg.search_max_scale), cfg.search_steps))


def _grid_profile(fit: _EpipolarFit, grid: np.ndarray, F: np.ndarray):
    """Per grid scale: the best fit's robust cost, inliers, median Sampson error (px) and pose."""
    n = len(grid)
    cost, n_in, med, poses = np.zeros(n), np.zeros(n, int), np.zeros(n), [None] * n
    start = int(np.argmin(np.abs(np.log(grid))))
    first = fit.initial_pose(grid[start], F)
    # Continuation from the prior outwards: each fit starts from its neighbour's pose.
    for order in (range(start, n), range(start, -1, -1)):
        pose = first
        for i in order:
            if poses[i] is None:
                cost[i], res, poses[i] = fit.fit(grid[i], *pose)
                n_in[i], med[i] = int(np.sum(np.abs(res) < fit.thr)), float(np.median(np.abs(res)))
            pose = poses[i]
    return cost, n_in, med, poses


def shared_focal_scale(
    problems: list[tuple[Matches, Intrinsics, Intrinsics, float]], cfg: IntrinsicsConfig
) -> FocalCandidate:
    """One focal scale for every image of several pairs taken with the same camera (the target and
    each reference), from ``problems`` = [(matches, prior K_target, prior K_source, threshold_px)].

    Each pair's search profile (as in :func:`search_focal`) is read as a likelihood of the shared
    log scale; their sum, with the prior, is minimised on the grid and refined between its
    neighbours. Pairs with too few matches are left out. The same observability and prior-conflict
    rules as for one pair decide whether the estimate is used."""
    usable = [p for p in problems if p[0].F is not None and len(p[0]) >= MIN_MATCHES_FOR_F]
    if not usable:
        return FocalCandidate("shared", False, reason="no pair has enough verified matches")
    sigma = max(prior_sigma(K, cfg) for _, K_t, K_s, _ in usable for K in (K_t, K_s))
    if sigma <= 0:
        return FocalCandidate("shared", False, reason="focal lengths given by flags")
    grid = _scale_grid(cfg)
    fits, profiles = [], []
    for m, K_t, K_s, thr in usable:
        fit = _EpipolarFit(m, K_t, K_s, (True, True), thr, cfg.search_max_matches)
        cost, _, _, poses = _grid_profile(fit, grid, m.F)
        c_min = max(float(cost.min()), 1e-12)
        fitted = dict(zip(np.log(grid), poses, strict=True))
        fits.append((fit, fitted, c_min, len(fit.d_t) / (cfg.search_variance_inflation * c_min)))
        profiles.append(cost)
    log_grid = np.log(grid)

    def nll(log_s: float) -> float:
        return sum(
            0.5 * (fit.fit_from_nearest(log_s, fitted) - c_min) * temper
            for fit, fitted, c_min, temper in fits
        )

    grid_nll = sum(0.5 * (c - f[2]) * f[3] for c, f in zip(profiles, fits, strict=True))
    i = int(np.argmin(grid_nll))
    lo, hi = log_grid[max(i - 1, 0)], log_grid[min(i + 1, len(grid) - 1)]
    best_x, best_nll = minimize_bounded(nll, lo, hi, xatol=3e-3)
    log_d = float(best_x) if best_nll < grid_nll[i] else float(log_grid[i])
    h = _CURVATURE_STEP
    curv = (nll(log_d + h) + nll(log_d - h) - 2.0 * nll(log_d)) / h**2
    sd_data = float(np.hypot(1.0 / np.sqrt(curv) if curv > 0 else np.inf, cfg.model_error))
    precision = 1.0 / sd_data**2 + 1.0 / sigma**2
    log_s, sd = float(log_d / sd_data**2 / precision), float(1.0 / np.sqrt(precision))
    conflict = abs(log_d) / np.hypot(sd_data, sigma)
    if conflict > cfg.max_prior_conflict:
        reason = f"the pairs' best shared focal contradicts the prior by {conflict:.1f} sigma: kept the prior"
        return FocalCandidate("shared", False, float(np.exp(log_d)), sd_data, reason)
    if sd > min(cfg.max_uncertainty, cfg.max_uncertainty_ratio * sigma):
        reason = (
            f"shared focal unobservable from {len(usable)} pairs: +-{100 * sd:.0f}% "
            f"(prior +-{100 * sigma:.0f}%)"
        )
        return FocalCandidate("shared", False, float(np.exp(log_s)), sd, reason)
    return FocalCandidate("shared", True, float(np.exp(log_s)), sd)


def shared_estimate(candidate: FocalCandidate, K_t: Intrinsics, K_s: Intrinsics) -> FocalEstimate:
    """The focal stage's result for one pair of a shared-camera fill."""
    if not candidate.ok:
        return FocalEstimate(K_t, K_s, "prior", "shared", candidate.reason, K_t, K_s, [candidate])
    K_t_new, K_s_new = (_scaled(K, candidate.scale, candidate.rel_uncertainty) for K in (K_t, K_s))
    return FocalEstimate(K_t_new, K_s_new, "estimated", "shared", "", K_t, K_s, [candidate])


def bougnoux_focals(F: np.ndarray, c_t: tuple[float, float], c_s: tuple[float, float]) -> tuple[float, float]:
    """Squared focal lengths (target, source) from F (``x_t^T F x_s = 0``, pixels) with principal
    points ``c_t``, ``c_s`` (S. Bougnoux, "From projective to Euclidean space under any practical
    situation", ICCV 1998; neither OpenCV nor SciPy has it). Negative or infinite values mean the
    configuration is degenerate."""
    A_t = np.array([[1.0, 0.0, c_t[0]], [0.0, 1.0, c_t[1]], [0.0, 0.0, 1.0]])
    A_s = np.array([[1.0, 0.0, c_s[0]], [0.0, 1.0, c_s[1]], [0.0, 0.0, 1.0]])
    Fc = A_t.T @ F @ A_s
    Fc = Fc / np.linalg.norm(Fc)
    return _bougnoux_right(Fc.T), _bougnoux_right(Fc)


def bougnoux_candidate(
    matches: Matches,
    K_t: Intrinsics,
    K_s: Intrinsics,
    free: tuple[bool, bool],
    sigma: float,
    cfg: IntrinsicsConfig,
) -> FocalCandidate:
    """Bougnoux's focal for the ``free`` images as a scale on their priors, combined with the prior
    (log-normal, ``sigma``); its data uncertainty is the spread over bootstrap refits of F."""
    axes_deg = optical_axes_deg(matches, K_t, K_s)
    if axes_deg < _PARALLEL_AXES_DEG:
        return FocalCandidate(
            "bougnoux", False, reason=f"Bougnoux degenerate: optical axes {axes_deg:.1f} deg apart (parallel)"
        )
    scale = _bougnoux_log_scale(matches.F, K_t, K_s, free)
    if scale is None:
        return FocalCandidate("bougnoux", False, reason="Bougnoux: imaginary focal (F degenerate for it)")
    rng = np.random.default_rng(0)
    n = len(matches)
    boot = []
    for _ in range(cfg.bougnoux_resamples):
        idx = rng.integers(0, n, n)
        F, _ = cv2.findFundamentalMat(matches.pts_source[idx], matches.pts_target[idx], cv2.FM_8POINT)
        if F is not None and F.shape == (3, 3):
            boot.append(_bougnoux_log_scale(F, K_t, K_s, free))
    valid = np.array([b for b in boot if b is not None])
    if len(valid) < _MIN_VALID_FRACTION * cfg.bougnoux_resamples:
        return FocalCandidate(
            "bougnoux",
            False,
            float(np.exp(scale)),
            reason=f"Bougnoux unstable: {len(valid)}/{cfg.bougnoux_resamples} resamples give a real focal",
        )
    sd_data = max(1.4826 * float(np.median(np.abs(valid - np.median(valid)))), 1e-6)
    # Product of two log-normals: precision-weighted mean and variance.
    w_data, w_prior = 1.0 / sd_data**2, 1.0 / sigma**2
    log_s = w_data * scale / (w_data + w_prior)
    sd = float(1.0 / np.sqrt(w_data + w_prior))
    in_range = np.log(cfg.search_min_scale) <= scale <= np.log(cfg.search_max_scale)
    if not in_range or sd > min(cfg.max_uncertainty, cfg.max_uncertainty_ratio * sigma):
        why = (
            "outside the searched range"
            if not in_range
            else f"too sensitive to the matches (+-{100 * sd_data:.0f}%)"
        )
        return FocalCandidate(
            "bougnoux", False, float(np.exp(log_s)), sd, f"Bougnoux x{np.exp(scale):.2f} {why}"
        )
    return FocalCandidate("bougnoux", True, float(np.exp(log_s)), sd)


def optical_axes_deg(matches: Matches, K_t: Intrinsics, K_s: Intrinsics) -> float:
    """Angle (deg) between the optical axes of the pose from E = K_t^T F K_s (cheirality-checked):
    near zero, the focal is unobservable and Bougnoux's formula singular."""
    pn_t = (matches.pts_target - [K_t.cx, K_t.cy]) / [K_t.fx, K_t.fy]
    pn_s = (matches.pts_source - [K_s.cx, K_s.cy]) / [K_s.fx, K_s.fy]
    E = K_t.K.T @ matches.F @ K_s.K
    _, R, _, _ = cv2.recoverPose(E, pn_s, pn_t, np.eye(3))
    return float(np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0))))


# ---------------------------------------------------------------------------------------------
# Internals


def _scaled(K: Intrinsics, scale: float, rel_uncertainty: float) -> Intrinsics:
    return replace(K, fx=K.fx * scale, fy=K.fy * scale, origin="estimated", rel_uncertainty=rel_uncertainty)


def _half_width(x: np.ndarray, y: np.ndarray, level: float) -> float:
    """Half the width of the interval around argmin(y) where the piecewise-linear y <= level
    (clipped at the ends of x)."""
    i = int(np.argmin(y))
    bounds = []
    for step in (-1, 1):
        j = i
        while 0 <= j + step < len(x) and y[j + step] <= level:
            j += step
        k = j + step
        if 0 <= k < len(x):
            bounds.append(x[j] + (x[k] - x[j]) * (level - y[j]) / (y[k] - y[j]))
        else:
            bounds.append(x[j])
    return 0.5 * abs(bounds[1] - bounds[0])


def _bougnoux_right(F: np.ndarray) -> float:
    """Squared focal of the camera whose points multiply ``F`` on the right (principal point at the
    origin): f^2 = -(p'^T [e']x I~ F p p^T F^T p') / (p'^T [e']x I~ F I~ F^T p'), p = p' = (0,0,1)."""
    ex = skew(np.linalg.svd(F)[0][:, 2])  # [e]x, e the epipole of the other image: F^T e = 0
    i_tilde = np.diag([1.0, 1.0, 0.0])
    p = np.array([0.0, 0.0, 1.0])
    num = p @ ex @ i_tilde @ F @ np.outer(p, p) @ F.T @ p
    den = p @ ex @ i_tilde @ F @ i_tilde @ F.T @ p
    return float(-num / den) if abs(den) > 1e-300 else float("inf")


def _bougnoux_log_scale(
    F: np.ndarray, K_t: Intrinsics, K_s: Intrinsics, free: tuple[bool, bool]
) -> float | None:
    """Mean log(focal / prior) of the free images from Bougnoux's formula; None if imaginary."""
    f2 = bougnoux_focals(F, (K_t.cx, K_t.cy), (K_s.cx, K_s.cy))
    logs = []
    for f2_i, K, is_free in zip(f2, (K_t, K_s), free, strict=True):
        if not is_free:
            continue
        if not np.isfinite(f2_i) or f2_i <= 0:
            return None
        logs.append(0.5 * np.log(f2_i) - np.log(np.sqrt(K.fx * K.fy)))
    return float(np.mean(logs))


class _EpipolarFit:
    """Best essential matrix for given focal scales: robust trust-region Gauss-Newton (soft-L1
    loss, :func:`geofill.utils.numerics.robust_least_squares`) on the Sampson errors in pixels, over R
    (rotation vector update) and the unit translation (two tangent coordinates)."""

    def __init__(
        self,
        matches: Matches,
        K_t: Intrinsics,
        K_s: Intrinsics,
        free: tuple[bool, bool],
        thr: float,
        max_n: int,
    ) -> None:
        idx = np.linspace(0, len(matches) - 1, min(len(matches), max_n)).round().astype(int)
        self.d_t = matches.pts_target[idx] - [K_t.cx, K_t.cy]  # pixels from the principal point
        self.d_s = matches.pts_source[idx] - [K_s.cx, K_s.cy]
        self.K_t, self.K_s, self.free, self.thr = K_t, K_s, free, thr
        # Homogeneous points as (3, N) rows: every product below runs along contiguous rows.
        self._p_t = np.vstack([self.d_t.T, np.ones(len(idx))])
        self._normalised_at: tuple[float, ...] = ()
        self._normalised: tuple[np.ndarray, np.ndarray] = (self._p_t, self._p_t)

    def focals(self, scale: float) -> tuple[np.ndarray, np.ndarray]:
        st = scale if self.free[0] else 1.0
        ss = scale if self.free[1] else 1.0
        return np.array([self.K_t.fx, self.K_t.fy]) * st, np.array([self.K_s.fx, self.K_s.fy]) * ss

    def residuals(self, Ms: np.ndarray, f_t: np.ndarray, f_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed Sampson errors (px) of F = K_t^-T E K_s^-1 for E = ``Ms[0]``, computed in
        normalised coordinates, and their (N, k - 1) Jacobian for the derivatives ``Ms[1:]`` of E
        ((k, 3, 3) in all)."""
        k, n = Ms.shape[0], self._p_t.shape[1]
        key = (*f_t, *f_s)
        if key != self._normalised_at:  # a fit evaluates one pair of focal lengths many times
            self._normalised_at = key
            self._normalised = (
                np.vstack([self.d_s.T / f_s[:, None], np.ones(n)]),
                np.vstack([self.d_t.T / f_t[:, None], np.ones(n)]),
            )
        n_s, n_t = self._normalised
        # With the first two rows of each matrix divided by f_t, (M n_s)[:2] is the image gradient
        # of x_t^T F x_s in the target and p_t . (M n_s) (p_t in pixels) is n_t^T M n_s; the
        # columns divided by f_s give the gradient in the source. One matrix product each.
        rows = Ms.copy()
        rows[:, :2] /= f_t[:, None]
        cols = Ms[:, :, :2].transpose(0, 2, 1) / f_s[:, None]
        e = (rows.reshape(3 * k, 3) @ n_s).reshape(k, 3, n)
        b = (cols.reshape(2 * k, 3) @ n_t).reshape(k, 2, n)
        num = (e * self._p_t).sum(axis=1)
        a = e[:, :2]
        den = np.maximum(np.sqrt(a[0, 0] ** 2 + a[0, 1] ** 2 + b[0, 0] ** 2 + b[0, 1] ** 2), 1e-12)
        r = num[0] / den
        d_den = (a[0, 0] * a[1:, 0] + a[0, 1] * a[1:, 1] + b[0, 0] * b[1:, 0] + b[0, 1] * b[1:, 1]) / den
        return r, ((num[1:] - r * d_den) / den).T

    def initial_pose(self, scale: float, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) of the essential matrix closest to K_t^T F K_s at ``scale``."""
        f_t, f_s = self.focals(scale)
        Kt = np.array([[f_t[0], 0, self.K_t.cx], [0, f_t[1], self.K_t.cy], [0, 0, 1.0]])
        Ks = np.array([[f_s[0], 0, self.K_s.cx], [0, f_s[1], self.K_s.cy], [0, 0, 1.0]])
        R, _, t = cv2.decomposeEssentialMat(Kt.T @ F @ Ks)
        return R, t.ravel()

    def fit_from_nearest(self, log_scale: float, poses: dict[float, tuple[np.ndarray, np.ndarray]]) -> float:
        """Robust cost of the best fit at scale exp(``log_scale``), started from the pose fitted at
        the nearest log scale in ``poses``, which the new pose joins: a continuation, so each fit
        starts close to its answer (the refinement's fits, all started from the best grid
        scale's pose, took 9.2 evaluations each instead of 6.4 on the real pairs)."""
        near = min(poses, key=lambda s: abs(s - log_scale))
        cost, _, poses[log_scale] = self.fit(float(np.exp(log_scale)), *poses[near])
        return cost

    def fit(self, scale: float, R0: np.ndarray, t0: np.ndarray):
        """(robust cost, residuals, (R, t)) of the best essential matrix at ``scale``, from (R0, t0).

        Parameters: x[:3] rotates R0 on the left (R = exp([x]) R0), x[3:] moves t0 in its tangent
        plane (t = normalised(t0 + x3 u + x4 v)). The Jacobian is analytic: with numerical
        differences the fit took 6x the residual evaluations, the bulk of the search time."""
        f_t, f_s = self.focals(scale)
        t0 = t0 / np.linalg.norm(t0)
        u = np.cross(t0, [1.0, 0.0, 0.0] if abs(t0[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(t0, u)

        def pose(x):
            w = t0 + x[3] * u + x[4] * v
            return rotation_from_rotvec(x[:3]) @ R0, w / np.linalg.norm(w), np.linalg.norm(w)

        def fun_jac(x):
            R, t, norm = pose(x)
            tx = skew(t)
            # d exp([w]) / dw_k = [J_l(w) e_k]x exp([w]), J_l the left Jacobian of SO(3), so
            # dE/dw_k = [t]x [J_l e_k]x R; dE/dx_3,4 = [dt]x R, dt the move of the normalised t.
            uv = np.array([u, v])
            directions = np.vstack([left_jacobian(x[:3]).T, (uv - np.outer(uv @ t, t)) / norm])
            dE = np.tensordot(directions, SKEW_GENERATORS, 1)
            dE[:3] = tx @ dE[:3]
            return self.residuals(np.concatenate([(tx @ R)[None], dE @ R]), f_t, f_s)

        x, cost, res = robust_least_squares(fun_jac, np.zeros(5), "soft_l1", self.thr)
        R, t, _ = pose(x)
        return 2.0 * cost, res, (R, t)
