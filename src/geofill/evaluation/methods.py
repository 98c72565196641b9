"""Evaluation methods by name: the registry, the baselines and geofill (with each preset).

A method is any ``(target, hole, sources, exif) -> MethodOutput`` callable registered under a name
(``sources``: the reference images offered, primary first; single-reference methods use the first);
the target it receives has its hole pixels zeroed, so no method can see the ground truth, and
``exif`` holds the images' EXIF lens data (what the CLI would read from the same files). Its output
is composited (its pixels inside the hole, the target's outside) before scoring, as in the papers.
A method that raises is recorded with its error and the run goes on."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..composite.inpaint import inpaint_single
from ..config import PRESETS, FillConfig, InpaintConfig
from ..errors import ConfigError
from .baselines import homography_fill_detailed, opencv_inpaint
from .pairs import PairExif


@dataclass
class MethodOutput:
    """What a method returns: the filled target (HxWx3 uint8), per-stage seconds, and optional
    scalar diagnostics (written as JSON in the results' ``info`` column)."""

    image: np.ndarray
    timings: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)


#: ``method(masked_target, hole, sources, exif) -> MethodOutput``; uint8 RGB images, bool hole.
Method = Callable[[np.ndarray, np.ndarray, Sequence[np.ndarray], PairExif], MethodOutput]

#: Methods selectable by name (``--methods``).
METHODS: dict[str, Method] = {}
#: Methods that use several references at once (the others are offered one at a time).
MULTI_REFERENCE: set[str] = set()
#: Names of the project's baselines; the summary counts every method's wins against each.
BASELINES = ("opencv_inpaint", "homography")


def register_method(
    name: str, method: Method, *, replace: bool = False, multi_reference: bool = False
) -> None:
    """Make ``method`` selectable as ``name``; re-registering a name needs ``replace=True``.
    ``multi_reference``: it fills from all the references it is given, not just the first."""
    if not name or "," in name:
        raise ValueError(f"invalid method name {name!r}")
    if name in METHODS and not replace:
        raise ValueError(f"method '{name}' is already registered")
    METHODS[name] = method
    if multi_reference:
        MULTI_REFERENCE.add(name)
    else:
        MULTI_REFERENCE.discard(name)


def _opencv_method(
    target: np.ndarray, hole: np.ndarray, sources: Sequence[np.ndarray], exif: PairExif
) -> MethodOutput:
    t0 = time.perf_counter()
    image = opencv_inpaint(target, hole)
    return MethodOutput(image, {"total": time.perf_counter() - t0})


def _homography_method(
    target: np.ndarray, hole: np.ndarray, sources: Sequence[np.ndarray], exif: PairExif
) -> MethodOutput:
    t0 = time.perf_counter()
    fill = homography_fill_detailed(target, hole, sources[0])
    info = {
        "n_matches": fill.n_matches,
        "n_inliers": fill.n_inliers,
        "hole_coverage": round(fill.hole_coverage, 4),
    }
    return MethodOutput(fill.image, {"total": time.perf_counter() - t0}, info)


def _patchmatch_method(
    target: np.ndarray, hole: np.ndarray, sources: Sequence[np.ndarray], exif: PairExif
) -> MethodOutput:
    t0 = time.perf_counter()
    image = inpaint_single(target, hole, InpaintConfig(method="patchmatch"))
    return MethodOutput(image, {"total": time.perf_counter() - t0})


register_method("opencv_inpaint", _opencv_method)
register_method("patchmatch_inpaint", _patchmatch_method)
register_method("homography", _homography_method)

#: What ``--methods`` defaults to: the baselines and geofill as configured (presets by name,
#: ``geofill_<preset>``: see :data:`geofill.config.PRESETS`).
DEFAULT_METHODS = (*BASELINES, "geofill")


def geofill_method(cfg: FillConfig) -> Method:
    """The full pipeline with ``cfg`` as an evaluation method (all references it is given)."""
    from ..pipeline import fill

    def run(
        target: np.ndarray, hole: np.ndarray, sources: Sequence[np.ndarray], exif: PairExif
    ) -> MethodOutput:
        res = fill(target, hole, list(sources), cfg, target_exif=exif.target, source_exifs=list(exif.sources))
        r = res.report
        ref = r.references[0]
        opt = ref.get("optimize", {})
        info = {
            "status": r.status,
            "fallbacks": r.fallbacks,
            "pose_status": ref.get("pose", {}).get("status", ""),
            "n_pose_inliers": ref.get("pose", {}).get("n_inliers", 0),
            "hole_coverage": round(1.0 - r.painted_fraction, 4),
            "supplied_fraction": [round(f, 4) for f in r.supplied_fraction],
            "focal_px": round(float(ref.get("intrinsics_target", {}).get("fx_px", math.nan)), 1),
            "focal_origin": ref.get("intrinsics_target", {}).get("origin"),
            "optimize": ": ".join(filter(None, (opt.get(k, "") for k in ("status", "reason")))),
        }
        return MethodOutput(res.image, dict(r.timings_s), info)

    return run


def register_geofill_methods(base: FillConfig | None = None) -> None:
    """(Re-)register every geofill variant on top of ``base`` (default config when None)."""
    base = base or FillConfig()
    register_method("geofill", geofill_method(base), replace=True, multi_reference=True)
    for name in PRESETS:
        register_method(
            f"geofill_{name}", geofill_method(base.preset(name)), replace=True, multi_reference=True
        )


register_geofill_methods()


def resolve_methods(names: Sequence[str] | None) -> dict[str, Method]:
    """Registered methods by name, in the given order (None: :data:`DEFAULT_METHODS`)."""
    if names is None:
        names = DEFAULT_METHODS
    unknown = [n for n in names if n not in METHODS]
    if unknown:
        raise ConfigError(f"unknown method(s) {unknown}; registered: {sorted(METHODS)}")
    return {n: METHODS[n] for n in names}
