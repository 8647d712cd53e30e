"""PEAK TRC logs (``.trc``), lines parsed by python-can; channels numbered from 0."""

from __future__ import annotations

import io
from collections.abc import Iterator

import can

from .text import _chain, _TextReader


class TrcReader(_TextReader):
    """PEAK TRC: python-can parses each line; a line it cannot parse is skipped and counted."""

    def start(self, lines: Iterator[str]) -> Iterator[str]:
        from can.io import trc

        self.pc = trc.TRCReader(io.StringIO())
        self.pc.file = lines
        first = self.pc._extract_header()  # the first line after the header
        return _chain([first] if first else [], lines)

    def clean(self, line: str) -> str:
        return line.strip()

    def parse(self, line: str) -> can.Message | None:
        if not line or line.startswith(";"):
            return None
        msg = self.pc._parse_cols(tuple(line.split(maxsplit=self.pc._num_columns)))
        if msg is None:
            return None  # a bus status line or another record type we do not read
        if isinstance(msg.channel, int):
            msg.channel -= 1  # TRC numbers buses from 1, python-can's writer adds 1
        return msg
