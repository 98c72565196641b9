"""Image-quality metrics of the evaluation: PSNR, SSIM (whole image and hole only), LPIPS from a
user-supplied local model file, and the removal protocols' leak (:func:`leak`: how much of an
object the output reproduces).

Whole-image scores follow the inpainting papers' convention (the filled image against the original
target, every pixel counted, data range 255). Hole-only scores count the hole's pixels only, which
is what separates methods: outside the hole every method returns the target unchanged.

SSIM uses the reference settings of Wang et al. (2004): 11x11 Gaussian window with sigma 1.5,
population statistics, K1 = 0.01, K2 = 0.03 (scikit-image's ``gaussian_weights=True,
use_sample_covariance=False``), computed per RGB channel and averaged.

LPIPS (Zhang et al., 2018) needs pretrained network weights, which geofill does not ship and cannot
download. Point ``GEOFILL_LPIPS_MODEL`` (or ``--lpips-model``) at a local LPIPS model file: ONNX
(``.onnx``), a ``torch.export`` program (``.pt2``) or TorchScript (``.pt``/``.pth``/``.ts``,
deprecated by PyTorch but still loaded). It must take two 1x3xHxW float32 RGB images in [-1, 1]
(the ``lpips`` package's convention with ``normalize=False``) and return the distance (its mean is
taken). One way to make such a file on a machine with the ``lpips`` package (not tried here, where
no weights exist; export with two *different* example images and dynamic H, W)::

    import lpips, torch
    net = lpips.LPIPS(net="alex").eval()
    x, y = torch.rand(2, 1, 3, 256, 256) * 2 - 1
    H, W = torch.export.Dim("H", min=32, max=4096), torch.export.Dim("W", min=32, max=4096)
    program = torch.export.export(net, (x, y), dynamic_shapes=({2: H, 3: W}, {2: H, 3: W}))
    torch.export.save(program, "lpips_alex.pt2")

Without a model, LPIPS is reported as ``unavailable: <reason>``, never silently left out.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from ..extras import require

#: Data range of uint8 images.
DATA_RANGE = 255.0
#: Environment variable naming the local LPIPS model file.
LPIPS_ENV = "GEOFILL_LPIPS_MODEL"
_TORCHSCRIPT_SUFFIXES = (".pt", ".pth", ".ts")
_EXPORT_SUFFIX = ".pt2"
_SSIM_SETTINGS = {"gaussian_weights": True, "sigma": 1.5, "use_sample_covariance": False}


def _check(a: np.ndarray, b: np.ndarray, region: np.ndarray | None) -> None:
    if a.shape != b.shape:
        raise ValueError(f"images differ in shape: {a.shape} vs {b.shape}")
    if a.dtype != np.uint8 or b.dtype != np.uint8:
        raise ValueError(f"metrics expect uint8 images, got {a.dtype} and {b.dtype}")
    if region is not None:
        if region.shape != a.shape[:2] or region.dtype != bool:
            raise ValueError(
                f"region must be a bool mask of shape {a.shape[:2]}, got {region.dtype} {region.shape}"
            )
        if not region.any():
            raise ValueError("region is empty")


def psnr(a: np.ndarray, b: np.ndarray, region: np.ndarray | None = None) -> float:
    """PSNR (dB) of uint8 images ``a`` vs. ``b`` over all pixels and channels, or over the pixels
    where the HxW bool ``region`` is True. ``inf`` when they are identical there."""
    _check(a, b, region)
    if region is not None:
        a, b = a[region], b[region]
    if np.array_equal(a, b):
        return float("inf")
    return float(peak_signal_noise_ratio(a, b, data_range=DATA_RANGE))


def ssim(a: np.ndarray, b: np.ndarray, region: np.ndarray | None = None) -> float:
    """SSIM of uint8 images (HxWx3 or HxW). Whole image: scikit-image's mean SSIM (the papers'
    convention); with an HxW bool ``region``: the mean of the SSIM map over the region's pixels
    (each pixel's SSIM still sees its 11x11 neighbourhood, hole or not)."""
    _check(a, b, region)
    channel_axis = -1 if a.ndim == 3 else None
    mean_ssim, ssim_map = structural_similarity(
        a, b, data_range=DATA_RANGE, channel_axis=channel_axis, full=True, **_SSIM_SETTINGS
    )
    if region is None:
        return float(mean_ssim)
    return float(ssim_map[region].mean())


class LpipsUnavailable(RuntimeError):
    """No usable LPIPS model; the message is the reason shown in the outputs."""


@dataclass
class LpipsScorer:
    """LPIPS distance from a local TorchScript or ONNX model (lower is better)."""

    path: Path
    backend: str  # "onnx" | "torch.export" | "torchscript"
    _model: object

    def __call__(self, a: np.ndarray, b: np.ndarray) -> float:
        """LPIPS distance between two HxWx3 uint8 RGB images of the same size."""
        _check(a, b, None)
        if a.ndim != 3 or a.shape[2] != 3:
            raise ValueError(f"LPIPS needs HxWx3 RGB images, got shape {a.shape}")
        x, y = _to_lpips_input(a), _to_lpips_input(b)
        if self.backend == "onnx":
            names = [i.name for i in self._model.get_inputs()]
            out = self._model.run(None, {names[0]: x, names[1]: y})[0]
            return float(np.mean(out))
        import torch

        with torch.inference_mode():
            out = self._model(torch.from_numpy(x), torch.from_numpy(y))
        return float(out.float().mean())


def _to_lpips_input(image: np.ndarray) -> np.ndarray:
    """HxWx3 uint8 -> 1x3xHxW float32 in [-1, 1]."""
    return np.ascontiguousarray((image.astype(np.float32) / 127.5 - 1.0).transpose(2, 0, 1)[None])


def lpips_model_path(path: str | os.PathLike | None = None) -> Path | None:
    """The LPIPS model file to use: ``path`` if given, else ``$GEOFILL_LPIPS_MODEL``, else None."""
    chosen = path if path is not None else os.environ.get(LPIPS_ENV) or None
    return Path(chosen) if chosen is not None else None


def load_lpips(path: str | os.PathLike | None = None) -> LpipsScorer:
    """Load the LPIPS model (see :func:`lpips_model_path`); :class:`LpipsUnavailable` with the reason
    when there is none or it cannot be loaded."""
    model_path = lpips_model_path(path)
    if model_path is None:
        raise LpipsUnavailable(
            f"no LPIPS model (set {LPIPS_ENV} or --lpips-model to a local LPIPS model file, "
            ".onnx/.pt2/.pt; geofill ships no weights)"
        )
    if not model_path.is_file():
        raise LpipsUnavailable(f"LPIPS model file not found: {model_path}")
    suffix = model_path.suffix.lower()
    try:
        if suffix == ".onnx":
            import onnxruntime

            session = onnxruntime.InferenceSession(str(model_path), providers=["CPUExecutionProvider"])
            if len(session.get_inputs()) != 2:
                raise LpipsUnavailable(f"LPIPS ONNX model {model_path} must take 2 inputs")
            return LpipsScorer(model_path, "onnx", session)
        if suffix in (_EXPORT_SUFFIX, *_TORCHSCRIPT_SUFFIXES):
            torch = require("torch", f"an LPIPS model saved with torch ({suffix})")
        if suffix == _EXPORT_SUFFIX:
            return LpipsScorer(model_path, "torch.export", torch.export.load(str(model_path)).module())
        if suffix in _TORCHSCRIPT_SUFFIXES:
            with warnings.catch_warnings():
                # The user chose the format; PyTorch's deprecation notice is not theirs to act on here.
                warnings.simplefilter("ignore", DeprecationWarning)
                model = torch.jit.load(str(model_path), map_location="cpu")
            return LpipsScorer(model_path, "torchscript", model)
    except LpipsUnavailable:
        raise
    except Exception as exc:  # any loader failure is a reason to report, not a crash
        raise LpipsUnavailable(f"cannot load LPIPS model {model_path}: {type(exc).__name__}: {exc}") from exc
    raise LpipsUnavailable(
        f"LPIPS model {model_path}: unknown format '{suffix}' (want .onnx, .pt2 or .pt/.pth/.ts)"
    )


def lpips_available(path: str | os.PathLike | None = None) -> tuple[bool, str]:
    """(True, description) when an LPIPS model loads, else (False, reason)."""
    try:
        scorer = load_lpips(path)
    except LpipsUnavailable as exc:
        return False, str(exc)
    return True, f"{scorer.backend} model {scorer.path}"


#: Leak: an object pixel is *distinguishable* where it differs from the truth by more than this
#: (Euclidean distance over RGB, 0-255) ...
LEAK_MIN_CONTRAST = 30.0
#: ... and *reproduced* where the output's distance to it is under this fraction of the output's
#: distance to the truth.
LEAK_RATIO = 0.5


@dataclass(frozen=True)
class Leak:
    """How much of an object an output reproduces: ``fraction`` = ``leaked`` / ``distinguishable``
    (None when no pixel is distinguishable)."""

    fraction: float | None
    leaked: int
    distinguishable: int


def leak_masks(
    output: np.ndarray,
    truth: np.ndarray,
    objects: Sequence[tuple[np.ndarray, np.ndarray]],
    region: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """HxW bool (leaked, distinguishable): the pixels of ``region`` where ``output`` reproduces one
    of ``objects`` and where one is distinguishable from ``truth``, by :func:`leak`'s rule."""
    _check(output, truth, region)
    out, tru = output[region], truth[region]
    d_true = _rgb_distance(out, tru)
    distinguishable = np.zeros(len(out), bool)
    leaked = np.zeros(len(out), bool)
    for image, mask in objects:
        _check(image, truth, None)
        obj = image[region]
        there = mask[region] & (_rgb_distance(obj, tru) > LEAK_MIN_CONTRAST)
        distinguishable |= there
        leaked |= there & (_rgb_distance(out, obj) < LEAK_RATIO * d_true)
    full_leaked, full_distinguishable = np.zeros(region.shape, bool), np.zeros(region.shape, bool)
    full_leaked[region], full_distinguishable[region] = leaked, distinguishable
    return full_leaked, full_distinguishable


def _rgb_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a.astype(np.float32) - b.astype(np.float32), axis=-1)


def leak(
    output: np.ndarray,
    truth: np.ndarray,
    objects: Sequence[tuple[np.ndarray, np.ndarray]],
    region: np.ndarray,
) -> Leak:
    """The fraction of ``region``'s pixels (the hole) where ``output`` reproduces an object.

    ``objects``: (HxWx3 uint8 image, HxW bool where it holds an object pixel) in the target's
    frame. Per pixel p and object k (where its mask holds), with Euclidean RGB distances
    (0-255): p is *distinguishable* for k when ``|obj_k - truth| > 30`` and *leaked* for k when
    it is distinguishable and ``|out - obj_k| < 0.5 |out - truth|``. A pixel counts as
    distinguishable / leaked when it is for any object; the fraction is over the distinguishable
    pixels only.

    >>> truth = np.zeros((1, 4, 3), np.uint8)
    >>> obj = np.full((1, 4, 3), 200, np.uint8)
    >>> out = np.array([[[200] * 3, [190] * 3, [20] * 3, [0] * 3]], np.uint8)
    >>> leak(out, truth, [(obj, np.ones((1, 4), bool))], np.ones((1, 4), bool))
    Leak(fraction=0.5, leaked=2, distinguishable=4)
    """
    leaked, distinguishable = leak_masks(output, truth, objects, region)
    n = int(distinguishable.sum())
    return Leak(float(leaked.sum()) / n if n else None, int(leaked.sum()), n)


#: Ghost: the working scale's long side (px; larger images are shrunk with INTER_AREA).
GHOST_WORK_SIDE = 640
#: A copy of an object is a set of SIFT matches from the output around the hole to one view's object
#: pixels (Lowe's ratio test against that object's features and the truth's own together, so that
#: background a method copied rightly never counts) that one similarity transform (shift, rotation,
#: scale: a fragment pasted elsewhere, nearer or farther) explains within GHOST_RANSAC_PX, with at
#: least GHOST_MIN_MATCHES of them.
GHOST_LOWE_RATIO = 0.8
GHOST_RANSAC_PX = 3.0
GHOST_MIN_MATCHES = 3
#: Copies looked for per view (each found copy's matches are taken out before the next search).
GHOST_MAX_COPIES = 3
#: With the view mapped by that transform, a hole pixel is the copy's where the output (blurred by
#: GHOST_BLUR_PX, as a resampled copy is) differs from the truth's by more than GHOST_MIN_CHANGE
#: (RMS over RGB, 0-255) and is nearer the mapped object than :data:`LEAK_RATIO` times that. Three
#: matches can agree by chance: a copy counts only where GHOST_MIN_AREA px (working scale) confirm it.
GHOST_BLUR_PX = 1.0
GHOST_MIN_CHANGE = 12.0
GHOST_MIN_AREA = 30


@dataclass(frozen=True)
class Ghost:
    """How much of the hole an output fills with an object's look, wherever the object was:
    ``fraction`` = ghost pixels / hole pixels at the working scale; ``mask`` the ghost pixels at
    full size (HxW bool)."""

    fraction: float
    ghost_px: int
    hole_px: int
    mask: np.ndarray


def _shrunk(image: np.ndarray, factor: float) -> np.ndarray:
    if factor == 1.0:
        return image
    h, w = image.shape[:2]
    size = (max(1, round(w * factor)), max(1, round(h * factor)))
    interp = cv2.INTER_AREA if factor < 1.0 else cv2.INTER_LINEAR
    return cv2.resize(image, size, interpolation=interp)


def _sift(image: np.ndarray, where: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints ((N, 2) x, y) and descriptors ((N, 128) float32) of ``image`` (HxWx3 uint8
    RGB) inside ``where`` (HxW bool).

    Plain SIFT descriptors, not the matcher's RootSIFT (``match.features.detect_sift``): with
    RootSIFT the ghost found less of the copies a person sees (walker_crowd, seed 0, living room:
    the homography's pasted passer-by 0.079 -> 0.058 of the hole, geofill's red and blue fragments
    with all references 0.023 -> 0)."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    keypoints, desc = cv2.SIFT_create().detectAndCompute(grey, where.astype(np.uint8) * 255)
    pts = np.float32([k.pt for k in keypoints]).reshape(-1, 2)
    return pts, desc if desc is not None else np.zeros((0, 128), np.float32)


def _blurred(image: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(image.astype(np.float32), (0, 0), GHOST_BLUR_PX)


def ghost(
    output: np.ndarray,
    truth: np.ndarray,
    hole: np.ndarray,
    appearances: Sequence[tuple[np.ndarray, np.ndarray]],
) -> Ghost:
    """The share of the hole where ``output`` shows an object (or a passer-by) *anywhere*, shifted,
    rotated or rescaled, rather than the true background.

    ``appearances``: (HxWx3 uint8 view, HxW bool object pixels in it) for every view that shows an
    object (the target as the methods get it, each reference). At a long side of
    :data:`GHOST_WORK_SIDE`, the output's SIFT features around the hole are matched to each view's
    object features; matches one similarity transform explains locate a copy (see the module's
    ``GHOST_*`` constants); the copy's pixels are the hole pixels, inside the mapped object, where
    the output is at least twice as near the mapped object as the truth. A copy keeps the
    object's texture, so SIFT finds it however a method warped, resampled or recoloured it; a
    smear of the surroundings has no features that match. Flat parts of a one-colour object are
    found only where they lie between matched edges and corners, and a fragment too small to hold
    three features is not found: the leak (:func:`leak`) counts an object put back in place.
    The truth scores 0.

    >>> rng = np.random.default_rng(0)
    >>> truth = rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)
    >>> hole = np.zeros((64, 64), bool); hole[16:48, 16:48] = True
    >>> ghost(truth, truth, hole, []).fraction
    0.0
    """
    _check(output, truth, hole)
    h, w = hole.shape
    factor = min(1.0, GHOST_WORK_SIDE / max(h, w))
    out, small_hole = _shrunk(output, factor), _shrunk(hole.astype(np.float32), factor) >= 0.5
    size = small_hole.shape[::-1]
    around = cv2.dilate(small_hole.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    found = np.zeros(small_hole.shape, bool)
    tru, blurred_out = _shrunk(truth, factor), _blurred(out)
    d_true = np.sqrt(np.mean((blurred_out - _blurred(tru)) ** 2, axis=2))
    changed = small_hole & (d_true > GHOST_MIN_CHANGE)
    out_pts, out_desc = _sift(out, around) if changed.any() and appearances else ((), ())
    if len(out_pts) >= GHOST_MIN_MATCHES:
        _, truth_desc = _sift(tru, around)
        for view, mask in appearances:
            small_view = _shrunk(view, factor)
            on = _shrunk(mask.astype(np.float32), factor) >= 0.5
            grown = cv2.dilate(on.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
            obj_pts, obj_desc = _sift(small_view, grown)
            if len(obj_pts) < GHOST_MIN_MATCHES:
                continue
            library = np.concatenate([obj_desc, truth_desc])
            src, dst = [], []
            for pair in cv2.BFMatcher(cv2.NORM_L2).knnMatch(out_desc, library, k=2):
                if len(pair) == 2 and pair[0].distance < GHOST_LOWE_RATIO * pair[1].distance:
                    if pair[0].trainIdx < len(obj_desc):  # nearest to the object, not the truth
                        src.append(obj_pts[pair[0].trainIdx])
                        dst.append(out_pts[pair[0].queryIdx])
            src, dst = np.float32(src).reshape(-1, 2), np.float32(dst).reshape(-1, 2)
            for _ in range(GHOST_MAX_COPIES):
                if len(src) < GHOST_MIN_MATCHES:
                    break
                A, inliers = cv2.estimateAffinePartial2D(src, dst, ransacReprojThreshold=GHOST_RANSAC_PX)
                if A is None or inliers.sum() < GHOST_MIN_MATCHES:
                    break
                mapped = cv2.warpAffine(small_view, A, size)
                inside = cv2.warpAffine(on.astype(np.uint8), A, size, flags=cv2.INTER_NEAREST) > 0
                d_obj = np.sqrt(np.mean((blurred_out - _blurred(mapped)) ** 2, axis=2))
                copy = changed & inside & (d_obj < LEAK_RATIO * d_true)
                if copy.sum() >= GHOST_MIN_AREA:
                    found |= copy
                keep = ~inliers.ravel().astype(bool)
                src, dst = src[keep], dst[keep]
    full = cv2.resize(found.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool) & hole
    n = int(small_hole.sum())
    return Ghost(float(found.sum() / n) if n else 0.0, int(found.sum()), n, full)
