"""The meta, drives and changes rows of a store (JSON columns without NaN)."""

from __future__ import annotations

import json
import math
import sqlite3
from collections.abc import Mapping

from ..core.result import finite


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


class _Drives:
    """The part of :class:`~vdp.store.Store` that writes and reads the meta, drives and changes rows;
    its state is Store's."""

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
