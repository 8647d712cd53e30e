"""Field logging: every raw frame to rotating candump ``.log`` files.

python-can's :class:`can.SizedRotatingLogger` does the writing and the size
rotation; this listener adds what an unattended logger needs:

- file names that sort in recording order: ``{prefix}-{seq:06d}-{UTC start}.log``,
  with ``{prefix}-current.log`` as the one open file;
- at most ``max_files`` files: the oldest closed ones are deleted;
- closed files are complete: flushed and fsync'ed before the rename, so a power
  cut leaves no half file among them.  After a crash the open file is salvaged
  at the next start: cut back to its last full line and closed like the others;
- disk full (or any other OSError) stops logging and says why, and never
  reaches the receive thread: estimation and the API carry on.  Logging tries
  again after RETRY_MIN s, backing off to RETRY_MAX, and the frames it could
  not write are counted (``lost``);
- the newest data wins: when free space falls under ``min_free`` (at each
  rotation, and before resuming after a full disk) the oldest closed files are
  deleted, each with a warning, until it is back above the floor;
- it cannot be unlinked from under itself: at every flush (and before each
  rotation) the open file is checked to still be ``{prefix}-current.log`` in
  the directory (same inode, still linked).  A file deleted or moved away, or
  the whole directory, is noticed within one flush: the directory is made
  again, a new file opened, and the frames not yet known to be in a file there
  are written again into it.  Left alone, every frame went into the deleted
  file until the next rotation, and none after it;
- the counts are exact: ``accepted`` = ``written`` + ``lost`` + ``pending``.
  A frame is written once a flush has put it into a file found in place (or a
  rotation closed it); ``pending`` ones are held until then, so a file that
  vanishes loses none of them.  When a write fails, the complete lines that
  reached the file are counted written and the rest of the buffer lost (a full
  disk counted ~85 buffered frames as written).
"""

from __future__ import annotations

import errno
import json
import logging
import os
import re
import shutil
import threading
import time
from pathlib import Path

import can

from .reader import EXT, TX, message_of

log = logging.getLogger(__name__)

HOLD_MAX = 16_384  # frames pending at most: one more is flushed and checked first (~2 s of a saturated bus)
RETRY_MIN = 1.0  # s before the first attempt to resume after a write error
RETRY_MAX = 30.0  # s: the wait doubles after each failed attempt, up to this
_TAIL = 1 << 16  # bytes read back when salvaging a file cut mid-line
HEADS_MAX = 4096  # ids whose line head (channel, id) the raw log keeps made


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class _Detached(Exception):
    """The open file is no longer the raw log's current file (never leaves this module)."""

    def __init__(self, why: str, gone: bool):
        super().__init__(why)
        self.gone = gone  # True: no name is left for the file (deleted): what it held is lost


class _Rotating(can.SizedRotatingLogger):
    """python-can's size check asks the text file for tell(), which flushes it: one write
    syscall per frame.  Asking every CHECK_EVERY frames lets the buffer work; a file then
    ends at most that many lines past max_bytes.  ``before_rollover`` is called before a
    file is closed and renamed (it raises _Detached for a file that is no longer in place)."""

    CHECK_EVERY = 128

    def __init__(self, *args, before_rollover=None, after_rollover=None, **kwargs):
        super().__init__(*args, **kwargs)
        self._since_check = 0
        self.before_rollover = before_rollover
        self.after_rollover = after_rollover

    def do_rollover(self) -> None:
        if self.before_rollover is not None:
            self.before_rollover()
        super().do_rollover()
        if self.after_rollover is not None:
            self.after_rollover(self)

    def should_rollover(self, msg: can.Message) -> bool:
        self._since_check += 1
        if self._since_check < self.CHECK_EVERY:
            return False
        self._since_check = 0
        return super().should_rollover(msg)


def _dup(logger) -> int | None:
    """A read-only descriptor of the logger's open file (write-only itself), to count its lines after
    it is closed, whatever its name is then (Linux's /proc; None elsewhere: the file is found by name)."""
    try:
        return os.open(f"/proc/self/fd/{logger.writer.file.fileno()}", os.O_RDONLY)
    except (OSError, ValueError, AttributeError):
        return None


class RawLog(can.Listener):
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

    def _check(self) -> None:
        """Flush, then count the held frames written if the file is in place; called with the lock held."""
        logger = self._logger
        if logger is None:
            return
        try:
            logger.writer.file.flush()
            self._in_place()
        except _Detached as gone:
            self._reattach(gone, [])
            return
        except OSError as exc:
            self._fail(exc)
            return
        except (AttributeError, ValueError):
            return
        self._settled(len(self._held))
        try:
            self._verified = logger.writer.file.tell()
        except (OSError, ValueError):
            pass

    def maybe_resume(self, now: float | None = None) -> bool:
        """After a failure, try again (after RETRY_MIN s, backing off to RETRY_MAX), making room
        by deleting the oldest closed files when the disk is under the free-space floor."""
        now = time.monotonic() if now is None else now
        if self._logger is not None or self._failed_at is None or now - self._failed_at < self._retry:
            return False
        with self._lock:
            why = self.error or "an error"
            self._failed_at = now
            self._retry = min(2 * self._retry, RETRY_MAX)
            try:
                self.dir.mkdir(parents=True, exist_ok=True)  # gone with the file that failed: disk_usage needs it
                self._make_room()
                if shutil.disk_usage(self.dir).free < min(self.min_free, 2 * self.max_bytes):
                    return False
                self._open()
            except OSError as exc:
                self._fail(exc)
                return False
        log.warning("raw CAN logging resumed in %s after: %s (%d frames not written)", self.dir, why, self.lost)
        return True

    # -- helpers ---------------------------------------------------------------------------------
    def _fail(self, exc: BaseException, closing: bool = False) -> None:
        """Stop logging; called with the lock held.  The held frames whose lines reached the file are
        written, the rest lost (``closing``: the caller has already tried to stop the writer)."""
        full = isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)
        why = "disk full" if full else f"{type(exc).__name__}: {exc}"
        first = self.error is None
        self.error, self.disk_full = why, full
        if first:
            self._failed_at = time.monotonic()
        logger, self._logger = self._logger, None
        if logger is not None and not closing:
            fd = _dup(logger)
            try:
                logger.stop()  # flushing again may fail the same way; what it cannot write is lost
            except Exception:
                try:
                    logger.writer.file.close()
                except Exception:
                    pass
        else:
            fd = None
        done = self._lines_in_file(fd)
        self._settled(min(done, len(self._held)))
        self._lose(len(self._held))
        self._held.clear()
        if first:
            log.error(
                "raw CAN logging stopped (%s) in %s; estimation and the API carry on. "
                "It resumes by itself once there is room.",
                why,
                self.dir,
            )

    def _lines_in_file(self, fd: int | None) -> int:
        """Complete lines after the last check in the open file (by ``fd``, else by name if it is still
        ours): the held frames that reached it.  0 for a file that is deleted."""
        try:
            if fd is None:
                try:
                    fd = os.open(self.current, os.O_RDONLY)
                except OSError:
                    return 0
                st = os.fstat(fd)
                if (st.st_dev, st.st_ino) != self._ident:
                    return 0
            st = os.fstat(fd)
            if st.st_nlink == 0:
                return 0
            n, pos = 0, self._verified
            while pos < st.st_size:
                block = os.pread(fd, 1 << 20, pos)
                if not block:
                    break
                n += block.count(b"\n")
                pos += len(block)
            return n
        except OSError:
            return 0
        finally:
            if fd is not None:
                os.close(fd)

    def _settled(self, n: int) -> None:
        """The first ``n`` held frames are in a file for good."""
        self.written += n
        del self._held[:n]

    def _lose(self, n: int) -> None:
        if n > 0:
            self.lost += n
            self._lost_at = time.monotonic()

    def _opened(self, logger) -> None:
        """Note which file and directory are the log's, to tell later whether they are still in place."""
        st = os.fstat(logger.writer.file.fileno())
        self._ident = (st.st_dev, st.st_ino)
        d = os.stat(self.dir)
        self._dir_ident = (d.st_dev, d.st_ino)
        self._verified = 0

    def _in_place(self) -> None:
        """Raise _Detached unless the open file is still linked, as {prefix}-current.log, in the same directory."""
        logger = self._logger
        st = os.fstat(logger.writer.file.fileno())
        if st.st_nlink == 0:
            raise _Detached(f"{self.current.name} was deleted (or its directory {self.dir})", gone=True)
        try:
            d = os.stat(self.dir)
            here = os.stat(self.current)
        except FileNotFoundError:
            raise _Detached(
                f"{self.current.name} was moved away from {self.dir} (or the directory was)", gone=False
            ) from None
        if (d.st_dev, d.st_ino) != self._dir_ident:
            raise _Detached(f"{self.dir} was replaced by another directory", gone=False)
        if (here.st_dev, here.st_ino) != self._ident:
            raise _Detached(f"{self.current.name} was replaced by another file", gone=False)

    def _reattach(self, gone: _Detached, rest: list[can.Message]) -> None:
        """The open file is no longer in place: make the directory again, open a new file, and write the
        frames held (and ``rest``, not yet written) into it.  Called with the lock held."""
        old, self._logger = self._logger, None
        flushed = True
        try:
            old.stop()  # a file moved away whole keeps what was flushed into it; a deleted one, nothing
        except Exception:
            flushed = False  # some may be missing from the moved file: all are written again (twice, not never)
            try:
                old.writer.file.close()
            except Exception:
                pass
        if flushed and not gone.gone:
            self._settled(len(self._held))  # in the moved file, under its new name
        held, self._held = self._held, []
        self.reopened += 1
        self.detached = f"{gone} at {time.strftime('%H:%M:%S')}"
        self._detached_at = time.monotonic()
        try:
            self._open()
        except OSError as exc:
            self._lose(len(held) + len(rest))
            self._fail(exc)
            return
        log.warning(
            "raw CAN log: %s; recording again in %s, with the %d frame(s) not yet known to be in a file there",
            gone,
            self.current,
            len(held) + len(rest),
        )
        self._write(held + rest)
        logger = self._logger
        if logger is not None:  # and into the new file for good, unless it went too (then the next flush sees it)
            try:
                logger.writer.file.flush()
                self._in_place()
            except (_Detached, OSError, ValueError):
                return
            self._settled(len(self._held))
            self._verified = logger.writer.file.tell()

    def _next_name(self) -> Path:
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(self._opened_at))
        path = self.dir / f"{self.prefix}-{self._seq:06d}-{stamp}.log"
        self._seq += 1
        return path

    def _rotate(self, source, dest, rolling: bool = False) -> None:
        """rotator of SizedRotatingLogger (``rolling``: the frame being written is not in the file yet);
        the writer is already closed (flushed) here."""
        src, dst = Path(source), Path(dest)
        fd = os.open(src, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(src, dst)
        if rolling:
            self._settled(len(self._held) - (0 if self._rolling_all else 1))
            self._verified = 0
        _fsync_dir(self.dir)
        self._note(dst)
        self._opened_at = time.time()
        self._start_file()
        self._prune()

    def _drops_now(self) -> dict:
        try:
            return dict(self.drops()) if self.drops is not None else {}
        except Exception:  # the index must never stop logging
            return {}

    def _start_file(self) -> None:
        self._in_file = 0
        self._drops_at_open = self._drops_now()

    def _note(self, closed: Path) -> None:
        """One line in the index for a file just closed: its frames, its span, and the frames lost before
        vdp read them (by cause) while it was the open file: where a replay of it has gaps."""
        now = self._drops_now()
        lost = {k: (v or 0) - (self._drops_at_open.get(k) or 0) for k, v in now.items() if v is not None}
        line = {
            "file": closed.name,
            "frames": self._in_file,
            "opened": round(self._opened_at, 3),
            "closed": round(time.time(), 3),
            "dropped": lost,
            "dropped_total": now,
        }
        try:
            with open(self.index, "a", encoding="utf-8") as f:
                f.write(json.dumps(line) + "\n")
        except OSError as exc:
            log.warning("raw CAN log: could not add %s to the index %s: %s", closed.name, self.index, exc)

    def _salvage(self, why: str = "left open by the last run") -> None:
        """A file left open by a crash (or by a close whose flush failed): cut a partial last line,
        then close it like any other."""
        size = self.current.stat().st_size
        if size == 0:
            self.current.unlink()
            return
        with open(self.current, "r+b") as f:
            f.seek(max(0, size - _TAIL))
            tail = f.read()
            if not tail.endswith(b"\n"):
                cut = tail.rfind(b"\n")
                keep = (size - len(tail) + cut + 1) if cut >= 0 else (0 if size <= _TAIL else size)
                f.truncate(keep)
                log.warning(
                    "%s: cut %d bytes of a line left unfinished (a crash, or a write the disk refused)",
                    self.current,
                    size - keep,
                )
            f.flush()
            os.fsync(f.fileno())
        if self.current.stat().st_size == 0:
            self.current.unlink()
            return
        self._opened_at = self.current.stat().st_mtime
        dst = self._next_name()
        os.replace(self.current, dst)
        _fsync_dir(self.dir)
        log.info("closed the raw log %s as %s", why, dst.name)

    def closed_files(self) -> list[Path]:
        """Closed files, oldest first."""
        try:
            names = [(int(m.group(1)), p) for p in self.dir.iterdir() if (m := self._pattern.match(p.name))]
        except OSError:
            return []
        return [p for _, p in sorted(names)]

    def _make_room(self) -> None:
        """Delete the oldest closed files while free space is under the floor (the newest data wins)."""
        closed = self.closed_files()
        while closed:
            try:
                free = shutil.disk_usage(self.dir).free
            except OSError:
                return
            if free >= self.min_free:
                return
            p = closed.pop(0)
            try:
                size = p.stat().st_size
                p.unlink()
            except OSError as exc:
                log.warning("could not delete old raw log %s to make room: %s", p, exc)
                continue
            self.deleted += 1
            self.deleted_for_space += 1
            log.warning(
                "deleted the oldest raw log %s (%d bytes): %d bytes free, under the floor of %d",
                p.name,
                size,
                free,
                self.min_free,
            )

    def _prune(self) -> None:
        self._make_room()
        closed = self.closed_files()
        extra = len(closed) - (self.max_files - 1)  # the open file is one of max_files
        for p in closed[: max(extra, 0)]:
            try:
                p.unlink()
                self.deleted += 1
                log.info("deleted the oldest raw log %s (keeping %d files)", p.name, self.max_files)
            except OSError as exc:
                log.warning("could not delete old raw log %s: %s", p, exc)

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
