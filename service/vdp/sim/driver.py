"""The driver: speed tracking by PI + feedforward on wheel torque, steering through actuators.

Torque: ``T = (m r + 2 J / r) * (a_cmd + kp e + ki int e)`` (feedforward covers the body
and both lumped wheels, eqs 1-2), then a first-order actuator lag, then the split
front/rear by sign (both axles drive and brake).  A speed command of zero holds the
car with a fixed brake torque, so a stopped car neither creeps nor chatters.

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

    def __post_init__(self) -> None:
        for name in ("drive_front", "brake_front"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ConfigError(f"driver: '{name}' must be within [0, 1], got {v}")
        for name in ("tau_torque", "tau_steer", "steer_rate", "a_max", "hold_torque"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"driver: '{name}' must be positive")


class Driver:
    """Stateful controller; call :meth:`update` once per integration step."""

    def __init__(self, cfg: DriverConfig, m: float, r: float, J: float, delta0: float = 0.0):
        self.cfg = cfg
        self.gain = m * r + 2.0 * J / r  # N m per m/s^2
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

    def update(self, dt: float, v_cmd: float, a_cmd: float, delta_cmd: float, v_x: float) -> tuple[float, float, float]:
        """Returns (T_f, T_r, delta) to apply over the next step."""
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
            else:
                self.integ += e * dt  # anti-windup: integrate only while unsaturated
            t_cmd = self.gain * a
        self.torque += self._lag_t * (t_cmd - self.torque)
        t = self.torque
        front = cfg.drive_front if t >= 0.0 else cfg.brake_front
        # Steering: rate limit, then lag.
        step = delta_cmd - self.delta_rl
        rs = self._rate_step
        self.delta_rl += rs if step > rs else (-rs if step < -rs else step)
        self.delta += self._lag_s * (self.delta_rl - self.delta)
        return front * t, (1.0 - front) * t, self.delta
