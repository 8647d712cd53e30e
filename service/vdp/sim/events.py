"""Events the two-stage model does not cover, for the simulator: reverse manoeuvres, ABS stops,
kerb strikes and wheel spin (``vdp simulate --events``; off by default).

Each event has a **plan** (when it happens, and the commands it needs) and **effects**.  The
plan is the same with or without the effects (``Events.effects = False``): the drive "without
them" has a stop where the other reverses, and a hard stop on a dry road where the other
stops on a slippery patch with ABS, so the two drives differ by the events alone
(benchmarks/gates.py).

- **Reverse manoeuvre**, in a stop (a ``hold`` of at least REV_MIN s): reverse gear engaged,
  the car rolls back up to REV_SPEED m/s and stops again.  vdp's single-track model rolls
  forwards only (vehicle.py), so the motion is integrated forwards and the sensors read its
  mirror image in the body's x (a_x, the yaw rate and the axle torques change sign; the wheel
  and GNSS speeds, magnitudes on vdp's bus, do not): what a reversing car's sensors read, up to
  the swap of the axles' roles at walking pace.
- **ABS stop**, in a ramp to standstill: a stop at ABS_DECEL m/s^2 demanded, on a patch of
  friction ABS_MU (the effects) or on the dry road (the plan alone).  The driver's ABS
  (driver.Driver) regulates the braked axles at their grip; its flag is the bus's ABS bit.
- **Kerb strike**, in a turn (or anywhere moving): an 80 ms half-sine on a_y, a_x and the roll
  rate, and a dip of the struck side's wheel speeds: a road input no tyre force explains.
- **Wheel spin**, pulling away: the front-left wheel's tread runs up to SPIN_SPEED m/s faster
  than the car for SPIN_TIME s (one wheel on ice), traction control's flag on meanwhile.

The flags go on the bus as the profile maps them (channels.STATUS; profiles/paper_status.toml
maps vdp.dbc's VEHICLE_STATUS).  The driver's own ABS and TCS set them in any drive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import ConfigError
from .scenario import Scenario

REV_MIN = 2.0  # s: the shortest stop a reverse manoeuvre fits in
REV_SPEED = 1.5  # m/s: its peak speed
ABS_DECEL = 6.0  # m/s^2 demanded
ABS_MU = 0.3  # friction of the slippery patch
KERB_TIME = 0.08  # s
KERB_AY, KERB_AX, KERB_ROLL, KERB_WHEEL = 6.0, -3.0, 0.4, 0.2  # m/s^2, m/s^2, rad/s, share of the wheel speed
SPIN_TIME, SPIN_SPEED = 1.5, 4.0  # s, m/s: how much faster than the car the spinning wheel's tread turns at most
KINDS = ("reverse", "abs", "kerb", "spin")


@dataclass(frozen=True)
class Events:
    reverse: int = 0  # reverse manoeuvres
    abs: int = 0  # ABS stops
    kerb: int = 0  # kerb strikes
    spin: int = 0  # wheel-spin launches
    effects: bool = True  # False: the same drive without the events (their plan only)

    @classmethod
    def parse(cls, text: str, effects: bool = True) -> Events:
        """``reverse=2,abs=2,kerb=4,spin=1`` (counts; any left out is 0)."""
        counts = {}
        for part in filter(None, (p.strip() for p in text.split(","))):
            name, _, n = part.partition("=")
            name = name.strip()
            if name not in KINDS or not n.strip().isdigit():
                raise ConfigError(f"--events: '{part}' is not KIND=COUNT with KIND one of {', '.join(KINDS)}")
            counts[name] = int(n)
        return cls(**counts, effects=effects)

    @property
    def any(self) -> bool:
        return bool(self.reverse or self.abs or self.kerb or self.spin)


@dataclass(frozen=True)
class Event:
    kind: str
    start: float
    end: float
    v0: float = 0.0  # the speed at the start (an ABS stop's)
    side: float = 1.0  # a kerb's side: +1 left, -1 right

    def meta(self) -> dict:
        return {"kind": self.kind, "start": round(self.start, 6), "end": round(self.end, 6)}


def _spread(cands: list, n: int) -> list:
    """``n`` of the candidates, spread evenly over them (all if fewer)."""
    if n >= len(cands):
        return cands
    return [cands[int((k + 0.5) * len(cands) / n)] for k in range(n)]


def plan(sc: Scenario, ev: Events, duration: float) -> list[Event]:
    """Where the scenario's events fall; a ConfigError if it has too few places for them."""
    segs = [s for s in sc.segments if s.end <= duration]
    speed = [(s, s.speed(0.0)[0], s.speed(s.end - s.start)[0]) for s in segs]
    out: list[Event] = []
    stops = [s for s, a, b in speed if a == 0.0 and b == 0.0 and s.end - s.start >= REV_MIN]
    brakes = [(s, a) for s, a, b in speed if b == 0.0 and a > 5.0]
    moving = [s for s, a, b in speed if min(a, b) > 5.0]
    turns = [s for s in moving if "turn" in s.name or "bend" in s.name] or moving
    pulls = [s for s, a, b in speed if a == 0.0 and b > 5.0]
    for kind, n, have in (("reverse", ev.reverse, stops), ("abs", ev.abs, brakes), ("kerb", ev.kerb, turns),
                          ("spin", ev.spin, pulls)):  # fmt: skip
        if n > len(have) and kind != "kerb":
            raise ConfigError(
                f"--events {kind}={n}: scenario {sc.name} has {len(have)} place(s) for it in {duration:g} s; "
                f"ask for fewer or choose a scenario with stops (city, ordinary)"
            )
    for s in _spread(stops, ev.reverse):
        out.append(Event("reverse", s.start + 0.2, s.end - 0.2))
    for s, v0 in _spread(brakes, ev.abs):
        out.append(Event("abs", s.start, s.end, v0))
    for k in range(ev.kerb):  # several kerbs may share a turn: spread along them
        if not turns:
            raise ConfigError(f"--events kerb: scenario {sc.name} never drives above 5 m/s")
        s = turns[k % len(turns)]
        f = (k // len(turns) + 0.5) / math.ceil(ev.kerb / len(turns))
        t0 = s.start + f * (s.end - s.start)
        out.append(Event("kerb", t0, t0 + KERB_TIME, side=1.0 if k % 2 else -1.0))
    for s in _spread(pulls, ev.spin):
        out.append(Event("spin", s.start + 0.5, s.start + 0.5 + SPIN_TIME))
    return sorted(out, key=lambda e: e.start)


def _half_sine(t: float, e: Event) -> float:
    return math.sin(math.pi * (t - e.start) / (e.end - e.start))


class EventRun:
    """The events of one drive, step by step: the commands they need, the friction they drive
    on, and what the sensors read."""

    def __init__(self, events: list[Event], effects: bool, mu: float, wheel_radius: float):
        self.events, self.effects, self.mu, self.r = events, effects, mu, wheel_radius
        self.i = 0  # the first event not yet over
        self.now: list[Event] = []

    def at(self, t: float) -> list[Event]:
        ev = self.events
        while self.i < len(ev) and ev[self.i].end + 1.0 < t:
            self.i += 1
        self.now = [e for e in ev[self.i : self.i + 4] if e.start <= t < e.end]
        return self.now

    def command(self, t: float, v: float, a: float, d: float) -> tuple[float, float, float]:
        """The driver's commands at ``t`` (the plan: the same with or without the effects)."""
        for e in self.now:
            if e.kind == "reverse":
                T = e.end - e.start
                w = math.pi / (T - 0.6)
                tau = t - e.start - 0.3  # the gear engages 0.3 s before the car moves, and after it stops
                if 0.0 < tau < T - 0.6:
                    return REV_SPEED * math.sin(w * tau) ** 2, REV_SPEED * w * math.sin(2 * w * tau), 0.0
            elif e.kind == "abs":
                v_cmd = e.v0 - ABS_DECEL * (t - e.start)
                return (v_cmd, -ABS_DECEL, d) if v_cmd > 0.0 else (0.0, 0.0, d)
        return v, a, d

    def friction(self) -> float:
        if self.effects and any(e.kind == "abs" for e in self.now):
            return ABS_MU
        return self.mu

    def sensors(self, t: float, values: dict, braking: bool, driving: bool, limited: bool) -> None:
        """Change one frame's channel values as the events make the sensors read them."""
        if "abs_active" in values:
            values["abs_active"] = 1.0 if limited and braking else 0.0
        if "tcs_active" in values:
            values["tcs_active"] = 1.0 if limited and driving else 0.0
        if not self.effects:
            return
        for e in self.now:
            if e.kind == "reverse":
                if "reverse" in values:
                    values["reverse"] = 1.0
                for c in ("accel_x", "yaw_rate", "wheel_torque_front", "wheel_torque_rear"):
                    if c in values:
                        values[c] = -values[c]
            elif e.kind == "kerb":
                k = _half_sine(t, e)
                for c, amp in (("accel_y", KERB_AY * e.side), ("accel_x", KERB_AX), ("roll_rate", -KERB_ROLL * e.side)):
                    if c in values:
                        values[c] += amp * k
                for c in ("wheel_speed_fl", "wheel_speed_rl") if e.side > 0 else ("wheel_speed_fr", "wheel_speed_rr"):
                    if c in values:
                        values[c] *= 1.0 - KERB_WHEEL * k
            elif e.kind == "spin":
                k = _half_sine(t, e)
                if "wheel_speed_fl" in values:
                    values["wheel_speed_fl"] += SPIN_SPEED * k / self.r
                if "tcs_active" in values:
                    values["tcs_active"] = 1.0
