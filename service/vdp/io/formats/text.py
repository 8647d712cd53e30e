"""What the text formats python-can parses share: a line loop where one bad line is one bad record."""

from __future__ import annotations

import gzip
import zlib
from collections.abc import Iterator

import can

from ...errors import LogFormatError
from .base import (
    _INF,
    _msg,
    _Reader,
)


class _TextReader(_Reader):
    """Line loop for the text formats python-can parses: one bad line is one bad record."""

    def parse(self, line: str) -> can.Message | None:
        """A frame, None for a line that holds none (comment, header, event), or raise for a bad one."""
        raise NotImplementedError

    def start(self, lines: Iterator[str]) -> Iterator[str]:
        """Read the header from ``lines``; return the iterator of the body's lines."""
        return lines

    def clean(self, line: str) -> str:
        """The text of a line as parse, bad and emit see it."""
        return line

    def read(self) -> Iterator[can.Message]:
        st = self.stats
        last = -_INF
        try:
            lines = self.start(self.lines())
        except (EOFError, zlib.error, gzip.BadGzipFile):
            raise
        except Exception as exc:
            raise LogFormatError(f"{self.path}: not a valid {self.src.format} file: {_msg(exc)}") from exc
        parse, clean = self.parse, self.clean
        for line in lines:
            n = self.lineno
            st.lines = n
            text = clean(line)
            try:
                msg = parse(text)
            except Exception as exc:
                self.bad(n, f"unreadable {self.src.format} line ({_msg(exc)[:60]})", text)
                continue
            if msg is None:
                continue
            ts = self.emit(n, msg, last, text)
            if ts is None:
                continue
            last = ts
            yield msg
        st.lines = self.lineno
        self.end_clock(last)


class _Pushback:
    """An iterator over lines that can give back the one it handed out last."""

    def __init__(self, it: Iterator[str]):
        self._it = it
        self._last: str | None = None
        self._back = False

    def __iter__(self) -> _Pushback:
        return self

    def __next__(self) -> str:
        if self._back:
            self._back = False
            assert self._last is not None
            return self._last
        self._last = next(self._it)
        return self._last

    def push_last(self) -> None:
        if self._last is not None:
            self._back = True


def _chain(first: list[str], rest: Iterator[str]) -> Iterator[str]:
    yield from first
    yield from rest
