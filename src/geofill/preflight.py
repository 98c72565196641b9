"""Checks of a fill's configured files and models, run before any work.

The pipeline reaches the depth stage only on pairs that do not fall back earlier, so a bad
``--depth-file`` or a learned depth model without weights would otherwise be refused on easy pairs
and ignored on hard ones. :func:`check_resources` refuses them up front, whatever the pair: the
CLI calls it after reading the inputs, and the Python API can call it before :func:`geofill.fill`."""

from __future__ import annotations

import numpy as np

from .composite.inpaint import get_inpainter
from .config import FillConfig
from .depth import choose_backend
from .errors import ConfigError, DepthFileError, DepthModelError
from .extras import require
from .io import read_depth_file


def check_resources(cfg: FillConfig, source_size: tuple[int, int]) -> None:
    """Raise the error the fill would meet later for a depth file, a learned depth model, a LaMa
    model or a learned matcher that the configuration asks for and that cannot be used. ``source_size`` is the
    (width, height) of the source image a depth file must match.

    Raises ConfigError (``file`` backend without a path), MissingExtraError, DepthFileError,
    DepthModelError, InpaintModelError, MatcherModelError."""
    depth = cfg.depth
    if depth.backend == "file":
        if not depth.file_path:
            raise ConfigError("depth backend 'file' needs a depth file (--depth-file PATH)")
        values = read_depth_file(depth.file_path, expected_size=source_size, scale=depth.file_scale)
        if not np.isfinite(values).any():
            raise DepthFileError(f"{depth.file_path}: no valid depth value (all zero or non-finite)")
    if depth.backend in ("onnx", "fused"):
        from .depth.onnx import resolve_model
        from .weights import WeightsUnavailable

        require("onnxruntime", f"depth backend '{depth.backend}'")
        weights = resolve_model(depth)
        if isinstance(weights, WeightsUnavailable):
            raise DepthModelError(f"depth backend '{depth.backend}': {weights}")
    elif depth.backend == "auto":
        choose_backend(depth)  # raises for an explicit model path that cannot be used
    get_inpainter(cfg.inpaint)  # raises for LaMa asked for and not usable; loads it once for the fill
    if cfg.matching.learned == "on" or cfg.matching.learned_model:
        from .match.learned import learned_matcher

        learned_matcher(cfg.matching)  # raises for a required learned matcher that cannot be used
