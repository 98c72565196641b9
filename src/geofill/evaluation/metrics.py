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


#: Ghost: the working scale's long side (px; larger images are shrunk with INTER_AREA), the patch
#: side compared there, the scales at which the objects' patches are offered (a fragment pasted
#: nearer or farther), and the most object patches kept (a regular subsample beyond).
GHOST_WORK_SIDE = 480
GHOST_PATCH = 7
GHOST_SCALES = (0.7, 1.0, 1.4)
GHOST_MAX_PATCHES = 60_000
#: A hole pixel is *changed* where the output's patch is this far (RMS over the patch, 0-255) from
#: the truth's, and a *ghost* where it is also nearer to some object patch than
#: :data:`LEAK_RATIO` times its distance to the truth's.
GHOST_MIN_CHANGE = 12.0
#: Only output patches with structure count (RMS about the patch's mean per channel, 0-255): a
#: smooth smear of the surroundings comes within a few levels of the smooth parts of many objects
#: (a plain face, a photo's blurred background) and was flagged as often as real copies; a copied
#: fragment keeps its edges and texture. A one-colour object's copy is thus counted along its
#: outline and shading edges, not across its flat inside.
GHOST_MIN_TEXTURE = 6.0
#: ... and nearer to that object patch than this (RMS, 0-255): a copy keeps the object's colours
#: (resampled, colour-corrected), a smear of the surroundings only comes near them.
GHOST_MAX_DISTANCE = 8.0
#: A copy's brightness may differ from the object's by this factor either way (a method's colour
#: correction): an object patch is compared with the output's at its best gain within it.
GHOST_GAIN = 1.3
#: Object patches are compared in this many principal components (then exactly, on the nearest few).
_GHOST_COMPONENTS = 16
_GHOST_CANDIDATES = 8


@dataclass(frozen=True)
class Ghost:
    """How much of the hole an output fills with an object's look, wherever the object was:
    ``fraction`` = ghost pixels / hole pixels at the working scale; ``mask`` the ghost pixels at
    full size (HxW bool)."""

    fraction: float
    ghost_px: int
    hole_px: int
    mask: np.ndarray


def _patches(image: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """(N, P*P*3) float32 patches of ``image`` (HxWx3, edge-replicated) around (N, 2) (y, x)."""
    r = GHOST_PATCH // 2
    padded = np.pad(image.astype(np.float32), ((r, r), (r, r), (0, 0)), mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, (GHOST_PATCH, GHOST_PATCH), axis=(0, 1))
    return windows[centres[:, 0], centres[:, 1]].reshape(len(centres), -1)


def _shrunk(image: np.ndarray, factor: float) -> np.ndarray:
    if factor == 1.0:
        return image
    h, w = image.shape[:2]
    size = (max(1, round(w * factor)), max(1, round(h * factor)))
    interp = cv2.INTER_AREA if factor < 1.0 else cv2.INTER_LINEAR
    return cv2.resize(image, size, interpolation=interp)


def ghost(
    output: np.ndarray,
    truth: np.ndarray,
    hole: np.ndarray,
    appearances: Sequence[tuple[np.ndarray, np.ndarray]],
) -> Ghost:
    """The share of the hole where ``output`` shows an object (or a passer-by) *anywhere*, shifted
    or rescaled, rather than the true background.

    ``appearances``: (HxWx3 uint8 view, HxW bool object pixels in it) for every view that shows an
    object (the target as the methods get it, each reference). Everything is shrunk to a long
    side of :data:`GHOST_WORK_SIDE`; the object library holds the :data:`GHOST_PATCH`-px patches
    centred on the object pixels of every view, each view also rescaled by :data:`GHOST_SCALES`.
    For each hole pixel p: ``d_true`` = RMS distance between the output's and the truth's patches
    at p, ``d_obj`` = RMS distance of the output's patch to its nearest library patch (searched
    by direction in the library's first principal components, the best few candidates compared
    exactly, each at its best brightness gain within :data:`GHOST_GAIN`).
    p is a *ghost* when ``d_true > GHOST_MIN_CHANGE``, the output's patch has structure (RMS about
    its mean >= :data:`GHOST_MIN_TEXTURE`), ``d_obj < GHOST_MAX_DISTANCE`` and ``d_obj <
    LEAK_RATIO * d_true``: the output differs from the truth there and looks at least twice as
    much like some piece of an object as like the background. The truth scores 0; a textured copy
    of the object anywhere in the hole scores its share of the hole.
    """
    _check(output, truth, hole)
    h, w = hole.shape
    centres, small_shape, d_true, d_obj = ghost_distances(output, truth, hole, appearances)
    is_ghost = (d_obj < LEAK_RATIO * d_true) & (d_obj < GHOST_MAX_DISTANCE)
    small = np.zeros(small_shape, np.uint8)
    small[centres[is_ghost, 0], centres[is_ghost, 1]] = 1
    full = cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST).astype(bool) & hole
    n = len(centres)
    return Ghost(float(is_ghost.mean()) if n else 0.0, int(is_ghost.sum()), n, full)


def ghost_distances(
    output: np.ndarray,
    truth: np.ndarray,
    hole: np.ndarray,
    appearances: Sequence[tuple[np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, tuple[int, int], np.ndarray, np.ndarray]:
    """:func:`ghost`'s measurements: the hole pixels at the working scale ((N, 2) (y, x)), that
    scale's (h, w), and per pixel ``d_true`` and ``d_obj`` (inf where the output is within
    :data:`GHOST_MIN_CHANGE` of the truth, flat, or no object shows anywhere)."""
    from scipy.spatial import cKDTree

    h, w = hole.shape
    factor = min(1.0, GHOST_WORK_SIDE / max(h, w))
    out, tru = _shrunk(output, factor), _shrunk(truth, factor)
    small_hole = _shrunk(hole.astype(np.float32), factor) >= 0.5
    centres = np.argwhere(small_hole)
    d_obj = np.full(len(centres), np.inf)
    library = []
    for view, mask in appearances:
        for scale in GHOST_SCALES:
            f = factor * scale
            on = _shrunk(mask.astype(np.float32), f) >= 0.5
            if on.any():
                library.append(_patches(_shrunk(view, f), np.argwhere(on)))
    queries = _patches(out, centres)
    d_true = np.sqrt(np.mean((queries - _patches(tru, centres)) ** 2, axis=1))
    per_channel = queries.reshape(len(queries), 3, -1)
    texture = np.sqrt(np.mean((per_channel - per_channel.mean(axis=2, keepdims=True)) ** 2, axis=(1, 2)))
    changed = (d_true > GHOST_MIN_CHANGE) & (texture >= GHOST_MIN_TEXTURE)
    if not library or not changed.any():
        return centres, small_hole.shape, d_true, d_obj
    lib = np.concatenate(library)
    if len(lib) > GHOST_MAX_PATCHES:
        lib = lib[np.linspace(0, len(lib) - 1, GHOST_MAX_PATCHES).astype(int)]
    # Searched by direction (patches scaled to unit length), so that a copy whose brightness a
    # method corrected is still found; compared with the best gain within GHOST_GAIN.
    unit_lib = lib / (np.linalg.norm(lib, axis=1, keepdims=True) + 1e-6)
    mean = unit_lib.mean(axis=0)
    n_comp = min(_GHOST_COMPONENTS, lib.shape[1], len(lib))
    _, _, vt = np.linalg.svd(unit_lib[:: max(1, len(lib) // 5000)] - mean, full_matrices=False)
    basis = vt[:n_comp].T
    tree = cKDTree((unit_lib - mean) @ basis)
    q = queries[changed]
    k = min(_GHOST_CANDIDATES, len(lib))
    unit_q = q / (np.linalg.norm(q, axis=1, keepdims=True) + 1e-6)
    _, idx = tree.query((unit_q - mean) @ basis, k=k)
    cand = lib[idx.reshape(len(q), k)]
    gain = np.einsum("nkd,nd->nk", cand, q) / (np.einsum("nkd,nkd->nk", cand, cand) + 1e-6)
    gain = np.clip(gain, 1.0 / GHOST_GAIN, GHOST_GAIN)
    d_obj[changed] = np.sqrt(np.mean((gain[..., None] * cand - q[:, None, :]) ** 2, axis=2)).min(axis=1)
    return centres, small_hole.shape, d_true, d_obj
