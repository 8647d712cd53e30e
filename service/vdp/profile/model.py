"""What a profile holds: the vehicle's constants, the priors, and how each channel is read (the types)."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

if sys.version_info >= (3, 11):
    pass
else:  # pragma: no cover
    pass

from ..core.params import NAMES
from ..units import UNIT_FACTORS

PARAMETERS = NAMES  # the six unknowns (core.params): each needs a prior
# optional per-axle cornering stiffness priors (stage 2 estimates each axle; C_alpha is their
# mean): both or neither; without them both axles start from the C_alpha prior
AXLE_PRIORS = ("C_alpha_f", "C_alpha_r")


@dataclass(frozen=True)
class Vehicle:
    """Known constants, SI units."""

    name: str
    mass: float  # m [kg]
    wheelbase: float  # L [m]
    wheel_radius: float  # r [m]
    wheel_inertia: float  # J [kg m^2], per axle: both wheels of the axle lumped (NOTES item 9)
    roll_stiffness: float  # k_phi [N m/rad]
    roll_damping: float  # c_phi [N m s/rad]
    steering_ratio: float  # steering-wheel angle / road-wheel angle [-]
    track: float  # b [m]
    g: float = 9.8
    # CG to front axle measured on axle scales (optional): stage 2 then needs no stage 1
    l_f: float | None = None  # [m]
    l_f_std: float | None = None  # [m], its 1-sigma (default 1 % of l_f)
    # The front wheels' steer the steering-wheel angle does not show (a K&C rig's figures; core.steer):
    # compliance steer out of the turn per N of the front axle's lateral force [rad/N] (the tyres'
    # aligning torque on a compliant steering), and roll steer per rad of body roll [rad/rad], front
    # out of the turn and rear into it (each understeer > 0).  0: the steering geometry is rigid.
    compliance_steer: float = 0.0
    roll_steer_f: float = 0.0
    roll_steer_r: float = 0.0


@dataclass(frozen=True)
class Prior:
    value: float
    std: float


@dataclass(frozen=True)
class ChannelMap:
    """How one canonical channel is read from the DBC."""

    channel: str
    message: str
    signal: str
    unit: str
    scale: float = 1.0
    offset: float = 0.0
    sign: float = 1.0
    sign_signal: str | None = None
    steering_wheel: bool = False  # the signal is the steering-wheel angle
    fine: str | None = None  # a finer signal of the same message, added to ``signal``
    alt: ChannelMap | None = None
    range: tuple[float, float] | None = None  # replaces the DBC's [min|max] of ``signal`` (its unit)
    # a status signal of the same message: (signal, values, True if those values mean valid)
    status: tuple[str, frozenset[int], bool] | None = None
    plausible: tuple[float, float] | None = None  # [min, max] of the SI value; outside is invalid
    # a status flag (channels.STATUS) read from an enum: the raw values that mean "on" (a gear
    # signal's reverse); the channel is then 1 while the signal holds one of them, else 0
    active: frozenset[int] | None = None
    where: str = ""  # "profile.toml [channels.x]" for error messages

    def factor(self, vehicle: Vehicle) -> float:
        """Multiplier from (v*scale+offset) in the source unit to canonical SI."""
        f, kind = UNIT_FACTORS[self.unit]
        if self.channel.startswith("wheel_speed") and kind == "speed":
            f /= vehicle.wheel_radius
        if self.steering_wheel:
            f /= vehicle.steering_ratio
        return f * self.sign


@dataclass(frozen=True)
class Term:
    """One signal of a composite channel: ``weight * si`` (or a factor of a product).

    ``factors`` multiply further signals into the term (``weight * si * si_1 * ...``): what a
    product becomes when [drivetrain] shares it out to the axles (a drive torque that is an
    engine torque times the gearbox's ratio).
    """

    map: ChannelMap  # how the signal is read; its ``channel`` is a source name or "term"
    weight: float = 1.0
    when: tuple[int, frozenset[int]] | None = None  # (index of a condition, its values): else 0
    factors: tuple[ChannelMap, ...] = ()


@dataclass(frozen=True)
class Composite:
    """A canonical channel computed from signals of one or more messages.

    ``sum``: the sum of ``weight * term``; ``product``: the product of the terms (times the
    first term's weight).  A term with ``when`` counts only while its condition signal (an
    enum such as a gear or a direction) holds one of the given raw values.  Each term keeps
    its newest value; the channel is emitted whenever a term arrives and every term is newer
    than ``max_age``.
    """

    channel: str
    op: str
    terms: tuple[Term, ...]
    conditions: tuple[ChannelMap, ...] = ()  # enum signals read raw
    max_age: float = 0.5  # s
    where: str = ""

    @property
    def maps(self) -> tuple[ChannelMap, ...]:
        """Every signal it reads, in slot order: each term's signal, then the terms' further
        factors (term by term), then the conditions (from :attr:`cond_start` on)."""
        return (
            tuple(t.map for t in self.terms) + tuple(f for t in self.terms for f in t.factors) + tuple(self.conditions)
        )

    @property
    def cond_start(self) -> int:
        return len(self.terms) + sum(len(t.factors) for t in self.terms)

    @property
    def messages(self) -> set[str]:
        return {m.message for m in self.maps}


@dataclass(frozen=True)
class Drivetrain:
    """Which axles drive, how the brakes split, and how brake pressure becomes torque."""

    driven: str = "front"  # "front", "rear" or "all"
    front_share: float = 0.5  # for "all": the front axle's share of the drive torque
    brake_balance: float = 0.65  # the front axle's share of the brake torque
    brake_gain: float | None = None  # N m of total brake torque per bar of brake pressure

    @property
    def drive_front(self) -> float:
        return {"front": 1.0, "rear": 0.0}.get(self.driven, self.front_share)

    @property
    def free_axle(self) -> str | None:
        """The axle no drive torque reaches ("front" or "rear"), a speed reference while unbraked."""
        return {"front": "rear", "rear": "front"}.get(self.driven)


@dataclass(frozen=True)
class MessageCheck:
    """Rolling counter and checksum of one message, checked or ignored."""

    message: str
    counter: str | None = None
    checksum: str | None = None
    checksum_kind: str = "vdp"  # "vdp" (see dbc/vdp.dbc) or "none"
    check: bool = True


@dataclass(frozen=True)
class Profile:
    path: Path
    vehicle: Vehicle
    priors: dict[str, Prior]
    dbc: Path
    bus_channel: str | None  # only frames from this log/bus channel are used (None = all)
    channels: dict[str, ChannelMap]
    checks: dict[str, MessageCheck] = field(default_factory=dict)
    extra_dbcs: tuple[Path, ...] = ()  # further DBCs of the same bus (dbc = [first, ...])
    composites: dict[str, Composite] = field(default_factory=dict)
    drivetrain: Drivetrain | None = None  # None: not given (per-axle torques mapped directly)
    # drive_torque, brake_torque, brake_pressure: one signal, or a composite (an engine torque times a ratio)
    sources: dict[str, ChannelMap | Composite] = field(default_factory=dict)
    cycle_ms: dict[str, int] = field(default_factory=dict)  # message periods the DBC does not give
    pad_short: bool = False  # frames shorter than their DBC length get zero bytes appended

    @property
    def dbcs(self) -> tuple[Path, ...]:
        return (self.dbc,) + self.extra_dbcs

    def has(self, name: str) -> bool:
        return name in self.channels or name in self.composites

    @property
    def speed_reference(self) -> str | None:
        """Where stage 1 and 2 get the ground speed: "gnss", "wheels" (the free-rolling axle
        while unbraked, with the IMU), or None."""
        if "speed" in self.channels:
            return "gnss"
        dt = self.drivetrain
        if dt is not None and dt.free_axle is not None:
            side = "f" if dt.free_axle == "front" else "r"
            if all(f"wheel_speed_{side}{w}" in self.channels for w in "lr"):
                return "wheels"
        return None

    def missing(self, needs: tuple[str, ...]) -> list[str]:
        out = [c for c in needs if not self.has(c) and not (c == "speed" and self.speed_reference)]
        if self.sources and "drive_torque" not in self.sources:  # the one source this car lacks
            out = ["drive_torque" if c == "wheel_torque_front" else c for c in out if c != "wheel_torque_rear"]
        return out
