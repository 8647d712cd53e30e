"""Run a scenario: truth physics + driver -> sensors -> CAN frames, streamed in time order.

In-process API (used by ``vdp simulate``, the tests and ``vdp serve --simulate``)::

    frames, truth = simulate("profiles/paper.toml", "paper", seed=1, noise="realistic")
    for msg in frames: ...            # can.Message, time-ordered, generated lazily

Timing: integration step 1 ms; each message is sampled at its DBC cycle time with a
fixed phase inside the period; timestamps are ``start_time + t`` exactly.
Randomness comes from independent streams of one seed (IMU biases, sensor noise,
frame drops, filler frames), so the same seed gives byte-identical output and
turning drops on does not change the noise.
"""

from __future__ import annotations

import dataclasses
import gzip
import heapq
import io
import json
import logging
import math
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

import can
import numpy as np

from ..channels import STATUS
from ..errors import BusError, ConfigError, LogFormatError, ProfileError
from ..outfile import replacing, write_text
from ..profile import Profile, load_profile
from .driver import Driver, DriverConfig
from .encode import Encoder
from .events import EventRun, Events
from .events import plan as plan_events
from .road import Imu, Road, add_load, body_accel, get_road, placement
from .scenario import Scenario, get_scenario
from .sensors import NoiseModel, Sensors, draw_bias, noise_model
from .truth import axle_parameters, truth_parameters
from .vehicle import STATE, V_FLOOR, Model, Params

log = logging.getLogger(__name__)

START_TIME = 1700000000.0
STEP_MS = 1  # integration step and sampling grid [ms]; DBC cycle times are whole ms
DT = STEP_MS / 1000.0
TRUTH_FORMAT = "vdp-truth/1"
REPO_ROOT = Path(__file__).resolve().parents[3]
DEFAULT_PROFILE = Path("profiles/paper.toml")

Tap = Callable[[float, str, dict], None]


def resolve_profile(path: str | Path | None = None) -> Path:
    """A profile path as given, else relative to the CWD, else relative to the repository."""
    p = Path(path) if path else DEFAULT_PROFILE
    if p.is_file():
        return p
    if not p.is_absolute():
        for base in (Path.cwd(), REPO_ROOT):
            q = base / p
            if q.is_file():
                return q
    raise ProfileError(f"{p}: no such profile file (looked in {Path.cwd()} and {REPO_ROOT})")


def _profile(profile: Profile | str | Path | None, dbc: str | Path | None) -> Profile:
    prof = profile if isinstance(profile, Profile) else load_profile(resolve_profile(profile))
    if dbc is not None:
        d = Path(dbc)
        if not d.is_file():
            raise ProfileError(f"{d}: DBC file does not exist")
        prof = dataclasses.replace(prof, dbc=d.resolve())
    return prof


class Simulation:
    """One simulated drive.  ``truth`` is known up front; ``frames()`` streams the bus."""

    def __init__(
        self,
        profile: Profile | str | Path | None = None,
        scenario: str | Scenario = "paper",
        seed: int = 0,
        noise: str | NoiseModel = "realistic",
        *,
        params: Mapping[str, float] | None = None,
        dbc: str | Path | None = None,
        drop_rate: float = 0.0,
        extra_ids: int = 0,
        extra_rate: float = 100.0,
        duration: float | None = None,
        start_time: float = START_TIME,
        driver: DriverConfig | None = None,
        bus_channel: str | None = None,
        road: str | Road | None = None,
        load: float = 0.0,
        imu: Imu | None = None,
        events: Events | None = None,
    ):
        self.profile = _profile(profile, dbc)
        veh = self.profile.vehicle
        self.scenario = scenario if isinstance(scenario, Scenario) else get_scenario(scenario, veh.wheelbase)
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
        if not 0.0 <= drop_rate < 1.0:
            raise ConfigError(f"drop rate must be within [0, 1), got {drop_rate}")
        if extra_ids < 0 or (extra_ids and not extra_rate > 0):
            raise ConfigError("extra ids need a count >= 0 and a positive rate")
        if duration is not None and not duration > 0:
            raise ConfigError(f"duration must be positive, got {duration}")
        self.seed, self.drop_rate = seed, float(drop_rate)
        self.extra_ids, self.extra_rate = int(extra_ids), float(extra_rate)
        self.duration = self.scenario.duration if duration is None else min(duration, self.scenario.duration)
        self.start_us = int(round(start_time * 1e6))
        self.bus_channel = bus_channel or self.profile.bus_channel or "can0"
        self.params = truth_parameters(params)
        self.per_axle = axle_parameters(params)
        # issue 28's world (sim.road), each off by default: the road, an undeclared load, the IMU's mounting
        self.road, self.imu = get_road(road), imu
        self.load = placement(load, veh.wheelbase, veh.track) if load else ()
        mp = Params.from_vehicle(veh, {**self.params, **self.per_axle})
        if self.load:  # the car as loaded: its truth is the loaded car's, the profile keeps its mass
            p = mp
            c = add_load(p.m, p.l_f, p.h, p.I_z, p.I_x, 0.0, self.load)
            self.params.update(l_f=c.l_f, h=c.h, I_z=c.I_z, I_x=c.I_x)
            mp = dataclasses.replace(mp, m=c.m, l_f=c.l_f, h=c.h, I_z=c.I_z, I_x=c.I_x)
        self.model = Model(mp)
        dtr = getattr(self.profile, "drivetrain", None)
        if driver is None and dtr is not None:  # drive and brake the axles as the profile says the car does
            driver = DriverConfig(drive_front=dtr.drive_front, brake_front=dtr.brake_balance)
        self.driver_cfg = driver or DriverConfig()
        self.noise = noise if isinstance(noise, NoiseModel) else noise_model(noise, veh.steering_ratio)
        self.encoder = Encoder(self.profile)  # validates the mapping against the DBC now
        for p in self.encoder.plans:
            if p.period_ms <= 0 or p.period_ms % STEP_MS:
                raise ProfileError(
                    f"{self.profile.dbc}: cycle time of {p.name} ({p.period_ms} ms) "
                    f"is not a positive multiple of {STEP_MS} ms"
                )
        if self.extra_ids > 0x800 - len(self.encoder.frame_ids & set(range(0x800))):
            raise ConfigError(f"--extra-ids {self.extra_ids}: not that many free 11-bit IDs")
        self.bias = draw_bias(self.noise, self._rngs()[0])
        self.events = events if events is not None and events.any else None
        self.event_plan = plan_events(self.scenario, self.events, self.duration) if self.events else []
        self.truth = self._truth()

    def _rngs(self) -> list[np.random.Generator]:
        # Independent streams: [IMU bias, sensor noise, frame drops, filler frames].
        return [np.random.default_rng(s) for s in np.random.SeedSequence(self.seed).spawn(4)]

    def _truth(self) -> dict:
        veh = dataclasses.asdict(self.profile.vehicle)
        noise = self.noise.describe()
        noise["bias"] = {c: b for c, b in self.bias.items() if b}
        return {
            "format": TRUTH_FORMAT,
            "parameters": dict(self.params),
            "per_axle": dict(self.per_axle),
            "vehicle": veh,
            "derived": {"l_r": self.profile.vehicle.wheelbase - self.params["l_f"]},
            "scenario": self.scenario.name,
            "seed": self.seed,
            "noise": noise,
            "start_time": self.start_us / 1e6,
            "duration": self.duration,
            "segments": self.scenario.meta(self.duration),
            **self._events_truth(),
            "profile": str(self.profile.path.resolve()),
            "dbc": str(self.profile.dbc),
            "bus": {
                "channel": self.bus_channel,
                "drop_rate": self.drop_rate,
                "extra_ids": self.extra_ids,
                "extra_rate": self.extra_rate if self.extra_ids else 0.0,
                "messages": {
                    p.name: {"id": p.frame_id, "period_ms": p.period_ms, "phase_ms": p.phase_ms}
                    for p in self.encoder.plans
                },
            },
            "driver": dataclasses.asdict(self.driver_cfg),
            "sim": {"dt": DT, "wheels": "linearly implicit backward Euler", "body": "Heun, omega held"},
            **self._world(),
            "units": {
                "parameters": {
                    "l_f": "m",
                    "h": "m",
                    "C_K": "-",
                    "C_alpha": "N/rad (per axle; the mean of per_axle's front and rear)",
                    "I_z": "kg m^2",
                    "I_x": "kg m^2",
                },
                "vehicle": "SI; roll_stiffness N m/rad, roll_damping N m s/rad, wheel_inertia per axle",
            },
        }

    def _world(self) -> dict:
        """The truth file's part on issue 28's options: only those that are on (an old truth stays the same)."""
        out: dict = {}
        if self.load:
            out["mass"] = self.model.params.m
            out["load"] = [dataclasses.asdict(i) for i in self.load]
        if self.road is not None:
            out["road"] = self.road.describe()
        if self.imu is not None:
            out["imu"] = self.imu.describe()
        return out

    def _events_truth(self) -> dict:
        """The events (sim.events) and their plan, for the truth (none: nothing, as before)."""
        if self.events is None:
            return {}
        ev = self.events
        counts = {"reverse": ev.reverse, "abs": ev.abs, "kerb": ev.kerb, "spin": ev.spin}
        return {"events": {"counts": counts, "effects": ev.effects, "plan": [e.meta() for e in self.event_plan]}}

    def frames(
        self, tap: Tap | None = None, progress: Callable[[float, float], None] | None = None
    ) -> Iterator[can.Message]:
        """Time-ordered frames; every call restarts the drive from the same seed.

        ``tap(t, message_name, values)`` sees the canonical values (with noise, before
        quantisation) of every frame that is sent; ``progress(t, duration)`` is called
        about once per simulated second.
        """
        model, sc = self.model, self.scenario
        p = model.params
        drv = Driver(self.driver_cfg, p.m, p.r, p.J)
        _, noise_rng, drop_rng, fill_rng = self._rngs()
        sensors = Sensors(self.noise, self.bias, noise_rng)
        enc = Encoder(self.profile, self.encoder.db)  # fresh counters
        step_ms = STEP_MS
        sched = [
            [p.phase_ms // step_ms, p.period_ms // step_ms, p, [(c, sensors.reader(c)) for c in p.channels]]
            for p in enc.plans
        ]
        drop = self.drop_rate
        drops = _Uniforms(drop_rng)
        fill = (
            _Filler(fill_rng, self.extra_ids, self.extra_rate, enc.frame_ids, self.start_us) if self.extra_ids else None
        )
        chan = self.bus_channel
        x = model.straight(sc.v0)
        n_steps = int(round(self.duration / DT))
        hint = 0
        start_us = self.start_us
        every = int(round(1.0 / DT))
        road, imu, dist = self.road, self.imu if self.imu is not None and self.imu.body else None, 0.0
        ang = (0.0, 0.0)
        hold = 0.5 * p.L if road is not None and road.bank else 0.0  # rad of steer per (rad/s of yaw error / m/s)
        ev = None
        if self.events is not None or any(c in self.profile.channels for c in STATUS):
            # sim.events: the events' commands, friction and sensors, and the status flags on the bus
            model.mu = p.mu
            ev = EventRun(self.event_plan, self.events is not None and self.events.effects, p.mu, p.r)
        for n in range(n_steps):
            t = n * DT
            v_cmd, a_cmd, d_cmd, hint = sc.command(t, hint)
            if hold:  # on a bank the driver holds the line the wheel is meant to give (an oversteering car drifts)
                d_cmd += hold * (x[0] * d_cmd / p.L - x[2]) / max(x[0], 1.0)
            event = ev is not None and ev.at(t)
            if event:
                v_cmd, a_cmd, d_cmd = ev.command(t, v_cmd, a_cmd, d_cmd)
            if ev is not None:
                model.mu = ev.friction()
            tf, tr, delta = drv.update(DT, v_cmd, a_cmd, d_cmd, x[0], wheel_slips(x, p.r))
            if road is not None:
                ang = road.angles(dist)
                model.set_road(*ang)
                dist += x[0] * DT
            # the steering ramps to the next step's angle (continuous, as the sensor samples it)
            d_next = d_cmd if event else sc.command(t + DT, hint)[2]  # (an event's own command: held)
            if hold and not event:
                d_next += hold * (x[0] * d_next / p.L - x[2]) / max(x[0], 1.0)
            x1, e = model.advance(x, tf, tr, delta, DT, drv.next_delta(d_next))
            if imu is not None:
                e = imu_reading(imu, e, x, ang, p.g)
            ts = (start_us + n * step_ms * 1000) / 1e6
            for item in sched:
                if item[0] != n:
                    continue
                item[0] += item[1]
                plan = item[2]
                values = {c: f(x, e, tf, tr, delta) for c, f in item[3]}
                if ev is not None:
                    ev.sensors(t, values, tf + tr < 0.0, tf + tr > 0.0, drv.limited)
                data = enc.encode(plan, values)
                if drop and drops() < drop:
                    continue
                if tap is not None:
                    tap(t, plan.name, values)
                yield can.Message(
                    timestamp=ts,
                    arbitration_id=plan.frame_id,
                    is_extended_id=plan.is_extended,
                    is_fd=plan.is_fd,
                    data=data,
                    channel=chan,
                    is_rx=False,
                )
            if fill is not None:
                end_us = start_us + (n + 1) * step_ms * 1000
                for msg in fill.until(end_us, chan):
                    if not (drop and drops() < drop):
                        yield msg
            if progress is not None and n % every == 0:
                progress(t, self.duration)
            x = x1
        if progress is not None:
            progress(self.duration, self.duration)


def imu_reading(imu: Imu, e: tuple, x, ang: tuple[float, float], g: float) -> tuple:
    """The forces tuple with a_x, a_y as a body-fixed accelerometer reads them (sim.road): the body
    pitched by ``pitch_gain`` per m/s^2 of a_x (the single track has no pitch of its own) and
    rolled by its roll angle, each plus the mounting offset; gravity normal to the road."""
    f_z = g * math.cos(ang[0]) * math.cos(ang[1])
    pitch = imu.pitch_gain * e[0] + imu.mount_pitch
    a_x, a_y = body_accel(e[0], e[1], f_z, pitch, x[3] + imu.mount_roll)
    return (a_x, a_y, *e[2:])


def wheel_slips(x, r: float) -> tuple[float, float]:
    """(s_f, s_r): each axle's wheel slip as its traction control sees it (eq 13, steering left out)."""
    v = x[0]
    d = v if v > V_FLOOR else V_FLOOR
    return (x[5] * r - v) / d, (x[6] * r - v) / d


class _Uniforms:
    def __init__(self, rng: np.random.Generator, block: int = 4096):
        self.rng, self.block, self.buf, self.i = rng, block, [], 0

    def __call__(self) -> float:
        if self.i >= len(self.buf):
            self.buf, self.i = self.rng.random(self.block).tolist(), 0
        self.i += 1
        return self.buf[self.i - 1]


class _Filler:
    """Unrelated frames (IDs not in the DBC, random payloads), each ID at ``rate`` Hz."""

    def __init__(self, rng: np.random.Generator, n: int, rate: float, taken: set[int], start_us: int):
        free = np.array([i for i in range(0x800) if i not in taken])
        self.ids = [int(i) for i in rng.choice(free, size=n, replace=False)]
        self.period_us = max(1, int(round(1e6 / rate)))
        self.rng = rng
        self.heap = [(start_us + int(rng.integers(0, self.period_us)), i) for i in self.ids]
        heapq.heapify(self.heap)

    def until(self, end_us: int, chan: str) -> Iterator[can.Message]:
        heap = self.heap
        while heap[0][0] < end_us:
            ts, fid = heapq.heappop(heap)
            heapq.heappush(heap, (ts + self.period_us, fid))
            yield can.Message(
                timestamp=ts / 1e6,
                arbitration_id=fid,
                is_extended_id=False,
                data=self.rng.bytes(8),
                channel=chan,
                is_rx=False,
            )


def simulate(
    profile: Profile | str | Path | None = None,
    scenario: str | Scenario = "paper",
    seed: int = 0,
    noise: str = "realistic",
    **kwargs,
) -> tuple[Iterator[can.Message], dict]:
    """(lazy time-ordered iterator of can.Message, truth dict); kwargs as :class:`Simulation`."""
    sim = Simulation(profile, scenario, seed, noise, **kwargs)
    return sim.frames(), sim.truth


REPEAT_GAP = 1.0  # s of silence between repeated drives: each starts afresh, as after a stop of the logger


class Repeated:
    """Drives of one scenario back to back in one log, seeds ``seed``, ``seed + 1``, ...: a long
    log of one car for a fleet or a benchmark (``vdp simulate --repeat N``).  Each drive starts
    REPEAT_GAP after the last one ended, from the scenario's start.  The truth is the first
    drive's, with the whole span, the segments of every drive on the log's clock and each
    drive's seed, start and sensor offsets under ``repeat``."""

    def __init__(self, make: Callable[[int, float], Simulation], count: int, start_time: float = START_TIME):
        if count < 1:
            raise ConfigError(f"--repeat must be at least 1, got {count}")
        self.sims: list[Simulation] = []
        t = start_time
        for k in range(count):
            sim = make(k, t)
            self.sims.append(sim)
            t = sim.start_us / 1e6 + sim.duration + REPEAT_GAP
        first, last = self.sims[0], self.sims[-1]
        self.scenario = first.scenario
        self.bus_channel = first.bus_channel
        self.duration = last.start_us / 1e6 + last.duration - first.start_us / 1e6
        self.truth = self._truth()

    def _truth(self) -> dict:
        first = self.sims[0]
        t0 = first.start_us / 1e6
        segments, drives = [], []
        for sim in self.sims:
            off = sim.start_us / 1e6 - t0
            for seg in sim.truth["segments"]:
                segments.append({**seg, "start": round(seg["start"] + off, 6), "end": round(seg["end"] + off, 6)})
            drives.append({"seed": sim.seed, "start": round(off, 6), "duration": sim.duration,
                           "bias": sim.truth["noise"].get("bias", {})})  # fmt: skip
        return {**first.truth, "duration": self.duration, "segments": segments, "repeat": drives}

    def frames(self, tap: Tap | None = None, progress: Callable[[float, float], None] | None = None):
        """Every drive's frames in turn; ``progress`` sees the time into the whole log."""
        t0 = self.sims[0].start_us / 1e6
        for sim in self.sims:
            off = sim.start_us / 1e6 - t0

            def step(t: float, _total: float, off: float = off) -> None:
                if progress is not None:
                    progress(off + t, self.duration)

            yield from sim.frames(tap, step if progress is not None else None)


# -- physics-only trace (tests, plots) ------------------------------------------------
def trace(
    scenario: str | Scenario = "paper",
    profile: Profile | str | Path | None = None,
    *,
    params: Mapping[str, float] | None = None,
    dt: float = DT,
    every: int = 10,
    duration: float | None = None,
    driver: DriverConfig | None = None,
) -> dict[str, np.ndarray]:
    """Truth time series of a scenario, without sensors: states, inputs, forces, heading.

    Keys: ``t``, the state names of :data:`vdp.sim.vehicle.STATE`, ``T_f``, ``T_r``,
    ``delta``, ``v_cmd``, ``delta_cmd``, every :class:`vdp.sim.vehicle.Forces` field,
    and ``heading`` (integrated yaw angle).  Samples every ``every`` steps.
    """
    prof = _profile(profile, None)
    veh = prof.vehicle
    sc = scenario if isinstance(scenario, Scenario) else get_scenario(scenario, veh.wheelbase)
    model = Model(Params.from_vehicle(veh, {**truth_parameters(params), **axle_parameters(params)}))
    p = model.params
    drv = Driver(driver or DriverConfig(), p.m, p.r, p.J)
    T = sc.duration if duration is None else min(duration, sc.duration)
    n_steps = int(round(T / dt))
    keys = (
        ("t",)
        + STATE
        + ("T_f", "T_r", "delta", "v_cmd", "delta_cmd")
        + ("a_x", "a_y", "F_zf", "F_zr", "F_xf", "F_xr", "F_yf", "F_yr", "s_f", "s_r", "alpha_f", "alpha_r")
        + ("heading",)
    )
    rows = []
    x = model.straight(sc.v0)
    hint, psi = 0, 0.0
    for n in range(n_steps):
        t = n * dt
        v_cmd, a_cmd, d_cmd, hint = sc.command(t, hint)
        tf, tr, delta = drv.update(dt, v_cmd, a_cmd, d_cmd, x[0], wheel_slips(x, p.r))
        x1, e = model.advance(x, tf, tr, delta, dt, drv.next_delta(sc.command(t + dt, hint)[2]))
        if n % every == 0:
            rows.append((t, *x, tf, tr, delta, v_cmd, d_cmd, *e, psi))
        psi += 0.5 * dt * (x[2] + x1[2])
        x = x1
    arr = np.array(rows, dtype=float).reshape(-1, len(keys))
    return {k: arr[:, i] for i, k in enumerate(keys)}


# -- outputs ------------------------------------------------------------------------------
def truth_path(log_path: str | Path) -> Path:
    """``drive.log`` -> ``drive.truth.json`` (also for ``drive.log.gz`` and other suffixes)."""
    p = Path(log_path)
    name = p.name
    if name.lower().endswith(".gz"):
        name = name[:-3]
    stem = name.rsplit(".", 1)[0] if "." in name else name
    return p.with_name(stem + ".truth.json")


def write_truth(truth: dict, path: str | Path) -> Path:
    path = Path(path)
    write_text(path, json.dumps(truth, indent=2, sort_keys=False) + "\n")
    return path


def _candump_line(msg: can.Message, chan: str) -> str:
    fid = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    sep = "##0" if msg.is_fd else "#"  # FD frames: flags nibble after '##'
    return f"({msg.timestamp:.6f}) {msg.channel or chan} {fid}{sep}{msg.data.hex().upper()}\n"


def check_writable(path: str | Path) -> None:
    """A LogFormatError unless ``path``'s format is one vdp replays and can be written here."""
    from ..io.logs import FORMATS

    path = Path(path)
    name = path.name.lower()
    suffix = "".join(path.suffixes[-2:]).lower() if name.endswith(".gz") else path.suffix.lower()
    if suffix.removesuffix(".gz") not in FORMATS:
        # python-can writes some formats (.txt, .db) that no reader of vdp's takes back
        raise LogFormatError(
            f"{path}: vdp cannot replay '{suffix or path.name}' logs; write one of "
            f"{', '.join(FORMATS)} (plain .log is candump -L, the bulk reader's)"
        )
    if suffix == ".mf4":
        try:
            import asammdf  # noqa: F401
        except ImportError:
            raise LogFormatError(f"{path}: python-can writes .mf4 only with asammdf: pip install 'vdp[mf4]'") from None


def write_log(frames: Iterator[can.Message], path: str | Path, channel: str = "can0") -> int:
    """Write frames to ``path``; the format follows the suffix.  Returns the frame count.

    ``.log`` and ``.log.gz`` are written directly as ``candump -L`` lines (deterministic,
    gzip without a timestamp); every other suffix goes through ``can.Logger``.
    """
    path = Path(path)
    name = path.name.lower()
    if not path.parent.is_dir():
        raise LogFormatError(f"{path}: directory {path.parent} does not exist")
    if not name.endswith((".log", ".log.gz")):
        check_writable(path)
    with replacing(path) as tmp:  # (the tmp's name ends in path's: python-can picks the same format)
        return _write_frames(frames, tmp, path, channel)


def _write_frames(frames: Iterator[can.Message], dest: Path, path: Path, channel: str) -> int:
    """write_log's work, into ``dest`` (the file that becomes ``path``)."""
    name = path.name.lower()
    n = 0
    if name.endswith((".log", ".log.gz")):
        raw = open(dest, "wb")
        try:
            if name.endswith(".gz"):
                gz = gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0)
                out = io.TextIOWrapper(gz, encoding="ascii", newline="\n")
            else:
                gz, out = None, io.TextIOWrapper(raw, encoding="ascii", newline="\n")
            buf = []
            for msg in frames:
                buf.append(_candump_line(msg, channel))
                n += 1
                if len(buf) >= 4096:
                    out.write("".join(buf))
                    buf.clear()
            out.write("".join(buf))
            out.flush()
            if gz is not None:
                out.detach()
                gz.close()
            else:
                out.detach()
        finally:
            raw.close()
        return n
    try:
        writer = can.Logger(str(dest))
    except ValueError as exc:
        raise LogFormatError(f"{path}: {exc}") from None
    except (NotImplementedError, ImportError) as exc:  # .mf4 needs asammdf
        raise LogFormatError(f"{path}: python-can cannot write it here ({exc}); pip install 'vdp[mf4]'") from None
    with writer:
        for msg in frames:
            writer.on_message_received(msg)
            n += 1
    return n


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


__all__ = [
    "DT",
    "START_TIME",
    "Simulation",
    "open_bus",
    "paced",
    "resolve_profile",
    "send_live",
    "simulate",
    "tee_bus",
    "trace",
    "truth_path",
    "write_log",
    "write_truth",
]
