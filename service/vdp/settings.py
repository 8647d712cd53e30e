"""Typed settings of the live service, loaded from one TOML file.

Nothing here runs at import time: ``load_settings(path)`` (``vdp serve
--config``) or ``simulate_settings(...)`` (``vdp serve --simulate``) builds a
:class:`Settings` tree at start-up, and every problem is a
:class:`vdp.errors.ConfigError` that names the file, the table and the key.

Relative paths in the file are relative to the file's own directory, so a
config and its profile can move together.
"""

from __future__ import annotations

import logging
import math
import sys
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from .errors import ConfigError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BusSettings:
    interface: str = "socketcan"
    channel: str = "can0"
    bitrate: int | None = 500_000  # socketcan ignores it: the kernel sets it (`ip link ... bitrate`)
    receive_own_messages: bool = False
    # vdp never transmits.  Where python-can can open the interface silent, it does
    # (see live.bus.LISTEN_ONLY); socketcan has no such flag: set it on the netdev.
    listen_only: bool = True
    # bytes of kernel receive buffer asked for a socket bus (None: live.bus.RECEIVE_BUFFER, ~1 s of a saturated bus)
    receive_buffer: int | None = None
    kwargs: dict[str, Any] = field(default_factory=dict)  # passed to can.Bus as they are


@dataclass(frozen=True)
class RawLogSettings:
    enabled: bool = True
    dir: Path = Path("raw")
    max_bytes: int = 64 * 1024 * 1024  # per file
    max_files: int = 64  # oldest deleted beyond this; bounds disk use to max_bytes * max_files
    # MiB of free space kept on the raw log's disk: under it the oldest files go (None: two files' worth)
    min_free_mb: int | None = None
    prefix: str = "vdp"


@dataclass(frozen=True)
class StoreSettings:
    path: Path = Path("vdp.sqlite")
    commit_interval: float = 1.0  # s between committed batches
    history_max_rows: int = 2_000_000  # oldest rows pruned beyond this
    synchronous: str = "full"  # "full" survives power loss with the last commit; "normal" may lose it


@dataclass(frozen=True)
class ApiSettings:
    host: str = "127.0.0.1"
    port: int = 8000
    reset_token: str | None = None  # POST /reset is disabled without one
    # Host header names answered besides localhost, 127.0.0.1 and [::1] (comma-separated), e.g. the logger's
    # DNS name; any other name is refused (DNS rebinding).  Bound beyond loopback, IP addresses are answered too.
    allowed_hosts: str = ""
    max_body: int = 4096  # bytes of a request body; a larger one is refused (413) before it is read
    header_timeout: float = 10.0  # s for a request's head (and then its body) to arrive; slower ones are closed
    # connections at once (None: 2,048, or fewer under a low open-file limit); when all are taken, the oldest
    # one still sending its request head is closed for the newcomer
    max_connections: int | None = None


@dataclass(frozen=True)
class SimulateSettings:
    enabled: bool = False
    scenario: str = "paper"
    speed: float = 20.0  # x real time; 0 = as fast as the estimator keeps up
    noise: str | None = None  # None: the simulator's default
    seed: int = 1
    loop: bool = False  # start the scenario again when it ends


# how the mass is taken (core.mass.MassConfig's modes, the same words: tests/test_service_settings.py)
MASS_MODES = ("auto", "on", "report", "off")


@dataclass(frozen=True)
class ServiceSettings:
    queue_size: int = 65_536  # frames between receive and estimation (about 8 s of a saturated bus)
    publish_interval: float = 0.25  # s between snapshots the API serves
    reconnect_min: float = 0.5  # s, first reconnect delay; doubles up to reconnect_max
    reconnect_max: float = 30.0
    silence: float = 5.0  # s without any frame: the bus is reported silent
    diverged_hold: float = 60.0  # s /health stays degraded after a filter reset
    # stage 2 estimates the front and the rear cornering stiffness separately (LearnerConfig.per_axle)
    per_axle: bool = True
    # the mass as driven (core.mass.MassConfig, as vdp replay --mass): "auto" learns it and puts it into
    # C_K, C_alpha and I_z once it is valid; "on" from the start; "report" learns it only; "off" takes the
    # profile's as known (/estimates says it is not estimated).  true and false (before "auto") mean on, off.
    mass: str = "auto"
    # model the road's grade and bank and the IMU's tilt with the body (core.road; the bank a state of
    # stage 2, docs/decisions/0025), as vdp replay --road does: for a car driven on hills and banked roads
    road: bool = False


@dataclass(frozen=True)
class Settings:
    profile: Path
    bus: BusSettings = field(default_factory=BusSettings)
    raw_log: RawLogSettings = field(default_factory=RawLogSettings)
    store: StoreSettings = field(default_factory=StoreSettings)
    api: ApiSettings = field(default_factory=ApiSettings)
    simulate: SimulateSettings = field(default_factory=SimulateSettings)
    service: ServiceSettings = field(default_factory=ServiceSettings)
    source: str = "<defaults>"  # where the settings came from, for messages


# -- validation -------------------------------------------------------------------------
def _where(src: str, table: str, key: str | None = None) -> str:
    return f"{src} [{table}]" + (f" '{key}'" if key else "")


def _check(src: str, table: str, key: str, value: Any, typ: Any) -> Any:
    """Check one value against the dataclass field's declared type; return it converted."""
    w = _where(src, table, key)
    t = typ.replace(" ", "") if isinstance(typ, str) else typ
    optional = isinstance(t, str) and t.endswith("|None")
    base = t[: -len("|None")] if optional else t
    if value is None:
        if optional:
            return None
        raise ConfigError(f"{w}: must not be empty")
    if base == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{w}: must be true or false, got {value!r}")
        return value
    if base == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{w}: must be an integer, got {value!r}")
        return value
    if base == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{w}: must be a finite number, got {value!r}")
        return float(value)
    if base == "str":
        if not isinstance(value, str):
            raise ConfigError(f"{w}: must be a string, got {value!r}")
        return value
    if base == "Path":
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{w}: must be a path (a non-empty string), got {value!r}")
        return Path(value)
    if base == "dict[str,Any]":
        if not isinstance(value, dict):
            raise ConfigError(f"{w}: must be a table, got {value!r}")
        return dict(value)
    raise AssertionError(f"unhandled settings type {typ!r}")  # pragma: no cover


def _table(src: str, name: str, cls: type, raw: Any, base: Path, paths: tuple[str, ...] = ()) -> Any:
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ConfigError(f"{_where(src, name)}: must be a table")
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(raw) - set(known))
    if unknown:
        raise ConfigError(f"{_where(src, name)}: unknown key(s) {unknown}; allowed: {sorted(known)}")
    vals = {}
    for key, value in raw.items():
        v = _check(src, name, key, value, known[key].type)
        if key in paths and v is not None and not v.is_absolute():
            v = (base / v).resolve()
        vals[key] = v
    return cls(**vals)


def _positive(src: str, table: str, key: str, value: float, allow_zero: bool = False) -> None:
    if value < 0 or (value == 0 and not allow_zero):
        raise ConfigError(f"{_where(src, table, key)}: must be {'>= 0' if allow_zero else 'positive'}, got {value}")


def _interface(src: str, name: str) -> None:
    """An interface python-can does not know is a typo, not a bus that is off: refuse it at start
    (the bus keeper would retry it for ever, as if the car were not on)."""
    import difflib

    from can.interfaces import VALID_INTERFACES

    if name in VALID_INTERFACES:
        return
    near = difflib.get_close_matches(name, sorted(VALID_INTERFACES), n=2)
    hint = f"; did you mean {' or '.join(repr(n) for n in near)}?" if near else ""
    raise ConfigError(
        f"{_where(src, 'bus', 'interface')}: python-can has no interface {name!r} "
        f"(it has: {', '.join(sorted(VALID_INTERFACES))}){hint}"
    )


def validate(s: Settings) -> Settings:
    """Checks that span keys or ranges; returns ``s`` unchanged."""
    src = s.source
    if not s.bus.interface:
        raise ConfigError(f"{_where(src, 'bus', 'interface')}: must name a python-can interface")
    _interface(src, s.bus.interface)
    if s.bus.bitrate is not None:
        _positive(src, "bus", "bitrate", s.bus.bitrate)
    if s.bus.receive_buffer is not None:
        _positive(src, "bus", "receive_buffer", s.bus.receive_buffer)
    if s.bus.receive_own_messages:
        raise ConfigError(
            f"{_where(src, 'bus', 'receive_own_messages')}: must be false; vdp never "
            "transmits, so there is nothing of its own to receive"
        )
    reserved = {"interface", "channel", "bitrate", "receive_own_messages", "receive_buffer"} & set(s.bus.kwargs)
    if reserved:
        raise ConfigError(f"{_where(src, 'bus.kwargs')}: {sorted(reserved)} belong in [bus] itself")
    _positive(src, "raw_log", "max_bytes", s.raw_log.max_bytes)
    if s.raw_log.max_bytes < 4096:
        raise ConfigError(f"{_where(src, 'raw_log', 'max_bytes')}: must be at least 4096, got {s.raw_log.max_bytes}")
    if s.raw_log.max_files < 2:
        raise ConfigError(
            f"{_where(src, 'raw_log', 'max_files')}: must be at least 2 (the open file "
            f"and one closed one), got {s.raw_log.max_files}"
        )
    if s.raw_log.min_free_mb is not None and (
        isinstance(s.raw_log.min_free_mb, bool)
        or not isinstance(s.raw_log.min_free_mb, int)
        or s.raw_log.min_free_mb < 0
    ):
        raise ConfigError(f"{_where(src, 'raw_log', 'min_free_mb')}: must be a whole number of MiB >= 0")
    if not s.raw_log.prefix or any(c in s.raw_log.prefix for c in "/\\ -"):
        raise ConfigError(f"{_where(src, 'raw_log', 'prefix')}: must be a plain word without '/', ' ' or '-'")
    raw = Path(s.raw_log.dir)
    if s.raw_log.enabled and raw.exists() and not raw.is_dir():
        raise ConfigError(f"{_where(src, 'raw_log', 'dir')} (--raw-dir): {raw} is a file, not a folder")
    store = Path(s.store.path)
    if store.is_dir():
        raise ConfigError(f"{_where(src, 'store', 'path')} (--db): {store} is a folder; name a database file in it")
    _positive(src, "store", "commit_interval", s.store.commit_interval)
    _positive(src, "store", "history_max_rows", s.store.history_max_rows)
    if s.store.synchronous not in ("full", "normal"):
        raise ConfigError(
            f"{_where(src, 'store', 'synchronous')}: must be 'full' or 'normal', got {s.store.synchronous!r}"
        )
    if not 0 <= s.api.port <= 65535:
        raise ConfigError(f"{_where(src, 'api', 'port')}: must be within 0..65535, got {s.api.port}")
    if not s.api.host:
        raise ConfigError(f"{_where(src, 'api', 'host')}: must not be empty")
    if s.api.reset_token is not None and len(s.api.reset_token) < 16:
        raise ConfigError(
            f"{_where(src, 'api', 'reset_token')}: must be at least 16 characters "
            "(generate one with: openssl rand -hex 24), or leave it out to disable POST /reset"
        )
    if not 64 <= s.api.max_body <= 1 << 20:
        raise ConfigError(f"{_where(src, 'api', 'max_body')}: must be within 64..1048576 bytes, got {s.api.max_body}")
    _positive(src, "api", "header_timeout", s.api.header_timeout)
    if s.api.max_connections is not None and s.api.max_connections < 16:
        raise ConfigError(f"{_where(src, 'api', 'max_connections')}: must be at least 16, got {s.api.max_connections}")
    _positive(src, "simulate", "speed", s.simulate.speed, allow_zero=True)
    sv = s.service
    _positive(src, "service", "queue_size", sv.queue_size)
    _positive(src, "service", "publish_interval", sv.publish_interval)
    _positive(src, "service", "reconnect_min", sv.reconnect_min)
    _positive(src, "service", "silence", sv.silence)
    _positive(src, "service", "diverged_hold", sv.diverged_hold, allow_zero=True)
    if sv.reconnect_max < sv.reconnect_min:
        raise ConfigError(f"{_where(src, 'service', 'reconnect_max')}: must be >= reconnect_min")
    if sv.mass not in MASS_MODES:
        raise ConfigError(f"{_where(src, 'service', 'mass')}: must be one of {', '.join(MASS_MODES)}, got {sv.mass!r}")
    return s


_SECTIONS = {
    "bus": BusSettings,
    "raw_log": RawLogSettings,
    "store": StoreSettings,
    "api": ApiSettings,
    "simulate": SimulateSettings,
    "service": ServiceSettings,
}
_PATHS = {"raw_log": ("dir",), "store": ("path",)}


def parse(raw: dict[str, Any], source: str, base: Path) -> Settings:
    """Settings from an already-parsed TOML document."""
    unknown = sorted(set(raw) - set(_SECTIONS) - {"profile"})
    if unknown:
        raise ConfigError(f"{source}: unknown section(s) or key(s) {unknown}; allowed: profile, {', '.join(_SECTIONS)}")
    prof = raw.get("profile")
    if not isinstance(prof, str) or not prof:
        raise ConfigError(f"{source}: 'profile' is missing; set profile = \"path/to/vehicle.toml\" at the top")
    profile = Path(prof)
    if not profile.is_absolute():
        profile = (base / profile).resolve()
    svc = raw.get("service")
    if isinstance(svc, dict) and isinstance(svc.get("mass"), bool):  # a switch before "auto": on or off
        raw = {**raw, "service": {**svc, "mass": "on" if svc["mass"] else "off"}}
    parts = {
        name: _table(source, name, cls, raw.get(name), base, _PATHS.get(name, ())) for name, cls in _SECTIONS.items()
    }
    return validate(Settings(profile=profile, source=source, **parts))


def load_settings(path: str | Path) -> Settings:
    """Read and validate a config file (``vdp serve --config``)."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: no such config file (an example is deploy/vdp.toml)")
    try:
        raw = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    return parse(raw, str(p), p.resolve().parent)


def simulate_settings(
    profile: Path,
    workdir: Path,
    scenario: str = "paper",
    speed: float = 20.0,
    db: Path | None = None,
    host: str = "127.0.0.1",
    port: int = 8000,
    noise: str | None = None,
    seed: int = 1,
    loop: bool = False,
    reset_token: str | None = None,
    raw_dir: Path | None = None,
) -> Settings:
    """Settings of ``vdp serve --simulate``: an in-process virtual bus, files under ``workdir``."""
    s = Settings(
        profile=profile,
        bus=BusSettings(interface="virtual", channel="", bitrate=None, listen_only=False),
        raw_log=RawLogSettings(dir=raw_dir or workdir / "raw", max_bytes=16 * 1024 * 1024, max_files=16),
        store=StoreSettings(path=db or workdir / "state.sqlite"),
        api=ApiSettings(host=host, port=port, reset_token=reset_token),
        simulate=SimulateSettings(enabled=True, scenario=scenario, speed=speed, noise=noise, seed=seed, loop=loop),
        source="vdp serve --simulate",
    )
    return validate(s)


def with_overrides(s: Settings, **api: Any) -> Settings:
    """A copy with some [api] keys replaced (command-line --host/--port beat the file)."""
    keep = {k: v for k, v in api.items() if v is not None}
    return validate(replace(s, api=replace(s.api, **keep))) if keep else s
