"""numba compilation with numba's on-disk cache wherever the user can write one.

``cache=True`` makes numba look for a writable folder: ``$NUMBA_CACHE_DIR``, the package's own
``__pycache__``, then the user-wide cache (``~/.cache/numba``). When none is writable (a read-only
install run by a user without a writable home) numba refuses the decorator with a RuntimeError at
import time; geofill then compiles in memory instead (every process pays the compile, about a
second) and says so once, naming the variable that gives the cache a home."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

from numba import njit


def njit_cached(**options: Any) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """``numba.njit(cache=True, **options)``, or without the cache where numba has nowhere to write."""

    def decorate(fn: Callable[..., Any]) -> Callable[..., Any]:
        try:
            return njit(cache=True, **options)(fn)
        except RuntimeError as exc:
            if "cannot cache function" not in str(exc):
                raise
            # One message for every function (Python shows a warning once per text and place).
            warnings.warn(
                "numba has no writable cache folder: geofill's kernels are compiled in memory on "
                "every run; set NUMBA_CACHE_DIR to a writable folder to keep the compiled code",
                RuntimeWarning,
                stacklevel=1,
            )
            return njit(**options)(fn)

    return decorate
