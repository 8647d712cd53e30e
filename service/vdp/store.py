"""The estimate store: stdlib SQLite in WAL mode, one transaction per update batch.

Tables:

- ``meta``: schema version, the profile's fingerprint and name, creation time;
- ``estimates``: the current value, std, validity, stage, status and sample count
  of each parameter (one row each, replaced per batch);
- ``history``: a row per parameter whenever its estimate changed, for
  ``GET /estimates/history``; bounded by pruning the oldest rows;
- ``drives``: one row per drive (an ignition cycle, a service run, or a stretch between two
  long silences of the bus): when, the estimates it started from and ended with, its own mass
  and wheel-speed scale measures, and its bus print (the CAN ids seen and their periods);
- ``changes``: each change named between drives (vdp.core.change): which, how large, when,
  the parameters it reset and their values before.

``drives`` and ``changes`` are added to a store of an earlier vdp when it is opened (the
schema version stays 1: an older vdp ignores them).

A store belongs to one vehicle profile (its fingerprint) and one schema
version.  Opening it with another raises :class:`StoreError` and leaves the
file alone: mixing another car's estimates in would be wrong, and deleting
the user's data silently would be worse.

A damaged store (SQLite reports corruption, or its quick check fails, say a
page overwritten in the middle or the meta table's index broken) is moved
aside, kept under ``NAME.damaged-<UTC time>``, and a fresh store starts;
``recovered`` says what happened.  Damage found later, by a query or a commit
of the running service, raises :class:`StoreDamaged`; :meth:`Store.recover`
then does the same as at open.  A full disk or an I/O error is a
:class:`StoreError` with ``retry = True``: the file is fine, try again later.
"""

from __future__ import annotations

import errno
import hashlib
import json
import logging
import math
import os
import sqlite3
import threading
import time
from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

from .core.result import Estimate, finite
from .errors import StoreDamaged, StoreError

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1
_APP_ID = 0x56445031  # "VDP1" in PRAGMA application_id: tells a vdp store from any other SQLite file
_CORRUPT = 11  # SQLITE_CORRUPT: a damaged page
_FULL, _IOERR, _CANTOPEN = 13, 10, 14  # SQLITE_FULL, SQLITE_IOERR, SQLITE_CANTOPEN: the file may be fine


class _Damaged(Exception):
    """The store's file is damaged (never leaves this module)."""


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


_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE estimates (
    name TEXT PRIMARY KEY, value REAL, std REAL, unit TEXT NOT NULL, valid INTEGER NOT NULL,
    stage INTEGER NOT NULL, status TEXT NOT NULL, samples INTEGER NOT NULL,
    t REAL NOT NULL, bus_t REAL);
CREATE TABLE history (
    id INTEGER PRIMARY KEY, t REAL NOT NULL, bus_t REAL, name TEXT NOT NULL, value REAL, std REAL,
    valid INTEGER NOT NULL, stage INTEGER NOT NULL, status TEXT NOT NULL, samples INTEGER NOT NULL);
CREATE INDEX history_name_t ON history (name, t);
CREATE INDEX history_t ON history (t);
"""

# added at open when missing (stores written before drives were kept)
_DRIVES = """
CREATE TABLE IF NOT EXISTS drives (
    id INTEGER PRIMARY KEY, t0 REAL NOT NULL, t1 REAL, bus_t0 REAL, bus_t1 REAL, state TEXT NOT NULL,
    start TEXT, last TEXT, mass TEXT, scale TEXT, print TEXT);
CREATE TABLE IF NOT EXISTS changes (
    id INTEGER PRIMARY KEY, t REAL NOT NULL, bus_t REAL, drive INTEGER, kind TEXT NOT NULL, what TEXT NOT NULL,
    size REAL, params TEXT NOT NULL, old TEXT NOT NULL)
"""


def _dumps(doc) -> str:
    """JSON with NaN and infinities as null (SQLite's JSON and the API's never hold them)."""

    def clean(x):
        if isinstance(x, float):
            return x if math.isfinite(x) else None
        if isinstance(x, dict):
            return {str(k): clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        return x

    return json.dumps(clean(doc), separators=(",", ":"))


def _loads(text):
    return None if text is None else json.loads(text)


def profile_fingerprint(profile) -> str:
    """SHA-256 over what makes estimates comparable: the vehicle, the priors, the channel map.

    Taken from the parsed profile, so comments and key order in the file don't matter.
    """

    def chan(cm) -> dict:
        d = asdict(cm)
        for m in (d, d.get("alt")):
            if m:
                m.pop("where", None)
                if m.get("fine") is None:
                    m.pop("fine", None)  # a key added later: unset, it leaves older fingerprints as they were
        return d

    veh = asdict(profile.vehicle)
    for k in ("compliance_steer", "roll_steer_f", "roll_steer_r"):
        if not veh.get(k):
            veh.pop(k, None)  # keys added later: unset, they leave older fingerprints as they were
    doc = {
        "vehicle": veh,
        "priors": {k: asdict(v) for k, v in sorted(profile.priors.items())},
        "channels": {k: chan(v) for k, v in sorted(profile.channels.items())},
    }
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@dataclass(frozen=True)
class Stored:
    """A committed estimate and when: unix time ``t`` and the bus time ``bus_t`` of its batch."""

    estimate: Estimate
    t: float
    bus_t: float | None


class Store:
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

    def _open(self, synchronous: str) -> None:
        self._w = self._connect()
        try:
            self._w.execute(f"PRAGMA synchronous={synchronous.upper()}")
            check = self._w.execute("PRAGMA quick_check(1)").fetchone()[0]
            if check != "ok":
                raise _Damaged(f"quick check: {check}")
            self._check_or_create()
            self._add_drives()
            self._r = self._connect()
            for row in self._w.execute("SELECT name, value, std, valid, status FROM estimates"):
                self._last[row[0]] = tuple(row[1:])
        except sqlite3.Error as exc:
            self._w.close()
            kind = _kind(exc)
            if kind == "damaged":
                raise _Damaged(str(exc)) from None
            if kind == "space":
                raise _unavailable(self.path, exc) from None
            raise StoreError(f"{self.path}: cannot open: {exc}") from None
        except BaseException:
            self._w.close()
            raise

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

    # -- opening ------------------------------------------------------------------------
    def _connect(self) -> sqlite3.Connection:
        try:
            con = sqlite3.connect(self.path, timeout=10.0, isolation_level=None, check_same_thread=False)
        except sqlite3.Error as exc:
            if _kind(exc) == "space":
                raise _unavailable(self.path, exc) from None
            raise StoreError(f"{self.path}: cannot open: {exc}") from None
        try:
            con.execute("PRAGMA busy_timeout=10000")
            mode = con.execute("PRAGMA journal_mode=WAL").fetchone()[0]
        except sqlite3.DatabaseError as exc:
            con.close()
            kind = _kind(exc)
            if kind == "damaged":
                raise _Damaged(str(exc)) from None
            if kind == "space":
                raise _unavailable(self.path, exc) from None
            raise StoreError(
                f"{self.path}: not a vdp store ({exc}); move it away or set [store] path to a new file"
            ) from None
        if str(mode).lower() != "wal":
            con.close()
            raise StoreError(f"{self.path}: cannot use WAL mode (got {mode}); is it on a network file system?")
        return con

    def _check_or_create(self) -> None:
        con = self._w
        tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        app_id = con.execute("PRAGMA application_id").fetchone()[0]
        if not tables and app_id == 0:
            con.execute("BEGIN IMMEDIATE")  # statements one by one: executescript() would COMMIT
            try:
                for stmt in filter(None, (s.strip() for s in _SCHEMA.split(";"))):
                    con.execute(stmt)
                meta = {
                    "schema_version": str(SCHEMA_VERSION),
                    "profile_fingerprint": self.fingerprint,
                    "profile_name": self.profile_name,
                    "created": f"{time.time():.3f}",
                }
                con.executemany("INSERT INTO meta VALUES (?, ?)", meta.items())
                con.execute(f"PRAGMA application_id={_APP_ID}")
                con.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
                con.execute("COMMIT")
            except BaseException:
                try:
                    con.execute("ROLLBACK")
                except sqlite3.Error:
                    pass  # SQLite rolled back by itself (a full disk does): keep the first error
                raise
            log.info("created estimate store %s for profile %s", self.path, self.profile_name or "?")
            return
        if app_id != _APP_ID or "meta" not in tables:
            raise StoreError(
                f"{self.path}: is an SQLite file but not a vdp estimate store; "
                "move it away or set [store] path to a new file"
            )
        meta = dict(con.execute("SELECT key, value FROM meta").fetchall())
        version = meta.get("schema_version")
        if version != str(SCHEMA_VERSION):
            raise StoreError(
                f"{self.path}: written with store schema {version}, this vdp uses "
                f"{SCHEMA_VERSION}; the stored estimates are not loaded. Move the file away "
                "(keep it if you want its history) or set [store] path to a new file"
            )
        fp = meta.get("profile_fingerprint")
        if fp != self.fingerprint:
            raise StoreError(
                f"{self.path}: holds estimates of another vehicle profile "
                f"('{meta.get('profile_name', '?')}', fingerprint {str(fp)[:12]}; this profile "
                f"'{self.profile_name}' is {self.fingerprint[:12]}); they are not loaded. Move "
                "the file away or set [store] path to a new file for this profile"
            )

    def _add_drives(self) -> None:
        con = self._w
        tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if {"drives", "changes"} <= tables:
            return
        con.execute("BEGIN IMMEDIATE")
        try:
            for stmt in filter(None, (s.strip() for s in _DRIVES.split(";"))):
                con.execute(stmt)
            con.execute("COMMIT")
        except BaseException:
            try:
                con.execute("ROLLBACK")
            except sqlite3.Error:
                pass
            raise

    # -- drives and changes ---------------------------------------------------------------
    def _write(self, sql: str, args: tuple) -> int:
        """One statement in its own transaction; the new row's id."""
        with self._wlock:
            con = self._w
            try:
                con.execute("BEGIN IMMEDIATE")
                cur = con.execute(sql, args)
                con.execute("COMMIT")
            except sqlite3.Error as exc:
                raise self._failed(con, exc, "could not commit") from None
        return int(cur.lastrowid or 0)

    def _failed(self, con, exc: sqlite3.Error, what: str) -> StoreError:
        """Roll the write transaction back (SQLite may have done so itself) and name the failure."""
        try:
            con.execute("ROLLBACK")
        except sqlite3.Error:
            pass
        if _kind(exc) == "damaged":
            return StoreDamaged(f"{self.path}: {exc}")
        return StoreError(f"{self.path}: {what}: {exc}")

    def meta(self, key: str) -> str | None:
        with self._rlock, self._reading():
            row = self._r.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return None if row is None else row[0]

    def learnt(self) -> dict | None:
        """The learners' state saved with the last estimates (None before any, or unreadable)."""
        text = self.meta("learnt")
        try:
            return None if text is None else json.loads(text)
        except ValueError:
            return None

    def set_meta(self, key: str, value: str) -> None:
        self._write("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, value))

    def begin_drive(self, t: float, bus_t: float | None, start: Mapping, bus_print: Mapping | None) -> int:
        """A new drive's row; its id."""
        return self._write(
            "INSERT INTO drives (t0, bus_t0, state, start, print) VALUES (?, ?, 'driving', ?, ?)",
            (t, finite(bus_t), _dumps(start), None if bus_print is None else _dumps(bus_print)),
        )

    def update_drive(
        self,
        drive: int,
        t: float,
        bus_t: float | None,
        last: Mapping,
        mass: Mapping | None,
        scale: Mapping | None,
        state: str = "driving",
    ) -> None:
        """The drive so far (``state`` "ended" once it has)."""
        self._write(
            "UPDATE drives SET t1 = ?, bus_t1 = ?, last = ?, mass = ?, scale = ?, state = ? WHERE id = ?",
            (
                t,
                finite(bus_t),
                _dumps(last),
                None if mass is None else _dumps(mass),
                None if scale is None else _dumps(scale),
                state,
                drive,
            ),
        )

    def add_change(self, t: float, bus_t: float | None, drive: int | None, change: Mapping, old: Mapping) -> int:
        """A named change (vdp.core.change.Change.as_dict()) and the values it reset."""
        numbers = {k: v for k, v in change.items() if k not in ("kind", "what", "size", "params")}
        return self._write(
            "INSERT INTO changes (t, bus_t, drive, kind, what, size, params, old) VALUES (?,?,?,?,?,?,?,?)",
            (
                t,
                finite(bus_t),
                drive,
                change["kind"],
                change["what"],
                finite(change.get("size")),
                _dumps(change.get("params", [])),
                _dumps({"values": old, "numbers": numbers}),
            ),
        )

    def drives(self, limit: int = 1000) -> list[dict]:
        """The newest ``limit`` drives, oldest first."""
        with self._rlock, self._reading():
            rows = self._r.execute(
                "SELECT id, t0, t1, bus_t0, bus_t1, state, start, last, mass, scale, print FROM drives "
                "ORDER BY id DESC LIMIT ?",
                (limit,),
            ).fetchall()
        keys = ("id", "t0", "t1", "bus_t0", "bus_t1", "state", "start", "last", "mass", "scale", "print")
        out = []
        for r in reversed(rows):
            d = dict(zip(keys, r))
            for k in ("start", "last", "mass", "scale", "print"):
                d[k] = _loads(d[k])
            out.append(d)
        return out

    def changes(self, limit: int = 1000) -> list[dict]:
        """The newest ``limit`` changes, oldest first."""
        with self._rlock, self._reading():
            rows = self._r.execute(
                "SELECT id, t, bus_t, drive, kind, what, size, params, old FROM changes ORDER BY id DESC LIMIT ?",
                (limit,),
            ).fetchall()
        return [
            {"id": r[0], "t": r[1], "bus_t": r[2], "drive": r[3], "kind": r[4], "what": r[5], "size": r[6],
             "params": _loads(r[7]), "old": _loads(r[8])}
            for r in reversed(rows)
        ]  # fmt: skip

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
