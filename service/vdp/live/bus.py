"""The bus side: open any python-can bus silent where possible, keep it open.

python-can's :class:`can.Notifier` runs one receive thread per bus.  Two ways it
goes wrong on a car:

- a listener raises: without an ``on_error`` handler the thread ends, silently;
- ``bus.recv`` raises (interface down, adapter unplugged): with a handler that
  says "handled", the thread calls ``recv`` again at once, a busy spin.

So every vdp listener catches its own errors, and :class:`BusLink` owns the
Notifier: its ``on_error`` records the error and wakes a keeper thread, which
stops the Notifier, shuts the bus, and opens it again with exponential backoff
(bounded, never a spin).  The keeper also checks the receive thread is alive
(heartbeat), so a thread that died any other way is noticed too.

Where the bus is an OS socket (socketcan, udp_multicast) the kernel queues frames
until the receive thread reads them, in a buffer of ``net.core.rmem_default``
(about 200 KiB: some 30 ms of a saturated bus).  The receive thread shares the GIL
with the estimator and the API, so a burst of API requests can hold it off longer
than that, and the kernel then drops frames without anyone counting them.  So the
link asks for :data:`RECEIVE_BUFFER` on every socket it opens.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import can

from ..errors import BusError
from ..settings import BusSettings
from .reader import _FLAGS, ERR, BlockNotifier, clean_frame, is_overrun, socket_drops

log = logging.getLogger(__name__)

# How to ask each python-can interface for listen-only (silent) mode.  Interfaces
# not listed have none in python-can: socketcan's is a property of the netdev
# (`ip link set can0 type can listen-only on`), virtual and udp_multicast have
# no controller.  vdp never calls send() on any bus either way.
LISTEN_ONLY: dict[str, dict] = {
    "slcan": {"listen_only": True},
    "vector": {"listen_only": True},
    "nixnet": {"listen_only": True},
    "cantact": {"monitor": True},
    "kvaser": {"driver_mode": False},  # canlib's DRIVER_MODE_SILENT
    "pcan": {"state": can.BusState.PASSIVE},
    "systec": {"state": can.BusState.PASSIVE},
    "seeedstudio": {"operation_mode": "silent"},
}

POLL = 0.5  # s: Notifier recv timeout and keeper heartbeat
# Kernel receive buffer asked for the bus socket: about a second of a saturated 1 Mbit/s
# bus (the kernel counts ~0.5-1 KiB per queued frame), so a GIL pause never loses frames.
RECEIVE_BUFFER = 8 << 20
STABLE = 60.0  # s up before a failure starts the backoff over at reconnect_min


def bus_kwargs(cfg: BusSettings) -> dict:
    kw: dict = {"interface": cfg.interface, "channel": cfg.channel, "receive_own_messages": False}
    if cfg.bitrate is not None and cfg.interface not in ("virtual", "udp_multicast"):
        kw["bitrate"] = cfg.bitrate
    if cfg.listen_only and cfg.interface in LISTEN_ONLY:
        kw.update(LISTEN_ONLY[cfg.interface])
    kw.update(cfg.kwargs)
    if cfg.interface == "udp_multicast":
        kw.pop("receive_own_messages")  # python-can refuses the key for this interface
    return kw


def bus_socket(bus: can.BusABC) -> socket.socket | None:
    """The OS socket under a python-can bus, where there is one (socketcan, udp_multicast)."""
    sock = getattr(bus, "socket", None)  # socketcan
    if sock is None:
        sock = getattr(getattr(bus, "_multicast", None), "_socket", None)  # udp_multicast
    return sock if isinstance(sock, socket.socket) else None


def rmem_max() -> int | None:
    """The most receive buffer a process without CAP_NET_ADMIN may ask for (Linux's net.core.rmem_max)."""
    try:
        with open("/proc/sys/net/core/rmem_max") as f:
            return int(f.read())
    except (OSError, ValueError):
        return None


def enlarge_receive_buffer(bus: can.BusABC, size: int = RECEIVE_BUFFER) -> int | None:
    """Ask the kernel for ``size`` bytes of receive buffer; return what it gave (None: no socket)."""
    sock = bus_socket(bus)
    if sock is None:
        return None
    # SO_RCVBUFFORCE goes past net.core.rmem_max but needs CAP_NET_ADMIN; SO_RCVBUF is capped by it.
    force = getattr(socket, "SO_RCVBUFFORCE", None)
    for opt in (force, socket.SO_RCVBUF):
        if opt is None:
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, opt, size)
            break
        except OSError:
            continue
    try:
        # Linux reports twice what was asked (it counts its bookkeeping): halve it back
        return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) // 2
    except OSError:
        return None


def guard_recv(bus: can.BusABC, channel: str, on_garbage: Callable[[BaseException], None]) -> None:
    """Every frame the bus gives passes :func:`clean_frame`; what is no CAN frame is a skipped, counted event.

    python-can's udp_multicast bus raises CanOperationError("could not unpack ...") from
    recv() for any stray datagram on its group; to the Notifier that is a failed bus, and
    the reconnect that follows loses every frame sent meanwhile, uncounted.  Other errors
    (the socket itself failing) still raise.
    """
    inner = getattr(bus, "_recv_internal", None)
    if inner is None:
        return

    def recv(timeout):
        try:
            msg, filtered = inner(timeout)
        except can.CanOperationError as exc:
            if "unpack" not in str(exc):
                raise
            on_garbage(exc)
            return None, False
        if msg is None:
            return None, filtered
        clean = clean_frame(msg, channel)
        if clean is None:
            on_garbage(ValueError(f"not a CAN frame: {_show(msg)}"))
            return None, False
        return clean, filtered

    bus._recv_internal = recv  # type: ignore[method-assign]


def _show(msg) -> str:
    """A bounded, one-line description of a forged frame, for the log."""
    fields = ("arbitration_id", "dlc", "channel", "timestamp", *_FLAGS)
    return repr({f: getattr(msg, f, None) for f in fields})[:200]


def frame_channel(cfg: BusSettings, profile_channel: str | None) -> str:
    """The channel name frames of this bus carry: the configured [bus] channel for a real bus; for a
    bus whose channel is an address or an in-process name (udp_multicast, virtual), the profile's
    [can] channel, else can0, as a car's bus would be named."""
    if cfg.interface in ("udp_multicast", "virtual") or not cfg.channel:
        return profile_channel or "can0"
    return cfg.channel


def open_bus(cfg: BusSettings) -> can.BusABC:
    kw = bus_kwargs(cfg)
    try:
        return can.Bus(**kw)
    except Exception as exc:  # python-can raises many types (CanError, OSError, ImportError, ValueError)
        raise BusError(f"cannot open {cfg.interface} bus '{cfg.channel}': {type(exc).__name__}: {exc}") from exc


@dataclass
class LinkState:
    state: str = "connecting"  # connecting | up | down | stopped
    since: float = 0.0  # time.time() of the last change
    reconnects: int = 0
    errors: int = 0
    last_error: str | None = None
    retry_in: float | None = None
    listen_only: bool | None = None  # None: the interface has no such mode
    receive_buffer: int | None = None  # bytes of kernel receive buffer (None: not a socket)
    garbage: int = 0  # datagrams that held no CAN frame (udp_multicast), skipped without a reconnect
    # frames lost before vdp read them, by cause: the kernel's socket receive buffer overflowed
    # (sk_drops, summed over every socket opened), and overrun reports of the controller (error frames)
    kernel_drops: int | None = None  # None: the interface has no such counter
    overruns: int = 0
    drops_at: float | None = None  # monotonic time drops were last found


class BusLink:
    """Keeps one bus open and its Notifier feeding ``listeners``.  Thread-safe to query."""

    def __init__(
        self,
        cfg: BusSettings,
        listeners: Iterable[can.Listener],
        reconnect_min: float = 0.5,
        reconnect_max: float = 30.0,
        opener: Callable[[BusSettings], can.BusABC] = open_bus,
        frame_channel: str | None = None,
    ):
        self.cfg = cfg
        # the channel every received frame is given (raw log, decoder): see frame_channel()
        self.frame_channel = frame_channel if frame_channel is not None else (cfg.channel or "can0")
        self.listeners = list(listeners) + [_ErrorHook(self)]
        self.reconnect_min = reconnect_min
        self.reconnect_max = reconnect_max
        self.opener = opener
        self.bus: can.BusABC | None = None
        self.notifier: can.Notifier | None = None
        self.info = LinkState(since=time.time())
        self.info.listen_only = (
            True
            if cfg.interface in LISTEN_ONLY and cfg.listen_only
            else (False if cfg.interface in LISTEN_ONLY else None)
        )
        self._failed = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._warned_buffer = False
        self._garbage_said = -60.0
        self._drops_said = -60.0
        self._sock: socket.socket | None = None  # the bus's OS socket, for its drop counter
        self._sock_drops = 0  # its counter when last read
        if cfg.listen_only and cfg.interface not in LISTEN_ONLY and cfg.interface not in ("virtual", "udp_multicast"):
            log.info(
                "python-can's %s interface has no listen-only mode; vdp never transmits, and for "
                "socketcan the netdev can be made silent: ip link set %s type can listen-only on",
                cfg.interface,
                cfg.channel,
            )

    # -- control ------------------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._keep, name="vdp-bus", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._failed.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
        self._close()
        self._set("stopped")

    @property
    def up(self) -> bool:
        return self.info.state == "up"

    def status(self) -> dict:
        i = self.info
        return {
            "interface": self.cfg.interface,
            "channel": self.cfg.channel,
            "state": i.state,
            "since": i.since,
            "reconnects": i.reconnects,
            "errors": i.errors,
            "last_error": i.last_error,
            "retry_in": i.retry_in,
            "listen_only": i.listen_only,
            "receive_buffer": i.receive_buffer,
            "garbage": i.garbage,
            "dropped": {"kernel": i.kernel_drops, "controller_overruns": i.overruns},
        }

    def dropped(self) -> int:
        """Frames lost before vdp read them, as far as counted (kernel drops; controller overrun reports)."""
        return (self.info.kernel_drops or 0) + self.info.overruns

    def poll_drops(self) -> None:
        """Read the open socket's drop counter (the keeper calls this every POLL, and at each close)."""
        with self._lock:
            sock = self._sock
            if sock is None:
                return
            try:
                n = socket_drops(sock)
            except OSError:
                n = None
            if n is None:
                return
            i = self.info
            new = n - self._sock_drops
            if new > 0:
                self._sock_drops = n
                i.kernel_drops = (i.kernel_drops or 0) + new
                i.drops_at = time.monotonic()
                self._said_drops(new)
            elif i.kernel_drops is None:
                i.kernel_drops = 0

    def _said_drops(self, new: int) -> None:
        now = time.monotonic()
        if now - self._drops_said >= 60.0:
            self._drops_said = now
            log.error(
                "%s '%s': the kernel dropped %d frame(s) (%d in all): the receive buffer overflowed "
                "before vdp read it; /status bus.dropped counts them",
                self.cfg.interface,
                self.cfg.channel,
                new,
                self.info.kernel_drops,
            )

    def _blocked(self, block: list) -> None:
        """After each block: count the controller's overrun reports in it (error frames only)."""
        for f in block:
            if f[2] & ERR and is_overrun(f):
                self.info.overruns += 1
                self.info.drops_at = time.monotonic()

    # -- called from the receive thread -----------------------------------------------------------
    def failed(self, exc: BaseException) -> None:
        self.info.errors += 1
        self.info.last_error = f"{type(exc).__name__}: {exc}"
        self._failed.set()
        # The Notifier calls recv() again right after this returns; wait a moment so a
        # dead interface is not polled in a tight loop before the keeper stops it.
        self._stop.wait(0.2)

    # -- keeper thread ------------------------------------------------------------------------------
    def _set(self, state: str) -> None:
        if state != self.info.state:
            self.info.state = state
            self.info.since = time.time()

    def _keep(self) -> None:
        delay = self.reconnect_min
        first = True
        while not self._stop.is_set():
            self.info.retry_in = None
            if not first:
                self.info.reconnects += 1
            first = False
            try:
                self._open()
            except BusError as exc:
                self.info.errors += 1
                self.info.last_error = str(exc)
                self._set("down")
                log.error("%s; retrying in %.1f s", exc, delay)
            else:
                opened = time.monotonic()
                self._set("up")
                log.info("receiving from %s bus '%s'", self.cfg.interface, self.cfg.channel)
                self._watch()
                if self._stop.is_set():
                    break
                self._set("down")
                log.error(
                    "bus %s '%s' failed (%s); reconnecting in %.1f s",
                    self.cfg.interface,
                    self.cfg.channel,
                    self.info.last_error,
                    delay,
                )
                self._close()
                if time.monotonic() - opened > STABLE:
                    delay = self.reconnect_min  # it ran well for a while: start the backoff over
            self.info.retry_in = delay
            if self._stop.wait(delay):
                break
            delay = min(delay * 2.0, self.reconnect_max)

    def _open(self) -> None:
        self._failed.clear()
        bus = self.opener(self.cfg)
        self._buffer(bus)
        guard_recv(bus, self.frame_channel, self._garbage)
        sock = bus_socket(bus)
        with self._lock:
            self._sock = sock
            self._sock_drops = 0
        if sock is not None:
            try:
                self._sock_drops = socket_drops(sock) or 0  # a socket starts at 0; counted from here anyway
            except OSError:
                pass
        try:
            notifier = BlockNotifier(
                bus, self.listeners, POLL, self.frame_channel, self._garbage, on_block=self._blocked
            )
        except Exception as exc:
            bus.shutdown()
            raise BusError(f"cannot start receiving from {self.cfg.interface} '{self.cfg.channel}': {exc}") from exc
        with self._lock:
            self.bus, self.notifier = bus, notifier

    def _garbage(self, exc: BaseException) -> None:
        """A datagram that is no CAN frame: count it; one warning a minute, never a reconnect."""
        i = self.info
        i.garbage += 1
        now = time.monotonic()
        if now - self._garbage_said >= 60.0:
            self._garbage_said = now
            log.warning(
                "%s '%s': skipped a datagram that is no CAN frame (%s; %d so far)",
                self.cfg.interface,
                self.cfg.channel,
                exc.__cause__ or exc,
                i.garbage,
            )

    def _buffer(self, bus: can.BusABC) -> None:
        want = self.cfg.receive_buffer or RECEIVE_BUFFER
        try:
            got = enlarge_receive_buffer(bus, want)
        except Exception as exc:  # a bus without a usable socket is still a bus
            log.debug("receive buffer: %s", exc)
            return
        self.info.receive_buffer = got
        if got is None or self._warned_buffer:
            return
        self._warned_buffer = True
        if got < want:
            cap = rmem_max()
            log.warning(
                "the kernel gave the %s bus a receive buffer of %d KiB, not the %d KiB asked for: the OS caps it "
                "(net.core.rmem_max = %s) and vdp lacks CAP_NET_ADMIN to go past it. A pause of the receive "
                "thread longer than the buffer holds loses frames (counted in /status bus.dropped). Raise the "
                "limit (sysctl -w net.core.rmem_max=%d) or run vdp with CAP_NET_ADMIN",
                self.cfg.interface,
                got >> 10,
                want >> 10,
                "unknown" if cap is None else f"{cap} bytes",
                want,
            )
        else:
            log.info("%s bus: kernel receive buffer of %d KiB", self.cfg.interface, got >> 10)

    def _watch(self) -> None:
        """Return when the bus failed or we are stopping; check the receive thread every POLL."""
        while not self._stop.is_set():
            if self._failed.wait(POLL):
                return
            self.poll_drops()
            n = self.notifier
            readers = getattr(n, "_readers", [])
            alive = any(getattr(r, "is_alive", lambda: True)() for r in readers) if readers else True
            if not alive or (n is not None and n.exception is not None and not self._failed.is_set()):
                exc = n.exception if n is not None and n.exception is not None else RuntimeError("receive thread ended")
                self.info.errors += 1
                self.info.last_error = f"receive thread died: {type(exc).__name__}: {exc}"
                return
            try:
                state = self.bus.state if self.bus is not None else can.BusState.ACTIVE
            except Exception:  # not every interface can tell
                state = can.BusState.ACTIVE
            if state == can.BusState.ERROR:
                self.info.last_error = "controller in error state (bus-off)"
                return

    def _close(self) -> None:
        with self._lock:
            notifier, bus = self.notifier, self.bus
            self.notifier = self.bus = None
        if notifier is not None:
            try:
                notifier.stop(timeout=2 * POLL + 1.0)
            except Exception as exc:
                log.debug("stopping the notifier: %s", exc)
        self.poll_drops()  # a closed socket's count is gone with it: read it last
        with self._lock:
            self._sock = None
        if bus is not None:
            try:
                bus.shutdown()
            except Exception as exc:
                log.debug("shutting the bus: %s", exc)


class _ErrorHook(can.Listener):
    """Last listener: tells the link when the Notifier reports an error."""

    def __init__(self, link: BusLink):
        self.link = link

    def on_message_received(self, msg: can.Message) -> None:
        pass

    def on_block(self, frames: list) -> None:
        """Nothing to do with frames; defined so BlockNotifier does not make a Message of each for it
        (it did: ~9 us a frame, half of the receive thread on a saturated bus)."""

    def on_error(self, exc: Exception) -> None:
        self.link.failed(exc)

    def stop(self) -> None:
        pass
