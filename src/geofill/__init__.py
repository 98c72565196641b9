"""geofill: reference-based image inpainting with two-view geometry."""

from .config import FillConfig
from .pipeline import FillReport, FillResult, fill

__all__ = ["FillConfig", "FillReport", "FillResult", "fill"]
__version__ = "0.1.0"
