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
then gives numba a folder of this user's own in the temp folder (``geofill-numba-<uid>``, created
private, used only while it is this user's and private: numba's cache files are pickles, which run
code when loaded). Where even that fails, it compiles in memory (every process pays the compile,
about a second) and says so once, in words, through the ``geofill`` logger (shown on stderr where
the logger has no handler), naming the variable that gives the cache a home."""

from __future__ import annotations

import functools
import os
import stat
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..progress import LOGGER

#: Kernels by module, in definition order: a module's kernels are built together (see Kernel.build).
_KERNELS: dict[str, list[Kernel]] = {}
_BUILD_LOCK = threading.RLock()
_WARM_UP: list[threading.Thread] = []
#: Said once per process: numba has nowhere to keep compiled code.
_NO_CACHE_SAID: list[bool] = []


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
    from numba import config, njit

    try:
        return njit(cache=True, **options)(fn)
    except RuntimeError as exc:
        if "cannot cache function" not in str(exc):
            raise
    folder = private_temp_folder("geofill-numba")
    if folder is not None and config.CACHE_DIR != str(folder):
        config.CACHE_DIR = str(folder)  # numba's first locator, read at each dispatcher's creation
        return _dispatcher(fn, options)
    if not _NO_CACHE_SAID:
        _NO_CACHE_SAID.append(True)
        LOGGER.warning(
            "geofill: note: numba found no writable folder for its compiled code (NUMBA_CACHE_DIR, "
            "the install's __pycache__, ~/.cache, the temp folder), so geofill's kernels are compiled "
            "again on every run (about a second); set NUMBA_CACHE_DIR to a writable folder to keep them"
        )
    return njit(**options)(fn)


def private_temp_folder(name: str) -> Path | None:
    """``<temp folder>/<name>-<uid>``, created readable and writable by this user only; None where
    it cannot be created or is not a folder of this user's that no one else may write or read."""
    uid = os.getuid() if hasattr(os, "getuid") else None
    folder = Path(tempfile.gettempdir()) / (f"{name}-{uid}" if uid is not None else name)
    try:
        folder.mkdir(mode=0o700, exist_ok=True)
        st = folder.lstat()
    except OSError:
        return None
    mine = uid is None or st.st_uid == uid
    if not (stat.S_ISDIR(st.st_mode) and mine and st.st_mode & 0o077 == 0 and os.access(folder, os.W_OK)):
        return None
    return folder


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
