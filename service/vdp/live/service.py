"""The live service: ingest -> estimation -> store writer, behind one read side for the API.

The pieces, each startable and testable alone:

- :class:`~vdp.live.ingest.Ingest`: bus -> raw log and the bounded frame queue
  (python-can's Notifier thread, ``vdp-bus`` reconnecting with backoff, and
  ``vdp-sim`` with ``--simulate``);
- :class:`~vdp.live.estimation.Estimation`: ``vdp-estimate``, the only thread
  that touches the pipeline; it publishes immutable snapshots;
- :class:`~vdp.live.writer.StoreWriter`: commits the latest snapshot to the store;
- this :class:`Service`: starts and stops them in order, runs ``vdp-keep`` (once
  per ``commit_interval``: commit, flush the raw log, measure rates, restart a
  dead worker) and answers the API from the latest snapshot.

The service raises :mod:`vdp.errors` exceptions only; the API turns them into
HTTP answers.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from .. import channels
from ..core.params import MASS, NAMES, PUBLISHED
from ..core.result import INVALID
from ..errors import VdpError
from ..result import jsonable
from ..settings import Settings
from ..store import profile_fingerprint
from .drives import Drives
from .estimation import COMMAND_TIMEOUT, Estimation, Published, Unavailable
from .ingest import Ingest
from .writer import StoreWriter

log = logging.getLogger(__name__)

__all__ = ["Published", "Service", "Unavailable"]


def profile_check_reasons(check: dict | None) -> list[str]:
    """/health's reasons from the self-check (profilecheck.Monitor.status()): a bus that does not
    fit the profile, messages of it never seen, and each finding."""
    if not check:
        return []
    out = []
    cov = check.get("coverage")
    if check.get("error"):
        out.append(f"profile check: {check['error']}")
    elif cov and cov["missing"]:
        out.append(f"profile check: {cov['message']}")
    out += [f"profile check: {f['message']}" for f in check.get("findings", ())]
    return out


class Service:
    def __init__(self, settings: Settings, profile=None, opener: Callable | None = None, pipeline=None):
        from ..pipeline import Pipeline
        from ..profile import load_profile

        self.settings = settings
        self.profile = profile if profile is not None else load_profile(settings.profile)
        self.fingerprint = profile_fingerprint(self.profile)
        self.ingest = Ingest(settings, self.profile, opener)
        # Stage 2's batch check solves in a background thread: numpy's ~20 s for a full record of a
        # bending tyre would stop this worker, whose queue holds ~8 s of a saturated bus.
        self.checks = CheckThread()
        cfg = self.estimator_config(
            settings.service.per_axle, self.checks, mass=settings.service.mass, road=settings.service.road
        )
        pipe = pipeline if pipeline is not None else Pipeline(self.profile, cfg)
        self.estimation = Estimation(
            pipe, self.ingest.queue, settings.service.publish_interval, channel=self.ingest.channel
        )
        self.writer = StoreWriter(settings.store, self.fingerprint, self.profile.vehicle.name)
        # drives, and the changes between them (a mass step, new tyres, another car on the bus)
        self.drives = Drives(self.profile, self.writer)
        self.estimation.gap_hook, self.estimation.gap_s = self._drives_silence, self.drives.gap
        self._looking: Future | None = None  # the drive look queued on the worker
        self.restored: dict | None = None
        self.restore_error: str | None = None
        self.resumed: list[str] = []  # the learners whose own state a restart took back ("mass" among them)
        self._keeper: threading.Thread | None = None
        self._stop = threading.Event()
        self._started = time.monotonic()
        self._started_wall = time.time()
        self._trimmed = time.monotonic()
        self.running = False

    @staticmethod
    def estimator_config(per_axle: bool, checks, mass: str = "auto", road: bool = False):
        """The live pipeline's estimator settings (pipeline.run_config's "live": ``checks`` the executor
        of stage 2's batch checks; ``per_axle``, ``mass``, ``road``: ``[service]``'s keys)."""
        from ..pipeline import run_config

        return run_config("live", per_axle=per_axle, mass=mass, road=road, checks=checks)

    # the pieces' parts that callers and tests reach for
    pipeline = property(lambda self: self.estimation.pipeline)
    queue = property(lambda self: self.ingest.queue)
    intake = property(lambda self: self.ingest.intake)
    rawlog = property(lambda self: self.ingest.rawlog)
    link = property(lambda self: self.ingest.link)
    sim = property(lambda self: self.ingest.sim)
    bus_cfg = property(lambda self: self.ingest.bus_cfg)
    store = property(lambda self: self.writer.store)
    store_state = property(lambda self: self.writer.state)
    store_error = property(lambda self: self.writer.error)

    # -- life cycle --------------------------------------------------------------------------
    def start(self) -> None:
        self._started, self._started_wall = time.monotonic(), time.time()
        self._restore(self.writer.open())
        self.drives.open()
        self.ingest.open_rawlog()
        self.estimation.start()
        self.ingest.start()
        self._stop.clear()
        self._keeper = threading.Thread(target=self._keeper_loop, name="vdp-keep", daemon=True)
        self._keeper.start()
        self.running = True

    def stop(self, budget: float | None = None, say: Callable[[str], None] | None = None) -> None:
        """Stop receiving, estimate what is queued (``budget``: seconds for both at most; the frames
        left then are dropped and counted in ``estimation.dropped``), commit, close the files.  ``say``: told
        what the stop is finishing, and what it left (the CLI prints it)."""
        if not self.running:
            return
        t0 = time.monotonic()
        self.running = False
        self.ingest.stop()
        self._stop.set()
        if self._keeper is not None:
            self._keeper.join(timeout=10.0)
        queued = self.ingest.queue.qsize()
        left = None if budget is None else max(budget - (time.monotonic() - t0), 0.0)  # receiving took its share
        closing = ", closing the raw log" if self.ingest.rawlog is not None else ""
        head = f"estimating the {queued} frames still queued" + (f" (for {left:.1f} s at most)" if left else "")
        (say or log.info)(f"stopping: {head}, saving the estimates{closing}")
        self.estimation.stop(budget=left)
        if self.estimation.dropped:
            (say or log.info)(
                f"{self.estimation.dropped} of the {queued} queued frames were not estimated ({self.dropped_note()})"
            )
        # a check still solving is not waited for: its fit would come after the last commit
        self.checks.shutdown(wait=False, cancel_futures=True)
        self._drives(self.drives.end)  # the worker has ended: the pipeline is this thread's
        self.commit()
        self.ingest.close()
        self.writer.close()
        log.info("service stopped")

    def dropped_note(self) -> str:
        """What the frames a stop left unestimated cost."""
        if self.sim is not None:
            return "simulated frames: nothing is lost"
        if self.settings.raw_log.enabled:
            return f"the raw log in {self.settings.raw_log.dir} has them: vdp replay it to estimate them too"
        return "they are lost: enable the raw log to keep every frame"

    def _restore(self, stored: dict) -> None:
        # the six the learners take back; the mass (core.mass) only through its learner's own state
        # (the store's "learnt"), resumed where it gives back the stored mass, else from the prior
        mass = {k: v.estimate for k, v in stored.items() if k == MASS}
        stored = {k: v for k, v in stored.items() if k in NAMES}
        if not stored:
            return
        why = self.estimation.restore({k: v.estimate for k, v in stored.items()})
        if why is not None:
            self.restore_error = f"{why} from {self.settings.store.path}; starting from the priors"
            log.error("%s", self.restore_error)
            return
        self.restored = stored
        learnt = self.writer.store.learnt() if self.writer.store is not None else None
        if learnt:  # the learners' own covariances: a restart neither tightens nor widens the stds
            resumed = self.estimation.resume(learnt, {**{k: v.estimate for k, v in stored.items()}, **mass})
            self.resumed = resumed
            log.info("resumed the learners' own state: %s", ", ".join(resumed) or "none (kept the stored stds)")
        when = max(v.t for v in stored.values())
        log.info(
            "restored %d estimates from %s (saved %s)",
            len(stored),
            self.settings.store.path,
            time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(when)),
        )

    # -- keeper thread ----------------------------------------------------------------------------
    def _keeper_loop(self) -> None:
        every = self.settings.store.commit_interval
        while not self._stop.wait(every):
            try:
                self.housekeeping()
            except Exception:
                log.exception("housekeeping failed; carrying on")

    def housekeeping(self) -> None:
        """One round of ``vdp-keep``: look at the drive, commit, flush the raw log, measure rates,
        restart a dead worker."""
        if self.running and self.estimation.alive and (self._looking is None or self._looking.done()):
            self._looking = self.estimation.post(self._drives_check)  # not waited for: commits go on
        self.commit()
        self.ingest.tick()
        if self.running:
            self.estimation.ensure_running()
        now = time.monotonic()
        if now - self._trimmed >= TRIM_EVERY:
            self._trimmed = now
            trim_heap()

    def _drives_check(self, pipe) -> None:
        self._drives(self.drives.check, pipe)

    def _drives_silence(self, pipe, end: float, start: float) -> None:
        self._drives(lambda p: self.drives.silence(p, end, start), pipe)

    def _drives(self, fn, pipe=None) -> None:
        """Run a drive look on the pipeline (a real one: a test's stand-in has no decoder); a failure is
        logged, never the worker's end."""
        pipe = self.pipeline if pipe is None else pipe
        if getattr(pipe, "decoder", None) is None:
            return
        try:
            fn(pipe)
        except Exception:
            log.exception("the drive check failed; carrying on")

    def commit(self) -> None:
        """Commit the latest snapshot, if it is new."""
        self.writer.commit(self.estimation.latest)

    def _call(self, fn: Callable[[Any], Any], timeout: float = COMMAND_TIMEOUT) -> Any:
        """Run ``fn(pipeline)`` on the worker, after every frame already queued."""
        if not self.running:
            raise Unavailable("the estimation worker is not running")
        return self.estimation.call(fn, timeout)

    # -- read side (any thread) ---------------------------------------------------------------------
    @property
    def latest(self) -> Published:
        return self.estimation.latest

    def backlog(self) -> float:
        return self.ingest.backlog()

    def sync(self, timeout: float = 60.0) -> Published:
        """Wait until every frame queued so far is estimated and every batch check has ended;
        return the snapshot after it (tests, and a caller who wants the numbers settled).  The
        samples the pipeline holds for the gates' look-ahead are taken too (Pipeline.flush)."""

        def settle(p) -> None:
            p.flush()
            est = getattr(p, "estimator", None)
            if est is not None:
                est.settle()

        self._call(settle, timeout)
        return self.latest

    def estimates(self) -> dict:
        pub = self.latest
        doc = pub.result.estimates_dict()
        del doc["windows"]
        doc.update(restored=pub.restored, bus_time=pub.bus_time, updated=pub.wall)
        return jsonable(doc)

    def health(self) -> dict:
        reasons: list[str] = []
        now = time.monotonic()
        sv = self.settings.service
        pub, ing = self.latest, self.ingest
        info = ing.link.info
        if info.state != "up":
            reasons.append(f"bus {info.state}" + (f": {info.last_error}" if info.last_error else ""))
        silent = ing.silent_for()
        if silent is None:
            reasons.append("no frames received yet")
        elif silent > sv.silence:
            reasons.append(f"no frames for {silent:.0f} s")
        else:
            stale = sorted(n for n, f in pub.result.channels.items() if f.stale)
            if stale:
                reasons.append(f"stale channels: {', '.join(stale)}")
        invalid = pub.result.decode.get("invalid_channels") or []
        if invalid:
            reasons.append(f"invalid channels (bad counter or checksum): {', '.join(invalid)}")
        reasons += self.estimation.diverged(sv.diverged_hold)
        reasons += profile_check_reasons(pub.result.profile_check)
        bad = sorted(n for n, p in pub.result.parameters.items() if p.status == INVALID)
        if bad:
            reasons.append(f"invalid estimates: {', '.join(bad)}")
        lost = info.drops_at
        if lost is not None and now - lost <= sv.diverged_hold:
            reasons.append(
                f"frames lost before vdp read them: {info.kernel_drops or 0} dropped by the kernel (receive "
                f"buffer full), {info.overruns} controller overrun report(s); the raw log has gaps there"
            )
        if ing.dropped_at is not None and now - ing.dropped_at <= sv.diverged_hold:
            reasons.append(
                f"estimation fell behind: {ing.intake.dropped} frame(s) dropped from estimation "
                "(thinned; the raw log has them)"
            )
        if ing.rawlog is not None and ing.rawlog.error:
            reasons.append(f"raw logging stopped: {ing.rawlog.error}")
        if ing.rawlog is not None:
            reasons += ing.rawlog.recently(sv.diverged_hold)
        if self.restore_error:
            reasons.append(self.restore_error)
        if not self.writer.ok:
            reasons.append(f"estimate store {self.writer.state}: {self.writer.error or ''}".rstrip(": "))
        if self.writer.recovered:
            reasons.append(f"estimate store recovered: {self.writer.recovered}")
        if not self.estimation.alive:
            reasons.append("estimation worker not running")
        sim = ing.sim
        if sim is not None and sim.error:
            reasons.append(f"simulation failed: {sim.error}")
        elif sim is not None and sim.done and silent is not None and silent > sv.silence:
            reasons.append("the simulated drive has ended (run with --loop to repeat it)")
        return {
            "status": "degraded" if reasons else "ok",
            "reasons": reasons,
            "stage": pub.result.stage,
            "uptime_s": self.uptime(),
        }

    def silent_for(self) -> float | None:
        return self.ingest.silent_for()

    def uptime(self) -> float:
        return time.monotonic() - self._started

    def status(self) -> dict:
        pub = self.latest
        r = pub.result
        est = self.estimation
        store = {
            **self.writer.status(),
            "restored": sorted(self.restored) if self.restored else [],
            "restore_error": self.restore_error,
            "hold": self.writer.hold,
        }
        parts = self.ingest.status()
        return jsonable(
            {
                "uptime_s": self.uptime(),
                "started": self._started_wall,
                "profile": {
                    "name": self.profile.vehicle.name,
                    "path": str(self.profile.path),
                    "fingerprint": self.fingerprint,
                },
                "bus": parts["bus"],
                "queue": parts["queue"],
                "estimation": {
                    "frames": pub.fed,
                    # frames of the bus estimation skipped to keep up (the raw log has every one)
                    "thinned": self.ingest.intake.dropped,
                    "samples": r.samples,
                    "errors": est.errors,
                    "stage": r.stage,
                    "bus_time": r.bus_time,
                    "worker_restarts": est.restarts,
                    "clock": r.clock,
                    "resets": r.resets,
                    "capabilities": r.capabilities,
                },
                "decode": r.decode,
                "profile_check": r.profile_check,
                "channels": self._channels_now(r.channels),
                "gating": {**r.supervisor, "window": r.current_window, "windows_total": len(r.windows)},
                "raw_log": parts["raw_log"],
                "store": store,
                "drives": self.drives.status(),
                "simulation": parts["simulation"],
            }
        )

    def _channels_now(self, chans: dict) -> dict:
        """Each channel as of now once the bus has been silent longer than [service] silence (the
        health check's "no frames for N s"): every channel stale, its age counted to now.  Ages at
        the newest frame stay small while nothing comes, and /status said "not stale"."""
        from ..result import Freshness

        silent = self.ingest.silent_for()
        if silent is None or silent <= self.settings.service.silence:
            return chans
        return {n: Freshness(None if f.age is None else f.age + silent, True) for n, f in chans.items()}

    def history(
        self,
        parameter: str | None = None,
        since: float | None = None,
        until: float | None = None,
        limit: int = 100,
        offset: int = 0,
    ) -> dict:
        if parameter is not None and parameter not in PUBLISHED:
            raise VdpError(f"unknown parameter '{parameter}'; known: {', '.join(PUBLISHED)}")
        return jsonable(self.writer.history(parameter, since, until, limit, offset))

    def drive_history(self, limit: int = 1000) -> dict:
        """Each parameter across drives (the value each drive ended with), the drives and the
        changes named between them, oldest first."""
        store = self.writer.store
        if store is None:
            raise Unavailable(
                f"no drive history: the store is {self.writer.state}"
                + (f" ({self.writer.error})" if self.writer.error else "")
            )
        drives, changes = store.drives(limit), store.changes(limit)
        series: dict[str, list] = {n: [] for n in NAMES}
        for d in drives:
            for n, e in (d["last"] or {}).items():
                if n in series:
                    series[n].append({"drive": d["id"], "t0": d["t0"], "t1": d["t1"], **e})
        return jsonable({"parameters": series, "drives": drives, "changes": changes})

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
        pub = self.latest
        r = pub.result
        ing = self.ingest
        rl = ing.rawlog
        return {
            "frames": ing.intake.received,
            "dropped": ing.intake.dropped,
            "kernel_drops": ing.link.info.kernel_drops,
            "controller_overruns": ing.link.info.overruns,
            "receive_buffer": ing.link.info.receive_buffer,
            "fed": pub.fed,
            "samples": r.samples,
            "queue_depth": ing.queue.qsize(),
            "queue_capacity": ing.queue.maxsize,
            "frames_per_s": ing.frames_per_s,
            "bus_up": ing.link.up,
            "reconnects": ing.link.info.reconnects,
            "bus_errors": ing.link.info.errors,
            "bus_garbage": ing.link.info.garbage,
            "errors": self.estimation.errors,
            "decode": r.decode,
            "parameters": r.parameters,
            "stage": r.stage,
            "active_stage": r.supervisor.get("active_stage"),
            "resets": r.resets,
            "uptime": self.uptime(),
            "raw_bytes": rl.stats()["bytes"] if rl is not None else 0,
            "raw_accepted": rl.accepted if rl is not None else 0,
            "raw_frames": rl.written if rl is not None else 0,
            "raw_lost": rl.lost if rl is not None else 0,
            "raw_reopened": rl.reopened if rl is not None else 0,
            "raw_ok": rl is None or rl.error is None,
            "store_ok": self.writer.ok,
            "store_commits": self.writer.commits,
            "store_recoveries": self.writer.recoveries,
            "healthy": self.health()["status"] == "ok",
            "channels_stale": sum(1 for f in r.channels.values() if f.stale),
            "channels": len(channels.NAMES),
        }


TRIM_EVERY = 60.0  # s between returns of freed heap memory to the OS


def _load_libc():
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        return libc if hasattr(libc, "malloc_trim") else None
    except OSError:
        return None


_LIBC = _load_libc()


def trim_heap() -> None:
    """Give the OS back the heap memory the allocator holds freed (glibc's malloc_trim; elsewhere nothing).
    Blocks of frames come and go all the time: without it RSS creeps up by fragments."""
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


class CheckThread:
    """The background batch checks' executor: one daemon thread, the checks in turn.

    Not a ThreadPoolExecutor: the interpreter joins its workers at exit, so a fit still solving
    when the service stopped held Ctrl-C's exit for seconds after "service stopped".  A daemon
    thread ends with the process; the fit it was solving comes after the last commit anyway.
    """

    def __init__(self):
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._down = False
        self._thread = threading.Thread(target=self._run, name="vdp-check", daemon=True)
        self._thread.start()

    def submit(self, fn: Callable, *args) -> Future:
        if self._down:
            raise RuntimeError("the checks' thread is shut down")
        fut: Future = Future()
        self._jobs.put((fut, fn, args))
        return fut

    def shutdown(self, wait: bool = False, cancel_futures: bool = True) -> None:
        """No new checks; those not begun are cancelled; ``wait``: for the one solving to end."""
        self._down = True
        while True:
            try:
                job = self._jobs.get_nowait()
            except queue.Empty:
                break
            if job is not None and cancel_futures:
                job[0].cancel()
        self._jobs.put(None)
        if wait:
            self._thread.join()

    def _run(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            fut, fn, args = job
            if not fut.set_running_or_notify_cancel():
                continue
            try:
                fut.set_result(fn(*args))
            except BaseException as exc:
                fut.set_exception(exc)
