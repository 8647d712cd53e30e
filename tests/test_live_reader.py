"""The block receive path: socketcan frames read directly, records written to the raw log exactly as
python-can's candump writer writes the same messages, and blocks thinned, never stalling the reader."""

from __future__ import annotations

import queue
import random
import socket
import struct

import can
import pytest
from can.interfaces.socketcan import constants as k
from can.interfaces.socketcan.socketcan import RECEIVED_TIMESTAMP_STRUCT, build_can_frame

from vdp.live.intake import FrameQueue, Intake
from vdp.live.rawlog import RawLog
from vdp.live.reader import ERR, TX, frame_of, is_overrun, message_of, socket_reader


class _Sock:
    """Stands in for a socketcan socket: recvmsg hands out prepared frames, then EAGAIN."""

    def __init__(self, frames):
        self.frames = list(frames)
        self.opts = []

    def setsockopt(self, *a):
        self.opts.append(a)

    def recvmsg(self, size, anc, flags):
        assert flags & socket.MSG_DONTWAIT
        if not self.frames:
            raise BlockingIOError
        cf, ts, mflags = self.frames.pop(0)
        stamp = RECEIVED_TIMESTAMP_STRUCT.pack(int(ts), int(round((ts % 1) * 1e9)))
        return cf, [(socket.SOL_SOCKET, k.SO_TIMESTAMPNS, stamp)], mflags, ("vcan0",)


class SocketcanBus:  # the name socket_reader dispatches on
    def __init__(self, sock):
        self.socket = sock
        self.channel = "vcan0"
        self.filters = None


MESSAGES = [
    can.Message(timestamp=1700000000.25, arbitration_id=0x123, data=b"\x01\x02\x03", is_extended_id=False),
    can.Message(timestamp=1700000000.5, arbitration_id=0x1ABCDEF, data=bytes(8), is_extended_id=True),
    can.Message(timestamp=1700000000.75, arbitration_id=0x7FF, is_remote_frame=True, dlc=2, is_extended_id=False),
    can.Message(
        timestamp=1700000001.0,
        arbitration_id=0x100,
        data=bytes(range(12)),
        is_fd=True,
        bitrate_switch=True,
        is_extended_id=False,
    ),
    # the controller's "receive buffer overflowed" error frame (linux/can/error.h)
    can.Message(
        timestamp=1700000001.5, arbitration_id=0x4, data=bytes([0, 0x01, 0, 0, 0, 0, 0, 0]), is_error_frame=True
    ),
]


def test_socketcan_frames_read_directly_are_the_messages_python_can_would_make():
    sock = _Sock((build_can_frame(m), m.timestamp, 0) for m in MESSAGES)
    got = socket_reader(SocketcanBus(sock), "can0", lambda e: pytest.fail(f"garbage: {e}"))
    assert got is not None
    block: list = []
    got[1](block, 100)
    assert len(block) == len(MESSAGES)
    assert any(o[1] == k.CAN_RAW_ERR_FILTER for o in sock.opts)  # overrun reports asked for
    for f, m in zip(block, MESSAGES):
        back = message_of(f, "can0")
        assert back.timestamp == pytest.approx(m.timestamp, abs=1e-6)
        assert (back.arbitration_id & 0x1FFFFFFF, back.is_extended_id, back.is_remote_frame) == (
            m.arbitration_id,
            m.is_extended_id,
            m.is_remote_frame,
        )
        assert (back.is_error_frame, back.is_fd, back.bitrate_switch) == (m.is_error_frame, m.is_fd, m.bitrate_switch)
        if not m.is_remote_frame:
            assert bytes(back.data) == bytes(m.data)
    assert [is_overrun(f) for f in block] == [False, False, False, False, True]
    assert block[-1][2] & ERR


def test_block_lines_are_python_cans_candump_lines_byte_for_byte(tmp_path):
    frames = [(m.timestamp, m.arbitration_id, frame_of(m)[2], bytes(m.data), None) for m in MESSAGES]
    frames += [(1600000000.0, 0x55, 0, b"\xaa", None)]  # earlier than the first: python-can clamps it
    ours = RawLog(tmp_path / "ours", 1 << 20, 4, channel="can0")
    ours.open()
    ours.on_block(frames[:3])
    ours.on_block(frames[3:])
    ours.close()
    ref = tmp_path / "ref.log"
    with can.CanutilsLogWriter(ref, channel="can0") as w:
        for f in frames:
            m = message_of(f, "can0")
            w.on_message_received(m)
    (mine,) = [p for p in (tmp_path / "ours").iterdir() if p.suffix == ".log"]
    assert mine.read_text() == ref.read_text()
    assert ours.written == len(frames) and ours.lost == 0
    index = (tmp_path / "ours" / "vdp-index.jsonl").read_text().splitlines()
    assert len(index) == 1 and f'"frames": {len(frames)}' in index[0]


def test_a_block_larger_than_the_room_left_is_thinned_and_counted():
    q = FrameQueue(maxsize=100)
    intake = Intake(q)
    block = [(1.0 + i, 0x10, 0, b"", None) for i in range(70)]
    intake.on_block(block)
    intake.on_block(block)  # 30 fit, 40 thinned
    intake.on_block(block)  # full: all 70 thinned
    assert q.qsize() == 100 and intake.received == 210 and intake.dropped == 110
    assert [len(q.get_nowait()) for _ in range(2)] == [70, 30]
    with pytest.raises(queue.Empty):
        q.get_nowait()


class _UdpSock:
    """Stands in for python-can's udp_multicast socket: recvmsg hands out prepared datagrams, then EAGAIN."""

    def __init__(self, datagrams):
        self.datagrams = list(datagrams)

    def recvmsg(self, size, anc, flags):
        assert flags & socket.MSG_DONTWAIT
        if not self.datagrams:
            raise BlockingIOError
        stamp = struct.pack("@ll", 1700000000, 250_000_000)
        return self.datagrams.pop(0), [(socket.SOL_SOCKET, 35, stamp)], 0, ("239.0.0.1", 1)  # SO_TIMESTAMPNS


class _Multicast:
    def __init__(self, sock):
        self._socket = sock
        self.timestamp_nanosecond = True
        self.max_buffer = 4096
        self.received_ancillary_buffer_size = socket.CMSG_SPACE(struct.calcsize("@ll"))
        self.received_timestamp_struct = "@ll"


class UdpMulticastBus:  # the name socket_reader dispatches on
    def __init__(self, sock):
        self._multicast = _Multicast(sock)
        self.filters = None
        self._can_protocol = can.CanProtocol.CAN_20


def _udp_cases():
    """Datagrams python-can's pack_message makes (plain frames of every id width, and frames that are not
    plain), and hand-made ones that only look like plain frames."""
    from can.interfaces.udp_multicast.utils import pack_message

    rng = random.Random(7)
    msgs = [
        can.Message(arbitration_id=aid, data=bytes(rng.randrange(256) for _ in range(n)), is_extended_id=ext)
        for aid, ext in [(0, False), (0x7F, False), (0x80, False), (0xFF, False), (0x100, False), (0x7FF, False),
                         (0, True), (0xFFFF, True), (0x10000, True), (0x1FFFFFFF, True)]
        for n in (0, 1, 8)
    ]  # fmt: skip
    msgs += [
        can.Message(arbitration_id=0x123, data=b"\xa5is_fd\xc2\xc2", is_extended_id=False),  # the tail's bytes as data
        can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False, channel="vcan0"),
        can.Message(arbitration_id=0x123, is_remote_frame=True, dlc=4, is_extended_id=False),
        can.Message(arbitration_id=0x123, data=bytes(12), is_fd=True, is_extended_id=False),
        can.Message(arbitration_id=0x4, data=bytes(8), is_error_frame=True),
    ]
    out = [pack_message(m) for m in msgs]
    plain = pack_message(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
    out += [
        plain.replace(b"\xa3dlc\x02", b"\xa3dlc\x03"),  # dlc says 3, data holds 2: python-can refuses it
        plain.replace(b"\xcd\x01\x23", b"\xcd\x08\x00"),  # 0x800: not a standard id
        plain.replace(b"\xa7channel\xc0", b"\xa7channel\xa3ab"),  # a channel string shorter than it says
        plain[:-1],  # cut short
        b"\x00garbage",
    ]
    return out


def test_udp_datagrams_read_directly_are_the_frames_python_can_would_make():
    """The udp_multicast reader's plain-frame match gives, for each datagram, what python-can's own
    unpacking (with its checks) gives: the same id, flags and data, or the same refusal."""
    from can.interfaces.udp_multicast.utils import unpack_message

    from vdp.live.bus import clean_frame

    datagrams = _udp_cases()
    refused: list = []
    got = socket_reader(UdpMulticastBus(_UdpSock(datagrams)), "can0", refused.append)
    assert got is not None
    block: list = []
    got[1](block, 1000)
    want, bad = [], 0
    for d in datagrams:
        try:
            m = unpack_message(d, check=True)
        except Exception:
            bad += 1
            continue
        if m.is_fd:  # a classic bus skips FD frames
            continue
        clean = clean_frame(m, "can0")
        if clean is None:
            bad += 1
        else:
            want.append(frame_of(clean))
    assert [(f[1], f[2] & ~TX, bytes(f[3])) for f in block] == [(w[1], w[2] & ~TX, bytes(w[3])) for w in want]
    assert all(f[0] == pytest.approx(1700000000.25) for f in block)
    # the dlc that lies, the 12-bit standard id, the channel string cut short, the cut datagram, the garbage
    assert len(refused) == bad == 5


def test_the_receive_thread_lingers_longer_only_where_the_buffer_has_room():
    """After a block the receive thread sleeps while the kernel queues the next: longer (fewer blocks,
    less CPU) only where the socket's buffer holds 8 times that long of a saturated bus."""
    from vdp.live.reader import BUS_MAX, FRAME_BYTES, LINGER, LINGER_MAX, linger_for

    assert linger_for(None) == linger_for(0) == LINGER
    assert linger_for(2 * 212992) == LINGER  # Linux's default rmem_max: ~50 ms of a saturated bus
    assert linger_for(2 * 4 << 20) == LINGER_MAX  # the 4 MiB the udp stand-in gets
    for rcvbuf in (1 << 18, 1 << 20, 3 << 20, 1 << 23):
        linger = linger_for(rcvbuf)
        assert LINGER <= linger <= LINGER_MAX
        assert linger == LINGER or linger * 8 <= rcvbuf / FRAME_BYTES / BUS_MAX + 1e-12
