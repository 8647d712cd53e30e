"""Vector BLF logs (``.blf``): a tolerant container reader of our own (damage is recorded, the rest read)."""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from decimal import Decimal

import can
from can.io import blf as _blf

from ...errors import LogFormatError
from .base import (
    _BLF_HEADER_SIZE,
    _EFF_MASK,
    _INF,
    _MAX_INNER,
    _MAX_OBJ,
    Source,
    _msg,
    _Reader,
    log,
)


class BlfReader(_Reader):
    """Vector BLF, tolerant of damage.

    python-can's reader stops at the first broken object, loses everything after an
    object whose size field is wrong (it waits for the size to arrive), and loops on a
    zero size.  Here every object is checked: a container whose size field is wrong
    is still read to the end of its own zlib stream; a stretch that cannot be read is
    skipped to the next ``LOBJ`` signature and recorded as damage.  Frames are decoded
    as python-can decodes them (its structs and constants).
    """

    def __init__(self, src: Source):
        super().__init__(src)
        self._buf = b""  # bytes read from the file and not consumed yet
        self._off = 0  # file offset of _buf[0]
        self._eof = False
        self._objects = 0

    # -- the file: top-level objects --------------------------------------------
    def _fill(self, n: int) -> bool:
        """At least ``n`` bytes in the buffer, if the file has them."""
        read = self.src._stream.read
        while len(self._buf) < n and not self._eof:
            chunk = read(max(n - len(self._buf), 1 << 16))
            if not chunk:
                self._eof = True
            self._buf += chunk
        return len(self._buf) >= n

    def _drop(self, n: int) -> None:
        self._buf = self._buf[n:]
        self._off += n

    def _resync(self, start: int, reason: str) -> bool:
        """Skip to the next LOBJ signature from buffer offset ``start``; record what was skipped.

        Up to 3 bytes before it are an object's padding (objects are padded to 4 bytes), not
        damage, when ``reason`` is empty.  False when no signature is left in the file.
        """
        at = self._off
        skipped = 0
        while True:
            k = self._buf.find(b"LOBJ", start)
            if k >= 0:
                skipped += k
                self._drop(k)
                break
            if self._eof:
                skipped += len(self._buf)
                self._drop(len(self._buf))
                if skipped > 3 or reason:
                    self.damaged(at, skipped, (reason or "unreadable bytes") + "; nothing readable after it")
                return False
            keep = max(len(self._buf) - 3, start)  # a signature may straddle the chunk edge
            skipped += keep
            self._drop(keep)
            start = 0
            self._fill(len(self._buf) + (1 << 16))
        if skipped > 3 or reason:
            self.damaged(at, skipped, reason or "unreadable bytes between objects")
        return True

    def _header(self) -> None:
        h = _blf.FILE_HEADER_STRUCT
        if not self._fill(h.size):
            raise LogFormatError(f"{self.path}: not a BLF file (header cut short)")
        fields = h.unpack_from(self._buf)
        hsize, self.file_size, self.object_count = fields[1], fields[10], fields[12]
        if not h.size <= hsize <= 4096:
            self.damaged(0, 0, f"header size field is {hsize}; assumed {_BLF_HEADER_SIZE}")
            hsize = _BLF_HEADER_SIZE
        self.start_timestamp = _blf.systemtime_to_timestamp(fields[14:22])
        self._fill(hsize)
        self._drop(hsize)
        if not self.src.compressed and self.file_size != self.src.size:
            self._size_note = f"the header says the file has {self.file_size:,} bytes; it has {self.src.size:,}"
        else:
            self._size_note = ""

    def _containers(self) -> Iterator[bytes]:
        base = _blf.OBJ_HEADER_BASE_STRUCT
        cont = _blf.LOG_CONTAINER_STRUCT
        while True:
            if not self._fill(base.size):
                if self._buf.strip(b"\x00"):
                    self.stats.truncated = True
                    self.damaged(self._off, len(self._buf), "the file ends inside an object header (truncated)")
                return
            sig, hsize, _hver, size, typ = base.unpack_from(self._buf)
            if sig != b"LOBJ":
                if not self._resync(1, "" if self._objects else "no LOBJ signature after the file header"):
                    return
                continue
            self._objects += 1
            if typ != _blf.LOG_CONTAINER:
                # top-level objects other than containers hold nothing we read
                if not base.size <= size <= _MAX_OBJ:
                    if not self._resync(4, f"object size field is {size}"):
                        return
                    continue
                if not self._fill(size):
                    self.stats.truncated = True
                    self.damaged(self._off, len(self._buf), "the file ends inside an object (truncated)")
                    return
                # frames live in containers: another type here is a damaged type field, or nothing we read
                self.damaged(self._off, size, f"object of type {typ} outside a container skipped")
                self._drop(size)
                continue
            start = self._off
            head = base.size + cont.size
            if not self._fill(head):
                self.stats.truncated = True
                self.damaged(start, len(self._buf), "the file ends inside a container header (truncated)")
                return
            method, _usize = cont.unpack_from(self._buf, base.size)
            if method == _blf.ZLIB_DEFLATE:
                data, used, problem = self._inflate(head)
                if data:
                    yield data
                if problem and self.stats.truncated:
                    self.damaged(start, 0, "the file ends inside a container (truncated); its readable part is used")
                    return
                if problem:
                    if not self._resync(head, f"container at byte {start}: {problem}"):
                        return
                    continue
                if used + head != size:
                    # the stream is whole and says where it ends: only the size field is wrong
                    self.damaged(start, 0, f"container size field is {size}; its data ends at {used + head}")
                self._drop(head + used)
            elif method == _blf.NO_COMPRESSION and head <= size <= _MAX_OBJ:
                if not self._fill(size):
                    self.stats.truncated = True
                    yield self._buf[head:]
                    self.damaged(start, 0, "the file ends inside a container (truncated)")
                    return
                yield self._buf[head:size]
                self._drop(size)
            elif not self._resync(4, f"container at byte {start}: compression {method}, size {size}"):
                return

    def _inflate(self, head: int) -> tuple[bytes, int, str]:
        """(data, compressed bytes used, problem or "") of the zlib stream at buffer offset ``head``."""
        z = zlib.decompressobj()
        out: list[bytes] = []
        got = 0
        pos = head
        while True:
            if pos - head > _MAX_OBJ:
                return b"".join(out), pos - head, f"zlib stream longer than {_MAX_OBJ} bytes"
            if pos >= len(self._buf) and not self._fill(pos + 1):
                self.stats.truncated = True
                return b"".join(out), pos - head, "the file ends inside it (truncated)"
            chunk = self._buf[pos : pos + 4096]
            try:
                piece = z.decompress(chunk, _MAX_OBJ - got)
            except zlib.error as exc:
                return b"".join(out), pos - head, f"corrupt zlib data ({exc})"
            out.append(piece)
            got += len(piece)
            if z.eof:
                return b"".join(out), pos - head + len(chunk) - len(z.unused_data), ""
            if z.unconsumed_tail:
                return b"".join(out), pos - head, f"inflates to more than {_MAX_OBJ} bytes"
            pos += len(chunk)

    # -- inside containers: frames ----------------------------------------------
    def read(self) -> Iterator[can.Message]:
        self._header()
        if self._size_note:
            log.info("%s: %s", self.path, self._size_note)
        tail = b""
        last = -_INF
        n = 0
        for data in self._containers():
            data = tail + data if tail else data
            pos = 0
            for msg, pos in self._objects_in(data):  # noqa: B007 (pos: where the cut-off object starts)
                if msg is None:
                    continue
                n += 1
                self.lineno = n
                ts = self.emit(n, msg, last, str(msg))
                if ts is None:
                    continue
                last = ts
                yield msg
            tail = data[pos:]
            if len(tail) > _MAX_INNER:
                self.damaged(-1, len(tail), f"an object in a container claims more than {_MAX_INNER} bytes")
                tail = b""
        if tail.strip(b"\x00") and not self.stats.truncated:
            self.damaged(-1, len(tail), "the last object is cut short")
        self.end_clock(last)

    def _objects_in(self, data: bytes) -> Iterator[tuple[can.Message | None, int]]:
        """(frame or None, offset after it) for each object; the offset ends at a cut-off object."""
        B = _blf
        base = B.OBJ_HEADER_BASE_STRUCT
        v1, v2 = B.OBJ_HEADER_V1_STRUCT, B.OBJ_HEADER_V2_STRUCT
        end = len(data)
        pos = 0
        while True:
            k = data.find(b"LOBJ", pos, pos + 8)  # objects are padded to 4 bytes
            if k < 0:
                if pos + 8 > end:
                    yield None, pos
                    return
                k = data.find(b"LOBJ", pos + 1)
                if k < 0:
                    self.damaged(-1, end - pos, "no object signature in the rest of a container")
                    yield None, end
                    return
                self.damaged(-1, k - pos, "bytes between objects inside a container")
            pos = k
            if pos + base.size > end:
                yield None, pos
                return
            _sig, hsize, hver, size, typ = base.unpack_from(data, pos)
            if not base.size < size <= _MAX_INNER or hsize > size:
                self.damaged(-1, 4, f"object size field is {size}")
                pos += 4
                continue
            nxt = pos + size
            if nxt > end:
                yield None, pos  # continues in the next container
                return
            try:
                msg = self._frame(data, pos + base.size, hver, hsize, size, typ, v1, v2)
            except (struct.error, ValueError, OverflowError) as exc:
                self.bad(self.lineno + 1, f"unreadable BLF object ({_msg(exc)[:60]})", f"type {typ} size {size}")
                msg = None
            pos = nxt
            yield msg, pos

    def _frame(self, data, pos, hver, hsize, size, typ, v1, v2) -> can.Message | None:
        B = _blf
        if typ not in (B.CAN_MESSAGE, B.CAN_MESSAGE2, B.CAN_ERROR_EXT, B.CAN_FD_MESSAGE, B.CAN_FD_MESSAGE_64):
            return None
        if hver == 1:
            flags, _, _, stamp = v1.unpack_from(data, pos)
            pos += v1.size
        elif hver == 2:
            flags, _, _, stamp = v2.unpack_from(data, pos)
            pos += v2.size
        else:
            raise ValueError(f"unknown object header version {hver}")
        factor = B.TIME_TEN_MICS_FACTOR if flags == 1 else B.TIME_ONE_NANS_FACTOR
        ts = float(Decimal(stamp) * factor) + self.start_timestamp
        ext = B.CAN_MSG_EXT
        if typ in (B.CAN_MESSAGE, B.CAN_MESSAGE2):
            channel, fl, dlc, can_id, can_data = B.CAN_MSG_STRUCT.unpack_from(data, pos)
            return can.Message(
                timestamp=ts,
                arbitration_id=can_id & _EFF_MASK,
                is_extended_id=bool(can_id & ext),
                is_remote_frame=bool(fl & B.REMOTE_FLAG),
                is_rx=not fl & B.DIR,
                dlc=dlc,
                data=can_data[:dlc],
                channel=channel - 1,
            )
        if typ == B.CAN_ERROR_EXT:
            m = B.CAN_ERROR_EXT_STRUCT.unpack_from(data, pos)
            return can.Message(
                timestamp=ts,
                is_error_frame=True,
                is_extended_id=bool(m[7] & ext),
                arbitration_id=m[7] & _EFF_MASK,
                dlc=m[5],
                data=m[9][: m[5]],
                channel=m[0] - 1,
            )
        if typ == B.CAN_FD_MESSAGE:
            channel, fl, dlc, can_id, _, _, fd, valid, can_data = B.CAN_FD_MSG_STRUCT.unpack_from(data, pos)
            return can.Message(
                timestamp=ts,
                arbitration_id=can_id & _EFF_MASK,
                is_extended_id=bool(can_id & ext),
                is_remote_frame=bool(fl & B.REMOTE_FLAG),
                is_fd=bool(fd & 0x1),
                is_rx=not fl & B.DIR,
                bitrate_switch=bool(fd & 0x2),
                error_state_indicator=bool(fd & 0x4),
                dlc=can.util.dlc2len(dlc),
                data=can_data[:valid],
                channel=channel - 1,
            )
        f = B.CAN_FD_MSG_64_STRUCT.unpack_from(data, pos)
        channel, dlc, valid, can_id, fd, direction, ext_off = f[0], f[1], f[2], f[4], f[6], f[12], f[13]
        n = min(valid, (ext_off or size) - hsize - B.CAN_FD_MSG_64_STRUCT.size)
        start = pos + B.CAN_FD_MSG_64_STRUCT.size
        payload = data[start : start + max(n, 0)].ljust(valid, b"\x00")
        return can.Message(
            timestamp=ts,
            arbitration_id=can_id & _EFF_MASK,
            is_extended_id=bool(can_id & ext),
            is_remote_frame=bool(fd & 0x0010),
            is_fd=bool(fd & 0x1000),
            is_rx=not direction,
            bitrate_switch=bool(fd & 0x2000),
            error_state_indicator=bool(fd & 0x4000),
            dlc=can.util.dlc2len(dlc),
            data=payload,
            channel=channel - 1,
        )
