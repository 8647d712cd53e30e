"""vdp serve: the live service (bus -> raw logs, estimates, SQLite, REST API).

vdp serve --config deploy/vdp.toml                       # in the car
vdp serve --simulate [--scenario paper] [--sim-speed 20] # no hardware: simulator on a virtual bus
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import sys
from pathlib import Path

from ..errors import ConfigError

log = logging.getLogger(__name__)

SIM_DIR = Path("out/serve")  # --simulate keeps its database and raw logs here by default


def add_parser(sub):
    p = sub.add_parser(
        "serve",
        help="run the live service: read the bus, log, estimate, serve HTTP",
        description="Read a CAN bus (or, with --simulate, the simulator on an in-process "
        "virtual bus), keep the raw frames on disk, estimate the parameters as "
        "the car drives, save them to SQLite and answer over HTTP.",
    )
    p.add_argument("--config", type=Path, help="service config TOML (example: deploy/vdp.toml)")
    p.add_argument("--simulate", action="store_true", help="no hardware: run the simulator onto a virtual bus")
    from ..sim.scenario import SCENARIOS
    from ..sim.sensors import NOISE_MODELS

    p.add_argument(
        "--scenario", choices=sorted(SCENARIOS), default="paper", help="--simulate: the scenario (default: paper)"
    )
    p.add_argument(
        "--sim-speed",
        type=float,
        default=20.0,
        help="--simulate: multiple of real time; 0 = as fast as estimation keeps up (default 20)",
    )
    p.add_argument("--noise", choices=NOISE_MODELS, help="--simulate: sensor noise model (default: the simulator's)")
    p.add_argument("--seed", type=int, default=1, help="--simulate: random seed (default 1)")
    p.add_argument(
        "--loop", action="store_true", help="--simulate: drive the scenario again and again, the seed one up each time"
    )
    p.add_argument("--profile", help="--simulate: vehicle profile (default: profiles/paper.toml)")
    p.add_argument(
        "--db", type=Path, help=f"estimate database (--simulate default: {SIM_DIR}/state.sqlite, in the current folder)"
    )
    p.add_argument(
        "--raw-dir", type=Path, help=f"raw CAN log directory (--simulate default: {SIM_DIR}/raw, in the current folder)"
    )
    p.add_argument("--host", help="address to listen on (default 127.0.0.1; anything else is logged)")
    p.add_argument("--port", type=int, help="TCP port (default 8000; 0 picks a free one)")
    return p


def _settings(args):
    from .. import settings as st

    if args.simulate == bool(args.config):
        raise ConfigError("give either --config FILE (a real bus) or --simulate (no hardware)")
    if args.simulate:
        from ..sim.run import resolve_profile

        token = os.environ.get("VDP_RESET_TOKEN") or None
        return st.simulate_settings(
            profile=resolve_profile(args.profile).resolve(),
            workdir=SIM_DIR,
            scenario=args.scenario,
            speed=args.sim_speed,
            db=args.db,
            host=args.host or "127.0.0.1",
            port=8000 if args.port is None else args.port,
            noise=args.noise,
            seed=args.seed,
            loop=args.loop,
            reset_token=token,
            raw_dir=args.raw_dir,
        )
    for flag in ("profile", "raw_dir", "noise"):
        if getattr(args, flag):
            raise ConfigError(f"--{flag.replace('_', '-')} is for --simulate; with --config set it in the file")
    s = st.load_settings(args.config)
    if args.db:
        from dataclasses import replace

        s = replace(s, store=replace(s.store, path=args.db))
    return st.with_overrides(s, host=args.host, port=args.port)


def _bind(host: str, port: int) -> socket.socket:
    """Bind before starting anything, so a busy port is a one-line error, not a half-started service."""
    try:
        family, kind, proto = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][:3]
    except socket.gaierror as exc:
        raise ConfigError(f"cannot listen on {host}: {exc}") from None
    # proto must say TCP: asyncio sets TCP_NODELAY only on sockets whose proto is IPPROTO_TCP,
    # and without it each answer (headers and body are two writes) waits ~40 ms for a delayed ACK.
    sock = socket.socket(family, kind, proto)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise ConfigError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    sock.listen(128)
    sock.set_inheritable(True)
    return sock


class _Terminate:
    """SIGTERM before and after uvicorn's own handler: stop cleanly (commit, close the raw log).

    Until the server exists, raise SystemExit (only service.start() can be running).  Once
    it exists, only ask it to stop: an exception thrown into the main thread at an
    arbitrary point (say, while it holds a lock a worker needs) could hang the exit.
    uvicorn re-raises the signal to us after its graceful shutdown; that is then a no-op.
    """

    def __init__(self):
        self.server = None

    def __call__(self, signum, frame):
        if self.server is None:
            raise SystemExit(0)
        self.server.should_exit = True


def build_server(settings, service):
    """The uvicorn server of ``vdp serve`` over a started service (tests run it in a thread)."""
    import uvicorn

    from ..api import create_app

    verbose = logging.getLogger().level <= logging.INFO
    api = settings.api
    limit = api.max_connections or _concurrency()
    config = uvicorn.Config(
        _guard_hosts(create_app(settings, service, max_requests=limit - HEALTH_RESERVE), api.host, api.allowed_hosts),
        log_level="info" if verbose else "warning",
        access_log=verbose,
        lifespan="on",
        timeout_graceful_shutdown=5,
        # The API must never starve the logger of file descriptors or CPU: bounded connections, idle
        # ones closed after a few seconds, slow ones after [api] header_timeout (see _guarded_protocol).
        # uvicorn's own limit_concurrency would answer 503 to /health too once slow clients hold it.
        limit_concurrency=None,
        timeout_keep_alive=TIMEOUT_KEEP_ALIVE,
        # h11 refuses a request head larger than this (431); the httptools protocol counts it itself
        h11_max_incomplete_event_size=HEAD_LIMIT,
        http=_guarded_protocol(limit, api.header_timeout),
    )
    return uvicorn.Server(config)


# s a thread holds the GIL before one waiting gets it: CPython's own 5 ms.  1 ms was tried against
# the API's p99 on a saturated bus and made no difference (11.4 against 11.0 ms, docs/decisions/
# 0020): what did was the receive thread's blocks and the snapshot
# routes.  VDP_SWITCH_INTERVAL sets another, for measuring.
SWITCH_INTERVAL = float(os.environ.get("VDP_SWITCH_INTERVAL", "0.005"))


def tune_interpreter() -> None:
    """Settings of the interpreter for a live service (vdp serve, and the benchmarks that stand in for it)."""
    sys.setswitchinterval(SWITCH_INTERVAL)
    # glibc gives each thread that allocates an arena of its own (up to 8 a core); a long-running
    # service of six threads then holds freed memory in all of them.  Two arenas: less RSS.
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").mallopt(-8, 2)  # M_ARENA_MAX
    except (OSError, AttributeError):
        pass  # not glibc


def run(args) -> int:
    from ..api import check_host
    from ..live import Service
    from ..live.lock import service_lock

    settings = _settings(args)
    check_host(settings.api.host)
    sock = _bind(settings.api.host, settings.api.port)
    try:
        # one service per store and raw-log directory: a second one is refused here, untouched files
        lock = service_lock(settings).acquire()
    except BaseException:
        sock.close()
        raise
    _raise_nofile()
    tune_interpreter()
    logging.getLogger("asyncio").addFilter(_AcceptErrors())
    service = Service(settings)
    terminate = _Terminate()
    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        service.start()
        terminate.server = server = build_server(settings, service)
        host, port = sock.getsockname()[:2]
        url = f"http://{'[' + host + ']' if ':' in host else host}:{port}"
        what = (
            f"simulating '{settings.simulate.scenario}' at {settings.simulate.speed:g}x on a virtual bus"
            if settings.simulate.enabled
            else f"reading {settings.bus.interface} '{settings.bus.channel}'"
        )
        print(
            f"vdp serve: {what}; estimates at {url}/estimates, health {url}/health, "
            f"status {url}/status, API docs {url}/docs",
            file=sys.stderr,
            flush=True,
        )
        if service.restored:
            print(
                f"vdp serve: carried on from the estimates saved in {settings.store.path} "
                f"(delete it, or pass --db NEW, to start from the priors)",
                file=sys.stderr,
                flush=True,
            )
        if service.store_state == "refused":
            print(f"vdp serve: not using the stored estimates: {service.store_error}", file=sys.stderr, flush=True)
        if settings.raw_log.enabled:
            print(f"vdp serve: raw CAN log in {settings.raw_log.dir}", file=sys.stderr, flush=True)
        server.run(sockets=[sock])
    finally:
        # a saturated queue holds ~32,000 frames, 7-10 s of estimation: a stop gives them STOP_BUDGET
        service.stop(budget=STOP_BUDGET, say=lambda words: print(f"vdp serve: {words}", file=sys.stderr, flush=True))
        sock.close()
        lock.release()
        signal.signal(signal.SIGTERM, previous)
    return 0


STOP_BUDGET = 1.0  # s a stop spends receiving's end and the queued frames: Ctrl-C exits within 2 s
LIMIT_CONCURRENCY = 2048  # connections at most (fewer under a low open-file limit)
HEALTH_RESERVE = 8  # of those, kept for GET /health: other requests in flight beyond the rest get 503
FD_RESERVE = 256  # open files kept for everything but API sockets: raw logs, the store, the bus
TIMEOUT_KEEP_ALIVE = 5  # s an idle connection stays open, also one that never sends a request


def _concurrency() -> int:
    """LIMIT_CONCURRENCY, or fewer when the open-file limit leaves less room beside FD_RESERVE."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    except (ImportError, ValueError, OSError):
        return LIMIT_CONCURRENCY
    if soft == resource.RLIM_INFINITY:
        return LIMIT_CONCURRENCY
    return max(32, min(LIMIT_CONCURRENCY, soft - FD_RESERVE))


HEAD_LIMIT = 16 * 1024  # bytes of a request head (request line and headers): a few KB is all vdp's routes need


def _guarded_protocol(limit: int, header_timeout: float):
    """uvicorn's HTTP protocol with two guards against clients that hold connections open.

    - A request head (request line and headers) must arrive within ``header_timeout`` s of the
      connection opening or of the previous answer; a client sending a byte every few seconds
      (slow-loris) is closed then.  uvicorn cancels its keep-alive timer on any byte and has no
      head timeout of its own; its idle timer is also started at open here (uvicorn starts it
      only after a first answer, so a client that connects and says nothing held its socket).
    - At most ``limit`` connections: a newcomer beyond it closes the oldest connection still
      waiting for its request head, so a client that asks promptly (a health check) is answered
      while slow ones hold the rest.  With none of those, the newcomer is closed.

    The protocol is uvicorn's httptools one (a C parser: 0.45-0.53 ms of CPU a request against
    h11's 0.77-0.79 on this machine, 0.32-0.36 with uvloop; docs/decisions/0020), h11's where
    httptools is not installed.  A head over HEAD_LIMIT is refused with 431 either way.
    """
    try:
        import httptools  # noqa: F401
        from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol as Base
    except ImportError:
        from uvicorn.protocols.http.h11_impl import H11Protocol as Base

    waiting: dict = {}  # connections still sending a request head -> None, oldest first
    live: set = set()
    said = {"at": -60.0, "closed": 0}  # one warning a minute under a flood

    class Guarded(Base):
        def connection_made(self, transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            live.add(self)
            self.timeout_keep_alive_task = self.loop.call_later(
                self.timeout_keep_alive, self.timeout_keep_alive_handler
            )
            self._head_task = None
            self._head_bytes, self._refused = 0, False
            self._await_head()
            if len(live) > limit:
                victim = next((c for c in waiting if c is not self), self)
                victim._drop()
                said["closed"] += 1
                if self.loop.time() - said["at"] >= 60.0:
                    said["at"] = self.loop.time()
                    log.warning(
                        "%d connections open, at most %d ([api] max_connections): closed the oldest still "
                        "sending its request (%d so far)",
                        len(live),
                        limit,
                        said["closed"],
                    )

        def _await_head(self) -> None:
            waiting[self] = None
            if self._head_task is None:
                self._head_task = self.loop.call_later(header_timeout, self._drop)

        def _head_done(self) -> None:
            waiting.pop(self, None)
            if self._head_task is not None:
                self._head_task.cancel()
                self._head_task = None

        def _drop(self) -> None:
            self._head_done()
            if not self.transport.is_closing():
                self.transport.close()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if not self.transport.is_closing():
                self._await_head()  # the next request on this connection gets the same time

        def connection_lost(self, exc) -> None:
            self._head_done()
            live.discard(self)
            super().connection_lost(exc)

        if Base.__name__ == "HttpToolsProtocol":
            # the parser's callbacks: the head's size as it comes, and its end

            def on_message_begin(self) -> None:
                self._head_bytes = 0
                self._refused = False
                super().on_message_begin()

            def on_url(self, url: bytes) -> None:
                self._count(len(url))
                super().on_url(url)

            def on_header(self, name: bytes, value: bytes) -> None:
                self._count(len(name) + len(value) + 4)
                super().on_header(name, value)

            def _count(self, n: int) -> None:
                self._head_bytes += n
                if self._head_bytes > HEAD_LIMIT and not self._refused:
                    self._refused = True  # the rest of what the parser has is not this app's
                    self._head_done()
                    self.transport.write(
                        b"HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-length: 0\r\n"
                        b"connection: close\r\n\r\n"
                    )
                    self.transport.close()

            def on_headers_complete(self) -> None:
                self._head_done()  # a request came in whole: it is the app's (and the body timeout's) now
                if not self._refused:
                    super().on_headers_complete()

            def on_body(self, body: bytes) -> None:
                if not self._refused:
                    super().on_body(body)

            def on_message_complete(self) -> None:
                if not self._refused:
                    super().on_message_complete()

            def data_received(self, data: bytes) -> None:
                if not self.transport.is_closing():
                    super().data_received(data)

        else:

            def data_received(self, data: bytes) -> None:
                import h11

                super().data_received(data)
                if self in waiting and self.conn.their_state is not h11.IDLE:
                    self._head_done()  # a request came in whole: it is the app's (and the body timeout's) now

    return Guarded


class _AcceptErrors(logging.Filter):
    """asyncio logs a traceback for every accept() that fails for lack of file descriptors
    (about 110 MB in 30 s under a connection flood); let one through a minute, with a count."""

    EVERY = 60.0

    def __init__(self):
        super().__init__()
        self._last = -self.EVERY
        self._dropped = 0

    def filter(self, record: logging.LogRecord) -> bool:
        if "accept" not in str(record.msg):
            return True
        import time

        now = time.monotonic()
        if now - self._last < self.EVERY:
            self._dropped += 1
            return False
        self._last = now
        record.msg = (
            f"{record.msg} ({self._dropped} more like it not shown; connections are bounded and idle ones closed)"
        )
        record.exc_info = None
        record.exc_text = None
        self._dropped = 0
        return True


_LOCAL = ("127.0.0.1", "::1", "localhost")


def _raise_nofile() -> None:
    """Soft limit of open files up to the hard one: sockets must never take the raw log's last fd."""
    try:
        import resource

        soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        want = hard if hard != resource.RLIM_INFINITY else 65536
        if soft != resource.RLIM_INFINITY and soft < want:
            resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))
    except (ImportError, ValueError, OSError) as exc:
        log.warning("could not raise the open-file limit: %s", exc)


def _guard_hosts(app, host: str, allowed: str = ""):
    """Answer only requests whose Host header names this machine, loopback included.

    A page on another site can make a browser on this machine (or on the car's network) send
    requests here under a DNS name of the attacker's that resolves to 127.0.0.1 or to the
    logger (DNS rebinding); those are refused (400).  Always answered: localhost, 127.0.0.1,
    [::1]; beyond loopback also the machine's names and any IP address (an address as Host is
    never that attack).  [api] allowed_hosts (and VDP_ALLOWED_HOSTS), comma-separated, add names.
    """
    names = {"localhost"}
    if host not in _LOCAL:
        names.update((socket.gethostname(), socket.getfqdn()))
    extra = f"{allowed},{os.environ.get('VDP_ALLOWED_HOSTS', '')}"
    names.update(n.strip() for n in extra.split(",") if n.strip())
    names = {n.lower() for n in names}
    log.info(
        "accepting Host headers: %s and %s",
        ", ".join(sorted(names)),
        "loopback addresses" if host in _LOCAL else "IP addresses",
    )
    from ..api.guard import HostGuard

    return HostGuard(app, frozenset(names), any_address=host not in _LOCAL)
