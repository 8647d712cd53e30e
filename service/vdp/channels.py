"""Canonical channels: the sensor set the estimator consumes, in SI units.

A vehicle profile maps each of these to DBC signals; everything downstream of
the decoder sees only these names and units.
"""

from __future__ import annotations

import math

# (name, SI unit) in the fixed order used by sample arrays.
CHANNELS: tuple[tuple[str, str], ...] = (
    ("wheel_speed_fl", "rad/s"),
    ("wheel_speed_fr", "rad/s"),
    ("wheel_speed_rl", "rad/s"),
    ("wheel_speed_rr", "rad/s"),
    ("wheel_torque_front", "N*m"),  # axle torque, drive positive, brake negative
    ("wheel_torque_rear", "N*m"),
    ("steering_angle", "rad"),  # road-wheel angle, positive left
    ("accel_x", "m/s^2"),
    ("accel_y", "m/s^2"),
    ("yaw_rate", "rad/s"),  # positive left (counter-clockwise from above)
    ("roll_rate", "rad/s"),
    ("speed", "m/s"),  # GNSS ground speed
    # status flags (1 while on, 0 while off; optional: a car whose bus lacks one is not gated by it).
    # They gate what the model does not cover (core.gates); no learner reads them.
    ("reverse", "1"),  # reverse gear engaged (a profile maps a gear enum with active_when)
    ("abs_active", "1"),  # ABS regulating a wheel
    ("esc_active", "1"),  # stability control braking a wheel
    ("tcs_active", "1"),  # traction control cutting torque or braking a spinning wheel
)

NAMES: tuple[str, ...] = tuple(n for n, _ in CHANNELS)
UNITS: dict[str, str] = dict(CHANNELS)
INDEX: dict[str, int] = {n: i for i, n in enumerate(NAMES)}
N = len(NAMES)

WS_FL, WS_FR, WS_RL, WS_RR, T_F, T_R, DELTA, AX, AY, YAW, ROLL, SPEED, REVERSE, ABS, ESC, TCS = range(N)
N_SENSORS = SPEED + 1  # the measured channels, before the status flags
STATUS = NAMES[N_SENSORS:]  # the status flags: a profile may map them with active_when

# What a missing channel means, in the words of a car's sensor set.
DESCRIPTIONS: dict[str, str] = {
    "wheel_speed_fl": "wheel speeds",
    "wheel_speed_fr": "wheel speeds",
    "wheel_speed_rl": "wheel speeds",
    "wheel_speed_rr": "wheel speeds",
    "wheel_torque_front": "per-axle wheel torque",
    "wheel_torque_rear": "per-axle wheel torque",
    "steering_angle": "steering angle",
    "accel_x": "longitudinal acceleration",
    "accel_y": "lateral acceleration",
    "yaw_rate": "yaw-rate gyro",
    "roll_rate": "roll-rate gyro",
    "speed": "GNSS ground speed",
    "reverse": "reverse gear",
    "abs_active": "ABS status",
    "esc_active": "ESC status",
    "tcs_active": "traction control status",
    # sources of the axle torques (vdp.profile.SOURCES)
    "drive_torque": "drive torque at the wheels",
    "brake_torque": "brake torque",
    "brake_pressure": "brake pressure",
}

# Which channels each stage needs; a profile lacking one disables the stage.
STAGE1_NEEDS = (
    "wheel_speed_fl",
    "wheel_speed_fr",
    "wheel_speed_rl",
    "wheel_speed_rr",
    "wheel_torque_front",
    "wheel_torque_rear",
    "accel_x",
    "speed",
    "steering_angle",
    "yaw_rate",
)
# Stage 2 needs no stage 1 once l_f is measured ([vehicle] l_f), nor a roll-rate gyro: its
# C_alpha and I_z come from the steering, yaw rate and a_y.  Its v_x is the speed filter's
# (GNSS, or the free-rolling axle) or else the rear wheels' (STAGE2_SPEED): a stage-2 window
# is at nearly constant speed, where the wheels' slip is a few tenths of a percent.
STAGE2_NEEDS = ("steering_angle", "accel_y", "yaw_rate")
STAGE2_SPEED = ("wheel_speed_rl", "wheel_speed_rr")
# I_x: the roll mode is seen through the roll-rate gyro only (a_y has no roll term in eq 7),
# so without one I_x is not_run while C_alpha and I_z are still estimated.
IX_NEEDS = ("roll_rate",)

# What a road car's sensors can read: a value beyond is a decoding or mapping fault (a
# LAT_ACCEL decoded at -500 m/s^2), never driving, and never reaches the estimator
# (vdp.buffer.Aligner drops and counts it).  Wheel speeds and torques scale with the car.
ACCEL_MAX = 15.0  # m/s^2: 1.5 g, beyond any road tyre's grip
RATE_MAX = 2.0  # rad/s of yaw or roll: 115 deg/s, beyond a spin at parking speed
ROAD_WHEEL_MAX = math.radians(45.0)  # rad: no road car's front wheels turn further
SPEED_MAX = 100.0  # m/s (360 km/h), forwards or reversing
TORQUE_ACCEL = 15.0  # m/s^2: an axle torque beyond mass * wheel radius * this would lift the car off
BRAKE_PRESSURE = (-5e5, 3e7)  # Pa: -5 to 300 bar, a master cylinder's offset to beyond any ABS pump


def limits(vehicle) -> tuple[list[float], list[float]]:
    """Per channel index, the lowest and highest value a road car's bus can carry (SI), for
    ``vehicle`` (a vdp.profile.Vehicle: its wheel radius and mass scale wheel speeds and torques)."""
    r = vehicle.wheel_radius
    bound = {
        "steering_angle": ROAD_WHEEL_MAX,
        "accel_x": ACCEL_MAX,
        "accel_y": ACCEL_MAX,
        "yaw_rate": RATE_MAX,
        "roll_rate": RATE_MAX,
        "speed": SPEED_MAX,
        **dict.fromkeys(STATUS, 1.0),  # (a flag beyond 1 is a mapping fault: map it with active_when)
        "wheel_torque_front": vehicle.mass * r * TORQUE_ACCEL,
        "wheel_torque_rear": vehicle.mass * r * TORQUE_ACCEL,
    }
    for w in ("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr"):
        bound[w] = SPEED_MAX / r  # rad/s
    hi = [bound[n] for n in NAMES]
    return [-b for b in hi], hi
