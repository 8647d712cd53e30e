"""Offline replay: a log source through the pipeline, faster than real time.

The work is :meth:`vdp.pipeline.Pipeline.run`; this is the name the CLI, the
benchmarks and the tests call it by.  Comparing with a truth file is the
report's business (:func:`vdp.report.document`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from .pipeline import Pipeline
from .result import RunResult

# Bytes of log from which the compiled filter steps pay for loading numba (~1 s of CPU: its import and
# its first cached function); a shorter log's replay runs numpy's steps, as the live service does, and
# never loads numba.  Whole `vdp replay` processes of the paper drive's first N lines, numpy / compiled,
# s of CPU (two rounds, 2026-11-28): 20,000 lines (0.92 MB) 1.3 / 1.9-2.1; 40,000 (1.84 MB) 2.1-2.6 /
# 2.3-2.7; the whole drive (3.1 MB) 4.3-4.8 / 2.7-3.1.  The two differ by ~1e-10 of a value (the
# steps' sums in another order; tests/test_kernels.py).  VDP_COMPILED_FROM sets another, for measuring.
COMPILED_FROM = int(os.environ.get("VDP_COMPILED_FROM", str(3 << 19)))


def compiled_pays(path: str | Path) -> bool:
    """Whether a replay of ``path`` runs the compiled filter steps (LearnerConfig.compiled): the one
    rule of `vdp replay` and `vdp batch`, so both give the same numbers for a log."""
    try:
        return Path(path).stat().st_size >= COMPILED_FROM
    except OSError:
        return False  # the reader says what is wrong with it


def replay(source, pipeline: Pipeline, progress: Callable[[int, int], None] | None = None) -> RunResult:
    """Feed every frame of ``source`` to ``pipeline``; return the typed result."""
    return pipeline.run(source, progress)
