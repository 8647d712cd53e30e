"""Time series out of a replay: the estimates over time and the channel samples the estimator saw.

``vdp replay --series FILE`` and ``--channels FILE`` write them as CSV or Parquet (by
suffix) for the tools engineers already use (pandas, DuckDB, PlotJuggler).  Both are
taps on the one pipeline: nothing here changes what is estimated.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from . import channels
from .core.params import NAMES
from .core.result import Estimate
from .core.sample import Sample
from .errors import ConfigError
from .outfile import replacing
from .result import RunResult

SUFFIXES = (".csv", ".parquet")
EVERY = 1.0  # s of bus time between series rows outside a window
EVERY_IN_WINDOW = 0.2  # s between rows while a gating window is open (where the estimates move)


def series_columns() -> list[str]:
    cols = ["t"]
    for name in NAMES:
        cols += [f"{name}", f"{name}_std", f"{name}_status"]
    return cols


def _row(t: float, params: Mapping[str, Estimate]) -> list:
    row: list = [t]
    for name in NAMES:
        p = params.get(name)
        row += [None, None, None] if p is None else [p.value, p.std, p.status]
    return row


class SeriesRecorder:
    """Snapshots of the estimates every ``every`` s of bus time (``every_in_window`` inside a window).

    ``wrap(source)`` yields the source's frames and records as they pass; the source's
    attributes (stats, position, ...) stay reachable through the wrapper.
    """

    def __init__(self, pipeline, every: float = EVERY, every_in_window: float = EVERY_IN_WINDOW):
        self.pipeline = pipeline
        self.every, self.every_in_window = every, every_in_window
        self.rows: list[list] = []
        self._next: float | None = None

    def maybe_record(self) -> None:
        t = self.pipeline.last_bus_time
        if t is None or (self._next is not None and t < self._next):
            return
        res = self.pipeline.result()
        self.rows.append(_row(t, res.parameters))
        active = res.supervisor.get("active_stage")
        self._next = t + (self.every_in_window if active else self.every)

    def finish(self, result: RunResult) -> None:
        """The last row is the result itself, at the last bus time."""
        t = result.bus_time
        if t is None:
            return
        row = _row(t, result.parameters)
        if self.rows and self.rows[-1][0] == t:
            self.rows[-1] = row
        else:
            self.rows.append(row)

    def wrap(self, source):
        return _Tapped(source, self)

    def table(self, t0: float | None) -> tuple[list[str], list[list]]:
        """Columns and rows, time relative to ``t0`` (the log's first frame)."""
        off = t0 or 0.0
        return series_columns(), [[r[0] - off, *r[1:]] for r in self.rows]


class _Tapped:
    def __init__(self, source, rec: SeriesRecorder):
        self._source, self._rec = source, rec

    def __getattr__(self, name):
        return getattr(self._source, name)

    def __iter__(self):
        rec = self._rec
        for msg in self._source:
            yield msg
            rec.maybe_record()


class ChannelTap:
    """Every aligned sample the estimator is handed: time, the channels in SI units (NaN where
    missing or stale), and the estimator's own v_x from its GNSS + IMU speed filter."""

    CHUNK = 4096

    def __init__(self, pipeline):
        self._chunks: list[np.ndarray] = []
        self._buf = np.empty((self.CHUNK, channels.N + 3))
        self._n = 0
        pipeline.tap(self._tap)

    def _tap(self, s: Sample) -> None:
        """One sample as the estimator saw it (v_x from its speed filter)."""
        b = self._buf[self._n]
        b[0] = s.t
        b[1 : channels.N + 1] = s.values
        b[channels.N + 1] = s.v_x
        b[channels.N + 2] = 1.0 if s.gap else 0.0
        self._n += 1
        if self._n == self.CHUNK:
            self._chunks.append(self._buf)
            self._buf = np.empty((self.CHUNK, channels.N + 3))
            self._n = 0

    def columns(self) -> list[str]:
        unit = {"rad/s": "_rad_s", "N*m": "_Nm", "rad": "_rad", "m/s^2": "_m_s2", "m/s": "_m_s", "1": ""}  # (1: a flag)
        return ["t", *(f"{n}{unit[channels.UNITS[n]]}" for n in channels.NAMES), "v_x_est_m_s", "gap"]

    def array(self, t0: float | None) -> np.ndarray:
        a = np.concatenate([*self._chunks, self._buf[: self._n]]) if (self._chunks or self._n) else np.empty((0, 15))
        if t0 is not None and len(a):
            a[:, 0] -= t0
        return a


def _kind(path: Path) -> str:
    name = path.name.lower()
    for s in SUFFIXES:
        if name.endswith(s):
            return s
    raise ConfigError(f"{path}: unknown table format; use a name ending in {' or '.join(SUFFIXES)}")


def _cell(v):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, float):
        return repr(v)  # round-trips exactly: the last row equals the JSON result
    return v


def write_table(path: str | Path, columns: list[str], rows) -> None:
    """Rows (lists or a 2-D array) to CSV or Parquet by the file's suffix; missing numbers are empty / null."""
    p = Path(path)
    if _kind(p) == ".csv":
        with replacing(p) as tmp, tmp.open("w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(columns)
            for r in rows:
                w.writerow([_cell(v.item() if hasattr(v, "item") else v) for v in r])
        return
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise ConfigError(f"{p}: Parquet needs pyarrow; pip install 'vdp[parquet]', or write .csv") from None
    if isinstance(rows, np.ndarray):
        data = {c: pa.array(rows[:, i], from_pandas=True) for i, c in enumerate(columns)}
    else:
        cols = list(zip(*rows)) if rows else [[] for _ in columns]
        data = {}
        for c, vals in zip(columns, cols):
            if c.endswith("_status"):
                data[c] = pa.array(list(vals), type=pa.string())
            else:
                data[c] = pa.array([None if v is None else float(v) for v in vals], type=pa.float64())
    with replacing(p) as tmp:
        pq.write_table(pa.table(data), tmp)


def check_suffix(path: str | Path) -> None:
    _kind(Path(path))
