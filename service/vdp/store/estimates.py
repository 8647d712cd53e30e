"""The store itself: its life (open, recover at open, close), the estimates and their history."""

from __future__ import annotations

import logging
import sqlite3
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from ..core.result import Estimate, finite
from ..errors import StoreError
from .damage import _Damaged, _Repair
from .drives import _Drives, _dumps
from .schema import _Schema

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Stored:
    """A committed estimate and when: unix time ``t`` and the bus time ``bus_t`` of its batch."""

    estimate: Estimate
    t: float
    bus_t: float | None


class Store(_Schema, _Repair, _Drives):
    """One SQLite file.  ``save`` from one writer thread; ``history``/``load`` from any thread."""

    def __init__(
        self,
        path: str | Path,
        fingerprint: str,
        profile_name: str = "",
        synchronous: str = "full",
        history_max_rows: int = 2_000_000,
    ):
        self.path = Path(path)
        self.fingerprint = fingerprint
        self.profile_name = profile_name
        self.history_max_rows = history_max_rows
        self.synchronous = synchronous
        self._last: dict[str, tuple] = {}  # what the last committed batch held, per parameter
        self._saves = 0
        self.commits = 0
        self._wlock = threading.Lock()
        self._rlock = threading.Lock()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(f"{self.path}: cannot create its directory: {exc.strerror or exc}") from None
        self.recovered: str | None = None  # set when a damaged file was moved aside at open
        try:
            self._open(synchronous)
        except _Damaged as why:
            moved = self._move_aside()
            self.recovered = f"the store was damaged ({why}); kept as {moved.name}, started a fresh one"
            log.error("%s: %s", self.path, self.recovered)
            try:
                self._open(synchronous)
            except _Damaged as again:
                raise StoreError(f"{self.path}: a fresh store is damaged too ({again}); is the disk failing?") from None

    # -- use ------------------------------------------------------------------------------
    def load(self) -> dict[str, Stored]:
        """The last committed estimate of each parameter."""
        with self._rlock, self._reading():
            rows = self._r.execute(
                "SELECT name, value, std, unit, valid, stage, status, samples, t, bus_t FROM estimates"
            ).fetchall()
        return {
            r[0]: Stored(
                Estimate(
                    name=r[0],
                    value=r[1],
                    std=r[2],
                    unit=r[3],
                    valid=bool(r[4]),
                    stage=r[5],
                    status=r[6],
                    samples=r[7],
                ),
                t=r[8],
                bus_t=r[9],
            )
            for r in rows
        }

    def save(
        self,
        parameters: Mapping[str, Estimate],
        t: float | None = None,
        bus_t: float | None = None,
        learnt: Mapping | None = None,
    ) -> int:
        """Commit one batch: the current rows, and history rows for what changed.  Returns those.
        ``learnt``: the learners' own state (TwoStageEstimator.learnt), kept in meta in the same
        transaction, so a restart resumes from the very state the estimates came from."""
        t = time.time() if t is None else t
        bus_t = finite(bus_t)
        cur, hist, seen = [], [], {}
        for name, e in parameters.items():
            value, std = finite(e.value), finite(e.std)  # the store never holds NaN
            valid = 1 if e.valid and value is not None else 0
            row = (name, value, std, e.unit, valid, int(e.stage), e.status, int(e.samples), t, bus_t)
            cur.append(row)
            key = (value, std, valid, e.status)
            seen[name] = key
            if self._last.get(name) != key:
                hist.append((t, bus_t, name, value, std, valid, row[5], e.status, row[7]))
        with self._wlock:
            con = self._w
            try:
                con.execute("BEGIN IMMEDIATE")
                con.executemany("INSERT OR REPLACE INTO estimates VALUES (?,?,?,?,?,?,?,?,?,?)", cur)
                if learnt is not None:
                    con.execute("INSERT OR REPLACE INTO meta VALUES ('learnt', ?)", (_dumps(learnt),))
                if hist:
                    con.executemany(
                        "INSERT INTO history (t, bus_t, name, value, std, valid, stage, status, "
                        "samples) VALUES (?,?,?,?,?,?,?,?,?)",
                        hist,
                    )
                self._saves += 1
                if self._saves % 600 == 0:
                    self._prune()
                con.execute("COMMIT")
            except sqlite3.Error as exc:
                raise self._failed(con, exc, "could not commit estimates") from None
        self._last.update(seen)
        self.commits += 1
        return len(hist)

    def _prune(self) -> None:
        # ids grow monotonically, so the newest history_max_rows rows are those above a cut-off id
        top = self._w.execute("SELECT max(id) FROM history").fetchone()[0]
        if top is not None and top > self.history_max_rows:
            n = self._w.execute("DELETE FROM history WHERE id <= ?", (top - self.history_max_rows,)).rowcount
            if n:
                log.info("pruned %d old history rows from %s", n, self.path)

    def history(
        self,
        parameter: str | None = None,
        since: float | None = None,
        until: float | None = None,
        limit: int = 100,
        offset: int = 0,
    ) -> tuple[list[dict], int]:
        """Rows oldest first, and how many match in all (for paging)."""
        where, args = [], []
        if parameter is not None:
            where.append("name = ?")
            args.append(parameter)
        if since is not None:
            where.append("t >= ?")
            args.append(since)
        if until is not None:
            where.append("t < ?")
            args.append(until)
        cond = (" WHERE " + " AND ".join(where)) if where else ""
        with self._rlock, self._reading():
            total = self._r.execute(f"SELECT count(*) FROM history{cond}", args).fetchone()[0]
            rows = self._r.execute(
                f"SELECT id, t, bus_t, name, value, std, valid, stage, status, samples "
                f"FROM history{cond} ORDER BY id LIMIT ? OFFSET ?",
                [*args, limit, offset],
            ).fetchall()
        items = [
            {
                "id": r[0],
                "t": r[1],
                "bus_t": r[2],
                "parameter": r[3],
                "value": r[4],
                "std": r[5],
                "valid": bool(r[6]),
                "stage": r[7],
                "status": r[8],
                "samples": r[9],
            }
            for r in rows
        ]
        return items, total

    def size(self) -> int:
        return sum(p.stat().st_size for p in (self.path, Path(f"{self.path}-wal")) if p.exists())

    def close(self) -> None:
        with self._wlock:
            try:
                self._w.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            except sqlite3.Error:
                pass
            self._w.close()
        with self._rlock:
            self._r.close()
