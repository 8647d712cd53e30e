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
  deleted, each with a warning, until it is back above the floor.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import shutil
import threading
import time
from pathlib import Path

import can

log = logging.getLogger(__name__)

RETRY_MIN = 1.0  # s before the first attempt to resume after a write error
RETRY_MAX = 30.0  # s: the wait doubles after each failed attempt, up to this
_TAIL = 1 << 16  # bytes read back when salvaging a file cut mid-line


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


class _Rotating(can.SizedRotatingLogger):
    """python-can's size check asks the text file for tell(), which flushes it: one write
    syscall per frame.  Asking every CHECK_EVERY frames lets the buffer work; a file then
    ends at most that many lines past max_bytes."""

    CHECK_EVERY = 128

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._since_check = 0

    def should_rollover(self, msg: can.Message) -> bool:
        self._since_check += 1
        if self._since_check < self.CHECK_EVERY:
            return False
        self._since_check = 0
        return super().should_rollover(msg)


class RawLog(can.Listener):
    """A Notifier listener; ``on_message_received`` never raises."""

    def __init__(
        self, directory: str | Path, max_bytes: int, max_files: int, prefix: str = "vdp", min_free: int | None = None
    ):
        self.dir = Path(directory)
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
        self.frames = 0
        self.lost = 0  # frames not written while logging was stopped
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
        self._seq = (int(self._pattern.match(closed[-1].name).group(1)) + 1) if closed else 1
        if self.current.is_file():
            self._salvage()
        self._opened_at = time.time()
        logger = _Rotating(self.current, max_bytes=self.max_bytes)
        logger.namer = lambda _default: str(self._next_name())
        logger.rotator = self._rotate
        self._logger = logger
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
            except OSError as exc:
                self._fail(exc, closing=True)

    def stop(self) -> None:
        """Listener API: the Notifier calls this on every reconnect; the file stays open."""

    # -- receive thread -------------------------------------------------------------------------
    def on_message_received(self, msg: can.Message) -> None:
        with self._lock:
            logger = self._logger
            if logger is None:
                self.lost += 1
                return
            try:
                logger.on_message_received(msg)
                self.frames += 1
            except OSError as exc:
                self.lost += 1
                self._fail(exc)
            except Exception as exc:  # a bug must not stop the receive thread
                self.lost += 1
                self._fail(exc)

    def on_error(self, exc: Exception) -> None:
        """The bus failed; the service handles it.  Defined so the Notifier counts it as handled."""

    # -- service thread ------------------------------------------------------------------------
    def flush(self) -> None:
        """Push buffered lines to the OS (bounds what a crash loses to about one interval)."""
        with self._lock:
            if self._logger is None:
                return
            try:
                self._logger.writer.file.flush()
            except OSError as exc:
                self._fail(exc)
            except (AttributeError, ValueError):
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
        """Stop logging; called with the lock held."""
        full = isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)
        why = "disk full" if full else f"{type(exc).__name__}: {exc}"
        first = self.error is None
        self.error, self.disk_full = why, full
        if first:
            self._failed_at = time.monotonic()
        logger, self._logger = self._logger, None
        if logger is not None and not closing:
            try:
                logger.stop()  # flushing again may fail the same way; the buffer is lost either way
            except Exception:
                try:
                    logger.writer.file.close()
                except Exception:
                    pass
        if first:
            log.error(
                "raw CAN logging stopped (%s) in %s; estimation and the API carry on. "
                "It resumes by itself once there is room.",
                why,
                self.dir,
            )

    def _next_name(self) -> Path:
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(self._opened_at))
        path = self.dir / f"{self.prefix}-{self._seq:06d}-{stamp}.log"
        self._seq += 1
        return path

    def _rotate(self, source, dest) -> None:
        """rotator of SizedRotatingLogger; the writer is already closed (flushed) here."""
        src, dst = Path(source), Path(dest)
        fd = os.open(src, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(src, dst)
        _fsync_dir(self.dir)
        self._opened_at = time.time()
        self._prune()

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
            "frames": self.frames,
            "lost": self.lost,
            "deleted_files": self.deleted,
            "deleted_for_space": self.deleted_for_space,
            "min_free": self.min_free,
            "error": self.error,
            "disk_full": self.disk_full,
            "max_bytes": self.max_bytes,
            "max_files": self.max_files,
        }
