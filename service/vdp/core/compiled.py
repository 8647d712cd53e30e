"""The core's compiled functions on demand: the first use loads them, else None (the numpy path).

Imported at the first filter, fit or block pass, not with the core: numba's import costs
~0.5 s, and a live service that never asks for a compiled step never pays it.  The first
use after an install compiles every signature at once and says so (core.warm.ensure).
"""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)

_MODULES: list = []  # [core.kernels, core.prepass] once imported, or [] and _FAILED set when numba cannot be
_FAILED: list = []


def _load() -> list:
    if not _MODULES and not _FAILED:
        try:
            from . import kernels, prepass, warm
        except ImportError as exc:
            log.warning("compiled steps unavailable (%s); using numpy's", exc)
            _FAILED.append(exc)
            return _MODULES
        warm.ensure()
        if not _MODULES:  # (another thread may have set them meanwhile: the same modules)
            _MODULES.extend((kernels, prepass))
    return _MODULES


def kernel(name: str):
    """The compiled function or UKF class ``name`` (of core.kernels or core.prepass), or None when
    numba is missing: the numpy path then does the same work."""
    for mod in _load():
        fn = getattr(mod, name, None)
        if fn is not None:
            return fn
    if _MODULES:
        raise AttributeError(f"no compiled function {name!r}")
    return None


def sig_in(sigmas, x):
    """A filter's sigma points as the compiled runs take them: no points yet (a filter just built,
    before its first predict) as a (0, n) array, not None, so that each run compiles for one
    signature, not two (the Optional's twin cost ~20 s of each install's first compile)."""
    import numpy as np

    return np.empty((0, len(x))) if sigmas is None else sigmas


def sig_out(sigmas):
    """The inverse of :func:`sig_in`: a run that drew no points hands back what it was given."""
    return None if len(sigmas) == 0 else sigmas
