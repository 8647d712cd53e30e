"""The road's slope and the IMU's tilt, separated from the car's acceleration (issue 28, part 2).

An accelerometer reads specific force.  One aligned with the road reads ``f_x = dv/dt +
g sin(theta)`` on a grade theta: eq (3)'s load transfer wants exactly that (the axle loads
move with the contact forces, whatever part of them holds the car on the slope), but eq (1)'s
speed does not.  One fixed to the body also tilts with the suspension: nose up by about
0.2 deg per m/s^2 of f_x, so its a_x reads ``(1 + kappa) f_x`` (``kappa = g * 0.0035`` rad per
m/s^2, about 3.4 %) plus the mounting offset; and rolled by the body's roll angle phi, so its
a_y reads ``f_y + g sin(phi)``, which eq (9) (``m h (a_y + g phi)``) would add a second time.

:class:`Tilt` works on rows of ``ROW`` seconds.  On each it compares the accelerometer's mean
with the GNSS speed's slope (the kinematic dv/dt; not the wheels', whose slip changes with
the torque): ``d = mean(a_x) - dv/dt = G + kappa dv/dt``, with ``G`` the grade's
``(1 + kappa) g sin(theta)`` plus the bias and mounting offset, a random walk (a road's grade
changes over hundreds of metres), and ``kappa`` the pitch gain, nearly constant.  A two-state
Kalman filter learns both; a row whose ``d`` is further from that than the grade can move in
a row (``GATE`` sigma) is counted as ``grade_gated`` (a GNSS glitch, a kerb, a grade too steep
to follow) and taken by no one.

:meth:`Tilt.correct` then gives each sample the accelerations in the road's axes:
``a_x / (1 + kappa)`` and ``a_y - g phi_hat`` with ``phi_hat = beta a_y``, a_y lagged by
``c_phi / k_phi``, and ``beta`` the body's roll per unit of the a_y the IMU reads, learnt from the
roll-rate gyro (its integral over a row against the lagged a_y's change, with the gyro's bias;
eq 9's quasi-static ``m h / (k_phi - m g h)`` is only its prior: a body rolls by its sprung mass
about its roll axis): the double count of eq (9) is taken out before the learners see a_y.
The grade itself stays in a_x (stage 1 needs it for eq 3); the speed filter
(:mod:`vdp.core.speed`) takes it out as its accelerometer offset, which then has to walk as
fast as a grade changes (:data:`GRADE_BIAS_WALK`).

Pure: no clock, no I/O.  Off unless :class:`RoadConfig` ``on``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from .. import channels as ch

log = logging.getLogger(__name__)

ROW = 2.0  # s per row: 20 GNSS speeds at 10 Hz give a slope to 0.02 m/s^2
GATE = 4.0  # sigma: a row beyond this is not the grade and tilt the model has
# m/s^2 per sqrt(s): how fast the grade term walks; a grade of +-8 % over a few hundred metres at
# 20 m/s changes g sin(theta) by up to about 0.15 m/s^2 per second
GRADE_WALK = 0.1
GRADE_BIAS_WALK = GRADE_WALK  # the speed filter's accelerometer offset, for SpeedConfig.bias_walk
KAPPA_PRIOR = (0.0, 0.05)  # the pitch gain: 0 for a road-aligned IMU, 0.034 at 0.2 deg per m/s^2
MIN_SPEED = 3.0  # m/s: below this the GNSS slope and the grade mean little
LEVEL_BAND = 0.1  # m/s^2 (1 % of grade) from the grade term's slow mean: a level road, for the pitch gain
LEVEL_RATE = ROW / 60.0  # the slow mean's weight per row (a minute)
# The body's roll per unit of the a_y a body-fixed IMU reads, beta = phi / a_y, is learnt from the
# roll-rate gyro: over each row its integral (the roll's change) against the change of the lagged
# a_y, with the gyro's bias, by least squares (a Kalman filter of constant states).  Eq (9)'s
# m h / (k_phi - m g h) is only the prior: the body rolls by its sprung mass about the roll axis
# (brush/saloon: g phi = 0.075 f_y against eq 9's 0.094), and 2 % of a_y is enough to move
# stage 2's C_alpha 15 % (docs/decisions/0022).
ROLL_ROW_NOISE = 2.0e-4  # rad: a row's roll change beyond beta x the lagged a_y's (dynamics, gyro noise)
BETA_REL_STD = 0.5  # the prior's relative std: a car's roll gain is known to within a factor of two
GYRO_BIAS_STD = 0.01  # rad/s: the roll-rate gyro's bias, prior
# m/s^2: a row whose lagged a_y moves less teaches beta less than the accelerometer's noise in the lag
# spoils it (0.05 m/s^2 white, lagged 0.07 s: 0.013; on the straights beta fell 0.0088 -> 0.0022, read
# from noise, and the corners' rows were then gated out as beyond it)
MIN_ROLL_STEP = 0.5


@dataclass(frozen=True)
class RoadConfig:
    on: bool = False  # off: today's estimates, to the bit
    body_imu: bool = True  # take the body's roll out of a_y (a road-aligned IMU: False)
    speed_walk: float = GRADE_BIAS_WALK  # the speed filter's a_x offset walk [m/s^2 per sqrt(s)]
    bank: bool = True  # stage 2 estimates the road's bank as a state (LearnerConfig.bank; docs/decisions/0025)


@dataclass
class _Row:
    """One row's sums.  The accelerometer is compared with the GNSS speed on the same footing:
    its integral u(t) is sampled at the GNSS speeds' times and both get the same least-squares
    slope (a mean a_x over the row would weight the row's ends more than the slope does, which
    on a 12.5 s sine of speed reads as a pitch gain of -0.017)."""

    t0: float
    n: int = 0
    ax: float = 0.0
    u: float = 0.0  # integral of a_x since t0 (trapezoid)
    a_prev: float = math.nan
    t_prev: float = math.nan
    # least squares over the GNSS speeds: sums of t, v, t t, t v, and of w = v - u, t w
    gn: int = 0
    st: float = 0.0
    sv: float = 0.0
    stt: float = 0.0
    stv: float = 0.0
    sw: float = 0.0
    stw: float = 0.0

    def slope(self) -> tuple[float, float, float] | None:
        """(dv/dt, dv/dt - a_x, their std at 0.05 m/s per speed) by least squares, or None."""
        if self.gn < 5:
            return None
        d = self.gn * self.stt - self.st * self.st
        if d <= 0:
            return None
        k = 1.0 / d
        dv = (self.gn * self.stv - self.st * self.sv) * k
        dw = (self.gn * self.stw - self.st * self.sw) * k
        return dv, dw, 0.05 * math.sqrt(self.gn * k)

    @property
    def v(self) -> float:
        return self.sv / self.gn if self.gn else math.nan


class Pitch:
    """The grade and pitch-gain filter (see the module): rows of ROW seconds of the accelerometer
    against the GNSS speed's slope.  :class:`Tilt` builds on it; with the road model off, the mass
    learner keeps one of its own, for the pitch gain only (core.mass)."""

    def __init__(self, kappa_std: float = KAPPA_PRIOR[1]):
        self.kappa_std0 = kappa_std
        self.reset()

    def reset(self) -> None:
        self.G, self.kappa = 0.0, KAPPA_PRIOR[0]
        self.level: float | None = None  # the grade term's slow mean: a level road's (the bias, the mounting)
        self.level_rows = 0  # rows the pitch gain learnt from
        self.moving = 0.0  # how fast the grade term moves now: EWMA of |dG| per sqrt(s) over rows
        self.P = [[1.0, 0.0], [0.0, self.kappa_std0**2]]  # G's prior: 1 m/s^2 (about 10 %)
        self.row: _Row | None = None
        self.rows = self.gated = 0
        self.last: dict | None = None  # the last row

    def add(self, t: float, gap: bool, ax: float, v: float, fresh: bool, age: float) -> None:
        """One sample: its time, whether a gap precedes it, its a_x, and the GNSS speed ``v`` with
        whether it is new at this sample and its age [s]."""
        if not math.isfinite(ax) or gap:
            self.row = None
            return
        r = self.row
        if r is None or t - r.t0 >= ROW:
            if r is not None:
                self._close(r)
            r = self.row = _Row(t)
        r.n += 1
        r.ax += ax
        if math.isfinite(r.a_prev):
            r.u += 0.5 * (ax + r.a_prev) * (t - r.t_prev)
        r.a_prev, r.t_prev = ax, t
        if fresh and math.isfinite(v):
            age = age if math.isfinite(age) else 0.0
            tt = t - r.t0 - age
            w = v - (r.u - ax * age)  # u at the speed's own time
            r.gn += 1
            r.st += tt
            r.sv += v
            r.stt += tt * tt
            r.stv += tt * v
            r.sw += w
            r.stw += tt * w

    def _close(self, r: _Row) -> None:
        """One row into the grade and tilt filter (H = [1, dv/dt])."""
        sl = r.slope()
        if sl is None or r.v < MIN_SPEED:
            self.last = None
            return
        a = r.ax / r.n
        dvdt, dw, sd = sl
        d = -dw  # a_x - dv/dt on the slope's footing
        P = self.P
        P[0][0] += GRADE_WALK**2 * ROW
        P[1][1] += 1e-9 * ROW  # the pitch gain hardly changes: a walk this slow still lets it average
        # the pitch gain is learnt on a level road only: on a grade the driver's answer to it (slower
        # uphill) ties the acceleration to the grade's changes, and the filter read that as pitch gain
        # (kappa 0.056-0.062 against 0.027-0.034 on both models' hills); there the grade is learnt
        # with kappa held, its uncertainty taken as noise
        level = self.level is None or abs(self.G - self.level) < LEVEL_BAND
        h0, h1 = 1.0, dvdt if level else 0.0
        pred = self.G + self.kappa * dvdt
        ph0 = P[0][0] * h0 + P[0][1] * h1
        ph1 = P[1][0] * h0 + P[1][1] * h1
        S = h0 * ph0 + h1 * ph1 + sd * sd + 0.02**2 + (0.0 if level else dvdt * dvdt * P[1][1])
        inn = d - pred
        self.rows += 1
        if inn * inn > GATE * GATE * S:
            self.gated += 1
            self.last = None
            return
        k0, k1 = ph0 / S, (ph1 / S if level else 0.0)
        self.level_rows += level
        self.moving += 0.3 * (abs(k0 * inn) / math.sqrt(ROW) - self.moving)
        self.G += k0 * inn
        self.kappa += k1 * inn
        if level:
            self.P = [
                [P[0][0] - k0 * ph0, P[0][1] - k0 * ph1],
                [P[1][0] - k1 * ph0, P[1][1] - k1 * ph1],
            ]
        else:
            p01 = P[0][1] - k0 * P[0][1]
            self.P = [[P[0][0] - k0 * P[0][0], p01], [p01, P[1][1]]]
        self.level = self.G if self.level is None else self.level + LEVEL_RATE * (self.G - self.level)
        self.last = {"t": r.t0 + ROW, "a_x": a, "dv_dt": dvdt, "G": self.G}

    @property
    def kappa_std(self) -> float:
        return math.sqrt(max(self.P[1][1], 0.0))

    def saved(self) -> list[float]:
        """The filter, for :meth:`restore` across a restart (a row still open is not kept)."""
        return [self.G, self.kappa, *self.P[0], *self.P[1], self.level if self.level is not None else math.nan,
                self.level_rows, self.moving, self.rows, self.gated]  # fmt: skip

    def restore(self, v) -> bool:
        """Carry on from :meth:`saved`; False, and nothing changed, for one damaged or of another prior."""
        try:
            G, kappa, p00, p01, p10, p11, level, level_rows, moving, rows, gated = (float(x) for x in v)
        except (TypeError, ValueError):
            return False
        if not all(map(math.isfinite, (G, kappa, p00, p01, p10, p11, moving))) or not 0.0 < p11 <= self.kappa_std0**2:
            return False
        self.reset()
        self.G, self.kappa, self.P = G, kappa, [[p00, p01], [p10, p11]]
        self.level = level if math.isfinite(level) else None
        self.level_rows, self.moving, self.rows, self.gated = int(level_rows), moving, int(rows), int(gated)
        return True


class Tilt(Pitch):
    """The grade and tilt filter and the per-sample correction (see the module)."""

    def __init__(self, vehicle, h: float, cfg: RoadConfig | None = None):
        self.cfg = cfg or RoadConfig()
        v = vehicle
        self.g = v.g
        # eq 9 quasi-static: phi = m h a_y / (k_phi - m g h); its lag c_phi / k_phi
        mh = v.mass * h
        self.roll_gain = mh / max(v.roll_stiffness - mh * v.g, 1e-9 * v.roll_stiffness)
        self.roll_tau = v.roll_damping / v.roll_stiffness if v.roll_stiffness > 0 else 0.0
        # eq 9's phi / a_y as the IMU reads it (a_y = f_y + g phi): the prior of the learnt beta
        self.beta_prior = self.roll_gain / (1.0 + self.g * self.roll_gain)
        super().__init__()

    def reset(self) -> None:
        super().reset()
        self.phi = 0.0
        self.t: float | None = None
        # the roll's filter (body_imu): beta and the roll-rate gyro's bias (see ROLL_ROW_NOISE)
        self.beta, self.gyro_bias = self.beta_prior, 0.0
        self.Pr = [[(BETA_REL_STD * self.beta_prior) ** 2, 0.0], [0.0, GYRO_BIAS_STD**2]]
        self.lag = 0.0  # a_y lagged by c_phi / k_phi
        self.roll_row: list[float] | None = None  # [t0, lag at t0, integral of the roll rate, last roll rate]
        self.roll_rows = self.roll_gated = 0

    def speed_walk(self, base: float) -> float:
        """The speed filter's a_x offset walk now [m/s^2 per sqrt(s)]: ``base`` on a level road, up
        to ``speed_walk`` while the grade moves (a walk that fast on a level road costs stage 1 its
        speed: h was not valid on the paper drive at 0.1 throughout)."""
        return min(max(base, 2.0 * self.moving), max(base, self.cfg.speed_walk))

    # -- per sample -------------------------------------------------------------
    def correct(self, s):
        """The sample with a_x and a_y in the road's axes (the grade stays in a_x)."""
        y = s.values
        ax, ay = y[ch.AX], y[ch.AY]
        self._accumulate(s, ax, ay)
        out = list(y)
        if math.isfinite(ax):
            out[ch.AX] = ax / (1.0 + self.kappa)
        if self.cfg.body_imu and math.isfinite(ay):
            # a_y = f_y + g phi and phi = beta a_y (lagged), beta learnt from the roll-rate gyro (_roll)
            dt = 0.0 if self.t is None else min(max(s.t - self.t, 0.0), 0.2)
            k = 1.0 if self.roll_tau <= 0 else 1.0 - math.exp(-dt / self.roll_tau) if dt > 0 else 0.0
            self.lag += k * (ay - self.lag)
            self._roll(s, y[ch.ROLL], dt)
            self.phi = self.beta * self.lag
            out[ch.AY] = ay - self.g * self.phi
        elif self.cfg.body_imu:
            self.roll_row = None
        self.t = s.t
        return s._replace(values=tuple(out))

    def _accumulate(self, s, ax: float, ay: float) -> None:
        y = s.values
        self.add(s.t, s.gap, ax, y[ch.SPEED], s.fresh[ch.SPEED], s.age[ch.SPEED])

    def _roll(self, s, p: float, dt: float) -> None:
        """The roll-rate gyro's integral over a row against the change of the lagged a_y:
        integral(p) = beta (lag(t1) - lag(t0)) + bias (t1 - t0), one row at a time (H = [d lag, t1 - t0])."""
        rr = self.roll_row
        if not math.isfinite(p) or s.gap:
            self.roll_row = None
            return
        if rr is None:
            self.roll_row = [s.t, self.lag, 0.0, p]
            return
        rr[2] += 0.5 * (p + rr[3]) * dt
        rr[3] = p
        if s.t - rr[0] < ROW:
            return
        H0, H1, z = self.lag - rr[1], s.t - rr[0], rr[2]
        self.roll_row = [s.t, self.lag, 0.0, p]
        if abs(H0) < MIN_ROLL_STEP:
            return
        P = self.Pr
        ph0 = P[0][0] * H0 + P[0][1] * H1
        ph1 = P[1][0] * H0 + P[1][1] * H1
        S = H0 * ph0 + H1 * ph1 + ROLL_ROW_NOISE**2
        inn = z - (self.beta * H0 + self.gyro_bias * H1)
        self.roll_rows += 1
        if inn * inn > GATE * GATE * S:
            self.roll_gated += 1
            return
        k0, k1 = ph0 / S, ph1 / S
        self.beta += k0 * inn
        self.gyro_bias += k1 * inn
        self.Pr = [[P[0][0] - k0 * ph0, P[0][1] - k0 * ph1], [P[1][0] - k1 * ph0, P[1][1] - k1 * ph1]]

    def state(self) -> dict:
        """What the road did to the drive, plainly."""
        return {
            "pitch_gain_kappa": round(self.kappa, 5),
            "pitch_gain_std": round(math.sqrt(max(self.P[1][1], 0.0)), 5),
            "grade_term_mps2": round(self.G, 4),
            "rows": self.rows,
            "level_rows": self.level_rows,
            "grade_gated": self.gated,
            **(
                {
                    "roll_per_a_y": round(self.beta, 6),
                    "roll_per_a_y_std": round(math.sqrt(max(self.Pr[0][0], 0.0)), 6),
                    "roll_per_a_y_prior": round(self.beta_prior, 6),
                    "roll_rows": self.roll_rows,
                    "roll_gated": self.roll_gated,
                }
                if self.cfg.body_imu
                else {}
            ),
            "reason": None
            if not self.gated
            else f"{self.gated} of {self.rows} rows of {ROW:g} s gated out: "
            "the accelerometer and the GNSS speed disagreed beyond the grade and tilt model",
        }
