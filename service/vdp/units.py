"""The units table: every unit a profile may name, its factor to SI and its kind, and the
kinds each canonical channel (and each [drivetrain] source) accepts."""

from __future__ import annotations

import math

# Unit -> (factor to SI, SI unit kind).  Linear speeds become rad/s for wheel
# channels through the wheel radius (see ChannelMap.convert).
UNIT_FACTORS: dict[str, tuple[float, str]] = {
    "rad/s": (1.0, "angular_rate"),
    "deg/s": (math.pi / 180.0, "angular_rate"),
    "rpm": (2.0 * math.pi / 60.0, "angular_rate"),
    "m/s": (1.0, "speed"),
    "km/h": (1.0 / 3.6, "speed"),
    "kph": (1.0 / 3.6, "speed"),
    "mph": (0.44704, "speed"),
    "kn": (0.514444, "speed"),
    "N*m": (1.0, "torque"),
    "Nm": (1.0, "torque"),
    "N.m": (1.0, "torque"),
    "kN*m": (1000.0, "torque"),
    "rad": (1.0, "angle"),
    "deg": (math.pi / 180.0, "angle"),
    "m/s^2": (1.0, "accel"),
    "m/s2": (1.0, "accel"),
    "g": (9.80665, "accel"),
    "bar": (1e5, "pressure"),
    "mbar": (100.0, "pressure"),
    "kPa": (1e3, "pressure"),
    "MPa": (1e6, "pressure"),
    "Pa": (1.0, "pressure"),
    "psi": (6894.757, "pressure"),
    "1": (1.0, "ratio"),
    "%": (0.01, "ratio"),
}
# VW's DBCs (opendbc vw_*.dbc) spell units like this; same meaning as above.
UNIT_ALIASES: dict[str, str] = {
    "Unit_DegreOfArcPerSecon": "deg/s",
    "Unit_MinutInver": "rpm",
    "Unit_KiloMeterPerHour": "km/h",
    "Unit_NewtoMeter": "Nm",
    "Unit_DegreOfArc": "deg",
    "Unit_MeterPerSeconSquar": "m/s^2",
    "Unit_ForceOfGravi": "g",
    # and others' (opendbc's hyundai_canfd)
    "km^h": "km/h",
    "Deg/s": "deg/s",
}
UNIT_FACTORS.update({alias: UNIT_FACTORS[unit] for alias, unit in UNIT_ALIASES.items()})
_UNIT_LIST = ", ".join(u for u in UNIT_FACTORS if u not in UNIT_ALIASES)

# What kind of unit each canonical channel accepts.
CHANNEL_KINDS: dict[str, tuple[str, ...]] = {
    "wheel_speed_fl": ("angular_rate", "speed"),
    "wheel_speed_fr": ("angular_rate", "speed"),
    "wheel_speed_rl": ("angular_rate", "speed"),
    "wheel_speed_rr": ("angular_rate", "speed"),
    "wheel_torque_front": ("torque",),
    "wheel_torque_rear": ("torque",),
    "steering_angle": ("angle",),
    "accel_x": ("accel",),
    "accel_y": ("accel",),
    "yaw_rate": ("angular_rate",),
    "roll_rate": ("angular_rate",),
    "speed": ("speed",),
    # status flags: a 0/1 bit as it is, or an enum's raw values through active_when
    "reverse": ("ratio",),
    "abs_active": ("ratio",),
    "esc_active": ("ratio",),
    "tcs_active": ("ratio",),
}

# Source channels: what production buses send instead of per-axle torque.  They never
# reach the estimator themselves; [drivetrain] turns them into wheel_torque_front/rear.
SOURCES: dict[str, tuple[str, ...]] = {
    "drive_torque": ("torque",),  # total drive torque at the wheels, of the driven axle(s)
    "brake_torque": ("torque",),  # total brake torque, a positive magnitude
    "brake_pressure": ("pressure",),  # master-cylinder pressure; times brake_gain is brake_torque
}
CHANNEL_KINDS.update(SOURCES)
# Any unit kind is allowed in a term of a composite channel (its weight converts it).
TERM = "term"
CHANNEL_KINDS[TERM] = tuple({k for _, k in UNIT_FACTORS.values()})
