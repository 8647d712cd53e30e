"""Bus test helpers: the paper's and the extra test profile, their DBCs, a frame encoder."""

from __future__ import annotations

from pathlib import Path

import can
import cantools

from vdp.io.checks import vdp_checksum
from vdp.profile import load_profile

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"
PAPER = load_profile(ROOT / "profiles" / "paper.toml")
EXTRA = load_profile(DATA / "extra.toml")
VDP_DB = cantools.database.load_file(str(PAPER.dbc), strict=True)
EXTRA_DB = cantools.database.load_file(str(EXTRA.dbc), strict=True)


def frame(db, name, t=0.0, counter=None, fix_checksum=True, channel=None, **values) -> can.Message:
    """Encode a message of ``db``; unspecified signals are 0, checksum made valid."""
    msg = db.get_message_by_name(name)
    vals = {s.name: 0 for s in msg.signals}
    if counter is not None:
        vals["COUNTER"] = counter
    vals.update(values)
    data = bytearray(msg.encode(vals, strict=False))
    if fix_checksum and "CHECKSUM" in vals:
        data[7] = vdp_checksum(msg.frame_id, data)
    return can.Message(
        timestamp=t, arbitration_id=msg.frame_id, is_extended_id=msg.is_extended_frame, data=data, channel=channel
    )
