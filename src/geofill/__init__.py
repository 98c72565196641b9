"""geofill: reference-based image inpainting with two-view geometry."""

from .config import FillConfig

__all__ = ["FillConfig"]
__version__ = "0.1.0"
