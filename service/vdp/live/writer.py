"""The store writer: the latest published estimates into the SQLite store, one transaction a batch.

It opens the store (a store of another profile or schema is refused, never
overwritten: estimation goes on from the priors, unsaved), hands what it held
back for restoring, commits each new snapshot once, and keeps the store's
state for /health and /status.  History queries read through it.

Damage found while running (a commit or a query meets a malformed page) is
handled as at start: the file is moved aside, kept, and a fresh store takes
over; /health says "estimate store recovered" from then on.  Left alone, every
later query answered 500 while /health said ok, and the file stayed damaged.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from ..errors import StoreDamaged, StoreError
from ..settings import StoreSettings
from ..store import Store, Stored
from .estimation import Published, Unavailable

log = logging.getLogger(__name__)

RETRY_MIN, RETRY_MAX = 1.0, 60.0  # s between attempts to open a store that was unavailable (disk full)


class StoreWriter:
    def __init__(self, cfg: StoreSettings, fingerprint: str, profile_name: str):
        self.cfg = cfg
        self.fingerprint = fingerprint
        self.profile_name = profile_name
        self.store: Store | None = None
        self.state = "closed"  # ok, refused, error, closed
        self.error: str | None = None
        self.last_commit: float | None = None
        self._lock = threading.Lock()
        self._committed_seq = -1
        # a damaged store moved aside at open (kept for the process's life: the file needs a look)
        self.recovered: str | None = None
        self.recoveries = 0
        self.reopen_attempts = 0
        self._retry_wait = RETRY_MIN
        self._retry_at = 0.0
        # why commits wait now (vdp.live.drives: the bus is not yet known to be the stored car's), or None
        self.hold: str | None = None

    def open(self) -> dict[str, Stored]:
        """Open the store; return the stored estimates worth restoring (none if it was refused)."""
        if not self._try_open():
            return {}
        return {k: v for k, v in self.store.load().items() if v.estimate.samples and v.estimate.value is not None}

    def _try_open(self) -> bool:
        cfg = self.cfg
        try:
            store = Store(cfg.path, self.fingerprint, self.profile_name, cfg.synchronous, cfg.history_max_rows)
        except StoreError as exc:
            if getattr(exc, "retry", False):  # disk full or I/O: the file is fine, try again later
                first = self.state != "unavailable"
                self.store, self.state, self.error = None, "unavailable", str(exc)
                self._retry_at = time.monotonic() + self._retry_wait
                self._retry_wait = min(2 * self._retry_wait, RETRY_MAX)
                if first:
                    log.error("estimate store unavailable, starting from the priors: %s", exc)
            else:
                self.store, self.state, self.error = None, "refused", str(exc)
                log.error("estimate store refused, starting from the priors and not saving: %s", exc)
            return False
        if store.recovered:
            self.recovered = f"{store.path}: {store.recovered}"
            self.recoveries += 1
        if self.state == "unavailable":
            log.warning("estimate store %s usable again", cfg.path)
        self.store, self.state, self.error = store, "ok", None
        self._retry_wait = RETRY_MIN
        return True

    def commit(self, pub: Published) -> None:
        """Commit ``pub`` if it is new: one transaction per batch.  A failure is kept and retried."""
        with self._lock:
            if self.store is None and self.state == "unavailable" and time.monotonic() >= self._retry_at:
                self.reopen_attempts += 1
                self._try_open()
            store = self.store
            if store is None or pub.seq == self._committed_seq or self.hold:
                return
            try:
                store.save(pub.result.parameters, t=pub.wall, bus_t=pub.bus_time, learnt=getattr(pub, "learnt", None))
            except StoreDamaged as exc:
                self._recover(store, exc)
                return  # the fresh store gets this snapshot at the next commit
            except StoreError as exc:
                if self.state != "error":
                    log.error("%s; will retry", exc)
                self.state, self.error = "error", str(exc)
                return
            if self.state == "error":
                log.info("estimate store writable again")
            self.state, self.error = "ok", None
            self.last_commit = time.time()
            self._committed_seq = pub.seq

    def refuse(self, why: str) -> None:
        """Stop using the store, leaving the file as it is (another car is on the bus: vdp.live.drives)."""
        with self._lock:
            if self.store is not None:
                self.store.close()
            self.store, self.state, self.error, self.hold = None, "refused", why, None

    def damaged(self, exc: BaseException) -> None:
        """An SQLite error said the file is damaged (from any thread): move it aside for a fresh store."""
        with self._lock:
            if self.store is not None:
                self._recover(self.store, exc)

    def _recover(self, store: Store, exc: BaseException) -> None:
        """Called with the lock held; ``store`` is the one that failed (another thread may have recovered it)."""
        if store is not self.store:
            return
        try:
            what = store.recover(str(exc).removeprefix(f"{store.path}: "))
        except StoreError as again:
            self.store, self.state, self.error = None, "error", str(again)
            log.error("estimate store lost: %s; estimates are not saved", again)
            return
        self.recovered = f"{store.path}: {what}"
        self.recoveries += 1
        self._committed_seq = -1  # the fresh store gets the current estimates at the next commit
        self.state, self.error = "ok", None

    def close(self) -> None:
        with self._lock:
            if self.store is not None:
                self.store.close()
                self.store = None
                self.state = "closed"

    # -- read side (any thread) ----------------------------------------------------------------
    @property
    def ok(self) -> bool:
        return self.state == "ok"

    @property
    def commits(self) -> int:
        store = self.store
        return store.commits if store is not None else 0

    def status(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "path": str(self.cfg.path),
            "state": self.state,
            "error": self.error,
            "last_commit": self.last_commit,
            "recovered": self.recovered,
            "recoveries": self.recoveries,
        }
        store = self.store
        if store is not None:
            out["commits"] = store.commits
            try:
                out["bytes"] = store.size()
            except OSError:
                out["bytes"] = None
        return out

    def history(
        self, parameter: str | None, since: float | None, until: float | None, limit: int, offset: int
    ) -> dict[str, Any]:
        store = self.store
        if store is None:
            raise Unavailable(
                f"no estimate history: the store is {self.state}" + (f" ({self.error})" if self.error else "")
            )
        try:
            items, total = store.history(parameter, since, until, limit, offset)
        except StoreDamaged as exc:
            with self._lock:
                self._recover(store, exc)
            raise Unavailable(
                f"the estimate store was found damaged: {self.recovered or self.error}; "
                "the history starts again from now"
            ) from None
        nxt = offset + len(items)
        return {
            "items": items,
            "total": total,
            "limit": limit,
            "offset": offset,
            "next_offset": nxt if nxt < total else None,
        }
