"""The CommonRoad multi-body model (``vehiclemodels.vehicle_dynamics_mb``) driven as a vdp car.

The library (package ``commonroad-vehicle-models``, BSD-3-Clause, TU Munich; vdp's
``bench`` extra) implements a 29-state multi-body car: a sprung mass with roll, pitch
and heave on springs, dampers and anti-roll torsion; front and rear unsprung masses
with their own roll, heave and lateral compliance; tyre vertical stiffness; and four
Pacejka Magic-Formula tyres with combined slip and camber.  Its parameter sets are real
cars (vehicle 1 Ford Escort, 2 BMW 320i, 3 VW Vanagon).

vdp calls the library's right-hand side unchanged and adds, outside it, only what the
library lacks or takes in another form:

* **wheel torques**: the library turns an acceleration demand into torques by its own
  split; vdp's driver gives axle torques instead, so the library's demand is held at 0
  and each wheel gets half its axle's torque (/ I_y_w) added to its spin equation;
* **steering**: the library's input is the steering rate; a fast servo (10 ms) follows
  the driver's road-wheel angle, and the library's own rate limit (0.4 rad/s) applies;
* **rolling resistance**: f_r F_z R_w at each wheel, against its spin;
* **aerodynamic drag**: 0.5 rho C_d A v_x |v_x| on v_x (acting at the sprung CG, so it
  adds no pitch moment about it).

Known constants for the profile: the elastic roll stiffness and damping are fitted to a
roll-moment step on the model (:func:`kc_roll`): the library spreads them over springs,
torsion terms, tyre compliance and the lateral compliant joints.

Sensors: a_x from the whole car's x-equation (sum of tyre forces minus drag over m), a_y
the sprung mass's lateral acceleration (the IMU sits on the body), yaw rate, the sprung
mass's roll rate (sign turned to vdp's: positive when the body leans out of a left
turn), the four wheel speeds (the library's L and R wheels sit at y = -T/2 and +T/2 of
its own equations, i.e. on vdp's right and left), the road-wheel angle (state 3) and the CG's ground speed.

Integration: classic Runge-Kutta 4 at 1 ms.  Before the drive the car runs 3 s straight
at the start speed so that the library's initial state (not at its static equilibrium)
settles.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
from dataclasses import dataclass

from ...errors import ConfigError
from .common import Model

log = logging.getLogger(__name__)

G = 9.81  # the library's own gravity constant
SERVO = 0.01  # s, steering servo time constant


@dataclass(frozen=True)
class Extra:
    """What vdp adds around the library's model (see the module docstring)."""

    f_r: float = 0.012
    cda: float = 0.65
    rho: float = 1.2
    steering_ratio: float = 15.0


# library vehicle id, extras, priors (realistic, imperfect)
CARS: dict[str, tuple[int, Extra, dict]] = {
    "bmw_320i": (
        2,
        Extra(cda=0.62),
        {
            "l_f": (1.29, 0.3),
            "h": (0.55, 0.2),
            "C_K": (15.0, 8.0),
            "C_alpha": (80000.0, 40000.0),
            "I_z": (2200.0, 1100.0),
            "I_x": (500.0, 250.0),
        },
    ),
    "vw_vanagon": (
        3,
        Extra(cda=0.95),
        {
            "l_f": (1.236, 0.3),
            "h": (0.7, 0.25),
            "C_K": (15.0, 8.0),
            "C_alpha": (100000.0, 50000.0),
            "I_z": (3000.0, 1500.0),
            "I_x": (1000.0, 500.0),
        },
    ),
    "ford_escort": (
        1,
        Extra(cda=0.65),
        {
            "l_f": (1.196, 0.3),
            "h": (0.55, 0.2),
            "C_K": (15.0, 8.0),
            "C_alpha": (85000.0, 42000.0),
            "I_z": (2000.0, 1000.0),
            "I_x": (550.0, 275.0),
        },
    ),
}


def _library():
    try:
        from vehiclemodels import vehicle_parameters
        from vehiclemodels.init_mb import init_mb
        from vehiclemodels.utils import tire_model
        from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb
    except ImportError:
        raise ConfigError(
            "the 'mb' model needs the CommonRoad vehicle models: pip install 'vdp[bench]' "
            "(or: pip install commonroad-vehicle-models)"
        ) from None
    return vehicle_parameters, init_mb, tire_model, vehicle_dynamics_mb


class MBModel(Model):
    """``vehicle_dynamics_mb`` with vdp's inputs; the state is the library's 29-vector."""

    def __init__(self, car: str):
        vid, extra, priors = CARS[car]
        vp, self._init, self._tire, self._f = _library()
        p = vp.setup_vehicle_parameters(vehicle_id=vid)
        self.p, self.x_extra = p, extra
        L = p.a + p.b
        m = p.m
        super().__init__(
            name="mb",
            car=car,
            mass=m,
            wheelbase=L,
            wheel_radius=p.R_w,
            wheel_inertia_axle=2.0 * p.I_y_w,
            roll_stiffness=0.0,  # measured below, on the model itself
            roll_damping=0.0,
            steering_ratio=extra.steering_ratio,
            track=0.5 * (p.T_f + p.T_r),
            g=G,
            priors=dict(priors),
        )
        # static axle loads as the library's own initial state sets them
        self.zf0 = p.m_s * G * p.b / L + p.m_uf * G
        self.zr0 = p.m_s * G * p.a / L + p.m_ur * G
        self.lf = L * self.zr0 / (self.zf0 + self.zr0)
        self.h_ra = p.h_raf + (p.h_rar - p.h_raf) * p.a / L  # roll axis under the sprung CG
        self.roll_stiffness, self.roll_damping, self.roll_inertia_kc = kc_roll(car)

    # -- truth ------------------------------------------------------------------------
    def fx(self, kappa: float, F_z: float, axle: str) -> float:
        t = self._tire
        s = -kappa  # the library's slip is 1 - R omega / u
        return t.formula_longitudinal_comb(s, 0.0, t.formula_longitudinal(s, 0.0, F_z, self.p.tire), self.p.tire)

    def fy(self, alpha: float, F_z: float, axle: str) -> float:
        t = self._tire
        a = -alpha  # the library's slip angle is atan(v_y / v_x) - delta
        f0, mu = t.formula_lateral(a, 0.0, F_z, self.p.tire)
        return t.formula_lateral_comb(0.0, a, 0.0, mu, F_z, f0, self.p.tire)

    def static_truth(self) -> dict[str, float]:
        # the IMU sits at the sprung CG (e = d), so eq 9 sees I_xx,s + m_s d (d - e) = I_xx,s
        return {"l_f": self.lf, "I_z": self.p.I_z, "I_x": self.p.I_Phi_s}

    def describe(self) -> dict:
        p = self.p
        keep = {k: getattr(p, k) for k in ("m", "m_s", "m_uf", "m_ur", "a", "b", "h_s", "h_cg", "h_raf", "h_rar")}
        keep.update({k: getattr(p, k) for k in ("I_Phi_s", "I_y_s", "I_z", "K_sf", "K_sr", "K_tsf", "K_tsr", "K_zt")})
        keep.update({"T_f": p.T_f, "T_r": p.T_r, "R_w": p.R_w, "I_y_w": p.I_y_w})
        keep["kc_roll"] = {
            "stiffness": self.roll_stiffness,
            "damping": self.roll_damping,
            "inertia_fitted": self.roll_inertia_kc,
            "how": "fitted to a 1000 N m roll-moment step on the sprung mass at 10 m/s (kc_roll)",
        }
        keep["vdp_extra"] = dataclasses.asdict(self.x_extra)
        keep["library"] = "commonroad-vehicle-models vehicle_dynamics_mb"
        return keep

    # -- physics ----------------------------------------------------------------------
    def initial(self, v0: float) -> list[float]:
        return list(self._init([0.0, 0.0, 0.0, float(v0), 0.0, 0.0, 0.0], self.p))

    def _loads(self, x) -> tuple[float, float]:
        p = self.p
        zf = (2.0 * x[16] + 2.0 * p.R_w * (math.cos(x[13]) - 1.0)) * p.K_zt
        zr = (2.0 * x[21] + 2.0 * p.R_w * (math.cos(x[18]) - 1.0)) * p.K_zt
        return zf, zr

    def deriv(self, x: list[float], T_f: float, T_r: float, delta: float) -> list[float]:
        p, e = self.p, self.x_extra
        f = self._f(list(x), [(delta - x[2]) / SERVO, 0.0], p)
        m = p.m
        Fd = 0.5 * e.rho * e.cda * x[3] * abs(x[3])
        f[3] -= Fd / m
        R = p.R_w
        for i, T in ((23, 0.5 * T_f), (24, 0.5 * T_f), (25, 0.5 * T_r), (26, 0.5 * T_r)):
            if x[i] <= 0.0 and f[i] == 0.0 and T <= 0.0:
                continue  # the library holds a wheel that would spin backwards
            side = 0.5 * (p.T_f if i < 25 else p.T_r) * (1.0 if i % 2 else -1.0)  # left +, right -
            j = 13 if i < 25 else 18
            k = 16 if i < 25 else 21
            Fz = (x[k] + R * (math.cos(x[j]) - 1.0) - side * math.sin(x[j])) * p.K_zt
            rr = e.f_r * max(Fz, 0.0) * R * math.tanh(x[i] * R / 0.5)
            f[i] += (T - rr) / p.I_y_w
        return f

    def step(
        self, x: list[float], T_f: float, T_r: float, delta: float, dt: float, delta_end: float | None = None
    ) -> tuple[list[float], tuple]:
        """One RK4 step; ``delta`` is the steering servo's command (its angle is the state x[2],
        continuous already), so ``delta_end`` is not needed and ignored."""
        k1 = self.deriv(x, T_f, T_r, delta)
        h = 0.5 * dt
        k2 = self.deriv([a + h * b for a, b in zip(x, k1)], T_f, T_r, delta)
        k3 = self.deriv([a + h * b for a, b in zip(x, k2)], T_f, T_r, delta)
        k4 = self.deriv([a + dt * b for a, b in zip(x, k3)], T_f, T_r, delta)
        s = dt / 6.0
        x1 = [a + s * (b1 + 2.0 * b2 + 2.0 * b3 + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
        for i in range(23, 27):
            x1[i] = max(x1[i], 0.0)
        vx, r, vy = x[3], x[5], x[10]
        ax = k1[3] - r * vy  # whole car: (sum of tyre forces - drag) / m
        ay = k1[10] + r * vx  # the sprung mass, where the IMU sits
        zf, zr = self._loads(x)
        # the library's 'left' wheels sit at y = -T/2 in its own equations (u_w_lf = v_x + T_f r / 2): in vdp's
        # frame (y left) they are the right-hand wheels, so fl <- its RF, fr <- its LF (and the same at the rear)
        row = (x[24], x[23], x[26], x[25], T_f, T_r, x[2], ax, ay, r, -x[7], math.hypot(vx, vy), zf, zr, vx, ax)
        return x1, row


@functools.cache
def kc_roll(car: str) -> tuple[float, float, float]:
    """The car's elastic roll stiffness and damping as a K&C rig would give them, measured on the model.

    The library spreads roll stiffness over springs, torsion terms, tyre compliance and
    the lateral compliant joints, so no one of its parameters is the car's roll
    stiffness.  A roll-moment step M on the sprung mass (driving straight at 10 m/s)
    is fitted by least squares to M = I phi'' + c phi' + k' phi; the elastic stiffness
    adds back gravity's share, k = k' + m_s g (h_s - h_roll_axis).  Returns (k, c, I).
    """
    import numpy as np

    m = MBModel.__new__(MBModel)  # the physics without the measured constants (no recursion)
    vid, extra, _ = CARS[car]
    vp, m._init, m._tire, m._f = _library()
    m.p, m.x_extra = vp.setup_vehicle_parameters(vehicle_id=vid), extra
    p = m.p
    moment = [0.0]
    base = m.deriv

    def deriv(x, T_f, T_r, delta):
        f = base(x, T_f, T_r, delta)
        f[7] += moment[0] / p.I_Phi_s
        return f

    m.deriv = deriv
    x, dt = m.initial(10.0), 0.001
    T = 30.0  # N m per axle: about what holds 10 m/s against drag and rolling resistance
    for _ in range(2000):
        x = m.step(x, T, T, 0.0, dt)[0]
    rows = []
    for i in range(3000):
        moment[0] = 1000.0 if i >= 200 else 0.0
        rows.append((x[6], x[7], moment[0]))
        x = m.step(x, T, T, 0.0, dt)[0]
    a = np.array(rows)
    phi, rate = a[:, 0] - a[0, 0], a[:, 1]
    A = np.column_stack([np.gradient(rate, dt), rate, phi])
    (inertia, c, k_el), *_ = np.linalg.lstsq(A, a[:, 2], rcond=None)
    h_ra = p.h_raf + (p.h_rar - p.h_raf) * p.a / (p.a + p.b)
    return float(k_el + p.m_s * G * (p.h_s - h_ra)), float(c), float(inertia)


def model(car: str = "bmw_320i") -> MBModel:
    if car not in CARS:
        raise ConfigError(f"mb model: unknown car '{car}'; choose one of {', '.join(CARS)}")
    return MBModel(car)
