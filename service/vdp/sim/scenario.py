"""Manoeuvres: speed and road-wheel angle commands over time, with segment metadata.

Times are seconds from log start.  Each segment has a kind that tells the
estimator (and its tests) what it was built for:

* ``stage1``: straight acceleration/braking (Table 2, first stage),
* ``stage2``: constant speed with continuous steering (second stage),
* ``transition``: a speed change between the paper's two stages,
* ``other``: anything else (settling, cruising, stops, turns).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

from ..errors import ConfigError

log = logging.getLogger(__name__)

KINDS = ("stage1", "stage2", "transition", "other")

SpeedFn = Callable[[float], "tuple[float, float]"]  # local time -> (v_cmd, dv_cmd/dt)
SteerFn = Callable[[float], float]  # local time -> road-wheel angle command [rad]


# -- command primitives ----------------------------------------------------------------
def const_speed(v: float) -> SpeedFn:
    return lambda t: (v, 0.0)


def ramp_speed(v0: float, v1: float, T: float) -> SpeedFn:
    """Half-cosine from v0 to v1 over T: smooth speed, bounded jerk at both ends."""
    dv, w = v1 - v0, math.pi / T

    def f(t: float) -> tuple[float, float]:
        if t >= T:
            return v1, 0.0
        return v0 + 0.5 * dv * (1.0 - math.cos(w * t)), 0.5 * dv * w * math.sin(w * t)

    return f


def sine_speed(vc: float, amp: float, period: float) -> SpeedFn:
    w = 2.0 * math.pi / period
    return lambda t: (vc + amp * math.sin(w * t), amp * w * math.cos(w * t))


def no_steer(t: float) -> float:
    return 0.0


def sawtooth_steer(amp: float, period: float) -> SteerFn:
    """Ramp -amp -> +amp over a period, then jump back (Figure 6); the driver rate-limits the jump."""
    return lambda t: -amp + 2.0 * amp * ((t / period) % 1.0)


def sine_steer(amp: float, period: float) -> SteerFn:
    w = 2.0 * math.pi / period
    return lambda t: amp * math.sin(w * t)


def turn_steer(angle: float, T: float, v: float, wheelbase: float) -> SteerFn:
    """Half-sine steer over T that turns the heading by about ``angle`` at speed v.

    Kinematic: heading = int v delta / L dt = v A 2T / (pi L); ignores the understeer
    gradient, so the real heading change is off by a few per cent.
    """
    amp = angle * math.pi * wheelbase / (2.0 * v * T)
    w = math.pi / T
    return lambda t: amp * math.sin(w * t) if t < T else 0.0


# -- scenario --------------------------------------------------------------------------
@dataclass(frozen=True)
class Segment:
    name: str
    kind: str
    start: float
    end: float
    speed: SpeedFn
    steer: SteerFn

    def meta(self) -> dict:
        return {"name": self.name, "kind": self.kind, "start": round(self.start, 6), "end": round(self.end, 6)}


@dataclass(frozen=True)
class Scenario:
    name: str
    v0: float  # initial speed; the car starts in steady straight motion (or held if 0)
    segments: tuple[Segment, ...]

    @property
    def duration(self) -> float:
        return self.segments[-1].end

    def meta(self, duration: float | None = None) -> list[dict]:
        """Segment metadata, clipped to ``duration`` when the run is truncated."""
        end = self.duration if duration is None else min(duration, self.duration)
        out = []
        for s in self.segments:
            if s.start >= end:
                break
            d = s.meta()
            d["end"] = round(min(s.end, end), 6)
            out.append(d)
        return out

    def command(self, t: float, hint: int = 0) -> tuple[float, float, float, int]:
        """(v_cmd, a_cmd, delta_cmd, segment index) at time t; pass the index back as hint."""
        segs = self.segments
        i = hint
        while i + 1 < len(segs) and t >= segs[i].end:
            i += 1
        s = segs[i]
        tl = min(t, s.end) - s.start
        v, a = s.speed(tl)
        return v, a, s.steer(tl), i


class Plan:
    """Builds a scenario segment by segment, keeping track of the current speed."""

    def __init__(self, name: str, v0: float):
        self.name, self.v0, self.v, self.t = name, float(v0), float(v0), 0.0
        self.segments: list[Segment] = []

    def add(self, name: str, kind: str, T: float, speed: SpeedFn, v_end: float, steer: SteerFn | None = None) -> Plan:
        if kind not in KINDS:
            raise ConfigError(f"scenario {self.name}: segment kind must be one of {KINDS}, got {kind!r}")
        if T <= 0:
            raise ConfigError(f"scenario {self.name}: segment '{name}' needs a positive duration")
        self.segments.append(Segment(name, kind, self.t, self.t + T, speed, steer or no_steer))
        self.t += T
        self.v = float(v_end)
        return self

    def cruise(self, T: float, name: str, kind: str = "other", steer: SteerFn | None = None) -> Plan:
        return self.add(name, kind, T, const_speed(self.v), self.v, steer)

    def hold(self, T: float, name: str = "stop") -> Plan:
        if self.v != 0.0:
            raise ConfigError(f"scenario {self.name}: '{name}' holds a stopped car; ramp to 0 first")
        return self.add(name, "other", T, const_speed(0.0), 0.0)

    def ramp(self, v1: float, T: float, name: str, kind: str = "other", steer: SteerFn | None = None) -> Plan:
        return self.add(name, kind, T, ramp_speed(self.v, v1, T), v1, steer)

    def sine(
        self, amp: float, period: float, cycles: int, name: str, kind: str = "other", steer: SteerFn | None = None
    ) -> Plan:
        return self.add(name, kind, period * cycles, sine_speed(self.v, amp, period), self.v, steer)

    def build(self) -> Scenario:
        if not self.segments:
            raise ConfigError(f"scenario {self.name}: no segments")
        return Scenario(self.name, self.v0, tuple(self.segments))


# -- the named scenarios -----------------------------------------------------------------
DEG = math.pi / 180.0


def _stage1(p: Plan) -> Plan:
    # Figure 4, centred at 20 m/s (NOTES 11): 20 + 10 sin(2 pi t / 12.5), 4 cycles.
    return p.cruise(2.0, "settle").sine(10.0, 12.5, 4, "stage1", "stage1")


def _stage2(p: Plan) -> Plan:
    # Figure 6: sawtooth road-wheel angle, period 10 s, amplitude 5 deg, at 10 m/s.
    return p.cruise(2.0, "straight").cruise(50.0, "stage2", "stage2", steer=sawtooth_steer(5.0 * DEG, 10.0))


def stage1(wheelbase: float = 2.5) -> Scenario:
    return _stage1(Plan("stage1", 20.0)).build()


def stage2(wheelbase: float = 2.5) -> Scenario:
    return _stage2(Plan("stage2", 10.0)).build()


def paper(wheelbase: float = 2.5) -> Scenario:
    p = _stage1(Plan("paper", 20.0))
    p.ramp(10.0, 8.0, "transition", "transition")
    return _stage2(p).build()


def city(wheelbase: float = 2.5) -> Scenario:
    """About four minutes of mixed driving; speeds stay <= 20 m/s whenever the wheel is turned."""
    L = wheelbase
    right, left = -90.0 * DEG, 90.0 * DEG
    p = Plan("city", 0.0)
    p.hold(3.0, "stop")
    p.ramp(12.0, 8.0, "pull away", "stage1")
    p.cruise(4.0, "cruise 12 m/s")
    p.ramp(5.0, 5.0, "brake for turn", "stage1")
    p.cruise(4.0, "right turn", steer=turn_steer(right, 4.0, 5.0, L))
    p.ramp(10.0, 5.0, "accelerate while steering", steer=sine_steer(1.5 * DEG, 5.0))
    p.cruise(24.0, "weave 10 m/s", "stage2", steer=sine_steer(3.0 * DEG, 4.0))
    p.cruise(2.0, "straight")
    p.ramp(18.0, 7.0, "accelerate", "stage1")
    p.cruise(6.0, "cruise 18 m/s")
    p.ramp(0.0, 9.0, "brake to stop", "stage1")
    p.hold(4.0)
    p.ramp(6.0, 5.0, "pull away", "stage1")
    p.cruise(4.0, "left turn", steer=turn_steer(left, 4.0, 6.0, L))
    p.ramp(10.0, 4.0, "accelerate")
    p.sine(2.0, 8.0, 4, "weave 8-12 m/s", steer=sine_steer(2.5 * DEG, 4.0))
    p.cruise(40.0, "sawtooth 10 m/s", "stage2", steer=sawtooth_steer(4.0 * DEG, 10.0))
    p.cruise(2.0, "straight")
    p.ramp(15.0, 5.0, "accelerate", "stage1")
    p.sine(5.0, 10.0, 3, "speed sine 10-20 m/s", "stage1")
    p.ramp(8.0, 6.0, "slow for turn", "stage1")
    p.cruise(5.0, "right turn", steer=turn_steer(right, 5.0, 8.0, L))
    p.cruise(9.0, "weave 8 m/s", "stage2", steer=sine_steer(3.5 * DEG, 3.0))
    p.ramp(0.0, 6.0, "brake to stop", "stage1")
    p.hold(5.0)
    p.ramp(10.0, 6.0, "pull away while steering", steer=sine_steer(2.0 * DEG, 6.0))
    p.ramp(0.0, 6.0, "brake to stop", "stage1")
    p.hold(2.0)
    return p.build()


def lane_change(amp: float, T: float, wait: float = 0.0) -> SteerFn:
    """One full sine of road-wheel angle over T after ``wait`` s: the car moves a lane across
    and straightens (amp at speed v gives a peak a_y of about v^2 amp / L)."""

    def steer(t: float) -> float:
        tau = t - wait
        return amp * math.sin(2.0 * math.pi * tau / T) if 0.0 <= tau <= T else 0.0

    return steer


def _ordinary(name: str, wheelbase: float, v_stop: float) -> Scenario:
    """About 14 minutes as an owner drives: town blocks with stops and junction turns, an
    arterial road with lane changes and bends, a highway cruise with lane changes, and town
    again.  No test-track manoeuvre: a_y mostly under 3 m/s^2, speeds held, firm
    acceleration only when pulling away.  Segments are labelled ``other``: what the
    supervisor takes from them is its own gating's business.  ``v_stop`` > 0 rolls through
    the stops at that speed instead (a model that cannot stand still)."""
    L = wheelbase
    right, left = -90.0 * DEG, 90.0 * DEG
    p = Plan(name, v_stop)

    def stop(T: float) -> None:
        if v_stop > 0.0:
            p.cruise(T, "give way")
        else:
            p.hold(T)

    def town(turn: float, v: float) -> None:
        stop(4.0)
        p.ramp(v, 7.0, "pull away")
        p.cruise(12.0, "town street", steer=sine_steer(0.4 * DEG, 7.0))
        p.ramp(5.0, 4.0, "slow for junction")
        p.cruise(4.5, "junction turn", steer=turn_steer(turn, 4.5, 5.0, L))
        p.ramp(v, 6.0, "accelerate out")
        p.cruise(15.0, "town street", steer=lane_change(1.5 * DEG, 4.0, 6.0))
        p.ramp(v_stop, 6.0, "stop at lights")

    for turn, v in ((right, 13.0), (left, 12.0), (right, 14.0), (left, 11.0)):
        town(turn, v)
    stop(3.0)
    p.ramp(17.0, 12.0, "on to the arterial")
    for _ in range(2):
        p.cruise(20.0, "arterial, lane change", steer=lane_change(1.1 * DEG, 5.0, 8.0))
        p.cruise(8.0, "arterial bend", steer=turn_steer(right / 3.0, 8.0, 17.0, L))
        p.cruise(20.0, "arterial", steer=sine_steer(0.2 * DEG, 9.0))
        p.cruise(8.0, "arterial bend", steer=turn_steer(left / 3.0, 8.0, 17.0, L))
        p.ramp(11.0, 6.0, "slow for traffic")
        p.cruise(10.0, "arterial, traffic")
        p.ramp(17.0, 8.0, "traffic clears")
    p.ramp(30.0, 18.0, "on to the highway")
    for _ in range(4):
        p.cruise(25.0, "highway", steer=sine_steer(0.08 * DEG, 12.0))
        p.cruise(8.0, "highway lane change", steer=lane_change(0.35 * DEG, 6.0, 1.0))
        p.cruise(15.0, "highway curve", steer=turn_steer(left / 6.0, 15.0, 30.0, L))
        p.sine(2.0, 20.0, 1, "highway, speed varies")
    p.ramp(15.0, 14.0, "off the highway")
    p.cruise(6.0, "exit bend", steer=turn_steer(right / 2.0, 6.0, 15.0, L))
    p.ramp(v_stop, 10.0, "stop at the end of the ramp")
    for turn, v in ((left, 12.0), (right, 13.0)):
        town(turn, v)
    stop(3.0)
    return p.build()


def ordinary(wheelbase: float = 2.5) -> Scenario:
    return _ordinary("ordinary", wheelbase, 0.0)


def ordinary_rolling(wheelbase: float = 2.5) -> Scenario:
    """``ordinary`` rolling through its stops at 5 m/s: for the independent models, whose
    explicit wheel integration needs the car moving (vdp.sim.independent.brush)."""
    return _ordinary("ordinary_rolling", wheelbase, 5.0)


SCENARIOS: dict[str, Callable[..., Scenario]] = {
    "stage1": stage1,
    "stage2": stage2,
    "paper": paper,
    "city": city,
    "ordinary": ordinary,
    "ordinary_rolling": ordinary_rolling,
}


def get_scenario(name: str, wheelbase: float = 2.5) -> Scenario:
    try:
        return SCENARIOS[name](wheelbase)
    except KeyError:
        raise ConfigError(f"unknown scenario '{name}'; choose one of {', '.join(SCENARIOS)}") from None
