"""Formats python-can reads whole (``.mf4``), with the same frame checks."""

from __future__ import annotations

from collections.abc import Iterator

import can

from .base import (
    _INF,
    _Reader,
)


class _PythonCanReader(_Reader):
    """python-can's reader for the format (.mf4), with the same frame checks."""

    def read(self) -> Iterator[can.Message]:
        last = -_INF
        n = 0
        for n, msg in enumerate(self.src._reader, 1):
            self.lineno = n
            ts = self.emit(n, msg, last, str(msg))
            if ts is None:
                continue
            last = ts
            yield msg
        self.end_clock(last)
