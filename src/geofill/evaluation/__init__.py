"""Evaluation protocol of the GeoFill paper: brush-stroke holes (masks), baselines, metrics, the
methods registry, pairs, the runner and its tables and figures.

``geofill eval`` is :func:`geofill.evaluation.cli.main_eval`; pipelines plug in with
:func:`register_method`."""

from .baselines import BaselineError, homography_fill, opencv_inpaint
from .masks import brush_stroke_mask, brush_strokes, mask_seed
from .methods import METHODS, MethodOutput, register_method
from .metrics import lpips_available, psnr, ssim
from .pairs import Pair, PairExif, load_pairs
from .runner import run_eval, sweep
from .tables import EvalRow

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
