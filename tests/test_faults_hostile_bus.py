"""Garbage on the bus interface (issue 13): datagrams that are no CAN frame and bursts of
unknown ids are counted, cause no reconnect, lose no frame, and grow no table.
"""

from __future__ import annotations

import random
import time
from pathlib import Path

import can

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
