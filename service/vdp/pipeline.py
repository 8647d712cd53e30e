"""The one pipeline, live or replay: frames -> decoder -> aligner -> ring -> estimator.

Only the frame source differs: ``vdp replay`` hands a log to :meth:`Pipeline.run`,
``vdp serve`` feeds frames from the bus one by one (:meth:`Pipeline.feed`) and
takes :meth:`Pipeline.result` now and then.  Readers see the typed
:class:`vdp.result.RunResult`, never the decoder, aligner or estimator inside.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from . import channels
from .buffer import Aligner, SampleRing
from .core import progress as coaching
from .core.estimator import EstimatorConfig, TwoStageEstimator
from .core.result import Estimate
from .core.sample import Sample
from .core.sample import block as sample_block
from .io.decoder import FrameDecoder
from .profile import Profile
from .profilecheck import Monitor
from .result import Clock, Freshness, LogInfo, RunResult

log = logging.getLogger(__name__)

STALE_PERIODS = 5.0  # a channel silent this many cycle times is stale
PROGRESS_EVERY = 4096  # frames between progress callbacks in run()


RUNS = ("replay", "batch", "live")
PLOT_ROWS = 20_000  # trace rows kept for vdp replay --plot: a 4-hour log's 144,000 rows took ~140 MB


def run_config(
    run: str,
    *,
    compiled: bool = False,
    per_axle: bool = True,
    mass: str = "auto",
    road: bool = False,
    ekf: bool = False,
    plot: bool = False,
    checks: Any = None,
) -> EstimatorConfig:
    """The estimator's settings for a run, assembled in this one place for ``run``:

    - ``replay`` (vdp replay): the compiled steps if ``compiled`` (vdp.replay.compiled_pays: a
      short log never loads numba); the trace kept only for a plot, at most PLOT_ROWS rows, thinned
      as the log goes on (without one, memory stays flat on long logs); the EKF beside if ``ekf``;
    - ``batch`` (vdp batch): as replay, with neither EKF nor trace (a plot's history grows with the
      log: 310 MB peak at 4 h against 200 MB at 1 h, and batch draws no plots);
    - ``live`` (vdp serve): numpy's filter steps (a live bus brings 50 samples/s, which they keep
      up with at a few per cent of a core, and numba's LLVM would add ~120 MB to the service's RSS:
      docs/decisions/0012, 0002), the EKF beside (/estimates' baseline), a 600-row trace for plots
      of recent data (history lives in the store), and stage 2's batch checks on ``checks`` (a
      background executor).

    ``per_axle``, ``mass`` (core.mass.MassConfig's mode) and ``road`` are the user's, the same
    in every run: ``--one-c``, ``--mass``, ``--road`` and ``[service]``'s keys.
    """
    from .core.learner import LearnerConfig
    from .core.mass import MassConfig
    from .core.road import RoadConfig

    if run not in RUNS:
        raise ValueError(f"run {run!r}: one of {', '.join(RUNS)}")
    live = run == "live"
    learner = LearnerConfig(per_axle=per_axle, compiled=compiled and not live, check_executor=checks)
    if live:
        trace_len, trace_max = 600, None
    else:
        trace_len, trace_max = (None, PLOT_ROWS) if plot and run == "replay" else (0, None)
    return EstimatorConfig(
        learner=learner,
        baseline=live or (ekf and run == "replay"),
        trace_len=trace_len,
        trace_max=trace_max,
        mass=MassConfig(mass),
        road=RoadConfig(on=road),
    )


class Pipeline:
    def __init__(self, profile: Profile, cfg: EstimatorConfig | None = None, ring_capacity: int = 3000):
        self.profile = profile
        self.decoder = FrameDecoder(profile)
        cfg = cfg or EstimatorConfig()
        # the speed reference this car has: GNSS at its resolution, or the free-rolling axle
        cfg = estimator_config(profile, self.decoder.db, cfg)
        self.estimator = TwoStageEstimator(profile.vehicle, profile.priors, cfg)
        self.aligner = Aligner(
            stale_after=self._stale_after(), tick=self.estimator.cfg.tick, limits=channels.limits(profile.vehicle)
        )
        self.ring = SampleRing(ring_capacity)
        self._taps: list[Callable[[Sample], None]] = []
        # samples taken but not yet estimated from: the gates' look-ahead (look_ahead), oldest first
        self._held: list[Sample] = []
        self._blocks = False  # the last samples came as a block the estimator took compiled (take_block)
        # the profile self-check of a running service, on the samples the ring holds (profilecheck);
        # vdp replay checks the log's first minutes instead and sets this to None
        self.monitor: Monitor | None = Monitor(profile, self.decoder, aligner=self.aligner)
        self.samples = 0
        self.finished = False  # a whole log has been read (run)
        self.last_bus_time: float | None = None  # the newest decoded frame's
        self.first_frame_time: float | None = None  # of any frame fed, decoded or not: the self-check's clock
        self.frame_time: float | None = None
        cap = self.capabilities()
        for stage, why in cap.items():
            if why:
                log.info("stage %s cannot run: %s", stage, why)

    def _stale_after(self) -> np.ndarray:
        out = np.full(channels.N, 0.1)
        for name, cm in self.profile.channels.items():
            try:
                cycle_ms = self.decoder.db.get_message_by_name(cm.message).cycle_time
            except KeyError:
                cycle_ms = None
            if cycle_ms:
                out[channels.INDEX[name]] = max(STALE_PERIODS * cycle_ms / 1000.0, 0.05)
        return out

    def capabilities(self) -> dict[str, str | None]:
        """Why each stage ("1", "2"), and I_x within stage 2, cannot run with this profile's
        channels (None: it can)."""
        p = self.profile
        out: dict[str, str | None] = {}
        silent = self.silent()
        # stage 2's speed: GNSS, the speed filter's wheel reference, or the rear wheels
        has_speed = p.has("speed") or p.speed_reference or all(p.has(c) for c in channels.STAGE2_SPEED)
        needs2 = channels.STAGE2_NEEDS + (() if has_speed else ("speed",))
        for stage, needs in (("1", channels.STAGE1_NEEDS), ("2", needs2)):
            out[stage] = _lacks(p.missing(needs))
            if out[stage] is None and silent:  # mapped, but the bus never carried it
                rear = stage == "2" and all(p.has(c) and c not in silent for c in channels.STAGE2_SPEED)
                out[stage] = _never(tuple(dict.fromkeys(needs + ("speed",))), silent, rear)
        if out["1"] and p.vehicle.l_f is None:
            tail = (
                "it needs l_f, and stage 1 cannot run: give the measured l_f (axle scales) "
                "as [vehicle] l_f and l_f_std in the profile"
            )
            out["2"] = f"{out['2']}; and {tail}" if out["2"] else tail
        ix = _lacks(p.missing(channels.IX_NEEDS))
        out["I_x"] = f"{ix}: the roll mode is unobservable, so I_x is not estimated" if ix else None
        return out

    def silent(self) -> dict[str, list[str]]:
        """Mapped channels that got no value because the bus never carried their message (nor
        an alternative's): channel -> the messages never decoded.  Known once a whole log is read
        (``finished``) or once the running service's self-check has looked; empty before."""
        mon = self.monitor
        if not (self.finished or (mon is not None and mon.checks)) or not self.frames:
            return {}
        good = {p.name: p.good for p in self.decoder._plans.values()}
        never = {name for name, n in good.items() if not n}
        out: dict[str, list[str]] = {}
        for name, cm in self.profile.channels.items():
            if cm.message in never and (cm.alt is None or cm.alt.message in never):
                out[name] = [cm.message] + ([cm.alt.message] if cm.alt is not None else [])
        for name, comp in getattr(self.profile, "composites", {}).items():
            absent = sorted(comp.messages & never)  # a composite needs every term current
            if absent:
                out[name] = absent
        if self.profile.speed_reference == "wheels":  # the ground speed is the wheels'
            wheels = [m for c in channels.NAMES[:4] for m in out.get(c, [])]
            if wheels:
                out["speed"] = list(dict.fromkeys(wheels))
        return out

    def feed(self, msg) -> None:
        """Consume one frame (a can.Message or anything with its attributes)."""
        t = self.frame_time = msg.timestamp
        if self.first_frame_time is None:
            self.first_frame_time = t
        pairs = self.decoder.decode(msg)
        if not pairs:
            return
        self.last_bus_time = t
        samples = self.aligner.push(t, pairs)
        if samples:
            self.take(samples)

    @property
    def frames(self) -> int:
        """Frames offered so far: the decoder counts every one (also those a source passed over)."""
        return self.decoder.stats.frames

    def look_ahead(self) -> int:
        """Samples the estimator takes each sample after it came: the gates see it that much earlier
        (core.gates.kerb: a kerb strike's rise, kerb_pre before the sample that fires, is gated too).
        The estimates lag as much (60 ms); :meth:`flush` takes the samples held at a log's end."""
        g = self.estimator.supervisor.gates.cfg
        return max(0, math.ceil(g.kerb_pre / self.estimator.cfg.tick - 1e-9))

    def take(self, samples: list[Sample]) -> None:
        """Estimate from aligned samples (the aligner's, or a block reader's that aligns itself),
        each :meth:`look_ahead` samples after it came."""
        ring, est, held, look = self.ring.append, self.estimator, self._held, self.look_ahead()
        self._blocks = False
        for s in samples:
            ring(s)
            if s.gap:  # nothing to look ahead across a gap: the samples before it are taken now
                self.flush()
            est.ahead(s)
            held.append(s)
            if len(held) > look:
                self._handle(held.pop(0))
        self.samples += len(samples)

    def _handle(self, s: Sample) -> None:
        s = self.estimator.handle(s.t, s)
        for fn in self._taps:
            fn(s)

    def flush(self) -> None:
        """Take the samples held for the look-ahead (a log's end, a gap): nothing comes after them."""
        held = self._held[:]
        self._held.clear()
        if held and self._blocks:  # (held from a block's compiled pass: taken as a block)
            T, Y, F, A = _arrays(held)
            self.estimator.handle_block(T, Y, F, A, held[0].gap)
            return
        for s in held:
            self._handle(s)

    def take_block(self, T: np.ndarray, Y: np.ndarray, F: np.ndarray, A: np.ndarray, gap: bool) -> None:
        """Estimate from a block of aligned samples as arrays (a block reader's, vdp.io.bulk):
        the same as :meth:`take` of their samples, in one compiled pass where the estimator
        can (TwoStageEstimator.handle_block) and no tap wants each sample."""
        if self._taps or not self.estimator.batchable():
            self.take(sample_block(T, Y, F, A, gap))
            return
        n = len(T)
        if not n:
            return
        self.ring.extend(T, Y)
        self.samples += n
        if gap:
            self.flush()
        held, look = self._held, self.look_ahead()
        self._blocks = True
        if held:  # the samples held from before, ahead of this block's (only the first may follow a gap)
            gap = held[0].gap
            T, Y, F, A = (np.concatenate((h, x)) for h, x in zip(_arrays(held), (T, Y, F, A)))
        keep = min(look, len(T))
        self.estimator.handle_block(T, Y, F, A, gap, ahead=keep)
        self._held = sample_block(T[len(T) - keep :], Y[len(T) - keep :], F[len(T) - keep :], A[len(T) - keep :],
                                  gap and keep == len(T)) if keep else []  # fmt: skip

    def tap(self, fn: Callable[[Sample], None]) -> None:
        """Call ``fn`` with every sample the estimator takes, as it saw it (derived fields set)."""
        self._taps.append(fn)

    def pass_over(self, counts: dict[int, int], other: int = 0) -> None:
        """Count frames a source left out because no plan decodes their id (see LogSource.keep_ids):
        by id, and ``other`` frames of ids it did not keep apart."""
        self.decoder.stats.add_unknown(counts, other)

    def run(self, source, progress: Callable[[int, int], None] | None = None) -> RunResult:
        """Feed every frame of ``source`` (a log: iterable of frames with ``stats``); return the result.

        ``progress(position, frames)`` is called every PROGRESS_EVERY frames.
        """
        t0 = time.monotonic()
        first = None
        keep_ids = getattr(source, "keep_ids", None)
        if keep_ids is not None:  # lines of ids the profile does not decode never become Messages
            keep_ids(self.decoder.ids)
        feed_into = getattr(source, "feed_into", None)
        if feed_into is not None:  # a block source (vdp.io.bulk) decodes and aligns itself, then take()s
            n, first = feed_into(self, progress)
        else:
            feed = self.feed
            n = 0
            for msg in source:
                feed(msg)
                n += 1
                if first is None:
                    first = msg.timestamp
                if progress is not None and n % PROGRESS_EVERY == 0:
                    progress(source.position, n)
        passed = getattr(source.stats, "passed_over", None) or {}
        other = getattr(source.stats, "passed_over_other", 0)
        if passed or other:
            self.pass_over(passed, other)
            n += sum(passed.values()) + other
        last = (self.last_bus_time if self.last_bus_time is not None else first) if n else None
        stats = source.stats.as_dict()
        duration = (last - first) if n and last is not None else 0.0
        # a log reader sums bus time over the runs between clock steps: never negative, never a jump's years
        bus_time = getattr(source.stats, "bus_time", None)
        if bus_time is not None:
            duration = bus_time
        info = LogInfo(
            path=str(getattr(source, "path", "")),
            frames=stats.get("frames", n),
            wall_s=time.monotonic() - t0,
            duration_s=duration,
            start_time=first,
            source=stats,
        )
        self.flush()
        self.estimator.finish()
        self.finished = True
        return self.result(trace=True, t0=first, log=info)

    def result(self, trace: bool = False, t0: float | None = None, log: LogInfo | None = None) -> RunResult:
        """The state now, as one immutable value (``trace``: with the estimator's trace)."""
        a = self.aligner
        snap = self.estimator.snapshot()
        caps = self.capabilities()
        coach, params = self._coach(snap, caps)
        ekf = snap.baseline_ekf
        check = None
        mon = self.monitor
        if mon is not None:  # parameters resting on a channel the check doubts are not valid
            mon.update(self.ring, self.first_frame_time, self.frame_time)
            params, ekf = mon.mark(params), mon.mark(ekf)
            check = mon.status()
        return RunResult.of(
            dataclasses.replace(snap, parameters=params, baseline_ekf=ekf),
            capabilities=caps,
            coaching=coach,
            decode=self.decode_stats(),
            clock=Clock(a.clock_backwards, a.clock_jumps),
            channels=self.freshness(),
            frames=self.frames,
            samples=self.samples,
            bus_time=self.last_bus_time,
            trace=tuple(self.estimator.trace) if trace else (),
            t0=t0,
            log=log,
            profile_check=check,
        )

    def decode_stats(self) -> dict:
        """The decoder's counters, and the values beyond a car's limits the aligner dropped."""
        out = self.decoder.stats.as_dict()
        out["out_of_bounds"] = self.aligner.refused_dict()
        return out

    def _coach(self, snap, caps) -> tuple[dict, dict[str, Estimate]]:
        """Progress and coaching from what the learners have (core.progress), and the UKF's
        estimates with their progress and hint filled in."""
        doc = {
            "parameters": {k: e.as_dict() for k, e in snap.parameters.items()},
            "stage": snap.stage,
            "supervisor": snap.supervisor,
            "capabilities": caps,
        }
        coach = coaching.assess(doc, self.profile.priors, self.estimator.cfg.tick)
        params = dict(snap.parameters)
        for name, c in coach["parameters"].items():
            e = params.get(name)
            if e is not None:
                params[name] = dataclasses.replace(e, progress=c["progress"], hint=c["hint"])
        return coach, params

    def freshness(self) -> dict[str, Freshness]:
        """Each mapped channel's age at the newest bus time, and whether it is stale."""
        out = {}
        t = self.last_bus_time
        for name in self.profile.channels:
            i = channels.INDEX[name]
            newest = self.aligner.newest(i)
            age = (t - newest) if (t is not None and math.isfinite(newest)) else None
            out[name] = Freshness(age, age is None or age > self.aligner.stale_after[i])
        return out

    def reset(self, stage: int | None = None) -> None:
        self.estimator.reset(stage)

    def restore(self, params: Mapping[str, Estimate]) -> None:
        """Start from stored estimates instead of the priors."""
        self.estimator.restore(params)


def _arrays(samples: list[Sample]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Samples as a block's arrays (ticks, values, fresh, ages by channel): core.sample.block's inverse."""
    return (
        np.array([s.t for s in samples], dtype=float),
        np.array([s.values for s in samples], dtype=float),
        np.array([s.fresh for s in samples], dtype=bool),
        np.array([s.age for s in samples], dtype=float),
    )


def _lacks(missing: list[str]) -> str | None:
    """'no yaw-rate gyro (the profile maps no yaw_rate)' for missing channels, or None."""
    if not missing:
        return None
    what = list(dict.fromkeys(channels.DESCRIPTIONS[m] for m in missing))
    return f"no {', no '.join(what)} (the profile maps no {', '.join(missing)})"


def _never(needs: tuple[str, ...], silent: dict[str, list[str]], speed_ok: bool) -> str | None:
    """'no wheel speeds (the bus never carried WHL_SPD11)' for needed channels whose messages
    never came, or None."""
    gone = [c for c in needs if c in silent and not (c == "speed" and speed_ok)]
    if not gone:
        return None
    what = list(dict.fromkeys(channels.DESCRIPTIONS.get(c, c) for c in gone))
    msgs = list(dict.fromkeys(m for c in gone for m in silent[c]))
    return f"no {', no '.join(what)} (the bus never carried {', '.join(msgs)})"


def speed_config(profile: Profile, db: Any, base: Any) -> Any:
    """The speed filter's settings for this car: the GNSS noise inflated by the speed signal's
    resolution, or the free-rolling axle as the reference when there is no GNSS."""
    from .core.speed import ROUNDING_STATE_MIN, gnss_noise

    cm = profile.channels.get("speed")
    if cm is not None:
        sig = db.get_message_by_name(cm.message).get_signal_by_name(cm.fine or cm.signal)
        step = abs(sig.conversion.scale * cm.scale * cm.factor(profile.vehicle)) if not sig.is_float else 0.0
        if step >= ROUNDING_STATE_MIN:  # a coarse step: its rounding error gets a state of its own
            return dataclasses.replace(base, gnss_step=step, wheel_ref=None)
        return dataclasses.replace(base, gnss_noise=gnss_noise(base.gnss_noise, step), wheel_ref=None)
    if getattr(profile, "speed_reference", None) == "wheels":
        return dataclasses.replace(base, wheel_ref=profile.drivetrain.free_axle)
    return base


def estimator_config(profile: Profile, db: Any, cfg: Any) -> Any:
    """``cfg`` (an EstimatorConfig) with this car's speed reference (:func:`speed_config`)."""
    return dataclasses.replace(cfg, speed=speed_config(profile, db, cfg.speed))
