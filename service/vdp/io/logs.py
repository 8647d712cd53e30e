"""Reading CAN log files as a stream of :class:`can.Message`.

``open_log`` picks the reader from the file name (``.log`` candump -L, ``.asc``,
``.blf``, ``.trc``, ``.csv``, ``.mf4``; any of them gzipped as ``NAME.gz``),
streams the file, and never loads it whole.

Every format skips a bad record the same way: it is counted by reason, named
with its line (or frame) number, and the rest of the file is replayed;
``strict`` stops at the first one instead.  python-can's readers stop at the
first bad line, so candump, ASC, TRC and CSV lines go through our own loops
(python-can still parses ASC and TRC lines), and BLF through our own tolerant
container reader.  Damage to a file's structure (a corrupt BLF container, a
gzip stream that ends early) replays what can be read and records what was
lost in ``stats.damage``.  Problems with the file itself (missing, empty, not
a regular file, wrong format) are a one-line :class:`vdp.errors.LogFormatError`.

Memory stays bounded whatever the input: a line is read at most ``_MAX_LINE``
bytes at a time (a longer one is skipped in pieces), BLF objects are capped,
and the per-channel and per-id tables are capped.  Absurd timestamps (NaN,
negative, beyond ``_MAX_TS``) are bad records.  A clock step back is followed
after ``_RESYNC_AFTER`` frames (the frames before are skipped and counted),
and bus time is summed over the runs between clock steps, so one far-future
frame or a step back never gives a negative or absurd duration.

Channel convention: candump names ("can0") are kept as strings; formats with
numbered channels give 0-based ints (python-can's ASC and BLF readers already
do; TRC is shifted to match), and ``channel_keys("can0")`` matches both.
"""

from __future__ import annotations

import base64
import binascii
import gzip
import importlib.util
import io
import logging
import math
import os
import re
import stat
import struct
import sys
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from decimal import Decimal
from itertools import chain
from pathlib import Path
from typing import Any, BinaryIO

import can
from can.io import blf as _blf

from ..errors import LogFormatError
from . import scan

log = logging.getLogger(__name__)

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


def open_log(path: str | Path, strict: bool = False, channel: str | None = None, quiet: bool = False) -> LogSource:
    """Open a CAN log for streaming.

    ``strict``: the first bad line raises LogFormatError instead of being skipped.
    ``channel``: keep only frames of this bus channel (frames without one are kept).
    ``quiet``: log no warnings (the stats still count everything).
    """
    return LogSource(Path(path), strict=strict, channel=channel, quiet=quiet)


class _Quiet:
    def warning(self, *args, **kwargs) -> None:
        pass


_QUIET = _Quiet()


_NOT_REGULAR = (
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


class LogSource:
    """An opened log: iterate it once for :class:`can.Message` objects.

    ``size`` and ``position`` (bytes of the file on disk; for gzip the
    position in the compressed stream) drive progress bars; ``stats`` fills in
    while iterating.
    """

    def __init__(self, path: Path, strict: bool = False, channel: str | None = None, quiet: bool = False):
        self.path = path
        self.strict = strict
        self.quiet = quiet  # no warnings: a second reader of the same bytes (the profile check) says nothing new
        self.channel = channel
        self._want = channel_keys(channel) if channel is not None else None
        self._used = False
        self._keep: frozenset[int] | None = None
        name = path.name
        suffixes = [s.lower() for s in path.suffixes]
        named_gz = bool(suffixes) and suffixes[-1] == ".gz"
        fmt = suffixes[-2] if named_gz and len(suffixes) >= 2 else (suffixes[-1] if suffixes else "")
        if fmt not in FORMATS:
            if path.is_dir():  # (a folder's name has no suffix: say what it is, not its format)
                raise LogFormatError(f"{path}: is a directory, not a log file; vdp batch replays a folder's logs")
            if not path.exists():  # a mistyped folder or file name: not a question of its format
                raise LogFormatError(f"{path}: no such file or directory")
            raise LogFormatError(
                f"{path}: unknown log format '{''.join(path.suffixes) or name}'; "
                f"supported: {', '.join(FORMATS)} (each optionally .gz)"
            )
        self.format = fmt
        self.stats = LogStats(unit="line" if fmt in _TEXT else "frame")
        try:
            st = os.stat(path)
        except FileNotFoundError:
            raise LogFormatError(f"{path}: no such file") from None
        except OSError as exc:
            raise LogFormatError(f"{path}: cannot open: {exc.strerror or exc}") from None
        if stat.S_ISDIR(st.st_mode):
            raise LogFormatError(f"{path}: is a directory, not a log file")
        for test, what in _NOT_REGULAR:
            # Opening a FIFO blocks until a writer comes; a device never ends.  A log is a file.
            if test(st.st_mode):
                raise LogFormatError(f"{path}: is {what}, not a log file; copy the log to a regular file first")
        try:
            self.size = st.st_size
            self._raw: BinaryIO = open(path, "rb")
        except FileNotFoundError:
            raise LogFormatError(f"{path}: no such file") from None
        except IsADirectoryError:
            raise LogFormatError(f"{path}: is a directory, not a log file") from None
        except OSError as exc:
            raise LogFormatError(f"{path}: cannot open: {exc.strerror or exc}") from None
        try:
            self._open_stream(named_gz)
        except BaseException:
            self._raw.close()
            raise

    def _open_stream(self, named_gz: bool) -> None:
        path, raw = self.path, self._raw
        if self.size == 0:
            raise LogFormatError(f"{path}: file is empty")
        magic = raw.read(2)
        raw.seek(0)
        self.compressed = magic == _GZ_MAGIC
        if named_gz and not self.compressed:
            raise LogFormatError(f"{path}: named .gz but is not gzip-compressed")
        if self.compressed:
            try:
                # a bare inflater: a cut stream gives what it has instead of raising
                head = zlib.decompressobj(31).decompress(raw.read(1 << 16), _SNIFF)
            except zlib.error as exc:
                raise LogFormatError(f"{path}: corrupt gzip: {_msg(exc)}") from None
            raw.seek(0)  # sniffed with a throw-away reader so progress starts at 0
            self._stream: BinaryIO = gzip.GzipFile(fileobj=raw, mode="rb")  # type: ignore[assignment]
        else:
            self._stream = raw
            head = raw.peek(_SNIFF)[:_SNIFF]  # type: ignore[attr-defined]
        if not head:
            raise LogFormatError(f"{path}: file is empty")
        fmt = self.format
        if fmt == ".blf" and not head.startswith(b"LOGG"):
            raise LogFormatError(f"{path}: not a BLF file (no LOGG signature)")
        if fmt == ".mf4" and not head.startswith(b"MDF"):
            raise LogFormatError(f"{path}: not an MF4 file (no MDF signature)")
        if fmt in _TEXT and b"\x00" in head:
            raise LogFormatError(f"{path}: binary data in a {fmt} text log; is it another format?")
        if fmt == ".mf4":
            self._reader = self._make_reader()

    def _make_reader(self) -> can.io.generic.MessageReader:
        fmt, path = self.format, self.path
        if fmt == ".mf4" and importlib.util.find_spec("asammdf") is None:
            raise LogFormatError(f"{path}: reading .mf4 needs asammdf; install it with: pip install 'vdp[mf4]'")
        cls = can.io.player.MESSAGE_READERS[fmt]
        try:
            return cls(self._stream)
        except Exception as exc:
            raise LogFormatError(f"{path}: not a readable {fmt} file: {_msg(exc)}") from exc

    # -- progress ----------------------------------------------------------
    @property
    def position(self) -> int:
        """Bytes of the file consumed so far (compressed bytes for gzip)."""
        try:
            return self._raw.tell()
        except (ValueError, OSError):  # closed: all read
            return self.size

    @property
    def fraction(self) -> float:
        return min(1.0, self.position / self.size) if self.size else 1.0

    # -- iteration ---------------------------------------------------------
    def keep_ids(self, keys) -> None:
        """Hand out only frames whose id is in ``keys`` (extended ids with bit 31 set).

        A bus carries many ids nobody decodes; a candump line of one is counted in
        ``stats.passed_over`` by id and read no further than its id (a bad timestamp
        there goes unnoticed, and does not matter), which is most of a replay's reading
        cost.  The first line of each id (it fills the id cache) and error frames are still
        handed out, as are frames of the other formats.
        """
        if self._used:
            raise RuntimeError("keep_ids() must come before iterating")
        self._keep = frozenset(keys)

    def __iter__(self) -> Iterator[can.Message]:
        if self._used:
            raise RuntimeError("a LogSource can be iterated only once; open the log again")
        self._used = True
        return _READERS.get(self.format, _PythonCanReader)(self).frames()

    def close(self) -> None:
        for f in (getattr(self, "_stream", None), self._raw):
            if f is not None:
                try:
                    f.close()
                except Exception:  # closing a half-read gzip/zlib stream may complain; nothing to save
                    pass

    def __enter__(self) -> LogSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Reader:
    """What every format shares: bad records, the clock, channels, the end-of-file report."""

    def __init__(self, src: LogSource):
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


class CandumpReader(_Reader):
    """Tolerant candump -L reader.  A block's lines are parsed at once by the compiled scan
    (:mod:`vdp.io.scan`, the one candump parser); the lines it refuses (remote, FD and error
    frames, damage: rare) are read one by one by the tolerant rules of :meth:`slow`, which
    read every line the scan accepts exactly as the scan does (``tests/test_scan.py``).
    Without the compiled scan (:func:`_use_scan`), every line goes by those rules.
    """

    def __init__(self, src: LogSource):
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
_SCAN_FROM = 1 << 22  # bytes: a log this long pays for loading numba's compiled scan (~0.5 s) itself


def _use_scan(size: int) -> bool:
    """Whether to parse with the compiled scan: where numba is loaded already (a replay's
    estimator loads it), or the log is long enough to pay for loading it.  Either way the
    same frames (the scan reads a line only as the tolerant rules would)."""
    return ("numba" in sys.modules or size >= _SCAN_FROM) and scan.available()


def _refused(chunk: bytes) -> Iterator[tuple]:
    """Every line of ``chunk`` as a row the scan refused: all go by the tolerant rules."""
    s = 0
    while True:
        e = chunk.find(b"\n", s)
        if e < 0:
            return
        yield (scan.FIELDS, s, e, 0.0, 0, 0, 0, 0, 0)
        s = e + 1


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


def _chain(first: list[str], rest: Iterator[str]) -> Iterator[str]:
    yield from first
    yield from rest


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


class BlfReader(_Reader):
    """Vector BLF, tolerant of damage.

    python-can's reader stops at the first broken object, loses everything after an
    object whose size field is wrong (it waits for the size to arrive), and loops on a
    zero size.  Here every object is checked: a container whose size field is wrong
    is still read to the end of its own zlib stream; a stretch that cannot be read is
    skipped to the next ``LOBJ`` signature and recorded as damage.  Frames are decoded
    as python-can decodes them (its structs and constants).
    """

    def __init__(self, src: LogSource):
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


_READERS: dict[str, type[_Reader]] = {
    ".log": CandumpReader,
    ".asc": AscReader,
    ".trc": TrcReader,
    ".csv": CsvReader,
    ".blf": BlfReader,
}


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
