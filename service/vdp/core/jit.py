"""numba's ``njit`` as the core's compiled modules use it, cached in a directory of their own.

numba invalidates a cached function when its own file changes, not when a function it calls
from another file does, nor a module constant it froze in (numba's caching notes): a change
to core/lateral.py would otherwise leave the old physics compiled.  So every compiled function
of the core is cached under one directory named by a hash of all the sources numba compiles
from (:data:`SOURCES`), and that hash is also each function's source stamp.  The directory is
chosen per function by a cache locator of this module's (numba's ``_CacheLocator`` interface),
so numba's global configuration is never changed: other code that caches with numba keeps
numba's own directories.

Under NUMBA_CACHE_DIR when that is set, else in ``core/__pycache__``; where that is read-only,
numba's own locators take over (its user-wide cache).
"""

from __future__ import annotations

import hashlib
import logging
import typing
from pathlib import Path

from numba import njit
from numba.core import caching
from numba.core import config as numba_config

log = logging.getLogger(__name__)

HERE = Path(__file__).resolve().parent
# every file whose functions numba compiles or whose constants it freezes into compiled code
SOURCES = ("lateral.py", "longitudinal.py", "batched.py", "passes.py", "prepass.py", "kernels/*.py")
# what the first compile after an install costs (core.warm.warm in a fresh cache, this checkout,
# an idle 2-core machine, 2026-11-28: 67 s wall, 66.5 s CPU; it was 146-160 s before each compiled
# run took one signature, core.compiled.sig_in)
FIRST_COMPILE = "about 70 s of CPU"
MARK = "warm.done"  # written by core.warm once every signature the learners use is compiled


def _digest() -> str:
    h = hashlib.sha1()
    for pattern in SOURCES:
        for path in sorted(HERE.glob(pattern)):
            h.update(path.read_bytes())
    return h.hexdigest()[:12]


DIGEST = _digest()


def cache_dir() -> Path:
    """Where the core's compiled code is cached (a directory per version of its sources)."""
    base = Path(numba_config.CACHE_DIR) if numba_config.CACHE_DIR else HERE / "__pycache__"
    return base / f"kernels-{DIGEST}"


class _Locator(caching._CacheLocator):
    """numba's cache locator for the core's functions: :func:`cache_dir`, stamped by :data:`DIGEST`."""

    def __init__(self, py_func):
        self._lineno = py_func.__code__.co_firstlineno
        self._path = str(cache_dir())

    def get_cache_path(self) -> str:
        return self._path

    def get_source_stamp(self) -> str:
        return DIGEST

    def get_disambiguator(self) -> str:
        return str(self._lineno)

    @classmethod
    def from_function(cls, py_func, py_file):
        self = cls(py_func)
        try:
            self.ensure_cache_path()
        except OSError:  # read-only: numba's own locators decide
            return None
        return self


class _Impl(caching.CompileResultCacheImpl):
    _locator_classes: typing.ClassVar[list] = [_Locator, *caching.CompileResultCacheImpl._locator_classes]


class _Cache(caching.FunctionCache):
    _impl_class = _Impl


def jit(**options):
    """``numba.njit(nogil=True, **options)`` whose compiled code is cached in :func:`cache_dir`."""

    def wrap(fn):
        disp = njit(nogil=True, **options)(fn)
        if hasattr(disp, "py_func"):  # (not under NUMBA_DISABLE_JIT, where njit hands back fn)
            disp._cache = _Cache(fn)  # what njit(cache=True) sets, with this module's locator
        return disp

    return wrap


def _mark_text() -> str:
    """The marker's text: the sources' digest and core/warm.py's own (a warm-up that learns a new
    signature makes the cache incomplete again, without recompiling the rest)."""
    return f"{DIGEST} {hashlib.sha1((HERE / 'warm.py').read_bytes()).hexdigest()[:12]}\n"


def cached() -> bool:
    """Whether every compiled signature the estimator uses is on disk (core.warm has run for
    these sources): False means the next estimate compiles them (FIRST_COMPILE, once)."""
    try:
        return (cache_dir() / MARK).read_text() == _mark_text()
    except OSError:
        return False


def mark_cached() -> None:
    if numba_config.DISABLE_JIT:  # nothing was compiled
        return
    try:
        (cache_dir() / MARK).write_text(_mark_text())
    except OSError as exc:  # a read-only install: the code is in numba's own cache, unmarked
        log.debug("cannot mark the compiled cache: %s", exc)
