"""Reading a profile's TOML into its types (load_profile), every key checked, with errors that say where."""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from .. import channels
from ..errors import ProfileError
from ..opendbc import opendbc_path as _opendbc_path
from ..units import _UNIT_LIST, CHANNEL_KINDS, SOURCES, TERM, UNIT_FACTORS
from .model import (
    ChannelMap,
    Composite,
    Drivetrain,
    MessageCheck,
    Profile,
    Term,
)
from .numbers import _num, _short
from .vehicle import _priors, _vehicle

_MAP_KEYS = {
    "message",
    "signal",
    "unit",
    "scale",
    "offset",
    "sign",
    "sign_signal",
    "steering_wheel",
    "fine",
    "alt",
    "range",
    "valid_when",
    "invalid_when",
    "plausible",
    "active_when",
}


def _channel(where: str, name: str, raw: Any, nested: bool = False, label: str | None = None) -> ChannelMap:
    w = f"{where} [channels.{label or (name + ('.alt' if nested else ''))}]"
    if not isinstance(raw, dict):
        raise ProfileError(f"{w}: must be a table with message, signal and unit")
    unknown = set(raw) - _MAP_KEYS
    if unknown:
        raise ProfileError(f"{w}: unknown key(s) {sorted(unknown)}; allowed: {sorted(_MAP_KEYS)}")
    for key in ("message", "signal", "unit"):
        if not isinstance(raw.get(key), str) or not raw[key]:
            raise ProfileError(f"{w}: missing '{key}' (a string)")
    unit = raw["unit"]
    if unit not in UNIT_FACTORS:
        raise ProfileError(f"{w}: unit '{unit}' is not known; use one of {_UNIT_LIST}")
    kind = UNIT_FACTORS[unit][1]
    if kind not in CHANNEL_KINDS[name]:
        si = channels.UNITS.get(name) or {"drive_torque": "N*m", "brake_torque": "N*m"}.get(name, "Pa")
        raise ProfileError(f"{w}: unit '{unit}' ({kind}) cannot be converted to {name}'s {si}")
    sign = _num(w, "sign", raw.get("sign", 1.0))
    if sign not in (1.0, -1.0):
        raise ProfileError(f"{w}: 'sign' must be 1 or -1, got {sign}")
    scale = _num(w, "scale", raw.get("scale", 1.0))
    if scale == 0:
        raise ProfileError(f"{w}: 'scale' must not be 0")
    sw = raw.get("steering_wheel", False)
    if not isinstance(sw, bool):
        raise ProfileError(f"{w}: 'steering_wheel' must be true or false")
    if sw and name != "steering_angle":
        raise ProfileError(f"{w}: 'steering_wheel' applies to steering_angle only")
    ss = raw.get("sign_signal")
    if ss is not None and not isinstance(ss, str):
        raise ProfileError(f"{w}: 'sign_signal' must be a signal name")
    fine = raw.get("fine")
    if fine is not None:
        if not isinstance(fine, str) or not fine:
            raise ProfileError(f"{w}: 'fine' must be a signal name, got {fine!r}")
        if fine in (raw["signal"], ss):
            raise ProfileError(
                f"{w}: 'fine' must be another signal than "
                f"{'signal' if fine == raw['signal'] else 'sign_signal'} '{fine}'"
            )
    rng = None
    if "range" in raw:
        r = raw["range"]
        if not isinstance(r, list) or len(r) != 2:
            raise ProfileError(f"{w}: 'range' must be [minimum, maximum] of the DBC signal, e.g. [-780, 780]")
        lo, hi = _num(w, "range", r[0]), _num(w, "range", r[1])
        if not lo < hi:
            raise ProfileError(f"{w}: 'range' must be [minimum, maximum] with minimum < maximum, got {r}")
        rng = (lo, hi)
    status = None
    for key, ok in (("valid_when", True), ("invalid_when", False)):
        if key not in raw:
            continue
        if status is not None:
            raise ProfileError(f"{w}: give 'valid_when' or 'invalid_when', not both")
        v = raw[key]
        vals = v.get("values") if isinstance(v, dict) else None
        if (
            not isinstance(v, dict)
            or set(v) != {"signal", "values"}
            or not isinstance(v["signal"], str)
            or not isinstance(vals, list)
            or not vals
            or not all(isinstance(x, int) and not isinstance(x, bool) for x in vals)
        ):
            raise ProfileError(
                f"{w}: '{key}' must be {{ signal = \"STATUS_SIGNAL\", values = [0] }} "
                f"(a status signal of the same message and its raw integer values)"
            )
        status = (v["signal"], frozenset(vals), ok)
    plaus = None
    if "plausible" in raw:
        r = raw["plausible"]
        if not isinstance(r, list) or len(r) != 2:
            raise ProfileError(f"{w}: 'plausible' must be [minimum, maximum] in {channels.UNITS.get(name, 'SI units')}")
        lo, hi = _num(w, "plausible", r[0]), _num(w, "plausible", r[1])
        if not lo < hi:
            raise ProfileError(f"{w}: 'plausible' must be [minimum, maximum] with minimum < maximum, got {r}")
        plaus = (lo, hi)
    active = None
    if "active_when" in raw:
        v = raw["active_when"]
        if name not in channels.STATUS:
            raise ProfileError(f"{w}: 'active_when' applies to the status flags only ({', '.join(channels.STATUS)})")
        if not isinstance(v, list) or not v or not all(isinstance(x, int) and not isinstance(x, bool) for x in v):
            raise ProfileError(
                f"{w}: 'active_when' must be a list of the signal's raw integer values that mean on, "
                f"e.g. [2] for a gear signal whose reverse is 2"
            )
        active = frozenset(v)
    alt = None
    if "alt" in raw:
        if nested:
            raise ProfileError(f"{w}: an alternative source cannot have its own 'alt'")
        alt = _channel(where, name, raw["alt"], nested=True)
    return ChannelMap(
        channel=name,
        message=raw["message"],
        signal=raw["signal"],
        unit=unit,
        scale=scale,
        offset=_num(w, "offset", raw.get("offset", 0.0)),
        sign=sign,
        sign_signal=ss,
        steering_wheel=sw,
        fine=fine,
        alt=alt,
        range=rng,
        status=status,
        plausible=plaus,
        active=active,
        where=w,
    )


def _checks(where: str, raw: Any) -> dict[str, MessageCheck]:
    if raw is None:
        return {}
    if not isinstance(raw, dict):
        raise ProfileError(f"{where} [checks]: must be a table of messages")
    out = {}
    for msg, entry in raw.items():
        w = f"{where} [checks.{msg}]"
        if not isinstance(entry, dict):
            raise ProfileError(f"{w}: must be a table")
        unknown = set(entry) - {"counter", "checksum", "checksum_kind", "check"}
        if unknown:
            raise ProfileError(f"{w}: unknown key(s) {sorted(unknown)}")
        kind = entry.get("checksum_kind", "vdp")
        if kind not in ("vdp", "none"):
            raise ProfileError(f"{w}: checksum_kind must be 'vdp' or 'none', got {kind!r}")
        check = entry.get("check", True)
        if not isinstance(check, bool):
            raise ProfileError(f"{w}: 'check' must be true or false")
        for key in ("counter", "checksum"):
            if key in entry and (not isinstance(entry[key], str) or not entry[key]):
                raise ProfileError(f"{w}: '{key}' must be a signal name, got {entry[key]!r}")
        out[msg] = MessageCheck(
            message=msg, counter=entry.get("counter"), checksum=entry.get("checksum"), checksum_kind=kind, check=check
        )
    return out


_MAX_PROFILE = 1 << 20  # bytes: a profile is a page of TOML


def load_profile(path: str | Path) -> Profile:
    """Read and validate a profile; every problem is a ProfileError naming the line's table."""
    path = Path(path)
    where = str(path)
    if not path.is_file():
        what = "a folder, not a profile file" if path.is_dir() else "no such profile file"
        hint = "" if path.is_absolute() else f" (a relative path is read from {Path.cwd()})"
        raise ProfileError(f"{where}: {what}{hint}")
    if path.stat().st_size > _MAX_PROFILE:
        raise ProfileError(f"{where}: {path.stat().st_size:,} bytes is not a profile (at most {_MAX_PROFILE:,})")
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ProfileError(f"{where}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ProfileError(f"{where}: arrays or tables nested too deeply to be a profile") from None
    unknown = set(raw) - {"vehicle", "priors", "can", "channels", "checks", "drivetrain"}
    if unknown:
        raise ProfileError(
            f"{where}: unknown section(s) {sorted(unknown)}; known: vehicle, priors, can, channels, checks, drivetrain"
        )
    vehicle = _vehicle(where, raw.get("vehicle"))
    priors = _priors(where, raw.get("priors"))
    can = raw.get("can")
    dbc_raw = can.get("dbc") if isinstance(can, dict) else None
    names = [dbc_raw] if isinstance(dbc_raw, str) else dbc_raw
    if not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names):
        raise ProfileError(
            f"{where} [can]: missing 'dbc' (a path relative to the profile, or opendbc:NAME, or a list of them)"
        )
    unknown = set(can) - {"dbc", "channel", "cycle_ms", "pad_short"}
    if unknown:
        raise ProfileError(
            f"{where} [can]: unknown key(s) {sorted(unknown)}; allowed: channel, cycle_ms, dbc, pad_short"
        )
    cycles = can.get("cycle_ms", {})
    if not isinstance(cycles, dict) or not all(
        isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in cycles.values()
    ):
        raise ProfileError(
            f"{where} [can]: 'cycle_ms' must be a table of message = period in whole ms, e.g. {{ GPS = 1000 }}"
        )
    dbcs = []
    for dbc_s in names:
        if dbc_s.startswith("opendbc:"):
            dbc = _opendbc_path(where, dbc_s[len("opendbc:") :])
        else:
            dbc = (path.parent / dbc_s).resolve()
        if not dbc.is_file():
            rel = "" if dbc_s.startswith("opendbc:") or Path(dbc_s).is_absolute() else (
                f" ('{dbc_s}' is read from the profile's own folder, {path.parent}: a copied profile keeps "
                f"its dbc line, so give the dbc's path from the new folder, or an absolute one)"
            )  # fmt: skip
            raise ProfileError(f"{where} [can]: dbc file '{dbc}' does not exist{rel}")
        if dbc in dbcs:
            raise ProfileError(f"{where} [can]: dbc '{dbc_s}' is listed twice")
        dbcs.append(dbc)
    bus_channel = can.get("channel")
    if bus_channel is not None and not isinstance(bus_channel, str):
        raise ProfileError(f"{where} [can]: 'channel' must be a string such as 'can0'")
    chans_raw = raw.get("channels")
    if not isinstance(chans_raw, dict) or not chans_raw:
        raise ProfileError(f"{where} [channels]: missing; map at least one of {', '.join(channels.NAMES)}")
    bad = set(chans_raw) - set(channels.NAMES) - set(SOURCES)
    if bad:
        raise ProfileError(
            f"{where} [channels]: unknown channel(s) {sorted(bad)}; known: {', '.join(channels.NAMES)}, "
            f"and the sources {', '.join(SOURCES)}"
        )
    maps, comps, sources = {}, {}, {}
    for name, entry in chans_raw.items():
        if isinstance(entry, dict) and "terms" in entry:
            if name in SOURCES:  # e.g. an engine torque times the gearbox's ratio
                sources[name] = _composite(where, name, entry)
            else:
                comps[name] = _composite(where, name, entry)
        elif name in SOURCES:
            sources[name] = _channel(where, name, entry)
            if name == "brake_pressure":  # beyond what a brake system holds: a decoding or mapping fault
                lo, hi = sources[name].plausible or (-math.inf, math.inf)
                lo, hi = max(lo, channels.BRAKE_PRESSURE[0]), min(hi, channels.BRAKE_PRESSURE[1])
                if lo < hi:
                    sources[name] = replace(sources[name], plausible=(lo, hi))
        else:
            maps[name] = _channel(where, name, entry)
    drivetrain = _drivetrain(where, raw.get("drivetrain"))
    if sources:
        comps.update(_axle_torques(where, drivetrain, sources, maps, comps))
    return Profile(
        path=path,
        vehicle=vehicle,
        priors=priors,
        dbc=dbcs[0],
        bus_channel=bus_channel,
        channels=maps,
        checks=_checks(where, raw.get("checks")),
        extra_dbcs=tuple(dbcs[1:]),
        composites=comps,
        drivetrain=drivetrain,
        sources=sources,
        cycle_ms=dict(cycles),
        pad_short=_pad_short(where, can.get("pad_short", False)),
    )


def _pad_short(where: str, v: Any) -> bool:
    if not isinstance(v, bool):
        raise ProfileError(f"{where} [can]: 'pad_short' must be true or false, got {v!r}")
    return v


def _drivetrain(where: str, raw: Any) -> Drivetrain | None:
    if raw is None:
        return None
    w = f"{where} [drivetrain]"
    if not isinstance(raw, dict):
        raise ProfileError(f"{w}: must be a table with driven, brake_balance (and front_share, brake_gain)")
    unknown = set(raw) - {"driven", "front_share", "brake_balance", "brake_gain"}
    if unknown:
        raise ProfileError(
            f"{w}: unknown key(s) {sorted(unknown)}; allowed: brake_balance, brake_gain, driven, front_share"
        )
    driven = raw.get("driven", "front")
    if driven not in ("front", "rear", "all"):
        raise ProfileError(f'{w}: \'driven\' must be "front", "rear" or "all", got {driven!r}')
    vals: dict[str, Any] = {"driven": driven}
    for key in ("front_share", "brake_balance"):
        if key in raw:
            v = _num(w, key, raw[key])
            if not 0.0 <= v <= 1.0:
                raise ProfileError(f"{w}: '{key}' is the front axle's share, within [0, 1]; got {v}")
            vals[key] = v
    if "front_share" in raw and driven != "all":
        raise ProfileError(f"{w}: 'front_share' applies to driven = \"all\" only")
    if "brake_gain" in raw:
        v = _num(w, "brake_gain", raw["brake_gain"])
        if v <= 0:
            raise ProfileError(f"{w}: 'brake_gain' (N m of brake torque per bar) must be positive, got {v}")
        vals["brake_gain"] = v
    return Drivetrain(**vals)


def _axle_torques(where, dt, sources, maps, comps) -> dict[str, Composite]:
    """wheel_torque_front/rear from drive_torque and brake_torque (or brake_pressure * brake_gain)."""
    w = f"{where} [channels]"
    if dt is None:
        raise ProfileError(
            f"{w}: {', '.join(sorted(sources))} need a [drivetrain] section (driven axle, brake balance) "
            f"to become per-axle torques"
        )
    for name in ("wheel_torque_front", "wheel_torque_rear"):
        if name in maps or name in comps:
            raise ProfileError(f"{w}: map {name} directly or through drive_torque/brake_*, not both")
    if "drive_torque" not in sources:
        return {}  # a brake signal alone gives no axle torque; Profile.missing names drive_torque
    if "brake_torque" in sources and "brake_pressure" in sources:
        raise ProfileError(f"{w}: map brake_torque or brake_pressure, not both")
    brake, gain = None, 1.0
    if "brake_torque" in sources:
        brake = sources["brake_torque"]
    elif "brake_pressure" in sources:
        if dt.brake_gain is None:
            raise ProfileError(f"{where} [drivetrain]: brake_pressure needs 'brake_gain' (N m per bar)")
        brake, gain = sources["brake_pressure"], dt.brake_gain / 1e5  # per Pa
    out = {}
    for name, d_share, b_share in (
        ("wheel_torque_front", dt.drive_front, dt.brake_balance),
        ("wheel_torque_rear", 1.0 - dt.drive_front, 1.0 - dt.brake_balance),
    ):
        terms, conds = _shared(sources["drive_torque"], d_share, [])
        ages = [s.max_age for s in (sources["drive_torque"], brake) if isinstance(s, Composite)]
        if brake is not None:  # brake torque acts against the drive (eq 2)
            more, conds = _shared(brake, -b_share * gain, conds)
            terms += more
        out[name] = Composite(
            name,
            "sum",
            tuple(terms),
            tuple(conds),
            max_age=min(ages, default=0.5),
            where=f"{where} [drivetrain] -> {name}",
        )
    return out


def _shared(src: ChannelMap | Composite, share: float, conds: list) -> tuple[list[Term], list]:
    """``share`` of a source as terms of a sum (and the conditions list, extended with the source's own):
    a signal is one term; a product one term with further factors; a sum its terms, each times ``share``."""
    if isinstance(src, ChannelMap):
        return [Term(src, share)], conds
    if src.op == "product":  # the first term's weight scales the product (Composite)
        first = src.terms[0]
        factors = first.factors + tuple(m for t in src.terms[1:] for m in (t.map, *t.factors))
        return [Term(first.map, first.weight * share, None, factors)], conds
    k = len(conds)
    terms = [
        Term(t.map, t.weight * share, None if t.when is None else (t.when[0] + k, t.when[1]), t.factors)
        for t in src.terms
    ]
    return terms, conds + list(src.conditions)


def _composite(where: str, name: str, raw: dict) -> Composite:
    w = f"{where} [channels.{name}]"
    unknown = set(raw) - {"terms", "op", "max_age", "conditions"}
    if unknown:
        raise ProfileError(
            f"{w}: unknown key(s) {sorted(unknown)} for a composite; allowed: conditions, max_age, op, terms"
        )
    op = raw.get("op", "sum")
    if op not in ("sum", "product"):
        raise ProfileError(f'{w}: \'op\' must be "sum" or "product", got {op!r}')
    conds_raw = raw.get("conditions", [])
    if not isinstance(conds_raw, list):
        raise ProfileError(f"{w}: 'conditions' must be a list of {{ message, signal }} enum signals")
    conds = []
    for i, c in enumerate(conds_raw):
        if not isinstance(c, dict) or set(c) != {"message", "signal"}:
            raise ProfileError(f"{w}: conditions[{i}] must be {{ message = ..., signal = ... }}")
        for key in ("message", "signal"):  # (a number or a list here went on to a TypeError)
            if not isinstance(c[key], str) or not c[key]:
                raise ProfileError(
                    f"{w}: conditions[{i}]: '{key}' must be a {key} name (a string), got {_short(c[key])}"
                )
        conds.append(ChannelMap(TERM, c["message"], c["signal"], "1", where=f"{w} conditions[{i}]"))
    terms_raw = raw.get("terms")
    if not isinstance(terms_raw, list) or not terms_raw:
        raise ProfileError(f"{w}: 'terms' must be a non-empty list of {{ message, signal, unit, weight }}")
    terms = []
    for i, t in enumerate(terms_raw):
        tw = f"{w} terms[{i}]"
        if not isinstance(t, dict):
            raise ProfileError(f"{tw}: must be a table with message, signal, unit (and weight, when)")
        t = dict(t)
        weight = _num(tw, "weight", t.pop("weight", 1.0))
        when = None
        if "when" in t:
            wv = t.pop("when")
            if (
                not isinstance(wv, dict)
                or set(wv) != {"condition", "values"}
                or not isinstance(wv["condition"], int)
                or not 0 <= wv["condition"] < len(conds)
                or not isinstance(wv["values"], list)
                or not all(isinstance(x, int) for x in wv["values"])
            ):
                raise ProfileError(
                    f"{tw}: 'when' must be {{ condition = K, values = [...] }}, K indexing 'conditions' "
                    f"(0 to {len(conds) - 1})"
                )
            when = (wv["condition"], frozenset(wv["values"]))
        if "alt" in t:
            raise ProfileError(f"{tw}: a term cannot have an 'alt'")
        terms.append(Term(_channel(where, TERM, t, nested=True, label=f"{name}.terms[{i}]"), weight, when))
    if op == "product" and any(t.when for t in terms):
        raise ProfileError(f"{w}: 'when' applies to op = \"sum\" only")
    max_age = _num(w, "max_age", raw.get("max_age", 0.5))
    if max_age <= 0:
        raise ProfileError(f"{w}: 'max_age' must be positive")
    return Composite(name, op, tuple(terms), tuple(conds), max_age, w)
