"""When the block reader pays (:func:`pays`) and which logs it takes (:func:`usable`); the replay
that uses it is vdp.replay.replay_log."""

from __future__ import annotations

from pathlib import Path

from .. import scan  # (no numba: the compiled parse is made at its first use)


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
