"""The receive thread: frames from the bus in blocks, and the kernel's count of the frames it dropped.

python-can's :class:`can.Notifier` hands each frame to each listener, one call per
frame, and its socket interfaces do a ``select`` and build a checked
:class:`can.Message` per frame: about 40 us a frame here, a fifth of a core on a
saturated bus before any raw logging.  :class:`BlockNotifier` keeps the Notifier's
contract (threads, ``exception``, ``on_error``, ``stop``) and changes the inside:

- frames are gathered into blocks: after a read the thread sleeps :data:`LINGER`
  (up to :data:`LINGER_MAX` on a socket whose receive buffer holds 8 times that of
  a saturated bus: :func:`linger_for`) while the kernel queues the next ones, then
  reads all that came, so listeners are called once a block, not once a frame;
- on a socket bus (udp_multicast, socketcan) it reads the socket itself,
  ``MSG_DONTWAIT`` until empty, and makes a :data:`Frame` record (a tuple) per
  frame, not a Message: the raw log formats the records directly, and the
  estimator makes Messages only of the frames it decodes;
- listeners with ``on_block(frames)`` get the block; others (tests, tools) get a
  Message per frame, as from a Notifier.

The kernel's drops: a socket's receive buffer that overflows drops datagrams and
counts them in ``sk_drops``, the very number ``SO_RXQ_OVFL`` puts in each
datagram's control message.  python-can's socket readers refuse a second control
message, so vdp reads the counter with ``getsockopt(SO_MEMINFO)`` instead
(:func:`socket_drops`), which also sees drops after the last frame read.
"""

from __future__ import annotations

import logging
import re
import socket
import struct
import time
from collections.abc import Callable

import can

log = logging.getLogger(__name__)

# Frame: (timestamp, arbitration_id, flags, data, message or None).  The message is the
# python-can one where the bus made it (a generic interface); None where vdp read the socket.
Frame = tuple
EXT, RTR, ERR, FD, BRS, ESI, TX = 1, 2, 4, 8, 16, 32, 64
LINGER = 0.01  # s the receive thread sleeps after a block, while the kernel (or driver) queues the next
LINGER_MAX = 0.05  # s: the longest, where the socket's receive buffer holds 8 times that of a saturated bus
FRAME_BYTES = 1024  # bytes of receive buffer a frame takes in the kernel (its skb; ~800 for a CAN or udp frame)
BUS_MAX = 9000  # frames/s of a saturated 1 Mbit/s classic CAN bus, 8-byte frames (~8,000 with stuffing)
BLOCK_MAX = 1024  # frames at most in one block
# linux/can/error.h: an error frame of class CAN_ERR_CRTL with CAN_ERR_CRTL_RX_OVERFLOW in data[1]
# is the controller saying its receive buffer overflowed (frames lost before the kernel saw them)
CAN_ERR_CRTL, CAN_ERR_CRTL_RX_OVERFLOW = 0x4, 0x01
_SO_MEMINFO = getattr(socket, "SO_MEMINFO", 55)
_SK_MEMINFO_DROPS = 8  # index in the u32 array (Linux >= 4.6)


def linger_for(rcvbuf: int | None, floor: float = LINGER) -> float:
    """The receive thread's sleep after a block, for a socket of ``rcvbuf`` bytes (``SO_RCVBUF``, as
    Linux reports it): ``floor``, up to :data:`LINGER_MAX` where the buffer holds 8 times as long a
    saturated bus.  Fewer, larger blocks cost less CPU (each wakes the estimation thread too): with
    a 4 MiB buffer, 25 ms instead of 10 took receive + raw logging from ~6.4 to ~5.6 % of a core, and
    50 ms instead of 25 took ~10 % off the receive thread's CPU and ~15 % off estimation's
    (docs/decisions/0020); a default 208 KiB buffer (~50 ms of a saturated bus) keeps ``floor``."""
    if not rcvbuf or rcvbuf <= 0:
        return floor
    holds = rcvbuf / FRAME_BYTES / BUS_MAX  # seconds of a saturated bus
    return min(LINGER_MAX, max(floor, holds / 8))


def frame_of(msg: can.Message) -> Frame:
    """The record of a python-can message (the message kept in it)."""
    flags = (
        (EXT if msg.is_extended_id else 0)
        | (RTR if msg.is_remote_frame else 0)
        | (ERR if msg.is_error_frame else 0)
        | (FD if msg.is_fd else 0)
        | (BRS if msg.bitrate_switch else 0)
        | (ESI if msg.error_state_indicator else 0)
        | (0 if msg.is_rx else TX)
    )
    return (msg.timestamp, msg.arbitration_id, flags, msg.data, msg)


def message_of(f: Frame, channel: str | None) -> can.Message:
    """A python-can message of a record (its own, if it came with one); timestamps rounded to the
    microsecond a candump log keeps, so the live estimate and a replay of the raw log see the same."""
    msg = f[4]
    if msg is not None:
        msg.timestamp = round(msg.timestamp, 6)
        return msg
    fl = f[2]
    return can.Message(
        timestamp=round(f[0], 6),
        arbitration_id=f[1],
        is_extended_id=bool(fl & EXT),
        is_remote_frame=bool(fl & RTR),
        is_error_frame=bool(fl & ERR),
        is_fd=bool(fl & FD),
        bitrate_switch=bool(fl & BRS),
        error_state_indicator=bool(fl & ESI),
        is_rx=not fl & TX,
        dlc=len(f[3]) if not fl & RTR else 0,
        data=f[3],
        channel=channel,
        check=False,
    )


def is_overrun(f: Frame) -> bool:
    """An error frame saying the controller's receive buffer overflowed."""
    d = f[3]
    return bool(f[2] & ERR) and bool(f[1] & CAN_ERR_CRTL) and len(d) > 1 and bool(d[1] & CAN_ERR_CRTL_RX_OVERFLOW)


def socket_drops(sock: socket.socket) -> int | None:
    """Datagrams (frames) the kernel dropped for this socket so far (its ``sk_drops``); None if it cannot tell."""
    try:
        buf = sock.getsockopt(socket.SOL_SOCKET, _SO_MEMINFO, 9 * 4)
        if len(buf) >= 9 * 4:
            return struct.unpack_from("9I", buf)[_SK_MEMINFO_DROPS]
    except (OSError, ValueError):
        pass
    if sock.type == socket.SOCK_DGRAM and sock.family in (socket.AF_INET, socket.AF_INET6):
        return _proc_udp_drops(sock)
    return None


def _proc_udp_drops(sock: socket.socket) -> int | None:
    """The 'drops' column of /proc/net/udp{,6} for this socket's inode (kernels without SO_MEMINFO)."""
    try:
        import os

        inode = os.fstat(sock.fileno()).st_ino
        name = "/proc/net/udp6" if sock.family == socket.AF_INET6 else "/proc/net/udp"
        with open(name) as f:
            next(f)
            for line in f:
                cols = line.split()
                if len(cols) > 12 and int(cols[9]) == inode:
                    return int(cols[12])
    except (OSError, ValueError, StopIteration):
        pass
    return None


# -- socket readers: (block, room) -> frames appended; raise what python-can would raise --------
# python-can's udp_multicast datagram (utils.pack_message: msgpack of an 11-key dict, keys in this order)
# of a classic data frame: not remote, not an error, not FD, no BRS/ESI, 0..8 data bytes, the
# arbitration id a non-negative int.  Anything else (or a datagram that only looks like one: the
# lengths are checked after the match) goes through python-can's own unpacking.
_UDP_PLAIN = re.compile(
    rb"\x8b\xa9timestamp\xcb.{8}"
    rb"\xaearbitration_id(?:([\x00-\x7f])|\xcc(.)|\xcd(..)|\xce(....))"
    rb"\xaeis_extended_id([\xc2\xc3])\xafis_remote_frame\xc2\xaeis_error_frame\xc2"
    rb"\xa7channel(?:\xc0|([\xa0-\xbf])(.{0,31}?))"
    rb"\xa3dlc([\x00-\x08])\xa4data\xc4([\x00-\x08])(.{0,8})"
    rb"\xa5is_fd\xc2\xaebitrate_switch\xc2\xb5error_state_indicator\xc2",
    re.S,
)


def _udp_reader(bus, channel: str, on_garbage: Callable[[BaseException], None]):
    """Read python-can's udp_multicast socket directly (same datagrams, same checks, no select per frame)."""
    from can.interfaces.udp_multicast.utils import unpack_message

    mc = bus._multicast
    sock: socket.socket = mc._socket
    if not getattr(mc, "timestamp_nanosecond", False):
        return None  # timestamps by ioctl per datagram: leave it to python-can
    size, anc = mc.max_buffer, mc.received_ancillary_buffer_size
    stamp = struct.Struct(mc.received_timestamp_struct)
    fd_ok = getattr(bus, "_can_protocol", None) is can.CanProtocol.CAN_FD
    match = _UDP_PLAIN.fullmatch
    recvmsg, flags = sock.recvmsg, socket.MSG_DONTWAIT
    from_bytes = int.from_bytes

    def slow(data: bytes, ts: float) -> Frame | None:
        """Anything but a plain classic frame: python-can's own unpacking and checks."""
        try:
            msg = unpack_message(data, replace={"timestamp": ts}, check=True)
        except Exception as exc:
            on_garbage(can.CanOperationError(f"could not unpack received message: {exc}"))
            return None
        if msg.is_fd and not fd_ok:
            return None
        clean = clean_frame(msg, channel)
        if clean is None:
            on_garbage(ValueError("not a CAN frame"))
            return None
        return frame_of(clean)

    def read(block: list, room: int) -> None:
        for _ in range(room):
            try:
                data, ancillary, _f, _a = recvmsg(size, anc, flags)
            except BlockingIOError:
                return
            except InterruptedError:
                continue
            except OSError as exc:
                raise can.CanOperationError(f"failed to receive from the UDP socket: {exc}") from exc
            try:
                sec, ns = stamp.unpack(ancillary[0][2])
                ts = sec + ns * 1e-9
            except (IndexError, struct.error):
                ts = time.time()
            # python-can's msgpack map of a plain classic frame, matched as bytes: msgpack's unpacking into
            # a dict and checking its 11 entries took ~6 us a frame, the regular expression ~2 (the kernel's
            # recvmsg itself takes ~3.5: recvmmsg through ctypes was no cheaper)
            m = match(data)
            plain = False
            if m is not None:
                a1, a2, a3, a4, ext, chead, chan, dlc, n, payload = m.groups()
                aid = from_bytes(a1 or a2 or a3 or a4, "big")
                ext = ext == b"\xc3"
                plain = (
                    dlc[0] == n[0] == len(payload)
                    and (chead is None or chead[0] - 0xA0 == len(chan))
                    and aid < (0x20000000 if ext else 0x800)
                )
            if plain:
                block.append((ts, aid, EXT if ext else 0, payload, None))
            else:
                f = slow(data, ts)
                if f is not None:
                    block.append(f)

    return sock, read


def _socketcan_reader(bus, channel: str, on_garbage: Callable[[BaseException], None]):
    """Read a socketcan socket directly: one recvmsg and one struct unpack a frame."""
    from can.interfaces.socketcan import constants as k
    from can.interfaces.socketcan.socketcan import RECEIVED_ANCILLARY_BUFFER_SIZE, RECEIVED_TIMESTAMP_STRUCT

    sock: socket.socket = bus.socket
    if getattr(bus, "channel", None) == "":
        return None  # bound to every interface: python-can names each frame's; leave it to python-can
    try:  # the controller's "receive buffer overflowed" error frames (and only those) into the stream
        sock.setsockopt(k.SOL_CAN_RAW, k.CAN_RAW_ERR_FILTER, CAN_ERR_CRTL)
    except OSError as exc:
        log.debug("CAN_RAW_ERR_FILTER: %s", exc)
    head = struct.Struct("=IBB2x")
    mtu, stamp = k.CANFD_MTU, RECEIVED_TIMESTAMP_STRUCT
    recvmsg, flags = sock.recvmsg, socket.MSG_DONTWAIT
    eff, rtr, err = k.CAN_EFF_FLAG, k.CAN_RTR_FLAG, k.CAN_ERR_FLAG
    brs, esi, dontroute = k.CANFD_BRS, k.CANFD_ESI, socket.MSG_DONTROUTE

    def read(block: list, room: int) -> None:
        for _ in range(room):
            try:
                cf, ancillary, mflags, _a = recvmsg(mtu, RECEIVED_ANCILLARY_BUFFER_SIZE, flags)
            except BlockingIOError:
                return
            except InterruptedError:
                continue
            except OSError as exc:
                raise can.CanOperationError(f"Error receiving: {exc.strerror}", exc.errno) from exc
            can_id, dlc, fdf = head.unpack_from(cf)
            try:
                sec, ns = stamp.unpack_from(ancillary[0][2])
                ts = sec + ns * 1e-9
            except (IndexError, struct.error):
                ts = time.time()
            fl = 0
            if can_id & eff:
                fl |= EXT
                aid = can_id & 0x1FFFFFFF
            else:
                aid = can_id & 0x7FF
            if can_id & rtr:
                fl |= RTR
            if can_id & err:
                fl |= ERR
            if len(cf) == mtu:
                fl |= FD | (BRS if fdf & brs else 0) | (ESI if fdf & esi else 0)
            if mflags & dontroute:
                fl |= TX
            block.append((ts, aid, fl, b"" if fl & RTR else cf[8 : 8 + dlc], None))

    return sock, read


def socket_reader(bus, channel: str, on_garbage: Callable[[BaseException], None]):
    """(socket, read) for a bus vdp can read the socket of directly; None for any other."""
    if getattr(bus, "filters", None) and not getattr(bus, "_is_filtered", False):
        return None  # python-can filters in software: leave it to python-can
    name = type(bus).__name__
    try:
        if name == "UdpMulticastBus":
            return _udp_reader(bus, channel, on_garbage)
        if name == "SocketcanBus":
            return _socketcan_reader(bus, channel, on_garbage)
    except (AttributeError, ImportError, OSError, TypeError) as exc:  # another python-can version
        log.info("reading %s through python-can (%s)", name, exc)
    return None


class BlockNotifier(can.Notifier):
    """A :class:`can.Notifier` whose thread hands listeners blocks of frames (see the module doc)."""

    def __init__(
        self,
        bus: can.BusABC,
        listeners: list,
        timeout: float,
        channel: str,
        on_garbage: Callable[[BaseException], None],
        on_block: Callable[[list], None] | None = None,
        linger: float = LINGER,
    ):
        self.channel = channel
        self.on_garbage = on_garbage
        self.linger = linger
        self.blocks = 0
        self.frames = 0
        self._after = on_block  # told each block after the listeners (the link counts overruns)
        self._block_listeners = [x.on_block for x in listeners if hasattr(x, "on_block")]
        self._frame_listeners = [x for x in listeners if not hasattr(x, "on_block")]
        super().__init__(bus, listeners, timeout)

    def _deliver(self, block: list) -> None:
        self.blocks += 1
        self.frames += len(block)
        for fn in self._block_listeners:
            fn(block)
        if self._frame_listeners:
            chan = self.channel
            for f in block:
                msg = f[4] if f[4] is not None else message_of(f, chan)
                for x in self._frame_listeners:
                    x(msg)
        if self._after is not None:
            self._after(block)

    def _rx_thread(self, bus: can.BusABC) -> None:
        try:
            reader = socket_reader(bus, self.channel, self.on_garbage)
        except Exception as exc:
            log.debug("socket reader: %s", exc)
            reader = None
        if reader is not None:
            self._run(bus, self._socket_fill(*reader))
        else:
            self._run(bus, self._bus_fill(bus))

    def _socket_fill(self, sock: socket.socket, read: Callable[[list, int], None]) -> Callable[[list], None]:
        import select

        poll = select.poll()
        poll.register(sock.fileno(), select.POLLIN | select.POLLERR | select.POLLHUP)
        if self.linger > 0:  # (0: no sleep at all, as asked)
            try:
                self.linger = linger_for(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF), self.linger)
            except OSError:
                pass
        wait_ms = int(self.timeout * 1000)

        def fill(block: list) -> None:
            if not poll.poll(wait_ms):
                return
            read(block, BLOCK_MAX)

        return fill

    def _bus_fill(self, bus: can.BusABC) -> Callable[[list], None]:
        recv, timeout = bus.recv, self.timeout

        def fill(block: list) -> None:
            msg = recv(timeout)
            while msg is not None:
                block.append(frame_of(msg))
                if len(block) >= BLOCK_MAX:
                    return
                msg = recv(0.0)

        return fill

    def _run(self, bus: can.BusABC, fill: Callable[[list], None]) -> None:
        linger, sleep = self.linger, time.sleep
        while not self._stopped:
            block: list = []
            try:
                fill(block)
                if block:
                    got, block = block, []
                    with self._lock:
                        self._deliver(got)
                    if len(got) < BLOCK_MAX and linger > 0:
                        sleep(linger)  # let the kernel queue the next block: one read and one write a block
            except Exception as exc:
                if block:  # read before the failure, not yet delivered: kept
                    try:
                        with self._lock:
                            self._deliver(block)
                    except Exception:
                        pass
                self.exception = exc
                if not self._on_error(exc):
                    raise
                log.debug("suppressed exception: %s", exc)


_NUMBER = (float, int)
_BYTES = (bytearray, bytes)
_FLAGS = ("is_extended_id", "is_remote_frame", "is_error_frame", "is_fd", "bitrate_switch", "error_state_indicator")


def clean_frame(msg: can.Message, channel: str) -> can.Message | None:
    """``msg`` put on ``channel``, if it holds only what a CAN frame can hold; None if it is no frame.

    udp_multicast fills every field from the datagram as it is: a channel "can0\n(123.0) can0
    0B1#..." wrote made-up lines into the raw log, and an id of 1.5 passes python-can's checks
    (they assume the types) and stopped the raw log's writer.  The channel is the configured one:
    the bus is one bus, whatever a sender says.  Changed in place: no copy per frame.
    """
    # one expression, no loop: this runs for every frame (0.7 us, half a per cent of a core at 8,000 frames/s)
    if not (
        type(msg.arbitration_id) is int
        and type(msg.dlc) is int
        and type(msg.timestamp) in _NUMBER
        and type(msg.data) in _BYTES
        and type(msg.is_extended_id) is bool
        and type(msg.is_remote_frame) is bool
        and type(msg.is_error_frame) is bool
        and type(msg.is_fd) is bool
        and type(msg.bitrate_switch) is bool
        and type(msg.error_state_indicator) is bool
    ):
        return None
    try:
        msg._check()  # id range, dlc against the data, flags that exclude each other, a finite timestamp
    except (ValueError, TypeError):
        return None
    msg.channel = channel
    return msg
