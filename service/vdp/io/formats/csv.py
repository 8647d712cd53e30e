"""python-can's CSV logs (``.csv``)."""

from __future__ import annotations

import base64
from collections.abc import Iterator

import can

from .text import _TextReader


class CsvReader(_TextReader):
    """python-can's CSV layout (timestamp,arbitration_id,extended,remote,error,dlc,data)."""

    def start(self, lines: Iterator[str]) -> Iterator[str]:
        next(lines, None)  # the header
        return lines

    def parse(self, line: str) -> can.Message | None:
        if not line.strip():
            return None
        ts, aid, ext, remote, err, dlc, data = line.rstrip("\r\n").split(",")
        return can.Message(
            timestamp=float(ts),
            is_remote_frame=remote == "1",
            is_extended_id=ext == "1",
            is_error_frame=err == "1",
            arbitration_id=int(aid, 16),
            dlc=int(dlc),
            data=base64.b64decode(data, validate=True),
        )
