"""Which of the profile's messages a log or bus carries, and the frames the decoder refused."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

from ..profile import Profile
from .limits import _subject
from .report import DEPENDS, Report

log = logging.getLogger(__name__)


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
    from ..io.decoder import _hex

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
