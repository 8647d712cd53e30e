"""Vehicle profile: one TOML file that describes a vehicle to vdp.

It holds the vehicle's known constants, the priors of the unknown parameters,
and how each canonical channel is read from the car's DBC.  Truth values of
the unknowns never belong here: the simulator keeps those in its own truth.

Conversion of a decoded DBC signal value ``v`` to the canonical SI value::

    si = sign * factor(unit) * (v * scale + offset)    [/ wheel_radius for linear wheel speeds]
                                                        [/ steering_ratio for steering_wheel]

``sign`` may instead come from another signal of the same message
(``sign_signal``): a non-zero value there flips the sign.  A channel split into a
coarse signal and a finer one of the same message (Toyota's STEER_ANGLE in 1.5 deg
steps plus STEER_FRACTION in 0.1 deg steps) names the second as ``fine``: ``v`` is
then the sum of the two decoded values.

``[can] dbc`` is a path relative to the profile, or ``opendbc:NAME`` for a DBC of
the installed opendbc package (the ``opendbc`` extra): a file it ships, or one its
generator builds (``NAME`` ends in ``_generated``, e.g. Toyota's).  Generated DBCs,
and shipped ones that cantools cannot parse as they are, are written to vdp's cache
directory (:mod:`vdp.opendbc`) and the profile points there.  The units a profile may
name are in :mod:`vdp.units`.  docs/PROFILES.md describes every key.

The package: ``model`` (the types), ``load`` (the TOML read into them).
"""

from __future__ import annotations

from .load import _axle_torques, load_profile
from .model import (
    AXLE_PRIORS,
    PARAMETERS,
    ChannelMap,
    Composite,
    Drivetrain,
    MessageCheck,
    Prior,
    Profile,
    Term,
    Vehicle,
)

__all__ = [
    "AXLE_PRIORS",
    "PARAMETERS",
    "ChannelMap",
    "Composite",
    "Drivetrain",
    "MessageCheck",
    "Prior",
    "Profile",
    "Term",
    "Vehicle",
    "_axle_torques",
    "load_profile",
]
