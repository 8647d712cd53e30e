"""What every log reader shares: limits, the statistics of a read, bad records, the clock,
channels and the end-of-file report (:class:`_Reader`).
"""

from __future__ import annotations

import gzip
import logging
import math
import re
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from itertools import chain
from typing import Any, Protocol

import can

from ...errors import LogFormatError

log = logging.getLogger("vdp.io.logs")  # the readers speak as vdp.io.logs, the name users filter on

FORMATS = (".log", ".asc", ".blf", ".trc", ".csv", ".mf4")
_TEXT = {".log", ".asc", ".trc", ".csv"}
# what a reader expects, said where none of a file's lines is read (another tool's export)
_LAYOUTS = {
    ".csv": "; a .csv log is python-can's: a header, then timestamp,arbitration_id,extended,remote,"
    "error,dlc,data per line (the id in hex, the data in base64); convert another tool's export to it or to candump",
    ".log": "; a .log is candump -L: '(1700000000.000000) can0 123#0011223344556677' per line",
}
_GZ_MAGIC = b"\x1f\x8b"
_SNIFF = 4096
_MAX_EXAMPLES = 100
_WRONG_FORMAT_AFTER = 100  # this many bad lines before any good one: not a log of this format
_RESYNC_AFTER = 10  # consecutive in-order lines behind the clock: the clock jumped back, follow it
_BLF_HEADER_SIZE = 144
_MAX_LINE = 1 << 16  # bytes: a longer line is skipped in pieces, never held whole (a gzip line bomb)
_BLOCK = 1 << 16  # bytes read at a time from text logs
_LONG = bytes(bytearray(b"\x00LONG\x00"))  # marks a too-long line (compared by identity, never equal by chance)
_MAX_TS = 1e10  # s (year 2286): later stamps are nonsense; near 1e21 a 10 ms tick cannot even advance
_JUMP = 3600.0  # s: a forward jump beyond this starts a new run of bus time (one far-future frame)
_MAX_CHANNELS = 1024  # distinct channel names: garbage beyond this is bad lines, not a growing table
_MAX_OBJ = 1 << 24  # bytes: a BLF object (or an inflated container) claiming more is damage
_MAX_INNER = 1 << 20  # bytes: a BLF object inside a container claiming more is damage
_MAX_DAMAGE = 100  # damage records kept (counts stay exact)

_ERR_FLAG = 0x20000000  # CAN_ERR_FLAG in a candump id
_EFF_MASK = 0x1FFFFFFF
_FD_LENGTHS = frozenset((0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64))
_DIRS = {b"R": True, b"r": True, b"T": False, b"t": False}
_INF = math.inf
_ID_CACHE_MAX = 1 << 16
EXT_KEY = 1 << 31  # marks an extended id in id keys (keep_ids, the decoder's plans): 0x123 != 0x00000123


def channel_keys(want: str) -> frozenset[Any]:
    """Every form a bus channel name takes across log formats: "can1" -> {"can1", "1", 1}."""
    keys: set[Any] = {want}
    m = re.fullmatch(r"[A-Za-z_]*(\d+)", want)
    if m:
        keys.update((m.group(1), int(m.group(1))))
    return frozenset(keys)


@dataclass(frozen=True)
class BadLine:
    line: int  # 1-based line number; frame number for formats without lines
    reason: str
    text: str


@dataclass(frozen=True)
class Damage:
    """A stretch of a file that could not be read: where, how much, why."""

    at: int  # byte offset in the (uncompressed) file, -1 if unknown
    bytes: int  # bytes skipped (-1: unknown, e.g. the rest of a truncated gzip stream)
    reason: str


@dataclass
class LogStats:
    """What reading a log found.  Counts are exact; only the examples are capped."""

    unit: str = "line"  # what BadLine.line counts: "line" (text formats) or "frame" (others)
    lines: int = 0
    frames: int = 0  # frames handed out
    error_frames: int = 0  # of those, error frames
    skipped: int = 0  # frames of other bus channels
    bad: int = 0
    resyncs: int = 0  # times the log's clock jumped back and we followed it
    jumps: int = 0  # forward clock jumps beyond _JUMP (not counted as bus time)
    bus_time: float | None = None  # s: frames' time span summed over the runs between clock steps (once read)
    reasons: dict[str, int] = field(default_factory=dict)
    examples: list[BadLine] = field(default_factory=list)
    channels: set[str] = field(default_factory=set)
    # frames of ids outside keep_ids(): id key -> count (never handed out)
    passed_over: dict[int, int] = field(default_factory=dict)
    passed_over_other: int = 0  # frames of such ids beyond the id cache (bulk reader): counted, not stored
    damage: list[Damage] = field(default_factory=list)
    damaged: int = 0  # damaged stretches (exact; ``damage`` keeps the first _MAX_DAMAGE)
    lost_bytes: int = 0  # bytes skipped in them (known sizes only)
    truncated: bool = False  # the file (or its gzip stream) ends early

    def add_bad(self, n: int, reason: str, text: str) -> None:
        self.bad += 1
        self.reasons[reason] = self.reasons.get(reason, 0) + 1
        if len(self.examples) < _MAX_EXAMPLES:
            self.examples.append(BadLine(n, reason, text[:120]))

    def add_damage(self, at: int, nbytes: int, reason: str) -> None:
        self.damaged += 1
        if nbytes > 0:
            self.lost_bytes += nbytes
        if len(self.damage) < _MAX_DAMAGE:
            self.damage.append(Damage(at, nbytes, reason))

    def damage_summary(self) -> str:
        """One line on what was lost, or "" for an undamaged file."""
        if not self.damaged:
            return ""
        first = self.damage[0]
        # where the reader found it: a corrupt gzip stream shows only at its end (the CRC check),
        # however early the damage lies; what it held before that came out as bad lines, if at all
        where = f" (found at byte {first.at:,} of the file)" if first.at >= 0 else ""
        unknown = any(d.bytes < 0 for d in self.damage)
        if self.lost_bytes:
            lost = f"{'at least ' if unknown else ''}{self.lost_bytes:,} bytes skipped"
        elif unknown:
            lost = "how much was lost is unknown"
        else:
            lost = "nothing skipped"
        if self.truncated:
            lost += ", the file ends early"
        bad = f"; {self.bad:,} bad {self.unit}s rejected in all" if self.bad else ""
        return (
            f"damaged in {self.damaged} place(s), {lost}; {self.frames:,} frames read{bad}; "
            f"first: {first.reason}{where}"
        )

    def as_dict(self) -> dict[str, Any]:
        return {
            # frames in the log: handed out plus passed over
            "lines": self.lines,
            "frames": self.frames + sum(self.passed_over.values()) + self.passed_over_other,
            "error_frames": self.error_frames,
            "passed_over": sum(self.passed_over.values()) + self.passed_over_other,
            "skipped_other_channels": self.skipped,
            "bad_lines": self.bad,
            "resyncs": self.resyncs,
            "clock_jumps_forward": self.jumps,
            "bus_time_s": self.bus_time,
            "bad_reasons": dict(self.reasons),
            "channels": sorted(self.channels),
            "bad_examples": [{self.unit: b.line, "reason": b.reason, "text": b.text} for b in self.examples],
            "damage": {
                "summary": self.damage_summary(),
                "places": self.damaged,
                "bytes_skipped": self.lost_bytes,
                "truncated": self.truncated,
                "examples": [{"at": d.at, "bytes": d.bytes, "reason": d.reason} for d in self.damage],
            },
        }


class _Quiet:
    def warning(self, *args, **kwargs) -> None:
        pass


_QUIET = _Quiet()


class Source(Protocol):
    """What a reader takes from the source that opened its file and chose it (vdp.io.logs.LogSource):
    named here, so that the formats need not import the module that imports them."""

    path: Any
    stats: LogStats
    strict: bool
    quiet: bool
    channel: str | None
    format: str
    size: int
    compressed: bool
    _want: Any
    _keep: Any
    _stream: Any
    _reader: Any

    position: Any  # where the source has read to (a property of LogSource)

    def close(self) -> None: ...


class _Reader:
    """What every format shares: bad records, the clock, channels, the end-of-file report."""

    def __init__(self, src: Source):
        self.src = src
        self.path = src.path
        self.stats = src.stats
        self.strict = src.strict
        self.log = _QUIET if src.quiet else log
        self._want = src._want
        self._first_good: int | None = None
        self._seg = 0.0  # start of the current run of bus time
        self._back_run = 0
        self._back_last = 0.0
        self._back_ref = -_INF  # the clock when the last line behind it came
        self.lineno = 0
        self.long_bytes = 0
        self.stats.bus_time = 0.0

    # -- bad records ---------------------------------------------------------
    def bad(self, n: int, reason: str, text: bytes | str) -> None:
        if isinstance(text, bytes):
            text = text.decode("ascii", "replace")
        text = text.rstrip("\r\n")
        st = self.stats
        if self.strict:
            raise LogFormatError(f"{self.path}: {st.unit} {n}: {reason}: {text[:80]!r}")
        st.add_bad(n, reason, text)
        if self._first_good is None and st.bad >= _WRONG_FORMAT_AFTER and st.unit == "line":
            first = st.examples[0]
            what = "a candump -L log" if self.src.format == ".log" else f"a valid {self.src.format} file"
            raise LogFormatError(
                f"{self.path}: not {what}: the first {st.bad} lines are unreadable (line {first.line}: {first.reason})"
            )

    def damaged(self, at: int, nbytes: int, reason: str) -> None:
        if self.strict:
            raise LogFormatError(f"{self.path}: damaged at byte {at}: {reason}")
        self.stats.add_damage(at, nbytes, reason)

    # -- the clock -----------------------------------------------------------
    def clock(self, ts: float, last: float, n: int, text: bytes | str) -> bool:
        """The slow path for a timestamp outside ``[last, last + _JUMP)``: True to use the frame.

        The callers' fast path is ``last <= ts < last + _JUMP``; ``last`` is -inf before
        the first frame.  A run of ``_RESYNC_AFTER`` frames behind the clock (and in order
        among themselves, with no good frame between) means the clock stepped back: follow it.
        """
        st = self.stats
        if not 0.0 <= ts < _MAX_TS:
            self.bad(n, _time_reason(ts), text)
            return False
        if last == -_INF:
            self._seg = ts
            return True
        if ts >= last:
            st.bus_time += last - self._seg
            self._seg = ts
            st.jumps += 1
            self.log.warning("%s: %s %d: clock jumped %.0f s forward", self.path, st.unit, n, ts - last)
            return True
        if self._back_run and ts >= self._back_last and self._back_ref == last:
            self._back_run += 1
        else:
            self._back_run = 1
        self._back_last, self._back_ref = ts, last
        if self._back_run < _RESYNC_AFTER:
            self.bad(n, "timestamp goes backwards", text)
            return False
        self.log.warning("%s: %s %d: clock jumped back %.6f s; following it", self.path, st.unit, n, last - ts)
        st.resyncs += 1
        st.bus_time += last - self._seg
        self._seg = ts
        self._back_run = 0
        return True

    def end_clock(self, last: float) -> None:
        if last > -_INF:
            self.stats.bus_time += last - self._seg

    # -- channels --------------------------------------------------------------
    def channel_name(self, name: str) -> bool:
        """Note a channel; False if too many distinct names were seen already (garbage)."""
        chans = self.stats.channels
        if name in chans:
            return True
        if len(chans) >= _MAX_CHANNELS:
            return False
        chans.add(name)
        return True

    # -- lines -----------------------------------------------------------------
    def blocks(self) -> Iterator[Any]:
        """Lists of lines (without their newline), read in blocks of _BLOCK bytes.

        Splitting blocks is faster than reading line by line, and bounds a line: one
        longer than _MAX_LINE is dropped as it is read and stands as the ``_LONG`` marker
        (its size in ``self.long_bytes``).  Chain them with itertools.chain.from_iterable.
        """
        read = self.src._stream.read
        carry = b""
        long = 0  # bytes of a too-long line skipped so far
        while True:
            b = read(_BLOCK)
            if not b:
                if long:
                    self.long_bytes = long
                    yield (_LONG,)
                elif carry:
                    yield (carry,)
                return
            if long:
                k = b.find(b"\n")
                if k < 0:
                    long += len(b)
                    continue
                self.long_bytes, long = long + k, 0
                yield (_LONG,)
                b = b[k + 1 :]
            parts = (carry + b).split(b"\n") if carry else b.split(b"\n")
            carry = parts.pop()
            if len(carry) > _MAX_LINE:
                long, carry = len(carry), b""
            yield parts

    def long_line(self, n: int) -> None:
        self.bad(n, f"line longer than {_MAX_LINE} bytes", f"{self.long_bytes:,} bytes")

    def lines(self) -> Iterator[str]:
        """Decoded lines of a text log, bounded in length; sets ``self.lineno``."""
        for n, line in enumerate(chain.from_iterable(self.blocks()), 1):
            self.lineno = n
            if line is _LONG:
                self.long_line(n)
                continue
            yield line.decode("utf-8", "replace")

    # -- the end -----------------------------------------------------------------
    def finish(self) -> None:
        st, src = self.stats, self.src
        if st.frames == 0 and st.skipped == 0:
            where = f"{st.lines} lines" if st.unit == "line" and st.lines else "the file"
            first = f"; {st.unit} {st.examples[0].line}: {st.examples[0].reason}" if st.examples else ""
            if st.damaged:
                first += f"; {st.damage_summary()}"
            what = "" if src.format == ".log" or not st.bad else f"not a valid {src.format} file: "
            layout = _LAYOUTS.get(src.format, "") if st.bad else ""
            raise LogFormatError(f"{self.path}: {what}no CAN frames in {where}{first}{layout}")
        if st.frames == 0:
            self.log.warning(
                "%s: no frames on channel %s; channels in the log: %s",
                self.path,
                src.channel,
                ", ".join(sorted(st.channels)) or "none",
            )
        if st.bad:
            at = f"; first at {st.unit} {st.examples[0].line}" if st.examples else ""
            self.log.warning(
                "%s: skipped %d bad %s%s (%s%s)",
                self.path,
                st.bad,
                st.unit,
                "" if st.bad == 1 else "s",
                ", ".join(f"{k}: {v}" for k, v in st.reasons.items()),
                at,
            )
        if st.damaged:
            self.log.warning("%s: %s", self.path, st.damage_summary())

    def gzip_end(self, exc: BaseException) -> None:
        """A gzip stream that ends early or breaks: keep what was read, say what was lost."""
        st = self.stats
        st.truncated = isinstance(exc, EOFError)
        what = "gzip stream ends early (truncated file)" if st.truncated else f"corrupt gzip data ({_msg(exc)})"
        self.damaged(self.src.position, -1, f"{what} after {st.unit} {self.lineno}; nothing after it is readable")

    def frames(self) -> Iterator[can.Message]:
        try:
            yield from self.read()
        except LogFormatError:
            raise
        except (EOFError, zlib.error, gzip.BadGzipFile) as exc:
            if not self.src.compressed:
                raise self.corrupt(exc) from exc
            self.gzip_end(exc)
        except Exception as exc:
            raise self.corrupt(exc) from exc
        finally:
            self.sync()
            self.src.close()
        self.finish()

    def read(self) -> Iterator[can.Message]:
        raise NotImplementedError

    def sync(self) -> None:
        """Store counters kept in locals by the fast loops."""

    def corrupt(self, exc: BaseException) -> LogFormatError:
        st = self.stats
        if not st.frames and not st.skipped:
            return LogFormatError(f"{self.path}: not a valid {self.src.format} file: {_msg(exc)}")
        return LogFormatError(f"{self.path}: corrupt {self.src.format} file after {st.unit} {self.lineno}: {_msg(exc)}")

    def emit(self, n: int, msg: can.Message, last: float, text: Any) -> float | None:
        """Channel filter, sanity and clock for a frame from python-can; the new clock or None to drop it."""
        st = self.stats
        ch = msg.channel
        if ch is not None:
            if not self.channel_name(str(ch)):
                self.bad(n, f"more than {_MAX_CHANNELS} distinct channels", text)
                return None
            if self._want is not None and ch not in self._want:
                st.skipped += 1
                return None
        problem = _frame_problem(msg)
        if problem:
            self.bad(n, problem, text)
            return None
        ts = msg.timestamp
        if not last <= ts < last + _JUMP and not self.clock(ts, last, n, text):
            return None
        if self._first_good is None:
            self._first_good = n
        st.frames += 1
        if msg.is_error_frame:
            st.error_frames += 1
        return ts


def _frame_problem(msg: can.Message) -> str:
    """What makes a frame from python-can unusable, or ""."""
    aid = msg.arbitration_id
    if not isinstance(aid, int) or aid < 0 or aid > (_EFF_MASK if msg.is_extended_id else 0x7FF):
        return "extended id above 0x1FFFFFFF" if msg.is_extended_id else "standard id above 0x7FF"
    n = len(msg.data)
    if msg.is_fd:
        if n not in _FD_LENGTHS:
            return f"CAN FD length {n} is not a valid FD length"
    elif n > 8:
        return f"{n} data bytes in a classic frame (max 8)"
    if not msg.is_remote_frame and not msg.is_error_frame and n < min(msg.dlc, 8):
        return f"{n} data bytes but DLC {msg.dlc}"
    return ""


def _time_reason(ts: float) -> str:
    if math.isnan(ts) or ts in (_INF, -_INF):
        return "non-finite timestamp"
    if ts < 0:
        return "negative timestamp"
    if ts >= _MAX_TS:
        return "timestamp out of range (after year 2286)"
    return "timestamp goes backwards"


def _msg(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__
