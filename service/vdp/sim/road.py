"""What a real drive adds to the test track: the road's grade and bank, an undeclared load,
and an IMU fixed to the body (issue 28).  Each is off by default.

These describe the *world* a simulated car drives in (like :mod:`.scenario`), not a
vehicle model: vdp's simulator (:mod:`.run`) and the independent models
(:mod:`.independent`) both take them, each with its own physics.  Nothing here is
used by the estimator (``vdp.core``).

Signs (vdp's channels): x forward, y left, z up.  Grade theta > 0 climbs (gravity pulls
the car back: ``dv_x/dt = f_x - g sin theta``); bank phi > 0 puts the right side down
(the same sign as the body's roll), so gravity pulls the car right and a car standing
on it reads ``a_y = +g sin phi``.  Body pitch > 0 is nose up (the body squats when
accelerating), body roll > 0 right side down.

An accelerometer measures specific force (acceleration minus gravity).  One aligned
with the road reads the contact forces over the mass, ``f = (sum F)/m`` (what vdp's
eq 1 and eq 7 call a_x, a_y); on a grade that is ``dv/dt + g sin theta``.  One fixed
to the body reads f in the body's axes, tilted by the suspension's pitch and roll
(:func:`body_accel`): on a flat road it reads ``f_x + g pitch`` and ``f_y + g roll``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import ConfigError

DEG = math.pi / 180.0


# -- the road ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Road:
    """A smooth road profile by distance travelled: grade (peak ``grade``, as tan) and bank
    (peak ``bank`` [rad]).  ``constant``: the peaks everywhere (a test's slope).

    The grade is two sines of distance (800 m and 260 m, 70 % and 30 % of the peak): a
    typical grade is about 0.75 of the peak (6 % of 8 %) and it never exceeds it; the bank
    one sine of 450 m.  ``phase`` shifts all three (a different stretch of road).
    """

    grade: float = 0.0
    bank: float = 0.0
    constant: bool = False
    phase: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.grade) and abs(self.grade) <= 0.3):
            raise ConfigError(f"road grade must be within +-0.3 (30 %), got {self.grade!r}")
        if not (math.isfinite(self.bank) and abs(self.bank) <= 10.0 * DEG):
            raise ConfigError(f"road bank must be within +-10 deg, got {self.bank / DEG!r} deg")

    def angles(self, s: float) -> tuple[float, float]:
        """(grade angle theta, bank angle phi) [rad] at distance s [m]."""
        if self.constant:
            return math.atan(self.grade), self.bank
        p = self.phase
        w = 2.0 * math.pi * s
        tan_th = self.grade * (0.7 * math.sin(w / 800.0 + p) + 0.3 * math.sin(w / 260.0 + 2.0 * p + 1.0))
        return math.atan(tan_th), self.bank * math.sin(w / 450.0 + 3.0 * p + 2.0)

    def describe(self) -> dict:
        return {"grade_peak": self.grade, "bank_peak_deg": self.bank / DEG, "constant": self.constant,
                "phase": self.phase}  # fmt: skip


ROADS = {
    "flat": Road(),
    "hills": Road(grade=0.08, bank=3.0 * DEG),  # issue 28: typically +-6 %, up to 8 %, bank +-3 deg
}


def get_road(name: str | Road | None) -> Road | None:
    if name is None or isinstance(name, Road):
        return name
    try:
        return ROADS[name]
    except KeyError:
        raise ConfigError(f"unknown road '{name}'; choose one of {', '.join(ROADS)}") from None


# -- the IMU's mounting ------------------------------------------------------------------
@dataclass(frozen=True)
class Imu:
    """How the accelerometer sits.  ``body``: fixed to the body, tilting with the suspension;
    else aligned with the road (vdp's model up to now).  ``pitch_gain``: body pitch per unit
    longitudinal specific force [rad per m/s^2] where the model has no pitch of its own (vdp's
    single-track simulator; the brush model pitches by its springs).  ``mount_pitch``,
    ``mount_roll``: a fixed mounting offset [rad]."""

    body: bool = False
    pitch_gain: float = 0.2 * DEG
    mount_pitch: float = 0.0
    mount_roll: float = 0.0

    def describe(self) -> dict:
        return {
            "body_fixed": self.body,
            "pitch_gain_deg_per_mps2": self.pitch_gain / DEG,
            "mount_pitch_deg": self.mount_pitch / DEG,
            "mount_roll_deg": self.mount_roll / DEG,
        }


def body_accel(f_x: float, f_y: float, f_z: float, pitch: float, roll: float) -> tuple[float, float]:
    """(a_x, a_y) an accelerometer fixed to a body pitched by ``pitch`` (nose up) and rolled by
    ``roll`` (right side down) reads, from the specific force (f_x, f_y, f_z) in the road's axes.

    The body's x axis in the road's axes is (cos p, 0, sin p), its y axis
    (-sin p sin r, cos r, cos p sin r): pitch about y, then roll about the new x.
    """
    sp, cp, sr, cr = math.sin(pitch), math.cos(pitch), math.sin(roll), math.cos(roll)
    return f_x * cp + f_z * sp, -f_x * sp * sr + f_y * cr + f_z * cp * sr


# -- the load ----------------------------------------------------------------------------
OCCUPANT = 75.0  # kg per passenger
SEATS = 3  # on the rear bench; a load beyond them is luggage


@dataclass(frozen=True)
class Mass:
    """A point mass in the car: x behind the front axle, y left of the centre line, z above the
    ground [m]; ``own`` its own inertia about its CG (same about every axis) [kg m^2]."""

    kg: float
    x: float
    y: float
    z: float
    own: float = 0.0


def placement(kg: float, wheelbase: float, track: float) -> tuple[Mass, ...]:
    """Passengers and luggage as a user loads them: up to three passengers of 75 kg on the rear
    bench (85 % of the wheelbase behind the front axle, their CG 0.75 m up, 0.38 m either side
    of the centre, the third in the middle), the rest as luggage in the boot (0.45 m behind the
    rear axle, 0.65 m up).  The driver is in the profile's mass already.  It moves the CG back
    and up, as the issue's "passengers and luggage" do."""
    if not (math.isfinite(kg) and 0.0 <= kg <= 1000.0):
        raise ConfigError(f"load must be within 0-1000 kg, got {kg!r}")
    out: list[Mass] = []
    y = 0.25 * track
    spots = (y, -y, 0.0)
    left = kg
    for k in range(SEATS):
        if left <= 0.0:
            break
        m = min(OCCUPANT, left)
        # a seated body: about 0.17 m radius of gyration of its own
        out.append(Mass(m, 0.85 * wheelbase, spots[k], 0.75, own=m * 0.03))
        left -= m
    if left > 0.0:
        out.append(Mass(left, wheelbase + 0.45, 0.0, 0.65, own=left * 0.05))
    return tuple(out)


@dataclass(frozen=True)
class Loaded:
    """The car with its load: mass, CG and inertias about the new CG."""

    m: float
    l_f: float
    h: float
    I_z: float
    I_x: float
    I_y: float


def add_load(m: float, l_f: float, h: float, I_z: float, I_x: float, I_y: float, items: tuple[Mass, ...]) -> Loaded:
    """The loaded car by the parallel-axis theorem (the car's own inertias about its own CG)."""
    M = m + sum(i.kg for i in items)
    lf = (m * l_f + sum(i.kg * i.x for i in items)) / M
    hh = (m * h + sum(i.kg * i.z for i in items)) / M
    dx, dz = l_f - lf, h - hh
    iz = I_z + m * dx * dx + sum(i.own + i.kg * ((i.x - lf) ** 2 + i.y**2) for i in items)
    ix = I_x + m * dz * dz + sum(i.own + i.kg * ((i.z - hh) ** 2 + i.y**2) for i in items)
    iy = I_y + m * (dx * dx + dz * dz) + sum(i.own + i.kg * ((i.x - lf) ** 2 + (i.z - hh) ** 2) for i in items)
    return Loaded(M, lf, hh, iz, ix, iy)
