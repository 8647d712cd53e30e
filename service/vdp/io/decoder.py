"""CAN frames -> canonical SI samples, per a vehicle profile and its DBC.

:class:`FrameDecoder` checks the profile's mapping against the DBC once, then
turns each frame into ``[(channel index, SI value), ...]``.  Bad frames never
raise: they are counted in :class:`DecodeStats` by arbitration ID and kind,
and a frame with any bad mapped signal yields nothing (no partial samples).

Hot path: one dict lookup finds a frame's plan (unknown IDs stop there), and the
plan's extractor (:mod:`vdp.io.signals`: the bit-level half, frames -> signal values,
generated code for plain integer signals, cantools for multiplexed messages and float
signals) yields the values this module maps to channels.  A channel with a
``fine`` signal (coarse + fine layouts) sums the two in the output loop.  What goes
beyond one signal per channel (composite channels, status and plausibility) lives in
:mod:`vdp.io.mapping`; the decoder hands it the decoded values.
"""

from __future__ import annotations

import difflib
import logging
import math
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import cantools

from .. import channels
from ..errors import ProfileError
from ..profile import Profile
from ..units import UNIT_FACTORS
from . import dbcfix
from .checks import counter_ok, vdp_checksum
from .logs import EXT_KEY as _EXT
from .logs import channel_keys
from .mapping import Composite as _Composite
from .mapping import invalid as _invalid
from .signals import cantools_extractor as _cantools_extractor
from .signals import check_fine, compile_extractor, limits  # noqa: F401  (limits: the decoder's API)
from .signals import nothing as _nothing

log = logging.getLogger(__name__)

MAX_UNKNOWN = 4096  # distinct unknown ids counted one by one
KINDS = ("unknown_id", "dlc", "remote", "error_frame", "range", "nonfinite", "mux", "counter", "checksum", "decode")
BAD_RUN_INVALID = 3  # consecutive counter/checksum failures that flag a message invalid
ALT_AFTER_CYCLES = 5.0  # primary silent this many cycle times: use the alternative source
DEFAULT_CYCLE = 0.1  # [s] until a message without GenMsgCycleTime has shown its period
ACTIVE = object()  # marks a status flag read from an enum's raw values (profile.ChannelMap.active)


class DecodeStats:
    """Counters of one decoder.  Written by the decoding thread, read by anyone:
    ``as_dict`` copies the dicts first (an atomic operation in CPython)."""

    def __init__(self, names: dict[int, str], plain: list[_Plan]):
        self.frames = 0  # frames offered
        self.decoded = 0  # frames accepted (all mapped signals good)
        self.error_frames = 0
        self.skipped_channel = 0  # frames of another bus channel
        self.other_channels: dict[str, int] = {}  # those channels' names (the first 16) -> frames
        self.unknown: dict[int, int] = {}  # plan key -> count (the first MAX_UNKNOWN distinct ids)
        self.unknown_other = 0  # frames of further unknown ids: a burst of random ids cannot grow the table
        self.errors: dict[tuple[int, str], int] = {}  # (plan key, kind) -> count
        self._counted = [0] * channels.N  # samples of plans with conditional outputs
        self._plain = plain  # plans that emit every output of every good frame: counted per frame
        self.invalid: tuple[str, ...] = ()  # channels flagged invalid right now
        self.invalid_samples: dict[tuple[str, str], int] = {}  # (channel, reason) -> values dropped
        self.invalid_range: dict[tuple[str, str], tuple[float, float]] = {}  # ... and the range they spanned
        self.padded = 0  # short frames given their trailing zero bytes back ([can] pad_short)
        self._names = names  # plan key -> DBC message name

    @property
    def samples(self) -> list[int]:
        """Samples emitted per channel index."""
        out = list(self._counted)
        for plan in self._plain:
            for o in plan.plain or ():
                out[o[0]] += plan.good
        return out

    def add_unknown(self, counts: dict[int, int], other: int = 0) -> None:
        """Frames of undecoded ids that never reached decode() (filtered at the source): by id,
        and ``other`` frames of ids the source counted without keeping them apart."""
        self.unknown_other += other
        self.frames += other
        unk = self.unknown
        for key, n in counts.items():
            if key in unk or len(unk) < MAX_UNKNOWN:
                unk[key] = unk.get(key, 0) + n
            else:
                self.unknown_other += n
            self.frames += n

    def error(self, key: int, kind: str) -> None:
        k = (key, kind)
        self.errors[k] = self.errors.get(k, 0) + 1

    def as_dict(self, top: int = 10) -> dict[str, Any]:
        unknown = self.unknown.copy()
        errors = self.errors.copy()
        by_id: dict[str, dict[str, int]] = {}
        by_kind: dict[str, int] = {}
        for (key, kind), n in sorted(errors.items()):
            by_id.setdefault(_hex(key), {})[kind] = n
            by_kind[kind] = by_kind.get(kind, 0) + n
        by_kind["unknown_id"] = sum(unknown.values()) + self.unknown_other
        by_kind["error_frame"] = self.error_frames
        return {
            "frames": self.frames,
            "decoded": self.decoded,
            "skipped_channel": self.skipped_channel,
            "error_frames": self.error_frames,
            "unknown_ids": [
                {"id": _hex(k), "count": n} for k, n in sorted(unknown.items(), key=lambda kv: -kv[1])[:top]
            ],
            "unknown_distinct": len(unknown),
            "unknown_untracked": self.unknown_other,  # frames of ids beyond the first MAX_UNKNOWN
            "errors": by_id,
            "errors_by_kind": {k: v for k, v in by_kind.items() if v},
            "messages": {_hex(k): self._names[k] for k, _ in errors if k in self._names},
            "samples": {name: n for name, n in zip(channels.NAMES, self.samples) if n},
            "invalid_channels": list(self.invalid),
            "invalid_samples": _by_channel(self.invalid_samples.copy()),
            "padded": self.padded,
        }


def _by_channel(counts: dict[tuple[str, str], int]) -> dict[str, dict[str, int]]:
    out: dict[str, dict[str, int]] = {}
    for (chan, why), n in sorted(counts.items()):
        out.setdefault(chan, {})[why] = n
    return out


def _hex(key: int) -> str:
    return f"0x{key & 0x1FFFFFFF:08X}" if key & _EXT else f"0x{key:03X}"


class _Plan:
    """Everything needed to decode one arbitration id, plus its live state."""

    __slots__ = (
        "bad_run",
        "channels",
        "checked",
        "cnt_mod",
        "cnt_pos",
        "cs_pos",
        "extract",
        "fixed_period",
        "flagged",
        "frame_id",
        "good",
        "invalid",
        "key",
        "last_good",
        "last_seen",
        "length",
        "name",
        "outputs",
        "period",
        "plain",
        "prev_count",
    )

    def __init__(self, key: int, name: str, frame_id: int, length: int, cycle_ms: float | None):
        self.key, self.name, self.frame_id, self.length = key, name, frame_id, length
        self.extract: Callable[[Any], tuple] = _nothing
        # (channel, value slot, mul, add, sign slot, primary plan if an alt, fine slot); -1: none
        self.outputs: list[tuple[int, int, float, float, int, _Plan | None, int, tuple | None]] = []
        self.cnt_pos = self.cs_pos = -1
        self.cnt_mod = 16
        self.prev_count: int | None = None
        self.bad_run = 0
        self.flagged = 0  # times it was flagged invalid
        self.invalid = False
        self.last_good: float | None = None
        self.last_seen: float | None = None
        self.fixed_period = bool(cycle_ms and cycle_ms > 0)
        self.period = cycle_ms / 1000.0 if cycle_ms and cycle_ms > 0 else DEFAULT_CYCLE
        self.channels: list[str] = []  # channels this message is the primary source of
        self.checked = False  # has a counter or checksum to check
        self.plain: list[tuple[int, int, float, float]] | None = None  # outputs, if all unconditional
        self.good = 0  # frames accepted

    def stale(self, t: float) -> bool:
        """True when this (primary) message can no longer be trusted to be current."""
        return self.invalid or self.last_good is None or t - self.last_good > ALT_AFTER_CYCLES * self.period


class FrameDecoder:
    """Decode CAN frames into canonical SI samples for one vehicle profile."""

    def __init__(self, profile: Profile, db: cantools.database.Database | None = None):
        self.profile = profile
        if db is None:
            db = load_dbc(profile)
        self.db = db
        self._dbc_name = " + ".join(Path(d).name for d in getattr(profile, "dbcs", (profile.dbc,)))
        self._want = channel_keys(profile.bus_channel) if profile.bus_channel else None
        self._pad = bool(getattr(profile, "pad_short", False))
        self._validate()
        self._plans: dict[int, _Plan] = {}
        self.ranges: dict[tuple[str, str], tuple[float, float]] = {}
        self._virtual: list[tuple[_Composite, int]] = []  # index - channels.N -> (composite, term)
        self._composites: dict[str, _Composite] = {}
        self._build()
        self.stats = DecodeStats(
            {k: p.name for k, p in self._plans.items()}, [p for p in self._plans.values() if p.plain is not None]
        )
        self._lock = threading.Lock()  # only for the rare valid <-> invalid transitions

    # -- construction ------------------------------------------------------
    def _message(self, where: str, name: str) -> Any:
        try:
            return self.db.get_message_by_name(name)
        except KeyError:
            names = [m.name for m in self.db.messages]
            close = (
                difflib.get_close_matches(name, names, n=5, cutoff=0.5)
                or [n for n in names if name.lower() in n.lower() or n.lower() in name.lower()][:5]
            )
            hint = (
                f"messages with similar names: {', '.join(close)}"
                if close
                else f"it has {len(names)} messages, none with a similar name"
            )
            raise ProfileError(f"{where}: message '{name}' is not in {self._dbc_name}; {hint}") from None

    def _signal(self, where: str, msg: Any, name: str, role: str = "signal") -> Any:
        try:
            return msg.get_signal_by_name(name)
        except KeyError:
            names = [s.name for s in msg.signals]
            close = difflib.get_close_matches(name, names, n=5, cutoff=0.5)
            hint = f"similar: {', '.join(close)}" if close else f"its signals: {', '.join(names[:30])}"
            raise ProfileError(
                f"{where}: {role} '{name}' is not in message '{msg.name}' of {self._dbc_name}; {hint}"
            ) from None

    def _validate(self) -> None:
        prof = self.profile
        for cmap in prof.channels.values():
            for m in (cmap, cmap.alt):
                if m is None:
                    continue
                msg = self._message(m.where, m.message)
                sig = self._signal(m.where, msg, m.signal)
                if m.sign_signal:
                    self._signal(m.where, msg, m.sign_signal, "sign_signal")
                if m.status:
                    self._signal(m.where, msg, m.status[0], "status signal")
                if m.fine:
                    check_fine(m.where, msg, sig, self._signal(m.where, msg, m.fine, "fine signal"))
                if (
                    sig.unit in UNIT_FACTORS
                    and UNIT_FACTORS[sig.unit] != UNIT_FACTORS[m.unit]
                    and m.scale == 1.0
                    and m.offset == 0.0
                ):
                    log.warning(
                        "%s: DBC gives %s.%s in '%s' but the profile says '%s'",
                        m.where,
                        m.message,
                        m.signal,
                        sig.unit,
                        m.unit,
                    )
            if cmap.alt is not None and cmap.alt.message == cmap.message:
                raise ProfileError(
                    f"{cmap.alt.where}: the alternative source must be another message "
                    f"than the primary '{cmap.message}'"
                )
        for comp in getattr(prof, "composites", {}).values():
            for m in comp.maps:
                msg = self._message(m.where, m.message)
                self._signal(m.where, msg, m.signal)
                if m.sign_signal:
                    self._signal(m.where, msg, m.sign_signal, "sign_signal")
                if m.status:
                    self._signal(m.where, msg, m.status[0], "status signal")
        for name, chk in prof.checks.items():
            where = f"{prof.path} [checks.{name}]"
            msg = self._message(where, name)
            if chk.counter:
                self._signal(where, msg, chk.counter, "counter signal")
            if chk.checksum:
                self._signal(where, msg, chk.checksum, "checksum signal")

    def _plan(self, msg: Any) -> _Plan:
        key = msg.frame_id | _EXT if msg.is_extended_frame else msg.frame_id
        plan = self._plans.get(key)
        if plan is None:
            plan = self._plans[key] = _Plan(key, msg.name, msg.frame_id, msg.length, msg.cycle_time)
        return plan

    def _build(self) -> None:
        prof = self.profile
        # Per message: ordered list of needed signals (name, raw, range-checked).
        needs: dict[int, list[tuple[str, bool, bool]]] = {}
        self.needs = needs  # kept: vdp.io.bulk decodes blocks of frames by the same slots
        outs: dict[int, list[tuple]] = {}
        msgs: dict[int, Any] = {}
        ranges = self.ranges  # the profile's range overrides, (message, signal) -> (lo, hi)
        for cmap in prof.channels.values():
            for m, primary in ((cmap, None), (cmap.alt, cmap)):
                if m is None:
                    continue
                msg = self.db.get_message_by_name(m.message)
                plan = self._plan(msg)
                msgs[plan.key] = msg
                need = needs.setdefault(plan.key, [])
                _need(need, m.signal, raw=m.active is not None, check=m.active is None)
                if m.sign_signal:
                    _need(need, m.sign_signal, raw=False, check=False)
                if m.fine:
                    _need(need, m.fine, raw=False, check=True)
                if m.range is not None:
                    ranges[(msg.name, m.signal)] = m.range
                if m.status is not None:
                    _need(need, m.status[0], raw=True, check=False)
                f = m.factor(prof.vehicle)
                outs.setdefault(plan.key, []).append(
                    (
                        channels.INDEX[cmap.channel],
                        m.signal,
                        f * m.scale if m.active is None else 1.0,
                        f * m.offset if m.active is None else 0.0,
                        m.sign_signal,
                        primary,
                        m.fine,
                        m.status if m.active is None else (ACTIVE, m.active),
                        m.plausible,
                    )
                )
                if primary is None:
                    plan.channels.append(cmap.channel)
        # composite channels: each term and condition is a virtual output (index >= channels.N)
        for comp in getattr(prof, "composites", {}).values():
            state = _Composite(comp)
            for j, m in enumerate(comp.maps):
                is_cond = j >= comp.cond_start
                msg = self.db.get_message_by_name(m.message)
                plan = self._plan(msg)
                msgs[plan.key] = msg
                need = needs.setdefault(plan.key, [])
                _need(need, m.signal, raw=is_cond, check=not is_cond)
                if m.sign_signal:
                    _need(need, m.sign_signal, raw=False, check=False)
                if m.status is not None:
                    _need(need, m.status[0], raw=True, check=False)
                if m.range is not None:
                    ranges[(msg.name, m.signal)] = m.range
                f = 1.0 if is_cond else m.factor(prof.vehicle)
                vidx = channels.N + len(self._virtual)
                self._virtual.append((state, j))
                outs.setdefault(plan.key, []).append(
                    (
                        vidx,
                        m.signal,
                        f * m.scale if not is_cond else 1.0,
                        f * m.offset if not is_cond else 0.0,
                        m.sign_signal,
                        None,
                        m.fine,
                        m.status,
                        m.plausible,
                    )
                )
            self._composites[comp.channel] = state
        for key, msg in msgs.items():
            plan = self._plans[key]
            need = needs[key]
            chk = prof.checks.get(msg.name)
            if chk is not None and chk.check:
                if chk.counter:
                    _need(need, chk.counter, raw=True, check=False)
                    plan.cnt_mod = 1 << msg.get_signal_by_name(chk.counter).length
                if chk.checksum and chk.checksum_kind == "vdp":
                    _need(need, chk.checksum, raw=True, check=False)
            pos = {name: i + 1 for i, (name, _, _) in enumerate(need)}  # slot 0: error kind
            if chk is not None and chk.check:
                plan.cnt_pos = pos[chk.counter] if chk.counter else -1
                plan.cs_pos = pos[chk.checksum] if chk.checksum and chk.checksum_kind == "vdp" else -1
                plan.checked = plan.cnt_pos >= 0 or plan.cs_pos >= 0
            plan.extract = compile_extractor(msg, need, ranges) or _cantools_extractor(msg, need, ranges)
            for idx, sig, mul, add, sign_sig, primary, fine, status, plaus in outs[key]:
                prim_plan = self._plan(self.db.get_message_by_name(primary.message)) if primary else None
                valid = None  # (status slot or -1, values, values mean valid, plausible lo, hi)
                if status is not None and status[0] is ACTIVE:
                    valid = status  # a status flag read from an enum's raw values (decode)
                elif status is not None or plaus is not None:
                    lo, hi = plaus if plaus is not None else (-math.inf, math.inf)
                    if status is not None:
                        valid = (pos[status[0]], status[1], status[2], lo, hi, f"{status[0]}")
                    else:
                        valid = (-1, frozenset(), True, lo, hi, "")
                plan.outputs.append(
                    (
                        idx,
                        pos[sig],
                        mul,
                        add,
                        pos[sign_sig] if sign_sig else -1,
                        prim_plan,
                        pos[fine] if fine else -1,
                        valid,
                    )
                )
            if not msg.is_multiplexed() and all(
                o[0] < channels.N and o[4] < 0 and o[5] is None and o[6] < 0 and o[7] is None for o in plan.outputs
            ):
                plan.plain = [o[:4] for o in plan.outputs]

    # -- decoding ----------------------------------------------------------
    @property
    def ids(self) -> dict[int, str]:
        """Decoded arbitration ids (extended ones with bit 31 set) -> DBC message name."""
        return {k: p.name for k, p in self._plans.items()}

    def decode(self, msg: can.Message) -> list[tuple[int, float]]:
        """``[(channel index, SI value), ...]`` from one frame; ``[]`` if it carries nothing usable."""
        st = self.stats
        st.frames += 1
        if msg.is_error_frame:
            st.error_frames += 1
            return []
        if self._want is not None:
            ch = msg.channel
            if ch is not None and ch not in self._want:
                st.skipped_channel += 1
                oc, name = st.other_channels, str(ch)
                if name in oc or len(oc) < 16:
                    oc[name] = oc.get(name, 0) + 1
                return []
        key = msg.arbitration_id
        if msg.is_extended_id:
            key |= _EXT
        plan = self._plans.get(key)
        if plan is None:
            unk = st.unknown
            if key in unk or len(unk) < MAX_UNKNOWN:
                unk[key] = unk.get(key, 0) + 1
            else:
                st.unknown_other += 1
            return []
        t = msg.timestamp
        if not plan.fixed_period:
            last = plan.last_seen
            if last is not None and t > last:
                # Learn the period; clip gaps so one pause does not make the source look fresh for long.
                plan.period += 0.05 * (min(t - last, 2.0 * plan.period) - plan.period)
        plan.last_seen = t
        if msg.is_remote_frame:
            st.error(key, "remote")
            return []
        data = msg.data
        if len(data) != plan.length:
            if not (self._pad and len(data) < plan.length):
                st.error(key, "dlc")
                return []
            # a log converted from fixed-width byte arrays lost the frame's trailing zero bytes
            data = bytes(data) + bytes(plan.length - len(data))
            st.padded += 1
        try:
            vals = plan.extract(data)
        except Exception:  # never from generated code; cantools may surprise
            log.debug("decoding %s failed", plan.name, exc_info=True)
            st.error(key, "decode")
            return []
        kind = vals[0]
        if plan.checked:
            if kind in {"mux", "decode"}:
                pass
            elif plan.cs_pos >= 0 and vals[plan.cs_pos] != vdp_checksum(plan.frame_id, data):
                kind = "checksum"
                if plan.prev_count is not None:  # its counter is garbage; assume it was the next one
                    plan.prev_count = (plan.prev_count + 1) % plan.cnt_mod
            elif plan.cnt_pos >= 0 and vals[plan.cnt_pos] is not None:
                count = vals[plan.cnt_pos]
                prev, plan.prev_count = plan.prev_count, count
                if not counter_ok(prev, count, plan.cnt_mod):
                    kind = "counter"
            if kind in {"checksum", "counter"}:
                plan.bad_run += 1
                if plan.bad_run == BAD_RUN_INVALID:
                    self._flag(plan, True)
        if kind is not None:
            st.error(key, kind)
            return []
        if plan.invalid:
            self._flag(plan, False)
        plan.bad_run = 0
        plan.last_good = t
        st.decoded += 1
        plan.good += 1
        plain = plan.plain
        if plain is not None:
            return [(idx, vals[pos] * mul + add) for idx, pos, mul, add in plain]
        out = []
        samples = st._counted
        touched = None  # composite channels whose terms this frame carries
        for idx, pos, mul, add, sign_pos, primary, fine_pos, valid in plan.outputs:
            v = vals[pos]
            if v is None or (primary is not None and not primary.stale(t)):
                continue  # not in this mux page, or the primary source is current
            if fine_pos >= 0:
                f = vals[fine_pos]
                if f is None:
                    continue  # the fine part is on another mux page: no whole value in this frame
                v += f
            v = v * mul + add
            if sign_pos >= 0 and vals[sign_pos]:
                v = -v
            if valid is not None and valid[0] is ACTIVE:
                v = 1.0 if v in valid[1] else 0.0  # (v is the raw value: mul 1, add 0)
            elif valid is not None:
                why = _invalid(valid, vals, v)
                if why is not None:  # never becomes a sample; counted per channel and reason
                    if idx >= channels.N:
                        comp, j = self._virtual[idx - channels.N]
                        comp.put(j, None, t)  # the composite waits for a valid term
                        k = (comp.comp.channel, f"{comp.label(j)}: {why}")
                    else:
                        k = (channels.NAMES[idx], why)
                    st.invalid_samples[k] = st.invalid_samples.get(k, 0) + 1
                    r = st.invalid_range.get(k)
                    st.invalid_range[k] = (v, v) if r is None else (min(r[0], v), max(r[1], v))
                    continue
            if idx >= channels.N:
                comp, j = self._virtual[idx - channels.N]
                comp.put(j, v, t)
                if touched is None:
                    touched = [comp]
                elif comp not in touched:
                    touched.append(comp)
                continue
            out.append((idx, v))
            samples[idx] += 1
        if touched is not None:  # once per frame, after all of its terms are in
            for comp in touched:
                cv = comp.value(t)
                if cv is not None:
                    out.append((comp.index, cv))
                    samples[comp.index] += 1
        return out

    def _flag(self, plan: _Plan, invalid: bool) -> None:
        with self._lock:
            plan.invalid = invalid
            self.stats.invalid = tuple(sorted(self.invalid_channels))
        if invalid:
            plan.flagged += 1
            # said once per message: a counter that never counts as [checks] says flips the message
            # invalid and back on every lucky frame (39 lines for 70 s); the profile check sums it up
            (log.warning if plan.flagged == 1 else log.debug)(
                "%s (%s): %d bad counter/checksum frames in a row; channels %s invalid%s",
                plan.name,
                _hex(plan.key),
                plan.bad_run,
                ", ".join(plan.channels) or "-",
                " (said once; the decode stats count every bad frame)" if plan.flagged == 1 else "",
            )
        else:
            (log.info if plan.flagged == 1 else log.debug)(
                "%s (%s): good frames again; channels %s valid",
                plan.name,
                _hex(plan.key),
                ", ".join(plan.channels) or "-",
            )

    @property
    def invalid_messages(self) -> frozenset[str]:
        return frozenset(p.name for p in self._plans.values() if p.invalid)

    @property
    def invalid_channels(self) -> frozenset[str]:
        """Channels whose primary message is flagged invalid and no valid alternative is current."""
        bad = set()
        for p in self._plans.values():
            if not p.invalid:
                continue
            for name in p.channels:
                alt = self.profile.channels[name].alt
                alt_plan = self._plans.get(_key_of(self.db, alt.message)) if alt else None
                if alt_plan is None or alt_plan.stale(p.last_seen or 0.0):
                    bad.add(name)
        return frozenset(bad)

    def is_valid(self, channel: str) -> bool:
        return channel not in self.invalid_channels


def _key_of(db: Any, name: str) -> int:
    m = db.get_message_by_name(name)
    return m.frame_id | _EXT if m.is_extended_frame else m.frame_id


def _need(need: list[tuple[str, bool, bool]], name: str, raw: bool, check: bool) -> None:
    for i, (n, r, c) in enumerate(need):
        if n == name:
            need[i] = (n, r and raw, c or check)
            return
    need.append((name, raw, check))


def load_dbc(profile: Profile) -> cantools.database.Database:
    """The profile's DBC, plus the messages it uses from any further DBCs (``dbc = [car, extra]``).

    A further DBC describes devices added to the car's bus, so only the messages the
    profile maps or checks come from it, and their ids must be free in the DBCs before it.
    """
    db = _load_one(profile, profile.dbc)
    used = {m.message for cm in profile.channels.values() for m in (cm, cm.alt) if m is not None}
    for comp in getattr(profile, "composites", {}).values():
        used |= comp.messages
    used |= set(profile.checks)
    for extra in getattr(profile, "extra_dbcs", ()):
        more = _load_one(profile, extra)
        have = {m.name for m in db.messages}
        ids = {(m.frame_id, m.is_extended_frame): m.name for m in db.messages}
        for m in more.messages:
            if m.name not in used or m.name in have:
                continue  # an earlier DBC's message of the same name wins
            clash = ids.get((m.frame_id, m.is_extended_frame))
            if clash is not None:
                raise ProfileError(
                    f"{profile.path} [can]: message {m.name} of {extra.name} has id "
                    f"0x{m.frame_id:X}, which {clash} of an earlier DBC already uses"
                )
            db.messages.append(m)
        db.refresh()
    for name, ms in getattr(profile, "cycle_ms", {}).items():  # periods the DBC does not give
        try:
            db.get_message_by_name(name).cycle_time = ms
        except KeyError:
            raise ProfileError(f"{profile.path} [can] cycle_ms: message '{name}' is not in the DBC") from None
    return db


def _load_one(profile: Profile, path: Path) -> cantools.database.Database:
    return dbcfix.load(path, f"{profile.path} [can]")
