"""The gating supervisor: which stage, if any, the current driving excites.

Table 2 of the paper, plus what a real drive needs:

- stage 1 (straight-line acceleration/braking): |delta| < 0.62 deg, |yaw rate| < 1 deg/s,
  speed above ``v_min`` (slip is singular near standstill, NOTES 11), and enough
  a_x excitation (RMS over a few seconds);
- stage 2 (steady speed, continuous steering): stage 1 converged (the hand-over),
  speed above ``v_min``, nearly constant speed (small mean a_x), and enough
  steering or yaw excitation;
- both need their channels fresh.

Hysteresis: a window opens after its conditions have held for ``t_on`` and
closes after they have failed for ``t_off``, so windows don't flicker.
Excitation is tracked with exponential moving statistics, which cost O(1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import channels as ch


@dataclass(frozen=True)
class GateConfig:
    v_min: float = 5.0  # m/s
    delta_max_1: float = math.radians(0.62)  # Table 2
    yaw_max_1: float = math.radians(1.0)  # Table 2
    ax_rms_min: float = 0.4  # m/s^2 over tau_ax
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
class _Gate:
    open: bool = False
    since: float | None = None  # when the raw condition last changed


@dataclass
class Supervisor:
    cfg: GateConfig = field(default_factory=GateConfig)
    stage1_needs: tuple[int, ...] = tuple(ch.INDEX[n] for n in ch.STAGE1_NEEDS)
    stage2_needs: tuple[int, ...] = tuple(ch.INDEX[n] for n in ch.STAGE2_NEEDS)
    wheel_radius: float = 0.3

    def __post_init__(self):
        self.reset()

    def reset(self) -> None:
        self._t: float | None = None
        self._ax_m = self._ax_sq = 0.0
        self._d_m = self._d_sq = self._yaw_sq = 0.0
        self._gates = {1: _Gate(), 2: _Gate()}
        self.windows: list[Window] = []
        self.active: int | None = None
        self.reason: dict[int, str] = {1: "no data yet", 2: "no data yet"}

    def _ema(self, dt: float, tau: float) -> float:
        return 1.0 - math.exp(-dt / tau)

    def update(self, t: float, s, stage1_done: bool) -> int | None:
        """Feed one sample; return the stage whose window is open (1, 2 or None)."""
        y = s.values
        dt = 0.01 if self._t is None or s.gap else min(max(t - self._t, 0.0), 0.1)
        self._t = t
        ax, d, yaw = y[ch.AX], y[ch.DELTA], y[ch.YAW]
        if math.isfinite(ax):
            k = self._ema(dt, self.cfg.tau_ax)
            self._ax_m += k * (ax - self._ax_m)
            self._ax_sq += k * (ax * ax - self._ax_sq)
        if math.isfinite(d) and math.isfinite(yaw):
            k = self._ema(dt, self.cfg.tau_steer)
            self._d_m += k * (d - self._d_m)
            self._d_sq += k * (d * d - self._d_sq)
            self._yaw_sq += k * (yaw * yaw - self._yaw_sq)
        c = self.cfg
        speed = s.v_x if math.isfinite(s.v_x) else y[ch.SPEED]
        if not math.isfinite(speed):
            speed = 0.5 * (y[ch.WS_RL] + y[ch.WS_RR]) * self.wheel_radius

        r1 = self._why1(y, speed, c)
        r2 = self._why2(y, speed, c, stage1_done)
        self.reason = {1: r1 or "open", 2: r2 or "open"}
        hard1 = r1 is not None and not r1.startswith("little")
        hard2 = r2 is not None and not r2.startswith("little")
        o1 = self._hyst(1, t, r1 is None, hard1)
        o2 = self._hyst(2, t, r2 is None, hard2)
        stage = 2 if o2 else 1 if o1 else None  # the conditions exclude each other; 2 wins a tie
        if stage != self.active:
            if self.active is not None:
                self.windows[-1].end = t
            if stage is not None:
                self.windows.append(Window(stage, t))
            self.active = stage
        if stage is not None:
            self.windows[-1].samples += 1
        return stage

    def _missing(self, y, needs) -> str | None:
        bad = [ch.NAMES[i] for i in needs if not math.isfinite(y[i])]
        return f"channels missing or stale: {', '.join(bad)}" if bad else None

    def _why1(self, y, speed, c) -> str | None:
        miss = self._missing(y, self.stage1_needs)
        if miss:
            return miss
        if not speed > c.v_min:
            return f"speed below {c.v_min} m/s"
        if abs(y[ch.DELTA]) >= c.delta_max_1:
            return "steering (|delta| >= 0.62 deg)"
        if abs(y[ch.YAW]) >= c.yaw_max_1:
            return "yawing (|yaw rate| >= 1 deg/s)"
        if math.sqrt(max(self._ax_sq, 0.0)) < c.ax_rms_min:
            return "little longitudinal excitation (a_x RMS too small)"
        return None

    def _why2(self, y, speed, c, stage1_done) -> str | None:
        if not stage1_done:
            return "waiting for stage 1 to converge"
        miss = self._missing(y, self.stage2_needs)
        if miss:
            return miss
        if not speed > c.v_min:
            return f"speed below {c.v_min} m/s"
        if abs(self._ax_m) > c.ax_mean_max_2:
            return "speed not constant (|mean a_x| too large)"
        d_std = math.sqrt(max(self._d_sq - self._d_m ** 2, 0.0))
        if d_std < c.delta_std_min_2 and math.sqrt(max(self._yaw_sq, 0.0)) < c.yaw_rms_min_2:
            return "little steering excitation"
        return None

    def _hyst(self, stage: int, t: float, ok: bool, hard: bool) -> bool:
        g = self._gates[stage]
        if ok == g.open:
            g.since = None
            return g.open
        if not ok and hard:
            g.open, g.since = False, None
            return False
        if g.since is None:
            g.since = t
        if t - g.since >= (self.cfg.t_on if ok else self.cfg.t_off):
            g.open, g.since = ok, None
        return g.open

    def state(self) -> dict:
        return {"active_stage": self.active, "reasons": {str(k): v for k, v in self.reason.items()},
                "windows": len(self.windows)}
