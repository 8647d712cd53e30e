"""candump -L logs (``.log``): the compiled scan's blocks, the refused lines by tolerant rules."""

from __future__ import annotations

import binascii
from collections.abc import Iterator
from typing import Any

import can

from .. import scan
from .base import (
    _BLOCK,
    _DIRS,
    _EFF_MASK,
    _ERR_FLAG,
    _FD_LENGTHS,
    _ID_CACHE_MAX,
    _INF,
    _JUMP,
    _LONG,
    _MAX_CHANNELS,
    _MAX_LINE,
    EXT_KEY,
    Source,
    _Reader,
)


class CandumpReader(_Reader):
    """Tolerant candump -L reader.  A block's lines are parsed at once by the compiled scan
    (:mod:`vdp.io.scan`, the one candump parser); the lines it refuses (remote, FD and error
    frames, damage: rare) are read one by one by the tolerant rules of :meth:`slow`, which
    read every line the scan accepts exactly as the scan does (``tests/test_scan.py``).
    Without the compiled scan (:func:`_use_scan`), every line goes by those rules.
    """

    def __init__(self, src: Source):
        super().__init__(src)
        self._keep = src._keep
        self._frames = self._skipped = 0

    def sync(self) -> None:
        st = self.stats
        st.lines, st.frames, st.skipped = self.lineno, self._frames, self._skipped

    def chunks(self) -> Iterator[Any]:
        """Whole lines, a block at a time (ending in a newline), or ``_LONG`` for a line longer
        than _MAX_LINE, skipped as it is read (its size in ``self.long_bytes``): the lines of
        :meth:`_Reader.blocks`, uncut."""
        read = self.src._stream.read
        carry = b""
        long = 0  # bytes of a too-long line skipped so far
        while True:
            b = read(_BLOCK)
            if not b:
                if long:
                    self.long_bytes = long
                    yield _LONG
                elif carry:
                    yield carry + b"\n"
                return
            if long:
                k = b.find(b"\n")
                if k < 0:
                    long += len(b)
                    continue
                self.long_bytes, long = long + k, 0
                yield _LONG
                b = b[k + 1 :]
            buf = carry + b if carry else b
            cut = buf.rfind(b"\n") + 1
            carry = buf[cut:]
            if len(carry) > _MAX_LINE:
                long, carry = len(carry), b""
            if cut:
                yield buf[:cut]

    def read(self) -> Iterator[can.Message]:
        st = self.stats
        chans: dict[Any, tuple[Any, bool]] = {}  # channel code (the scan's) or text -> (channel, wanted)
        # an id's spelling (scan.pack of its text) -> (id, extended, kept, key), valid plain ids only
        ids: dict[int, tuple[int, bool, bool, int]] = {}
        keep = self._keep
        over = st.passed_over
        msg_cls = can.Message
        clock = self.clock
        slow = self.slow
        last = -_INF
        jump = _JUMP
        frames = skipped = 0
        lineno = 0
        fast = _use_scan(self.src.size)
        try:
            for chunk in self.chunks():
                if chunk is _LONG:
                    lineno += 1
                    self.long_line(lineno)
                    continue
                if fast:
                    r = scan.lines(chunk, False)
                    rows: Any = zip(
                        r[3].tolist(),
                        r[4].tolist(),
                        r[5].tolist(),
                        r[7].tolist(),
                        r[8].tolist(),
                        r[9].tolist(),
                        r[11].tolist(),
                        r[12].tolist(),
                        r[15].tolist(),
                    )
                    data = r[10].tobytes()
                    ch_lo, ch_hi = r[13].tolist(), r[14].tolist()
                else:
                    rows = _refused(chunk)
                for i, (code, s, e, ts, key, spelled, dlc, ch_code, rx) in enumerate(rows):
                    lineno += 1
                    if code:
                        if code == scan.EMPTY:
                            continue
                        msg = slow(lineno, chunk[s:e], last, chans, ids)
                        if msg is None:
                            continue
                        if msg is _SKIPPED:
                            skipped += 1
                            continue
                        ts = msg.timestamp
                    else:
                        ch = chans.get(ch_code)
                        if ch is None:
                            ch = self._chan(chunk[ch_lo[i] : ch_hi[i]])
                            if ch is None:
                                self.bad(lineno, f"more than {_MAX_CHANNELS} distinct channels", chunk[s:e])
                                continue
                            chans[ch_code] = ch
                        if not ch[1]:
                            skipped += 1
                            continue
                        known = ids.get(spelled)
                        if known is not None and not known[2]:
                            over[key] = over.get(key, 0) + 1  # an id nobody decodes (keep_ids)
                            continue
                        if not last <= ts < last + jump and not clock(ts, last, lineno, chunk[s:e]):
                            continue
                        ext = key > _EFF_MASK
                        aid = key & _EFF_MASK
                        if known is None and len(ids) < _ID_CACHE_MAX:
                            ids[spelled] = (aid, ext, keep is None or key in keep, key)
                        # Positional: half the cost of keywords.  Order of can.Message (4.x): timestamp,
                        # arbitration_id, is_extended_id, is_remote_frame, is_error_frame, channel,
                        # dlc, data, is_fd, is_rx; tests check the fields.
                        msg = msg_cls(ts, aid, ext, False, False, ch[0], dlc, data[8 * i : 8 * i + dlc], False, rx == 1)
                    last = ts
                    if not frames:
                        self._first_good = lineno
                    frames += 1
                    if not lineno & 0xFFF:
                        self.lineno, self._frames, self._skipped = lineno, frames, skipped
                        self.sync()
                    yield msg
        finally:
            self.lineno, self._frames, self._skipped = lineno, frames, skipped
            self.end_clock(last)

    def slow(self, n: int, line: bytes, last: float, chans: dict, ids: dict[int, tuple[int, bool, bool, int]]) -> Any:
        """A line the scan refused (or any line, without it), by the tolerant rules: its message,
        None (a bad line, a frame dropped), or ``_SKIPPED`` (a channel not asked for)."""
        parts = line.split()
        if len(parts) == 3:
            ts_b, ch_b, frame = parts
            rx = True
        elif not parts:
            return None
        elif len(parts) == 4 and parts[3] in _DIRS:
            ts_b, ch_b, frame, d = parts
            rx = _DIRS[d]
        else:
            self.bad(n, "not '(time) channel id#data'", line)
            return None
        ch = chans.get(ch_b)
        if ch is None:
            ch = self._chan(ch_b)
            if ch is None:
                self.bad(n, f"more than {_MAX_CHANNELS} distinct channels", line)
                return None
            chans[ch_b] = ch
        if not ch[1]:
            return _SKIPPED
        id_b, sep, data = frame.partition(b"#")
        key = ids.get(scan.pack(id_b)) if len(id_b) in (3, 8) else None
        if key is not None and not key[2]:
            over = self.stats.passed_over
            over[key[3]] = over.get(key[3], 0) + 1  # an id nobody decodes (keep_ids)
            return None
        try:
            ts = float(ts_b[1:-1])
        except ValueError:
            ts = None
        if ts is None or ts_b[0] != 40 or ts_b[-1] != 41:  # '(' and ')'
            self.bad(n, "bad timestamp", line)
            return None
        if not last <= ts < last + _JUMP and not self.clock(ts, last, n, line):
            return None
        try:
            payload = binascii.unhexlify(data)
        except ValueError:
            payload = None
        if key is None or payload is None or len(payload) > 8 or not sep:
            msg = self.odd(n, line, ts, ch[0], rx, id_b, sep, data, ids)
            if msg is not None and msg.is_error_frame:
                self.stats.error_frames += 1
            return msg
        return can.Message(ts, key[0], key[1], False, False, ch[0], len(payload), payload, False, rx)

    def _chan(self, ch_b: bytes) -> tuple[Any, bool] | None:
        name = ch_b.decode("ascii", "replace")
        if not self.channel_name(name):
            return None
        value: Any = int(name) if name.isdigit() else name
        return value, self._want is None or value in self._want

    def odd(
        self,
        n: int,
        line: bytes,
        ts: float,
        chan: Any,
        rx: bool,
        id_b: bytes,
        sep: bytes,
        data: bytes,
        ids: dict[int, tuple[int, bool, bool, int]],
    ) -> can.Message | None:
        """Everything but a plain known-id classic frame: new ids, remote, FD, error frames, bad lines."""
        bad = self.bad
        if not sep:
            bad(n, "no '#' between id and data", line)
            return None
        if len(id_b) not in (3, 8):
            bad(n, "id is not 3 or 8 hex digits", line)
            return None
        try:
            aid = int.from_bytes(binascii.unhexlify(id_b if len(id_b) == 8 else b"0" + id_b), "big")
        except ValueError:
            bad(n, "id is not hex", line)
            return None
        ext = len(id_b) == 8
        err = ext and bool(aid & _ERR_FLAG)
        if not ext and aid > 0x7FF:
            bad(n, "standard id above 0x7FF", line)
            return None
        if ext and not err and aid > _EFF_MASK:
            bad(n, "extended id above 0x1FFFFFFF", line)
            return None
        if not err and len(ids) < _ID_CACHE_MAX:
            key = aid | EXT_KEY if ext else aid
            ids[scan.pack(id_b)] = (aid, ext, self._keep is None or key in self._keep, key)
        fd = remote = False
        flags = 0
        dlc = None
        if data[:1] == b"#":  # CAN FD: '##' + one flags nibble + data
            fd = True
            try:
                flags = int(data[1:2], 16)
            except ValueError:
                bad(n, "CAN FD flags are not one hex digit", line)
                return None
            data = data[2:]
        elif data[:1] in (b"R", b"r"):
            rest = data[1:]
            if rest and not (len(rest) == 1 and rest.isdigit() and int(rest) <= 8):
                bad(n, "bad remote frame length", line)
                return None
            remote, dlc, data = True, int(rest or 0), b""
        elif b"_" in data:  # classic 8-byte frame with raw DLC 9..15: '#1122334455667788_C'
            data, _, raw_dlc = data.partition(b"_")
            if len(data) != 16 or len(raw_dlc) != 1 or raw_dlc not in b"9ABCDEFabcdef":
                bad(n, "bad raw DLC suffix", line)
                return None
        if len(data) % 2:
            bad(n, "odd number of data hex digits", line)
            return None
        try:
            payload = binascii.unhexlify(data)
        except ValueError:
            bad(n, "data is not hex", line)
            return None
        if fd:
            if len(payload) not in _FD_LENGTHS:
                bad(n, f"CAN FD length {len(payload)} is not a valid FD length", line)
                return None
        elif len(payload) > 8:
            bad(n, f"{len(payload)} data bytes in a classic frame (max 8)", line)
            return None
        return can.Message(
            timestamp=ts,
            arbitration_id=aid & _EFF_MASK,
            is_extended_id=ext,
            is_remote_frame=remote,
            is_error_frame=err,
            channel=chan,
            dlc=len(payload) if dlc is None else dlc,
            data=payload,
            is_fd=fd,
            bitrate_switch=bool(flags & 1),
            error_state_indicator=bool(flags & 2),
            is_rx=rx,
        )


_SKIPPED = object()  # CandumpReader.slow: a frame of a channel not asked for


def _use_scan(size: int) -> bool:
    """Whether to parse with the compiled scan (:func:`vdp.io.scan.pays`)."""
    return scan.pays(size)


def _refused(chunk: bytes) -> Iterator[tuple]:
    """Every line of ``chunk`` as a row the scan refused: all go by the tolerant rules."""
    s = 0
    while True:
        e = chunk.find(b"\n", s)
        if e < 0:
            return
        yield (scan.FIELDS, s, e, 0.0, 0, 0, 0, 0, 0)
        s = e + 1
