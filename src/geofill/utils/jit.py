"""numba kernels: numba imported when a kernel is first used, its on-disk cache wherever the user can
write one, and its start-up overlapped with other work.

Starting numba costs a process ~0.4 s (importing it ~0.15 s; the first use of its CPU target, which
imports numba's NumPy support and through it ``scipy.linalg``, ~0.25 s), a fifth of a 1280x720 fill.
:func:`njit_cached` therefore returns a :class:`Kernel` that imports numba and builds its dispatcher
on first use, so importing geofill's modules does not pay it, and :func:`warm_up` starts numba in a
background thread: a fill calls it first thing, and the start-up runs while the matching stage's
SIFT (OpenCV, which releases the GIL) keeps the main thread waiting. Not earlier: the start-up is
Python code holding the GIL, and work that releases it in many short pieces (Pillow decodes a PNG
in 64 kB chunks) then waits for it each time: reading berlin_01_02's two 1280x960 PNGs took 0.41 s
next to it instead of 0.09 s.

``cache=True`` makes numba look for a writable folder: ``$NUMBA_CACHE_DIR``, the package's own
``__pycache__``, then the user-wide cache (``~/.cache/numba``). When none is writable (a read-only
install run by a user without a writable home) numba refuses to cache with a RuntimeError; geofill
then compiles in memory instead (every process pays the compile, about a second) and says so once,
naming the variable that gives the cache a home."""

from __future__ import annotations

import functools
import threading
import warnings
from collections.abc import Callable
from typing import Any

#: Kernels by module, in definition order: a module's kernels are built together (see Kernel.build).
_KERNELS: dict[str, list[Kernel]] = {}
_BUILD_LOCK = threading.RLock()
_WARM_UP: list[threading.Thread] = []


class Kernel:
    """A function compiled by numba (``njit(cache=True, **options)``) when first called or built.

    Calls go to the numba dispatcher; other attributes are the dispatcher's."""

    def __init__(self, fn: Callable[..., Any], options: dict[str, Any]):
        self.fn, self.options = fn, options
        self.dispatcher: Any = None
        functools.update_wrapper(self, fn)
        _KERNELS.setdefault(fn.__module__, []).append(self)

    def __call__(self, *args: Any) -> Any:
        return (self.dispatcher or self.build())(*args)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.build(), name)

    def build(self) -> Any:
        """The numba dispatcher. Every kernel of the same module is built with it, and a kernel
        defined with decorator syntax replaces itself by its dispatcher in the module: a kernel
        calling another (an inlined helper) finds the callee as a module global, and numba can only
        compile a call to a dispatcher."""
        with _BUILD_LOCK:
            if self.dispatcher is None:
                for k in _KERNELS[self.fn.__module__]:
                    if k.dispatcher is None:
                        k.dispatcher = _dispatcher(k.fn, k.options)
                        if k.fn.__globals__.get(k.fn.__name__) is k:
                            k.fn.__globals__[k.fn.__name__] = k.dispatcher
        return self.dispatcher


def njit_cached(**options: Any) -> Callable[[Callable[..., Any]], Kernel]:
    """``numba.njit(cache=True, **options)`` built on first use (:class:`Kernel`), or without the
    cache where numba has nowhere to write."""

    def decorate(fn: Callable[..., Any]) -> Kernel:
        return Kernel(fn, options)

    return decorate


def _dispatcher(fn: Callable[..., Any], options: dict[str, Any]) -> Any:
    from numba import njit

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


@njit_cached()
def _increment(x):  # pragma: no cover - compiled
    return x + 1


def warm_up() -> None:
    """Start numba in a background thread, once per process (later calls return at once). Nothing
    waits for it: a kernel used before it is done waits for numba's import like any import."""
    with _BUILD_LOCK:
        if not _WARM_UP:
            _WARM_UP.append(threading.Thread(target=_start_numba, name="geofill-numba-start", daemon=True))
            _WARM_UP[0].start()


def _start_numba() -> None:
    # The first call of a cached kernel imports numba, starts its CPU target and loads the code.
    try:
        _increment(1)
    except Exception:
        pass  # the same error is raised where a kernel is first used, in the caller's thread
