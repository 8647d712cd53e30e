"""Rolling counters and checksums, as the ECUs on vdp's own bus send them.

The "vdp" checksum (documented in dbc/vdp.dbc)::

    CHECKSUM = 0xFF - ((sum of data bytes 0..6 + (frame_id & 0xFF) + (frame_id >> 8)) & 0xFF)

It sits in byte 7, so it is computed over the encoded payload with byte 7 zero.
"""

from __future__ import annotations

COUNTER_MODULO = 16


def vdp_checksum(frame_id: int, data: bytes | bytearray) -> int:
    s = sum(data[:7]) + (frame_id & 0xFF) + ((frame_id >> 8) & 0xFF)
    return 0xFF - (s & 0xFF)


def counter_ok(previous: int | None, current: int, modulo: int = COUNTER_MODULO) -> bool:
    """True if ``current`` follows ``previous`` (the first frame is always fine)."""
    return previous is None or current == (previous + 1) % modulo
