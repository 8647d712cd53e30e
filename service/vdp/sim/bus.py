"""A simulated drive onto a live CAN bus, paced to real time."""

from __future__ import annotations

import time
from collections.abc import Iterator

import can

from ..errors import BusError


def open_bus(interface: str, channel: str | None = None) -> can.BusABC:
    defaults = {"virtual": "vdp", "socketcan": "vcan0"}
    if interface == "udp_multicast":
        from can.interfaces.udp_multicast import UdpMulticastBus

        defaults["udp_multicast"] = UdpMulticastBus.DEFAULT_GROUP_IPv4
    chan = channel or defaults.get(interface)
    try:
        return can.Bus(interface=interface, channel=chan)
    except Exception as exc:  # python-can raises many types (CanError, OSError, ImportError, ...)
        raise BusError(f"cannot open {interface} bus '{chan}': {exc}") from None


def paced(frames: Iterator[can.Message], speed: float) -> Iterator[can.Message]:
    """Yield frames no earlier than ``speed`` x real time (0 = as fast as possible)."""
    if speed <= 0:
        yield from frames
        return
    t0 = w0 = None
    for msg in frames:
        if t0 is None:
            t0, w0 = msg.timestamp, time.monotonic()
        wait = w0 + (msg.timestamp - t0) / speed - time.monotonic()
        if wait > 0.002:
            time.sleep(wait)
        yield msg


def tee_bus(frames: Iterator[can.Message], bus: can.BusABC, speed: float = 1.0) -> Iterator[can.Message]:
    """Send each frame onto ``bus`` at ``speed`` x real time, then pass it on."""
    for msg in paced(frames, speed):
        try:
            bus.send(msg)
        except can.CanError as exc:
            raise BusError(f"send failed on {bus.channel_info}: {exc}") from None
        yield msg


def send_live(frames: Iterator[can.Message], bus: can.BusABC, speed: float = 1.0) -> int:
    """Send frames onto ``bus`` at ``speed`` x real time; returns the number sent."""
    return sum(1 for _ in tee_bus(frames, bus, speed))
