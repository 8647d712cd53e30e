"""The block reader's entry point: :func:`replay_log` replays a log a block at a time where that
pays, and frame by frame where the log needs the per-frame reader's rules (:mod:`vdp.io.bulk`)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ...result import RunResult
from .. import scan  # (no numba: the compiled parse is made at its first use)
from ..logs import open_log
from .source import BulkSource, Irregular

log = logging.getLogger(__name__)


def pays(path: str | Path) -> bool:
    """Whether reading ``path`` a block at a time pays (a candump log, and :func:`scan.pays`:
    numba loaded already, or a long log); the result is the same either way."""
    try:
        size = Path(path).stat().st_size
    except OSError:
        return False  # the per-frame reader says what is wrong with it
    return usable(path) and scan.pays(size)


def usable(path: str | Path) -> bool:
    """Bulk replay covers candump -L logs, plain or gzipped."""
    suffixes = [s.lower() for s in Path(path).suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    return bool(suffixes) and suffixes[-1] == ".log"


def replay_log(
    path: str | Path,
    make_pipeline: Callable[[], Any],
    strict: bool = False,
    channel: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    bulk: bool | None = None,
    wrap: Callable[[Any], Any] | None = None,
) -> tuple[RunResult, Any]:
    """``replay()``'s result for a log, and the pipeline it ran on.

    candump logs go the bulk way where it pays (``bulk`` None: :func:`pays`; True: always,
    False: never); if the log turns out to need the per-frame reader's rules, it is
    replayed again that way on a fresh pipeline.  ``wrap``: applied to a per-frame source
    (a recorder that needs every frame).
    """
    from ...replay import replay

    if bulk is None:
        bulk = pays(path)
    if bulk and usable(path):
        src = BulkSource(path, strict=strict, channel=channel)
        pipe = make_pipeline()
        try:
            return replay(src, pipe, progress=progress), pipe
        except Irregular as why:
            log.info("%s: %s; replaying it frame by frame", path, why)
        finally:
            src.close()
    source = open_log(path, strict=strict, channel=channel)
    pipe = make_pipeline()
    try:
        return replay(wrap(source) if wrap else source, pipe, progress=progress), pipe
    finally:
        source.close()
