"""Sensor models: truth state -> canonical channel values (SI units, vdp.channels).

``none``: exact values (the DBC quantisation still applies when encoding).
``realistic``: white noise on every channel, plus a constant per-run bias on the
IMU (accelerometers and gyros), drawn once from the seed.

Single track: both front wheel-speed channels report the front axle's omega, both
rear ones the rear axle's.  GNSS speed is the ground speed of the CG,
``hypot(v_x, v_y)`` (it differs from v_x by < 0.01 m/s in these manoeuvres).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from .. import channels
from ..errors import ConfigError
from .vehicle import VX, VY, WF, WR, WZ, P

log = logging.getLogger(__name__)

NOISE_MODELS = ("none", "realistic")
_DEG = math.pi / 180.0


@dataclass(frozen=True)
class NoiseModel:
    name: str
    sigma: dict[str, float] = field(default_factory=dict)  # white noise per channel, SI
    bias_sigma: dict[str, float] = field(default_factory=dict)  # per-run constant bias, SI

    def describe(self) -> dict:
        return {
            "model": self.name,
            "sigma": dict(self.sigma),
            "bias_sigma": dict(self.bias_sigma),
            "units": {c: channels.UNITS.get(c, "N*m") for c in self.sigma},
        }


def noise_model(name: str, steering_ratio: float = 1.0) -> NoiseModel:
    """The named noise model; the steering sigma is 0.1 deg at the handwheel."""
    if name == "none":
        return NoiseModel("none")
    if name != "realistic":
        raise ConfigError(f"unknown noise model '{name}'; choose one of {', '.join(NOISE_MODELS)}")
    sigma = dict.fromkeys(("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr"), 0.03)
    sigma.update(
        {
            "wheel_torque_front": 5.0,
            "wheel_torque_rear": 5.0,
            "steering_angle": 0.1 * _DEG / steering_ratio,
            "accel_x": 0.05,
            "accel_y": 0.05,
            "yaw_rate": 0.1 * _DEG,
            "roll_rate": 0.1 * _DEG,
            "speed": 0.05,
            "drive_torque": 5.0,  # what a production bus sends instead of per-axle torque
            "brake_torque": 5.0,
        }
    )
    bias = {"accel_x": 0.02, "accel_y": 0.02, "yaw_rate": 0.03 * _DEG, "roll_rate": 0.03 * _DEG}
    return NoiseModel("realistic", sigma, bias)


class Normals:
    """Standard normal draws in blocks: scalar numpy calls are slow in a hot loop."""

    def __init__(self, rng: np.random.Generator, block: int = 8192):
        self.rng, self.block = rng, block
        self.buf: list[float] = []
        self.i = 0

    def __call__(self) -> float:
        if self.i >= len(self.buf):
            self.buf = self.rng.standard_normal(self.block).tolist()
            self.i = 0
        self.i += 1
        return self.buf[self.i - 1]


# Truth value of each channel from (state, forces tuple, T_f, T_r, delta).
def _truth_readers() -> dict:
    return {
        "wheel_speed_fl": lambda x, e, tf, tr, d: x[WF],
        "wheel_speed_fr": lambda x, e, tf, tr, d: x[WF],
        "wheel_speed_rl": lambda x, e, tf, tr, d: x[WR],
        "wheel_speed_rr": lambda x, e, tf, tr, d: x[WR],
        "wheel_torque_front": lambda x, e, tf, tr, d: tf,
        "wheel_torque_rear": lambda x, e, tf, tr, d: tr,
        "steering_angle": lambda x, e, tf, tr, d: d,
        "accel_x": lambda x, e, tf, tr, d: e[0],
        "accel_y": lambda x, e, tf, tr, d: e[1],
        "yaw_rate": lambda x, e, tf, tr, d: x[WZ],
        "roll_rate": lambda x, e, tf, tr, d: x[P],
        "speed": lambda x, e, tf, tr, d: math.hypot(x[VX], x[VY]),
        # the status flags: off (sim.events sets them in the frames it changes)
        **{c: (lambda x, e, tf, tr, d: 0.0) for c in channels.STATUS},
        # sources (profile.SOURCES): the total drive torque and the brake torque's magnitude
        "drive_torque": lambda x, e, tf, tr, d: max(tf + tr, 0.0),
        "brake_torque": lambda x, e, tf, tr, d: max(-(tf + tr), 0.0),
    }


TRUTH_READERS = _truth_readers()  # the roll angle itself is not measured (NOTES 13)


def draw_bias(model: NoiseModel, rng: np.random.Generator) -> dict[str, float]:
    """Per-run constant biases, drawn in channel order so a seed always gives the same ones."""
    return {c: float(rng.normal(0.0, model.bias_sigma[c])) if c in model.bias_sigma else 0.0 for c in channels.NAMES}


class Sensors:
    """Reads channels with white noise and the given per-run bias."""

    def __init__(self, model: NoiseModel, bias: dict[str, float], noise_rng: np.random.Generator):
        self.model = model
        names = (*channels.NAMES, "drive_torque", "brake_torque")
        self.bias = {c: float(bias.get(c, 0.0)) for c in names}
        self.sigma = {c: model.sigma.get(c, 0.0) for c in names}
        self._normal = Normals(noise_rng)

    def read(self, channel: str, x, e, T_f: float, T_r: float, delta: float) -> float:
        v = TRUTH_READERS[channel](x, e, T_f, T_r, delta) + self.bias[channel]
        s = self.sigma[channel]
        return v + s * self._normal() if s else v

    def reader(self, channel: str):
        """A fast closure for one channel: f(x, e, T_f, T_r, delta) -> measured value."""
        truth = TRUTH_READERS[channel]
        b, s, normal = self.bias[channel], self.sigma[channel], self._normal
        if s:
            return lambda x, e, tf, tr, d: truth(x, e, tf, tr, d) + b + s * normal()
        if b:
            return lambda x, e, tf, tr, d: truth(x, e, tf, tr, d) + b
        return truth
