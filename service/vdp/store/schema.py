"""Opening a store: its tables created, or checked to be this profile's and this schema's, and
the tables added since an earlier vdp."""

from __future__ import annotations

import hashlib
import json
import logging
import sqlite3
import time
from dataclasses import asdict

from ..errors import StoreError
from .damage import _Damaged, _kind, _unavailable

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1
_APP_ID = 0x56445031  # "VDP1" in PRAGMA application_id: tells a vdp store from any other SQLite file

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


class _Schema:
    """The part of :class:`~vdp.store.Store` that opens its file; its state is Store's."""

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
