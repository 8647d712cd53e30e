"""vdp export: a replay's result handed to a simulator or a script.

vdp export out.json --format commonroad --out car.yaml     # commonroad-vehicle-models parameter layout
vdp export out.json --format carla --out car.carla.json    # CARLA 0.9 vehicle physics fields
vdp export out.json --format toml --out car.toml           # plain, with units, stds and status
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ..errors import ConfigError
from ..outfile import write_text
from .paths import check_apart, check_output, profile_inputs


def add_parser(sub):
    from ..export import FORMATS

    p = sub.add_parser(
        "export",
        help="write a result's parameters for CommonRoad, CARLA, or as plain JSON/TOML",
        description="Convert the JSON result of `vdp replay --json` into a simulator's parameter file. "
        "Parameters the drive did not give (not_run, not_identifiable: the prior's numbers, or invalid) are left "
        "out of the simulator formats.",
    )
    p.add_argument("result", type=Path, help="a result JSON from vdp replay --json")
    p.add_argument("--format", required=True, metavar="F", help=f"one of {', '.join(FORMATS)}")
    p.add_argument("--out", required=True, type=Path, help="file to write ('-' for standard output)")
    p.add_argument(
        "--profile", help="vehicle profile for the known constants (default: the one the result names, else paper)"
    )
    return p


def _load(path: Path) -> dict:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such result file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path}: not a result JSON: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("parameters"), dict):
        raise ConfigError(f"{path}: has no 'parameters' object; is it the JSON of vdp replay --json?")
    if not all(isinstance(p, dict) for p in data["parameters"].values()):
        # the truth file beside a replay's result has plain numbers: {"l_f": 1.4, ...}
        raise ConfigError(
            f"{path}: its parameters are plain numbers, not estimates (a truth file from vdp simulate?); "
            "export the JSON of vdp replay --json"
        )
    return data


def constants(data: dict, profile: str | None):
    """(the known constants, the profile they came from, or None: the result's own)."""
    from ..export import Constants
    from ..profile import load_profile
    from .replay import default_profile

    if profile is None and isinstance(data.get("vehicle"), dict):
        return Constants.from_dict(data["vehicle"]), None
    prof = load_profile(profile or default_profile())
    return Constants.of(prof.vehicle), prof


def run(args) -> int:
    from ..export import check_format, mass_of, not_valid, render, usable

    # everything that can be refused is refused before any work
    check_format(args.format)
    to_stdout = str(args.out) == "-"
    if not to_stdout:
        check_output(args.out, "--out")
    data = _load(args.result)
    const, prof = constants(data, args.profile)
    if not to_stdout:
        check_apart({"--out": args.out}, {"the result": args.result, **(profile_inputs(prof) if prof else {})})
    try:
        text = render(args.format, data["parameters"], const, source=str(args.result))
    except ConfigError as exc:  # a number that is not one: name the file, and where the constants came from
        fix = "; or give --profile PROFILE to take the profile's constants" if str(exc).startswith("vehicle.") else ""
        raise ConfigError(f"{args.result}: {exc}{fix}") from None
    if to_stdout:
        sys.stdout.write(text)
    else:
        write_text(args.out, text)
    keep, skipped = usable(data["parameters"], const)
    _, said = mass_of(data["parameters"], const)
    if said["source"] == "learnt":  # (the file's mass, axle loads and stiffness per load are of it)
        print(
            f"vdp export: the mass is the one learnt from the data, {said['value']:.0f} kg "
            f"(the profile's [vehicle] mass is {said['profile_mass']:g} kg)",
            file=sys.stderr,
        )
    if keep.get("l_f", {}).get("status") == "measured" and args.format in ("commonroad", "carla"):
        print(f"vdp export: l_f is the profile's measured {const.l_f:g} m (stage 1 did not run)", file=sys.stderr)
    if skipped and args.format in ("commonroad", "carla"):
        print(
            f"vdp export: left out (not estimated from the data, or mostly the prior): {', '.join(skipped)}",
            file=sys.stderr,
        )
    bad = not_valid(data["parameters"])
    if bad and args.format in ("commonroad", "carla"):
        # a simulator takes the number as it is: say which ones the result does not vouch for
        print(
            f"vdp export: exported but not valid (the data or the model do not support them; each "
            f"reason is in the result): {', '.join(bad)}",
            file=sys.stderr,
        )
    if not to_stdout:
        print(f"wrote {args.out} ({args.format})")
    return 0
