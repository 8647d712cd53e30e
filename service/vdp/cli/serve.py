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


def run(args) -> int:
    import uvicorn

    from ..api import check_host, create_app
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
    logging.getLogger("asyncio").addFilter(_AcceptErrors())
    service = Service(settings)
    terminate = _Terminate()
    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        service.start()
        verbose = logging.getLogger().level <= logging.INFO
        config = uvicorn.Config(
            _guard_hosts(create_app(settings, service), settings.api.host),
            log_level="info" if verbose else "warning",
            access_log=verbose,
            lifespan="on",
            timeout_graceful_shutdown=5,
            # the API must never starve the logger of file descriptors or CPU: bounded connections
            # (503 beyond), and idle ones closed after a few seconds
            limit_concurrency=_concurrency(),
            timeout_keep_alive=TIMEOUT_KEEP_ALIVE,
            http=_idle_closing_protocol(),
        )
        terminate.server = server = uvicorn.Server(config)
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
LIMIT_CONCURRENCY = 2048  # connections and requests in flight at most; beyond, uvicorn answers 503 at once
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


def _idle_closing_protocol():
    """uvicorn's h11 protocol, with the keep-alive timer also started when a connection opens:
    uvicorn times out idle connections only after a first response, so a client that connects
    and says nothing would hold its socket (and a file descriptor) for ever."""
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class IdleClosing(H11Protocol):
        def connection_made(self, transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self.timeout_keep_alive_task = self.loop.call_later(
                self.timeout_keep_alive, self.timeout_keep_alive_handler
            )

    return IdleClosing


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


def _guard_hosts(app, host: str):
    """Beyond localhost, answer only requests whose Host header is an address or a name of this machine.

    A page on another site can make a browser on the car's network send requests here under
    a DNS name of the attacker's (DNS rebinding); those are refused (400).  An IP address as
    Host is never that attack, so any is accepted.  VDP_ALLOWED_HOSTS (comma-separated) adds
    names, e.g. the logger's DNS name.
    """
    if host in _LOCAL:
        return app
    names = {"localhost", socket.gethostname(), socket.getfqdn()}
    extra = os.environ.get("VDP_ALLOWED_HOSTS", "")
    names.update(n.strip() for n in extra.split(",") if n.strip())
    names = {n.lower() for n in names}
    log.info("accepting Host headers: IP addresses and %s", ", ".join(sorted(names)))
    return HostGuard(app, frozenset(names))


class HostGuard:
    """ASGI middleware: 400 for a Host header that is neither an IP address nor an allowed name."""

    def __init__(self, app, names: frozenset[str]):
        self.app = app
        self.names = names

    def allowed(self, host: str) -> bool:
        import ipaddress

        if host.startswith("["):  # [v6]:port
            name = host[1 : host.find("]")] if "]" in host else host
        else:
            name = host.rsplit(":", 1)[0] if host.count(":") == 1 else host
        name = name.lower()
        if name in self.names:
            return True
        try:
            ipaddress.ip_address(name)
        except ValueError:
            return False
        return True

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http":
            host = next((v.decode("latin-1") for k, v in scope["headers"] if k == b"host"), "")
            if not self.allowed(host):
                from starlette.responses import PlainTextResponse

                await PlainTextResponse(f"Host {host!r} is not one of this logger's names\n", 400)(scope, receive, send)
                return
        await self.app(scope, receive, send)
