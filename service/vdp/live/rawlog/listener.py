"""The raw log's listener: its counts, opening and closing, and the receive thread's writes."""

from __future__ import annotations

import logging
import re
import shutil
import threading
import time
from pathlib import Path

import can

from ..reader import EXT, TX, message_of
from .files import _Files
from .recovery import RETRY_MIN, _Recovery
from .rotating import _Detached, _Rotating

log = logging.getLogger(__name__)

HOLD_MAX = 16_384  # frames pending at most: one more is flushed and checked first (~2 s of a saturated bus)
HEADS_MAX = 4096  # ids whose line head (channel, id) the raw log keeps made


class RawLog(_Files, _Recovery, can.Listener):
    """A Notifier listener; ``on_message_received`` never raises."""

    def __init__(
        self,
        directory: str | Path,
        max_bytes: int,
        max_files: int,
        prefix: str = "vdp",
        min_free: int | None = None,
        channel: str = "can0",
        drops=None,
    ):
        self.dir = Path(directory)
        self._heads: dict[int, tuple[str, str]] = {}  # id (bit 31: extended, bit 30: sent) -> line head, tail
        self.channel = channel  # the channel written for frames read from a socket (bus.frame_channel)
        # drops(): {cause: frames lost before vdp read them, so far}; each closed file's line in the
        # index ({prefix}-index.jsonl) says how many were lost while it was the open file
        self.drops = drops
        self.index = self.dir / f"{prefix}-index.jsonl"
        self._in_file = 0  # frames written to the open file
        self._drops_at_open: dict = {}
        self._rolling_all = False  # a block's rollover: every held frame is in the file being closed
        self.max_bytes = max_bytes
        # free-space floor: the oldest files go before the disk fills (default: room for two files)
        self.min_free = 2 * max_bytes if min_free is None else min_free
        self.max_files = max_files
        self.prefix = prefix
        self.current = self.dir / f"{prefix}-current.log"
        self._pattern = re.compile(rf"^{re.escape(prefix)}-(\d{{6,}})-[0-9TZ]+\.log$")
        self._lock = threading.Lock()  # the rx thread writes, the service thread flushes
        self._logger: _Rotating | None = None
        self._seq = 0
        self._opened_at = time.time()
        self.accepted = 0  # frames handed to the raw log
        self.written = 0  # of those, known to be in a file (flushed into a file found in place, or closed)
        self.lost = 0  # of those, in no file: logging was stopped, a write failed, or a file was deleted
        self._held: list[can.Message] = []  # the rest, pending: written to the open file since the last check
        self._verified = 0  # bytes of the open file at the last check: what follows are the held frames' lines
        self._ident: tuple[int, int] | None = None  # (device, inode) of the open file, and of its directory
        self._dir_ident: tuple[int, int] | None = None
        self.reopened = 0  # times the file or the directory vanished from under the log
        self.detached: str | None = None  # what happened the last time
        self._detached_at: float | None = None  # monotonic time of it
        self._lost_at: float | None = None  # monotonic time frames were last lost
        self.error: str | None = None
        self.disk_full = False
        self._failed_at: float | None = None
        self._retry = RETRY_MIN
        self.deleted = 0
        self.deleted_for_space = 0  # of those, deleted to keep free space above min_free

    # -- life cycle -------------------------------------------------------------------------
    def open(self) -> None:
        """Create the directory, close out a file left by a crash, start a new file."""
        with self._lock:
            try:
                self._open()
            except OSError as exc:
                self._fail(exc)

    def _open(self) -> None:
        self.dir.mkdir(parents=True, exist_ok=True)
        closed = self.closed_files()
        # never a number used before in this run: a directory made again starts after the last one
        self._seq = max(self._seq, (int(self._pattern.match(closed[-1].name).group(1)) + 1) if closed else 1)
        if self.current.is_file():
            self._salvage()
        self._opened_at = time.time()
        logger = _Rotating(
            self.current, max_bytes=self.max_bytes, before_rollover=self._in_place, after_rollover=self._opened
        )
        logger.namer = lambda _default: str(self._next_name())
        logger.rotator = lambda src, dst: self._rotate(src, dst, rolling=True)
        self._logger = logger
        self._opened(logger)
        self._start_file()
        self.error, self.disk_full, self._failed_at = None, False, None
        self._retry = RETRY_MIN
        self._prune()
        log.info("raw CAN log: %s (rotating at %d bytes, keeping %d files)", self.dir, self.max_bytes, self.max_files)
        free = shutil.disk_usage(self.dir).free
        if free < self.min_free:  # said at start, not first found when the disk is already full
            log.warning(
                "raw CAN log: %s has %.1f MiB free, less than the %.1f MiB kept free ([raw_log] min_free_mb): "
                "the oldest logs there are deleted for room, and logging pauses when none are left; "
                "give it a larger disk",
                self.dir,
                free / 2**20,
                self.min_free / 2**20,
            )

    def close(self) -> None:
        """Flush and close the open file, and name it like the other closed files."""
        with self._lock:
            self._check()  # a file deleted meanwhile: its pending frames go into a new one first
            logger, self._logger = self._logger, None
            if logger is None:
                return
            try:
                logger.stop()
            except OSError as exc:  # a full disk: the last flush failed, a line may be cut in half
                self._fail(exc, closing=True)
                try:
                    if self.current.exists():
                        self._salvage("whose last write failed")  # cut the unfinished line, name it
                        self._prune()
                except OSError as again:
                    self._fail(again, closing=True)
                return
            try:
                if self.current.exists():
                    if self.current.stat().st_size:
                        self._rotate(self.current, self._next_name())
                    else:
                        self.current.unlink()
                self._settled(len(self._held))
            except OSError as exc:
                self._fail(exc, closing=True)

    @property
    def channel(self) -> str:
        return self._channel

    @channel.setter
    def channel(self, name: str) -> None:
        self._channel = name
        self._heads = {}  # the line heads name the channel

    @property
    def frames(self) -> int:
        """Frames written (the name /status and older callers use)."""
        return self.written

    def recently(self, seconds: float) -> list[str]:
        """What /health should say about the last ``seconds``: frames lost, the file replaced."""
        now = time.monotonic()
        out = []
        if self._lost_at is not None and now - self._lost_at <= seconds:
            out.append(f"raw log lost {self.lost} frame(s) in all, the last {now - self._lost_at:.0f} s ago")
        if self._detached_at is not None and now - self._detached_at <= seconds:
            out.append(f"raw log: {self.detached}; recording again in a new file")
        return out

    def stop(self) -> None:
        """Listener API: the Notifier calls this on every reconnect; the file stays open."""

    # -- receive thread -------------------------------------------------------------------------
    def on_message_received(self, msg: can.Message) -> None:
        with self._lock:
            self.accepted += 1
            if self._logger is None:
                self._lose(1)
                return
            if len(self._held) >= HOLD_MAX:
                self._check()
                if self._logger is None:
                    self._lose(1)
                    return
            self._held.append(msg)
            try:
                self._logger.on_message_received(msg)
                self._in_file += 1
            except Exception as exc:
                self._not_written(exc, [msg])

    def on_block(self, frames: list) -> None:
        """A block of frame records (:data:`vdp.live.reader.Frame`) from the receive thread: formatted
        as candump -L lines (python-can's CanutilsLogWriter's, byte for byte) and written in one call."""
        with self._lock:
            n = len(frames)
            self.accepted += n
            logger = self._logger
            if logger is None:
                self._lose(n)
                return
            if len(self._held) + n > HOLD_MAX:
                self._check()
                logger = self._logger
                if logger is None:
                    self._lose(n)
                    return
            self._held.extend(frames)
            try:
                self._write_lines(logger, frames)
                self._in_file += n
                if logger.max_bytes > 0 and logger.writer.file.tell() >= logger.max_bytes:
                    self._rolling_all = True
                    try:
                        logger.do_rollover()
                    finally:
                        self._rolling_all = False
            except _Detached as gone:  # found at the rotation: the held frames go into a new file
                self._reattach(gone, [])
            except Exception as exc:  # OSError (disk full) or a bug: what reached the file is counted
                self._fail(exc)

    def _write_lines(self, logger, frames: list) -> None:
        """Called with the lock held."""
        w = logger.writer
        write = w.file.write
        first = w.last_timestamp
        if first is None:  # python-can's writer clamps every timestamp to at least the file's first
            first = w.last_timestamp = frames[0][0] or 0.0
        chan = self.channel
        out: list[str] = []
        add = out.append
        heads, get = self._heads, self._heads.get
        for f in frames:
            ts, aid, fl, data, msg = f
            if fl & ~(EXT | TX) or (msg is not None and msg.channel != chan):
                if out:  # anything unusual (remote, error, FD, another channel): python-can's own writer
                    write("".join(out))
                    out.clear()
                w.on_message_received(message_of(f, chan))
                continue
            ts = ts if ts >= first else first
            # the line's parts after the time, made once an id (bounded: a bus of random ids is not cached)
            key = aid | (0x80000000 if fl & EXT else 0) | (0x40000000 if fl & TX else 0)
            head = get(key)
            if head is None:
                head = (f") {chan} {aid:08X}#" if fl & EXT else f") {chan} {aid:03X}#", " T\n" if fl & TX else " R\n")
                if len(heads) < HEADS_MAX:
                    heads[key] = head
            add(f"({ts:f}{head[0]}{data.hex().upper()}{head[1]}")
        if out:
            write("".join(out))

    def _write(self, msgs: list) -> None:
        """Write ``msgs`` (held until a check finds them in place); called with the lock held."""
        for k, msg in enumerate(msgs):
            self._held.append(msg)
            try:
                if type(msg) is tuple:
                    msg = message_of(msg, self.channel)
                self._logger.on_message_received(msg)
                self._in_file += 1
            except Exception as exc:
                self._not_written(exc, msgs[k:])
                return

    def _not_written(self, exc: Exception, rest: list[can.Message]) -> None:
        """Writing ``rest[0]`` (the last held frame) raised; ``rest[1:]`` are not written yet."""
        if isinstance(exc, _Detached):  # found at a rotation: the held frames and these go into a new file
            self._held.pop()  # not in the old file: the rotation comes before its line
            self._reattach(exc, rest)
        elif isinstance(exc, OSError):
            self._fail(exc)
            self._lose(len(rest) - 1)
        else:  # a bug must not stop the receive thread; the frame was not written
            self._held.pop()
            self._lose(1)
            self._fail(exc)
            self._lose(len(rest) - 1)

    def on_error(self, exc: Exception) -> None:
        """The bus failed; the service handles it.  Defined so the Notifier counts it as handled."""

    # -- service thread ------------------------------------------------------------------------
    def flush(self) -> None:
        """Push buffered lines to the OS (bounds what a crash loses to about one interval), and check the
        file is still in place: a file or directory deleted or moved away is replaced at once."""
        with self._lock:
            self._check()

    # -- helpers ---------------------------------------------------------------------------------
    def _settled(self, n: int) -> None:
        """The first ``n`` held frames are in a file for good."""
        self.written += n
        del self._held[:n]

    def _lose(self, n: int) -> None:
        if n > 0:
            self.lost += n
            self._lost_at = time.monotonic()

    def stats(self) -> dict:
        files = self.closed_files()
        sizes = []
        for p in files + ([self.current] if self.current.exists() else []):
            try:
                sizes.append(p.stat().st_size)
            except OSError:
                pass
        try:
            free = shutil.disk_usage(self.dir).free
        except OSError:
            free = None
        return {
            "enabled": True,
            "active": self._logger is not None,
            "dir": str(self.dir),
            "current": str(self.current) if self._logger is not None else None,
            "closed_files": len(files),
            "bytes": sum(sizes),
            "disk_free": free,
            "accepted": self.accepted,
            "frames": self.written,  # written: in a file for good
            "pending": len(self._held),  # written to the open file, not yet checked in place
            "lost": self.lost,
            "reopened": self.reopened,
            "detached": self.detached,
            "deleted_files": self.deleted,
            "deleted_for_space": self.deleted_for_space,
            "min_free": self.min_free,
            "error": self.error,
            "disk_full": self.disk_full,
            "max_bytes": self.max_bytes,
            "max_files": self.max_files,
            "index": str(self.index),
        }
