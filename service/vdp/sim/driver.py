"""The driver: speed tracking by PI + feedforward on wheel torque, steering through actuators.

Torque: ``T = (m r + 2 J / r) * (a_cmd + kp e + ki int e)`` (feedforward covers the body
and both lumped wheels, eqs 1-2), then a first-order actuator lag, then the split
front/rear by sign (both axles drive and brake).  A speed command of zero holds the
car with a fixed brake torque, so a stopped car neither creeps nor chatters.

Traction control and ABS: given the axles' wheel slips, an axle whose slip (in the
direction of its torque) exceeds ``slip_max`` has its torque cut by an integral
controller, ``dT_cap/dt = -k (|s| - slip_max)``, which lets go as the slip falls back.
Without it a front-driven car asked for the paper's 5 m/s^2 spins its front wheels up to
thousands of rad/s (the tyre's grip is mu F_zf, about 3.4 m/s^2 of the paper car), which
no production car with ESC does.  Below ``slip_min_speed`` it is off (as ABS is), and
while it cuts, the speed controller's integrator holds still.

Steering: the road-wheel angle command goes through a rate limit and a small lag.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from ..errors import ConfigError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class DriverConfig:
    kp: float = 1.5  # 1/s: m/s^2 of acceleration per m/s of speed error
    ki: float = 0.5  # 1/s^2
    a_max: float = 8.0  # m/s^2, limit of the demanded acceleration
    tau_torque: float = 0.05  # s, powertrain/brake actuator lag
    drive_front: float = 0.5  # share of a drive torque on the front axle
    brake_front: float = 0.6  # share of a brake torque on the front axle
    hold_torque: float = 1000.0  # N m total brake torque at standstill
    steer_rate: float = math.radians(40.0)  # rad/s road wheel
    tau_steer: float = 0.02  # s
    # traction control and ABS (None: off): the axle slip beyond which they cut its torque;
    # a linear tyre of C_K = 10 and mu = 1 reaches its grip at 0.1
    slip_max: float | None = 0.1
    slip_time: float = 0.01  # s: the cut's time constant at a tyre of C_K = 10 and full static load
    slip_min_speed: float = 2.0  # m/s: below this neither acts (nor does ABS in a car)

    def __post_init__(self) -> None:
        for name in ("drive_front", "brake_front"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ConfigError(f"driver: '{name}' must be within [0, 1], got {v}")
        if self.slip_max is not None and not self.slip_max > 0:
            raise ConfigError(f"driver: 'slip_max' must be positive or None, got {self.slip_max}")
        for name in ("tau_torque", "tau_steer", "steer_rate", "a_max", "hold_torque", "slip_time"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"driver: '{name}' must be positive")


class Driver:
    """Stateful controller; call :meth:`update` once per integration step."""

    def __init__(self, cfg: DriverConfig, m: float, r: float, J: float, delta0: float = 0.0):
        self.cfg = cfg
        self.gain = m * r + 2.0 * J / r  # N m per m/s^2
        # traction control's gain [N m/s per unit slip]: an axle carrying m g / 2 with C_K = 10
        # moves its slip by 1 / (r C_K m g / 2) per N m, so this closes the loop in about slip_time
        self.k_slip = 0.5 * m * 9.8 * r * 10.0 / cfg.slip_time
        self.cap = [math.inf, math.inf]  # |torque| each axle may take now
        self.limited = False  # traction control or ABS cut an axle last step
        self.integ = 0.0
        self.torque = 0.0  # lagged total torque
        self.delta_rl = delta0  # rate-limited command
        self.delta = delta0  # actual road-wheel angle
        self._dt = None
        self._lag_t = self._lag_s = 0.0
        self._rate_step = 0.0

    def _set_dt(self, dt: float) -> None:
        self._dt = dt
        self._lag_t = 1.0 - math.exp(-dt / self.cfg.tau_torque)  # exact first-order discretisation
        self._lag_s = 1.0 - math.exp(-dt / self.cfg.tau_steer)
        self._rate_step = self.cfg.steer_rate * dt

    def update(
        self,
        dt: float,
        v_cmd: float,
        a_cmd: float,
        delta_cmd: float,
        v_x: float,
        slip: tuple[float, float] | None = None,
    ) -> tuple[float, float, float]:
        """Returns (T_f, T_r, delta) to apply over the next step; ``slip`` (s_f, s_r), the axles'
        wheel slips now, lets traction control and ABS act."""
        if dt != self._dt:
            self._set_dt(dt)
        cfg = self.cfg
        if v_cmd <= 0.05 and a_cmd <= 0.0:
            self.integ = 0.0
            t_cmd = -cfg.hold_torque
        else:
            e = v_cmd - v_x
            a = a_cmd + cfg.kp * e + cfg.ki * self.integ
            if a > cfg.a_max:
                a = cfg.a_max
            elif a < -cfg.a_max:
                a = -cfg.a_max
            elif not self.limited:
                self.integ += e * dt  # anti-windup: integrate only while unsaturated and not cut
            t_cmd = self.gain * a
        self.torque += self._lag_t * (t_cmd - self.torque)
        t = self.torque
        front = cfg.drive_front if t >= 0.0 else cfg.brake_front
        t_f, t_r = front * t, (1.0 - front) * t
        if slip is not None and cfg.slip_max is not None:
            t_f, t_r = self._limit(0, t_f, slip[0], v_x, dt), self._limit(1, t_r, slip[1], v_x, dt)
        self.delta_rl, self.delta = self._steer(delta_cmd)
        return t_f, t_r, self.delta

    def _steer(self, delta_cmd: float) -> tuple[float, float]:
        """(rate-limited command, road-wheel angle) one step on: rate limit, then lag."""
        step = delta_cmd - self.delta_rl
        rs = self._rate_step
        rl = self.delta_rl + (rs if step > rs else (-rs if step < -rs else step))
        return rl, self.delta + self._lag_s * (rl - self.delta)

    def next_delta(self, delta_cmd: float) -> float:
        """The road-wheel angle the next :meth:`update` will return for this command (the
        steering does not depend on the car's state), without moving the driver: the end of the
        step the simulator ramps the angle to."""
        return self._steer(delta_cmd)[1]

    def _limit(self, i: int, torque: float, slip: float, v_x: float, dt: float) -> float:
        """Axle ``i``'s torque after traction control (driving) or ABS (braking)."""
        want = abs(torque)
        if v_x < self.cfg.slip_min_speed:
            self.cap[i] = want
            if i == 0:
                self.limited = False
            return torque
        s = slip if torque >= 0.0 else -slip  # the slip in the torque's direction
        # integral control with the request as the ceiling: while the slip stays below
        # slip_max the cap rises faster than any request and the torque is the request exactly
        cap = min(self.cap[i] - self.k_slip * (s - self.cfg.slip_max) * dt, want)
        cap = max(cap, 0.0)
        self.cap[i] = cap
        cut = cap < want
        self.limited = cut if i == 0 else (self.limited or cut)
        return math.copysign(cap, torque)
