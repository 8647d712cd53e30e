"""Reading CAN log files as a stream of :class:`can.Message`.

``open_log`` picks the reader from the file name (``.log`` candump -L, ``.asc``,
``.blf``, ``.trc``, ``.csv``, ``.mf4``; any of them gzipped as ``NAME.gz``),
streams the file, and never loads it whole.  Each format's reader is its own module
in :mod:`vdp.io.formats` (their registry), as python-can's ``can/io/``.

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

import gzip
import importlib.util
import os
import stat
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

import can

from ..errors import LogFormatError
from .formats import DEFAULT, READERS
from .formats.base import _GZ_MAGIC, _SNIFF, _TEXT, EXT_KEY, FORMATS, BadLine, Damage, LogStats, _msg, channel_keys

# what other modules take from here (the readers' shared names live in vdp.io.formats.base)
__all__ = ["EXT_KEY", "FORMATS", "BadLine", "Damage", "LogSource", "LogStats", "channel_keys", "open_log"]


def open_log(path: str | Path, strict: bool = False, channel: str | None = None, quiet: bool = False) -> LogSource:
    """Open a CAN log for streaming.

    ``strict``: the first bad line raises LogFormatError instead of being skipped.
    ``channel``: keep only frames of this bus channel (frames without one are kept).
    ``quiet``: log no warnings (the stats still count everything).
    """
    return LogSource(Path(path), strict=strict, channel=channel, quiet=quiet)


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
        return READERS.get(self.format, DEFAULT)(self).frames()

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
