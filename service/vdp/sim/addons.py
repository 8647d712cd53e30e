"""A production car's profile plus vdp's add-on sensors, for simulating both stages on its layout.

A production bus lacks per-axle torque, a roll-rate gyro and a ground speed
(docs/PROFILES.md).  ``with_addons`` adds vdp's own messages for them
(dbc/vdp.dbc: WHEEL_TORQUE, IMU_RATES, GNSS_VELOCITY) as a second DBC of the
same bus, as a user would in the profile with ``dbc = [car, "vdp.dbc"]``.
The decoder refuses a frame id that the car's DBC already uses.

``CAR_TRUTH`` holds plausible parameters for the shipped cars (not Table 6,
whose I_x = 4175 kg m^2 no car of this size has), each off its profile's prior
so that the filters have to move.  Like :mod:`.truth`, it is for the simulator.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..profile import ChannelMap, MessageCheck, Profile

VDP_DBC = Path(__file__).resolve().parents[3] / "dbc" / "vdp.dbc"

ADDONS = {  # channel: (vdp.dbc message, signal, unit)
    "wheel_torque_front": ("WHEEL_TORQUE", "TORQUE_FRONT", "Nm"),
    "wheel_torque_rear": ("WHEEL_TORQUE", "TORQUE_REAR", "Nm"),
    "roll_rate": ("IMU_RATES", "ROLL_RATE", "deg/s"),
    "speed": ("GNSS_VELOCITY", "GNSS_SPEED", "m/s"),
}

CAR_TRUTH = {
    "toyota_rav4": {"l_f": 1.2, "h": 0.62, "C_K": 10.0, "C_alpha": 95000.0, "I_z": 2900.0, "I_x": 650.0},
    "vw_golf_mk7": {"l_f": 1.1, "h": 0.53, "C_K": 10.0, "C_alpha": 85000.0, "I_z": 2400.0, "I_x": 520.0},
    "hyundai_elantra_2017": {"l_f": 1.12, "h": 0.52, "C_K": 10.0, "C_alpha": 80000.0, "I_z": 2200.0, "I_x": 480.0},
}


def with_addons(prof: Profile, dbc: Path = VDP_DBC) -> Profile:
    """``prof`` with the add-on channels mapped to ``dbc``'s messages (counters and checksums checked)."""
    chans = dict(prof.channels)
    for ch, (msg, sig, unit) in ADDONS.items():
        chans[ch] = ChannelMap(ch, msg, sig, unit, where=f"{prof.path} [channels.{ch}] (add-on)")
    checks = dict(prof.checks)
    for name in ("WHEEL_TORQUE", "IMU_RATES"):
        checks[name] = MessageCheck(name, counter="COUNTER", checksum="CHECKSUM")
    # the add-on measures each axle's torque: the car's own drive/brake sources are not needed,
    # and the simulator's driver keeps its default split (both axles drive and brake)
    return dataclasses.replace(
        prof,
        channels=chans,
        checks=checks,
        extra_dbcs=prof.extra_dbcs + (dbc,),
        composites={},
        sources={},
        drivetrain=None,
    )
