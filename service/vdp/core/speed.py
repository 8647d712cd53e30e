"""Longitudinal speed from GNSS and the IMU: a two-state Kalman filter.

State ``[v_x, b_ax]``: speed over ground and the accelerometer's bias.
``v_x`` integrates the measured a_x minus the bias (eq 1 with the IMU's a_x);
each GNSS speed corrects it.  The driven wheels are left out on purpose: stage
1 compares them with this speed, and an estimate built from them would carry
the torque noise back into the slip (see :mod:`vdp.core.longitudinal`).

Without GNSS, a car with one driven axle has a reference all the same: the
free-rolling axle carries no torque while it is not braked, so its wheels turn
at the ground speed (no slip, eq 14 with F_x = 0) up to the tyre's rolling radius.
core.passes.speed_measured gives that speed when it applies; the filter takes it as
the measurement (``wheel_noise``), and while the free axle is braked the IMU
carries the speed alone, with the bias learnt before.

A GNSS speed in coarse steps (whole mph in Ford's GPS messages: 0.447 m/s, once a second)
carries a rounding error that white noise cannot describe: uniform over a step (std
step/sqrt 12) while the speed sweeps through steps, but the same value sample after sample
while the speed stays within one step.  Such a GNSS gets a third state, the rounding error
``e`` (``gnss_step`` > 0): each GNSS speed measures ``v_x + e``, and ``e`` forgets itself as
the speed travels, by ``exp(-6 |dv| / step)`` over a speed change ``dv`` (the initial slope of
a sawtooth's autocorrelation, ``1 - 6 d`` at ``d`` steps).  While the car accelerates the
steps average out; at constant speed the filter keeps the step's uncertainty instead of
averaging a constant error away.

**Turning.** v_x changes by ``a_x + r v_y`` (eq 1 of a body that yaws), and the filter sees a_x
alone: in a turn the term ``r v_y`` it leaves out reads as an accelerometer bias.  A junction
turn at 5 m/s has it at 0.3-0.4 m/s^2 for seconds (the CG's lateral speed there is the
kinematic ``r l_r``), and the bias learnt from it (-0.09 m/s^2 on the independent models'
ordinary drive) stayed long after the turn: v_x read 0.07 m/s (1 % at 7 m/s) fast in the
acceleration out of the junction, the slips stage 1 compares with it 1 % low, and C_K 15-40 %
high (docs/decisions/0028).  So while the car turns (``turn`` > 0, core.passes.turning: the
estimator's yaw rate beyond stage 1's straight-line limit) the bias is held, a Schmidt
consider state (no gain, its variance kept), and ``turn``, a bound on ``|r v_y|``, widens the
speed's process noise so that the GNSS carries v_x through the turn.  The accelerometer's bias is learnt while driving
straight, as the gyro offsets are.

**Reversing.** The GNSS and wheel speeds are magnitudes, so backwards the model's dv/dt = a_x has
the wrong sign.  While the gates see reverse (core.passes.reversing: the gear, or a signed speed
below zero), the bias is held the same way, with ``turn`` = 2 |a_x|.  Unheld, backing out of a
parking space taught it -0.24 m/s^2 for a minute, and stage 1's C_K read 1.8 std low after it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import passes as ps


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
    # the GNSS speed's quantisation step [m/s]; a step this coarse gets a rounding-error state
    gnss_step: float = 0.0


ROUNDING_STATE_MIN = 0.035  # m/s: a coarser step than this gets its state (its std 1/5 of 0.05 m/s)
DECORRELATE = 6.0  # per step of speed travelled: the sawtooth's autocorrelation 1 - 6 d


def gnss_noise(base: float, step: float) -> float:
    """GNSS speed noise [m/s] for a signal quantised in a fine ``step`` m/s (below
    ``ROUNDING_STATE_MIN``; a coarser one gets :class:`RoundedSpeedFilter`).

    The rounding error is uniform (std step/sqrt 12) but not white: while the speed changes
    by less than a step the error stays the same.  For a step this fine, half of it, the
    error's largest value, is taken as a white noise's std.
    """
    return math.sqrt(base * base + 0.25 * step * step)


def speed_filter(cfg: SpeedConfig, st: list[float] | None = None) -> SpeedFilter:
    """The speed filter for ``cfg``: with a rounding-error state for a coarse GNSS step (``st``: SpeedFilter's)."""
    return RoundedSpeedFilter(cfg, st) if cfg.gnss_step > 0.0 else SpeedFilter(cfg, st)


class SpeedFilter:
    """The two-state filter.  Its state is entries V to A_PREV of a state list (core.passes, whose
    :func:`~vdp.core.passes.speed_step` is its step here and in the compiled block pass): ``st``,
    one the estimator shares with its other parts, or a list of its own."""

    v, p_vv, p_vb, p_bb, bias = (ps.Entry(i) for i in (ps.V, ps.P_VV, ps.P_VB, ps.P_BB, ps.BIAS))
    t, a_prev = ps.Entry(ps.S_T, none=True), ps.Entry(ps.A_PREV)

    def __init__(self, cfg: SpeedConfig | None = None, st: list[float] | None = None):
        self.st = ps.new_state() if st is None else st
        self.cfg = cfg or SpeedConfig()
        self.bias = 0.0
        self.p_bb = 0.05**2
        self.reset()

    @property
    def cfg(self) -> SpeedConfig:
        return self._cfg

    @cfg.setter
    def cfg(self, cfg: SpeedConfig) -> None:  # (the estimator changes bias_walk with the road's grade)
        self._cfg = cfg
        self._p = [math.nan] * ps.N_PARAMS
        ps.speed_params(self._p, cfg)

    def reset(self) -> None:
        """Forget the speed (not the bias, which outlives gaps)."""
        ps.speed_reset(self.st)

    @property
    def ready(self) -> bool:
        return math.isfinite(self.st[ps.V])

    @property
    def std(self) -> float:
        st = self.st  # (read here, not through the attributes: this is read every sample)
        return math.sqrt(st[ps.P_VV]) if math.isfinite(st[ps.V]) else math.nan

    # a fine GNSS (or the wheels) decorrelates the speed's error within stage 1's assumed
    # time (LearnerConfig.speed_corr): not tracked here
    corr_time = 0.0

    def step(self, t: float, a_x: float, gnss: float | None, noise: float | None = None, turn: float = 0.0) -> None:
        """Advance to ``t`` with the measured a_x; correct with a speed measured at ``t``
        (GNSS, or the free-rolling axle), of std ``noise`` (default: ``gnss_noise``).
        ``turn`` > 0 (m/s^2, a bound on the ``r v_y`` the model leaves out): the car turns, the
        bias is held and the speed's process noise widened by it (module docstring)."""
        has = gnss is not None
        ps.speed_step(self.st, self._p, t, a_x, gnss if has else 0.0, has, math.nan if noise is None else noise, turn)


class RoundedSpeedFilter(SpeedFilter):
    """:class:`SpeedFilter` with a third state, the GNSS speed's rounding error ``e``.

    State ``[v_x, b_ax, e]``, covariance ``P`` (3x3).  A GNSS speed measures ``v_x + e`` with
    the white ``gnss_noise``; the free-rolling axle, ``v_x`` alone.  ``e`` is a first-order
    Gauss-Markov process of variance step^2 / 12 whose correlation decays with the speed
    travelled (module docstring).
    """

    def reset(self) -> None:
        self.v = math.nan
        self.e = 0.0
        self.tau = 0.0  # s: the speed error's correlation time (corr_time)
        self.t_meas: float | None = None
        self.P = np.zeros((3, 3))
        self.P[1, 1] = self.p_bb
        self.t = None
        self.a_prev = math.nan

    @property
    def p_vv(self) -> float:
        return float(self.P[0, 0])

    @property
    def std(self) -> float:
        return math.sqrt(self.p_vv) if self.ready else math.nan

    @property
    def corr_time(self) -> float:
        """How long [s] the speed's error stays correlated: the interval between measurements
        over the share of an error each one removes (the gain on v_x), averaged.  About 5 s
        for whole mph at 1 Hz (about 1 s for a 10 Hz GNSS of 0.05 m/s)."""
        return self.tau

    def step(self, t: float, a_x: float, gnss: float | None, noise: float | None = None, turn: float = 0.0) -> None:
        c = self.cfg
        q = c.gnss_step
        var_e = q * q / 12.0
        is_gnss = noise is None
        r = c.gnss_noise if is_gnss else noise
        dt = None if self.t is None else t - self.t
        self.p_bb = float(self.P[1, 1])  # the bias outlives a reset, with its uncertainty
        if not math.isfinite(a_x) or dt is None or dt <= 0 or dt > c.max_gap:
            self.reset()
            self.P[1, 1] = self.p_bb
            self.t = t if math.isfinite(a_x) else None
        elif self.ready:
            a_mean = 0.5 * (a_x + self.a_prev) if math.isfinite(self.a_prev) else a_x
            dv = dt * (a_mean - self.bias)
            self.v += dv
            phi = math.exp(-DECORRELATE * abs(dv) / q)
            self.e *= phi
            F = np.array([[1.0, -dt, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, phi]])
            Q = np.diag([(c.accel_noise * dt) ** 2 + (turn * dt) ** 2, c.bias_walk**2 * dt, var_e * (1.0 - phi * phi)])
            self.P = F @ self.P @ F.T + Q
            self.t = t
        self.a_prev = a_x
        if gnss is None or not math.isfinite(gnss):
            return
        if not self.ready:
            self.v, self.e = gnss, 0.0
            P = np.zeros((3, 3))
            P[1, 1] = self.P[1, 1]
            if is_gnss:  # v = z - e - noise: v and e start anticorrelated
                P[0, 0], P[2, 2], P[0, 2] = r * r + var_e, var_e, -var_e
            else:
                P[0, 0], P[2, 2] = r * r, var_e
            P[2, 0] = P[0, 2]
            self.P = P
            self.t = t
            return
        h = np.array([1.0, 0.0, 1.0 if is_gnss else 0.0])
        Ph = self.P @ h
        k = Ph / (h @ Ph + r * r)
        if self.t_meas is not None and t > self.t_meas and k[0] > 0.0:
            tau = min((t - self.t_meas) / float(k[0]), 120.0)
            self.tau = tau if self.tau == 0.0 else self.tau + 0.1 * (tau - self.tau)
        self.t_meas = t
        if turn > 0.0:  # turning: the bias is held (a consider state), P by Joseph's form for that gain
            k[1] = 0.0
            A = np.eye(3) - np.outer(k, h)
            self.P = A @ self.P @ A.T + np.outer(k, k) * (r * r)
        else:
            self.P = self.P - np.outer(k, Ph)
        x = np.array([self.v, self.bias, self.e]) + k * (gnss - self.v - h[2] * self.e)
        self.v, self.bias, self.e = float(x[0]), float(x[1]), float(x[2])
        self.P = 0.5 * (self.P + self.P.T)
