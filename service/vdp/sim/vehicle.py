"""Truth physics: single-track vehicle with roll and two lumped wheels (Li et al. 2021).

Conventions (stated once, NOTES items 1-3, 9):

* x forward, y left, yaw rate positive counter-clockwise, road-wheel angle
  delta positive left; roll angle phi (eq 9 calls it roll rate, NOTES 4).
* Slip angles (eq 12 replaced, NOTES 3): ``alpha_f = delta - (v_y + l_f r)/v_x``,
  ``alpha_r = -(v_y - l_r r)/v_x``, ``F_y = C_alpha * alpha`` (per axle; the axles'
  stiffness may differ: ``C_alpha_front``, ``C_alpha_rear``, by default both C_alpha).
* Slip ratio (eq 13) uses the wheel-frame speed of each axle:
  ``s = (omega r - v_w) / max(|v_w|, 1)``, ``v_wf = v_x cos d + (v_y + l_f r) sin d``,
  ``v_wr = v_x``.  Longitudinal force (eq 14) ``F_x = C_K F_z s``.
* Both tyre forces are clipped to ``mu * F_z`` (friction limit, extremes only).
* Axle loads (eq 3) use the body acceleration a_x of eq 6; the loop
  F_x -> a_x -> F_z -> F_x is linear in a_x and solved exactly at every evaluation.
* eq 5 corrected: ``dv_y/dt = a_y - v_x r`` (NOTES 1); eq 6 with ``-F_yf sin d``;
  eq 10 corrected: yaw moment ``l_f (F_xf sin d + F_yf cos d) - l_r F_yr`` (NOTES 2).
* J is per axle: each axle is one lumped wheel (NOTES 9).  No drag, no rolling
  resistance (the paper neglects both).

The wheel modes are stiff (tau = J v / (r^2 C_K F_z), about 1 ms at 10 m/s,
NOTES 10).  :meth:`Model.step` therefore takes omega by a linearly implicit
backward-Euler step (F_x is linear in omega for a given wheel speed and F_z, so
omega_{n+1} has a closed form), solved against the *predicted* wheel-frame speed at
t_{n+1}; the body states take a Heun step whose first stage uses (x_n, omega_n) and
whose second uses (x_pred, omega_{n+1}).  Holding omega at omega_{n+1} in both stages
instead makes the body feel a force that lags v by one step: a bias of about
C_K F_z dt / (m max(v, 1)), 1-2 % of F_x at low speed; this form is 5-20x more
accurate at 1 ms and needs two force evaluations per step, not three.
Pure Python floats: at this size they beat numpy.

State vector (list of floats): see :data:`STATE`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

from ..errors import ConfigError

log = logging.getLogger(__name__)

STATE = ("v_x", "v_y", "yaw_rate", "roll", "roll_rate", "omega_f", "omega_r")
VX, VY, WZ, PHI, P, WF, WR = range(len(STATE))

V_FLOOR = 1.0  # m/s, floor of the speed in the slip denominators (eqs 12, 13; NOTES 11)
V_HOLD = 0.1  # m/s, below this a braking car is held at standstill


@dataclass(frozen=True)
class Params:
    """Everything the physics needs, SI units (k_phi, c_phi per radian)."""

    m: float
    g: float
    L: float
    r: float
    J: float  # per axle
    k_phi: float
    c_phi: float
    l_f: float
    h: float
    C_K: float
    C_alpha: float  # per axle
    I_z: float
    I_x: float
    mu: float = 1.0  # friction limit of both tyre forces
    # per-axle cornering stiffness when the axles differ (None: C_alpha on that axle)
    C_alpha_front: float | None = None
    C_alpha_rear: float | None = None

    @property
    def l_r(self) -> float:
        return self.L - self.l_f

    @classmethod
    def from_vehicle(cls, vehicle: Any, unknowns: Mapping[str, float]) -> Params:
        """Known constants from a :class:`vdp.profile.Vehicle`, unknowns from a dict."""
        return cls(
            m=vehicle.mass,
            g=vehicle.g,
            L=vehicle.wheelbase,
            r=vehicle.wheel_radius,
            J=vehicle.wheel_inertia,
            k_phi=vehicle.roll_stiffness,
            c_phi=vehicle.roll_damping,
            l_f=unknowns["l_f"],
            h=unknowns["h"],
            C_K=unknowns["C_K"],
            C_alpha=unknowns["C_alpha"],
            I_z=unknowns["I_z"],
            I_x=unknowns["I_x"],
            C_alpha_front=unknowns.get("C_alpha_front"),
            C_alpha_rear=unknowns.get("C_alpha_rear"),
        )


class Forces(NamedTuple):
    """Tyre forces and body accelerations at one state (what the IMU measures)."""

    a_x: float
    a_y: float
    F_zf: float
    F_zr: float
    F_xf: float
    F_xr: float
    F_yf: float
    F_yr: float
    s_f: float
    s_r: float
    alpha_f: float
    alpha_r: float


class Model:
    """The truth vehicle.  Methods take and return the state as a list of 7 floats."""

    def __init__(self, params: Params):
        p = params
        if not 0.0 < p.l_f < p.L:
            raise ConfigError(
                f"l_f={p.l_f:g} m must lie inside the wheelbase L={p.L:g} m (the profile's [vehicle] "
                f"wheelbase): give --param l_f between 0 and {p.L:g}"
            )
        self.params = p
        self.m, self.g, self.r, self.J = p.m, p.g, p.r, p.J
        self.lf, self.lr = p.l_f, p.l_r
        self.CK, self.mu = p.C_K, p.mu
        self.Caf = p.C_alpha if p.C_alpha_front is None else p.C_alpha_front
        self.Car = p.C_alpha if p.C_alpha_rear is None else p.C_alpha_rear
        self.Iz, self.Ix = p.I_z, p.I_x
        self.kphi, self.cphi = p.k_phi, p.c_phi
        self.mh = p.m * p.h
        # eq 3: F_zf = zf0 - k a_x, F_zr = zr0 + k a_x
        self.zf0 = p.m * p.g * p.l_r / p.L
        self.zr0 = p.m * p.g * p.l_f / p.L
        self.k = p.m * p.h / p.L
        self._held = (0.0, 0.0, self.zf0, self.zr0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        # the road's gravity along x and y (sim.road: 0 on a flat road, where x - 0.0 is x exactly)
        self.gx = self.gy = 0.0

    def set_road(self, theta: float, phi: float) -> None:
        """Grade theta (> 0 climbs) and bank phi (> 0 right side down) under the car now (sim.road).

        Gravity's part along the road takes from eqs 4-5 (dv_x/dt = a_x + v_y r - g sin theta,
        dv_y/dt = a_y - v_x r - g cos theta sin phi, a_x and a_y the contact forces over m: what a
        road-aligned accelerometer reads); the part normal to it, g cos theta cos phi, sets the
        static axle loads of eq 3.  Eq 9's roll is relative to the road, driven by that a_y.
        """
        p = self.params
        ct, cp = math.cos(theta), math.cos(phi)
        self.gx = p.g * math.sin(theta)
        self.gy = p.g * ct * math.sin(phi)
        self.zf0 = p.m * p.g * ct * cp * p.l_r / p.L
        self.zr0 = p.m * p.g * ct * cp * p.l_f / p.L
        # held by its brakes, the car reads the specific force that holds it
        self._held = (self.gx, self.gy, self.zf0, self.zr0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    # -- public API -----------------------------------------------------------------
    def straight(self, v: float) -> list[float]:
        """Steady straight-line state at speed v: no drag, so F_x = 0 and omega = v / r."""
        return [float(v), 0.0, 0.0, 0.0, 0.0, v / self.r, v / self.r]

    @staticmethod
    def held(x: Sequence[float], T_f: float, T_r: float) -> bool:
        """Standstill with the brakes on: the car is held (never rolls back or chatters)."""
        return x[VX] < V_HOLD and T_f + T_r < 0.0

    def evaluate(self, x: Sequence[float], T_f: float, T_r: float, delta: float) -> Forces:
        if self.held(x, T_f, T_r):
            return Forces(*self._held)
        return Forces(*self._eval(x[VX], x[VY], x[WZ], x[WF], x[WR], delta, math.cos(delta), math.sin(delta)))

    def derivatives(self, x: Sequence[float], T_f: float, T_r: float, delta: float) -> list[float]:
        """Full right-hand side including the stiff wheel equations (eq 2)."""
        if self.held(x, T_f, T_r):
            return [0.0, 0.0, 0.0, x[P], self._roll_acc(self.gy, x[PHI], x[P]), 0.0, 0.0]
        cd, sd = math.cos(delta), math.sin(delta)
        e = self._eval(x[VX], x[VY], x[WZ], x[WF], x[WR], delta, cd, sd)
        d = list(self._body(x[VX], x[VY], x[WZ], x[PHI], x[P], e, cd, sd))
        return d + [(T_f - self.r * e[4]) / self.J, (T_r - self.r * e[5]) / self.J]

    def step(
        self, x: Sequence[float], T_f: float, T_r: float, delta: float, dt: float, delta_end: float | None = None
    ) -> list[float]:
        return self.advance(x, T_f, T_r, delta, dt, delta_end)[0]

    def advance(
        self, x: Sequence[float], T_f: float, T_r: float, delta: float, dt: float, delta_end: float | None = None
    ) -> tuple[list[float], tuple]:
        """One step of length dt; returns (new state, raw Forces tuple at x).

        The torques are held over the step.  The road-wheel angle goes linearly from ``delta``
        to ``delta_end`` (held when None): a real steering angle is continuous, and a staircase
        held over each 1-ms step lags the sampled angle by half a step, which an estimator that
        interpolates the samples reads as the tyres responding 0.5 ms early (on a light car on
        stiff tyres, +0.6 % C_alpha, +1.7 % I_z from this alone)."""
        vx, vy, wz, phi, p, wf, wr = x
        if vx < V_HOLD and T_f + T_r < 0.0:
            # Standstill: the brakes hold the car; only the roll mode relaxes (a_y = 0, or the bank's).
            q1 = self._roll_acc(self.gy, phi, p)
            phi_t, p_t = phi + dt * p, p + dt * q1
            q2 = self._roll_acc(self.gy, phi_t, p_t)
            return [0.0, 0.0, 0.0, phi + 0.5 * dt * (p + p_t), p + 0.5 * dt * (q1 + q2), 0.0, 0.0], self._held
        cd, sd = math.cos(delta), math.sin(delta)
        e = self._eval(vx, vy, wz, wf, wr, delta, cd, sd)
        # Body (eqs 4, 5, 8-10), Heun stage 1 at (x_n, omega_n).
        k1 = self._body(vx, vy, wz, phi, p, e, cd, sd)
        vx_t, vy_t, wz_t = vx + dt * k1[0], vy + dt * k1[1], wz + dt * k1[2]
        phi_t, p_t = phi + dt * k1[3], p + dt * k1[4]
        if delta_end is not None and delta_end != delta:  # Heun's second stage at the step's end
            delta = delta_end
            cd, sd = math.cos(delta), math.sin(delta)
        # Wheels (eq 2): backward Euler against the predicted wheel-frame speed, F_z frozen.
        wf1 = self._wheel(wf, T_f, e[2], vx_t * cd + (vy_t + self.lf * wz_t) * sd, dt)
        wr1 = self._wheel(wr, T_r, e[3], vx_t, dt)
        # Heun stage 2 at (x_pred, omega_n+1): the body feels the same F_x the wheel did.
        k2 = self._body(vx_t, vy_t, wz_t, phi_t, p_t, self._eval(vx_t, vy_t, wz_t, wf1, wr1, delta, cd, sd), cd, sd)
        h = 0.5 * dt
        vx1 = vx + h * (k1[0] + k2[0])
        return [
            vx1 if vx1 > 0.0 else 0.0,
            vy + h * (k1[1] + k2[1]),
            wz + h * (k1[2] + k2[2]),
            phi + h * (k1[3] + k2[3]),
            p + h * (k1[4] + k2[4]),
            wf1,
            wr1,
        ], e

    # -- hot path -------------------------------------------------------------------
    def _eval(self, vx: float, vy: float, wz: float, wf: float, wr: float, delta: float, cd: float, sd: float) -> tuple:
        CK, mu, m, k = self.CK, self.mu, self.m, self.k
        u = vx if vx > V_FLOOR else V_FLOOR
        vyf = vy + self.lf * wz
        af = delta - vyf / u  # eq 12a (NOTES 3 convention)
        ar = (self.lr * wz - vy) / u  # eq 12b
        vwf = vx * cd + vyf * sd  # front wheel-frame speed (eq 13)
        df = vwf if vwf > V_FLOOR else (-vwf if vwf < -V_FLOOR else V_FLOOR)
        dr = vx if vx > V_FLOOR else (-vx if vx < -V_FLOOR else V_FLOOR)
        sf = (wf * self.r - vwf) / df
        sr = (wr * self.r - vx) / dr
        # eq 14 as a friction coefficient F_x / F_z, clipped at mu.
        mf = CK * sf
        mf = mu if mf > mu else (-mu if mf < -mu else mf)
        mr = CK * sr
        mr = mu if mr > mu else (-mu if mr < -mu else mr)
        fyf = self.Caf * af  # eq 11b, per axle
        fyr = self.Car * ar
        # eqs 3 + 6: m a_x = mf cos d F_zf(a_x) - F_yf sin d + mr F_zr(a_x), linear in a_x.
        zf0, zr0 = self.zf0, self.zr0
        c = mf * cd
        ax = (c * zf0 - fyf * sd + mr * zr0) / (m + k * (c - mr))
        fzf = zf0 - k * ax
        lim = mu * fzf
        if fyf > lim or fyf < -lim:
            # Front lateral force at the friction limit: F_yf = +-mu F_zf(a_x), still linear.
            c -= (mu if fyf > 0.0 else -mu) * sd
            ax = (c * zf0 + mr * zr0) / (m + k * (c - mr))
            fzf = zf0 - k * ax
            fyf = (mu if fyf > 0.0 else -mu) * fzf
        fzr = zr0 + k * ax
        lim = mu * fzr
        fyr = lim if fyr > lim else (-lim if fyr < -lim else fyr)
        fxf = mf * fzf
        fxr = mr * fzr
        ay = (fxf * sd + fyf * cd + fyr) / m  # eq 7
        return ax, ay, fzf, fzr, fxf, fxr, fyf, fyr, sf, sr, af, ar

    def _body(self, vx: float, vy: float, wz: float, phi: float, p: float, e: tuple, cd: float, sd: float) -> tuple:
        ax, ay, _, _, fxf, _, fyf, fyr = e[:8]
        return (
            ax + vy * wz - self.gx,  # eq 4 (minus the road's grade, set_road)
            ay - vx * wz - self.gy,  # eq 5 corrected (NOTES 1; minus the road's bank)
            (self.lf * (fxf * sd + fyf * cd) - self.lr * fyr) / self.Iz,  # eqs 8, 10 (NOTES 2)
            p,
            (self.mh * (ay + self.g * phi) - self.kphi * phi - self.cphi * p) / self.Ix,
        )  # eq 9

    def _roll_acc(self, ay: float, phi: float, p: float) -> float:
        return (self.mh * (ay + self.g * phi) - self.kphi * phi - self.cphi * p) / self.Ix

    def _wheel(self, w: float, T: float, Fz: float, vw: float, dt: float) -> float:
        """Backward-Euler omega update of J dw/dt = T - r F_x (eq 2), F_x piecewise linear in w."""
        d = vw if vw > V_FLOOR else (-vw if vw < -V_FLOOR else V_FLOOR)
        c = self.CK * Fz / d if Fz > 0.0 else 0.0  # dF_x / d(omega r)
        g = dt / self.J
        r = self.r
        w1 = (w + g * (T + r * c * vw)) / (1.0 + g * r * r * c)
        # F_x(w) is monotone, so the root lies on the saturated piece if the linear one overshoots.
        mx = self.CK * (w1 * r - vw) / d
        if mx > self.mu:
            w1 = w + g * (T - r * self.mu * Fz)
        elif mx < -self.mu:
            w1 = w + g * (T + r * self.mu * Fz)
        return w1 if w1 > 0.0 else 0.0  # brakes lock a wheel, they never spin it backwards
