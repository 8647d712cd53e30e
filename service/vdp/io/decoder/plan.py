"""A profile's mapping checked against its DBC and compiled into plans (:mod:`vdp.io.decoder`).

One plan per arbitration id: the extractor of the signals it needs (:mod:`vdp.io.signals`),
the slots of its counter and checksum, and its outputs (channel, value slot, scale and
offset, sign and fine slots, alternative source, status and plausibility), with the live
state the frame decoder keeps on it.
"""

from __future__ import annotations

import difflib
import logging
import math
from collections.abc import Callable
from typing import Any

from ... import channels
from ...errors import ProfileError
from ...units import UNIT_FACTORS
from ..logs import EXT_KEY as _EXT
from ..mapping import Composite as _Composite
from ..signals import cantools_extractor as _cantools_extractor
from ..signals import check_fine, compile_extractor
from ..signals import nothing as _nothing

log = logging.getLogger(__name__)

ALT_AFTER_CYCLES = 5.0  # primary silent this many cycle times: use the alternative source
DEFAULT_CYCLE = 0.1  # [s] until a message without GenMsgCycleTime has shown its period
ACTIVE = object()  # marks a status flag read from an enum's raw values (profile.ChannelMap.active)


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


class Planning:
    """:class:`vdp.io.decoder.FrameDecoder`'s construction: the profile checked against the DBC
    (``_validate``) and its plans built (``_build``)."""

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


def _need(need: list[tuple[str, bool, bool]], name: str, raw: bool, check: bool) -> None:
    for i, (n, r, c) in enumerate(need):
        if n == name:
            need[i] = (n, r and raw, c or check)
            return
    need.append((name, raw, check))
