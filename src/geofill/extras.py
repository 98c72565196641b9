"""Optional parts of geofill, each behind a pip extra and imported only when asked for.

A base install (``pip install geofill``) fills with the offline defaults; asking for an optional
part without its extra is one :class:`MissingExtraError` line that names the extra to install."""

from __future__ import annotations

import importlib
import importlib.util
from types import ModuleType

from .errors import MissingExtraError

#: Importable module -> the extra of pyproject.toml that installs it.
EXTRAS: dict[str, str] = {
    "onnxruntime": "onnx",
    "huggingface_hub": "onnx",
    "OpenEXR": "exr",
    "pillow_heif": "heif",
    "patchmatch": "patchmatch",
    "matplotlib": "eval",
    "torch": "torch",
    "pytorch_optimizer": "paper",
    "pycolmap": "sfm",
}


def available(module: str) -> bool:
    """True when ``module`` can be imported (checked without importing it)."""
    return importlib.util.find_spec(module) is not None


def install_hint(module: str) -> str:
    """``pip install "geofill[EXTRA]"`` for the extra that provides ``module``."""
    return f'pip install "geofill[{EXTRAS[module]}]"'


def require(module: str, purpose: str) -> ModuleType:
    """Import ``module`` for ``purpose``, or raise MissingExtraError naming its extra."""
    if not available(module):
        raise MissingExtraError(
            f"{purpose} needs the optional '{EXTRAS[module]}' extra: {install_hint(module)}"
        )
    return importlib.import_module(module)
