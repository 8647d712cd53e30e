"""Offline replay: a log source through the pipeline, faster than real time.

The work is :meth:`vdp.pipeline.Pipeline.run`; this is the name the CLI, the
benchmarks and the tests call it by.  Comparing with a truth file is the
report's business (:func:`vdp.report.document`).
"""

from __future__ import annotations

from collections.abc import Callable

from .pipeline import Pipeline
from .result import RunResult


def replay(source, pipeline: Pipeline, progress: Callable[[int, int], None] | None = None) -> RunResult:
    """Feed every frame of ``source`` to ``pipeline``; return the typed result."""
    return pipeline.run(source, progress)
