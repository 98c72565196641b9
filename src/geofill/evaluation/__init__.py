"""Evaluation protocol of the GeoFill paper: brush-stroke holes (masks), baselines, metrics, the
methods registry, pairs, the runner and its tables and figures; and the object-removal protocols
(:mod:`.removal`: ``static``, ``solid``, ``solid_plain``, ``strangers``, ``walker``,
``walker_crowd``; objects in :mod:`.cutouts` and :mod:`.solids`) with their leak and ghost
metrics.

``geofill eval`` is :func:`geofill.evaluation.cli.main_eval`; pipelines plug in with
:func:`register_method`."""

from .baselines import BaselineError, homography_fill, opencv_inpaint
from .masks import brush_stroke_mask, brush_strokes, mask_seed
from .methods import METHODS, MethodOutput, register_method
from .metrics import Ghost, Leak, ghost, leak, lpips_available, psnr, ssim
from .pairs import Pair, PairExif, load_pairs
from .removal import PROTOCOLS, RemovalCase, make_case
from .runner import run_eval, sweep
from .tables import EvalRow

__all__ = [
    "METHODS",
    "PROTOCOLS",
    "BaselineError",
    "EvalRow",
    "Ghost",
    "Leak",
    "MethodOutput",
    "Pair",
    "PairExif",
    "RemovalCase",
    "brush_stroke_mask",
    "brush_strokes",
    "ghost",
    "homography_fill",
    "leak",
    "load_pairs",
    "lpips_available",
    "make_case",
    "mask_seed",
    "opencv_inpaint",
    "psnr",
    "register_method",
    "run_eval",
    "ssim",
    "sweep",
]
