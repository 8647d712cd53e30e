"""The gating supervisor: which stage, if any, the current driving excites.

Table 2 of the paper, plus what a real drive needs:

- stage 1 (straight-line acceleration/braking): |delta| < 0.62 deg, |yaw rate| < 1 deg/s,
  speed above ``v_min`` (slip is singular near standstill, NOTES 11), and enough
  a_x excitation (its spread over a few seconds);
- stage 2 (steady speed, continuous steering): stage 1 converged (the hand-over),
  speed above ``v_min``, nearly constant speed (small mean a_x), and enough
  steering or yaw excitation;
- both need their channels fresh;
- neither runs while a gate for what the model does not cover holds (core.gates: reverse,
  ABS, ESC, TCS, a kerb strike, wheel spin), and the share of the drive each gate took is
  counted (``state()["gated"]``).

Hysteresis: a window opens after its conditions have held for ``t_on`` and
closes after they have failed for ``t_off``, so windows don't flicker.
Excitation is tracked with exponential moving statistics, which cost O(1).
"""

from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass, field

from .. import channels as ch
from . import gates as gt
from . import passes as ps

MAX_WINDOWS = 500  # windows kept for reports and the API


class Code(enum.IntEnum):
    """What keeps a stage's window shut (0: nothing); the compiled block pass (core.prepass)
    returns these codes, so both paths word a reason alike."""

    SPEED_LOW = 1
    STEERING = 2
    YAWING = 3
    LITTLE_AX = 4
    LITTLE_STEER = 5
    NOT_CONSTANT = 6
    MISSING = 7  # a channel the stage needs is missing or stale (Reason.channels)
    WAITING = 8
    # core.gates' codes that shut the windows, GATED + k for gate k (reverse ... wheel spin)
    GATED_REVERSE = 9
    GATED_ABS = 10
    GATED_ESC = 11
    GATED_TCS = 12
    GATED_KERB = 13
    GATED_SPIN = 14
    NO_DATA = 15  # before the first sample


SPEED_LOW, STEERING, YAWING, LITTLE_AX, LITTLE_STEER, NOT_CONSTANT, MISSING, WAITING = tuple(Code)[:8]


class Reason(str):
    """Why a stage's window is shut: the text a user reads (JSON, /estimates, the dashboard) that
    is also typed, with its :class:`Code` and, for MISSING, the channels, so that no one parses
    the text back (core.progress, core.batched)."""

    code: Code
    channels: tuple[str, ...]

    def __new__(cls, code: Code, text: str, channels: tuple[str, ...] = ()):
        self = super().__new__(cls, text)
        self.code, self.channels = code, channels
        return self

    def __reduce__(self):  # (pickled with the estimator: a process pool, a Dask worker)
        return Reason, (self.code, str(self), self.channels)

    @property
    def hard(self) -> bool:
        """Whether it shuts an open window at once (not a little excitation, which the hysteresis waits out)."""
        return ps.is_hard(self.code)


REASONS = {
    SPEED_LOW: "speed below {v_min} m/s",
    STEERING: "steering (|delta| >= 0.62 deg)",
    YAWING: "yawing (|yaw rate| >= 1 deg/s)",
    LITTLE_AX: "little longitudinal excitation (a_x varies too little)",
    LITTLE_STEER: "little steering excitation",
    NOT_CONSTANT: "speed not constant (|mean a_x| too large)",
    WAITING: "waiting for stage 1's l_f",
}
# what the model does not cover (core.gates): reverse, ABS, ESC, TCS, a kerb strike, wheel spin
GATED = WAITING  # the reason code of gate k is GATED + k
REASONS.update({Code(GATED + k): f"gated out: {gt.NAMES[k]}" for k in range(1, gt.SHUTS + 1)})


@dataclass(frozen=True)
class GateConfig:
    v_min: float = 5.0  # m/s
    delta_max_1: float = math.radians(0.62)  # Table 2
    yaw_max_1: float = math.radians(1.0)  # Table 2
    ax_std_min: float = 0.4  # m/s^2, spread of a_x over tau_ax
    ax_mean_max_2: float = 0.6  # m/s^2: "speed remains constant"
    delta_std_min_2: float = math.radians(0.8)
    yaw_rms_min_2: float = math.radians(3.0)
    tau_ax: float = 2.0  # s
    tau_steer: float = 3.0  # s
    t_on: float = 0.3  # s
    t_off: float = 0.5  # s


@dataclass
class Window:
    stage: int
    start: float
    end: float | None = None
    samples: int = 0

    def as_dict(self) -> dict:
        return {"stage": self.stage, "start": self.start, "end": self.end, "samples": self.samples}


@dataclass
class Supervisor:
    cfg: GateConfig = field(default_factory=GateConfig)
    stage1_needs: tuple[int, ...] = tuple(ch.INDEX[n] for n in ch.STAGE1_NEEDS)
    stage2_needs: tuple[int, ...] = tuple(ch.INDEX[n] for n in ch.STAGE2_NEEDS)
    wheel_radius: float = 0.3
    gates_cfg: gt.GatesConfig = field(default_factory=gt.GatesConfig)
    # the excitation and the windows in entries U_T to K_STEER of a state list (core.passes, whose
    # ``supervise`` and ``hyst`` are the steps on both paths): the estimator's, or one of its own
    st: list[float] = field(default_factory=ps.new_state, repr=False, compare=False)

    # how long the driving itself (channels and hand-over aside) met each stage's conditions
    # (excited), and the moving statistics of a_x, delta and the yaw rate
    _t, observed = ps.Entry(ps.U_T, none=True), ps.Entry(ps.OBSERVED)
    _ax_m, _ax_sq, _d_m, _d_sq, _yaw_sq = (ps.Entry(i) for i in (ps.AX_M, ps.AX_SQ, ps.D_M, ps.D_SQ, ps.YAW_SQ))

    def __post_init__(self):
        self._p = [math.nan] * ps.N_PARAMS
        ps.gate_params(self._p, self.cfg)
        self._p[ps.RADIUS] = self.wheel_radius
        # each code's reason, in this supervisor's limits, made once (the per-sample path hands them out)
        self._reasons = {code: Reason(code, text.format(v_min=self.cfg.v_min)) for code, text in REASONS.items()}
        self.gates = gt.Gates(self.gates_cfg, self.wheel_radius)
        self.reset()

    def reset(self) -> None:
        st = self.st
        st[ps.U_T : ps.K_STEER + 1] = [0.0] * (ps.K_STEER + 1 - ps.U_T)
        st[ps.U_T] = st[ps.SINCE1] = st[ps.SINCE2] = st[ps.K_DT] = math.nan  # (no sample yet, no gain for a step yet)
        # what most often stopped each stage: "no steering excitation" and the like
        self.blockers: dict[int, dict[str, float]] = {1: {}, 2: {}}
        self.windows: deque[Window] = deque(maxlen=MAX_WINDOWS)  # the newest; memory stays flat
        self.window_count = 0
        self.active: int | None = None
        self._r1 = self._r2 = Reason(Code.NO_DATA, "no data yet")
        self.gates.reset()

    @property
    def excited(self) -> dict[int, float]:
        """Seconds the driving met each stage's conditions."""
        return {1: self.st[ps.EXC1], 2: self.st[ps.EXC2]}

    def update(self, t: float, s, stage1_done: bool, gate: int | None = None) -> int | None:
        """Feed one sample; return the stage whose window is open (1, 2 or None).  ``gate``: its
        gate code where the caller took it from the gates already (the estimator, before the speed)."""
        y = s.values
        g = self.gates.update(t, s.gap, y) if gate is None else gate
        dt, c1, c2 = ps.supervise(self.st, self._p, t, s.gap, g, y[ch.AX], y[ch.DELTA], y[ch.YAW], s.v_x, y[ch.SPEED],
                                  y[ch.WS_RL], y[ch.WS_RR])  # fmt: skip
        d1 = self._reasons[c1] if c1 else None
        d2 = self._reasons[c2] if c2 else None
        for stage, d in ((1, d1), (2, d2)):
            if d is not None:
                b = self.blockers[stage]
                b[d] = b.get(d, 0.0) + dt
        r1 = self._missing(y, self.stage1_needs) or d1
        r2 = self._reasons[WAITING] if not stage1_done else self._missing(y, self.stage2_needs) or d2
        self._r1, self._r2 = r1, r2
        hard1 = r1 is not None and r1.hard
        hard2 = r2 is not None and r2.hard
        o1 = ps.hyst(self.st, ps.OPEN1, ps.SINCE1, t, r1 is None, hard1, self._p)
        o2 = ps.hyst(self.st, ps.OPEN2, ps.SINCE2, t, r2 is None, hard2, self._p)
        stage = 2 if o2 else 1 if o1 else None  # the conditions exclude each other; 2 wins a tie
        if stage != self.active:
            if self.active is not None:
                self.windows[-1].end = t
            if stage is not None:
                self.windows.append(Window(stage, t))
                self.window_count += 1
            self.active = stage
        if stage is not None:
            self.windows[-1].samples += 1
        return stage

    @property
    def reason(self) -> dict[int, Reason | str]:
        """Why each stage's window is not open at the last sample ("open" where it is)."""
        return {1: self._r1 or "open", 2: self._r2 or "open"}

    def why(self, code: int) -> Reason:
        """The reason of a code (REASONS), in this supervisor's limits."""
        return self._reasons[code]

    def _missing(self, y, needs) -> Reason | None:
        for i in needs:  # (the usual case, every channel there, without building a list)
            if not math.isfinite(y[i]):
                bad = tuple(ch.NAMES[i] for i in needs if not math.isfinite(y[i]))
                return Reason(MISSING, f"channels missing or stale: {', '.join(bad)}", bad)
        return None

    def excitation(self) -> dict:
        """Per stage: seconds the driving met its conditions, of how many, and the main blocker."""
        out = {}
        for stage in (1, 2):
            b = self.blockers[stage]
            out[str(stage)] = {
                "seconds": round(self.excited[stage], 2),
                "of": round(self.observed, 2),
                "main_blocker": max(b, key=b.get) if b else None,
            }
        return out

    def state(self) -> dict:
        return {
            "active_stage": self.active,
            "reasons": {str(k): v for k, v in self.reason.items()},
            "windows": self.window_count,
            "excitation": self.excitation(),
            "gated": self.gates.summary(),
        }
