"""Vector ASC logs (``.asc``), lines parsed by python-can."""

from __future__ import annotations

import io
import re
from collections.abc import Iterator
from typing import Any

import can

from .text import _Pushback, _TextReader


class AscReader(_TextReader):
    """Vector ASC: python-can parses each line; a line it cannot parse is skipped and counted."""

    def start(self, lines: Iterator[str]) -> Iterator[str]:
        from can.io import asc

        self._regex = asc.ASC_MESSAGE_REGEX
        self._trigger = asc.ASC_TRIGGER_REGEX
        self._start = re.compile(r"^\d+\.\d+\s+Start of measurement")
        # a classic frame's start (time, bus number, id, direction) on a line python-can cannot read:
        # a damaged frame, not one of the events it skips (statistics, error frames, J1939, comments)
        self._framelike = re.compile(r"^\d+\.\d+\s+\d+\s+[0-9A-Fa-f]{1,8}x?\s+(?:Rx|Tx)\b")
        self._idlike = re.compile(r"^\d+\.\d+\s+\d+\s+[0-9A-Fa-f]{1,8}x?(?:\s|$)")
        self.pc = asc.ASCReader(io.StringIO())
        body = self.pc.file = _Pushback(lines)
        self.pc._extract_header()  # stops on the first line after the header: give it back
        body.push_last()
        return body

    def parse(self, line: str) -> can.Message | None:
        pc = self.pc
        line = line.strip()
        m = self._trigger.match(line)
        if m:
            pc.start_time = 0.0 if pc.relative_timestamp else pc._datetime_to_timestamp(m.group("datetime_string"))
            return None
        if self._start.match(line):
            return None
        if not self._regex.match(line):
            if self._framelike.match(line) or self._idlike.match(line):
                raise ValueError("a frame line python-can cannot read")
            return None  # a comment, bus statistics, J1939 or another event we do not read
        ts_s, channel, rest = line.split(None, 2)
        kw: dict[str, Any] = {"timestamp": float(ts_s) + pc.start_time}
        if channel == "CANFD":
            kw["is_fd"] = True
            return pc._process_fd_can_frame(rest, kw)
        if not channel.isdigit():
            return None
        kw["channel"] = int(channel) - 1
        return pc._process_classic_can_frame(rest, kw)
