"""Profile self-check: does the profile read this car's bus the way the physics says it must?

A wrong sign, unit or steering flag gives "converged" estimates with tight stds that
are wrong (a_x flipped: l_f +65 %; the steering-wheel angle read as the road-wheel
angle: C_alpha -61 %; wheel speeds /3.6: l_f +90 %).  Each of these breaks a relation
that holds on any car, whatever its parameters:

- ``a_y = v * r`` in a steady turn (no sideslip change), and its sign;
- ``a_x = dv/dt`` (eq 1), and its sign;
- the wheel speeds times the wheel radius equal the ground speed (a few % of slip);
- the steering angle and the yaw rate have the same sign (ISO 8855: both positive left);
- ``delta = L * r / v`` within an understeer margin at moderate a_y (the kinematic
  bicycle): a road-wheel angle 15x too large or small is the steering-wheel flag;
- ``(T_f + T_r) / r = (m + 2 J / r^2) * a_x`` plus road loads (eq 1-2, both axles'
  wheel inertia), fitted for ``m``;
- the l_f prior lies inside the wheelbase.

:func:`check_samples` takes aligned samples (arrays); :func:`check_log` decodes the
first minutes of a log through the profile first.  Each mismatch is a :class:`Finding`
naming the channel (or profile key), the likely fix and the parameters that rest on it,
which :func:`mark_invalid` then reports as not valid.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from . import channels as ch
from .core.params import MASS, STAGE2
from .core.result import NOT_RUN, Estimate
from .errors import ProfileError
from .profile import PARAMETERS, Profile

log = logging.getLogger(__name__)

# Stage 2 takes stage 1's l_f, h and C_K as known: a fault under stage 1 spoils both.
DEPENDS: dict[str, tuple[str, ...]] = {
    "wheel_speed": PARAMETERS,
    "wheel_torque": PARAMETERS,
    "accel_x": PARAMETERS,
    "speed": PARAMETERS,
    "mass": PARAMETERS,
    "l_f": PARAMETERS,
    "steering_angle": STAGE2,
    "accel_y": STAGE2,
    "yaw_rate": STAGE2,
}
TICK = 0.02  # s between aligned samples
CHECK_SECONDS = 300.0  # of bus time read from the start of a log
MIN_SAMPLES = 50  # samples a relation needs before it is judged (1 s at 50 Hz)
KNOWN_FACTORS = {  # a ratio near one of these names the unit mistake
    3.6: "km/h read as m/s",
    1 / 3.6: "m/s read as km/h",
    2.23694: "mph read as m/s",
    1 / 2.23694: "m/s read as mph",
    1.609344: "km/h read as mph",
    1 / 1.609344: "mph read as km/h",
    9.80665: "g read as m/s^2",
    1 / 9.80665: "m/s^2 read as g",
    180 / math.pi: "deg read as rad",
    math.pi / 180: "rad read as deg",
}


@dataclass(frozen=True)
class Finding:
    check: str  # e.g. "accel_x_sign"
    subject: str  # the channel or profile key at fault: "accel_x", "vehicle.mass", "priors.l_f"
    message: str  # one line, with the likely fix
    params: tuple[str, ...]  # parameters that rest on it: not reported valid

    def as_dict(self) -> dict:
        return {"check": self.check, "subject": self.subject, "message": self.message, "params": list(self.params)}


@dataclass
class Report:
    findings: list[Finding] = field(default_factory=list)
    measured: dict[str, float] = field(default_factory=dict)  # the figures each check found
    skipped: dict[str, str] = field(default_factory=dict)  # check -> why it could not be judged
    seconds: float = 0.0  # bus time looked at

    def add(self, check: str, subject: str, message: str, params: tuple[str, ...]) -> None:
        self.findings.append(Finding(check, subject, message, params))

    @property
    def invalid(self) -> dict[str, str]:
        """Parameter -> why it is not valid (the first finding that concerns it)."""
        out: dict[str, str] = {}
        for f in self.findings:
            for p in f.params:
                out.setdefault(p, f"profile check: {f.message}")
        return out

    def as_dict(self) -> dict:
        return {
            "findings": [f.as_dict() for f in self.findings],
            "measured": {k: round(v, 4) for k, v in self.measured.items()},
            "skipped": dict(self.skipped),
            "seconds": round(self.seconds, 1),
        }


def mark_invalid(params: Mapping[str, Estimate], report: Report) -> dict[str, Estimate]:
    """The estimates with ``valid = False`` and the ``reason`` on every parameter a finding concerns;
    a learnt mass (core.mass) where a finding concerns the channels it rests on.  A valid learnt mass
    that the six are scaled with answers the finding on the profile's mass: that one marks nothing."""
    out = dict(params)
    m = out.get(MASS)
    if m is not None and m.status != NOT_RUN:
        why = next((f.message for f in report.findings if _under_mass(f)), None)
        if why is not None:
            out[MASS] = dataclasses.replace(m, valid=False, reason=f"profile check: {why}")
    findings = report.findings
    if _mass_learnt(out):
        findings = [f for f in findings if f.subject != "vehicle.mass"]
    for name, why in Report(findings).invalid.items():
        e = out.get(name)
        if e is not None:
            out[name] = dataclasses.replace(e, valid=False, reason=why)
    return out


def _mass_learnt(params: Mapping[str, Estimate]) -> bool:
    """A valid learnt mass that the six are scaled with (core.mass.scaled marks them ``mass_used``)."""
    m = params.get(MASS)
    used = any("mass_used" in (e.extra or {}) for n, e in params.items() if n != MASS)
    return m is not None and m.status != NOT_RUN and m.valid and used


def _under_mass(f: Finding) -> bool:
    """A finding on a channel the learnt mass rests on: the torques, a_x and the speeds, which
    stage 1 rests on too (C_K among its parameters).  Not the profile's mass (the learnt one
    replaces it) nor a prior (the mass takes none from the geometry)."""
    return "C_K" in f.params and not f.subject.startswith(("vehicle.", "priors."))


def _factor_name(ratio: float) -> str | None:
    for f, name in KNOWN_FACTORS.items():
        if abs(ratio / f - 1.0) < 0.08:
            return name
    return None


def _smooth(x: np.ndarray, n: int) -> np.ndarray:
    if len(x) < n or n < 2:
        return x
    k = np.ones(n) / n
    return np.convolve(x, k, mode="same")


REVERSE_MAX = 4.0  # m/s: no car reverses faster; a run beyond this went forwards


def _directions(v: np.ndarray, dv: np.ndarray, ax: np.ndarray, ok: np.ndarray, win: int) -> np.ndarray | str | None:
    """With wheel speeds that carry no direction, a reversing run's d|v|/dt is -a_x: per sample
    -1 in the runs (between stops) that went the other way than the fast ones, +1 elsewhere.
    None where no run disagrees (or the speeds are signed); "ambiguous" where runs disagree but
    none was fast enough to be surely forwards."""
    if not np.any(np.isfinite(v)) or np.nanmin(v) < -0.1:
        return None  # signed: reversing shows as a negative speed, and dv/dt keeps its sign
    moving = np.nan_to_num(_smooth(v, win)) > 0.5
    edges = np.flatnonzero(np.diff(np.concatenate(([0], moving.astype(np.int8), [0]))))
    runs = []  # (start, end, correlation, top speed)
    for a, b in zip(edges[::2], edges[1::2]):
        m = ok[a:b]
        if m.sum() < 10 or not (np.std(dv[a:b][m]) > 0 and np.std(ax[a:b][m]) > 0):
            continue
        runs.append((a, b, float(np.corrcoef(dv[a:b][m], ax[a:b][m])[0, 1]), float(np.nanmax(v[a:b]))))
    if not any(r[2] > 0.3 for r in runs) or not any(r[2] < -0.3 for r in runs):
        return None
    sure = [r for r in runs if abs(r[2]) > 0.3]
    top = max(sure, key=lambda r: r[3])  # the fastest run went forwards, if any was fast
    if top[3] < REVERSE_MAX:
        return "ambiguous"
    flip = np.ones(len(v))
    for a, b, rho, _ in sure:
        if rho * top[2] < 0:
            flip[a:b] = -1.0
    return flip


def _ax_per_dv_dt(
    v: np.ndarray, ax: np.ndarray, t: np.ndarray, win: int, min_n: int, note: dict | None = None
) -> tuple[float, float] | None:
    """(a_x per dv/dt of the speed ``v``, their correlation), or None where the drive has too little
    acceleration or braking to say.  Both sides are noisy (dv/dt of a quantised speed too), so a
    least-squares slope would be biased low: the ratio of the spreads with the correlation's sign
    (reduced major axis); means removed, for the road's grade and the sensor's offset.  ``ax``
    smoothed as ``v`` is, over ``win`` samples.  Runs reversed with speeds that carry no direction
    count with dv/dt turned round (:func:`_directions`); ``note`` gets "reversing_s" (samples) or
    "ambiguous"."""
    dv = np.gradient(_smooth(v, win), t)
    ok = np.isfinite(dv) & np.isfinite(ax) & (v > 1.0)
    ok[:win] = ok[-win:] = False
    flip = _directions(v, dv, ax, ok, win)
    if isinstance(flip, str):
        if note is not None:
            note["ambiguous"] = True
        return None
    if flip is not None:
        dv = dv * flip
        if note is not None:
            note["reversing_s"] = int(((flip < 0) & ok).sum())
    strong = ok & (np.abs(dv) > 0.3)
    if strong.sum() < min_n or not np.std(dv[ok]) > 0.2:
        return None
    rho = float(np.corrcoef(dv[ok], ax[ok])[0, 1])
    return math.copysign(float(np.std(ax[ok]) / np.std(dv[ok])), rho), rho


def _mean_of(a: np.ndarray) -> np.ndarray:
    """The mean over the rows of ``a`` of the finite values, NaN where there is none (np.nanmean
    without its "Mean of empty slice" warning, which reached the user's terminal)."""
    n = np.isfinite(a).sum(axis=0)
    return np.where(n > 0, np.nansum(a, axis=0) / np.maximum(n, 1), np.nan)


def _fit(x: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of y = k x through the origin."""
    d = float(np.dot(x, x))
    return float(np.dot(x, y) / d) if d > 0 else math.nan


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


def check_samples(profile: Profile, t: np.ndarray, y: np.ndarray, report: Report | None = None) -> Report:
    """Check the profile against aligned samples: ``y[i, channel index]`` in SI (NaN where missing)."""
    rep = check_profile(profile, report)
    veh = profile.vehicle
    have = set(profile.channels) | set(getattr(profile, "composites", {}))
    n = len(t)
    rep.seconds = float(t[-1] - t[0]) if n > 1 else 0.0
    if n < MIN_SAMPLES:
        rep.skipped["all"] = f"only {n} aligned samples ({rep.seconds:.1f} s): too little data to check the profile"
        return rep
    dt = float(np.median(np.diff(t))) if n > 1 else TICK
    win = max(int(round(0.5 / max(dt, 1e-3))), 1)  # 0.5 s smoothing for derivatives
    min_n = max(int(MIN_SAMPLES * TICK / max(dt, 1e-3)), 10)  # 1 s of data, whatever the rate
    wheels = [c for c in ("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr") if c in have]
    v_wheel = None
    if wheels:
        v_wheel = _mean_of(np.stack([y[:, ch.INDEX[c]] for c in wheels])) * veh.wheel_radius
    v_ref = y[:, ch.SPEED] if "speed" in have else None

    # 1. wheel speeds against the ground speed
    if v_wheel is not None and v_ref is not None:
        ok = np.isfinite(v_wheel) & np.isfinite(v_ref) & (v_ref > 3.0)
        if ok.sum() >= min_n:
            ratio = float(np.median(v_wheel[ok] / v_ref[ok]))
            rep.measured["wheel_speed_scale"] = ratio
            if not 0.94 < ratio < 1.06:  # slip and tyre growth stay within a few per cent
                # which of the two is wrong: the one a_x (dv/dt) disagrees with
                ax = _smooth(y[:, ch.AX], win) if "accel_x" in have else None
                fits = {
                    name: k is not None and abs(k[1]) >= 0.5 and 0.8 < k[0] < 1.25
                    for name, k in (
                        ("wheels", None if ax is None else _ax_per_dv_dt(v_wheel, ax, t, win, min_n)),
                        ("ground", None if ax is None else _ax_per_dv_dt(v_ref, ax, t, win, min_n)),
                    )
                }
                if fits["wheels"] and not fits["ground"]:
                    why = _factor_name(1.0 / ratio)
                    rep.add(
                        "speed_scale",
                        "speed",
                        f"the ground speed comes out {1.0 / ratio:.3g}x the wheel speeds times wheel_radius"
                        + (f" ({why})" if why else "")
                        + ", and a_x agrees with the wheels: fix the unit or scale of speed",
                        DEPENDS["speed"],
                    )
                    v_ref = None  # the checks below go by the wheels
                else:
                    why = _factor_name(ratio)
                    rep.add(
                        "wheel_speed_scale",
                        "wheel_speed",
                        f"the wheel speeds times wheel_radius come out {ratio:.3g}x the ground speed"
                        + (
                            f" ({why}): fix the wheel speeds' unit"
                            if why
                            else ": check their unit, scale and wheel_radius"
                        )
                        + ("" if fits["ground"] else " (or the ground speed's: a_x does not tell which)"),
                        DEPENDS["wheel_speed"],
                    )
        else:
            rep.skipped["wheel_speed_scale"] = "no driving above 3 m/s with both wheel and ground speed"
    v = v_ref if v_ref is not None else v_wheel
    wheel_bad = any(f.check == "wheel_speed_scale" for f in rep.findings)
    if v is not None and v_ref is None:
        v = v_wheel  # the only speed there is; its scale is checked through a_y = v r below

    # 2. a_x against dv/dt (of the wheels when their scale is right: a coarse GNSS steps)
    if v is not None and "accel_x" in have:
        v_d = v_wheel if v_wheel is not None and not wheel_bad else v
        note: dict = {}
        fit = _ax_per_dv_dt(v_d, _smooth(y[:, ch.AX], win), t, win, min_n, note)
        if "reversing_s" in note:
            rep.measured["accel_x_reversing_s"] = note["reversing_s"] * dt
        if note.get("ambiguous"):
            rep.skipped["accel_x"] = (
                "a_x against dv/dt: the speeds carry no direction and the drive went both ways at low speed "
                "(reversing), with no run fast enough to be surely forwards: not judged"
            )
        elif fit is not None:
            k, rho = fit
            rep.measured["accel_x_dv_dt_correlation"] = rho
            rep.measured["accel_x_per_dv_dt"] = k
            if abs(rho) < 0.5:
                rep.skipped["accel_x"] = f"a_x and dv/dt correlate too weakly to judge (rho = {rho:.2f})"
            elif k < -0.5:
                rep.add(
                    "accel_x_sign",
                    "accel_x",
                    f"accel_x looks sign-flipped (a_x = {k:.2f} x dv/dt): set sign = -1 in [channels.accel_x]",
                    DEPENDS["accel_x"],
                )
            elif not 0.8 < abs(k) < 1.25:
                # after reversing with speeds that carry no direction, a ratio is no unit's mistake
                why = None if "reversing_s" in note else _factor_name(abs(k))
                subject = "accel_x" if v_ref is not None or wheel_bad else "accel_x or wheel_speed"
                rep.add(
                    "accel_x_scale",
                    "accel_x",
                    f"accel_x is {k:.3g}x dv/dt of the {'ground' if v_ref is not None else 'wheel'} speed"
                    + (f" ({why})" if why else "")
                    + f": check the unit of {subject}",
                    DEPENDS["accel_x"],
                )
        else:
            rep.skipped["accel_x"] = "no acceleration or braking above 0.3 m/s^2 to compare a_x with dv/dt"

    # 3. steady turns: a_y = v r, steering sign, steering ratio
    yaw = y[:, ch.YAW] if "yaw_rate" in have else None
    turn = None
    if yaw is not None and v is not None:
        r_s = _smooth(yaw, win)
        dr = np.gradient(r_s, t)
        turn = np.isfinite(r_s) & np.isfinite(v) & (np.abs(r_s) > 0.04) & (v > 3.0) & (np.abs(dr) < 0.2)
        turn[:win] = turn[-win:] = False
        if turn.sum() < min_n:
            rep.skipped["turns"] = "no steady turn (yaw rate above 0.04 rad/s at over 3 m/s)"
            turn = None
    steer_sign = None
    if turn is not None and "steering_angle" in have:
        d = _smooth(y[:, ch.DELTA], win)
        okd = turn & np.isfinite(d)
        if okd.sum() >= min_n:
            steer_sign = float(np.sign(np.dot(d[okd], yaw[okd])))
    ay_k = None
    if turn is not None and "accel_y" in have:
        ay = _smooth(y[:, ch.AY], win)
        ok = turn & np.isfinite(ay)
        if ok.sum() >= min_n:
            ay_k = _fit(v[ok] * yaw[ok], ay[ok])
            rep.measured["accel_y_per_v_r"] = ay_k
    if ay_k is not None and ay_k < -0.5:
        if steer_sign is not None and steer_sign < 0:
            rep.add(
                "yaw_rate_sign",
                "yaw_rate",
                "yaw_rate looks sign-flipped (against both a_y = v r and the steering angle): "
                "set sign = -1 in [channels.yaw_rate]",
                DEPENDS["yaw_rate"],
            )
        elif steer_sign is not None:
            rep.add(
                "accel_y_sign",
                "accel_y",
                "accel_y looks sign-flipped (a_y has the opposite sign of v r, while the steering angle and the "
                "yaw rate agree): set sign = -1 in [channels.accel_y]",
                DEPENDS["accel_y"],
            )
        else:
            rep.add(
                "accel_y_sign",
                "accel_y",
                "accel_y and yaw_rate disagree in sign (a_y = -v r): one of them needs sign = -1; "
                "map steering_angle to tell which",
                DEPENDS["accel_y"],
            )
    elif ay_k is not None and not 0.8 < ay_k < 1.25:
        why = _factor_name(ay_k)
        if v_ref is None and not wheel_bad:
            subject, hint = "wheel_speed", "the wheel speeds' unit (or accel_y's, or yaw_rate's)"
        else:
            subject, hint = "accel_y", "accel_y's unit (or yaw_rate's)"
        rep.add(
            "accel_y_scale",
            subject,
            f"a_y is {ay_k:.3g}x v r in steady turns" + (f" ({why})" if why else "") + f": check {hint}",
            DEPENDS["accel_y"] if subject == "accel_y" else DEPENDS["wheel_speed"],
        )
    if steer_sign is not None and steer_sign < 0 and not any(f.check == "yaw_rate_sign" for f in rep.findings):
        rep.add(
            "steering_sign",
            "steering_angle",
            "steering_angle has the opposite sign of the yaw rate (positive must be left for both): "
            "set sign = -1 in [channels.steering_angle]",
            DEPENDS["steering_angle"],
        )
    if turn is not None and "steering_angle" in have:
        d = _smooth(y[:, ch.DELTA], win)
        ay = y[:, ch.AY] if "accel_y" in have else v * yaw
        ok = turn & np.isfinite(d) & (np.abs(np.nan_to_num(ay)) < 4.0)
        if ok.sum() >= min_n:
            kin = veh.wheelbase * yaw[ok] / v[ok]  # the kinematic road-wheel angle
            q = float(np.median(np.abs(d[ok]) / np.abs(kin)))
            rep.measured["steer_per_kinematic"] = q
            sr = veh.steering_ratio
            if abs(q / sr - 1.0) < 0.5:
                rep.add(
                    "steering_wheel",
                    "steering_angle",
                    f"steering_angle is {q:.1f}x the road-wheel angle the yaw rate implies, about the steering "
                    f"ratio ({sr:g}): it is the steering-wheel angle; set steering_wheel = true",
                    DEPENDS["steering_angle"],
                )
            elif abs(q * sr - 1.0) < 0.5:
                rep.add(
                    "steering_wheel",
                    "steering_angle",
                    f"steering_angle is 1/{1 / q:.1f} of the road-wheel angle the yaw rate implies, about "
                    f"1/steering ratio: it is the road-wheel angle already; set steering_wheel = false",
                    DEPENDS["steering_angle"],
                )
            elif not 0.7 < q < 2.5:
                rep.add(
                    "steering_ratio",
                    "vehicle.steering_ratio",
                    f"steering_angle is {q:.2f}x the kinematic road-wheel angle L r / v (expected 1 to 2 with "
                    f"understeer): check vehicle.steering_ratio ({sr:g}) and the channel's unit",
                    DEPENDS["steering_angle"],
                )

    # 4. mass against torque / acceleration (eq 1-2 summed over both axles)
    if "wheel_torque_front" in have and "wheel_torque_rear" in have and "accel_x" in have and v is not None:
        if any(f.subject in ("accel_x", "wheel_speed") for f in rep.findings):
            rep.skipped["mass"] = "not judged: accel_x or the wheel speeds are wrong themselves"
        else:
            force = _smooth((y[:, ch.T_F] + y[:, ch.T_R]) / veh.wheel_radius, win)
            ax = _smooth(y[:, ch.AX], win)
            ok = np.isfinite(force) & np.isfinite(ax) & np.isfinite(v) & (v > 1.0)
            ok[:win] = ok[-win:] = False
            strong = ok & (np.abs(ax) > 0.5)
            if strong.sum() >= min_n:
                # road loads: a constant (rolling resistance, grade) and a v^2 term (drag)
                A = np.column_stack([ax[ok], np.ones(ok.sum()), v[ok] ** 2])
                coef, *_ = np.linalg.lstsq(A, force[ok], rcond=None)
                m_eff = float(coef[0])
                m_fit = m_eff - 2.0 * veh.wheel_inertia / veh.wheel_radius**2
                rep.measured["mass_fit"] = m_fit
                if not 0.92 < m_fit / veh.mass < 1.08:
                    # a mass several times too small: the torque is most likely taken before the gearbox
                    # (an engine's, whose gear ratio of ~3-15 is missing), not a loaded car
                    geared = 0.0 < m_fit < veh.mass / 2.5
                    first = (
                        f"the drive torque looks like the engine's, before the gearbox (the ratio "
                        f"{veh.mass / m_fit:.1f} is that of a gear times the final drive): map drive_torque "
                        f"as it times the gear ratio (docs/PROFILES.md), or check the torque channels' unit"
                        if geared
                        else "set the mass as driven (kerb weight plus occupants and load), or check the "
                        "torque channels' unit and wheel_radius"
                    )
                    rep.add(
                        "mass",
                        "vehicle.mass",
                        f"vehicle.mass is {veh.mass:g} kg, but the wheel torques and a_x imply {m_fit:.0f} kg "
                        f"({100 * (veh.mass / m_fit - 1):+.0f} %): {first}",
                        DEPENDS["mass"],
                    )
            else:
                rep.skipped["mass"] = "no acceleration or braking above 0.5 m/s^2 with both axle torques"
    _not_checked(rep, have, y, v is not None)
    return rep


# Each check the samples allow: the figure it measures when made, and the channels it needs.
CHECKS = (
    ("wheel_speed_scale", "wheel_speed_scale", ("wheel_speed", "speed"), "the wheel speeds against the ground speed"),
    ("accel_x", "accel_x_per_dv_dt", ("accel_x", "v"), "a_x against dv/dt"),
    ("accel_y", "accel_y_per_v_r", ("accel_y", "yaw_rate", "v"), "a_y against v r in steady turns"),
    ("steering_angle", "steer_per_kinematic", ("steering_angle", "yaw_rate", "v"), "steering against the yaw rate"),
    ("mass", "mass_fit", ("wheel_torque_front", "wheel_torque_rear", "accel_x", "v"), "the mass from torque and a_x"),
)
_TO_COMPARE = {  # what a missing channel leaves a check without
    "speed": "no ground speed (speed) to compare with",
    "yaw_rate": "no yaw rate to compare with",
    "v": "no speed (neither speed nor wheel speeds) to compare with",
}


def _not_checked(rep: Report, have: set[str], y: np.ndarray, has_v: bool) -> None:
    """Name every check of CHECKS that was not made, with why: a missing channel, one without
    values, or the driving (the check's own reason, or the steady turns' for the lateral ones)."""
    turns = rep.skipped.pop("turns", None)
    for key, figure, needs, what in CHECKS:
        if figure in rep.measured:
            continue
        why = None
        for n in needs:
            if n == "v":
                present = has_v
                cols = [ch.SPEED] if "speed" in have else [ch.INDEX[w] for w in ch.NAMES[:4] if w in have]
            elif n == "wheel_speed":
                cols = [ch.INDEX[w] for w in ch.NAMES[:4] if w in have]
                present = bool(cols)
            else:
                present, cols = n in have, [ch.INDEX[n]]
            if not present:
                why = _TO_COMPARE.get(n, f"no {n}") + f" (the profile maps no {'wheel speeds' if n == 'v' else n})"
                break
            k = max((int(np.isfinite(y[:, c]).sum()) for c in cols), default=0)
            if k < MIN_SAMPLES:
                name = {"v": "speed", "wheel_speed": "wheel speed"}.get(n, n)
                why = (
                    f"{'no' if not k else f'only {k}'} {name} values in the samples (its frames refused, "
                    f"or its values beyond what a car can read)"
                )
                break
        if why is None and key in rep.skipped:
            continue  # the check's own reason: the driving did not allow it
        if why is None:
            why = turns if turns and key in ("accel_y", "steering_angle") else "too little driving where it applies"
        rep.skipped[key] = f"{what}: {why}"


@dataclass
class Coverage:
    """How many of the profile's messages a log (or a live bus) holds."""

    wanted: dict[str, int]  # message name -> frames decoded
    other: list[tuple[str, int]]  # the log's most frequent ids the profile does not decode
    source: str = "log"  # "log" or "bus": what the message says holds the frames
    refused: dict[str, dict[str, int]] = field(default_factory=dict)  # unseen message -> its frames' errors by kind
    other_channels: dict[str, int] = field(default_factory=dict)  # frames left out: on another bus channel
    bus_channel: str | None = None  # the profile's [can] channel

    def refused_share(self, name: str) -> float:
        """The share of a message's frames the decoder refused (counter, checksum, length, layout)."""
        bad = sum(self.refused.get(name, {}).values())
        return bad / (bad + self.wanted.get(name, 0)) if bad else 0.0

    @property
    def seen(self) -> int:
        return len(self.wanted) - len(self.missing)

    @property
    def missing(self) -> list[str]:
        """Messages never decoded, or refused for most of their frames (the decoder had next to no values)."""
        return [m for m, n in self.wanted.items() if not n or self.refused_share(m) > 0.5]

    def message(self, top: bool = True) -> str:
        """One line: "0 of 7 of the profile's messages seen (missing: ...); the ids the log holds most: ..."."""
        missing = self.missing
        out = f"{self.seen} of {len(self.wanted)} of the profile's messages seen" + (
            f" (missing: {', '.join(missing)})" if missing else ""
        )
        for name, kinds in self.refused.items():  # the id is there, but its frames are refused
            n = sum(kinds.values())
            why = ", ".join(f"{k} {c}" for k, c in sorted(kinds.items(), key=lambda kv: -kv[1]))
            good = self.wanted.get(name, 0)
            if good:
                out += f"; {name} came {n + good} times, {n} refused ({why})"
            else:
                out += f"; {name} came {n} time{'s' if n > 1 else ''}, none decoded ({why})"
        if self.other_channels and self.seen < len(self.wanted):
            n = sum(self.other_channels.values())
            names = ", ".join(f"{c} ({k})" for c, k in sorted(self.other_channels.items(), key=lambda kv: -kv[1]))
            out += (
                f"; {n} frames came on other bus channels ({names}) than the profile's [can] channel "
                f"'{self.bus_channel}': set it to the channel the car's bus is on, or delete it"
            )
        where = "bus carries" if self.source == "bus" else "log holds"
        if top and missing:  # the clue to which id a missing message is
            ids = ", ".join(f"{i} ({n})" for i, n in self.other[:8]) or "none"
            out += f"; the ids the {where} most: {ids}"
        elif top and self.other:  # every message there: the rest is for information, not a fault
            ids = ", ".join(f"{i} ({n})" for i, n in self.other[:8])
            out += f" (the {where} other ids too, which the profile does not use: {ids})"
        return out

    def as_dict(self) -> dict:
        return {
            "seen": self.seen,
            "wanted": len(self.wanted),
            "frames": dict(self.wanted),
            "missing": self.missing,
            "refused": {k: dict(v) for k, v in self.refused.items()},
            "other_channels": dict(self.other_channels),
            "top_ids": [{"id": i, "count": n} for i, n in self.other[:8]],
            "message": self.message(),
        }


def check_log(
    path: str | Path,
    profile: Profile,
    seconds: float = CHECK_SECONDS,
    strict_coverage: bool = True,
    quiet: bool = False,
) -> tuple[Report, Coverage]:
    """Decode the first ``seconds`` of bus time of a log and check the profile against it.

    A log that holds none of the profile's messages, or fewer than half, is a ProfileError
    with the counts and the ids the log does hold (unless ``strict_coverage`` is false).
    ``quiet``: the reader logs no warnings (a replay that reads the log next gives them).
    """
    return check_head(first_seconds(path, profile, seconds, quiet), profile, strict_coverage, path)


def check_head(head: Head, profile: Profile, strict_coverage: bool = True, path: str | Path = "the log") -> tuple:
    """:func:`check_log` of a log's first seconds already read (:func:`first_seconds`); ``head``
    is left as it was (its samples serve the drive's measures too: across.measures_of)."""
    from .io.logs import channel_keys

    dec, al, ts, y, st = head.decoder, head.aligner, head.t, head.y.copy(), head.stats
    cov = coverage(dec)
    if getattr(st, "skipped", 0):  # the log source left out the frames of other bus channels
        names = sorted(c for c in getattr(st, "channels", ()) if c not in channel_keys(profile.bus_channel))
        cov.other_channels = {", ".join(names) or "?": st.skipped}
    if strict_coverage and cov.seen * 2 < len(cov.wanted):
        raise ProfileError(f"{path}: the log does not fit profile {profile.path}: {cov.message()}")
    # a channel whose message is missing or refused for most frames (and no alternative stands in):
    # its few values are not judged, and its checks say why
    lost = {
        c: cm.message
        for c, cm in profile.channels.items()
        if cm.message in cov.missing and (cm.alt is None or cm.alt.message in cov.missing)
    }
    rep = Report()
    if len(ts):
        for c in lost:
            y[:, ch.INDEX[c]] = np.nan
        check_samples(profile, ts, y, rep)
    else:
        check_profile(profile, rep)
    check_bounds(al.refused, dec.stats.samples, rep)
    check_brake_pressure(profile, dec, rep)
    check_refused(profile, cov, dec.db, rep)
    for key, figure, needs, what in CHECKS:
        chans = [c for n in needs for c in (ch.NAMES[:4] if n == "wheel_speed" else (n,)) if c in lost]
        if figure not in rep.measured and chans:
            m = lost[chans[0]]
            how = "refused" if m in cov.refused else "missing"
            rep.skipped[key] = f"{what}: {chans[0]} had next to no values (its message {m} {how})"
    return rep, cov


class Head(NamedTuple):
    """A log's first seconds, decoded and aligned (:func:`first_seconds`)."""

    decoder: Any  # the FrameDecoder that read them (its counts per id: vdp.core.change.id_counts)
    aligner: Any
    t: np.ndarray  # sample times [s]
    y: np.ndarray  # sample values (one row per sample, channels.INDEX columns)
    stats: Any  # the reader's
    span: float  # bus time from the first frame read to the last [s]


def first_seconds(path: str | Path, profile: Profile, seconds: float = CHECK_SECONDS, quiet: bool = True) -> Head:
    """The first ``seconds`` of bus time of a log, decoded and aligned as the profile check reads
    them (the running service's self-check keeps its samples alike).  A candump log goes a block
    at a time where that pays (vdp.io.bulk, the same samples and decoder counts); one it hands
    back, a short one, and any other format, frame by frame.  Every frame reaches the decoder,
    those of ids it does not know included."""
    from .buffer import Aligner
    from .io import bulk
    from .io.decoder import FrameDecoder
    from .io.logs import open_log

    def fresh():
        dec = FrameDecoder(profile)
        stale = np.full(ch.N, 0.5)
        for name, cm in profile.channels.items():  # a 1 Hz GPS stays usable between its frames
            cycle = dec.db.get_message_by_name(cm.message).cycle_time
            if cycle:
                stale[ch.INDEX[name]] = max(5.0 * cycle / 1000.0, 0.5)
        return dec, Aligner(stale_after=stale, tick=TICK, limits=ch.limits(profile.vehicle))

    if bulk.pays(path):
        dec, al = fresh()
        sink = _Sink(dec, al)
        src = bulk.BulkSource(path, channel=profile.bus_channel, until=seconds, keep_all=True)
        try:
            src.feed_into(sink)
        except bulk.Irregular as why:
            log.debug("%s: %s; checking it frame by frame", path, why)
        else:
            return Head(dec, al, *sink.arrays(), src.stats, float(src.stats.bus_time or 0.0))
        finally:
            src.close()
    dec, al = fresh()
    ts: list[float] = []
    rows: list[tuple] = []
    t0 = t1 = None
    with open_log(path, channel=profile.bus_channel, quiet=quiet) as src:
        for msg in src:
            if t0 is None:
                t0 = msg.timestamp
            if msg.timestamp - t0 > seconds:
                break
            t1 = msg.timestamp
            pairs = dec.decode(msg)
            if pairs:
                for s in al.push(msg.timestamp, pairs):
                    ts.append(s.t)
                    rows.append(s.values)
    y = np.vstack(rows) if rows else np.zeros((0, ch.N))
    return Head(dec, al, np.asarray(ts), y, src.stats, (t1 - t0) if t0 is not None else 0.0)


class _Sink:
    """What the block reader feeds (a pipeline's decoder, aligner, feed and take_block): keeps
    the aligned samples, as the frame-by-frame loop of :func:`first_seconds` keeps them."""

    def __init__(self, decoder, aligner):
        self.decoder, self.aligner = decoder, aligner
        self.last_bus_time = None
        self._t: list[np.ndarray] = []
        self._y: list[np.ndarray] = []

    def feed(self, msg) -> None:
        pairs = self.decoder.decode(msg)
        if pairs:
            samples = self.aligner.push(msg.timestamp, pairs)
            if samples:
                self._t.append(np.array([s.t for s in samples]))
                self._y.append(np.array([s.values for s in samples]))

    def take_block(self, T, Y, F, A, gap) -> None:
        self._t.append(T)
        self._y.append(Y)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        if not self._t:
            return np.zeros(0), np.zeros((0, ch.N))
        return np.concatenate(self._t), np.vstack(self._y)


REFUSED_SHARE = 0.03  # a message whose frames the decoder refuses more often than this is a finding

# Why the decoder refuses a message's frames, by the kind it counts most, and what to do.
_REFUSED_WHY = {
    "counter": (
        "its counter {counter} does not step by one per frame, as [checks] says (another signal, step or width)",
        "name the right counter in [checks] {name}, or leave the message unchecked: {name} = {{ check = false }}",
    ),
    "checksum": (
        "its checksum {checksum} is not computed as checksum_kind says",
        'set checksum_kind = "none" in [checks] {name}, or {name} = {{ check = false }}',
    ),
    "dlc": (
        "its frames are not the length the DBC gives ({length} bytes): the DBC describes another model or year",
        "use the DBC of this car; if a converter dropped trailing zero bytes, set pad_short = true in [can]",
    ),
}
_LAYOUT = (
    "its values lie outside the DBC's ranges or its layout differs (kinds: {kinds}): the DBC describes "
    "another model or year",
    "use the DBC of this car, or widen the signal's range in the profile",
)


def check_refused(profile: Profile, cov: Coverage, db, report: Report) -> Report:
    """A finding per message the decoder refuses for more than REFUSED_SHARE of its frames: the
    share, the likely cause and the fix; the parameters resting on its channels are doubted."""
    for name, kinds in cov.refused.items():
        share = cov.refused_share(name)
        if share <= REFUSED_SHARE:
            continue
        bad = sum(kinds.values())
        top = max(kinds, key=kinds.get)
        chk = profile.checks.get(name)
        try:
            length = db.get_message_by_name(name).length
        except KeyError:
            length = "?"
        fill = {
            "name": name,
            "counter": getattr(chk, "counter", None) or "",
            "checksum": getattr(chk, "checksum", None) or "",
            "length": length,
            "kinds": ", ".join(sorted(kinds)),
        }
        why, fix = _REFUSED_WHY.get(top, _LAYOUT)
        chans = [c for c, cm in profile.channels.items() if cm.message == name]
        chans += [c for c, comp in getattr(profile, "composites", {}).items() if name in comp.messages]
        params = tuple(dict.fromkeys(p for c in chans for p in DEPENDS.get(_subject(c), ("I_x",))))
        counts = ", ".join(f"{k} {n}" for k, n in sorted(kinds.items(), key=lambda kv: -kv[1]))
        report.add(
            f"{name}_refused",
            name,
            f"the decoder refused {bad} of {bad + cov.wanted.get(name, 0)} frames of {name} ({100 * share:.0f} %: "
            f"{counts}), and {', '.join(chans) or 'its channels'} lost their values: likely "
            + why.format(**fill)
            + "; fix: "
            + fix.format(**fill),
            params,
        )
    return report


def primary_messages(profile: Profile) -> set[str]:
    """The messages the profile reads its channels from (not the alternatives)."""
    names = {cm.message for cm in profile.channels.values()}
    for comp in getattr(profile, "composites", {}).values():
        names |= comp.messages
    return names


def coverage(dec, source: str = "log") -> Coverage:
    """The frames ``dec`` (a FrameDecoder) decoded per primary message, and the ids it did not decode."""
    from .io.decoder import _hex

    primaries = primary_messages(dec.profile)
    plans = [p for p in dec._plans.values() if p.name in primaries]
    wanted = {p.name: p.good for p in plans}
    errors = dec.stats.errors.copy()
    refused: dict[str, dict[str, int]] = {}
    for p in plans:
        kinds = {kind: n for (key, kind), n in errors.items() if key == p.key}
        if kinds and sum(kinds.values()) > REFUSED_SHARE * (p.good + sum(kinds.values())):
            refused[p.name] = kinds
    other = sorted(dec.stats.unknown.copy().items(), key=lambda kv: -kv[1])
    return Coverage(
        wanted,
        [(_hex(k), n) for k, n in other],
        source,
        refused,
        dict(getattr(dec.stats, "other_channels", {})),
        dec.profile.bus_channel,
    )


def lines(rep: Report, mass_on: bool = False) -> list[str]:
    """What the CLI prints: one warning line per finding.  ``mass_on``: the mass is learnt as driven
    (core.mass), so the finding on the profile's mass marks the six only if that is not learnt."""
    return lines_of(rep.findings, mass_on)


def lines_of(findings: list[Finding], mass_on: bool = False) -> list[str]:
    out = []
    for f in findings:
        line = f"profile check: {f.message}"
        if f.params and mass_on and f.subject == "vehicle.mass":
            line += f" (not valid unless the mass learnt as driven is: {', '.join(f.params)})"
        elif f.params:
            line += f" (not valid: {', '.join(f.params)})"
        out.append(line)
    return out


def mass_answer(params: Mapping[str, Estimate], rep: Report) -> str | None:
    """The line that says a valid learnt mass answered the finding on the profile's mass (None
    where there is no such finding or the mass was not learnt valid)."""
    if not _mass_learnt(params) or not any(f.subject == "vehicle.mass" for f in rep.findings):
        return None
    m = params[MASS]
    return (
        f"profile check: the mass learnt as driven, {m.value:.0f} ± {m.std:.0f} kg, answers the finding on "
        f"vehicle.mass: the parameters are scaled with it and keep their own verdicts"
    )


START_AFTER = 10.0  # s of bus time before a running service's first check
START_CYCLES = 3.0  # ... or this many periods of the profile's slowest message, if longer


class Monitor:
    """The self-check of a running service.

    It keeps the aligned samples it is shown (10 Hz, the newest ``keep`` seconds) and checks
    once ``start`` seconds of bus time have passed since the first frame (START_AFTER, or three
    periods of the profile's slowest message if that is longer: a 1 Hz GPS is seen three
    times), then every ``every`` seconds of bus time.  Each check also counts which of the
    profile's messages the bus carried (:func:`coverage`): a bus that carries none or few of
    them (fewer than half) is an :attr:`error` with the counts and the ids the bus carries
    most; after the first check the counts are kept current at every update.  Each new
    finding, and each change of which messages are seen, is logged once; :meth:`mark`
    applies the newest report to estimates.
    """

    def __init__(
        self,
        profile: Profile,
        decoder=None,
        keep: float = 600.0,
        every: float = 30.0,
        rate: float = 0.1,
        start: float | None = None,
        aligner=None,
    ):
        self.aligner = aligner  # its values beyond a car's limits are findings too
        self.profile, self.decoder, self.keep, self.every, self.rate = profile, decoder, keep, every, rate
        self.start = start if start is not None else start_after(profile, decoder)
        self.t: list[float] = []
        self.y: list[np.ndarray] = []
        self.last_t = -math.inf
        self.next_check: float | None = None
        self.checked_at: float | None = None  # bus time of the newest check
        self.checks = 0
        self.report = check_profile(profile)
        self.coverage: Coverage | None = None
        self._said: set[str] = set()
        self._said_coverage: tuple | None = None
        self._say()

    @property
    def error(self) -> str | None:
        """The bus does not fit the profile: none or fewer than half of its messages seen."""
        cov = self.coverage
        if cov is None or cov.seen * 2 >= len(cov.wanted):
            return None
        return f"the bus does not fit profile {self.profile.path}: {cov.message()}"

    def update(self, ring, first: float | None = None, now: float | None = None) -> None:
        """Take the samples ``ring`` (a SampleRing) got since the last call; check when due.

        ``first`` and ``now`` are the bus times of the first and the newest frame (decoded or
        not); without them the samples' times stand in.
        """
        ts, ys = ring.latest()
        new = ts > self.last_t
        for t, y in zip(ts[new], ys[new]):
            if not self.t or t - self.t[-1] >= self.rate:
                self.t.append(float(t))
                self.y.append(y.copy())
        if len(ts) and new.any():
            self.last_t = float(ts[-1])
        while self.t and self.t[-1] - self.t[0] > self.keep:
            self.t.pop(0)
            self.y.pop(0)
        if first is None or now is None:
            if not self.t:
                return
            first, now = self.t[0], self.t[-1]
        if self.next_check is None:
            self.next_check = first + self.start
        if now >= self.next_check:
            self.next_check = now + self.every
            self.check(now)
        elif self.checks and self.decoder is not None:  # the counts stay current between checks
            self.coverage = coverage(self.decoder, source="bus")
            self._say()

    def check(self, now: float) -> None:
        """Check now: the messages seen so far, and the profile against the samples kept."""
        self.checked_at = now
        self.checks += 1
        if self.decoder is not None:
            self.coverage = coverage(self.decoder, source="bus")
        y = np.vstack(self.y) if self.y else np.empty((0, ch.N))
        self.report = check_samples(self.profile, np.asarray(self.t), y)
        if self.aligner is not None:
            decoded = None if self.decoder is None else self.decoder.stats.samples
            check_bounds(self.aligner.refused, decoded, self.report)
        if self.coverage is not None and self.error is None:  # (a bus of another car: the error says it all)
            check_refused(self.profile, self.coverage, self.decoder.db, self.report)
        self._say()

    def _say(self) -> None:
        for f in self.report.findings:
            if f.check not in self._said:
                self._said.add(f.check)
                log.warning("%s", lines_of([f])[0])
        cov = self.coverage
        if cov is None:
            return
        said = (cov.seen, tuple(cov.missing), tuple(cov.refused))  # a change of what is seen, not of counts
        if said == self._said_coverage:
            return
        self._said_coverage = said
        if self.error:
            log.error("profile check: %s", self.error)
        elif cov.seen < len(cov.wanted):
            log.warning("profile check: %s", cov.message())
        else:
            log.info("profile check: %s", cov.message(top=False))

    def mark(self, params):
        """``params`` (name -> Estimate) with those the newest report doubts marked not valid."""
        return None if params is None else mark_invalid(params, self.report)

    def status(self) -> dict:
        """What /status shows: when the check ran, its findings, the messages seen, the error."""
        doc = self.report.as_dict()
        doc.update(
            checked_at=self.checked_at,
            checks=self.checks,
            start_after_s=self.start,
            every_s=self.every,
            coverage=None if self.coverage is None else self.coverage.as_dict(),
            error=self.error,
        )
        return doc


def start_after(profile: Profile, decoder=None) -> float:
    """Bus time [s] a running service waits before its first check (see :class:`Monitor`)."""
    longest = 0.0
    if decoder is not None:
        names = primary_messages(profile)
        for plan in decoder._plans.values():
            if plan.name in names and plan.fixed_period:
                longest = max(longest, plan.period)
    return max(START_AFTER, START_CYCLES * longest)
