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
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ProfileError
from ..io import dbcfix
from ..io.checks import vdp_checksum
from ..io.decoder import check_fine
from ..profile import ChannelMap, Profile

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
    step: float = 1.0  # the coarse signal's DBC step

    def raw(self, si: float, out: dict) -> None:
        """Put the DBC physical value of canonical ``si`` into ``out`` (and the sign flag)."""
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

    @property
    def channels(self) -> list[str]:
        return [s.channel for s in self.signals]


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
        for comp in getattr(profile, "composites", {}).values():
            if comp.conditions or any(
                t.map.channel not in ("drive_torque", "brake_torque", "brake_pressure") for t in comp.terms
            ):
                raise ProfileError(
                    f"{comp.where}: the simulator encodes composite channels built by [drivetrain] only "
                    f"(drive_torque, brake_torque, brake_pressure), not general terms or conditions"
                )
            for t in comp.terms:
                gain = 1.0
                if t.map.channel == "brake_pressure":  # the simulator's brake torque, as a pressure
                    gain = profile.drivetrain.brake_gain / 1e5
                self._add(t.map, by_name, source_gain=gain)
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
        if any(s.signal == cm.signal for s in plan.signals):
            return  # one signal feeding two channels (e.g. a shared wheel speed): encode once
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
        )
        if cm.fine is not None:
            try:
                fine = msg.get_signal_by_name(cm.fine)
            except KeyError:
                raise ProfileError(f"{cm.where}: fine signal '{cm.fine}' is not in message '{msg.name}'") from None
            check_fine(cm.where, msg, sig, fine)
            sp.fine, (sp.fine_lo, sp.fine_hi) = cm.fine, signal_range(fine)
            sp.grid, sp.step = float(sig.offset), abs(float(sig.scale))
        plan.signals.append(sp)

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
