"""The profile's DBC, and the messages it uses from further DBCs, as one database (:mod:`vdp.io.decoder`)."""

from __future__ import annotations

from pathlib import Path

import cantools

from ...errors import ProfileError
from ...profile import Profile
from .. import dbcfix


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
