"""geofill: reference-based image inpainting with two-view geometry."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .config import FillConfig

if TYPE_CHECKING:
    from .pipeline import FillReport, FillResult, fill

__all__ = ["FillConfig", "FillReport", "FillResult", "fill"]
__version__ = "0.1.0"

#: Names served from :mod:`geofill.pipeline` on first use: importing the pipeline loads OpenCV, SciPy,
#: numba and the solvers (seconds), which ``geofill --help`` and ``geofill config`` must not pay.
_PIPELINE_NAMES = frozenset({"FillReport", "FillResult", "fill"})


def __getattr__(name: str) -> Any:
    if name in _PIPELINE_NAMES:
        from . import pipeline

        return getattr(pipeline, name)
    raise AttributeError(f"module 'geofill' has no attribute {name!r}")
