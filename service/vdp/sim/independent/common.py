"""What the independent models share: the drive, the truth definitions, and the path onto the bus.

A model (see :class:`Model`) steps its own state with its own integrator.  :func:`drive`
runs it through a scenario with vdp's driver and records, every millisecond, the
noise-free value of each canonical channel plus the axle loads; the physics never
depends on the seed, so one recorded drive serves every seed and noise model.
:class:`IndependentSimulation` then adds sensor noise and encodes the frames through
the profile's DBC exactly as :class:`vdp.sim.run.Simulation` does, so the log reaches
the estimator by the same DBC -> candump -> ``vdp replay`` path.

The profile handed to the estimator holds only what a user would know of the car:
mass, wheelbase, wheel radius, wheel inertia, roll stiffness and damping, steering
ratio, track, and deliberately imperfect priors.  The truth file is never read by it.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from ... import channels
from ...errors import ConfigError
from ...profile import Prior, Profile, Vehicle, load_profile
from ..driver import Driver, DriverConfig
from ..encode import Encoder
from ..scenario import Scenario, get_scenario
from ..sensors import NoiseModel, Normals, draw_bias, noise_model
from . import DEFINITIONS

log = logging.getLogger(__name__)

DT = 0.001  # s: integration step and sampling grid (every DBC cycle time is a whole number of ms)
START_TIME = 1700000000.0
TRUTH_FORMAT = "vdp-truth/1"
REPO_ROOT = Path(__file__).resolve().parents[4]
BASE_PROFILE = REPO_ROOT / "profiles" / "paper.toml"  # vdp's bus: its DBC and channel map, nothing of its car
DBC = (BASE_PROFILE.parent / "../dbc/vdp.dbc").resolve()  # the DBC that profile names
SETTLE = 3.0  # s driven straight before the recorded drive starts
AUX = ("F_zf", "F_zr", "v_x", "a_x")  # recorded beside the channels, for the truth definitions


@dataclass
class Model:
    """Interface of an independent model; subclasses fill in the physics.

    ``step(x, T_f, T_r, delta, dt)`` returns ``(x_next, out)`` where ``out`` holds, at
    ``x`` (before the step): the 12 canonical channel values in :data:`vdp.channels.NAMES`
    order (torques as given) followed by :data:`AUX`.
    """

    name: str = ""
    car: str = ""
    mass: float = 0.0
    wheelbase: float = 0.0
    wheel_radius: float = 0.0
    wheel_inertia_axle: float = 0.0  # both wheels of an axle [kg m^2]
    roll_stiffness: float = 0.0  # what a K&C rig reports for the whole car [N m/rad]
    roll_damping: float = 0.0  # [N m s/rad]
    steering_ratio: float = 15.0
    track: float = 1.5
    g: float = 9.81
    priors: dict[str, tuple[float, float]] = field(default_factory=dict)
    # issue 28 (sim.road), each off by default: the mass the profile declares when the car carries
    # an undeclared load (None: ``mass``), the road under it, the IMU's mounting
    declared_mass: float | None = None
    load_kg: float = 0.0
    road: Any = None
    imu: Any = None

    def set_road(self, theta: float, phi: float) -> None:
        """The road's grade and bank under the car now (a model that drives roads overrides it)."""
        raise ConfigError(f"{self.name}: this model drives only flat roads")

    # -- physics, per model ---------------------------------------------------------
    def initial(self, v0: float) -> list[float]:
        raise NotImplementedError

    def step(
        self, x: list[float], T_f: float, T_r: float, delta: float, dt: float, delta_end: float | None = None
    ) -> tuple[list[float], tuple]:
        """(state after dt, the channels' row at x); the steering command goes linearly from
        ``delta`` to ``delta_end`` over the step (held when None)."""
        raise NotImplementedError

    def fx(self, kappa: float, F_z: float, axle: str) -> float:
        """Longitudinal force of one tyre at slip ratio kappa, no slip angle, no camber."""
        raise NotImplementedError

    def fy(self, alpha: float, F_z: float, axle: str) -> float:
        """Lateral force of one tyre at slip angle alpha (vdp's sign: F_y > 0 for alpha > 0), no slip ratio."""
        raise NotImplementedError

    def static_truth(self) -> dict[str, float]:
        """l_f, I_z and I_x as :data:`DEFINITIONS` says (they do not depend on the drive)."""
        raise NotImplementedError

    def describe(self) -> dict:
        """The model's own parameters, for the truth file."""
        return {}

    # -- what the estimator is told ------------------------------------------------
    def vehicle(self) -> Vehicle:
        return Vehicle(
            name=f"{self.name}-{self.car}",
            mass=self.mass if self.declared_mass is None else self.declared_mass,
            wheelbase=self.wheelbase,
            wheel_radius=self.wheel_radius,
            wheel_inertia=self.wheel_inertia_axle,
            roll_stiffness=self.roll_stiffness,
            roll_damping=self.roll_damping,
            steering_ratio=self.steering_ratio,
            track=self.track,
            g=self.g,
        )

    def kc(self) -> dict[str, float]:
        """The front wheels' compliance and roll steer as a K&C rig reports them, in the profile's
        Vehicle fields (core.steer); {} for a model whose steering is rigid."""
        return {}

    def profile(self) -> Profile:
        """vdp's bus (profiles/paper.toml's DBC and channels) with this car's known constants and priors."""
        base = load_profile(BASE_PROFILE)
        priors = {k: Prior(float(v), float(s)) for k, (v, s) in self.priors.items()}
        return dataclasses.replace(base, vehicle=self.vehicle(), priors=priors)

    def profile_toml(self) -> str:
        """The same profile as a TOML file (absolute DBC path), for ``vdp replay --profile``."""
        v = self.vehicle()
        lines = [
            f"# {self.name} model, car '{self.car}': known constants and priors only (vdp simulate --model).",
            "# The unknowns' true values are in the drive's truth JSON, never here.",
            "",
            "[vehicle]",
            f'name = "{v.name}"',
        ]
        for k in ("mass", "wheelbase", "wheel_radius", "wheel_inertia", "roll_stiffness", "roll_damping"):
            lines.append(f"{k} = {getattr(v, k)!r}")
        lines += [f"steering_ratio = {v.steering_ratio!r}", f"track = {v.track!r}", f"g = {v.g!r}", "", "[priors]"]
        kc = self.kc()
        if kc:  # known to a K&C rig, not to every owner: declared only when uncommented (core.steer)
            lines[-2:-2] = [
                "# the K&C rig's figures of this car's steering (uncomment to declare them):",
                f"# compliance_steer_deg_per_kN = {kc.get('compliance_steer', 0.0) * 180e3 / math.pi:.4g}",
                f"# roll_steer_front = {kc.get('roll_steer_f', 0.0)!r}",
                f"# roll_steer_rear = {kc.get('roll_steer_r', 0.0)!r}",
            ]
        for k, (val, sd) in self.priors.items():
            lines.append(f"{k} = {{ value = {float(val)!r}, std = {float(sd)!r} }}")
        text = BASE_PROFILE.read_text(encoding="utf-8")
        can_part = text[text.index("[can]") :]
        can_part = can_part.replace('dbc = "../dbc/vdp.dbc"', f'dbc = "{DBC}"')
        return "\n".join(lines) + "\n\n" + can_part


# -- the drive --------------------------------------------------------------------------
@dataclass
class Trace:
    """A recorded drive at 1 ms: ``values[n, i]`` is channel i (:data:`vdp.channels.NAMES`) at t = n DT."""

    model: str
    car: str
    scenario: str
    duration: float
    values: np.ndarray  # (n, 12) noise-free channel values
    aux: np.ndarray  # (n, len(AUX))
    segments: list[dict]

    @property
    def t(self) -> np.ndarray:
        return np.arange(len(self.values)) * DT

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        np.savez_compressed(
            path,
            values=self.values,
            aux=self.aux,
            meta=json.dumps(
                {
                    "model": self.model,
                    "car": self.car,
                    "scenario": self.scenario,
                    "duration": self.duration,
                    "segments": self.segments,
                }
            ),
        )
        return path

    @classmethod
    def load(cls, path: str | Path) -> Trace:
        with np.load(path) as z:
            meta = json.loads(str(z["meta"]))
            return cls(values=z["values"], aux=z["aux"], **meta)


def drive(
    model: Model,
    scenario: str | Scenario = "paper",
    duration: float | None = None,
    driver: DriverConfig | None = None,
    progress: Callable[[float, float], None] | None = None,
) -> Trace:
    """Run ``model`` through ``scenario`` with vdp's driver; record the noise-free channels every ms."""
    sc = scenario if isinstance(scenario, Scenario) else get_scenario(scenario, model.wheelbase)
    T = sc.duration if duration is None else min(float(duration), sc.duration)
    drv = Driver(driver or DriverConfig(), model.mass, model.wheel_radius, model.wheel_inertia_axle)
    n_steps = int(round(T / DT))
    out = np.empty((n_steps, channels.N_SENSORS + len(AUX)))
    x = model.initial(sc.v0)
    v_x = sc.v0
    # settle straight at the start speed first (the driver's integrator learns the drag), not recorded
    for _ in range(int(round(SETTLE / DT))):
        tf, tr, delta = drv.update(DT, sc.v0, 0.0, 0.0, v_x)
        x, row = model.step(x, tf, tr, delta, DT)
        v_x = row[channels.N_SENSORS + AUX.index("v_x")]
    hint = 0
    every = int(round(1.0 / DT))
    road, dist = model.road, 0.0
    for n in range(n_steps):
        t = n * DT
        v_cmd, a_cmd, d_cmd, hint = sc.command(t, hint)
        tf, tr, delta = drv.update(DT, v_cmd, a_cmd, d_cmd, v_x)
        if road is not None:
            model.set_road(*road.angles(dist))
            dist += v_x * DT
        x, row = model.step(x, tf, tr, delta, DT, drv.next_delta(sc.command(t + DT, hint)[2]))
        out[n] = row
        v_x = row[channels.N_SENSORS + AUX.index("v_x")]
        if not math.isfinite(v_x):
            raise ConfigError(f"{model.name}/{model.car}: the model diverged at t = {t:.3f} s")
        if progress is not None and n % every == 0:
            progress(t, T)
    return Trace(
        model.name, model.car, sc.name, T, out[:, : channels.N_SENSORS], out[:, channels.N_SENSORS :], sc.meta(T)
    )


# -- truth ------------------------------------------------------------------------------
def _mask(trace: Trace, kind: str) -> np.ndarray:
    t = trace.t
    m = np.zeros(len(t), dtype=bool)
    for s in trace.segments:
        if s["kind"] == kind:
            m |= (t >= s["start"]) & (t < s["end"])
    return m


def slope(f: Callable[[float], float], h: float) -> float:
    """Central difference at 0."""
    return (f(h) - f(-h)) / (2.0 * h)


def load_transfer_height(model: Model, trace: Trace) -> float:
    """h from the rear axle's load against m a_x / L (with a constant and v^2), on the straight parts.

    A drive without straight-line acceleration (``stage2``) cannot define it: then the
    model drives the first 25 s of ``stage1`` for it (once per model and car and process).
    """
    m = _mask(trace, "stage1")
    if m.sum() < 10000:
        return _probe_height(model.name, model.car, model.load_kg)
    return _height(model, trace.aux[m])


def _height(model: Model, aux: np.ndarray) -> float:
    F_zr, v, ax = (aux[:, AUX.index(k)] for k in ("F_zr", "v_x", "a_x"))
    if np.ptp(ax) < 1.0:
        raise ConfigError(f"{model.name}/{model.car}: the drive has too little a_x to define h")
    A = np.column_stack([np.ones_like(v), v * v, model.mass * ax / model.wheelbase])
    coef, *_ = np.linalg.lstsq(A, F_zr, rcond=None)
    return float(coef[2])


@functools.cache
def _probe_height(name: str, car: str, load: float = 0.0) -> float:
    from . import get_model

    model = get_model(name, car, load=load) if load else get_model(name, car)
    trace = drive(model, "stage1", duration=25.0)
    return _height(model, trace.aux[_mask(trace, "stage1")])


def axle_loads(trace: Trace, kind: str) -> tuple[float, float]:
    m = _mask(trace, kind)
    if m.sum() < 1000:
        m = np.ones(len(trace.values), dtype=bool)
    return float(trace.aux[m, 0].mean()), float(trace.aux[m, 1].mean())


def truth_of(model: Model, trace: Trace) -> dict:
    """The six parameters (and the per-axle stiffnesses) as :data:`DEFINITIONS` defines them."""
    out = dict(model.static_truth())
    out["h"] = load_transfer_height(model, trace)
    per_axle = {}
    zf, zr = axle_loads(trace, "stage1")
    for axle, z in (("front", zf), ("rear", zr)):
        per_axle[f"C_K_{axle}"] = 2.0 * slope(lambda k, z=z, a=axle: model.fx(k, z / 2.0, a), 1e-5) / z
        per_axle[f"F_z_{axle}_stage1"] = z
    zf, zr = axle_loads(trace, "stage2")
    for axle, z in (("front", zf), ("rear", zr)):
        per_axle[f"C_alpha_{axle}"] = 2.0 * slope(lambda a, z=z, ax=axle: model.fy(a, z / 2.0, ax), 1e-5)
        per_axle[f"F_z_{axle}_stage2"] = z
    out["C_K"] = 0.5 * (per_axle["C_K_front"] + per_axle["C_K_rear"])
    out["C_alpha"] = 0.5 * (per_axle["C_alpha_front"] + per_axle["C_alpha_rear"])
    params = {k: out[k] for k in ("l_f", "h", "C_K", "C_alpha", "I_z", "I_x")}
    return {"parameters": params, "per_axle": per_axle}


# -- onto the bus -----------------------------------------------------------------------
class IndependentSimulation:
    """One drive of an independent model: ``truth`` up front, ``frames()`` streams the bus.

    The same interface as :class:`vdp.sim.run.Simulation` for what ``vdp simulate``
    uses (``truth``, ``frames``, ``bus_channel``, ``duration``, ``scenario``), plus
    ``profile_toml()`` for the profile a user would write for this car.
    """

    def __init__(
        self,
        model: str | Model,
        car: str | None = None,
        scenario: str | Scenario = "paper",
        seed: int = 0,
        noise: str | NoiseModel = "realistic",
        *,
        duration: float | None = None,
        trace: Trace | None = None,
        start_time: float = START_TIME,
        bus_channel: str | None = None,
    ):
        from . import get_model

        self.model = model if isinstance(model, Model) else get_model(model, car)
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
        self.seed = seed
        self.profile = self.model.profile()
        self.scenario = scenario if isinstance(scenario, Scenario) else get_scenario(scenario, self.model.wheelbase)
        self.trace = trace if trace is not None else drive(self.model, self.scenario, duration)
        self.duration = self.trace.duration
        self.start_us = int(round(start_time * 1e6))
        self.bus_channel = bus_channel or self.profile.bus_channel or "can0"
        self.noise = noise if isinstance(noise, NoiseModel) else noise_model(noise, self.model.steering_ratio)
        self.encoder = Encoder(self.profile)
        self.bias = draw_bias(self.noise, self._rngs()[0])
        self.truth = self._truth()

    def _rngs(self) -> list[np.random.Generator]:
        # the same streams as vdp's simulator: [IMU bias, sensor noise, frame drops, filler frames]
        return [np.random.default_rng(s) for s in np.random.SeedSequence(self.seed).spawn(4)]

    def _truth(self) -> dict:
        t = truth_of(self.model, self.trace)
        noise = self.noise.describe()
        noise["bias"] = {c: b for c, b in self.bias.items() if b}
        return {
            "format": TRUTH_FORMAT,
            "parameters": t["parameters"],
            "per_axle": t["per_axle"],
            "definitions": dict(DEFINITIONS),
            "model": {"name": self.model.name, "car": self.model.car, "parameters": self.model.describe()},
            "vehicle": dataclasses.asdict(self.model.vehicle()),
            "derived": {"l_r": self.model.wheelbase - t["parameters"]["l_f"]},
            "scenario": self.scenario.name,
            "seed": self.seed,
            "noise": noise,
            "start_time": self.start_us / 1e6,
            "duration": self.duration,
            "segments": self.trace.segments,
            "dbc": str(self.profile.dbc),
            "sim": {"dt": DT},
            **self._world(),
        }

    def _world(self) -> dict:
        """Issue 28's options that are on (an old truth file stays the same)."""
        m, out = self.model, {}
        if m.declared_mass is not None:
            out["mass"] = m.mass
            out["declared_mass"] = m.declared_mass
        if m.road is not None:
            out["road"] = m.road.describe()
        if m.imu is not None:
            out["imu"] = m.imu.describe()
        return out

    def profile_toml(self) -> str:
        return self.model.profile_toml()

    def frames(self, tap=None, progress: Callable[[float, float], None] | None = None) -> Iterator[can.Message]:
        """Time-ordered frames of the recorded drive with this seed's noise; restarts on every call."""
        _, noise_rng, _, _ = self._rngs()
        normal = Normals(noise_rng)
        sigma = [self.noise.sigma.get(c, 0.0) for c in channels.NAMES]
        bias = [self.bias.get(c, 0.0) for c in channels.NAMES]
        enc = Encoder(self.profile, self.encoder.db)
        idx = {c: i for i, c in enumerate(channels.NAMES)}
        sched = [[p.phase_ms, p.period_ms, p, [(c, idx[c]) for c in p.channels]] for p in enc.plans]
        vals = self.trace.values
        n_steps = len(vals)
        every = 1000
        for n in range(n_steps):
            row = None
            for item in sched:
                if item[0] != n:
                    continue
                item[0] += item[1]
                if row is None:
                    row = vals[n].tolist()
                plan = item[2]
                values = {}
                for c, i in item[3]:
                    s = sigma[i]
                    values[c] = row[i] + bias[i] + (s * normal() if s else 0.0)
                if tap is not None:
                    tap(n * DT, plan.name, values)
                yield can.Message(
                    timestamp=(self.start_us + n * 1000) / 1e6,
                    arbitration_id=plan.frame_id,
                    is_extended_id=plan.is_extended,
                    is_fd=plan.is_fd,
                    data=enc.encode(plan, values),
                    channel=self.bus_channel,
                    is_rx=False,
                )
            if progress is not None and n % every == 0:
                progress(n * DT, self.duration)
        if progress is not None:
            progress(self.duration, self.duration)
