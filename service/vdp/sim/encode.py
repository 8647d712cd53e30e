"""CAN encoding through the profile's channel mapping, inverted, and the profile's DBC.

The profile decodes ``si = factor * (v * scale + offset)`` (``factor`` includes the
unit, the sign, the wheel radius for linear wheel speeds and the steering ratio for
a steering-wheel signal; a ``sign_signal`` flips the sign when non-zero).  Here the
inverse: ``v = (si / factor - offset) / scale``, clipped into the signal's DBC range,
so the same simulator can feed any car's DBC.  Unmapped signals of a sent message get
a constant; rolling counters and checksums follow the profile's ``[checks]``.

A channel with a ``fine`` signal is split: the coarse signal takes the point of its
grid that leaves the remainder nearest the middle of the fine signal's range, the fine
signal the remainder (Toyota's STEER_ANGLE rounds to 1.5 deg and STEER_FRACTION
carries the rest, -0.7 to 0.7 deg, as on the real car).

Composite channels (a sum, a weighted sum, a product, pieces chosen by an enum; and the
[drivetrain]'s sources when they are composites themselves) are encoded by
:class:`Composites`: it chooses the enum values and the product's further factors, and
solves the sums for the signals (least squares with the signals' ranges as bounds), so
that decoding gives the channel's value back within the signals' quantisation.  A single
-signal [drivetrain] source (drive_torque, brake_torque, brake_pressure) is encoded
directly from the simulator's value of it, as before.
"""

from __future__ import annotations

import itertools
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ProfileError
from ..io import dbcfix
from ..io.checks import vdp_checksum
from ..io.signals import check_fine
from ..profile import ChannelMap, Composite, Profile

log = logging.getLogger(__name__)

# Unmapped signals that a receiver may validate: a good 3D GNSS fix.
CONSTANTS = {"FIX_TYPE": 3, "NUM_SATS": 12}
DEFAULT_CYCLE_MS = 10


def signal_range(sig, dbc_range: bool = True) -> tuple[float, float]:
    """Physical range a signal can carry: its DBC [min|max] (unless ``dbc_range`` is false)
    within what its bits can hold."""
    lo, hi = float("-inf"), float("inf")
    if not sig.is_float:
        n = sig.length
        rmin, rmax = (-(1 << (n - 1)), (1 << (n - 1)) - 1) if sig.is_signed else (0, (1 << n) - 1)
        a, b = rmin * sig.scale + sig.offset, rmax * sig.scale + sig.offset
        lo, hi = min(a, b), max(a, b)
    mn, mx = (sig.minimum, sig.maximum) if dbc_range else (None, None)
    tol = abs(sig.scale) * 1e-3
    if not sig.is_float and ((mn is not None and mn < lo - tol) or (mx is not None and mx > hi + tol)):
        return lo, hi  # a DBC range the bits cannot reach is not a physical range (as the decoder's limits())
    if not (mn == 0 and mx == 0):  # [0|0] in a DBC means "no range given"
        if mn is not None:
            lo = max(lo, float(mn))
        if mx is not None:
            hi = min(hi, float(mx))
    return lo, hi


def clip(v: float, lo: float, hi: float) -> float:
    return lo if v < lo else (hi if v > hi else v)


@dataclass
class SignalPlan:
    signal: str
    channel: str
    inv_factor: float  # 1 / ChannelMap.factor
    scale: float
    offset: float
    lo: float
    hi: float
    sign_signal: str | None = None
    fine: str | None = None  # the finer signal added to this one
    fine_lo: float = 0.0
    fine_hi: float = 0.0
    grid: float = 0.0  # the coarse signal's DBC offset: its values are grid + k * step
    step: float = 1.0  # the coarse signal's DBC step (0: a float signal)
    active: tuple[float, float] | None = None  # a status flag from an enum: its (on, off) values

    def decoded(self, si: float) -> float:
        """The canonical value a decoder reads back after :meth:`raw` of ``si`` (range and
        quantisation; not for ``fine`` pairs)."""
        q = si * self.inv_factor
        neg = self.sign_signal is not None and q < 0.0
        if neg:
            q = -q
        v = clip((q - self.offset) / self.scale, self.lo, self.hi)
        if self.step > 0:
            v = self.grid + round((v - self.grid) / self.step) * self.step  # as cantools rounds
        out = (v * self.scale + self.offset) / self.inv_factor
        return -out if neg else out

    @property
    def si_step(self) -> float:
        """One step of the signal in canonical units (0 for a float signal)."""
        return abs(self.step * self.scale / self.inv_factor)

    def si_range(self) -> tuple[float, float]:
        """The canonical values the signal can carry."""
        a = (self.lo * self.scale + self.offset) / self.inv_factor
        b = (self.hi * self.scale + self.offset) / self.inv_factor
        lo, hi = min(a, b), max(a, b)
        if self.sign_signal is not None:
            m = max(abs(lo), abs(hi))
            return -m, m
        return lo, hi

    def raw(self, si: float, out: dict) -> None:
        """Put the DBC physical value of canonical ``si`` into ``out`` (and the sign flag)."""
        if self.active is not None:
            out[self.signal] = self.active[0] if si > 0.5 else self.active[1]
            return
        q = si * self.inv_factor
        if self.sign_signal is not None:
            flip = q < 0.0
            out[self.sign_signal] = 1 if flip else 0
            if flip:
                q = -q
        v = (q - self.offset) / self.scale
        if self.fine is None:
            out[self.signal] = self.lo if v < self.lo else (self.hi if v > self.hi else v)
            return
        mid = 0.5 * (self.fine_lo + self.fine_hi)
        c = clip(self.grid + round((v - mid - self.grid) / self.step) * self.step, self.lo, self.hi)
        out[self.signal] = c
        out[self.fine] = clip(v - c, self.fine_lo, self.fine_hi)


@dataclass
class MessagePlan:
    name: str
    frame_id: int
    is_extended: bool
    is_fd: bool
    period_ms: int
    message: object  # cantools Message
    base: dict  # constant values of unmapped signals
    signals: list[SignalPlan] = field(default_factory=list)
    counter: str | None = None
    counter_modulo: int = 16
    checksum: bool = False  # vdp checksum in byte 7
    phase_ms: int = 0
    count: int = 0  # frames encoded so far (drives the counter)
    solved: list[tuple[SignalPlan, int]] = field(default_factory=list)  # signals of composites: variable index
    conds: list[tuple[str, int, float, float]] = field(default_factory=list)  # (enum signal, index, scale, offset)
    targets: tuple[str, ...] = ()  # the channels the composites' solution needs

    @property
    def channels(self) -> list[str]:
        return [s.channel for s in self.signals] + list(self.targets)


def load_dbc(path: Path):
    if not Path(path).is_file():
        raise ProfileError(f"{path}: DBC file does not exist")
    return dbcfix.load(path)


class Encoder:
    """Turns canonical channel values into frames of the profile's DBC."""

    def __init__(self, profile: Profile, db=None):
        self.profile = profile
        if db is None:
            from ..io.decoder import load_dbc as load_profile_dbc

            db = load_profile_dbc(profile)  # the profile's DBC(s), merged as the decoder sees them
        self.db = db
        self.plans: list[MessagePlan] = []
        by_name: dict[str, MessagePlan] = {}
        for cm in profile.channels.values():
            for m in (cm, cm.alt):
                if m is not None:
                    self._add(m, by_name)
        # What the composites must come to: the [drivetrain]'s sources (the simulator has their
        # values; the axle torques built from them follow), and every other composite channel.
        targets: list[tuple[str, float, Composite]] = []  # (value to read, its gain, definition)
        built = set()
        sources = getattr(profile, "sources", {}) or {}
        if "drive_torque" in sources:
            built = {"wheel_torque_front", "wheel_torque_rear"}  # made by [drivetrain] from the sources
        for name, src in sources.items():
            read, gain = name, 1.0
            if name == "brake_pressure":  # the simulator's brake torque, as a pressure
                read, gain = "brake_torque", profile.drivetrain.brake_gain / 1e5
            if not built:
                continue  # a brake signal alone makes no axle torque: nothing reads it
            if isinstance(src, Composite):
                targets.append((read, 1.0 / gain, src))
            else:
                self._add(src, by_name, source_gain=gain)
        for comp in getattr(profile, "composites", {}).values():
            if comp.channel not in built:
                targets.append((comp.channel, 1.0, comp))
        self.composites = Composites(self, targets, by_name) if targets else None
        self._checks(by_name)
        self.plans = sorted(by_name.values(), key=lambda p: p.frame_id)
        # Fixed phases inside each period so the messages interleave like on a real bus.
        for j, p in enumerate(self.plans):
            p.phase_ms = (1 + 3 * j) % p.period_ms
        log.debug(
            "encoder: %d messages: %s",
            len(self.plans),
            ", ".join(f"{p.name}@{p.period_ms}ms+{p.phase_ms}" for p in self.plans),
        )

    @property
    def frame_ids(self) -> set[int]:
        return {m.frame_id for m in self.db.messages}

    def _message(self, cm: ChannelMap):
        try:
            return self.db.get_message_by_name(cm.message)
        except KeyError:
            raise ProfileError(f"{cm.where}: message '{cm.message}' is not in {self.profile.dbc}") from None

    def _add(self, cm: ChannelMap, by_name: dict[str, MessagePlan], source_gain: float = 1.0) -> None:
        sp = self.signal_plan(cm, by_name, source_gain)
        plan = by_name[cm.message]
        if any(s.signal == cm.signal for s in plan.signals):
            return  # one signal feeding two channels (e.g. a shared wheel speed): encode once
        plan.signals.append(sp)

    def message_plan(self, cm: ChannelMap, by_name: dict[str, MessagePlan]) -> MessagePlan:
        """The plan of ``cm``'s message (made on first use)."""
        msg = self._message(cm)
        if msg.is_multiplexed():
            raise ProfileError(
                f"{cm.where}: message '{cm.message}' is multiplexed; the simulator cannot encode multiplexed messages"
            )
        plan = by_name.get(msg.name)
        if plan is None:
            base = {}
            for sig in msg.signals:
                lo, hi = signal_range(sig)
                base[sig.name] = clip(float(CONSTANTS.get(sig.name, 0)), lo, hi)
            period = msg.cycle_time or DEFAULT_CYCLE_MS
            if not msg.cycle_time:
                log.info(
                    "%s: message %s has no cycle time; sending it every %d ms",
                    self.profile.dbc,
                    msg.name,
                    DEFAULT_CYCLE_MS,
                )
            # a payload over 8 bytes can only travel as CAN FD, whether or not the DBC says so
            is_fd = bool(msg.is_fd) or msg.length > 8
            plan = MessagePlan(msg.name, msg.frame_id, msg.is_extended_frame, is_fd, int(period), msg, base)
            by_name[msg.name] = plan
        return plan

    def signal_plan(self, cm: ChannelMap, by_name: dict[str, MessagePlan], source_gain: float = 1.0) -> SignalPlan:
        """How ``cm``'s signal is encoded (its message's plan made, its status set valid)."""
        plan = self.message_plan(cm, by_name)
        msg = plan.message
        try:
            sig = msg.get_signal_by_name(cm.signal)
        except KeyError:
            raise ProfileError(f"{cm.where}: signal '{cm.signal}' is not in message '{msg.name}'") from None
        if cm.sign_signal is not None and cm.sign_signal not in {s.name for s in msg.signals}:
            raise ProfileError(f"{cm.where}: sign_signal '{cm.sign_signal}' is not in message '{msg.name}'")
        if cm.status is not None:  # send the status a receiver reads as valid
            sig_name, values, ok_if_in = cm.status
            if sig_name not in plan.base:
                raise ProfileError(f"{cm.where}: status signal '{sig_name}' is not in message '{msg.name}'")
            if ok_if_in:
                plan.base[sig_name] = min(values)
            else:
                plan.base[sig_name] = next(v for v in range(1 << 16) if v not in values)
        lo, hi = signal_range(sig)
        if cm.range is not None:  # the profile's range replaces the DBC's, within what the bits carry
            full = signal_range(sig, dbc_range=False)
            lo, hi = max(cm.range[0], full[0]), min(cm.range[1], full[1])
        channel = "brake_torque" if cm.channel == "brake_pressure" else cm.channel
        sp = SignalPlan(
            cm.signal,
            channel,
            1.0 / (cm.factor(self.profile.vehicle) * source_gain),
            cm.scale,
            cm.offset,
            lo,
            hi,
            cm.sign_signal,
            grid=float(sig.offset),
            step=0.0 if sig.is_float else abs(float(sig.scale)),
        )
        if cm.active is not None:  # on: the first raw value that means on; off: the first that does not
            off = next(v for v in range(1 << 16) if v not in cm.active)
            sp.active = tuple(float(v * sig.scale + sig.offset) for v in (min(cm.active), off))
        if cm.fine is not None:
            try:
                fine = msg.get_signal_by_name(cm.fine)
            except KeyError:
                raise ProfileError(f"{cm.where}: fine signal '{cm.fine}' is not in message '{msg.name}'") from None
            check_fine(cm.where, msg, sig, fine)
            sp.fine, (sp.fine_lo, sp.fine_hi) = cm.fine, signal_range(fine)
        return sp

    def _checks(self, by_name: dict[str, MessagePlan]) -> None:
        for name, chk in self.profile.checks.items():
            plan = by_name.get(name)
            if plan is None:
                log.debug("checks: message %s is not sent by the simulator", name)
                continue
            sigs = {s.name: s for s in plan.message.signals}
            where = f"{self.profile.path} [checks.{name}]"
            if chk.counter is not None:
                if chk.counter not in sigs:
                    raise ProfileError(f"{where}: counter '{chk.counter}' is not in message '{name}'")
                plan.counter = chk.counter
                plan.counter_modulo = 1 << sigs[chk.counter].length  # as the decoder expects (io.decoder)
            if chk.checksum is not None and chk.checksum_kind == "vdp":
                s = sigs.get(chk.checksum)
                if s is None:
                    raise ProfileError(f"{where}: checksum '{chk.checksum}' is not in message '{name}'")
                in_byte7 = s.length == 8 and (
                    (s.byte_order == "little_endian" and s.start == 56)
                    or (s.byte_order == "big_endian" and s.start == 63)
                )
                if not in_byte7 or plan.message.length < 8:
                    raise ProfileError(f"{where}: the vdp checksum must be an 8-bit signal in byte 7")
                plan.checksum = True

    def encode(self, plan: MessagePlan, values: dict[str, float]) -> bytes:
        """Payload of the next frame of ``plan``; advances its rolling counter."""
        data = dict(plan.base)
        for sp in plan.signals:
            sp.raw(values[sp.channel], data)
        if plan.targets:
            x, conds = self.composites.solve(values)
            for sp, j in plan.solved:
                sp.raw(x[j], data)
            for name, j, scale, offset in plan.conds:
                data[name] = conds[j] * scale + offset
        if plan.counter is not None:
            data[plan.counter] = plan.count % plan.counter_modulo
        plan.count += 1
        payload = plan.message.encode(data, scaling=True, padding=False, strict=False)
        if plan.checksum:
            payload = bytearray(payload)
            payload[7] = 0
            payload[7] = vdp_checksum(plan.frame_id, payload)
            payload = bytes(payload)
        return payload


MAX_COMBOS = 256  # enum value combinations tried per solve


@dataclass
class _Term:
    weight: float
    free: int  # the variable the sum is solved for
    fixed: tuple[int, ...]  # further factors: variables set before the solve
    when: tuple[int, frozenset[int]] | None  # (enum index, its values)


class Composites:
    """Encodes composite channels: from the values they must come to (``targets``), the value
    of every signal they read.

    Each signal is a variable in canonical units (its ChannelMap's value).  Per solve:

    1. the enum (condition) values: the combination used last if it still works, else the
       first that does, in the order the profile lists the pieces' values (and, last, a
       value in no piece's list, which turns them all off);
    2. a product's further factors start at 1 (or the nearest value their signal carries)
       and grow, on their signal's grid, when the first factor would leave its range: an
       engine torque times a gear ratio takes a lower gear for more torque;
    3. the sums, linear in the remaining variables, are solved by least squares (the
       smallest solution when there are more signals than channels), within the signals'
       ranges when the plain solution leaves them.
    """

    def __init__(self, enc: Encoder, targets: list[tuple[str, float, Composite]], by_name: dict):
        self.reads = tuple(r for r, _, _ in targets)
        self.gains = np.array([g for _, g, _ in targets])
        keys: dict[tuple[str, str], int] = {}  # (message, signal) -> variable
        self.plans: list[SignalPlan] = []
        maps: list[ChannelMap] = []
        role: dict[int, str] = {}
        cond_keys: dict[tuple[str, str], int] = {}
        self.cond_values: list[list[int]] = []
        cond_range: list[tuple[int, int]] = []
        self.terms: list[list[_Term]] = []
        for _, _, comp in targets:

            def var(cm: ChannelMap, how: str, comp=comp) -> int:
                key = (cm.message, cm.signal)
                if key in cond_keys:
                    raise ProfileError(f"{comp.where}: {cm.message}.{cm.signal} is both an enum condition and a term")
                j = keys.get(key)
                if j is None:
                    sp = enc.signal_plan(cm, by_name)
                    plain = next((p.channel for p in by_name[cm.message].signals if p.signal == cm.signal), None)
                    if plain is not None:
                        raise ProfileError(
                            f"{cm.where}: the simulator cannot encode {cm.message}.{cm.signal}: it is also "
                            f"{plain}'s signal, and one value cannot serve both"
                        )
                    j = keys[key] = len(self.plans)
                    self.plans.append(sp)
                    maps.append(cm)
                    role[j] = how
                elif _mapping(maps[j], enc) != _mapping(cm, enc):
                    raise ProfileError(
                        f"{cm.where}: the simulator cannot encode {cm.message}.{cm.signal}: it is read with "
                        f"another unit, scale, offset or sign in {maps[j].where}"
                    )
                if role[j] != how:
                    raise ProfileError(
                        f"{comp.where}: the simulator cannot encode {cm.message}.{cm.signal}: it is a further "
                        f"factor of a product in one place and a term of a sum in another"
                    )
                return j

            conds = []
            for cm in comp.conditions:
                key = (cm.message, cm.signal)
                if key in keys:
                    raise ProfileError(f"{comp.where}: {cm.message}.{cm.signal} is both an enum condition and a term")
                k = cond_keys.get(key)
                if k is None:
                    k = cond_keys[key] = len(self.cond_values)
                    self.cond_values.append([])
                    plan = enc.message_plan(cm, by_name)
                    sig = plan.message.get_signal_by_name(cm.signal)
                    lo, hi = signal_range(sig)
                    r = sorted(round((b - sig.offset) / sig.scale) for b in (lo, hi))
                    cond_range.append((int(r[0]), int(r[1])))
                    plan.conds.append((cm.signal, k, float(sig.scale), float(sig.offset)))
                conds.append(k)
            terms = []
            if comp.op == "product":
                first = comp.terms[0]
                rest = first.factors + tuple(m for t in comp.terms[1:] for m in (t.map, *t.factors))
                terms.append(_Term(first.weight, var(first.map, "free"), tuple(var(m, "fixed") for m in rest), None))
            else:
                for t in comp.terms:
                    when = None
                    if t.when is not None:
                        k = conds[t.when[0]]
                        when = (k, t.when[1])
                        for v in sorted(t.when[1]):
                            if v not in self.cond_values[k] and cond_range[k][0] <= v <= cond_range[k][1]:
                                self.cond_values[k].append(v)
                    terms.append(_Term(t.weight, var(t.map, "free"), tuple(var(m, "fixed") for m in t.factors), when))
            self.terms.append(terms)
        for k, (lo, hi) in enumerate(cond_range):  # and a value that turns every piece off
            off = next((v for v in range(lo, min(hi, lo + 4096) + 1) if v not in self.cond_values[k]), None)
            if off is not None:
                self.cond_values[k].append(off)
        self.combos = list(itertools.islice(itertools.product(*self.cond_values), MAX_COMBOS + 1))
        if len(self.combos) > MAX_COMBOS:
            raise ProfileError(
                f"{targets[0][2].where}: the simulator tries at most {MAX_COMBOS} combinations of enum values"
            )
        self.n = len(self.plans)
        self.free = sorted({t.free for ts in self.terms for t in ts})
        self.ranges = [p.si_range() for p in self.plans]
        self.lo = np.array([self.ranges[j][0] for j in self.free])
        self.hi = np.array([self.ranges[j][1] for j in self.free])
        self.unit = [self.plans[j].decoded(_nominal(self.ranges[j])) for j in range(self.n)]
        self._last = self.combos[0]
        self._key: tuple | None = None
        self._out: tuple[list[float], tuple[int, ...]] = ([0.0] * self.n, self._last)
        for plan in by_name.values():  # which messages carry variables, and what they need
            for j, (sp, cm) in enumerate(zip(self.plans, maps)):
                if cm.message == plan.name:
                    plan.solved.append((sp, j))
            if plan.solved or plan.conds:
                plan.targets = self.reads

    def solve(self, values: dict) -> tuple[list[float], tuple[int, ...]]:
        """(each variable's value, each enum's raw value) for the targets' ``values``."""
        key = tuple(values[r] for r in self.reads)
        if key == self._key:
            return self._out
        target = np.array(key) * self.gains
        best = None
        for combo in (self._last, *self.combos):
            x, miss = self._solve(target, combo)
            if miss <= 1e-9 * (1.0 + float(np.abs(target).max(initial=0.0))):
                best = (x, combo, 0.0)
                break
            if best is None or miss < best[2]:
                best = (x, combo, miss)
        x, combo, _ = best
        self._last, self._key, self._out = combo, key, (x, combo)
        return self._out

    def _solve(self, target: np.ndarray, combo: tuple[int, ...]) -> tuple[list[float], float]:
        """The variables for one enum combination, and how far the channels miss their targets."""
        c = list(self.unit)
        col = {j: i for i, j in enumerate(self.free)}
        for _ in range(8):  # grow the further factors until the first factors fit their range
            A = np.zeros((len(self.terms), len(self.free)))
            for i, terms in enumerate(self.terms):
                for t in terms:
                    if t.when is not None and combo[t.when[0]] not in t.when[1]:
                        continue
                    A[i, col[t.free]] += t.weight * math.prod(c[k] for k in t.fixed)
            sol = np.linalg.lstsq(A, target, rcond=None)[0]
            grown = False
            for terms in self.terms:
                for t in terms:
                    v = sol[col[t.free]]
                    lo, hi = self.ranges[t.free]
                    if t.fixed and not lo <= v <= hi:
                        grown = self._grow(t, v, c) or grown
            if not grown:
                break
        if not (np.all(sol >= self.lo) and np.all(sol <= self.hi)):
            if len(self.free) == 1:  # one signal: the nearest value within its range is the best
                sol = np.clip(sol, self.lo, self.hi)
            else:
                from scipy.optimize import lsq_linear

                lo, hi = self.lo, np.maximum(self.hi, self.lo + 1e-12)
                sol = lsq_linear(A, target, bounds=(lo, hi), method="bvls").x
        x = list(c)
        for j, i in col.items():
            x[j] = float(sol[i])
        miss = float(np.abs(A @ sol - target).max(initial=0.0))
        return x, miss

    def _grow(self, t: _Term, v: float, c: list[float]) -> bool:
        """Change one further factor of ``t`` so that its first factor, ``v`` now, can fit its
        range: turn its sign if ``v`` has one the first factor cannot take, else make it larger
        (on its signal's grid); the next factor when one is at the end of its range."""
        lo, hi = self.ranges[t.free]
        room = 0.9 * (hi if v > 0 else -lo)
        for k in t.fixed:
            flo, fhi = self.ranges[k]
            plan = self.plans[k]
            if room <= 0:  # the first factor cannot take this sign: a further one turns
                flip = plan.decoded(clip(-c[k], flo, fhi))
                if flip * c[k] < 0:
                    c[k] = flip
                    return True
                continue
            if c[k] == 0:
                continue
            want = c[k] * abs(v) / room
            new = plan.decoded(clip(want, flo, fhi))
            if abs(new) < abs(want):  # rounded down onto the grid: one step further
                new = plan.decoded(clip(new + math.copysign(plan.si_step, new), flo, fhi))
            if abs(new) > abs(c[k]) and new * c[k] > 0:
                c[k] = new
                return True
        return False


def _mapping(cm: ChannelMap, enc: Encoder) -> tuple:
    return (cm.factor(enc.profile.vehicle), cm.scale, cm.offset, cm.sign_signal, cm.fine)


def _nominal(rng: tuple[float, float]) -> float:
    """A further factor's starting value: 1, or the nearest value its signal carries (not 0)."""
    lo, hi = rng
    if lo <= 1.0 <= hi:
        return 1.0
    v = clip(1.0, lo, hi)
    return v if v != 0 else (hi if hi > 0 else lo)
