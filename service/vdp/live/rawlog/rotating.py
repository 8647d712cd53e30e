"""python-can's rotating writer as the raw log uses it, and the file helpers under it."""

from __future__ import annotations

import os
from pathlib import Path

import can


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class _Detached(Exception):
    """The open file is no longer the raw log's current file (never leaves this package)."""

    def __init__(self, why: str, gone: bool):
        super().__init__(why)
        self.gone = gone  # True: no name is left for the file (deleted): what it held is lost


class _Rotating(can.SizedRotatingLogger):
    """python-can's size check asks the text file for tell(), which flushes it: one write
    syscall per frame.  Asking every CHECK_EVERY frames lets the buffer work; a file then
    ends at most that many lines past max_bytes.  ``before_rollover`` is called before a
    file is closed and renamed (it raises _Detached for a file that is no longer in place)."""

    CHECK_EVERY = 128

    def __init__(self, *args, before_rollover=None, after_rollover=None, **kwargs):
        super().__init__(*args, **kwargs)
        self._since_check = 0
        self.before_rollover = before_rollover
        self.after_rollover = after_rollover

    def do_rollover(self) -> None:
        if self.before_rollover is not None:
            self.before_rollover()
        super().do_rollover()
        if self.after_rollover is not None:
            self.after_rollover(self)

    def should_rollover(self, msg: can.Message) -> bool:
        self._since_check += 1
        if self._since_check < self.CHECK_EVERY:
            return False
        self._since_check = 0
        return super().should_rollover(msg)


def _dup(logger) -> int | None:
    """A read-only descriptor of the logger's open file (write-only itself), to count its lines after
    it is closed, whatever its name is then (Linux's /proc; None elsewhere: the file is found by name)."""
    try:
        return os.open(f"/proc/self/fd/{logger.writer.file.fileno()}", os.O_RDONLY)
    except (OSError, ValueError, AttributeError):
        return None
