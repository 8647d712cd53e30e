"""A first profile for a new car: candidate DBC signals per channel, by name and unit, and
with a log of the car, by behaviour.

:func:`candidates` scores every signal of the DBC for each channel (and source) by its
name (English, German and the usual abbreviations) and whether its unit can be converted
to the channel's.  With a log (:func:`behaviour`), the signals that never move are pushed
down, wheel-speed candidates are ranked by how closely they follow the others, and
yaw-rate candidates by how well they follow the steering angle times the speed.
:func:`draft` writes a commented TOML profile that ``vdp profile check`` then validates.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import channels
from .text import one_line, toml_str
from .units import CHANNEL_KINDS, SOURCES, UNIT_FACTORS

# channel -> (patterns that must all match the lower-case "message.signal", patterns that add)
_B = r"(^|[._])"  # a token boundary before
_E = r"([._]|$)"  # and after
_PATTERNS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "wheel_speed_fl": (
        (r"wh(ee)?l|rad|wheel", rf"fl|front_?left|left_?front|{_B}(lf|vl){_E}"),
        (r"sp(ee)?d|_w_|geschw",),
    ),
    "wheel_speed_fr": (
        (r"wh(ee)?l|rad|wheel", rf"fr|front_?right|right_?front|{_B}(rf|vr){_E}"),
        (r"sp(ee)?d|_w_|geschw",),
    ),
    "wheel_speed_rl": (
        (r"wh(ee)?l|rad|wheel", rf"rl|rear_?left|left_?rear|{_B}(lr|hl){_E}"),
        (r"sp(ee)?d|_w_|geschw",),
    ),
    "wheel_speed_rr": ((r"wh(ee)?l|rad|wheel", rf"rr|rear_?right|right_?rear|{_B}hr{_E}"), (r"sp(ee)?d|_w_|geschw",)),
    "steering_angle": ((r"ste(er)?|str|lenk|sas|lwi|pin",), (r"ang|an_|winkel|_an", r"wheel|whl|comp|est")),
    "yaw_rate": ((r"yaw|gier",), (r"rate|_w_|rt|gierrate", r"veh|esp|esc|imu")),
    "accel_x": ((r"lon|laeng|ax\b|accel_?x|long",), (r"acc|_a_|beschl", r"veh|esp|esc|imu")),
    "accel_y": ((r"lat|quer|ay\b|accel_?y",), (r"acc|_a_|beschl", r"veh|esp|esc|imu")),
    # "rol" as in Ford's VehRol_W_Actl, not in CONTROL, sCROLL, ROLLing or contROLLER
    "roll_rate": ((r"(?<!cont)(?<!sc)rol(?!l(?:ing|er))|wank",), (r"rate|_w_|rt", r"veh|imu")),
    "speed": ((r"gps|gnss|nav",), (r"sp(ee)?d|vel|_v_",)),
    # "Mom" as in VW's MO_Mom_Ist_Summe: a token, not MOMentary
    "drive_torque": ((rf"tq|torq|moment|{_B}mom{_E}",), (r"wh(ee)?l|whl|prpl|drive|axle|rad", r"tot|actl|ist")),
    "brake_torque": ((rf"tq|torq|moment|{_B}mom{_E}", r"brk|brake|brems"), (r"tot|actl|ist",)),
    "brake_pressure": ((r"pres|druck", r"brk|brake|brems|esp|cyl"), (r"mc|master|haupt|bremsdruck|cyl",)),
    "wheel_torque_front": ((r"tq|torq", rf"front|vorder|{_B}(fa|va){_E}"), (r"wh(ee)?l|axle|achs",)),
    "wheel_torque_rear": ((r"tq|torq", rf"rear|hinter|{_B}(ra|ha){_E}"), (r"wh(ee)?l|axle|achs",)),
}
# a torque named for the engine or motor is taken before the gearbox: at the wheels it is that
# times the gear ratio (a composite, docs/PROFILES.md), which a plain mapping leaves out
_ENGINE = re.compile(r"eng|motor|\bmo_|etq|tqi|\bice|crank")  # in the signal's name
ENGINE_NOTE = (
    "an engine torque? vdp needs the torque at the wheels: map drive_torque as this times the gear "
    "ratio (a product, docs/PROFILES.md; profiles/vw_golf_mk7.toml does it)"
)
# never a channel's value: counters, checksums and CRCs, status, validity and quality bits, errors,
# requests and targets, limits, (Hyundai's DATC/FATC) the air conditioning's temperatures and torques,
# what a display shows the driver, and a GPS position (its "lon" and "lat" are no accelerations)
_NOT = re.compile(
    r"count|cnt|checksum|chksum|chks|_cs\b|crc|alive|parity|_qf|qual|valid|vld|stat|err(or)?\b|fault|diag|"
    r"warn|req|rq|lamp|btn|button|cmd|target|trg|max|min|lim|temp|acn|aircon|hvac|display|"
    r"latitude|longitude|altitude"
)
UNIT_GUESS = {  # DBC unit spellings vdp's table does not hold
    "radians/second": "rad/s",
    "rad/sec": "rad/s",
    "degrees": "deg",
    "degree": "deg",
    "degrees/second": "deg/s",
    "deg/sec": "deg/s",
    "kph": "km/h",
    "mph": "mph",
    "nm": "Nm",
    "newton meter": "Nm",
    "bar": "bar",
    "kilopascal": "kPa",
    "m/s2": "m/s^2",
    "m/s²": "m/s^2",
}


@dataclass
class Candidate:
    message: str
    signal: str
    unit: str | None  # vdp's name of the DBC unit, if known
    dbc_unit: str
    score: float
    note: str = ""
    engine: bool = False  # a drive torque named for the engine: before the gearbox (ENGINE_NOTE)
    fine: str | None = None  # a finer signal of the same message that completes this one (_fine)
    wrong_kind: bool = False  # its DBC unit is of another quantity (an angle for a torque)
    percent: bool = False  # a torque in per cent of a reference torque (PERCENT_NOTE)

    @property
    def mapped(self) -> bool:
        """Whether the draft maps it as the channel's best (an uncommented line): a unit vdp knows,
        of the channel's quantity, and not an engine's torque."""
        return self.unit is not None and not self.engine and not self.wrong_kind and not self.percent


PERCENT_NOTE = (
    "a torque in per cent: map it as a term whose weight is the reference torque in N m (times the "
    'gear ratio, for an engine\'s), e.g. [channels.drive_torque] terms = [{{ message = "{message}", '
    'signal = "{signal}", unit = "%", weight = EDIT }}] (profiles/hyundai_elantra_2017.toml does it)'
)
_STEERING = re.compile(r"steer|str(?!nd)|mdps|eps|lkas|lenk")
_BRAKE = re.compile(r"brk|brake|brems")
_TORQUES = ("drive_torque", "brake_torque", "wheel_torque_front", "wheel_torque_rear")


def unit_of(dbc_unit: str | None) -> str | None:
    u = (dbc_unit or "").strip()
    if u in UNIT_FACTORS:
        return u
    return UNIT_GUESS.get(u.lower()) or next((k for k in UNIT_FACTORS if k.lower() == u.lower()), None)


def _fine(msg, sig) -> str | None:
    """A signal of the same message that carries what ``sig`` rounds away: the same known unit, a
    finer step, and a range about zero that fills one of ``sig``'s steps and no more (range plus
    its own step at least the coarse step: the rule the profile's loader checks the pair by,
    io.signals.check_fine; Toyota's STEER_ANGLE in 1.5 deg steps and STEER_FRACTION, -0.7...0.7
    deg in 0.1 deg).  The profile's ``fine`` adds the two."""
    step = abs(sig.scale or 0.0)
    if not step or sig.is_float or unit_of(sig.unit) is None:
        return None
    for other in msg.signals:
        if other is sig or other.is_float or (other.unit or "") != (sig.unit or ""):
            continue
        lo, hi, fine = other.minimum, other.maximum, abs(other.scale or 0.0)
        if not (0 < fine < step and lo is not None and hi is not None and lo < 0 < hi):
            continue
        if step * (1 - 1e-6) <= hi - lo + fine and hi - lo <= 1.05 * step:
            return other.name
    return None


def _sentinels(sig) -> bool:
    """Whether the value table only names codes outside the signal's [min|max] (Ford's GPS_Speed:
    254 Unknown, 255 Invalid): a measurement with its no-value codes, not a state."""
    lo, hi = sig.minimum, sig.maximum
    if lo is None or hi is None:
        return False
    return all(not lo <= raw * (sig.scale or 1.0) + (sig.offset or 0.0) <= hi for raw in sig.choices)


def _elsewhere(ch: str, name: str) -> bool:
    """Whether a signal's own name matches another channel's patterns and not ``ch``'s: it came in
    by its message's name (Yaw_Data_FD1.VehRol_W_Actl for yaw_rate), and it is the other's."""
    if all(re.search(p, name) for p in _PATTERNS[ch][0]):
        return False
    # the torques' patterns nest (every brake torque's name is also a drive torque's): not among them
    others = [o for o in _PATTERNS if o != ch and not (ch in _TORQUES and o in _TORQUES)]
    return any(all(re.search(p, name) for p in _PATTERNS[o][0]) for o in others)


def candidates(db, top: int = 5) -> dict[str, list[Candidate]]:
    """Per channel (and source), the best-scoring signals of the DBC by name and unit."""
    out: dict[str, list[Candidate]] = {}
    names = [*channels.NAMES[: channels.N_SENSORS], *SOURCES]  # (the status flags: not proposed yet)
    for ch in names:
        must, more = _PATTERNS[ch]
        kinds = CHANNEL_KINDS[ch]
        found = []
        for m in db.messages:
            for s in m.signals:
                name = f"{m.name}.{s.name}".lower()
                if not all(re.search(p, name) for p in must) or _NOT.search(s.name.lower()) or s.length < 6:
                    continue
                if s.choices and (s.length <= 8 or 2 * len(s.choices) >= 2**s.length) and not _sentinels(s):
                    continue  # a value table over a short field: a state or a mode, not a measured quantity
                if _elsewhere(ch, s.name.lower()):
                    continue  # its own name is another channel's (FLWheelSpd in a "Front" message for fr)
                if ch == "drive_torque" and _BRAKE.search(s.name.lower()):
                    continue  # a brake's torque (VW's PLA_Bremsmoment) never drives
                unit = unit_of(s.unit)
                if ch in _TORQUES and _STEERING.search(name):
                    continue  # the steering's torque (an EPS's, a driver's, unit given or not) drives no wheel
                score = 1.0 + sum(1.0 for p in more if re.search(p, name))
                percent = unit == "%" and ch in _TORQUES  # per cent of a reference torque: a term's weight
                if unit is not None:
                    score += 2.0 if UNIT_FACTORS[unit][1] in kinds or percent else -3.0
                c = Candidate(m.name, s.name, unit, s.unit or "", score, percent=percent)
                c.wrong_kind = unit is not None and UNIT_FACTORS[unit][1] not in kinds and not percent
                c.fine = _fine(m, s)
                if ch == "drive_torque" and _ENGINE.search(s.name.lower()):
                    c.engine = True
                    c.score -= 2.0
                found.append(c)
        found.sort(key=lambda c: -c.score)
        out[ch] = found[:top]
    return out


def propose(
    db, log_path: str | Path | None = None, top: int = 5, seconds: float = 120.0
) -> tuple[dict[str, list[Candidate]], LogFacts | None]:
    """The candidates ``vdp profile new`` shows: by name and unit, and with a log re-ranked by
    behaviour (see :func:`behaviour`) from a longer list, so that a signal the names rank sixth
    (Hyundai's EMS11.TQI_ACOR among five torques that tie) can still come first."""
    if log_path is None:
        return candidates(db, top), None
    cands = candidates(db, top=4 * top)
    facts = behaviour(db, cands, log_path, seconds)
    for cs in cands.values():
        del cs[top:]
    return cands, facts


@dataclass
class LogFacts:
    """What the log says of the [can] section: the bus channel that carries every mapped message
    where the log has several (None: one channel, or no one carries them all), and the mapped
    messages' frames there shorter than the DBC's length, per message."""

    channel: str | None = None
    also: list[str] = field(default_factory=list)  # the log's other channels
    short: dict[str, int] = field(default_factory=dict)
    still: dict[str, list[str]] = field(default_factory=dict)  # channel -> its candidates that never move


def behaviour(db, cands: dict[str, list[Candidate]], log_path: str | Path, seconds: float = 120.0) -> LogFacts:
    """Re-rank the candidates by what their values do in a log of the car (in place); return
    what the log says of its channels and short frames."""
    from .io.logs import open_log

    wanted = {(c.message, c.signal) for cs in cands.values() for c in cs}
    wanted |= {(c.message, c.fine) for cs in cands.values() for c in cs if c.fine}
    by_id = {}
    for m in db.messages:
        if any(msg == m.name for msg, _ in wanted):
            by_id[(m.frame_id, m.is_extended_frame)] = m
    series: dict[tuple[str, str], list[tuple[float, float]]] = {k: [] for k in wanted}
    t0 = None
    per_channel: dict[str, int] = {}  # frames of the candidates' messages by bus channel
    seen_on: set[str] = set()  # every channel the log has frames on
    where: dict[str, set[str]] = {}  # message -> the channels it comes on
    short: dict[tuple[str, str], int] = {}  # (channel, message) -> frames shorter than the DBC's
    with open_log(log_path) as src:
        for msg in src:
            t0 = msg.timestamp if t0 is None else t0
            if msg.timestamp - t0 > seconds:
                break
            chan = str(msg.channel) if msg.channel is not None else ""
            seen_on.add(chan)
            m = by_id.get((msg.arbitration_id, msg.is_extended_id))
            if m is None:
                continue
            per_channel[chan] = per_channel.get(chan, 0) + 1
            where.setdefault(m.name, set()).add(chan)
            if len(msg.data) < m.length:
                short[(chan, m.name)] = short.get((chan, m.name), 0) + 1
            if len(msg.data) != m.length:
                continue
            try:
                vals = m.decode(bytes(msg.data), decode_choices=False)
            except Exception:  # a frame of another layout: skip it
                continue
            for s, v in vals.items():
                if (m.name, s) in series and isinstance(v, (int, float)) and math.isfinite(v):
                    series[(m.name, s)].append((msg.timestamp - t0, float(v)))
    grid = np.arange(0.0, seconds, 0.05)

    def on_grid(key):
        pts = series.get(key) or []
        if len(pts) < 20:
            return None
        a = np.asarray(pts)
        return np.interp(grid[grid <= a[-1, 0]], a[:, 0], a[:, 1])

    def corr(a, b):
        n = min(len(a), len(b))
        if n < 20 or np.std(a[:n]) == 0 or np.std(b[:n]) == 0:
            return 0.0
        return float(np.corrcoef(a[:n], b[:n])[0, 1])

    def whole(c):  # with its finer part: a coarse angle in 1.5 deg steps may sit still on a straight
        g, f = on_grid((c.message, c.signal)), on_grid((c.message, c.fine)) if c.fine else None
        if g is None or f is None:
            return g
        n = min(len(g), len(f))
        return g[:n] + f[:n]

    still: dict[str, list[str]] = {}
    for ch, cs in cands.items():
        for c in list(cs):
            g = whole(c)
            if g is None:
                c.score -= 2.0
                c.note = "not in the log"
            elif np.std(g) == 0:  # a constant, or a signal this car does not send: never proposed
                cs.remove(c)
                still.setdefault(ch, []).append(f"{c.message}.{c.signal}")
    for c in cands.get("steering_angle", []):  # an angle is signed and centred near 0 on a drive
        g = whole(c)
        if g is None:
            continue
        lo, mid, hi = np.percentile(g, [5, 50, 95])
        if lo >= 0 or hi <= 0:
            c.score -= 1.5
            c.note = "never changes sign in the log: not a signed angle (or one with an offset)"
        elif abs(mid) > 0.25 * (hi - lo):
            c.score -= 1.0
            c.note = f"centred at {mid:.3g}, not near 0"
        else:
            c.score += 1.0
            c.note = "signed, centred near 0"
    wheels = [on_grid((c.message, c.signal)) for w in ("fl", "fr", "rl", "rr") for c in cands[f"wheel_speed_{w}"][:1]]
    wheels = [w for w in wheels if w is not None]
    if wheels:
        n = min(len(w) for w in wheels)
        ref = np.median(np.stack([w[:n] for w in wheels]), axis=0)
        for w in ("fl", "fr", "rl", "rr"):
            for c in cands[f"wheel_speed_{w}"]:
                g = on_grid((c.message, c.signal))
                if g is not None:
                    r = corr(g, ref)
                    c.score += 2.0 * r
                    c.note = c.note or f"follows the wheel speeds (r = {r:.2f})"
        # a drive torque moves with dv/dt of the wheels, a brake's torque or pressure against it
        dvdt = np.gradient(np.convolve(ref, np.ones(10) / 10, mode="same"), grid[:n])
        for ch, sign in (("drive_torque", 1), ("wheel_torque_front", 1), ("wheel_torque_rear", 1)):
            for c in cands.get(ch, []):
                _with_dvdt(c, on_grid((c.message, c.signal)), dvdt, sign, corr)
        for ch in ("brake_torque", "brake_pressure"):
            for c in cands.get(ch, []):
                _with_dvdt(c, on_grid((c.message, c.signal)), dvdt, -1, corr)
        # a longitudinal acceleration is dv/dt, either way round (Toyota's KINEMATICS.ACCEL_X points back)
        for c in cands.get("accel_x", []):
            g = on_grid((c.message, c.signal))
            if g is not None:
                r = corr(g, dvdt)
                c.score += 2.0 * abs(r)
                c.note = c.note or f"follows dv/dt of the wheels (r = {r:+.2f})"
        cands["steering_angle"].sort(key=lambda c: -c.score)
        steer = next((whole(c) for c in cands["steering_angle"][:1]), None)
        if steer is not None:
            n = min(len(steer), len(ref))
            turn = steer[:n] * ref[:n]
            for ch in ("yaw_rate", "accel_y"):  # both go with steering x speed, the lateral one x speed again
                for c in cands[ch]:
                    g = on_grid((c.message, c.signal))
                    if g is not None:
                        r = corr(g, turn * ref[:n] if ch == "accel_y" else turn)
                        c.score += 2.0 * abs(r)
                        what = "a yaw rate" if ch == "yaw_rate" else "a lateral acceleration"
                        c.note = c.note or f"looks like {what} (r = {r:+.2f} with steering x speed)"
    for cs in cands.values():
        cs.sort(key=lambda c: -c.score)
    facts = LogFacts(still=still)
    # the messages the draft maps (the best candidate of each channel it writes uncommented)
    src = _has_sources(cands)
    mapped = {cs[0].message for ch, cs in cands.items() if cs and _drafted(ch, src) and cs[0].mapped}
    on = {m: c for m, c in where.items() if m in mapped}
    # a log of several buses (a comma device logs four): keep to the one that carries every mapped
    # message, the most of their frames first; other units' frames of the same ids stay out. Where
    # no one bus carries them all, no filter: it would drop a message.
    if len(seen_on) > 1 and on:
        carry = [c for c in sorted(per_channel, key=lambda c: -per_channel[c]) if all(c in cs for cs in on.values())]
        if carry:
            facts.channel = carry[0]
            facts.also = sorted(seen_on - {carry[0]})
    facts.short = {m: n for (c, m), n in short.items() if m in mapped and (facts.channel is None or c == facts.channel)}
    return facts


def _with_dvdt(c: Candidate, g, dvdt, sign: int, corr) -> None:
    """Score a torque or pressure by how it follows ``sign`` x dv/dt (braking: -dv/dt)."""
    if g is None:
        return
    r = sign * corr(g, dvdt)
    c.score += 2.0 * max(r, 0.0)
    c.note = c.note or (f"moves with {'-' if sign < 0 else ''}dv/dt (r = {r:.2f})" if r > 0.3 else c.note)
    if r < 0.2:  # it moves, but not with the car's acceleration: outweighs a name's points (an engine's -2)
        c.score -= 2.0


def _has_sources(cands: dict[str, list[Candidate]]) -> bool:
    """Whether the draft maps a drive torque and brake sources (no per-axle wheel torques)."""
    return bool(cands.get("drive_torque")) and not cands.get("wheel_torque_front")


def _drafted(ch: str, has_sources: bool) -> bool:
    """Whether the draft writes channel (or source) ``ch`` at all."""
    if ch in ("wheel_torque_front", "wheel_torque_rear"):
        return not has_sources
    return has_sources if ch in SOURCES else True


def draft(
    dbc: Path,
    cands: dict[str, list[Candidate]],
    name: str = "my-car",
    facts: LogFacts | None = None,
    ref: str | None = None,
) -> str:
    """A commented TOML profile: the best candidate per channel mapped, the others as comments.
    ``ref``: how [can] dbc names the DBC (``opendbc:NAME``), if not by its path."""
    L = [
        f"# Draft profile for {one_line(name)}, written by `vdp profile new` from {one_line(dbc.name)}.",
        "# Every value marked EDIT is a placeholder: put in your car's numbers, then run",
        "#   vdp profile check LOG --profile THIS_FILE",
        "# on a drive with some acceleration, braking and turns; it names each sign or unit it doubts.",
        "",
        "[vehicle]",
        f"name = {toml_str(name)}",  # (a quote or a newline in it is escaped, not TOML broken)
        "mass = 1500.0              # kg as driven (kerb weight plus occupants): EDIT",
        "wheelbase = 2.65           # m: EDIT",
        "wheel_radius = 0.31        # m, rolling radius of the tyres: EDIT",
        "wheel_inertia = 2.0        # kg m^2 per axle, both wheels lumped: EDIT",
        "roll_stiffness = 80000.0   # N m/rad: EDIT (about 6 deg/g for a passenger car)",
        "roll_damping = 5000.0      # N m s/rad: EDIT",
        "steering_ratio = 15.0      # steering-wheel / road-wheel angle: EDIT",
        "track = 1.55               # m: EDIT",
        "",
        "[priors]                   # vague on purpose; l_f must lie inside the wheelbase",
        "l_f     = { value = 1.15,    std = 0.3 }",
        "h       = { value = 0.55,    std = 0.2 }",
        "C_K     = { value = 8.0,     std = 4.0 }",
        "C_alpha = { value = 80000.0, std = 40000.0 }",
        "I_z     = { value = 2500.0,  std = 1200.0 }",
        "I_x     = { value = 600.0,   std = 400.0 }",
        "",
        "[can]",
        f"dbc = {toml_str(ref or str(dbc))}",
    ]
    if facts is not None and facts.channel:
        L.append(
            f"channel = {toml_str(facts.channel)}  # the log has frames on "
            f"{one_line(', '.join([facts.channel, *facts.also]))}; the mapped messages come on "
            f"{one_line(facts.channel)}: another bus's frames of the same ids stay out"
        )
    if facts is not None and facts.short:
        worst = max(facts.short, key=facts.short.get)
        L.append(
            f"pad_short = true  # {sum(facts.short.values())} frame(s) in the log shorter than the DBC's "
            f"length ({one_line(worst)}: {facts.short[worst]}); without this they are refused"
        )
    L.append("")
    has_sources = _has_sources(cands)
    if has_sources:
        L += [
            "[drivetrain]               # which axles drive, how the brakes split: EDIT",
            'driven = "front"',
            "brake_balance = 0.65",
            "",
        ]
    L.append("[channels]")
    for ch in [*channels.NAMES[: channels.N_SENSORS], *SOURCES]:
        cs = cands.get(ch) or []
        if not _drafted(ch, has_sources):
            continue
        gone = (facts.still.get(ch) if facts is not None else None) or []
        if gone:
            L.append(f"# {ch}: never moved in the log, so not proposed: {', '.join(gone[:4])}")
        if not cs:
            L.append(f"# {ch}: no candidate in the DBC" + (" that moves in the log" if gone else ""))
            continue
        best = cs[0]
        unit = best.unit or "EDIT"
        flag = "" if best.unit else f"  # DBC unit '{one_line(best.dbc_unit)}' unknown to vdp: EDIT unit"
        extra = f", fine = {toml_str(best.fine)}" if best.fine else ""  # (a coarse value's finer part)
        extra += ", steering_wheel = true" if ch == "steering_angle" else ""
        why = f"  # {best.note}" if best.note and not flag else ""
        line = (
            f"{ch} = {{ message = {toml_str(best.message)}, signal = {toml_str(best.signal)}, "
            f"unit = {toml_str(unit)}{extra} }}"
        )
        if best.percent:  # a term of a composite, its weight the reference torque: the user's to give
            L.append(f"# {ch}: {best.message}.{best.signal} [%]: " + PERCENT_NOTE.format(**vars(best)))
        elif best.engine:  # left out: mapped as it is, stage 1 would read the gearbox's ratio as mass
            L.append(f"# {line}  # {ENGINE_NOTE}")
        elif best.wrong_kind:  # a name that matches, a unit that does not (STEER_TORQUE_SENSOR.STEER_ANGLE)
            L.append(
                f"# {line}  # its unit '{one_line(best.dbc_unit)}' is not one of a {ch}: no signal fits; "
                "map it yourself"
            )
        else:
            L.append(("# " if not best.unit else "") + line + (flag or why))
        for c in cs[1:3]:
            note = "an engine torque? at the wheels it is this times the gear ratio" if c.engine else c.note
            L.append(f"#   or {c.message}.{c.signal} [{one_line(c.dbc_unit or '-')}]" + (f" ({note})" if note else ""))
    return "\n".join(L) + "\n"
