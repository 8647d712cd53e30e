"""Checks of values against what any car can produce, and of the profile against itself."""

from __future__ import annotations

import logging
from collections.abc import Mapping

from .. import channels as ch
from ..profile import Profile
from .report import DEPENDS, Report

log = logging.getLogger(__name__)


BOUNDS_SHARE = 0.01  # values beyond a car's limits: above this share of a channel's, its parameters are doubted


def _subject(name: str) -> str:
    """The DEPENDS key of a channel: the four wheel speeds are one, both axle torques one."""
    for head in ("wheel_speed", "wheel_torque"):
        if name.startswith(head):
            return head
    return name


def check_bounds(refused: Mapping[int, list], decoded: list[int] | None, report: Report) -> Report:
    """A finding per channel whose values went beyond what a road car's bus can carry
    (channels.limits; the aligner dropped them: ``refused``, channel -> [count, lowest, highest]).
    ``decoded``: values decoded per channel (DecodeStats.samples), for the share."""
    for c, (n, lo, hi) in sorted(refused.items()):
        name = ch.NAMES[c]
        of = decoded[c] if decoded is not None and c < len(decoded) and decoded[c] >= n else None
        share = n / of if of else 1.0
        if any(f.subject == name for f in report.findings):  # a finding says what is wrong with it already
            report.measured[f"{name}_beyond_limits"] = n
            continue
        unit = ch.UNITS[name]
        extra = ""
        if name.startswith("wheel_torque"):
            extra = " (the drive torque, or the brake pressure times brake_gain, that make it)"
        elif name in ch.STATUS:  # a flag is 0 or 1: an enum maps through active_when
            extra = " (a status flag: map a state or gear signal with active_when = [the raw values that mean on])"
        report.add(
            f"{name}_bounds",
            name,
            f"{name}{extra}: {n} value{'s' if n > 1 else ''}"
            + (f" of {of} ({100 * share:.0f} %)" if of else "")
            + f" beyond what a car can read (seen {lo:.4g} to {hi:.4g} {unit}), kept from the estimator: "
            f"check the signal's unit, scale, offset and layout in the profile and the DBC",
            DEPENDS.get(_subject(name), ("I_x",)) if share > BOUNDS_SHARE and name not in ch.STATUS else (),
        )
    return report


def check_brake_pressure(profile: Profile, dec, report: Report) -> Report:
    """A finding when brake-pressure values went beyond what a brake system holds (or the profile's
    plausible range, which the loader narrows to channels.BRAKE_PRESSURE): the decoder dropped them."""
    bp = getattr(profile, "sources", {}).get("brake_pressure")
    if bp is None or getattr(bp, "plausible", None) is None:
        return report
    label = f"{bp.message}.{bp.signal}: implausible"
    key = next((k for k in dec.stats.invalid_samples if k[1] == label), None)  # one per axle: the same values
    if key is None:
        return report
    n, (lo, hi) = dec.stats.invalid_samples[key], dec.stats.invalid_range[key]
    good = sum(p.good for p in dec._plans.values() if p.name == bp.message)
    share = n / good if good else 1.0
    a, b = bp.plausible
    report.add(
        "brake_pressure_bounds",
        "brake_pressure",
        f"brake_pressure: {n} value{'s' if n > 1 else ''} ({100 * share:.0f} % of {bp.message}'s frames) outside "
        f"{a / 1e5:g} to {b / 1e5:g} bar (seen {lo / 1e5:.4g} to {hi / 1e5:.4g} bar), kept from the estimator: "
        f"check the signal's unit ({bp.unit}), scale and offset",
        DEPENDS["wheel_torque"] if share > BOUNDS_SHARE else (),
    )
    return report


def check_profile(profile: Profile, report: Report | None = None) -> Report:
    """The checks that need no data: priors against geometry."""
    rep = report or Report()
    veh, pri = profile.vehicle, profile.priors
    lf = pri["l_f"].value
    if not 0.0 < lf < veh.wheelbase:
        rep.add(
            "prior_l_f",
            "priors.l_f",
            f"the l_f prior ({lf:g} m) is not inside the wheelbase ({veh.wheelbase:g} m): "
            f"l_f is the distance from the front axle to the centre of gravity; set it between 0 and the wheelbase "
            f"(about {0.45 * veh.wheelbase:.2f} m for a front-engined car)",
            DEPENDS["l_f"],
        )
    h = pri["h"].value
    if h > veh.track:
        rep.add(
            "prior_h",
            "priors.h",
            f"the h prior ({h:g} m) is above the track ({veh.track:g} m): no road car's centre of gravity is that high",
            ("h",),
        )
    return rep
