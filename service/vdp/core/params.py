"""The six unknown parameters: names, units, stages and sane ranges."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ParamSpec:
    name: str
    unit: str
    stage: int
    lo: float  # sane range: an estimate outside it is invalid
    hi: float
    converged_rel: float  # std / |value| below which the estimate counts as converged
    description: str
    # std / |value| at or below which the number is worth using (the verdict: Estimate.valid);
    # the honest std (floor and model error included) must reach it
    useful_rel: float = 0.05
    # the model class's own error, relative (1 sigma): what no length of drive averages out
    floor_rel: float = 0.0


# useful_rel: issue 24's usefulness thresholds (what a vehicle model can use), not tuned.
# floor_rel: the bias that stays on vdp's own simulator however long the drive (the tuning set:
# paper x8 and x32 back to back, paper noise-free, small and suv; docs/decisions/0001-honest-std.md):
# h +0.42 %, l_f +0.14 %, C_K +0.61 %, C_alpha +0.79 % on x8, I_z +1.0 % noise-free, each taken
# as about one sigma.  A real car is further from the model: that part is the mismatch terms'.
SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("l_f", "m", 1, 0.3, 4.0, 0.007, "CG to front axle", useful_rel=0.02, floor_rel=0.002),
    ParamSpec("h", "m", 1, 0.1, 2.0, 0.024, "CG height", useful_rel=0.05, floor_rel=0.005),
    ParamSpec(
        "C_K", "1", 1, 1.0, 60.0, 0.015, "longitudinal slip stiffness per unit load (eq 14)", 0.05, floor_rel=0.007
    ),
    ParamSpec("C_alpha", "N/rad", 2, 5.0e3, 5.0e5, 0.015, "cornering stiffness per axle (eq 11b)", 0.05, 0.01),
    ParamSpec("I_z", "kg*m^2", 2, 200.0, 2.0e4, 0.025, "yaw moment of inertia", useful_rel=0.05, floor_rel=0.015),
    ParamSpec("I_x", "kg*m^2", 2, 100.0, 2.0e4, 0.05, "roll moment of inertia", useful_rel=0.10, floor_rel=0.03),
)

BY_NAME: dict[str, ParamSpec] = {s.name: s for s in SPECS}
NAMES: tuple[str, ...] = tuple(s.name for s in SPECS)
STAGE1: tuple[str, ...] = ("l_f", "h", "C_K")
STAGE2: tuple[str, ...] = ("C_alpha", "I_z", "I_x")
# what a result publishes: the six, and the mass (core.mass) after them, learnt where mass
# estimation is on and "not_run" with the reason where it is off
MASS = "mass"
PUBLISHED: tuple[str, ...] = (*NAMES, MASS)
