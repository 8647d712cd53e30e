"""Estimates handed on: a CommonRoad vehicle-parameter file, CARLA vehicle physics, plain JSON or TOML.

Pure text out of (parameters, vehicle constants): the CLI (``vdp export``) and the API
(``/export``) write or serve it.  A parameter whose estimate is ``not_run``,
``not_identifiable`` or ``invalid`` is the prior, mostly the prior, or garbage, so it is
left out of the simulator formats (and named in ``skipped``); plain JSON and TOML carry
every one with its status and std.

The mass every format writes, and computes the axle loads and C_alpha per unit load with, is
the learnt one where the result has it learnt and valid (``vdp replay --mass``, ``[service]
mass = true``: the six were put on it, core.mass.scaled), else the profile's ``[vehicle] mass``;
each format says which (:func:`mass_of`).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, replace

from .core.params import BY_NAME, MASS, NAMES, PUBLISHED
from .core.result import CONVERGED, INVALID, NOT_IDENTIFIABLE, NOT_RUN, UNCERTAIN, finite
from .errors import ConfigError
from .text import clean, one_line, toml_str

FORMATS = {
    "commonroad": ("yaml", "application/yaml"),
    "carla": ("json", "application/json"),
    "json": ("json", "application/json"),
    "toml": ("toml", "application/toml"),
}
UNUSABLE = (NOT_RUN, INVALID, NOT_IDENTIFIABLE)  # the prior, garbage, or mostly the prior


@dataclass(frozen=True)
class Constants:
    """The known constants a simulator file needs beside the estimates (the profile's [vehicle])."""

    name: str
    mass: float
    wheelbase: float
    wheel_radius: float
    wheel_inertia: float  # per axle, both wheels
    track: float
    g: float = 9.8
    # l_f measured on axle scales ([vehicle] l_f): handed on where stage 1 did not estimate it
    l_f: float | None = None
    l_f_std: float | None = None

    @classmethod
    def of(cls, vehicle) -> Constants:
        v = vehicle
        l_f, sd = getattr(v, "l_f", None), getattr(v, "l_f_std", None)
        return cls(v.name, v.mass, v.wheelbase, v.wheel_radius, v.wheel_inertia, v.track, v.g, l_f, sd)

    @classmethod
    def from_dict(cls, d: dict) -> Constants:
        try:
            return cls(**{k: d[k] for k in cls.__dataclass_fields__ if k in d})
        except TypeError as exc:
            raise ConfigError(f"vehicle constants incomplete: {exc}") from None


def check_format(fmt: str) -> str:
    if fmt not in FORMATS:
        raise ConfigError(f"unknown export format '{fmt}'; use one of {', '.join(FORMATS)}")
    return fmt


MEASURED = "measured"  # the status of a value handed on from the profile, not estimated


def usable(params: dict, const: Constants | None = None) -> tuple[dict[str, dict], list[str]]:
    """(name -> estimate) of the parameters worth handing on, and the names left out.  An l_f
    stage 1 did not estimate is the profile's measured one where ``const`` has it (stage 2
    used that one too): a car without axle torques is otherwise exported without its CG."""
    keep, skipped = {}, []
    for name in NAMES:
        p = params.get(name) or {}
        if name == "l_f" and p.get("status", NOT_RUN) == NOT_RUN and const is not None and const.l_f is not None:
            sd = const.l_f_std if const.l_f_std is not None else 0.01 * const.l_f  # (as stage 2 takes it)
            keep[name] = {"value": const.l_f, "std": sd, "unit": "m", "status": MEASURED, "valid": True}
        elif p.get("value") is None or p.get("status", NOT_RUN) in UNUSABLE:
            skipped.append(name)
        else:
            keep[name] = p
    return keep, skipped


MASS_DESCRIPTION = "vehicle mass as driven (kerb weight, occupants, load)"


def mass_of(params: dict, const: Constants) -> tuple[Constants, dict]:
    """(the constants with the mass the file is made with, what says which): the result's learnt
    mass where it is valid (learnt from the data, its std within its usefulness threshold) or the
    six were scaled with it (core.mass.scaled's ``mass_source``: the axle loads and C_alpha per
    unit load then take the mass C_alpha was published with), else the profile's, with the reason
    the learnt one is not taken."""
    p = params.get(MASS)
    put = [
        (e.get("extra") or {}).get("mass_used")
        for n, e in params.items()
        if n != MASS and isinstance(e, dict) and (e.get("extra") or {}).get("mass_source") == "learnt"
    ]
    if isinstance(p, dict) and (p.get("valid") or put) and p.get("status") in (CONVERGED, UNCERTAIN):
        # the mass the six were scaled with (mode auto may take the learnt one in part), else the learnt
        v, sd = (put[0] if put and put[0] is not None else p.get("value")), p.get("std")
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0:
            said = {"source": "learnt", "value": float(v), "std": finite(sd), "status": p["status"]}
            return replace(const, mass=float(v)), {**said, "profile_mass": const.mass}
    if not isinstance(p, dict):
        why = "the result has no mass (made before vdp learnt it)"
    elif p.get("status", NOT_RUN) == NOT_RUN:
        why = 'the mass was not learnt (vdp replay --mass off, [service] mass = "off")'
    else:
        why = f"the learnt mass is not valid ({p.get('status')}): see its reason in the result"
    return const, {"source": "profile", "value": const.mass, "reason": why}


def _mass_line(said: dict) -> str:
    """A comment's words on the mass: learnt (its std and status) or the profile's, and why."""
    if said["source"] == "learnt":
        sd = f"+- {said['std']:.4g} kg" if said.get("std") is not None else "std unknown"
        return (
            f"learnt from the data ({sd}, {said['status']}; the profile's [vehicle] mass is {said['profile_mass']:g})"
        )
    return f"the profile's [vehicle] mass, a known constant: {said['reason']}"


# the constants a simulator file is computed from: each a positive number (a zero wheelbase
# divided by zero, a NaN mass was written as "m: nan", which YAML reads as a string)
POSITIVE = ("mass", "wheelbase", "wheel_radius", "wheel_inertia", "track", "g")
_AXLES = ("C_alpha_front", "C_alpha_front_std", "C_alpha_rear", "C_alpha_rear_std")


def _number(field: str, v, positive: bool = False) -> None:
    """Refuse ``v`` unless it is a finite number (and above 0 where ``positive``).  A NaN, an
    inf or a number in quotes comes only from a hand-edited or damaged result (vdp writes an
    unknown number as null): no format can carry it as a number, so it is refused, not written."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        said = json.dumps(clean(v))[:40] if isinstance(v, str) else type(v).__name__
        raise ConfigError(f"{field} is {said}, not a number: write it as a number (without quotes)")
    if not math.isfinite(v):
        null = ", or null where it is not known" if field.startswith("parameters.") else ""
        raise ConfigError(f"{field} is {v}: not a number a parameter file can hold; put the number there{null}")
    if positive and not v > 0:
        raise ConfigError(f"{field} is {v}: it must be above 0")


def check(params: dict, const: Constants) -> None:
    """Every number the export writes or computes with, refused with the field's name unless
    it is a finite number: before any text is made, so a bad one never leaves half a file."""
    for k in POSITIVE:
        _number(f"vehicle.{k}", getattr(const, k), positive=True)
    for k in ("l_f", "l_f_std"):
        if getattr(const, k) is not None:
            _number(f"vehicle.{k}", getattr(const, k), positive=True)
    for name in PUBLISHED:
        p = params.get(name)
        if p is None:
            continue
        if not isinstance(p, dict):
            raise ConfigError(f"parameters.{name} must be an object with value, std and status")
        for k in ("value", "std"):
            if p.get(k) is not None:
                _number(f"parameters.{name}.{k}", p[k])
        x = p.get("extra") or {}
        if not isinstance(x, dict):
            raise ConfigError(f"parameters.{name}.extra must be an object")
        for k in _AXLES:
            if x.get(k) is not None:
                _number(f"parameters.{name}.extra.{k}", x[k])


def render(fmt: str, params: dict, const: Constants, source: str = "") -> str:
    """The text of ``params`` (a result's ``parameters``) in format ``fmt``; a number that is
    not one (NaN, inf, text, a zero wheelbase) is a ConfigError naming its field."""
    check_format(fmt)
    check(params, const)
    const, said = mass_of(params, const)
    return {"commonroad": _commonroad, "carla": _carla, "json": _json, "toml": _toml}[fmt](params, const, source, said)


def _num(v: float) -> str:
    return repr(float(v))


def _axle_loads(const: Constants, l_f: float) -> tuple[float, float]:
    """Static axle loads [N]: the front axle carries the share l_r / L (moment balance)."""
    w = const.mass * const.g
    return w * (const.wheelbase - l_f) / const.wheelbase, w * l_f / const.wheelbase


def _about(p: dict) -> str:
    std = p.get("std")
    sd = f"+- {std:.4g}" if std is not None else "std unknown"
    valid = "" if p.get("valid", True) else ", NOT VALID (see its reason in the result)"
    unit = one_line(p.get("unit", ""))  # (in a comment: a newline in it would start a line of YAML)
    if p.get("status") == MEASURED:
        return f"{sd} {unit}, measured: the profile's [vehicle] l_f, not estimated"
    return f"{sd} {unit}, {one_line(p.get('status', '?'))}{valid}"


def not_valid(params: dict) -> list[str]:
    """The names of the parameters handed on (``usable``) whose estimate is not valid."""
    keep, _ = usable(params)
    return [n for n, p in keep.items() if not p.get("valid", False)]


def _commonroad(params: dict, const: Constants, source: str, said: dict) -> str:
    """The layout of the commonroad-vehicle-models parameter YAML (parameters_vehicleN.yaml):
    the same keys and units, only those vdp knows; load it over a base set."""
    keep, skipped = usable(params, const)
    lines = [
        f"# {one_line(const.name)}: vehicle parameters estimated by vdp"
        + (f" from {one_line(source)}" if source else ""),
        "# layout of commonroad-vehicle-models' parameters_vehicle<N>.yaml; merge over a base set",
        "# (keys vdp does not estimate are absent). Each estimate's 1-sigma and status in its comment.",
    ]
    if skipped:
        lines.append(f"# left out (not estimated from the data): {', '.join(skipped)}")
    lines += ["", f"# vehicle mass [kg]  ({one_line(_mass_line(said))})", f"m: {_num(const.mass)}"]
    if "l_f" in keep:
        l_f = keep["l_f"]["value"]
        lines += [
            "",
            f"# distance from center of gravity to front axle [m]  ({_about(keep['l_f'])})",
            f"a: {_num(l_f)}",
            "# distance from center of gravity to rear axle [m]  (wheelbase - a)",
            f"b: {_num(const.wheelbase - l_f)}",
        ]
    if "I_z" in keep:
        lines += [
            "",
            f"# moment of inertia in yaw [kg m^2]  ({_about(keep['I_z'])})",
            f"I_z: {_num(keep['I_z']['value'])}",
        ]
    if "I_x" in keep:
        lines += [
            "",
            f"# moment of inertia in roll [kg m^2]  ({_about(keep['I_x'])}; vdp's is of the whole car)",
            f"I_Phi_s: {_num(keep['I_x']['value'])}",
        ]
    if "h" in keep:
        h = keep["h"]["value"]
        lines += [
            "",
            f"# center of gravity height of total mass [m]  ({_about(keep['h'])})",
            f"h_cg: {_num(h)}",
            "# M_s center of gravity above ground [m]  (vdp does not split sprung mass: h_cg)",
            f"h_s: {_num(h)}",
        ]
    lines += [
        "",
        "# track width front and rear [m] (known constant)",
        f"T_f: {_num(const.track)}",
        f"T_r: {_num(const.track)}",
        "# effective wheel radius [m] (known constant)",
        f"R_w: {_num(const.wheel_radius)}",
        "# wheel inertia [kg m^2] (known constant, per wheel)",
        f"I_y_w: {_num(const.wheel_inertia / 2)}",
    ]
    tire = []
    if "C_K" in keep:
        # Pacejka's K_x / F_z at nominal load is vdp's C_K by definition (eq 14)
        tire += [
            f"  # longitudinal slip stiffness Kfx/Fz  ({_about(keep['C_K'])})",
            f"  p_kx1: {_num(keep['C_K']['value'])}",
        ]
    if "C_alpha" in keep and "l_f" in keep:
        # the single-track model uses C_S = -p_ky1 / p_dy1 per unit axle load: vdp's one
        # C_alpha per axle over the mean static axle load (m g / 2)
        c = keep["C_alpha"]
        c_s = c["value"] / (const.mass * const.g / 2)
        sd = f"+- {c['std'] / (const.mass * const.g / 2):.4g}" if c.get("std") is not None else "std unknown"
        tire += [
            f"  # lateral stiffness Kfy/Fznom [1/rad]: -C_alpha / (m g / 2)  ({sd}, {one_line(c.get('status'))})",
            f"  p_ky1: {_num(-c_s)}",
        ]
    if tire:
        lines += ["", "tire:", *tire]
    return "\n".join(lines) + "\n"


def _carla(params: dict, const: Constants, source: str, said: dict) -> str:
    """CARLA 0.9's VehiclePhysicsControl / WheelPhysicsControl field names and units (radius in
    cm), wheels front-left, front-right, rear-left, rear-right.  PhysX has no inertia fields:
    I_z and I_x go in the ``vdp`` block only."""
    keep, skipped = usable(params, const)
    out: dict = {"mass": const.mass}
    l_f = keep["l_f"]["value"] if "l_f" in keep else None
    if l_f is not None:
        # forward of the wheelbase midpoint, above the ground; CARLA 0.9 applies center_of_mass
        # as a nudge from the mesh's own centre, so subtract the blueprint's before applying
        out["center_of_mass"] = {
            "x": const.wheelbase / 2 - l_f,
            "y": 0.0,
            "z": keep["h"]["value"] if "h" in keep else 0.0,
        }
    wheels = []
    loads = _axle_loads(const, l_f) if l_f is not None else None
    for axle in (0, 0, 1, 1):
        w: dict = {"radius": const.wheel_radius * 100.0}
        if loads is not None:
            f_z = loads[axle] / 2  # per wheel
            if f_z <= 0:  # an l_f at or beyond an axle: no load on the other, no stiffness per load
                wheels.append(w)
                continue
            if "C_K" in keep:
                # PhysX: longitudinal stiffness [N per unit slip] per unit g = C_K F_z / g
                w["long_stiff_value"] = keep["C_K"]["value"] * f_z / const.g
            if "C_alpha" in keep:
                # cornering stiffness of one wheel per unit of its static load [1/rad]
                w["lat_stiff_value"] = keep["C_alpha"]["value"] / 2 / f_z
        wheels.append(w)
    out["wheels"] = wheels
    out["vdp"] = {
        "vehicle": clean(const.name),
        "source": clean(source),
        "note": "CARLA 0.9 (PhysX) fields; set them on carla.VehiclePhysicsControl / WheelPhysicsControl. "
        "center_of_mass is relative to the wheelbase midpoint on the ground; PhysX's load curve scales "
        "lat_stiff_value at the rest load, check it against your CARLA version.",
        "mass": said,
        "parameters": _plain(params)["parameters"],
        "skipped": skipped,
    }
    return json.dumps(out, indent=2, allow_nan=False) + "\n"


def _plain(params: dict, const: Constants | None = None, source: str = "", said: dict | None = None) -> dict:
    out: dict = {"parameters": {}}
    for name in PUBLISHED:
        p = params.get(name) or {}
        spec = BY_NAME.get(name)
        out["parameters"][name] = {
            "value": finite(p.get("value")),
            "std": finite(p.get("std")),
            "unit": p.get("unit", spec.unit if spec else "kg"),
            "status": p.get("status", NOT_RUN),
            "valid": bool(p.get("valid", False)),
            "description": spec.description if spec else MASS_DESCRIPTION,
        }
        if p.get("reason"):  # why it is not valid, or not learnt
            out["parameters"][name]["reason"] = p["reason"]
        x = p.get("extra") or {}
        for k in ("C_alpha_front", "C_alpha_front_std", "C_alpha_rear", "C_alpha_rear_std"):
            if x.get(k) is not None:  # C_alpha is the axles' mean: each axle as well
                out["parameters"][name][k] = finite(x[k])
    if const is not None:
        out["vehicle"] = {**asdict(const), "name": clean(const.name)}
        if said is not None:  # which mass vehicle.mass is: learnt, or the profile's
            out["vehicle"]["mass_source"] = said["source"]
    if source:
        out["source"] = clean(source)
    return out


def _json(params: dict, const: Constants, source: str, said: dict) -> str:
    return json.dumps(_plain(params, const, source, said), indent=2, allow_nan=False) + "\n"


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):  # (finite: check)
        return repr(float(v)) if isinstance(v, float) else str(v)
    return toml_str(v)  # a quote or a newline in a name escaped, not the file broken


def _toml(params: dict, const: Constants, source: str, said: dict) -> str:
    """Plain TOML; an unknown number is left out (TOML has no null)."""
    d = _plain(params, const, source, said)
    lines = [f"# vdp estimates of {one_line(const.name)}" + (f" from {one_line(source)}" if source else "")]
    lines += [f"# vehicle.mass: {one_line(_mass_line(said))}", ""]
    lines.append("[vehicle]")
    lines += [f"{k} = {_toml_value(v)}" for k, v in d["vehicle"].items() if v is not None]
    for name, p in d["parameters"].items():
        lines += ["", f"[parameters.{name}]"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in p.items() if v is not None]
    return "\n".join(lines) + "\n"
