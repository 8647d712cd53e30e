"""The raw log's failures: a write the disk refused stops logging (and it resumes later), and a file
or directory gone from under the log is noticed at a check and replaced, the frames held written again."""

from __future__ import annotations

import errno
import logging
import os
import shutil
import time

import can

from .rotating import _Detached, _dup

log = logging.getLogger(__name__)

RETRY_MIN = 1.0  # s before the first attempt to resume after a write error
RETRY_MAX = 30.0  # s: the wait doubles after each failed attempt, up to this


class _Recovery:
    """The part of :class:`~vdp.live.rawlog.RawLog` that checks, stops, resumes and reattaches; its
    state is RawLog's."""

    # -- service thread ------------------------------------------------------------------------
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
