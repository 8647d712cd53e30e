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


SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("l_f", "m", 1, 0.3, 4.0, 0.007, "CG to front axle"),
    ParamSpec("h", "m", 1, 0.1, 2.0, 0.024, "CG height"),
    ParamSpec("C_K", "1", 1, 1.0, 60.0, 0.015, "longitudinal slip stiffness per unit load (eq 14)"),
    ParamSpec("C_alpha", "N/rad", 2, 5.0e3, 5.0e5, 0.015, "cornering stiffness per axle (eq 11b)"),
    ParamSpec("I_z", "kg*m^2", 2, 200.0, 2.0e4, 0.025, "yaw moment of inertia"),
    ParamSpec("I_x", "kg*m^2", 2, 100.0, 2.0e4, 0.05, "roll moment of inertia"),
)

BY_NAME: dict[str, ParamSpec] = {s.name: s for s in SPECS}
NAMES: tuple[str, ...] = tuple(s.name for s in SPECS)
STAGE1: tuple[str, ...] = ("l_f", "h", "C_K")
STAGE2: tuple[str, ...] = ("C_alpha", "I_z", "I_x")
