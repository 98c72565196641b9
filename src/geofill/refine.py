"""Refinement of a source rendering before it is pasted into the target's hole.

The paper corrects the render with TransFill's learned colour-spatial transformer, whose weights are
not public; here the same two jobs are done with classical tools, measured in docs/results.md:

* residual spatial alignment (:mod:`geofill.utils.residual_flow`): dense flow on the known band around the
  hole, carried into the hole and composed with the render's correspondence field;
* colour/exposure: the source was shot with another exposure / white balance. ``global``: a
  per-channel affine map ``target ≈ gain * render + offset`` fitted robustly on the band (what the
  homography baseline uses); ``gain``: the same map as smooth per-pixel fields (local statistics on
  the band, carried into the hole by membrane interpolation); ``poisson``: a gradient-domain blend,
  i.e. the render plus the harmonic interpolant of the (smoothed) target - render difference on the
  band, so the fill keeps the render's gradients and meets the target's values on the border.

Fits are robust (soft-L1 loss, down-weighted residuals) because a rendering is never perfectly
aligned and the band holds parallax, occlusions and moving objects."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np

from .config import RefineConfig
from .io import as_unit_float
from .render import RenderResult
from .utils.membrane import membrane_fill, resize_channels
from .utils.numerics import robust_linear_fit
from .utils.residual_flow import band_flow, compose_maps

#: Fewer known pixels than this and the fit keeps the identity map.
MIN_COLOUR_SAMPLES = 64
#: Samples used per channel; more add time, not accuracy, for a 2-parameter fit.
_MAX_COLOUR_SAMPLES = 20000
#: Residual scale (in [0, 1] intensity units) beyond which the soft-L1 loss stops being quadratic.
_LOSS_SCALE = 0.03
#: Soft-L1 rather than a redescending loss (Cauchy): misalignment residuals are not gross outliers,
#: and on the dev pairs the softer loss gave ~0.25 dB more hole PSNR to the homography baseline.
_LOSS = "soft_l1"
_GAIN_BOUNDS = (1.0 / 3.0, 3.0)
_OFFSET_BOUNDS = (-0.5, 0.5)


@dataclass(frozen=True)
class ColourGain:
    """Per-channel ``gain * x + offset`` in [0, 1] intensity units, fitted on ``n_samples`` pixels."""

    gain: np.ndarray  # (C,) float64
    offset: np.ndarray  # (C,) float64
    n_samples: int

    @classmethod
    def identity(cls, channels: int = 3, n_samples: int = 0) -> ColourGain:
        return cls(np.ones(channels), np.zeros(channels), n_samples)


def fit_colour_gain(
    source: np.ndarray,
    target: np.ndarray,
    known: np.ndarray,
    *,
    offset: bool = True,
    max_samples: int = _MAX_COLOUR_SAMPLES,
) -> ColourGain:
    """Fit ``target ≈ gain * source + offset`` per channel on the pixels where ``known`` is True.

    ``source`` (the rendering / warped source) and ``target``: HxWxC, uint8 or float in [0, 1];
    ``known``: HxW bool. ``offset=False`` fits the gain alone (safer when the known pixels span a
    narrow intensity range). Gains are kept in [1/3, 3] and offsets in [-0.5, 0.5]. With fewer than
    :data:`MIN_COLOUR_SAMPLES` known pixels the identity map is returned. At most ``max_samples``
    pixels, evenly strided, enter the fit."""
    if source.shape != target.shape or known.shape != source.shape[:2]:
        raise ValueError(f"shape mismatch: source {source.shape}, target {target.shape}, known {known.shape}")
    channels = source.shape[2]
    idx = np.flatnonzero(known)
    n_known = int(idx.size)
    if n_known < MIN_COLOUR_SAMPLES:
        return ColourGain.identity(channels, n_known)
    # An even stride keeps the subsample deterministic and spread over the whole band.
    idx = idx[:: max(1, idx.size // max_samples)]
    src = as_unit_float(source).reshape(-1, channels)[idx].astype(np.float64)
    dst = as_unit_float(target).reshape(-1, channels)[idx].astype(np.float64)
    gains, offsets = np.ones(channels), np.zeros(channels)
    n = 2 if offset else 1
    lower = np.array([_GAIN_BOUNDS[0], _OFFSET_BOUNDS[0]])[:n]
    upper = np.array([_GAIN_BOUNDS[1], _OFFSET_BOUNDS[1]])[:n]
    for c in range(channels):
        A = np.column_stack([src[:, c], np.ones(len(idx))])[:, :n]
        fit = robust_linear_fit(A, dst[:, c], _LOSS, _LOSS_SCALE, lower, upper, x0=np.array([1.0, 0.0])[:n])
        gains[c] = fit[0]
        if offset:
            offsets[c] = fit[1]
    return ColourGain(gains, offsets, n_known)


def apply_colour_gain(image: np.ndarray, colour: ColourGain) -> np.ndarray:
    """``gain * image + offset`` per channel, clipped; returns the dtype it was given (uint8 rounded,
    float in [0, 1])."""
    out = as_unit_float(image) * colour.gain.astype(np.float32) + colour.offset.astype(np.float32)
    out = np.clip(out, 0.0, 1.0)
    if image.dtype == np.uint8:
        return np.rint(out * 255.0).astype(np.uint8)
    return out


#: Residual (intensity units) at which a band pixel's weight halves: pixels further off the global
#: colour map are occluders, moving objects or misaligned edges, not exposure.
_ROBUST_SCALE = 0.06
#: Samples of the global fit that serves as prior and fallback of the local models (a
#: 6-parameter fit; fewer than the baseline's 20000 cost nothing in accuracy and 4x less time).
_PRIOR_SAMPLES = 5000
#: Local weight (fraction of the Gaussian's mass on trusted band pixels) under which a band pixel's
#: local statistics are too thin to use; it is filled like a hole pixel.
_MIN_LOCAL_WEIGHT = 0.05


@dataclass
class ColourField:
    """Per-pixel ``gain * x + offset`` (each (h, w, C) float32, intensity units in [0, 1])."""

    gain: np.ndarray
    offset: np.ndarray

    @classmethod
    def constant(cls, colour: ColourGain, shape: tuple[int, int]) -> ColourField:
        c = colour.gain.size
        gain = np.broadcast_to(colour.gain.astype(np.float32), (*shape, c)).copy()
        return cls(gain, np.broadcast_to(colour.offset.astype(np.float32), (*shape, c)).copy())

    def resized(self, width: int, height: int) -> ColourField:
        """Bilinearly resampled to ``width`` x ``height`` (the fields are smooth)."""
        if self.gain.shape[:2] == (height, width):
            return self

        def up(a: np.ndarray) -> np.ndarray:
            return cv2.resize(a, (width, height), interpolation=cv2.INTER_LINEAR).reshape(height, width, -1)

        return ColourField(up(self.gain), up(self.offset))

    def apply(self, image: np.ndarray) -> np.ndarray:
        """The map applied to an HxWxC image of the same size; returns the dtype given (uint8
        rounded, float in [0, 1])."""
        # In place: at 4K each full-window temporary is ~20 MB of fresh pages to fault in.
        out = image.astype(np.float32)
        if image.dtype == np.uint8:
            out /= 255.0
        out *= self.gain
        out += self.offset
        np.clip(out, 0.0, 1.0, out=out)
        if image.dtype == np.uint8:
            out *= 255.0
            return np.rint(out, out=out).astype(np.uint8)
        return out


def _gauss(a: np.ndarray, sigma: float) -> np.ndarray:
    out = cv2.GaussianBlur(a, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    return out.reshape(a.shape)


def robust_band_weights(
    render: np.ndarray, target: np.ndarray, band: np.ndarray, prior: ColourGain
) -> np.ndarray:
    """(H, W) float32 weights in [0, 1] of band pixels (0 off the band): Cauchy weights of their
    residual under the global colour map ``prior``."""
    res = apply_colour_gain(as_unit_float(render), prior) - as_unit_float(target)
    r = np.sqrt(np.mean(res * res, axis=2))
    return np.where(band, 1.0 / (1.0 + (r / _ROBUST_SCALE) ** 2), 0.0).astype(np.float32)


def smooth_gain_field(
    render: np.ndarray,
    target: np.ndarray,
    weights: np.ndarray,
    domain: np.ndarray,
    sigma_px: float,
    prior: ColourGain,
    eps: float = 0.0005,
) -> ColourField:
    """Spatially smooth ``target ≈ gain(x) * render + offset(x)``: weighted local least squares
    (Gaussian window ``sigma_px``, band ``weights``) on the band, the gain regularised towards
    ``prior``'s by ``eps`` (intensity variance), then both fields membrane-filled over ``domain``
    (the hole and its band).
    ``render``/``target``: HxWxC uint8 or float in [0, 1]."""
    r, t = as_unit_float(render), as_unit_float(target)
    c = r.shape[2]
    w = weights[..., None]
    # The statistics are Gaussian-weighted sums of per-pixel moments: block sums on a grid a few
    # times finer than sigma keep them exact up to the window's resolution at a fraction of the cost.
    k = max(1, int(sigma_px // 3))
    h, wd = weights.shape
    size = (max(1, -(-wd // k)), max(1, -(-h // k)))
    # Written in place: the products and their concatenation took three times the memory traffic.
    moments = np.empty((h, wd, 1 + 4 * c), np.float32)
    moments[..., 0] = weights
    np.multiply(w, r, out=moments[..., 1 : 1 + c])
    np.multiply(w, t, out=moments[..., 1 + c : 1 + 2 * c])
    np.multiply(moments[..., 1 : 1 + c], r, out=moments[..., 1 + 2 * c : 1 + 3 * c])
    np.multiply(moments[..., 1 : 1 + c], t, out=moments[..., 1 + 3 * c :])
    moments = resize_channels(moments, size, cv2.INTER_AREA)
    blurred = _gauss(moments, sigma_px / k)
    W = blurred[..., :1]
    Wd = np.maximum(W, 1e-6)
    m_r, m_t = blurred[..., 1 : 1 + c] / Wd, blurred[..., 1 + c : 1 + 2 * c] / Wd
    var = blurred[..., 1 + 2 * c : 1 + 3 * c] / Wd - m_r * m_r
    cov = blurred[..., 1 + 3 * c :] / Wd - m_r * m_t
    g0 = prior.gain.astype(np.float32)
    gain = np.clip((cov + eps * g0) / (np.maximum(var, 0.0) + eps), *_GAIN_BOUNDS)
    offset = m_t - gain * m_r
    known = (moments[..., 0] > 0) & (W[..., 0] >= _MIN_LOCAL_WEIGHT)
    coarse_domain = cv2.resize(domain.astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0
    fallback = np.concatenate([g0, prior.offset.astype(np.float32)])
    both = membrane_fill(np.concatenate([gain, offset], axis=2), known, coarse_domain, fallback)
    return ColourField(both[..., :c], both[..., c:]).resized(wd, h)


def poisson_field(
    render: np.ndarray,
    target: np.ndarray,
    weights: np.ndarray,
    domain: np.ndarray,
    smooth_px: float,
    prior: ColourGain,
) -> ColourField:
    """Gradient-domain colour correction: ``offset`` is the harmonic interpolant over ``domain`` of
    the target - render difference on the band (gain 1), so ``render + offset`` keeps the render's
    gradients inside the hole and equals the target on the band. With ``smooth_px`` > 0 the
    difference is first averaged (Gaussian, band ``weights``) so misaligned texture does not streak
    into the hole; ``smooth_px`` = 0 is the exact Poisson blend on the band's trusted pixels."""
    r, t = as_unit_float(render), as_unit_float(target)
    diff = t - r
    if smooth_px > 0:
        W = _gauss(weights, smooth_px)
        diff = _gauss(weights[..., None] * diff, smooth_px) / np.maximum(W, 1e-6)[..., None]
        known = (weights > 0) & (W >= _MIN_LOCAL_WEIGHT)
    else:
        known = weights >= 0.5
    # Where no trusted pixel is in reach, the global map's offset at the band's mean intensity.
    fallback = (prior.gain - 1.0) * float(r[weights > 0].mean()) + prior.offset if known.any() else 0.0
    offset = membrane_fill(diff, known, domain, fallback)
    return ColourField(np.ones_like(offset), offset)


@dataclass
class RefineInfo:
    """What refinement did (report fields). Errors are mean absolute RGB differences (8-bit levels)
    between render and target on the trusted band, at the estimation resolution."""

    colour: str = "none"
    flow_applied: bool = False
    flow_trusted_px: int = 0
    flow_median_band_px: float = 0.0
    flow_max_hole_px: float = 0.0
    alpha_lost_px: int = 0
    band_px: int = 0
    band_error_before: float = float("nan")
    band_error_after: float = float("nan")
    estimate_scale: float = 1.0


@dataclass(frozen=True)
class RefinedRender:
    """The refined render at target resolution: ``image`` HxWx3 uint8 (zero where ``alpha`` is
    False), its coverage, the flow-corrected correspondence field and what was done."""

    image: np.ndarray
    alpha: np.ndarray
    render: RenderResult
    info: RefineInfo

    def summary(self) -> str:
        i = self.info
        return (
            f"flow {'applied' if i.flow_applied else 'off'} (band median {i.flow_median_band_px:.2f} px), "
            f"colour {i.colour}: band error {i.band_error_before:.1f} -> {i.band_error_after:.1f}"
        )

    def report(self) -> dict[str, Any]:
        return asdict(self.info)


def _shrink(image: np.ndarray, scale: float) -> np.ndarray:
    if scale >= 1.0:
        return image
    h, w = image.shape[:2]
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def _shrink_mask(mask: np.ndarray, scale: float, *, any_pixel: bool) -> np.ndarray:
    """Downscaled mask: True where any (``any_pixel``) or all of the covered input pixels are."""
    if scale >= 1.0:
        return mask
    area = _shrink(mask.astype(np.float32), scale)
    return area > 0.0 if any_pixel else area > 0.999


def _band_error(render: np.ndarray, target: np.ndarray, band: np.ndarray) -> float:
    if not band.any():
        return float("nan")
    return float(np.abs(render[band].astype(np.float32) - target[band].astype(np.float32)).mean())


def refine_render(
    target: np.ndarray, hole: np.ndarray, source: np.ndarray, render: RenderResult, cfg: RefineConfig
) -> RefinedRender:
    """Align and colour-correct the source render inside the hole (see the module docstring).

    ``target`` (HxWx3 uint8, its hole pixels are never read), ``hole`` (HxW bool), ``source``
    (uint8, the render's texture), ``render`` at target resolution. Fields are estimated on the
    render's window at a long side of at most ``cfg.max_side`` and applied at full resolution."""
    H, W = hole.shape
    rows, cols = render.window()
    scale = min(1.0, cfg.max_side / max(H, W))
    px = max(H, W) / 1280.0 * scale  # config px -> estimation px
    info = RefineInfo(colour=cfg.colour, estimate_scale=scale)
    t_win, hole_win = target[rows, cols], hole[rows, cols]
    hole_e = _shrink_mask(hole_win, scale, any_pixel=True)
    t_e = _shrink(t_win, scale)
    # The hole and the known ring within band_px of it (a distance transform: O(N) for any radius).
    domain = cv2.distanceTransform((~hole_e).astype(np.uint8), cv2.DIST_L2, 3) <= max(1.0, cfg.band_px * px)
    ring = domain & ~hole_e

    def estimate_view(rr: RenderResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        full = rr.sample_window(source)
        return full, _shrink(full, scale), ring & _shrink_mask(rr.alpha[rows, cols], scale, any_pixel=False)

    r_win, r_e, band = estimate_view(render)
    info.band_px = int(band.sum())
    info.band_error_before = _band_error(r_e, t_e, band)
    if cfg.flow and band.any():
        bf = band_flow(
            r_e, t_e, hole_e, band,
            preset=cfg.flow_preset,
            max_px=cfg.flow_max_px * px,
            consistency_px=cfg.flow_consistency_px * px,
        )  # fmt: skip
        if bf is not None:
            h, w = hole_win.shape
            flow = (
                bf.flow
                if scale >= 1.0
                else cv2.resize(bf.flow, (w, h), interpolation=cv2.INTER_LINEAR) / scale
            )
            corrected = _with_flow(render, flow)
            info.flow_applied = True
            info.flow_trusted_px = bf.n_trusted
            info.flow_median_band_px = bf.median_band_px / scale
            info.flow_max_hole_px = (
                float(np.linalg.norm(flow[hole_win], axis=1).max()) if hole_win.any() else 0.0
            )
            info.alpha_lost_px = int(
                (render.alpha[rows, cols] & ~corrected.alpha[rows, cols] & hole_win).sum()
            )
            render = corrected
            r_win, r_e, band = estimate_view(render)
    field = _colour_field(r_e, t_e, band, domain, cfg, px)
    if field is not None:
        refined_e = field.apply(r_e)
        r_win = field.resized(r_win.shape[1], r_win.shape[0]).apply(r_win)
    else:
        refined_e = r_e
    info.band_error_after = _band_error(refined_e, t_e, band)
    r_win[~render.alpha[rows, cols]] = 0
    image = np.zeros_like(target)
    image[rows, cols] = r_win
    return RefinedRender(image, render.alpha, render, info)


def _with_flow(render: RenderResult, flow: np.ndarray) -> RenderResult:
    """``render`` with its correspondence field composed with ``flow`` (the size of its window)."""
    rows, cols = render.window()
    out = RenderResult(
        render.map_x.copy(), render.map_y.copy(), render.depth, render.alpha.copy(), render.roi
    )
    mx, my, alpha = compose_maps(
        render.map_x[rows, cols], render.map_y[rows, cols], render.alpha[rows, cols], flow
    )
    out.map_x[rows, cols], out.map_y[rows, cols], out.alpha[rows, cols] = mx, my, alpha
    return out


def _colour_field(
    render: np.ndarray, target: np.ndarray, band: np.ndarray, domain: np.ndarray, cfg: RefineConfig, px: float
) -> ColourField | None:
    """The configured colour model fitted at the estimation resolution (None for "none")."""
    if cfg.colour == "none":
        return None
    prior = fit_colour_gain(render, target, band, max_samples=_PRIOR_SAMPLES)
    shape = band.shape
    if cfg.colour == "global" or prior.n_samples < MIN_COLOUR_SAMPLES:
        return ColourField.constant(prior, shape)
    weights = robust_band_weights(render, target, band, prior)
    if cfg.colour == "gain":
        return smooth_gain_field(
            render, target, weights, domain, max(cfg.gain_sigma_px * px, 1.0), prior, cfg.gain_eps
        )
    return poisson_field(render, target, weights, domain, cfg.poisson_smooth_px * px, prior)
