"""A profile's ``[vehicle]`` and ``[priors]`` tables: the car's known constants (and its K&C steer,
core.steer) and the priors of the unknowns, checked against what a road vehicle can be."""

from __future__ import annotations

import math
from typing import Any

from ..errors import ProfileError
from .model import AXLE_PRIORS, PARAMETERS, Prior, Vehicle
from .numbers import _num

_VEHICLE_KEYS = {
    "name": str,
    "mass": float,
    "wheelbase": float,
    "wheel_radius": float,
    "wheel_inertia": float,
    "roll_stiffness": float,
    "roll_damping": float,
    "steering_ratio": float,
    "track": float,
    "g": float,
}


# Plausible bounds of a road vehicle's known constants [SI]: a typo (or a unit slip) is named
# here instead of making the filters diverge.
_VEHICLE_RANGE = {
    "mass": (50.0, 100000.0),
    "wheelbase": (0.3, 30.0),
    "wheel_radius": (0.05, 3.0),
    "wheel_inertia": (1e-3, 1e4),
    "roll_stiffness": (1.0, 1e9),
    "roll_damping": (1e-3, 1e8),
    "steering_ratio": (1.0, 100.0),
    "track": (0.3, 5.0),
    "g": (1.0, 30.0),
}


# K&C steer (Vehicle.compliance_steer, roll_steer_f/_r), as a K&C rig reports it: key -> (field,
# to SI, plausible range in the profile's unit).  Compact cars: about 0.1-0.3 deg/kN and 0.05-0.15
# deg/deg; beyond these a unit slip (rad for deg, N for kN) is the likelier cause.
_KC = {
    "compliance_steer_deg_per_kN": ("compliance_steer", math.pi / 180.0 / 1000.0, (0.0, 2.0)),
    "roll_steer_front": ("roll_steer_f", 1.0, (-0.5, 0.5)),
    "roll_steer_rear": ("roll_steer_r", 1.0, (-0.5, 0.5)),
}


def _kc(where: str, raw: dict[str, Any]) -> dict[str, float]:
    out = {}
    for key, (dst, si, (lo, hi)) in _KC.items():
        if key in raw:
            v = _num(where, key, raw[key])
            if not lo <= v <= hi:
                unit = "per kN of the front axle's lateral force" if si != 1.0 else "per deg of body roll"
                raise ProfileError(
                    f"{where}: '{key}' = {v:g} is not plausible (expected {lo:g} to {hi:g} deg of "
                    f"road-wheel angle {unit}, as a K&C rig reports it)"
                )
            out[dst] = v * si
    return out


def _vehicle(where: str, raw: dict[str, Any]) -> Vehicle:
    if not isinstance(raw, dict):
        raise ProfileError(
            f"{where} [vehicle]: missing table; add a [vehicle] section with "
            f"{', '.join(k for k in _VEHICLE_KEYS if k != 'g')}"
        )
    optional = {"l_f", "l_f_std"}  # a measured l_f (axle scales) and its 1-sigma
    unknown = set(raw) - set(_VEHICLE_KEYS) - {"roll_stiffness_per_deg", "roll_damping_per_deg"} - optional - set(_KC)
    if unknown:
        raise ProfileError(
            f"{where} [vehicle]: unknown key(s) {sorted(unknown)}; "
            f"allowed: {sorted(set(_VEHICLE_KEYS) | optional | set(_KC))}"
        )
    vals: dict[str, Any] = {}
    # Table 6 gives k_phi and c_phi per degree; accept that form and convert (NOTES item 5).
    for src, dst in (("roll_stiffness_per_deg", "roll_stiffness"), ("roll_damping_per_deg", "roll_damping")):
        if src in raw:
            if dst in raw:
                raise ProfileError(f"{where} [vehicle]: give '{dst}' or '{src}', not both")
            vals[dst] = _num(f"{where} [vehicle]", src, raw[src]) * 180.0 / math.pi
    for key, typ in _VEHICLE_KEYS.items():
        if key in vals:
            continue
        if key not in raw:
            if key == "g":
                continue
            raise ProfileError(f"{where} [vehicle]: missing '{key}'")
        if typ is str:
            if not isinstance(raw[key], str) or not raw[key]:
                raise ProfileError(f"{where} [vehicle]: 'name' must be a non-empty string")
            vals[key] = raw[key]
        else:
            v = _num(f"{where} [vehicle]", key, raw[key])
            if v <= 0:
                raise ProfileError(f"{where} [vehicle]: '{key}' must be positive, got {v}")
            vals[key] = v
    for key, (lo, hi) in _VEHICLE_RANGE.items():
        v = vals.get(key)
        if v is not None and not lo <= v <= hi:
            src = f"{key}_per_deg" if key in ("roll_stiffness", "roll_damping") and key not in raw else key
            shown = v * math.pi / 180.0 if src != key else v
            raise ProfileError(
                f"{where} [vehicle]: '{src}' = {shown:g} is not plausible for a road vehicle "
                f"(expected {lo:g} to {hi:g} in SI units{', per radian' if src != key else ''})"
            )
    for key in sorted(optional & set(raw)):
        v = _num(f"{where} [vehicle]", key, raw[key])
        if v <= 0:
            raise ProfileError(f"{where} [vehicle]: '{key}' must be positive, got {v}")
        vals[key] = v
    vals.update(_kc(f"{where} [vehicle]", raw))
    if "l_f_std" in vals and "l_f" not in vals:
        raise ProfileError(f"{where} [vehicle]: 'l_f_std' needs 'l_f' (the measured CG to front axle distance)")
    if "l_f" in vals and not vals["l_f"] < vals["wheelbase"]:
        raise ProfileError(
            f"{where} [vehicle]: 'l_f' = {vals['l_f']} m must be less than the wheelbase ({vals['wheelbase']} m)"
        )
    return Vehicle(**vals)


def _priors(where: str, raw: Any) -> dict[str, Prior]:
    if not isinstance(raw, dict):
        raise ProfileError(f"{where} [priors]: missing table; give value and std for {', '.join(PARAMETERS)}")
    out = {}
    for name in PARAMETERS + tuple(n for n in AXLE_PRIORS if n in raw):
        entry = raw.get(name)
        w = f"{where} [priors.{name}]"
        if not isinstance(entry, dict) or "value" not in entry or "std" not in entry:
            raise ProfileError(f"{w}: missing; write {name} = {{ value = ..., std = ... }}")
        extra_keys = set(entry) - {"value", "std"}
        if extra_keys:
            raise ProfileError(f"{w}: unknown key(s) {sorted(extra_keys)}; allowed: std, value")
        value, std = _num(w, "value", entry["value"]), _num(w, "std", entry["std"])
        if value <= 0 or std <= 0:
            raise ProfileError(f"{w}: value and std must be positive, got value={value}, std={std}")
        out[name] = Prior(value, std)
    extra = set(raw) - set(PARAMETERS) - set(AXLE_PRIORS)
    if extra:
        raise ProfileError(
            f"{where} [priors]: unknown parameter(s) {sorted(extra)}; known: {', '.join(PARAMETERS)} "
            f"(and optionally {' and '.join(AXLE_PRIORS)}, per axle)"
        )
    axles = [n for n in AXLE_PRIORS if n in raw]
    if axles and len(axles) != len(AXLE_PRIORS):
        raise ProfileError(
            f"{where} [priors]: {axles[0]} needs {' and '.join(n for n in AXLE_PRIORS if n not in axles)} "
            "too (per-axle cornering stiffness priors come in pairs); or remove it to start both axles at C_alpha"
        )
    return out
