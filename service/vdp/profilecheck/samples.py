"""The physics checks on aligned samples (check_samples): signs, units and scales a car must show."""

from __future__ import annotations

import logging
import math

import numpy as np

from .. import channels as ch
from ..profile import Profile
from .limits import check_profile
from .report import DEPENDS, Report

log = logging.getLogger(__name__)


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


# m/s: below this a turn's steering is near the kinematic angle whatever the car's handling (|K v^2 / L| < 0.3
# for an understeer gradient up to 0.006 rad per m/s^2 on a 2.8 m wheelbase)
SLOW_TURN = 12.0
SLOW_TURN_HI = 1.6  # the most a slow turn's steering exceeds the kinematic angle by (understeer 1.3, compliance)
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


def _flip(profile: Profile, name: str) -> str:
    """The fix for a channel read with the wrong sign: set sign = -1, or, where the profile already
    has it, take it back out."""
    c = profile.channels.get(name)
    if c is not None and getattr(c, "sign", 1.0) < 0:
        return f"remove sign = -1 from [channels.{name}] (or set sign = 1)"
    return f"set sign = -1 in [channels.{name}]"


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
                    f"accel_x looks sign-flipped (a_x = {k:.2f} x dv/dt): " + _flip(profile, "accel_x"),
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
                + _flip(profile, "yaw_rate"),
                DEPENDS["yaw_rate"],
            )
        elif steer_sign is not None:
            rep.add(
                "accel_y_sign",
                "accel_y",
                "accel_y looks sign-flipped (a_y has the opposite sign of v r, while the steering angle and the "
                "yaw rate agree): " + _flip(profile, "accel_y"),
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
            + _flip(profile, "steering_angle"),
            DEPENDS["steering_angle"],
        )
    if turn is not None and "steering_angle" in have:
        d = _smooth(y[:, ch.DELTA], win)
        ay = y[:, ch.AY] if "accel_y" in have else v * yaw
        ok = turn & np.isfinite(d) & (np.abs(np.nan_to_num(ay)) < 4.0)
        # delta / (L r / v) = 1 + K v^2 / L: judged on slow turns where there are enough, since at speed a
        # car's understeer gradient K moves it (a loaded car that oversteers read 0.53 at highway speed)
        slow = ok & (v < SLOW_TURN)
        where = f" in turns below {SLOW_TURN:g} m/s" if slow.sum() >= min_n else ""
        ok = slow if where else ok
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
            elif not 0.7 < q < (SLOW_TURN_HI if where else 2.5):
                rep.add(
                    "steering_ratio",
                    "vehicle.steering_ratio",
                    f"steering_angle is {q:.2f}x the kinematic road-wheel angle L r / v{where} (expected about 1 "
                    f"in slow turns, up to 2 with understeer at speed): check vehicle.steering_ratio ({sr:g}) and "
                    f"the channel's unit",
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
                    if m_fit < 0:  # no load or unit makes a mass negative: the force and a_x disagree in sign
                        first = (
                            "a negative mass: a wheel torque channel (or their sum) has the wrong sign; check "
                            "sign and scale in [channels.wheel_torque_front] and [channels.wheel_torque_rear]"
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
