"""Evaluation protocol of the GeoFill paper: brush-stroke holes, baselines, metrics, runner.

``geofill eval`` is :func:`geofill.evaluation.cli.main_eval`; pipelines plug in with
:func:`register_method`."""

from .baselines import BaselineError, homography_fill, opencv_inpaint
from .masks import brush_stroke_mask, brush_strokes, mask_seed
from .metrics import lpips_available, psnr, ssim
from .runner import (
    METHODS,
    EvalRow,
    MethodOutput,
    Pair,
    PairExif,
    load_pairs,
    register_method,
    run_eval,
    sweep,
)

__all__ = [
    "METHODS",
    "BaselineError",
    "EvalRow",
    "MethodOutput",
    "Pair",
    "PairExif",
    "brush_stroke_mask",
    "brush_strokes",
    "homography_fill",
    "load_pairs",
    "lpips_available",
    "mask_seed",
    "opencv_inpaint",
    "psnr",
    "register_method",
    "run_eval",
    "ssim",
    "sweep",
]
