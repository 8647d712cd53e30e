"""A damaged store, or one that cannot be used now: SQLite's errors told apart, and a damaged file
moved aside (kept) for a fresh store."""

from __future__ import annotations

import errno
import logging
import os
import sqlite3
import time
from contextlib import contextmanager
from pathlib import Path

from ..errors import StoreDamaged, StoreError

log = logging.getLogger(__name__)

_CORRUPT = 11  # SQLITE_CORRUPT: a damaged page
_FULL, _IOERR, _CANTOPEN = 13, 10, 14  # SQLITE_FULL, SQLITE_IOERR, SQLITE_CANTOPEN: the file may be fine


class _Damaged(Exception):
    """The store's file is damaged (never leaves this package)."""


def _kind(exc: sqlite3.Error) -> str:
    """ "damaged", "space" (disk full or I/O: try again later) or "" for other errors."""
    code = getattr(exc, "sqlite_errorcode", None)
    text = str(exc).lower()
    if code is not None:
        code &= 0xFF  # extended codes carry the primary one in the low byte
    if code == _CORRUPT or "malformed" in text:
        return "damaged"
    if code in (_FULL, _IOERR, _CANTOPEN) or "disk is full" in text or "disk i/o error" in text:
        return "space"
    return ""


def is_damage(exc: BaseException) -> bool:
    """True for an SQLite error saying the file is damaged."""
    return isinstance(exc, sqlite3.Error) and _kind(exc) == "damaged"


def _unavailable(path: Path, exc: BaseException) -> StoreError:
    """A StoreError for a store that is fine but cannot be written now; the caller retries."""
    full = "full" in str(exc).lower() or getattr(exc, "errno", None) in (errno.ENOSPC, errno.EDQUOT)
    why = "the disk is full" if full else f"I/O error ({exc})"
    err = StoreError(
        f"{path}: cannot be used now: {why}; estimates are not saved until it can, and vdp "
        "tries again by itself (free some space on that disk)"
    )
    err.retry = True  # type: ignore[attr-defined]
    return err


class _Repair:
    """The part of :class:`~vdp.store.Store` that names its failures and moves a damaged file aside;
    its state is Store's."""

    def _move_aside(self) -> Path:
        """Rename the store (and its -wal/-shm) to NAME.damaged-<UTC time>: kept, never deleted."""
        for con in (getattr(self, "_w", None), getattr(self, "_r", None)):
            if con is not None:
                try:
                    con.close()
                except sqlite3.Error:
                    pass
        stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        dest = self.path.with_name(f"{self.path.name}.damaged-{stamp}")
        n = 1
        while dest.exists():
            n += 1
            dest = self.path.with_name(f"{self.path.name}.damaged-{stamp}-{n}")
        try:
            for suffix in ("-wal", "-shm"):
                side = self.path.with_name(self.path.name + suffix)
                if side.exists():
                    os.replace(side, dest.with_name(dest.name + suffix))
            os.replace(self.path, dest)
        except OSError as exc:
            raise StoreError(f"{self.path}: damaged, and cannot be moved aside: {exc.strerror or exc}") from None
        return dest

    def _failed(self, con, exc: sqlite3.Error, what: str) -> StoreError:
        """Roll the write transaction back (SQLite may have done so itself) and name the failure."""
        try:
            con.execute("ROLLBACK")
        except sqlite3.Error:
            pass
        if _kind(exc) == "damaged":
            return StoreDamaged(f"{self.path}: {exc}")
        return StoreError(f"{self.path}: {what}: {exc}")

    @contextmanager
    def _reading(self):
        """SQLite errors of a read as vdp errors: damage as StoreDamaged, the rest as StoreError (never a 500)."""
        try:
            yield
        except sqlite3.Error as exc:
            if _kind(exc) == "damaged":
                raise StoreDamaged(f"{self.path}: {exc}") from None
            raise StoreError(f"{self.path}: cannot be read now: {exc}") from None

    def recover(self, why: str) -> str:
        """The file was found damaged while in use: move it aside (kept) and start a fresh store, as
        at open.  Returns what happened (also kept in ``recovered``); StoreError if that fails."""
        with self._wlock, self._rlock:
            moved = self._move_aside()
            self._last.clear()
            self.recovered = f"the store was damaged ({why}); kept as {moved.name}, started a fresh one"
            log.error("%s: %s", self.path, self.recovered)
            try:
                self._open(self.synchronous)
            except _Damaged as again:
                raise StoreError(f"{self.path}: a fresh store is damaged too ({again}); is the disk failing?") from None
        return self.recovered

    def integrity(self) -> str:
        with self._rlock:
            return str(self._r.execute("PRAGMA integrity_check").fetchone()[0])
