"""Offline replay: a log through the pipeline, faster than real time.

The use case `vdp replay` and `vdp batch` share: :func:`check` reads the log's first minutes and
checks the profile against them (profilecheck), :func:`replay_file` replays the whole log with
that check standing for the running service's self-check, and marks the parameters it found a
mismatch under not valid.  :func:`replay_log` is the reading: a candump log a block at a time
where that pays (vdp.io.bulk), else frame by frame.  Comparing with a truth file is the report's
business (:func:`vdp.report.document`).
"""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .pipeline import Pipeline
from .result import RunResult

log = logging.getLogger(__name__)

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


def replay_log(
    path: str | Path,
    make_pipeline: Callable[[], Any],
    strict: bool = False,
    channel: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    bulk: bool | None = None,
    wrap: Callable[[Any], Any] | None = None,
) -> tuple[RunResult, Any]:
    """:func:`replay`'s result for a log, and the pipeline it ran on.

    candump logs go the bulk way where it pays (``bulk`` None: vdp.io.bulk.pays; True: always,
    False: never); if the log turns out to need the per-frame reader's rules, it is
    replayed again that way on a fresh pipeline.  ``wrap``: applied to a per-frame source
    (a recorder that needs every frame).
    """
    from .io import bulk as blocks
    from .io.logs import open_log

    if bulk is None:
        bulk = blocks.pays(path)
    if bulk and blocks.usable(path):
        src = blocks.BulkSource(path, strict=strict, channel=channel)
        pipe = make_pipeline()
        try:
            return replay(src, pipe, progress=progress), pipe
        except blocks.Irregular as why:
            log.info("%s: %s; replaying it frame by frame", path, why)
        finally:
            src.close()
    source = open_log(path, strict=strict, channel=channel)
    pipe = make_pipeline()
    try:
        return replay(wrap(source) if wrap else source, pipe, progress=progress), pipe
    finally:
        source.close()


@dataclasses.dataclass(frozen=True)
class Checked:
    """The profile checked against a log's first minutes (:func:`check`)."""

    head: Any  # profilecheck.Head: those minutes decoded and aligned (the drive's measures read them too)
    report: Any  # profilecheck.Report: the findings, and the parameters each marks not valid
    coverage: Any  # profilecheck.Coverage: the channels the log has


def check(path: str | Path, profile: Any) -> Checked:
    """The profile against the log's first minutes; a log of another car stops here (ProfileError).
    Quiet: the replay reads the same lines and warns of what it skips, once."""
    from . import profilecheck

    head = profilecheck.first_seconds(path, profile, quiet=True)
    rep, cov = profilecheck.check_head(head, profile, path=path)
    return Checked(head, rep, cov)


def replay_file(
    path: str | Path,
    profile: Any,
    cfg: Any,
    checked: Checked,
    prepare: Callable[[Pipeline], None] | None = None,
    **read: Any,
) -> RunResult:
    """A log's replay (`vdp replay`, `vdp batch`): :func:`replay_log` on a fresh pipeline per
    attempt (``prepare`` sets recorders on it), the log's own :func:`check` standing for the
    running service's self-check, and the parameters it found a mismatch under not valid,
    whatever the filter says.  ``read``: replay_log's ``strict``, ``progress``, ``bulk``, ``wrap``."""
    from .profilecheck import mark_invalid

    def make() -> Pipeline:
        pipe = Pipeline(profile, cfg)
        pipe.monitor = None  # the check of the log's first minutes stands for the replay
        if prepare is not None:
            prepare(pipe)
        return pipe

    result, _ = replay_log(path, make, channel=profile.bus_channel, **read)
    rep = checked.report
    ekf = result.baseline_ekf
    return dataclasses.replace(
        result,
        parameters=mark_invalid(result.parameters, rep),
        baseline_ekf=None if ekf is None else mark_invalid(ekf, rep),
    )
