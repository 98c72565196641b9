"""Single-image inpainting for hole pixels the source cannot supply (and whole holes on fallback).

``telea``/``ns``: OpenCV's fast-marching and Navier-Stokes inpainting (no weights; the default when
no LaMa model is found). ``lama``: LaMa through ONNX Runtime (:mod:`geofill.lama`), which needs a
model file; ``auto``: LaMa when its model resolves, else Telea, and the report says which and why.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .config import InpaintConfig
from .errors import ConfigError

_METHODS = {"telea": cv2.INPAINT_TELEA, "ns": cv2.INPAINT_NS}
#: Environment variable holding the path of a LaMa ONNX model (after ``inpaint.lama_model``).
LAMA_ENV_VAR = "GEOFILL_LAMA_MODEL"
#: Loaded LaMa sessions by resolved path: loading a 200 MB model costs seconds, every fill reuses it.
_LAMA_CACHE: dict[Path, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {}


@dataclass(frozen=True)
class Inpainter:
    """A resolved single-image inpainter: ``run(image HxWx3 uint8, region HxW bool)`` returns the
    image with ``region`` filled; ``description`` says which method and why (for the report)."""

    name: str
    description: str
    run: Callable[[np.ndarray, np.ndarray], np.ndarray]


def resolve_lama_model(cfg: InpaintConfig) -> Path | str:
    """The LaMa model file: ``cfg.lama_model``, then ``$GEOFILL_LAMA_MODEL``; or why there is none."""
    for where, given in (
        ("inpaint.lama_model", cfg.lama_model),
        (f"${LAMA_ENV_VAR}", os.environ.get(LAMA_ENV_VAR)),
    ):
        if given:
            path = Path(given).expanduser()
            return path if path.is_file() else f"{where} {path} is not a file"
    return f"no LaMa model given (inpaint.lama_model or ${LAMA_ENV_VAR}; geofill ships no weights)"


def _opencv(method: str, radius_px: float) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    def run(image: np.ndarray, region: np.ndarray) -> np.ndarray:
        # Only pixels within the radius of the region are ever read: inpaint that window (at 4K,
        # cv2.inpaint's full-size work buffers would cost seconds).
        ys, xs = np.nonzero(region)
        pad = int(np.ceil(radius_px)) + 2
        y0, y1 = max(int(ys.min()) - pad, 0), min(int(ys.max()) + pad + 1, region.shape[0])
        x0, x1 = max(int(xs.min()) - pad, 0), min(int(xs.max()) + pad + 1, region.shape[1])
        out = image.copy()
        window = np.ascontiguousarray(image[y0:y1, x0:x1])
        out[y0:y1, x0:x1] = cv2.inpaint(
            window, region[y0:y1, x0:x1].astype(np.uint8), radius_px, _METHODS[method]
        )
        return out

    return run


def _lama(path: Path) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    key = path.resolve()
    if key not in _LAMA_CACHE:
        from .lama import LamaOnnx

        _LAMA_CACHE[key] = LamaOnnx(key)
    return _LAMA_CACHE[key]


def get_inpainter(cfg: InpaintConfig) -> Inpainter:
    """The inpainter ``cfg`` asks for. ``lama`` without a usable model is a :class:`ConfigError`;
    ``auto`` then falls back to Telea and says so."""
    if cfg.method in _METHODS:
        return Inpainter(cfg.method, cfg.method, _opencv(cfg.method, cfg.radius_px))
    found = resolve_lama_model(cfg)
    problem = found if isinstance(found, str) else None
    if problem is None:
        try:
            return Inpainter("lama", f"lama ({found})", _lama(found))
        except Exception as exc:  # onnxruntime raises its own types for unreadable/invalid models
            problem = f"LaMa model {found} could not be loaded: {type(exc).__name__}: {exc}".replace(
                "\n", " "
            )
    if cfg.method == "lama":
        raise ConfigError(f"inpaint.method is 'lama' but {problem}")
    return Inpainter("telea", f"telea (auto: {problem})", _opencv("telea", cfg.radius_px))


def inpaint_single(image: np.ndarray, hole: np.ndarray, cfg: InpaintConfig) -> np.ndarray:
    """Fill ``hole`` (bool) of an HxWx3 uint8 image from its surroundings; other pixels unchanged."""
    if not hole.any():
        return image.copy()
    out = get_inpainter(cfg).run(image, hole)
    np.copyto(out, image, where=~hole[..., None])
    return out
