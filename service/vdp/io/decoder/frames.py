"""Frames through their plans: :class:`FrameDecoder` and its counters (:mod:`vdp.io.decoder`)."""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any

import can
import cantools

from ... import channels
from ...profile import Profile
from ..checks import counter_ok, vdp_checksum
from ..logs import EXT_KEY as _EXT
from ..logs import channel_keys
from ..mapping import Composite as _Composite
from ..mapping import invalid as _invalid
from .dbc import load_dbc
from .plan import ACTIVE, Planning, _Plan

log = logging.getLogger(__name__)

MAX_UNKNOWN = 4096  # distinct unknown ids counted one by one
KINDS = ("unknown_id", "dlc", "remote", "error_frame", "range", "nonfinite", "mux", "counter", "checksum", "decode")
BAD_RUN_INVALID = 3  # consecutive counter/checksum failures that flag a message invalid


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


class FrameDecoder(Planning):
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
