"""The pipeline's result: one typed, immutable view of a run (replay) or of the live state.

:meth:`vdp.pipeline.Pipeline.result` builds a :class:`RunResult`;
:meth:`~vdp.pipeline.Pipeline.run` returns one at the end of a log.  The
replay CLI, the report, the store, the live service and the API read this and
nothing inside the pipeline.  :func:`jsonable` is the one JSON serialiser:
NaN and inf become null, dataclasses their ``as_dict()``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .core.result import Estimate, Snapshot, Stage, TraceRow, WindowSpan


@dataclass(frozen=True)
class Clock:
    """Bus-time faults the aligner handled."""

    backwards: int = 0  # frames whose time went back (dropped, or followed after a run of them)
    jumps: int = 0  # restarts of the sample grid (a gap, or the clock stepping)

    def as_dict(self) -> dict[str, int]:
        return {"backwards": self.backwards, "jumps": self.jumps}


@dataclass(frozen=True)
class Freshness:
    """One mapped channel at the newest bus time."""

    age: float | None  # s since its newest value; None if never seen
    stale: bool

    def as_dict(self) -> dict[str, Any]:
        return {"age": self.age, "stale": self.stale}


@dataclass(frozen=True)
class LogInfo:
    """What reading a log found, and how fast it went (replay only)."""

    path: str
    frames: int  # frames in the log: handed to the pipeline plus passed over at the source
    wall_s: float
    duration_s: float  # bus time from the first frame to the newest decoded one
    start_time: float | None  # the first frame's bus time
    source: Mapping[str, Any] = field(default_factory=dict)  # the reader's statistics (LogStats.as_dict())

    @property
    def realtime_factor(self) -> float:
        return self.duration_s / self.wall_s if self.wall_s > 0 else 0.0


@dataclass(frozen=True)
class RunResult:
    """Everything a run produced, at one moment.

    Times in ``windows`` and ``trace`` are bus times; ``t0`` (the first frame's
    bus time in a replay, None live) is the origin the JSON document and the
    plot put them on.
    """

    parameters: Mapping[str, Estimate]  # the UKF: the method
    baseline_ekf: Mapping[str, Estimate] | None  # the EKF baseline (None if not run)
    stage: Stage
    supervisor: Mapping[str, Any]
    windows: tuple[WindowSpan, ...]
    resets: Mapping[str, int]
    capabilities: Mapping[str, str | None]  # per stage "1"/"2", and "I_x": None if it can run, else why not
    decode: Mapping[str, Any]  # the decoder's statistics (DecodeStats.as_dict())
    clock: Clock
    channels: Mapping[str, Freshness]
    frames: int  # frames fed to the pipeline (and counted at the source)
    samples: int  # aligned samples the estimator saw
    bus_time: float | None  # the newest decoded frame's bus time
    coaching: Mapping[str, Any] | None = None  # per stage progress and gate, `next`: what to drive (core.progress)
    trace: tuple[TraceRow, ...] = ()
    t0: float | None = None
    log: LogInfo | None = None
    # a running service's profile self-check (profilecheck.Monitor.status()); None in a replay,
    # which checks the log's first minutes before it starts
    profile_check: Mapping[str, Any] | None = None

    @classmethod
    def of(cls, snap: Snapshot, **kw) -> RunResult:
        return cls(
            parameters=snap.parameters,
            baseline_ekf=snap.baseline_ekf,
            stage=snap.stage,
            supervisor=snap.supervisor,
            windows=snap.windows,
            resets=snap.resets,
            **kw,
        )

    @property
    def current_window(self) -> WindowSpan | None:
        w = self.windows[-1] if self.windows else None
        return w if w is not None and w.end is None else None

    def estimates_dict(self) -> dict[str, Any]:
        """The estimator's part (parameters, baseline, stage, gating, capabilities)."""
        t0 = self.t0 or 0.0
        return {
            "parameters": {k: e.as_dict() for k, e in self.parameters.items()},
            "baseline_ekf": None
            if self.baseline_ekf is None
            else {k: e.as_dict() for k, e in self.baseline_ekf.items()},
            "stage": self.stage,
            "supervisor": dict(self.supervisor),
            "windows": [w.as_dict(t0) for w in self.windows],
            "resets": dict(self.resets),
            "capabilities": dict(self.capabilities),
            "coaching": self.coaching,
        }

    def to_dict(self) -> dict[str, Any]:
        """The document of ``vdp replay --json`` (the trace is left out: the plot has it)."""
        out = self.estimates_dict()
        if self.log is not None:
            lg = self.log
            out["log"] = {
                "path": lg.path,
                "frames": lg.frames,
                "wall_s": lg.wall_s,
                "duration_s": lg.duration_s,
                "realtime_factor": lg.realtime_factor,
                "start_time": lg.start_time,
                **lg.source,
                "decode": dict(self.decode),
                "clock": self.clock.as_dict(),
            }
        return out

    def trace_since_start(self) -> list[TraceRow]:
        """The trace with times relative to ``t0`` (for plots)."""
        t0 = self.t0 or 0.0
        return [(r[0] - t0, *r[1:]) for r in self.trace]


def jsonable(obj: Any) -> Any:
    """A copy safe for strict JSON: non-finite floats become None, numpy scalars plain
    numbers, dataclasses their ``as_dict()`` (or their fields), paths strings."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, (str, int, bool)) or obj is None:
        return obj
    if isinstance(obj, Mapping):
        return {k if isinstance(k, str) else str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [jsonable(v) for v in obj]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        if hasattr(obj, "to_dict"):
            return jsonable(obj.to_dict())
        if hasattr(obj, "as_dict"):
            return jsonable(obj.as_dict())
        return jsonable({f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)})
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "item"):  # numpy scalar
        return jsonable(obj.item())
    return str(obj)
