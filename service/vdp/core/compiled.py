"""core.kernels on demand: the compiled steps when numba imports, else None (the numpy path).

Imported at the first filter or fit, not with the core: numba's import costs ~0.5 s, and a
live service that never asks for a compiled step never pays it.
"""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)

_KERNELS: list = []  # core.kernels once imported, or None when numba cannot be


def kernel(name: str):
    """core.kernels' ``name`` (a compiled function or UKF class), or None when numba is missing:
    the numpy path then does the same work."""
    if not _KERNELS:
        try:
            from . import kernels
        except ImportError as exc:
            log.warning("compiled steps unavailable (%s); using numpy's", exc)
            kernels = None
        _KERNELS.append(kernels)
    return None if _KERNELS[0] is None else getattr(_KERNELS[0], name)
