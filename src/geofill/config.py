"""One typed configuration object with the paper's defaults, dumpable/loadable as JSON.

Every stage reads only its own section. Unknown keys in a JSON file are errors (a typo must not
silently fall back to a default)."""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from .errors import ConfigError


@dataclass
class IntrinsicsConfig:
    """Where each image's pinhole intrinsics come from (see :mod:`geofill.intrinsics`)."""

    #: Explicit focal length (px of the input image) for both images; wins over EXIF and defaults.
    focal_px: float | None = None
    #: Full calibration [fx, fy, cx, cy] (px of the input target image); wins over everything.
    target: list[float] | None = None
    #: Full calibration [fx, fy, cx, cy] (px of the input source image); wins over everything.
    source: list[float] | None = None
    #: Use the EXIF focal length when present: FocalLengthIn35mmFilm, else FocalLength with the
    #: focal-plane resolution (see :mod:`geofill.intrinsics`).
    use_exif: bool = True
    #: Focal-length estimation from the pair, after matching and before the pose (see
    #: :mod:`geofill.focal`): ``none`` keeps the prior (flag, EXIF or default: the paper's setting);
    #: ``search`` profiles the robust Sampson cost of the best essential matrix over a focal scale
    #: (default: best on the GT-pose pairs and synthetic scenes, benchmarks/focal_bench.py);
    #: ``bougnoux`` is the closed form from F; ``auto`` combines the two. Focal lengths given by a
    #: flag are never estimated; an EXIF focal is a prior the estimate may move within its uncertainty.
    estimate: Literal["none", "search", "bougnoux", "auto"] = "search"
    #: Prior 1-sigma of log(focal) for the default focal guess (1.0: a factor of e either way).
    prior_sigma_default: float = 1.0
    #: Prior 1-sigma of log(focal) for an EXIF focal (phones' EXIF is usually right to a few %).
    #: Below ``model_error``, so by default the pair cannot move an EXIF focal: the estimate checks
    #: it (report) and takes over only where EXIF is absent, or trusted less than this.
    prior_sigma_exif: float = 0.05
    #: Focal scales (relative to the prior) searched: log grid from ``search_min_scale`` to
    #: ``search_max_scale`` with ``search_steps`` points, then refined around the best.
    search_min_scale: float = 0.33
    search_max_scale: float = 3.0
    search_steps: int = 13
    #: The search reads its Sampson cost as a Gaussian likelihood of the focal with the information
    #: divided by this: SIFT positions carry correlated errors (localisation bias), so the formal
    #: likelihood is overconfident (25: the standard deviation x5).
    search_variance_inflation: float = 25.0
    #: Relative focal error (1 sigma) the pair can never beat: what lens distortion, an off-centre
    #: principal point or a rolling shutter leave. Estimates on the GT pairs were 0-16 % off where
    #: more than 70 matches (benchmarks/focal_bench.py).
    model_error: float = 0.1
    #: Matches used by the search at most (evenly subsampled, for speed).
    search_max_matches: int = 2000
    #: The estimate is used only if its uncertainty (1-sigma of log focal) is at most this and at
    #: most ``max_uncertainty_ratio`` times the prior's; otherwise the focal is unobservable from
    #: this pair (e.g. parallel optical axes: stereo, pure sideways or forward motion; few matches)
    #: and the prior is kept, with the reason in the report. 0.25 turned away the two estimates
    #: that were 32 % off or unverifiable on the DEV pairs (+-44 %, +-32 %).
    max_uncertainty: float = 0.25
    max_uncertainty_ratio: float = 0.7
    #: A pair whose best focal is further than this many standard deviations from the prior
    #: contradicts it: the prior is kept (an EXIF focal wins over an estimate it rules out).
    max_prior_conflict: float = 3.0
    #: ``bougnoux``: bootstrap resamples of the matches that measure the formula's sensitivity.
    bougnoux_resamples: int = 32


@dataclass
class MatchingConfig:
    """SIFT matching between target and source (hole excluded)."""

    #: SIFT keypoints per image (strongest kept); 0 = no limit. 4000 gave the same pose accuracy
    #: as 8000 on the GT-pose pairs (median 0.18 deg / 0.95 deg) at half the matching time.
    max_features: int = 4000
    #: Lowe's ratio test threshold.
    ratio: float = 0.8
    #: Keep only matches that are each other's nearest neighbour.
    mutual: bool = True
    #: Target keypoints closer than this to the hole (px at a 1280-px long side, scaled) are dropped:
    #: their descriptors see the object being removed.
    hole_margin_px: float = 8.0
    #: Robust estimator for the epipolar geometry.
    robust_method: Literal["magsac", "ransac", "lmeds"] = "magsac"
    #: Inlier threshold (px at the working resolution).
    ransac_threshold_px: float = 1.0
    ransac_confidence: float = 0.9999
    ransac_max_iters: int = 10000


@dataclass
class GeometryConfig:
    """Relative pose, triangulation, depth scale/offset fit and degeneracy checks."""

    #: Fewer verified matches than this is a degenerate pair (single-image fallback).
    min_inliers: int = 20
    #: Median triangulation angle (deg) under which the pair is treated as near-pure rotation.
    min_median_parallax_deg: float = 0.3
    #: Triangulated points with a reprojection error above this (px) are discarded.
    max_reprojection_px: float = 4.0
    #: Triangulated points with a ray angle below this (deg) carry no depth information.
    min_point_parallax_deg: float = 0.05
    #: Least squares or a robust (Huber, IRLS) variant for the depth scale/offset fit.
    depth_fit: Literal["lstsq", "robust"] = "robust"
    #: Space of the affine depth fit. Inverse depth measured better on the GT-depth pairs
    #: (benchmarks/depth_fit_space.py; docs/results.md) whatever the backend's native space.
    fit_space: Literal["depth", "inverse"] = "inverse"


@dataclass
class DepthConfig:
    """Which depth backend gives the source's dense depth."""

    #: ``auto``: ``fused`` when the learned model's weights resolve, else ``stereo`` (the reason is
    #: printed and reported); ``stereo``: weight-free plane sweep + edge-aware completion;
    #: ``onnx``: learned monocular network; ``fused``: learned depth fitted densely to stereo;
    #: ``sparse``: triangulated points interpolated; ``file``: a user-supplied map.
    backend: Literal["auto", "stereo", "fused", "onnx", "sparse", "file"] = "auto"
    #: ``onnx``/``fused``: which network (Depth Anything V2 Small is Apache-2.0; DPT-Hybrid is the
    #: paper's; MiDaS v2.1 small is the fastest).
    model: Literal["depth-anything-v2-small", "dpt-hybrid", "midas-v2.1-small"] = "depth-anything-v2-small"
    #: ``onnx``/``fused``: explicit ONNX file of ``model``; wins over its environment variable, the
    #: cache and the hub (CLI ``--depth-model``).
    model_path: str | None = None
    #: Allow downloading missing weights from the hub (``HF_HUB_OFFLINE=1`` forbids it too).
    download: bool = True
    #: ``file`` backend: path of a .npy / 16-bit PNG / TIFF / EXR map the size of the source.
    file_path: str | None = None
    #: ``file`` backend: what the values are.
    file_kind: Literal["depth", "inverse_depth", "disparity"] = "depth"
    #: ``file`` backend: multiply stored values by this to get the stated kind (e.g. 0.001 for mm PNG).
    file_scale: float = 1.0
    #: ``file`` backend: True when the map is metric (pose translation gets its scale from it).
    file_metric: bool = False
    #: ``sparse`` backend: working long side (px) of the edge-aware interpolation.
    sparse_max_side: int = 640
    #: ``stereo``: long side (px) of the plane sweep and of its completion.
    stereo_max_side: int = 448
    #: ``stereo``: most depth hypotheses (planes uniform in inverse depth); fewer are used when the
    #: sweep's displacement range is shorter (about one plane per pixel of displacement).
    stereo_max_planes: int = 96
    #: ``stereo``: side (px at the sweep's resolution) of the NCC window.
    stereo_patch_px: int = 7
    #: ``stereo``: radius (px) of the guided filter that aggregates each cost slice; 0 = off.
    stereo_aggregation_radius: int = 8
    #: ``stereo``: pixels under this confidence (0-1) are re-estimated by edge-aware completion.
    stereo_min_confidence: float = 0.5


@dataclass
class OptimizeConfig:
    """Joint pose-depth optimisation (paper Sec. 3.2 and supplement; :mod:`geofill.optimize`).

    Pixel distances are given at a 1280-px long side (the paper's 1280x720) and scaled with the
    long side of the optimisation's finest level."""

    enabled: bool = True
    #: ``fast``: Levenberg-Marquardt on the same objective; ``paper``: DiffGrad, as published.
    solver: Literal["fast", "paper"] = "fast"
    #: Weights of L_photo, L_feat and L_negD (paper: 10, 10, 0.5).
    lambda_photo: float = 10.0
    lambda_feat: float = 10.0
    lambda_negd: float = 0.5
    #: Loss switches (the paper's loss ablation).
    use_photo: bool = True
    use_feat: bool = True
    use_negd: bool = True
    #: Weight-map switches (the paper's W ablation); both off = uniform weights.
    use_hole_weight: bool = True
    use_edge_weight: bool = True
    #: sigma of the hole-distance weight W_h = exp(-d^2 / 2 sigma^2) (paper: 192 px at 1280x720).
    hole_sigma_px: float = 192.0
    #: Gaussian blur kernel sizes before each of the Canny edge maps of W_e (the paper uses 4 maps
    #: and gives no sizes; odd after scaling).
    edge_blur_kernels: list[int] = field(default_factory=lambda: [3, 7, 15, 31])
    #: Canny hysteresis thresholds per blurred image (the paper gives none): the high one is this
    #: percentile of its gradient magnitude over known pixels, the low one ``canny_low_ratio`` times it
    #: (fixed thresholds found 0.4 % to 34 % edge pixels on the dev pairs, whatever their contrast).
    canny_high_percentile: float = 90.0
    canny_low_ratio: float = 0.4
    #: Square dilation of each edge map (paper: kernel size 4).
    edge_dilation_px: int = 4
    #: Barron's general robust loss for L_feat: shape alpha and scale c (paper: -2 and 10 px).
    barron_alpha: float = -2.0
    barron_c_px: float = 10.0
    #: Gaussian pyramid levels, optimised coarse to fine (paper: 4).
    pyramid_levels: int = 4
    #: Long side (px) of the finest level; the working images are downsized to it when larger. The
    #: paper optimises at 1280 px; 640 gave the same mean hole PSNR on the 23 DEV pairs (19.06 dB,
    #: no pair worse by more than 0.19 dB) with the stage 1.3-3.8x faster (docs/architecture.md).
    max_side: int = 640
    #: ``paper`` solver: DiffGrad's constant learning rate (paper: 1e-2).
    paper_lr: float = 1e-2
    #: ``paper`` solver: cumulative iteration limits per level, coarse to fine (paper: 4k, 7k, 9k, 10k).
    paper_iterations: list[int] = field(default_factory=lambda: [4000, 7000, 9000, 10000])
    #: ``paper`` solver: convergence threshold eps_opt and window m of the supplement's test.
    paper_eps: float = 1e-6
    paper_window: int = 10
    #: ``fast`` solver: Levenberg-Marquardt iterations per level, coarse to fine.
    fast_iterations: list[int] = field(default_factory=lambda: [30, 20, 12, 8])
    #: ``fast`` solver: a level stops when an accepted step lowers the objective by less than this
    #: (relative).
    fast_ftol: float = 1e-6
    #: ``fast`` solver: largest step, as the 95th percentile of the motion it gives the reprojected
    #: points, in px of the pyramid level being solved (a trust region).
    fast_step_px: float = 4.0
    #: ``fast`` solver: photometric residuals only on source pixels whose reprojection lands where W
    #: (max-filtered by ``fast_margin_px``) is at least this fraction of its maximum; 0 = all pixels.
    fast_min_weight: float = 1e-3
    #: ``fast`` solver: margin (px at each level) around the weighted area kept in that set.
    fast_margin_px: int = 1
    #: torch intra-op threads while optimising (restored afterwards). The work is many small
    #: memory-bound operations: 2 threads were 13x slower than 1 with the 2 cores shared by other jobs.
    threads: int = 1
    #: Refine a focal scale shared by both images as an extra parameter (issue 7); off = the paper.
    refine_focal: bool = False
    #: Weak prior on the log focal scale phi: ``w * l0 * phi^2`` with l0 the initial objective, so a
    #: focal change by a factor e costs ``w`` times the initial objective.
    focal_prior_weight: float = 0.01


@dataclass
class RenderConfig:
    """Rendering the source into the target view."""

    #: Mesh edges with 2|d_i - d_j| / (d_i + d_j) above this are cut (paper: 4e-2).
    edge_threshold: float = 0.04
    #: A hole the source covers less than this fraction of falls back to single-image inpainting.
    min_hole_coverage: float = 0.05


@dataclass
class RefineConfig:
    """Residual alignment and colour correction of the render, then its merge with single-image
    inpainting (:mod:`geofill.refine`, :mod:`geofill.merge`). Pixel distances are at a 1280-px
    long side and scale with the image."""

    #: Colour/exposure correction fitted on the known band: "none"; "global" (one robust gain +
    #: offset per channel, as the homography baseline); "gain" (spatially smooth gain + offset);
    #: "poisson" (gradient-domain: the render's gradients, the target's values on the border).
    colour: Literal["none", "global", "gain", "poisson"] = "gain"
    #: Residual alignment: dense optical flow (OpenCV DIS) render -> target on the known band,
    #: carried into the hole by membrane interpolation and composed with the correspondence field.
    flow: bool = True
    #: Width (px) of the known ring around the hole that refinement measures on.
    band_px: float = 32.0
    #: Long side (px) of the image-equivalent resolution at which flow and colour fields are
    #: estimated; they are applied at the input resolution.
    max_side: int = 1280
    #: DIS preset (speed/accuracy).
    flow_preset: Literal["ultrafast", "fast", "medium"] = "fast"
    #: Band flow vectors longer than this (px) or failing the forward-backward check by more than
    #: ``flow_consistency_px`` are not trusted.
    flow_max_px: float = 24.0
    flow_consistency_px: float = 1.0
    #: Gaussian scale (px) of the local statistics of the "gain" colour model.
    gain_sigma_px: float = 8.0
    #: Regulariser of the local gain (intensity variance): where the render's local variance is
    #: below it (flat regions, where gain and offset cannot be told apart) the gain tends to the
    #: global one and the offset does the work.
    gain_eps: float = 0.0005
    #: Gaussian scale (px) of the smoothing of the target - render difference on the band before
    #: the "poisson" solve (0: exact Poisson blend; larger: fewer streaks from misaligned texture).
    poisson_smooth_px: float = 4.0
    #: Width (px) of the soft blend (M_single) from the render into single-image inpainting where the
    #: render has no data; 0 pastes with hard edges.
    feather_px: float = 4.0


@dataclass
class InpaintConfig:
    """Single-image inpainting for what the source cannot supply."""

    #: "telea"/"ns": OpenCV (no weights); "lama": LaMa through ONNX Runtime; "auto": LaMa when its
    #: model resolves (path, $GEOFILL_LAMA_MODEL, cache, hub), else Telea (the reason is reported).
    method: Literal["telea", "ns", "lama", "auto"] = "auto"
    #: OpenCV inpainting neighbourhood radius (px).
    radius_px: float = 5.0
    #: Explicit LaMa ONNX file (e.g. Carve/LaMa-ONNX's lama.onnx); wins over the environment
    #: variable, the cache and the hub.
    lama_model: str | None = None
    #: Allow downloading the LaMa model from the hub (``HF_HUB_OFFLINE=1`` forbids it too). Off by
    #: default: no checksum is published for it, so a 207 MB unverifiable download is opt-in.
    download: bool = False


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
    #: Geometry (matching, pose, depth, optimisation) runs with the long side capped at this (px);
    #: rendering and compositing run at the input resolution.
    working_max_side: int = 1280
    #: Inputs with more pixels than this are refused (decompression-bomb guard).
    max_pixels: int = 60_000_000
    #: Masks covering more than this fraction of the target are refused.
    max_mask_fraction: float = 0.9
    #: Images with a side under this (px) are refused.
    min_side_px: int = 64

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
        try:
            data = json.loads(Path(path).read_text())
        except FileNotFoundError as exc:
            raise ConfigError(f"config file not found: {path}") from exc
        except json.JSONDecodeError as exc:
            raise ConfigError(f"config file {path} is not valid JSON: {exc}") from exc
        return cls.from_dict(data)

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


def _build(cls: type, data: Any, where: str):
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected an object, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)}; known: {sorted(names)}")
    kwargs = {}
    for name, value in data.items():
        kwargs[name] = _coerce(hints[name], value, f"{where}.{name}")
    return cls(**kwargs)


def _coerce(tp: Any, value: Any, where: str) -> Any:
    if dataclasses.is_dataclass(tp):
        return _build(tp, value, where)
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is Literal:
        if value not in args:
            raise ConfigError(f"{where}: {value!r} is not one of {list(args)}")
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(arg, value, where)
            except ConfigError:
                continue
        raise ConfigError(f"{where}: {value!r} does not fit {tp}")
    if origin in (list, tuple):
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        (inner,) = args[:1] or (Any,)
        return origin(_coerce(inner, v, where) for v in value)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    return value


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
    return overrides
