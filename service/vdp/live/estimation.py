"""The estimation loop: the only thread (``vdp-estimate``) that touches the pipeline.

It takes frames and commands (reset, restore, tests' probes) from one queue,
in arrival order, and every ``publish_interval`` publishes an immutable
:class:`Published` snapshot.  Readers (store writer, API) only ever see the
latest snapshot, so a request never waits for a filter step.
"""

from __future__ import annotations

import itertools
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field
from typing import Any

from ..errors import VdpError
from ..result import RunResult
from .reader import ERR, EXT, message_of

log = logging.getLogger(__name__)

_STOP = object()
_EXT_KEY = 1 << 31  # the decoder's key of an extended id (vdp.io.decoder)
COMMAND_TIMEOUT = 10.0  # s an API command waits for the worker


class Unavailable(VdpError):
    """The service cannot answer this now (worker busy or stopped, store refused)."""


@dataclass(frozen=True)
class Published:
    """One consistent view of the estimator, taken on the worker thread."""

    seq: int
    wall: float
    result: RunResult
    fed: int
    restored: bool = False
    # the learners' own state (TwoStageEstimator.learnt), stored with the estimates for a restart
    learnt: dict | None = None

    @property
    def bus_time(self) -> float | None:
        return self.result.bus_time


@dataclass
class _Command:
    fn: Callable[[Any], Any]
    future: Future = field(default_factory=Future)


def _same(a: float | None, b: float | None) -> bool:
    return a is not None and b is not None and math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-12)


class Estimation:
    def __init__(self, pipeline, frames: queue.Queue, publish_interval: float, channel: str | None = None):
        self.pipeline = pipeline
        self.channel = channel  # the channel frames read from a socket are given (bus.frame_channel)
        self.queue = frames
        self.publish_interval = publish_interval
        self.errors = 0  # frames on which estimation raised, and failed snapshots
        self.fed = 0
        self.dropped = 0  # frames queued at a stop that ran out of time, not estimated
        self._stop_by: float | None = None  # monotonic time by which a stop must be done
        self.restarts = 0
        self.restored = False  # the estimator started from stored estimates
        self._seq = itertools.count(1)
        self._pub = Published(0, time.time(), pipeline.result(), 0)
        self._dirty = True
        self._checks = 0  # background batch-check fits seen by the last snapshot
        self._thread: threading.Thread | None = None
        self._resets_seen: dict = {}
        self._diverged: dict[str, tuple[float, str]] = {}  # filter kind -> (monotonic time, what)
        self._keep: frozenset | bool | None = False  # decoded ids, found at the first block
        # run as hook(pipeline, end, start) before the run's first frame (end None) and before the
        # first frame after a silence of the bus longer than ``gap_s`` of bus time, end and start its
        # bounds (the service's drives: a silence ends a drive and begins the next, whose frames must
        # all count to it, whenever the keeper runs)
        self.gap_hook: Callable[[Any, float, float], None] | None = None
        self.gap_s = math.inf
        self._last_t: float | None = None

    # -- life cycle ------------------------------------------------------------------------------
    def restore(self, estimates: Mapping) -> str | None:
        """Start from stored estimates (before :meth:`start`); the error if the estimator did not
        take them (claiming "restored" over the priors would be a lie)."""
        self.pipeline.restore(estimates)
        now = self.pipeline.result().parameters
        off = [k for k, e in estimates.items() if k not in now or not _same(now[k].value, e.value)]
        if off:
            return f"the estimator did not take the stored estimates of {', '.join(sorted(off))}"
        self.restored = True
        return None

    def resume(self, learnt: Mapping, estimates: Mapping) -> list[str]:
        """After :meth:`restore`, before :meth:`start`: each learner's own state where it gives back
        the stored estimates (TwoStageEstimator.resume); the learners resumed."""
        est = getattr(self.pipeline, "estimator", None)
        if est is None or not hasattr(est, "resume"):
            return []
        done = est.resume(learnt, estimates)
        self._pub = Published(0, time.time(), self.pipeline.result(), 0)
        return done

    def start(self) -> None:
        self.publish()
        self._spawn()

    def _spawn(self) -> None:
        self._thread = threading.Thread(target=self._work, name="vdp-estimate", daemon=True)
        self._thread.start()

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def ensure_running(self) -> None:
        """Start the worker again if it ever died (called by the keeper)."""
        if self._thread is not None and not self._thread.is_alive():
            self.restarts += 1
            log.error("the estimation worker stopped; starting it again (restart %d)", self.restarts)
            self._spawn()

    def stop(self, timeout: float = 60.0, budget: float | None = None) -> None:
        """Estimate what is queued, publish, and end the worker.  ``budget``: seconds to spend on
        the queued frames at most; those left then are dropped and counted (:attr:`dropped`)."""
        if self.alive:
            if budget is not None:
                self._stop_by = time.monotonic() + budget
            self.queue.put(_STOP)
            self._thread.join(timeout=timeout)

    def _drop_rest(self, item) -> None:
        """Drop ``item`` and every frame queued before the stop; refuse the commands among them."""
        q = self.queue
        while item is not _STOP:
            if isinstance(item, _Command):
                if item.future.set_running_or_notify_cancel():
                    item.future.set_exception(Unavailable("the service is stopping"))
            else:
                self.dropped += len(item) if type(item) is list else 1
            item = q.get()
        self.publish()

    # -- the worker --------------------------------------------------------------------------------
    def _work(self) -> None:
        q = self.queue
        interval = self.publish_interval
        next_pub = time.monotonic() + interval
        while True:
            try:
                item = q.get(timeout=interval)
            except queue.Empty:
                item = None
            if item is _STOP:
                self.pipeline.flush()  # the samples held for the gates' look-ahead: nothing comes after them
                self.publish()
                return
            if isinstance(item, _Command):
                self._run(item)
                next_pub = time.monotonic() + interval
                continue
            if item is not None:
                if self._stop_by is not None and time.monotonic() > self._stop_by:
                    self._drop_rest(item)  # out of time to stop in: the rest is not estimated
                    return
                if type(item) is list:
                    self._feed_block(item)
                else:
                    self._feed_one(item)
                self._dirty = True
            now = time.monotonic()
            if now >= next_pub:
                # new frames, or a batch check that finished in the background since (its fit changes
                # the stds even when the bus has gone quiet)
                if self._dirty or self._checks_solved() != self._checks:
                    self.publish()
                next_pub = now + interval

    def _after_gap(self, t: float) -> None:
        """Run the gap hook if ``t`` (bus time of the next frame) is the first or follows a silence
        longer than gap_s."""
        last, self._last_t = self._last_t, t
        if (last is None or t - last > self.gap_s) and self.gap_hook is not None:
            try:
                self.gap_hook(self.pipeline, last, t)
            except Exception:
                log.exception("the look at a silence of the bus failed; carrying on")

    def _feed_one(self, msg) -> None:
        if self.gap_hook is not None:
            self._after_gap(msg.timestamp)
        try:
            # candump logs keep microseconds: rounding here makes the live estimate
            # and a replay of the raw log see the very same numbers.
            msg.timestamp = round(msg.timestamp, 6)
            self.pipeline.feed(msg)
        except Exception:
            self._failed()
        self.fed += 1

    def _failed(self) -> None:
        self.errors += 1
        if self.errors == 1 or self.errors % 1000 == 0:
            log.exception("estimation failed on a frame (%d so far); carrying on", self.errors)

    def _feed_block(self, block: list) -> None:
        """A block of frame records: the frames of ids the decoder decodes become Messages and are fed
        (one at a time: an error costs one frame); the others are only counted by id, as a replay
        that leaves them out counts them (Pipeline.pass_over), never made into Messages."""
        if self.gap_hook is not None and block:
            last = block[0][0] if self._last_t is None else self._last_t
            if block[-1][0] - last > self.gap_s:  # (a block spans ~0.1 s of a bus: rarely true)
                cut = next((i for i, f in enumerate(block) if f[0] - (block[i - 1][0] if i else last) > self.gap_s), 0)
                if cut:
                    self._feed_block(block[:cut])
                    block = block[cut:]
            self._after_gap(block[0][0])
            self._last_t = block[-1][0]
        pipe, chan = self.pipeline, self.channel
        keep = self._decoded_ids()
        if keep is None:  # a pipeline without a decoder to ask (tests' stand-ins): every frame is fed
            for f in block:
                self._feed_one(message_of(f, chan))
            return
        feed = pipe.feed
        other: dict[int, int] = {}
        for f in block:
            fl = f[2]
            key = f[1] | _EXT_KEY if fl & EXT else f[1]
            if key in keep or fl & ERR:
                try:
                    feed(message_of(f, chan))
                except Exception:
                    self._failed()
            else:
                other[key] = other.get(key, 0) + 1
        if other:
            try:
                pipe.pass_over(other)
            except Exception:
                self._failed()
        self.fed += len(block)

    def _decoded_ids(self) -> frozenset | None:
        """Ids (extended ones with bit 31 set) the pipeline's decoder decodes; None: feed every frame.
        Also None when the decoder keeps only other channels than this bus's (it counts those apart)."""
        if self._keep is False:
            dec = getattr(self.pipeline, "decoder", None)
            want = getattr(dec, "_want", None)
            ok = dec is not None and hasattr(self.pipeline, "pass_over") and (want is None or self.channel in want)
            self._keep = frozenset(dec.ids) if ok else None
        return self._keep

    def _run(self, cmd: _Command) -> None:
        if not cmd.future.set_running_or_notify_cancel():
            return
        try:
            result = cmd.fn(self.pipeline)
        except BaseException as exc:
            self.publish()
            cmd.future.set_exception(exc)
        else:
            # publish first: a caller woken by the result (sync) reads the snapshot at once
            self.publish()
            cmd.future.set_result(result)

    def _checks_solved(self) -> int:
        est = getattr(self.pipeline, "estimator", None)
        return est.checks_solved() if est is not None else 0

    def publish(self) -> None:
        """Take a snapshot (on the worker thread, or before it runs)."""
        checks = self._checks_solved()  # before the snapshot: a fit landing during it publishes again
        try:
            pub = Published(
                seq=next(self._seq),
                wall=time.time(),
                result=self.pipeline.result(trace=True),
                fed=self.fed,
                restored=self.restored,
                learnt=self._learnt(),
            )
        except Exception:
            self.errors += 1
            log.exception("taking a snapshot failed")
            return
        self._dirty = False
        self._checks = checks
        self._note_resets(pub.result.resets)
        self._pub = pub

    def _learnt(self) -> dict | None:
        est = getattr(self.pipeline, "estimator", None)
        return est.learnt() if est is not None and hasattr(est, "learnt") else None

    def _note_resets(self, resets: Mapping[str, int]) -> None:
        for kind, n in resets.items():
            if isinstance(n, int) and n > self._resets_seen.get(kind, 0):
                self._diverged[kind] = (
                    time.monotonic(),
                    f"the {kind.upper()} filter diverged and was reset to its "
                    f"last good estimate ({n} time{'s' if n > 1 else ''} so far)",
                )
            self._resets_seen[kind] = n

    # -- any thread --------------------------------------------------------------------------------
    @property
    def latest(self) -> Published:
        return self._pub

    def diverged(self, hold: float) -> list[str]:
        """Divergences of the last ``hold`` seconds, one per filter kind (the EKF's never hides the UKF's)."""
        now = time.monotonic()
        return [what for when, what in self._diverged.values() if now - when <= hold]

    def post(self, fn: Callable[[Any], Any]) -> Future | None:
        """Queue ``fn(pipeline)`` to run on the worker after the frames queued so far; do not wait.
        None when the queue is full (try again later)."""
        cmd = _Command(fn)
        try:
            self.queue.put_nowait(cmd)
        except queue.Full:
            return None
        return cmd.future

    def call(self, fn: Callable[[Any], Any], timeout: float = COMMAND_TIMEOUT) -> Any:
        """Run ``fn(pipeline)`` on the worker, after every frame already queued."""
        if not self.alive:
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
