"""The live service: bus -> (raw log, queue) -> one estimation worker -> snapshots -> store, API.

Threads and what each owns:

- python-can's Notifier thread (per connection, made by :class:`BusLink`): calls
  the listeners; they only append to the raw log and put frames in a bounded queue;
- ``vdp-bus``: opens the bus, notices failures, reconnects with backoff;
- ``vdp-estimate``: the only thread that touches the pipeline.  It feeds frames
  and runs commands (reset) in arrival order, and every ``publish_interval``
  publishes an immutable snapshot.  Everything the API shows comes from the
  latest snapshot, so a request never waits for a filter step;
- ``vdp-keep``: once per ``commit_interval`` commits the latest snapshot to the
  store (one transaction), flushes the raw log, measures rates, and restarts the
  worker if it ever died;
- ``vdp-sim`` (``--simulate`` only): the simulator sending onto a virtual bus.

The service raises :mod:`vdp.errors` exceptions only; the API turns them into
HTTP answers.
"""

from __future__ import annotations

import itertools
import logging
import math
import os
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field, replace
from typing import Any

from .. import channels
from ..core.params import NAMES
from ..core.result import INVALID
from ..errors import StoreError, VdpError
from ..result import RunResult, jsonable
from ..settings import Settings
from ..store import Store, profile_fingerprint
from .bus import BusLink, open_bus
from .intake import Intake, Rename
from .rawlog import RawLog

log = logging.getLogger(__name__)

_STOP = object()
_sim_ids = itertools.count(1)
RATE_WINDOW = 5.0  # s over which frames/s is measured
COMMAND_TIMEOUT = 10.0  # s an API command waits for the worker


class Unavailable(VdpError):
    """The service cannot answer this now (worker busy or stopped, store refused)."""


def _close(a: float | None, b: float | None) -> bool:
    return a is not None and b is not None and math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-12)


@dataclass(frozen=True)
class Published:
    """One consistent view of the estimator, taken on the worker thread."""

    seq: int
    wall: float
    result: RunResult
    fed: int
    restored: bool = False

    @property
    def bus_time(self) -> float | None:
        return self.result.bus_time


@dataclass
class _Command:
    fn: Callable[[Any], Any]
    future: Future = field(default_factory=Future)


class Service:
    def __init__(self, settings: Settings, profile=None, opener: Callable | None = None, pipeline=None):
        from ..core.estimator import EstimatorConfig
        from ..pipeline import Pipeline
        from ..profile import load_profile

        self.settings = settings
        self.profile = profile if profile is not None else load_profile(settings.profile)
        sv = settings.service
        # The live trace only backs plots of recent data; history lives in the store.
        self.pipeline = pipeline if pipeline is not None else Pipeline(self.profile, EstimatorConfig(trace_len=600))
        self.queue: queue.Queue = queue.Queue(maxsize=sv.queue_size)
        self.intake = Intake(self.queue)
        self.rawlog = (
            RawLog(
                settings.raw_log.dir, settings.raw_log.max_bytes, settings.raw_log.max_files, settings.raw_log.prefix
            )
            if settings.raw_log.enabled
            else None
        )
        bus_cfg = settings.bus
        self.sim = None
        listeners: list = []
        if settings.simulate.enabled:
            # A virtual channel of our own: two services in one process never share frames.
            bus_cfg = replace(
                bus_cfg, interface="virtual", channel=f"vdp-sim-{os.getpid()}-{next(_sim_ids)}", kwargs={}
            )
            listeners.append(Rename(self.profile.bus_channel or "can0"))
        listeners.append(self.intake)
        if self.rawlog is not None:
            listeners.append(self.rawlog)
        self.bus_cfg = bus_cfg
        self.link = BusLink(bus_cfg, listeners, sv.reconnect_min, sv.reconnect_max, opener or open_bus)
        if settings.simulate.enabled:
            from .simfeed import SimFeed

            self.sim = SimFeed(self.profile, settings.simulate, bus_cfg.channel, self.backlog)
        self.fingerprint = profile_fingerprint(self.profile)
        self.store: Store | None = None
        self.store_state = "closed"
        self.store_error: str | None = None
        self.store_last_commit: float | None = None
        self.restored: dict | None = None
        self.restore_error: str | None = None
        self._seq = itertools.count(1)
        self._pub = Published(0, time.time(), self.pipeline.result(), 0)
        self._fed = 0
        self._errors = 0
        self._dirty = True
        self._worker: threading.Thread | None = None
        self._keeper: threading.Thread | None = None
        self.worker_restarts = 0
        self._stop = threading.Event()
        self._started = time.monotonic()
        self._started_wall = time.time()
        self._rates: deque = deque()
        self.frames_per_s = 0.0
        self._resets_seen: dict = {}
        self._diverged: dict[str, tuple[float, str]] = {}  # filter kind -> (monotonic time, what)
        self._dropped_seen = 0
        self._dropped_at: float | None = None
        self._commit_lock = threading.Lock()
        self._committed_seq = -1
        self.running = False

    # -- life cycle --------------------------------------------------------------------------
    def start(self) -> None:
        self._started, self._started_wall = time.monotonic(), time.time()
        self._open_store()
        if self.rawlog is not None:
            self.rawlog.open()
        self._publish()
        self._worker = threading.Thread(target=self._work, name="vdp-estimate", daemon=True)
        self._worker.start()
        self.link.start()
        self._keeper = threading.Thread(target=self._keep, name="vdp-keep", daemon=True)
        self._keeper.start()
        if self.sim is not None:
            self.sim.start(ready=lambda: self.link.up)
        self.running = True

    def stop(self) -> None:
        """Stop receiving, estimate what is queued, commit, close the files."""
        if not self.running:
            return
        self.running = False
        if self.sim is not None:
            self.sim.stop()
        self.link.stop()
        self._stop.set()
        if self._keeper is not None:
            self._keeper.join(timeout=10.0)
        if self._worker is not None and self._worker.is_alive():
            self.queue.put(_STOP)
            self._worker.join(timeout=60.0)
        self.commit()
        if self.rawlog is not None:
            self.rawlog.close()
        if self.store is not None:
            self.store.close()
            self.store = None
            self.store_state = "closed"
        log.info("service stopped")

    def _open_store(self) -> None:
        cfg = self.settings.store
        try:
            self.store = Store(
                cfg.path, self.fingerprint, self.profile.vehicle.name, cfg.synchronous, cfg.history_max_rows
            )
        except StoreError as exc:
            self.store, self.store_state, self.store_error = None, "refused", str(exc)
            log.error("estimate store refused, starting from the priors and not saving: %s", exc)
            return
        self.store_state, self.store_error = "ok", None
        stored = {k: v for k, v in self.store.load().items() if v.estimate.samples and v.estimate.value is not None}
        if not stored:
            return
        self.pipeline.restore({k: v.estimate for k, v in stored.items()})
        # Check the estimator really took them: claiming "restored" over the priors would be a lie.
        now = self.pipeline.result().parameters
        off = [k for k, v in stored.items() if k not in now or not _close(now[k].value, v.estimate.value)]
        if off:
            self.restore_error = (
                f"the estimator did not take the stored estimates of {', '.join(sorted(off))} "
                f"from {cfg.path}; starting from the priors"
            )
            log.error("%s", self.restore_error)
            return
        self.restored = stored
        when = max(v.t for v in stored.values())
        log.info(
            "restored %d estimates from %s (saved %s)",
            len(stored),
            cfg.path,
            time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(when)),
        )

    # -- worker thread -------------------------------------------------------------------------
    def _work(self) -> None:
        q, pipe = self.queue, self.pipeline
        interval = self.settings.service.publish_interval
        next_pub = time.monotonic() + interval
        while True:
            try:
                item = q.get(timeout=interval)
            except queue.Empty:
                item = None
            if item is _STOP:
                self._publish()
                return
            if isinstance(item, _Command):
                self._run(item)
                next_pub = time.monotonic() + interval
                continue
            if item is not None:
                try:
                    # candump logs keep microseconds: rounding here makes the live estimate
                    # and a replay of the raw log see the very same numbers.
                    item.timestamp = round(item.timestamp, 6)
                    pipe.feed(item)
                except Exception:
                    self._errors += 1
                    if self._errors == 1 or self._errors % 1000 == 0:
                        log.exception("estimation failed on a frame (%d so far); carrying on", self._errors)
                self._fed += 1
                self._dirty = True
            now = time.monotonic()
            if now >= next_pub:
                if self._dirty:
                    self._publish()
                next_pub = now + interval

    def _run(self, cmd: _Command) -> None:
        if not cmd.future.set_running_or_notify_cancel():
            return
        try:
            result = cmd.fn(self.pipeline)
        except BaseException as exc:
            self._publish()
            cmd.future.set_exception(exc)
        else:
            # publish first: a caller woken by the result (sync) reads the snapshot at once
            self._publish()
            cmd.future.set_result(result)

    def _publish(self) -> None:
        pipe = self.pipeline
        try:
            pub = Published(
                seq=next(self._seq),
                wall=time.time(),
                result=pipe.result(trace=True),
                fed=self._fed,
                restored=self.restored is not None,
            )
        except Exception:
            self._errors += 1
            log.exception("taking a snapshot failed")
            return
        self._dirty = False
        self._note_resets(pub.result.resets)
        self._pub = pub

    def _note_resets(self, resets: dict) -> None:
        for kind, n in resets.items():
            if isinstance(n, int) and n > self._resets_seen.get(kind, 0):
                self._diverged[kind] = (
                    time.monotonic(),
                    f"the {kind.upper()} filter diverged and was reset to its "
                    f"last good estimate ({n} time{'s' if n > 1 else ''} so far)",
                )
            self._resets_seen[kind] = n

    def _call(self, fn: Callable[[Any], Any], timeout: float = COMMAND_TIMEOUT) -> Any:
        """Run ``fn(pipeline)`` on the worker, after every frame already queued."""
        if not self.running or self._worker is None or not self._worker.is_alive():
            raise Unavailable("the estimation worker is not running")
        cmd = _Command(fn)
        try:
            self.queue.put(cmd, timeout=timeout)
        except queue.Full:
            raise Unavailable("the estimation queue is full; try again") from None
        try:
            return cmd.future.result(timeout=timeout)
        except FutureTimeout:
            cmd.future.cancel()
            raise Unavailable(f"the estimation worker did not answer within {timeout:.0f} s") from None

    # -- keeper thread ----------------------------------------------------------------------------
    def _keep(self) -> None:
        every = self.settings.store.commit_interval
        while not self._stop.wait(every):
            try:
                self._tick()
            except Exception:
                log.exception("housekeeping failed; carrying on")

    def _tick(self) -> None:
        self.commit()
        if self.rawlog is not None:
            self.rawlog.flush()
            self.rawlog.maybe_resume()
        now = time.monotonic()
        self._rates.append((now, self.intake.received))
        while self._rates and now - self._rates[0][0] > RATE_WINDOW:
            self._rates.popleft()
        t0, n0 = self._rates[0]
        self.frames_per_s = (self.intake.received - n0) / (now - t0) if now > t0 else 0.0
        if self.intake.dropped > self._dropped_seen:
            self._dropped_seen, self._dropped_at = self.intake.dropped, now
        if self._worker is not None and not self._worker.is_alive() and self.running:
            self.worker_restarts += 1
            log.error("the estimation worker stopped; starting it again (restart %d)", self.worker_restarts)
            self._worker = threading.Thread(target=self._work, name="vdp-estimate", daemon=True)
            self._worker.start()

    def commit(self) -> None:
        """Commit the latest snapshot, if it is new: one transaction per batch."""
        with self._commit_lock:
            store, pub = self.store, self._pub
            if store is None or pub.seq == self._committed_seq:
                return
            try:
                store.save(pub.result.parameters, t=pub.wall, bus_t=pub.bus_time)
            except StoreError as exc:
                if self.store_state != "error":
                    log.error("%s; will retry", exc)
                self.store_state, self.store_error = "error", str(exc)
                return
            if self.store_state == "error":
                log.info("estimate store writable again")
            self.store_state, self.store_error = "ok", None
            self.store_last_commit = time.time()
            self._committed_seq = pub.seq

    # -- read side (any thread) ---------------------------------------------------------------------
    @property
    def latest(self) -> Published:
        return self._pub

    def backlog(self) -> float:
        """Fill fraction of the estimation queue, counting the simulator's frames still on its
        virtual bus: that queue has no bound, so a lagging receive thread would grow it."""
        flight = self.sim.sent - self.intake.received if self.sim is not None else 0
        return (self.queue.qsize() + max(flight, 0)) / self.queue.maxsize

    def sync(self, timeout: float = 60.0) -> Published:
        """Wait until every frame queued so far is estimated; return the snapshot after it (tests)."""
        self._call(lambda p: None, timeout)
        return self._pub

    def estimates(self) -> dict:
        pub = self._pub
        doc = pub.result.estimates_dict()
        del doc["windows"]
        doc.update(restored=pub.restored, bus_time=pub.bus_time, updated=pub.wall)
        return jsonable(doc)

    def health(self) -> dict:
        reasons: list[str] = []
        now = time.monotonic()
        hold = self.settings.service.diverged_hold
        pub = self._pub
        if self.link.info.state != "up":
            why = self.link.info.last_error
            reasons.append(f"bus {self.link.info.state}" + (f": {why}" if why else ""))
        silent = self.silent_for()
        if silent is None:
            reasons.append("no frames received yet")
        elif silent > self.settings.service.silence:
            reasons.append(f"no frames for {silent:.0f} s")
        else:
            stale = sorted(n for n, f in pub.result.channels.items() if f.stale)
            if stale:
                reasons.append(f"stale channels: {', '.join(stale)}")
        invalid = pub.result.decode.get("invalid_channels") or []
        if invalid:
            reasons.append(f"invalid channels (bad counter or checksum): {', '.join(invalid)}")
        # each filter kind on its own: the EKF diverging must not hide that the UKF did
        reasons += [what for when, what in self._diverged.values() if now - when <= hold]
        bad = sorted(n for n, p in pub.result.parameters.items() if p.status == INVALID)
        if bad:
            reasons.append(f"invalid estimates: {', '.join(bad)}")
        if self._dropped_at is not None and now - self._dropped_at <= hold:
            reasons.append(f"estimation fell behind: {self.intake.dropped} frame(s) dropped")
        if self.rawlog is not None and self.rawlog.error:
            reasons.append(f"raw logging stopped: {self.rawlog.error}")
        if self.restore_error:
            reasons.append(self.restore_error)
        if self.store_state != "ok":
            reasons.append(f"estimate store {self.store_state}: {self.store_error or ''}".rstrip(": "))
        if self._worker is None or not self._worker.is_alive():
            reasons.append("estimation worker not running")
        if self.sim is not None and self.sim.error:
            reasons.append(f"simulation failed: {self.sim.error}")
        elif self.sim is not None and self.sim.done and silent is not None and silent > self.settings.service.silence:
            reasons.append("the simulated drive has ended (run with --loop to repeat it)")
        return {
            "status": "degraded" if reasons else "ok",
            "reasons": reasons,
            "stage": pub.result.stage,
            "uptime_s": self.uptime(),
        }

    def silent_for(self) -> float | None:
        last = self.intake.last_rx
        return None if last is None else time.monotonic() - last

    def uptime(self) -> float:
        return time.monotonic() - self._started

    def status(self) -> dict:
        pub = self._pub
        r = pub.result
        silent = self.silent_for()
        store: dict[str, Any] = {
            "path": str(self.settings.store.path),
            "state": self.store_state,
            "error": self.store_error,
            "last_commit": self.store_last_commit,
            "restored": sorted(self.restored) if self.restored else [],
            "restore_error": self.restore_error,
        }
        if self.store is not None:
            store["commits"] = self.store.commits
            try:
                store["bytes"] = self.store.size()
            except OSError:
                store["bytes"] = None
        return jsonable(
            {
                "uptime_s": self.uptime(),
                "started": self._started_wall,
                "profile": {
                    "name": self.profile.vehicle.name,
                    "path": str(self.profile.path),
                    "fingerprint": self.fingerprint,
                },
                "bus": {
                    **self.link.status(),
                    "frames": self.intake.received,
                    "frames_per_s": self.frames_per_s,
                    "last_frame_age_s": silent,
                },
                "queue": {"depth": self.queue.qsize(), "capacity": self.queue.maxsize, "dropped": self.intake.dropped},
                "estimation": {
                    "frames": pub.fed,
                    "samples": r.samples,
                    "errors": self._errors,
                    "stage": r.stage,
                    "bus_time": r.bus_time,
                    "worker_restarts": self.worker_restarts,
                    "clock": r.clock,
                    "resets": r.resets,
                    "capabilities": r.capabilities,
                },
                "decode": r.decode,
                "channels": r.channels,
                "gating": {**r.supervisor, "window": r.current_window, "windows_total": len(r.windows)},
                "raw_log": self.rawlog.stats() if self.rawlog is not None else {"enabled": False},
                "store": store,
                "simulation": self.sim.status() if self.sim is not None else None,
            }
        )

    def history(
        self,
        parameter: str | None = None,
        since: float | None = None,
        until: float | None = None,
        limit: int = 100,
        offset: int = 0,
    ) -> dict:
        if parameter is not None and parameter not in NAMES:
            raise VdpError(f"unknown parameter '{parameter}'; known: {', '.join(NAMES)}")
        store = self.store
        if store is None:
            raise Unavailable(
                f"no estimate history: the store is {self.store_state}"
                + (f" ({self.store_error})" if self.store_error else "")
            )
        items, total = store.history(parameter, since, until, limit, offset)
        nxt = offset + len(items)
        return jsonable(
            {
                "items": items,
                "total": total,
                "limit": limit,
                "offset": offset,
                "next_offset": nxt if nxt < total else None,
            }
        )

    def reset(self, stage: int | None) -> dict:
        """Clear stage 1, 2 or (None) both, on the worker, in order with the frames."""
        if stage not in (None, 1, 2):
            raise VdpError(f"stage must be 1, 2 or all, got {stage!r}")
        self._call(lambda p: p.reset(stage))
        log.warning("estimates reset: %s", "all stages" if stage is None else f"stage {stage}")
        self.commit()
        return {"reset": "all" if stage is None else str(stage), **self.estimates()}

    def metrics(self) -> dict:
        """Numbers for /metrics, read without locks."""
        pub = self._pub
        r = pub.result
        rl = self.rawlog
        return {
            "frames": self.intake.received,
            "dropped": self.intake.dropped,
            "fed": pub.fed,
            "samples": r.samples,
            "queue_depth": self.queue.qsize(),
            "queue_capacity": self.queue.maxsize,
            "frames_per_s": self.frames_per_s,
            "bus_up": self.link.up,
            "reconnects": self.link.info.reconnects,
            "bus_errors": self.link.info.errors,
            "errors": self._errors,
            "decode": r.decode,
            "parameters": r.parameters,
            "stage": r.stage,
            "active_stage": r.supervisor.get("active_stage"),
            "resets": r.resets,
            "uptime": self.uptime(),
            "raw_bytes": rl.stats()["bytes"] if rl is not None else 0,
            "raw_frames": rl.frames if rl is not None else 0,
            "raw_lost": rl.lost if rl is not None else 0,
            "raw_ok": rl is None or rl.error is None,
            "store_ok": self.store_state == "ok",
            "store_commits": self.store.commits if self.store else 0,
            "healthy": self.health()["status"] == "ok",
            "channels_stale": sum(1 for f in r.channels.values() if f.stale),
            "channels": len(channels.NAMES),
        }
