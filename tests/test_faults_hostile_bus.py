"""Garbage on the bus interface (issue 13): datagrams that are no CAN frame and bursts of
unknown ids are counted, cause no reconnect, lose no frame, and grow no table.
"""

from __future__ import annotations

import random
import re
import time
from pathlib import Path

import can
import pytest

from vdp.live.bus import BusLink
from vdp.pipeline import Pipeline
from vdp.profile import load_profile
from vdp.settings import BusSettings

ROOT = Path(__file__).resolve().parents[1]
GARBAGE_ID = 0x7FF  # frames the test sender marks as "a datagram that does not unpack"


def _garbage_bus(channel: str):
    """A virtual bus whose recv fails for marked frames exactly as python-can's udp_multicast
    does for a stray datagram (CanOperationError from the unpack error)."""

    def opener(cfg):
        bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        inner = bus._recv_internal

        def recv(timeout):
            msg, filtered = inner(timeout)
            if msg is not None and msg.arbitration_id == GARBAGE_ID:
                try:
                    raise ValueError("unpack(b) received extra data.")
                except ValueError as exc:
                    raise can.CanOperationError("could not unpack received message") from exc
            return msg, filtered

        bus._recv_internal = recv
        return bus

    return opener


def test_garbage_datagrams_are_counted_with_no_reconnect_and_no_loss():
    channel = "rel-garbage-test"
    got: list[can.Message] = []

    class Keep(can.Listener):
        def on_message_received(self, msg):
            got.append(msg)

    cfg = BusSettings(interface="virtual", channel=channel, bitrate=None, listen_only=False)
    link = BusLink(cfg, [Keep()], opener=_garbage_bus(channel))
    link.start()
    tx = can.Bus(interface="virtual", channel=channel)
    try:
        deadline = time.monotonic() + 10
        while not link.up and time.monotonic() < deadline:
            time.sleep(0.02)
        good = 0
        for k in range(500):
            garbage = k % 5 == 0
            tx.send(can.Message(arbitration_id=GARBAGE_ID if garbage else 0x0B1, is_extended_id=False, data=bytes(8)))
            good += not garbage
            time.sleep(0.001)
        while len(got) < good and time.monotonic() < deadline:
            time.sleep(0.02)
        assert len(got) == good and all(m.arbitration_id == 0x0B1 for m in got)
        assert link.info.garbage == 100 and link.info.reconnects == 0 and link.info.errors == 0 and link.up
        assert link.status()["garbage"] == 100
    finally:
        tx.shutdown()
        link.stop()


def test_a_burst_of_random_unknown_ids_is_counted_in_bounded_memory():
    dec = Pipeline(load_profile(ROOT / "profiles" / "paper.toml")).decoder
    rng = random.Random(1)
    n = 50_000
    for k in range(n):
        aid = rng.getrandbits(29) | 0x10000000  # extended ids the profile never maps
        dec.decode(can.Message(timestamp=1.7e9 + k * 1e-4, arbitration_id=aid, is_extended_id=True, data=bytes(8)))
    d = dec.stats.as_dict()
    assert d["errors_by_kind"]["unknown_id"] == n and d["frames"] == n
    assert d["unknown_distinct"] == 4096 and len(dec.stats.unknown) == 4096
    assert sum(dec.stats.unknown.values()) + d["unknown_untracked"] == n and d["unknown_untracked"] > n - 4096 - 10


# -- forged datagrams: what reaches the raw log is a CAN frame on the configured channel ----------

FORGE_SCRIPT = r"""
import json, sys, time
from dataclasses import replace
from pathlib import Path

import can, msgpack

from vdp.live.ingest import Ingest
from vdp.profile import load_profile
from vdp.settings import BusSettings, RawLogSettings, Settings

tmp, root = Path(sys.argv[1]), Path(sys.argv[2])
group = "239.74.163.26"
s = Settings(
    profile=root / "profiles" / "paper.toml",
    bus=BusSettings(interface="udp_multicast", channel=group, bitrate=None),
    raw_log=RawLogSettings(dir=tmp / "raw", max_bytes=1 << 20, max_files=4),
)
ing = Ingest(s, load_profile(s.profile))
ing.open_rawlog()
ing.start()
end = time.monotonic() + 30
while not ing.link.up and time.monotonic() < end:
    time.sleep(0.05)
tx = can.Bus(interface="udp_multicast", channel=group)
sock = tx._multicast._socket

def forge(**over):
    d = {"timestamp": 5.0, "arbitration_id": 0x0B1, "is_extended_id": False, "is_remote_frame": False,
         "is_error_frame": False, "channel": "can0", "dlc": 1, "data": b"\x01", "is_fd": False,
         "bitrate_switch": False, "error_state_indicator": False}
    d.update(over)
    sock.sendto(msgpack.packb(d, use_bin_type=True), (group, 43113))

tx.send(can.Message(arbitration_id=0x0B1, data=b"\x00", is_extended_id=False))
# a channel that writes two made-up lines into a candump log
forge(channel="can0 0B1#01 R\n(1.000000) can0 123#DEADBEEF R\n(2.000000) can0")
forge(arbitration_id=1.5)  # a float id: python-can's checks pass it, the log writer cannot format it
forge(channel={"a": 1})
tx.send(can.Message(arbitration_id=0x0B1, data=b"\x02", is_extended_id=False))
end = time.monotonic() + 30
while ing.intake.received + ing.link.info.garbage < 5 and time.monotonic() < end:
    time.sleep(0.05)
time.sleep(0.3)
ing.tick()
st = ing.status()
ing.stop()
ing.close()
lines = [l for f in sorted((tmp / "raw").glob("*.log")) for l in f.read_text().splitlines()]
tx.shutdown()
print(json.dumps({"lines": lines, "received": ing.intake.received, "garbage": st["bus"]["garbage"],
                  "raw": {k: st["raw_log"][k] for k in ("lost", "error")}}))
"""


def test_a_forged_udp_multicast_datagram_cannot_write_lines_into_the_raw_log(tmp_path):
    from helpers.netns import netns_reason, run_in_netns

    why = netns_reason()
    if why:
        pytest.skip(why)
    out = run_in_netns(FORGE_SCRIPT, str(tmp_path), str(ROOT), timeout=120)
    lines = out["lines"]
    # the two true frames and the two with a forged channel, each one line on the configured channel
    # (the paper profile names none: can0); the float id is skipped and counted, the writer carries on
    assert len(lines) == 4 and out["received"] == 4, out
    assert all(re.fullmatch(r"\(\d+\.\d{6}\) can0 0B1#0[012] R", line) for line in lines), lines
    assert out["garbage"] == 1 and out["raw"] == {"lost": 0, "error": None}, out
