"""core.batched's pass, compiled (numba): imported at its first use, not with the core.

Its import compiles the helpers in place in core.batched (the pass calls them as its
module's globals, inlined) and the pass itself.  Python's import lock makes replays that
start at once in one process (a Dask worker's threads) wait for this module to be made
once: a second compile of an already compiled helper is an error in numba.  The code is
cached on disk beside core/batched.py, keyed on that file.
"""

from __future__ import annotations

from numba import njit

from . import batched

for _name in ("_speed_reset", "_speed_step", "_hyst", "_missing", "_hard", "_blocked"):
    setattr(batched, _name, njit(cache=True, nogil=True, inline="always")(getattr(batched, _name)))

prepass = njit(cache=True, nogil=True)(batched._prepass)
