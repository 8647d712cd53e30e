"""Run a scenario: truth physics + driver -> sensors -> CAN frames, streamed in time order.

In-process API (used by ``vdp simulate``, the tests and ``vdp serve --simulate``)::

    frames, truth = simulate("profiles/paper.toml", "paper", seed=1, noise="realistic")
    for msg in frames: ...            # can.Message, time-ordered, generated lazily

Timing: integration step 1 ms; each message is sampled at its DBC cycle time with a
fixed phase inside the period; timestamps are ``start_time + t`` exactly.
Randomness comes from independent streams of one seed (IMU biases, sensor noise,
frame drops, filler frames), so the same seed gives byte-identical output and
turning drops on does not change the noise.

The pieces: :mod:`.base` (clock, profile lookup), :mod:`.filler` (drops, unrelated
frames), :mod:`.trace` (physics only), :mod:`.logfile` (log and truth files) and
:mod:`.bus` (a live bus); every name stays importable from here.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

import can
import numpy as np

from ..channels import STATUS
from ..errors import ConfigError, ProfileError
from ..profile import Profile
from .base import (  # noqa: F401 (this module's names before the split)
    DEFAULT_PROFILE,
    DT,
    REPO_ROOT,
    START_TIME,
    STEP_MS,
    TRUTH_FORMAT,
    _profile,
    resolve_profile,
    wheel_slips,
)
from .bus import open_bus, paced, send_live, tee_bus
from .driver import Driver, DriverConfig
from .encode import Encoder
from .events import EventRun, Events
from .events import plan as plan_events
from .filler import _Filler, _Uniforms
from .logfile import check_writable, truth_path, write_log, write_truth  # noqa: F401 (check_writable: cli.simulate's)
from .road import Imu, Road, add_load, body_accel, get_road, placement
from .scenario import Scenario, get_scenario
from .sensors import NoiseModel, Sensors, draw_bias, noise_model
from .trace import trace
from .truth import axle_parameters, truth_parameters
from .vehicle import Model, Params

log = logging.getLogger(__name__)

Tap = Callable[[float, str, dict], None]


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
