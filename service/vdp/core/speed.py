"""Longitudinal speed from GNSS and the IMU: a two-state Kalman filter.

State ``[v_x, b_ax]``: speed over ground and the accelerometer's bias.
``v_x`` integrates the measured a_x minus the bias (eq 1 with the IMU's a_x);
each GNSS speed corrects it.  The driven wheels are left out on purpose: stage
1 compares them with this speed, and an estimate built from them would carry
the torque noise back into the slip (see :mod:`vdp.core.longitudinal`).

Without GNSS, a car with one driven axle has a reference all the same: the
free-rolling axle carries no torque while it is not braked, so its wheels turn
at the ground speed (no slip, eq 14 with F_x = 0) up to the tyre's rolling radius.
:func:`wheel_reference` gives that speed when it applies; the filter takes it as
the measurement (``wheel_noise``), and while the free axle is braked the IMU
carries the speed alone, with the bias learnt before.

A GNSS speed in coarse steps (whole mph in Ford's GPS messages: 0.447 m/s) has a
rounding error of up to half a step that stays put while the speed changes slowly, so its
noise is inflated by half a step (:func:`gnss_noise`).  That is not all it takes: the
error is correlated in time, which a white measurement noise cannot say, and stage 1's
stds stay somewhat narrow on such a GNSS (BENCHMARKS.md, "Production bus layouts").
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
    # no GNSS: the free-rolling axle ("front" or "rear") as the reference while unbraked
    wheel_ref: str | None = None
    wheel_noise: float = 0.05  # m/s: rolling radius error and noise of the axle's mean wheel speed
    brake_torque_max: float = 20.0  # N m: a free axle torque below minus this is braking


def gnss_noise(base: float, step: float) -> float:
    """GNSS speed noise [m/s] for a signal quantised in ``step`` m/s.

    The rounding error is uniform (std step/sqrt 12) but not white: while the speed changes
    by less than a step the error stays the same, so averaging many samples does not shrink
    it as the filter assumes.  Half a step, its largest value, is taken as its std instead.
    """
    return math.sqrt(base * base + 0.25 * step * step)


def wheel_reference(
    cfg: SpeedConfig, ws_left: float, ws_right: float, axle_torque: float, wheel_radius: float
) -> float | None:
    """Ground speed from the free-rolling axle's wheel speeds [rad/s], or None while it is braked
    (or a value is missing)."""
    if cfg.wheel_ref is None:
        return None
    if not (math.isfinite(ws_left) and math.isfinite(ws_right)):
        return None
    if math.isfinite(axle_torque) and axle_torque < -cfg.brake_torque_max:
        return None  # braked: the wheels slip, they are no reference now
    return 0.5 * (ws_left + ws_right) * wheel_radius


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

    def step(self, t: float, a_x: float, gnss: float | None, noise: float | None = None) -> None:
        """Advance to ``t`` with the measured a_x; correct with a speed measured at ``t``
        (GNSS, or the free-rolling axle), of std ``noise`` (default: ``gnss_noise``)."""
        c = self.cfg
        r = c.gnss_noise if noise is None else noise
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
            self.v, self.p_vv, self.p_vb = gnss, r**2, 0.0
            self.t = t
            return
        s = self.p_vv + r**2
        k_v, k_b = self.p_vv / s, self.p_vb / s
        e = gnss - self.v
        self.v += k_v * e
        self.bias += k_b * e
        p_vv, p_vb, p_bb = self.p_vv, self.p_vb, self.p_bb
        self.p_vv = p_vv - k_v * p_vv
        self.p_vb = p_vb - k_v * p_vb
        self.p_bb = p_bb - k_b * p_vb
