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
    p.add_argument("--scenario", default="paper", help="--simulate: the scenario (default: paper)")
    p.add_argument(
        "--sim-speed",
        type=float,
        default=20.0,
        help="--simulate: multiple of real time; 0 = as fast as estimation keeps up (default 20)",
    )
    p.add_argument("--noise", help="--simulate: sensor noise model (default: the simulator's)")
    p.add_argument("--seed", type=int, default=1, help="--simulate: random seed (default 1)")
    p.add_argument("--loop", action="store_true", help="--simulate: drive the scenario again and again")
    p.add_argument("--profile", help="--simulate: vehicle profile (default: profiles/paper.toml)")
    p.add_argument("--db", type=Path, help=f"estimate database (--simulate default: {SIM_DIR}/state.sqlite)")
    p.add_argument("--raw-dir", type=Path, help=f"raw CAN log directory (--simulate default: {SIM_DIR}/raw)")
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

    settings = _settings(args)
    check_host(settings.api.host)
    sock = _bind(settings.api.host, settings.api.port)
    service = Service(settings)
    terminate = _Terminate()
    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        service.start()
        verbose = logging.getLogger().level <= logging.INFO
        config = uvicorn.Config(
            create_app(settings, service),
            log_level="info" if verbose else "warning",
            access_log=verbose,
            lifespan="on",
            timeout_graceful_shutdown=5,
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
        service.stop()
        sock.close()
        signal.signal(signal.SIGTERM, previous)
    return 0
