"""The two-stage estimator: supervisor plus a UKF and an EKF learner per stage.

Aligned samples go in through ``handle(t, sample)``; ``snapshot()`` gives the
parameters (UKF, the method), the EKF baseline, the supervisor's state and the
windows.  Stage 2 starts once l_f is known (the hand-over): measured in the
profile, or stage 1's estimate valid even if h and C_K are not yet; it takes
l_f (considered, with its std), h and C_K of the same filter kind.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from .. import channels as ch
from . import batched, steer
from . import passes as ps
from .compiled import kernel
from .learn.base import LearnerConfig
from .learn.stage1 import Stage1
from .learn.stage2 import Stage2
from .mass import STAGE as MASS_STAGE
from .mass import MassConfig, MassLearner, scaled, unscaled
from .mass import off as mass_off
from .params import MASS
from .result import CONVERGED, NOT_RUN, SETTLED, UNCERTAIN, Estimate, Snapshot, WindowSpan
from .road import RoadConfig, Tilt
from .sample import Sample
from .speed import SpeedConfig, speed_filter
from .supervisor import GateConfig, Supervisor

log = logging.getLogger(__name__)

L_F_KNOWN = 0.02  # stage 1's l_f relative std at which stage 2 may start (TwoStageEstimator.l_f_known)


@dataclass(frozen=True)
class EstimatorConfig:
    learner: LearnerConfig = field(default_factory=LearnerConfig)
    gate: GateConfig = field(default_factory=GateConfig)
    speed: SpeedConfig = field(default_factory=SpeedConfig)
    baseline: bool = True  # run the EKF baseline beside the UKF
    # s between aligned samples: 20 ms keeps every 10 ms frame in the interpolation
    # while halving the per-sample work (supervisor, learners) of a 100 Hz grid
    tick: float = 0.02
    trace_every: float = 0.1  # s between trace points (for plots and history)
    trace_len: int | None = None  # None keeps all (replay); live service bounds it
    # None: a row every trace_every; else once the trace holds this many rows, every other row
    # is dropped and the spacing doubles, so a long log's trace (replay --plot) stays this small
    trace_max: int | None = None
    # issue 28: the mass learnt, and put into the results where it reads off the profile's (MassConfig:
    # auto), and the road's grade and tilt (off by default)
    mass: MassConfig = field(default_factory=MassConfig)
    road: RoadConfig = field(default_factory=RoadConfig)


class GyroBias:
    """Yaw- and roll-rate gyro offsets, averaged while the car drives straight.

    On a straight, level road both true rates are ~0, so their mean is the
    offset; an unmodelled offset would otherwise be read as roll or yaw
    dynamics and bias I_x and C_alpha.  The state is entries G_YAW to G_T of a
    state list (core.passes, whose ``gyro_update`` is the step on both paths):
    ``st``, the estimator's, or a list of its own.
    """

    yaw, roll, t = ps.Entry(ps.G_YAW), ps.Entry(ps.G_ROLL), ps.Entry(ps.G_T, none=True)

    def __init__(self, tau: float = 30.0, st: list[float] | None = None):
        self.tau = tau
        self.st = ps.new_state() if st is None else st
        self.st[ps.G_YAW] = self.st[ps.G_ROLL] = self.st[ps.G_N] = 0.0
        self.st[ps.G_T] = math.nan
        self._gate: GateConfig | None = None

    @property
    def n(self) -> int:
        return int(self.st[ps.G_N])

    def update(self, s, gate: GateConfig) -> tuple[float, float]:
        """Take one sample; return the (yaw, roll) offsets to remove from it."""
        if gate is not self._gate:  # (the parameters list made once: the estimator passes its one config)
            self._gate, self._p = gate, [math.nan] * ps.N_PARAMS
            ps.gate_params(self._p, gate)
            self._p[ps.GYRO_TAU] = self.tau
        y = s.values
        ps.gyro_update(self.st, self._p, s.t, y[ch.DELTA], y[ch.YAW], y[ch.ROLL])
        return self.st[ps.G_YAW], self.st[ps.G_ROLL]


def _close(a: float | None, b: float | None) -> bool:
    return a is not None and b is not None and math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-15)


def _known(e: Estimate) -> bool:
    """Whether stage 1's l_f estimate is good enough for stage 2: converged, or uncertain with
    its std within L_F_KNOWN of its value."""
    if e.status == CONVERGED:
        return True
    ok = e.status == UNCERTAIN and e.value is not None and e.std is not None
    return ok and 0.0 < e.std <= L_F_KNOWN * abs(e.value)


class TwoStageEstimator:
    def __init__(self, vehicle, priors, cfg: EstimatorConfig | None = None):
        self.vehicle = vehicle
        self.priors = priors
        self.cfg = cfg or EstimatorConfig()
        kinds = ("ukf", "ekf") if self.cfg.baseline else ("ukf",)
        # with the road modelled, stage 2 carries its bank as a state (LearnerConfig.bank, core.lateral.BANK)
        road = self.cfg.road
        lcfg = replace(self.cfg.learner, tick=self.cfg.tick, bank=self.cfg.learner.bank or (road.on and road.bank))
        self.s1 = {k: Stage1(k, vehicle, priors, lcfg) for k in kinds}
        self.s2 = {k: Stage2(k, vehicle, priors, lcfg) for k in kinds}
        # with the free-rolling axle as the speed reference, no stage waits for a GNSS speed
        need1, need2 = Supervisor.stage1_needs, Supervisor.stage2_needs
        if self.cfg.speed.wheel_ref is not None:
            need1, need2 = (tuple(i for i in n if i != ch.SPEED) for n in (need1, need2))
        # the speed filter's, the gyro offsets' and the supervisor's state, laid out as the block pass's (core.passes)
        self.state = ps.new_state()
        self.supervisor = Supervisor(self.cfg.gate, need1, need2, wheel_radius=vehicle.wheel_radius, st=self.state)
        self.speed = speed_filter(self.cfg.speed, self.state)
        self.gyro_bias = GyroBias(st=self.state)
        self.trace: deque = deque(maxlen=self.cfg.trace_len)
        self._next_trace = None
        self._trace_every = self.cfg.trace_every
        self._stage = None  # the supervisor's stage at the last sample
        self.handover_t: float | None = None
        self.t: float | None = None
        # the parameters of the speed measurement, the gyro offsets and the supervisor (core.passes'): an
        # array for the compiled block pass, a list for the per-sample path
        self._pass_params = batched.params(self.cfg, vehicle, self.gyro_bias.tau)
        self._p = self._pass_params.tolist()
        self._needs = tuple(np.array(n, dtype=np.int64) for n in (need1, need2))  # (the supervisor's)
        m = self.cfg.mass  # issue 28 (core.mass, core.road)
        self.tilt = Tilt(vehicle, priors["h"].value, self.cfg.road) if self.cfg.road.on else None
        self.mass = MassLearner(vehicle, m, self.tilt) if m.learn else None
        # the front wheels' compliance and roll steer a profile declares (core.steer; 0: none)
        lf = vehicle.l_f if vehicle.l_f is not None else priors["l_f"].value
        self.steer_k = steer.gain(vehicle, lf, priors["h"].value)

    # -- learner interface ---------------------------------------------
    def handle(self, t: float, s: Sample) -> Sample:
        """Take one aligned sample; return it with the derived fields (speed, gyro offsets) set."""
        self.t = t
        if self.steer_k:
            s = steer.sample(s, self.steer_k)
        if self.tilt is not None:  # a_x and a_y into the road's axes; the speed filter follows the grade (core.road)
            s = self.tilt.correct(s)
            self.speed.cfg = replace(self.speed.cfg, bias_walk=self.tilt.speed_walk(self.cfg.speed.bias_walk))
        gate = self.supervisor.gates.update(t, s.gap, s.values)  # (the speed filter holds its bias in reverse)
        v_x, v_std, ax_bias = self._speed(t, s, gate)
        yaw_bias, roll_bias = self.gyro_bias.update(s, self.cfg.gate)
        s = s.derived(v_x=v_x, v_std=v_std, ax_bias=ax_bias, yaw_bias=yaw_bias, roll_bias=roll_bias)
        if self.mass is not None:
            self.mass.handle(t, s)
        stage = self.supervisor.update(t, s, self.handover_t is not None, gate)
        self._learn(t, s, stage)
        # no trace kept (trace_len=0: vdp batch, replay without --plot): no row built either
        if self.trace.maxlen != 0 and (self._next_trace is None or t >= self._next_trace):
            self._next_trace = t + self._trace_every
            self.trace.append(self._trace_row(t, stage))
            if self.cfg.trace_max is not None and len(self.trace) >= self.cfg.trace_max:
                self._thin_trace()
        return s

    def _learn(self, t: float, s: Sample, stage: int | None) -> None:
        """The learners' part of a sample (``s`` derived, ``stage`` the supervisor's)."""
        done = self.handover_t is not None
        for kind in self.s1:
            l1, l2 = self.s1[kind], self.s2[kind]
            if stage == 1:
                l1.handle(t, s)
            elif l1.filter is not None:
                l1.end_window()
            if stage == 2:
                # stage 1 does not move while stage 2 runs: its results are taken again only
                # when stage 2 (re)starts or was reset (a snapshot per sample cost ~4 % of a replay)
                if l2.filter is None and (l2.known is None or self._stage != 2):
                    e = l1.snapshot()
                    l_f, l_f_std = self.l_f(kind)
                    # C_K only from data: before stage 1 has run (a car without axle torques),
                    # stage 2 leaves the front drive force out (Stage2.set_stage1)
                    c_k = None if e["C_K"].status == NOT_RUN else e["C_K"].value
                    h = e["h"]  # (no value where stage 1's left what a car has: the prior's then)
                    h_v, h_sd = (h.value, h.std) if h.value is not None else (self.priors["h"].value, None)
                    l2.set_stage1(l_f, h_v, c_k, l_f_std, h_sd)
                l2.handle(t, s)
            elif l2.filter is not None:
                l2.end_window()
        # l_f becomes known only by a stage-1 sample (or from the profile: checked at the first
        # sample and after a reset or restore), so the stage-1 snapshot is not taken otherwise
        if not done and (stage == 1 or self._stage is None) and self.l_f_known():
            self.handover_t = t
            log.info("l_f known at t=%.2f s; stage 2 may start", t)
        self._stage = stage

    # -- a block at a time (a replay) ------------------------------------
    def batchable(self) -> bool:
        """Whether :meth:`handle_block` runs the compiled pass: no trace kept (its rows come from
        every sample), the compiled steps wanted (LearnerConfig.compiled: off, numpy's reference
        runs everything) and numba there, and the speed filter one it repeats (core.batched)."""
        return (
            self.trace.maxlen == 0
            and self.cfg.learner.compiled
            and batched.batchable(self.speed)
            and kernel("prepass") is not None
            and self.tilt is None
        )

    def ahead(self, s: Sample) -> None:
        """Show the gates a sample before its turn (core.gates.kerb: a kerb strike gates the
        samples of its rise, which come before the one that fires): vdp.pipeline's look-ahead."""
        self.supervisor.gates.ahead(s.t, s.values)

    def handle_block(
        self, T: np.ndarray, Y: np.ndarray, F: np.ndarray, A: np.ndarray, gap: bool, ahead: int = 0
    ) -> None:
        """Take aligned samples as arrays (ticks T, values Y, fresh F, ages A by channel; ``gap``:
        the first follows a gap): what :meth:`handle` on each would do, to the last bit, with
        the speed filter, gyro offsets and supervisor compiled over the block (core.batched),
        only the samples a learner takes visited in Python, and an open window's run of them
        stepped compiled (Stage1.steps, Stage2.steps).  The last ``ahead`` rows are only shown
        to the gates (:meth:`ahead`), each ``ahead`` rows before its turn.  Needs :meth:`batchable`."""
        n = len(T) - ahead
        if n <= 0:
            return
        su = self.supervisor
        gaps = np.zeros(len(T), dtype=bool)
        gaps[0] = gap
        gate = su.gates.block(T, Y, gaps, n, ahead)  # core.gates: what the model does not cover, per sample
        if ahead:
            T, Y, F, A, gaps = T[:n], Y[:n], F[:n], A[:n], gaps[:n]
        if self.steer_k:
            Y = steer.block(Y, self.steer_k)
        st0 = np.array(self.state)  # (core.passes' layout: the speed filter's, gyro offsets' and supervisor's state)
        blk0, first0 = batched.blockers(su)
        prev0 = self._stage or 0
        done_from = 0 if self.handover_t is not None else n
        kern = kernel("prepass")
        i0 = 0
        while True:
            st, blk, first = st0.copy(), blk0.copy(), first0.copy()
            out = np.empty((n, 5))
            stage = np.empty(n, dtype=np.int64)
            codes = kern(T, Y, F, A, gaps, gate, st, self._pass_params, batched.CHANNELS, self._needs[0],
                         self._needs[1], done_from, blk, first, out, stage)  # fmt: skip
            handed = self._visit(T, Y, F, A, gaps, out, stage, i0, prev0)
            if handed is None:
                break
            # l_f became known at sample ``handed``: the supervisor sees it from the next on
            done_from = i0 = handed + 1
        if self.mass is not None:  # the mass sees every sample, with the speed filter's v_x and the gyro's offset
            self.mass.handle_block(T, Y, F, A, gap, out[:, 0], out[:, 3])
        self.state[:] = st.tolist()
        batched.set_blockers(su, blk, first)
        batched.windows(su, T, stage)
        last = Y[-1].tolist()
        su._r1 = batched.reason(su, codes[0], last, su.stage1_needs)
        su._r2 = batched.reason(su, codes[1], last, su.stage2_needs)
        self.t = float(T[-1])
        self._stage = int(stage[-1]) or None

    def _visit(self, T, Y, F, A, gaps, out, stage, i0: int, prev0: int) -> int | None:
        """Run the learners on the samples from ``i0`` that one takes, or that open or close a
        window, or (l_f not yet known) that :meth:`_learn` checks the hand-over at: each by
        :meth:`_learn`, or a run of them in an open window by the learner's compiled steps up
        to the first that needs :meth:`_learn`.  Returns the sample where l_f became known, or
        None."""
        done = self.handover_t is not None
        prev = np.empty_like(stage)
        prev[0] = prev0
        prev[1:] = stage[:-1]
        want = (stage != 0) | (stage != prev)
        if not done:
            want |= prev == 0
        want[:i0] = False
        idx = np.flatnonzero(want)
        if not len(idx):
            return None
        idx = idx.tolist()
        stg, pv = stage.tolist(), prev.tolist()
        # a window is stepped compiled once its filter is open (Stage1.steps, Stage2.steps), one UKF at a
        # time; stage 1's once l_f is known (before, each of its samples may hand over)
        one = len(self.s1) == 1
        runs = {1: self.s1["ukf"] if one and done else None, 2: self.s2["ukf"] if one else None}
        ends = {sg: np.flatnonzero(stage != sg) for sg, l in runs.items() if l is not None}
        learn = self._learn
        k = 0
        while k < len(idx):
            i = idx[k]
            t = float(T[i])
            v_x, v_std, ax_b, yaw_b, roll_b = out[i].tolist()
            s = Sample(t, tuple(Y[i].tolist()), tuple(F[i].tolist()), tuple(A[i].tolist()), bool(gaps[i]),
                       v_x, v_std, ax_b, yaw_b, roll_b)  # fmt: skip
            self._stage = pv[i] or None
            learn(t, s, stg[i] or None)
            if not done and self.handover_t is not None:
                return i
            k += 1
            run = runs.get(stg[i])
            if run is not None and run.runnable():
                other = ends[stg[i]]
                q = np.searchsorted(other, i)
                end = int(other[q]) if q < len(other) else len(stage)
                if end > i + 1:
                    # the run's samples up to the first that needs the learner's own step
                    k += run.steps(T, Y, out, gaps, i + 1, end) - (i + 1)
        return None

    def _thin_trace(self) -> None:
        """Keep every other trace row, from the first, and double the spacing of the rows to come."""
        self.trace = deque(list(self.trace)[::2], maxlen=self.trace.maxlen)
        self._trace_every *= 2.0

    def _speed(self, t: float, s, gate: int = 0) -> tuple[float, float, float]:
        """Run the GNSS + IMU speed filter (``gate``: the sample's, core.gates); return v_x, its std
        and the a_x bias."""
        y = s.values
        gnss, has, noise = ps.speed_measured(self._p, ps.CHANNELS, y, s.fresh, s.age)
        if s.gap:
            self.speed.reset()
        # (> 0: the car turns or reverses, the speed filter holds its a_x bias)
        turn = max(ps.turning(self._p, y[ch.YAW]), ps.reversing(y[ch.AX], gate))
        self.speed.step(t, y[ch.AX], gnss if has else None, None if math.isnan(noise) else noise, turn)
        std = self.speed.std
        # stage 1 takes the speed's error as correlated over speed_corr^2 x 10 ms (4 s); one
        # that stays longer (a coarse 1 Hz GNSS: about 10 s) counts for less: its std widens by
        # sqrt(2 tau / that), 2 tau being how far apart two of its errors are independent
        assumed = self.cfg.learner.speed_corr**2 * 0.01
        if 2.0 * self.speed.corr_time > assumed:
            std *= math.sqrt(2.0 * self.speed.corr_time / assumed)
        return self.state[ps.V], std, self.state[ps.BIAS]  # (the filter's v and bias, read without its attributes)

    def reset(self, stage: int | None = None) -> None:
        """Clear one stage (1 or 2), the mass (core.mass.STAGE: a mass step named between drives), or all (None)."""
        if stage in (None, 1):
            for l in self.s1.values():
                l.reset()
            self.handover_t = None
        if stage in (None, 2, 1):
            for l in self.s2.values():
                l.reset()
        self._stage = None
        if stage in (None, MASS_STAGE) and self.mass is not None:
            self.mass.reset()
        if stage is None:
            if self.tilt is not None:
                self.tilt.reset()
            self.supervisor.reset()
            self.trace.clear()
            self._trace_every = self.cfg.trace_every

    def finish(self) -> None:
        """The data have ended (a log's last frame): the next snapshot is the whole log's, its batch
        checks solved on every row (stage 2) and block (stage 1) kept.  Without this a replay
        polled for results on the way (``vdp replay --series``) would end on a check up to a
        quarter of its rows old, and stage 1's on one up to a quarter of its blocks old."""
        for learner in self.s2.values():
            learner.check.complete = True
        for learner in self.s1.values():  # stage 1's check on every block, as the last ones came sparser
            if learner.check_due(final=True):
                learner.check_batch(full=True)

    def settle(self) -> None:
        """Every background batch check ended and none stale (LearnerConfig.check_executor): the
        next snapshot does not depend on when it is taken."""
        for learner in self.s2.values():
            learner.settle()

    def checks_solved(self) -> int:
        """Batch-check fits finished so far (a background one landing changes the snapshot)."""
        return sum(learner.check.poll() for learner in self.s2.values())

    def snapshot(self) -> Snapshot:
        return Snapshot(
            parameters=self.parameters("ukf"),
            baseline_ekf=self.parameters("ekf") if "ekf" in self.s1 else None,
            stage=self.stage(),
            supervisor={**self.supervisor.state(), "learners": self.learners()},
            windows=tuple(WindowSpan(w.stage, w.start, w.end, w.samples) for w in self.supervisor.windows),
            resets={k: self.s1[k].resets + self.s2[k].resets for k in self.s1},
        )

    def learners(self) -> dict:
        """What each learner has seen, plainly (for progress and coaching, and for a reader who
        wants to know why a parameter is not valid): per filter kind and stage."""
        tick = self.cfg.tick
        out = {}
        for kind in self.s1:
            l1, l2 = self.s1[kind], self.s2[kind]
            f = l1.fit
            out[kind] = {
                "stage1": {
                    "seconds_in_windows": round(l1.samples * tick, 2),
                    "blocks_used": len(l1._blocks),
                    "blocks_beyond_small_slip": l1.gated,
                    "reseeds_from_batch_optimum": l1.reseeds,
                    "batch_chi2_per_dof": None if f is None else round(f.chi2, 3),
                    "batch_whiteness_lag1": None if f is None else round(f.rho, 3),
                    "model_mismatch": l1.mismatch()[1],
                    "tyre": l1.tyre(),
                },
                "stage2": {
                    "seconds_in_windows": round(l2.samples * tick, 2),
                    "windows_restarted": l2.restarts,
                    "window": l2.window.as_dict(),
                    "all_windows": l2.total.as_dict(),
                    "roll_rate_row": l2.roll_total.as_dict(),
                    "model_mismatch": l2.mismatch()[1],
                    "output_error_fit": l2.check.as_dict(),  # the batch check (core.output_error)
                },
            }
        return out

    # -- helpers -------------------------------------------------------
    def l_f_known(self) -> bool:
        """Stage 2 needs l_f only (docs/decisions/0007: h and C_K hardly move it): measured
        in the profile, or stage 1's UKF estimate converged or known to L_F_KNOWN, whether or not
        h and C_K are.  Stage 2 carries l_f's std (lateral.CONSIDER), so a car whose stage 1 is
        widened by a model mismatch (l_f 0.8-1.8 % on the independent models, never converged with
        the priors x1.6) still runs stage 2, with C_alpha's and I_z's stds the wider for it."""
        return getattr(self.vehicle, "l_f", None) is not None or _known(self.s1["ukf"].snapshot()["l_f"])

    def l_f(self, kind: str) -> tuple[float, float | None]:
        """(l_f, std) for stage 2: the profile's measured value (1 % if no std given), else stage 1's;
        the UKF's where this kind's own is not known to L_F_KNOWN (l_f_known judges the UKF's)."""
        v = self.vehicle
        if getattr(v, "l_f", None) is not None:
            return v.l_f, v.l_f_std if v.l_f_std is not None else 0.01 * v.l_f
        e = self.s1[kind].snapshot()["l_f"]
        if kind != "ukf" and not _known(e):
            e = self.s1["ukf"].snapshot()["l_f"]
        return e.value, e.std

    def parameters(self, kind: str = "ukf") -> dict[str, Estimate]:
        out = {}
        for learner in (self.s1[kind], self.s2[kind]):
            out.update(learner.snapshot())
        e, v = out.get("l_f"), self.vehicle
        if e is not None and e.status == NOT_RUN and getattr(v, "l_f", None) is not None:
            # the l_f stage 2 uses is the profile's, not this (stage 1's prior): say so
            l_f, sd = self.l_f(kind)
            why = (
                f"not estimated (stage 1 has not run); stage 2 uses the profile's "
                f"l_f = {l_f:.3g} ± {sd:.2g} m ([vehicle] l_f)"
            )
            out["l_f"] = replace(e, reason=why)
        if self.cfg.mass.put:  # the learnt mass into the six, its std carried (core.mass.scaled)
            out = scaled(out, self.mass.snapshot(), self.vehicle.mass, self.cfg.mass.auto)
        if kind == "ukf":  # the mass after the six: learnt (core.mass), or said to be off (never left out)
            # (one learner, not a filter kind's: the EKF baseline's six are scaled by it, not given it again)
            out[MASS] = self.mass.snapshot() if self.mass is not None else mass_off(self.vehicle.mass)
        return out

    def stage(self) -> str:
        if self.handover_t is None:
            return "stage1"
        # done when every stage-2 parameter is either converged or known not to be identifiable
        # (I_x not_run for want of a roll-rate gyro is as settled as it will get)
        settled = all(
            e.status in SETTLED or (e.status == NOT_RUN and e.reason) for e in self.s2["ukf"].snapshot().values()
        )
        return "done" if settled else "stage2"

    def restore(self, params: Mapping[str, Estimate]) -> None:
        """Start from stored estimates (value, std, samples) instead of the priors.  ``params`` are
        as :meth:`parameters` publishes them: with the learnt mass put in (cfg.mass.put), they are
        taken out of it first (core.mass.unscaled, with the mass as the learner has it now: resumed
        first at a restart, :meth:`resume`), as the filters run with the profile's mass."""
        if self.cfg.mass.put and self.mass is not None:
            params = unscaled(dict(params), self.mass.snapshot(), self.vehicle.mass, self.cfg.mass.auto)
        for kind in self.s1:
            for learner in (self.s1[kind], self.s2[kind]):
                snap = learner.snapshot()
                vals, stds, n = [], [], 0
                for name in learner.names:
                    p = params.get(name)
                    v, sd = (p.value, p.std) if p is not None else (None, None)
                    ok = v is not None and sd is not None and math.isfinite(v) and math.isfinite(sd) and sd > 0
                    vals.append(v if ok else snap[name].value)
                    stds.append(sd if ok else snap[name].std)
                    if ok:
                        n = max(n, p.samples or 1)
                if n:
                    learner.set_params(vals, np.diag(np.square(stds)), n)
        self._stage = None  # stage 2 takes stage 1's restored results at its next sample
        if self.l_f_known():
            self.handover_t = self.t if self.t is not None else 0.0

    def learnt(self) -> dict:
        """Each learner's own state in the published parameters: value, the filter's covariance
        (without the honest std's floor and mismatch terms) and samples, for a restart to carry on
        exactly where it was (:meth:`resume`).  Keyed "kind/stage"; learners that saw no data left out.
        The mass learner's own state under "mass" (core.mass.MassLearner.state) wherever it runs:
        its presence says the six were published with it."""
        out = {}
        if self.mass is not None:
            out[MASS] = self.mass.state()
        for kind in self.s1:
            for learner in (self.s1[kind], self.s2[kind]):
                if learner.samples:
                    theta, cov = learner.params()
                    pub, pcov = learner._publish(theta, cov)
                    out[f"{kind}/{learner.stage}"] = {
                        "names": list(learner.names),
                        "value": [float(v) for v in pub],
                        "cov": np.asarray(pcov, dtype=float).tolist(),
                        "samples": int(learner.samples),
                    }
        return out

    def resume(self, learnt: Mapping, params: Mapping[str, Estimate]) -> list[str]:
        """After :meth:`restore`: take each learner's own state (:meth:`learnt`) where it gives back
        the very estimates stored (``params``): the filter's covariance with its correlations, so a
        restart neither tightens the std (the diagonal alone would) nor widens it (the honest std
        put back into the filter would, at every restart).  Where it does not (a stored value that
        was the batch check's, a std widened by a mismatch the restarted learner has not seen yet),
        the learner keeps :meth:`restore`'s.  Returns the learners resumed.

        The mass first (``learnt["mass"]``, where it gives back the stored ``params["mass"]``;
        otherwise it starts from the prior): the six were published with it, so :meth:`restore`
        is done again with it before the learners' own states are compared."""
        done = []
        if self.mass is not None and learnt.get(MASS) and self._resume_mass(learnt[MASS], params.get(MASS)):
            done.append(MASS)
            if self.cfg.mass.put:  # restore()'s values, taken out of the mass they were published with
                self.restore({k: v for k, v in params.items() if k != MASS})
        for kind in self.s1:
            for learner in (self.s1[kind], self.s2[kind]):
                st = learnt.get(f"{kind}/{learner.stage}")
                if not st or st.get("names") != list(learner.names):
                    continue
                cov = np.asarray(st["cov"], dtype=float)
                if cov.shape != (len(learner.names),) * 2 or not np.all(np.isfinite(cov)):
                    continue
                keep = (*learner._publish(*learner.params()), learner.samples)  # restore()'s, to go back to
                learner.set_params(st["value"], cov, 0)  # 0: the covariance holds no floor to take out
                learner.samples = max(keep[2], int(st["samples"]))
                snap = learner.snapshot()
                if self.cfg.mass.put:  # compared as published: with the mass put in
                    snap = scaled(snap, self.mass.snapshot(), self.vehicle.mass, self.cfg.mass.auto)
                same = all(
                    params.get(n) is not None
                    and _close(snap[n].value, params[n].value)
                    and _close(snap[n].std, params[n].std)
                    for n in learner.names
                    if params.get(n) is not None and params[n].value is not None
                )
                if same:
                    done.append(f"{kind}/{learner.stage}")
                else:
                    learner.set_params(keep[0], keep[1], 0)
                    learner.samples = keep[2]
        self._stage = None
        if self.l_f_known():
            self.handover_t = self.t if self.t is not None else 0.0
        return done

    def _resume_mass(self, st: Mapping, stored: Estimate | None) -> bool:
        """The mass learner from its own state, kept where it gives back the stored mass estimate."""
        if stored is None or not self.mass.load(st):
            return False
        e = self.mass.snapshot()
        if _close(e.value, stored.value) and _close(e.std, stored.std):
            return True
        log.warning("the stored mass learner does not give back the stored mass (%s kg); it starts from the prior",
                    stored.value)  # fmt: skip
        self.mass.reset()
        return False

    def _trace_row(self, t: float, stage) -> tuple:
        """(t, stage, per kind: ((value, std) per parameter)) straight from the filters."""
        row = [t, stage]
        for kind in self.s1:
            row.append(self.s1[kind].values() + self.s2[kind].values())
        return tuple(row)
