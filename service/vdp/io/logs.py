"""Reading CAN log files as a stream of :class:`can.Message`.

``open_log`` picks the reader from the file name (``.log`` candump -L, ``.asc``,
``.blf``, ``.trc``, ``.csv``, ``.mf4``; any of them gzipped as ``NAME.gz``),
streams the file, and never loads it whole.  candump logs go through our own
tolerant parser: python-can's stops at the first bad line, ours skips it,
counts it and keeps going.  Every problem with the file itself (missing,
empty, wrong format, truncated, corrupt) is a one-line
:class:`vdp.errors.LogFormatError`.

Channel convention: candump names ("can0") are kept as strings; formats with
numbered channels give 0-based ints (python-can's ASC and BLF readers already
do; TRC is shifted to match), and ``channel_keys("can0")`` matches both.
"""

from __future__ import annotations

import binascii
import gzip
import importlib.util
import io
import logging
import math
import re
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import can

from ..errors import LogFormatError

log = logging.getLogger(__name__)

FORMATS = (".log", ".asc", ".blf", ".trc", ".csv", ".mf4")
_TEXT = {".log", ".asc", ".trc", ".csv"}
_GZ_MAGIC = b"\x1f\x8b"
_SNIFF = 4096
_MAX_EXAMPLES = 100
_WRONG_FORMAT_AFTER = 100  # this many bad lines before any good one: not a candump log
_RESYNC_AFTER = 10  # consecutive in-order lines behind the clock: the clock jumped back, follow it
_BLF_HEADER_SIZE = 144

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


@dataclass
class LogStats:
    """What reading a log found.  Counts are exact; only the examples are capped."""

    unit: str = "line"  # what BadLine.line counts: "line" (candump) or "frame" (other formats)
    lines: int = 0
    frames: int = 0  # frames handed out
    error_frames: int = 0  # of those, error frames
    skipped: int = 0  # frames of other bus channels
    bad: int = 0
    resyncs: int = 0  # times the log's clock jumped back and we followed it
    reasons: dict[str, int] = field(default_factory=dict)
    examples: list[BadLine] = field(default_factory=list)
    channels: set[str] = field(default_factory=set)
    # frames of ids outside keep_ids(): id key -> count (never handed out)
    passed_over: dict[int, int] = field(default_factory=dict)

    def add_bad(self, n: int, reason: str, text: str) -> None:
        self.bad += 1
        self.reasons[reason] = self.reasons.get(reason, 0) + 1
        if len(self.examples) < _MAX_EXAMPLES:
            self.examples.append(BadLine(n, reason, text[:120]))

    def as_dict(self) -> dict[str, Any]:
        return {
            # frames in the log: handed out plus passed over
            "lines": self.lines,
            "frames": self.frames + sum(self.passed_over.values()),
            "error_frames": self.error_frames,
            "passed_over": sum(self.passed_over.values()),
            "skipped_other_channels": self.skipped,
            "bad_lines": self.bad,
            "resyncs": self.resyncs,
            "bad_reasons": dict(self.reasons),
            "channels": sorted(self.channels),
            "bad_examples": [{self.unit: b.line, "reason": b.reason, "text": b.text} for b in self.examples],
        }


def open_log(path: str | Path, strict: bool = False, channel: str | None = None) -> LogSource:
    """Open a CAN log for streaming.

    ``strict``: the first bad line raises LogFormatError instead of being skipped.
    ``channel``: keep only frames of this bus channel (frames without one are kept).
    """
    return LogSource(Path(path), strict=strict, channel=channel)


class LogSource:
    """An opened log: iterate it once for :class:`can.Message` objects.

    ``size`` and ``position`` (bytes of the file on disk; for gzip the
    position in the compressed stream) drive progress bars; ``stats`` fills in
    while iterating.
    """

    def __init__(self, path: Path, strict: bool = False, channel: str | None = None):
        self.path = path
        self.strict = strict
        self.channel = channel
        self._want = channel_keys(channel) if channel is not None else None
        self._used = False
        self._first_good: int | None = None
        self._keep: frozenset[int] | None = None
        name = path.name
        suffixes = [s.lower() for s in path.suffixes]
        named_gz = bool(suffixes) and suffixes[-1] == ".gz"
        fmt = suffixes[-2] if named_gz and len(suffixes) >= 2 else (suffixes[-1] if suffixes else "")
        if fmt not in FORMATS:
            raise LogFormatError(
                f"{path}: unknown log format '{''.join(path.suffixes) or name}'; "
                f"supported: {', '.join(FORMATS)} (each optionally .gz)"
            )
        self.format = fmt
        self.stats = LogStats(unit="line" if fmt == ".log" else "frame")
        try:
            self.size = path.stat().st_size
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
                head = gzip.GzipFile(fileobj=raw, mode="rb").read(_SNIFF)
            except (OSError, EOFError, zlib.error) as exc:
                raise LogFormatError(f"{path}: corrupt or truncated gzip: {_msg(exc)}") from None
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
        if fmt != ".log":
            self._reader = self._make_reader()

    def _make_reader(self) -> can.io.generic.MessageReader:
        fmt, path = self.format, self.path
        if fmt == ".mf4" and importlib.util.find_spec("asammdf") is None:
            raise LogFormatError(f"{path}: reading .mf4 needs asammdf; install it with: pip install 'vdp[mf4]'")
        cls = can.io.player.MESSAGE_READERS[fmt]
        if fmt in _TEXT:
            src: Any = io.TextIOWrapper(self._stream, encoding="utf-8", errors="replace")
        else:
            src = self._stream
        try:
            reader = cls(src)
        except Exception as exc:
            raise LogFormatError(f"{path}: not a readable {fmt} file: {_msg(exc)}") from exc
        if fmt == ".blf" and not self.compressed and reader.file_size > max(self.size, _BLF_HEADER_SIZE):
            # The writer records the final size in the header; a cut file is shorter.
            raise LogFormatError(f"{path}: truncated BLF: {self.size} of {reader.file_size} bytes")
        return reader

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
        handed out, as are frames of formats read by python-can.
        """
        if self._used:
            raise RuntimeError("keep_ids() must come before iterating")
        self._keep = frozenset(keys)

    def __iter__(self) -> Iterator[can.Message]:
        if self._used:
            raise RuntimeError("a LogSource can be iterated only once; open the log again")
        self._used = True
        return self._candump() if self.format == ".log" else self._frames()

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

    def _bad(self, n: int, reason: str, text: bytes | str) -> None:
        if isinstance(text, bytes):
            text = text.decode("ascii", "replace")
        text = text.rstrip("\r\n")
        if self.strict:
            raise LogFormatError(f"{self.path}: {self.stats.unit} {n}: {reason}: {text[:80]!r}")
        self.stats.add_bad(n, reason, text)
        if self._first_good is None and self.stats.bad >= _WRONG_FORMAT_AFTER and self.format == ".log":
            first = self.stats.examples[0]
            raise LogFormatError(
                f"{self.path}: not a candump -L log: the first {self.stats.bad} lines are "
                f"unreadable (line {first.line}: {first.reason})"
            )

    def _finish(self) -> None:
        st = self.stats
        if st.frames == 0 and st.skipped == 0:
            where = f"{st.lines} lines" if st.unit == "line" else "the file"
            first = f"; {st.unit} {st.examples[0].line}: {st.examples[0].reason}" if st.examples else ""
            raise LogFormatError(f"{self.path}: no CAN frames in {where}{first}")
        if st.frames == 0:
            log.warning(
                "%s: no frames on channel %s; channels in the log: %s",
                self.path,
                self.channel,
                ", ".join(sorted(st.channels)) or "none",
            )
        if st.bad:
            log.warning(
                "%s: skipped %d bad %ss (%s)",
                self.path,
                st.bad,
                st.unit,
                ", ".join(f"{k}: {v}" for k, v in st.reasons.items()),
            )

    def _corrupt(self, n: int, exc: BaseException) -> LogFormatError:
        if not self.stats.frames and not self.stats.skipped and not (self.compressed and _gzip_error(exc)):
            return LogFormatError(f"{self.path}: not a valid {self.format} file: {_msg(exc)}")
        what = "truncated or corrupt" + (" gzip" if self.compressed else "")
        return LogFormatError(f"{self.path}: {what} {self.format} file after {self.stats.unit} {n}: {_msg(exc)}")

    def _frames(self) -> Iterator[can.Message]:
        """python-can's reader for the format, with the same checks as our candump parser."""
        st, want, trc = self.stats, self._want, self.format == ".trc"
        last = 0.0
        n = 0
        try:
            for n, msg in enumerate(self._reader, 1):
                ch = msg.channel
                if trc and isinstance(ch, int):
                    ch = msg.channel = ch - 1  # TRC numbers buses from 1, python-can's writer adds 1
                if ch is not None:
                    st.channels.add(str(ch))
                    if want is not None and ch not in want:
                        st.skipped += 1
                        continue
                ts = msg.timestamp
                if not last <= ts < _INF:
                    self._bad(n, _time_reason(ts), str(msg))
                    continue
                last = ts
                st.frames += 1
                if msg.is_error_frame:
                    st.error_frames += 1
                yield msg
        except LogFormatError:
            raise
        except Exception as exc:
            raise self._corrupt(n, exc) from exc
        finally:
            self.close()
        self._finish()

    def _candump(self) -> Iterator[can.Message]:
        """Tolerant, fast candump -L parser over binary lines.

        The common line takes one split, one float, two dict lookups and one
        unhexlify; everything unusual goes to ``_odd``.
        """
        st = self.stats
        chans: dict[bytes, tuple[Any, bool]] = {}  # channel text -> (channel, wanted)
        # id text -> (id, extended, kept, key), valid plain ids only
        ids: dict[bytes, tuple[int, bool, bool, int]] = {}
        over = st.passed_over
        unhex = binascii.unhexlify
        msg_cls = can.Message
        last = 0.0
        back_run, back_last = 0, 0.0
        frames = skipped = 0
        lineno = 0
        try:
            for lineno, line in enumerate(self._stream, 1):
                parts = line.split()
                if len(parts) == 3:
                    ts_b, ch_b, frame = parts
                    rx = True
                elif not parts:
                    continue
                elif len(parts) == 4 and parts[3] in _DIRS:
                    ts_b, ch_b, frame, d = parts
                    rx = _DIRS[d]
                else:
                    self._bad(lineno, "not '(time) channel id#data'", line)
                    continue
                ch = chans.get(ch_b)
                if ch is None:
                    ch = chans[ch_b] = self._chan(ch_b)
                if not ch[1]:
                    skipped += 1
                    continue
                id_b, sep, data = frame.partition(b"#")
                key = ids.get(id_b)
                if key is not None and not key[2]:
                    over[key[3]] = over.get(key[3], 0) + 1  # an id nobody decodes (keep_ids)
                    continue
                try:
                    ts = float(ts_b[1:-1])
                except ValueError:
                    ts = None
                if ts is None or ts_b[0] != 40 or ts_b[-1] != 41:  # '(' and ')'
                    self._bad(lineno, "bad timestamp", line)
                    continue
                if not last <= ts < _INF:
                    if math.isnan(ts) or ts == _INF or ts < 0:
                        self._bad(lineno, _time_reason(ts), line)
                        continue
                    # Behind the clock: skip, unless a run of in-order lines says the clock jumped.
                    back_run = back_run + 1 if back_run and ts >= back_last else 1
                    back_last = ts
                    if back_run < _RESYNC_AFTER:
                        self._bad(lineno, "timestamp goes backwards", line)
                        continue
                    log.warning("%s: line %d: clock jumped back %.6f s; following it", self.path, lineno, last - ts)
                    st.resyncs += 1
                back_run = 0
                try:
                    payload = unhex(data)
                except ValueError:
                    payload = None
                if key is None or payload is None or len(payload) > 8 or not sep:
                    msg = self._odd(lineno, line, ts, ch[0], rx, id_b, sep, data, ids)
                    if msg is None:
                        continue
                    if msg.is_error_frame:
                        st.error_frames += 1
                else:
                    # Positional: half the cost of keywords.  Order of can.Message (4.x): timestamp,
                    # arbitration_id, is_extended_id, is_remote_frame, is_error_frame, channel,
                    # dlc, data, is_fd, is_rx; tests check the fields.
                    msg = msg_cls(ts, key[0], key[1], False, False, ch[0], len(payload), payload, False, rx)
                last = ts
                if not frames:
                    self._first_good = lineno
                frames += 1
                if not lineno & 0xFFF:
                    st.lines, st.frames, st.skipped = lineno, frames, skipped
                yield msg
        except LogFormatError:
            raise
        except Exception as exc:
            st.lines, st.frames, st.skipped = lineno, frames, skipped
            raise self._corrupt(lineno, exc) from exc
        finally:
            st.lines, st.frames, st.skipped = lineno, frames, skipped
            self.close()
        self._finish()

    def _chan(self, ch_b: bytes) -> tuple[Any, bool]:
        name = ch_b.decode("ascii", "replace")
        self.stats.channels.add(name)
        value: Any = int(name) if name.isdigit() else name
        return value, self._want is None or value in self._want

    def _odd(
        self,
        n: int,
        line: bytes,
        ts: float,
        chan: Any,
        rx: bool,
        id_b: bytes,
        sep: bytes,
        data: bytes,
        ids: dict[bytes, tuple[int, bool, bool, int]],
    ) -> can.Message | None:
        """Everything but a plain known-id classic frame: new ids, remote, FD, error frames, bad lines."""
        if not sep:
            self._bad(n, "no '#' between id and data", line)
            return None
        if len(id_b) not in (3, 8):
            self._bad(n, "id is not 3 or 8 hex digits", line)
            return None
        try:
            aid = int.from_bytes(binascii.unhexlify(id_b if len(id_b) == 8 else b"0" + id_b), "big")
        except ValueError:
            self._bad(n, "id is not hex", line)
            return None
        ext = len(id_b) == 8
        err = ext and bool(aid & _ERR_FLAG)
        if not ext and aid > 0x7FF:
            self._bad(n, "standard id above 0x7FF", line)
            return None
        if ext and not err and aid > _EFF_MASK:
            self._bad(n, "extended id above 0x1FFFFFFF", line)
            return None
        if not err and len(ids) < _ID_CACHE_MAX:
            key = aid | EXT_KEY if ext else aid
            ids[id_b] = (aid, ext, self._keep is None or key in self._keep, key)
        fd = remote = False
        flags = 0
        dlc = None
        if data[:1] == b"#":  # CAN FD: '##' + one flags nibble + data
            fd = True
            try:
                flags = int(data[1:2], 16)
            except ValueError:
                self._bad(n, "CAN FD flags are not one hex digit", line)
                return None
            data = data[2:]
        elif data[:1] in (b"R", b"r"):
            rest = data[1:]
            if rest and not (len(rest) == 1 and rest.isdigit() and int(rest) <= 8):
                self._bad(n, "bad remote frame length", line)
                return None
            remote, dlc, data = True, int(rest or 0), b""
        elif b"_" in data:  # classic 8-byte frame with raw DLC 9..15: '#1122334455667788_C'
            data, _, raw_dlc = data.partition(b"_")
            if len(data) != 16 or len(raw_dlc) != 1 or raw_dlc not in b"9ABCDEFabcdef":
                self._bad(n, "bad raw DLC suffix", line)
                return None
        if len(data) % 2:
            self._bad(n, "odd number of data hex digits", line)
            return None
        try:
            payload = binascii.unhexlify(data)
        except ValueError:
            self._bad(n, "data is not hex", line)
            return None
        if fd:
            if len(payload) not in _FD_LENGTHS:
                self._bad(n, f"CAN FD length {len(payload)} is not a valid FD length", line)
                return None
        elif len(payload) > 8:
            self._bad(n, f"{len(payload)} data bytes in a classic frame (max 8)", line)
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


def _time_reason(ts: float) -> str:
    if math.isnan(ts) or ts in (_INF, -_INF):
        return "non-finite timestamp"
    if ts < 0:
        return "negative timestamp"
    return "timestamp goes backwards"


def _gzip_error(exc: BaseException) -> bool:
    return isinstance(exc, (EOFError, zlib.error, gzip.BadGzipFile))


def _msg(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__
