"""Longitudinal speed from GNSS and the IMU: a two-state Kalman filter.

State ``[v_x, b_ax]``: speed over ground and the accelerometer's bias.
``v_x`` integrates the measured a_x minus the bias (eq 1 with the IMU's a_x);
each GNSS speed corrects it.  The wheel speeds are left out on purpose: stage
1 compares them with this speed, and an estimate built from them would carry
the torque noise back into the slip (see :mod:`vdp.core.longitudinal`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class SpeedConfig:
    accel_noise: float = 0.08  # m/s^2, IMU noise plus what the model misses
    bias_walk: float = 0.002  # m/s^2 per sqrt(s)
    gnss_noise: float = 0.05  # m/s
    max_gap: float = 0.2  # s without a_x: restart from the next GNSS speed


class SpeedFilter:
    def __init__(self, cfg: SpeedConfig | None = None):
        self.cfg = cfg or SpeedConfig()
        self.bias = 0.0
        self.p_bb = 0.05**2
        self.reset()

    def reset(self) -> None:
        """Forget the speed (not the bias, which outlives gaps)."""
        self.v = math.nan
        self.p_vv = self.p_vb = 0.0
        self.t: float | None = None
        self.a_prev = math.nan

    @property
    def ready(self) -> bool:
        return math.isfinite(self.v)

    @property
    def std(self) -> float:
        return math.sqrt(self.p_vv) if self.ready else math.nan

    def step(self, t: float, a_x: float, gnss: float | None) -> None:
        """Advance to ``t`` with the measured a_x; correct with a GNSS speed valid at ``t``."""
        c = self.cfg
        dt = None if self.t is None else t - self.t
        if not math.isfinite(a_x) or dt is None or dt <= 0 or dt > c.max_gap:
            self.reset()
            self.t = t if math.isfinite(a_x) else None
        elif self.ready:
            # trapezoidal: exact for a_x linear in time, so a smooth a_x leaves no drift to mistake for bias
            a_mean = 0.5 * (a_x + self.a_prev) if math.isfinite(self.a_prev) else a_x
            self.v += dt * (a_mean - self.bias)
            # P = F P F^T + Q with F = [[1, -dt], [0, 1]]
            p_vv = self.p_vv - 2 * dt * self.p_vb + dt * dt * self.p_bb + (c.accel_noise * dt) ** 2
            p_vb = self.p_vb - dt * self.p_bb
            self.p_vv, self.p_vb = p_vv, p_vb
            self.p_bb += c.bias_walk**2 * dt
            self.t = t
        self.a_prev = a_x
        if gnss is None or not math.isfinite(gnss):
            return
        if not self.ready:
            self.v, self.p_vv, self.p_vb = gnss, c.gnss_noise**2, 0.0
            self.t = t
            return
        s = self.p_vv + c.gnss_noise**2
        k_v, k_b = self.p_vv / s, self.p_vb / s
        e = gnss - self.v
        self.v += k_v * e
        self.bias += k_b * e
        p_vv, p_vb, p_bb = self.p_vv, self.p_vb, self.p_bb
        self.p_vv = p_vv - k_v * p_vv
        self.p_vb = p_vb - k_v * p_vb
        self.p_bb = p_bb - k_b * p_vb
