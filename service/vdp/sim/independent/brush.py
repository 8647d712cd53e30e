"""A four-wheel car written from first principles, with brush tyres.

Frame and signs (vdp's channels): x forward, y left, z up; yaw rate r positive to the
left; roll phi positive right side down (the body leans out of a left turn); pitch
theta positive nose up (the body squats when accelerating); steer delta positive left.
The reference point moves with the car at the whole car's CG in plan, on the roll axis;
the IMU sits there and reads road-plane accelerations (no gravity from body attitude).

Masses: a sprung body (m_s, CG a_s behind the front axle at height h_s) and two unsprung
axles (m_uf, m_ur, at wheel-centre height r).  The whole car's CG is
l_f = (m_s a_s + m_ur L) / m behind the front axle.

Equations (solved every evaluation; the two couplings are linear and solved exactly):

* body:   m a_x = sum F_x - F_drag + m_s e theta'',   m a_y = sum F_y + m_s d phi''
  (the sprung CG sits d above the roll axis and e above the pitch centre and swings
  with roll and pitch);  v_x' = a_x + r v_y,  v_y' = a_y - r v_x,  I_z r' = sum M_z.
* roll about the roll axis:   I_xr phi'' = m_s d (a_y + g phi) - k_phi phi - c_phi phi',
  with I_xr = I_xx,s + m_s d^2.
* pitch about the pitch centre:   I_yp theta'' = m_s e (a_x + g theta)
  + F_drag (h_aero - h_pc) - k_theta theta - c_theta theta',  I_yp = I_yy,s + m_s e^2.
* axle loads: static + longitudinal transfer (unsprung masses at height r, the sprung
  mass's force through the pitch centre, the pitch spring and damper moment, drag
  through the pitch centre) / L; per axle the lateral transfer (unsprung mass at r,
  the axle's share of the sprung mass's force through its roll centre, its share of
  the roll spring and damper moment) / track.  The loads depend on a_x and a_y and the
  forces on the loads: that loop is solved by one fixed-point pass per evaluation from
  the previous evaluation's accelerations (its gain is about mu h / L, < 0.1, and the
  accelerations change little in a quarter millisecond).
* tyres: the isotropic brush model with combined slip (Pacejka, Tyre and Vehicle
  Dynamics, ch. 3): theoretical slips sigma_x = kappa / (1 + kappa),
  sigma_y = tan(alpha) / (1 + kappa); with S = |(C_x sigma_x, C_y sigma_y)| and
  t = S / (3 mu F_z), the force magnitude is mu F_z (3t - 3t^2 + t^3) below t = 1 and
  mu F_z above, shared out along (C_x sigma_x, C_y sigma_y).  Stiffness grows with load,
  less than in proportion: C(F_z) = c F_z (1 - q (F_z - F_z0) / F_z0).
  kappa = (omega r - u) / |u| at the wheel's own speed u (floored at 1 m/s).
* wheels: J omega' = T - r F_x - f_r F_z r tanh(omega r / 0.5): rolling resistance as
  a moment at each wheel, so a free-rolling tyre carries a small braking slip.
* drag 0.5 rho C_d A v_x |v_x| at height h_aero.

Integration: classic Runge-Kutta 4 at 1 ms (the wheel modes' time constant is
J u / (r^2 C_x), 3 ms at 10 m/s: fine above about 3 m/s, which is why only the
scenarios that stay above 5 m/s are offered).  Pure Python floats.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field, replace

from ..road import Imu, Road, add_load, body_accel, placement
from .common import Model

log = logging.getLogger(__name__)

V_FLOOR = 1.0  # m/s, floor of the wheel speed in the slip ratio


@dataclass(frozen=True)
class BrushCar:
    """Every parameter of the brush-tyre car (SI)."""

    name: str
    m_s: float  # sprung mass
    m_uf: float  # front unsprung mass
    m_ur: float
    L: float  # wheelbase
    a_s: float  # sprung CG behind the front axle
    h_s: float  # sprung CG height
    t_f: float  # track
    t_r: float
    r: float  # rolling radius
    J_w: float  # one wheel's spin inertia
    h_rcf: float  # roll centre heights
    h_rcr: float
    k_phif: float  # roll stiffness per axle [N m/rad]
    k_phir: float
    c_phif: float  # roll damping per axle [N m s/rad]
    c_phir: float
    I_xs: float  # sprung mass about its own CG
    I_ys: float
    I_z: float  # whole car, yaw
    h_pc: float  # pitch centre height
    k_th: float  # pitch stiffness [N m/rad]
    c_th: float
    c_x: float  # longitudinal slip stiffness per unit load at F_z0 [-]
    c_yf: float  # cornering stiffness per unit load at F_z0 [1/rad]
    c_yr: float
    q_x: float  # load degression of the stiffnesses
    q_y: float
    mu: float = 1.0
    f_r: float = 0.012  # rolling resistance coefficient
    cda: float = 0.65  # drag area [m^2]
    rho: float = 1.2
    h_aero: float = 0.55
    steering_ratio: float = 15.0
    g: float = 9.81
    # Effects the other cars leave out (issue 24's wider zoo); each is off at its default.
    relax: float = 0.0  # tyre relaxation length [m]: the slip angle lags the kinematic one by relax / |u|
    trail: float = 0.0  # pneumatic trail [m]: the front tyres' aligning torque is trail x F_y
    k_steer: float = 0.0  # steering stiffness at the road wheels [N m/rad]: they yield to the aligning torque
    roll_steer_f: float = 0.0  # front road-wheel angle per roll angle (out of the turn: understeer)
    roll_steer_r: float = 0.0  # rear road-wheel angle per roll angle (into the turn: understeer)
    priors: dict = field(default_factory=dict)


CARS: dict[str, BrushCar] = {
    # A mid-size saloon: front-heavy, stiffer at the front in roll (understeer), 1600 kg.
    "saloon": BrushCar(
        name="saloon",
        m_s=1450.0,
        m_uf=80.0,
        m_ur=70.0,
        L=2.75,
        a_s=1.20,
        h_s=0.58,
        t_f=1.58,
        t_r=1.57,
        r=0.31,
        J_w=1.0,
        h_rcf=0.06,
        h_rcr=0.12,
        k_phif=60000.0,
        k_phir=40000.0,
        c_phif=4000.0,
        c_phir=3000.0,
        I_xs=450.0,
        I_ys=2200.0,
        I_z=2600.0,
        h_pc=0.30,
        k_th=150000.0,
        c_th=9000.0,
        c_x=16.0,
        c_yf=11.0,
        c_yr=14.5,
        q_x=0.10,
        q_y=0.20,
        priors={
            "l_f": (1.375, 0.3),
            "h": (0.55, 0.2),
            "C_K": (12.0, 6.0),
            "C_alpha": (90000.0, 45000.0),
            "I_z": (3000.0, 1500.0),
            "I_x": (700.0, 350.0),
        },
    ),
    # A small car as in issue 11: about 1,100 kg, wheelbase 2.58 m, roll stiffness 48,000 N m/rad.
    "small": BrushCar(
        name="small",
        m_s=980.0,
        m_uf=65.0,
        m_ur=55.0,
        L=2.58,
        a_s=1.00,
        h_s=0.56,
        t_f=1.46,
        t_r=1.44,
        r=0.29,
        J_w=0.8,
        h_rcf=0.05,
        h_rcr=0.10,
        k_phif=30000.0,
        k_phir=18000.0,
        c_phif=1800.0,
        c_phir=1200.0,
        I_xs=250.0,
        I_ys=1300.0,
        I_z=1650.0,
        h_pc=0.25,
        k_th=90000.0,
        c_th=5000.0,
        c_x=15.0,
        c_yf=12.0,
        c_yr=16.0,
        q_x=0.10,
        q_y=0.20,
        cda=0.62,
        h_aero=0.5,
        priors={
            "l_f": (1.29, 0.3),
            "h": (0.55, 0.2),
            "C_K": (12.0, 6.0),
            "C_alpha": (80000.0, 40000.0),
            "I_z": (2200.0, 1100.0),
            "I_x": (500.0, 350.0),
        },
    ),
    # A compact hatchback with what a real car adds to its tyres' kinematic slips: a relaxation
    # length of 0.45 m, aligning torque through a compliant steering (about 1 deg of road-wheel
    # angle per g at the front), and roll steer at both axles (K&C figures of compact cars).
    "compact": BrushCar(
        name="compact",
        m_s=1130.0,
        m_uf=70.0,
        m_ur=55.0,
        L=2.64,
        a_s=1.05,
        h_s=0.57,
        t_f=1.53,
        t_r=1.51,
        r=0.30,
        J_w=0.9,
        h_rcf=0.07,
        h_rcr=0.11,
        k_phif=38000.0,
        k_phir=24000.0,
        c_phif=2400.0,
        c_phir=1700.0,
        I_xs=320.0,
        I_ys=1600.0,
        I_z=1950.0,
        h_pc=0.28,
        k_th=110000.0,
        c_th=6500.0,
        c_x=14.0,
        c_yf=11.5,
        c_yr=15.0,
        q_x=0.12,
        q_y=0.18,
        mu=0.95,
        cda=0.64,
        h_aero=0.52,
        relax=0.45,
        trail=0.035,
        k_steer=18000.0,
        roll_steer_f=0.08,
        roll_steer_r=0.04,
        priors={
            "l_f": (1.3, 0.3),
            "h": (0.55, 0.2),
            "C_K": (12.0, 6.0),
            "C_alpha": (80000.0, 40000.0),
            "I_z": (2300.0, 1100.0),
            "I_x": (550.0, 350.0),
        },
    ),
}


def brush_force(kappa: float, alpha: float, F_z: float, C_x: float, C_y: float, mu: float) -> tuple[float, float]:
    """(F_x, F_y) of the isotropic brush tyre; alpha > 0 gives F_y > 0 (vdp's sign)."""
    if F_z <= 0.0:
        return 0.0, 0.0
    den = max(1.0 + kappa, 0.05)  # a locked wheel: the slips are unbounded, the force at the friction limit
    sx = C_x * kappa / den
    sy = C_y * math.tan(alpha) / den
    S = math.hypot(sx, sy)
    if S == 0.0:
        return 0.0, 0.0
    lim = mu * F_z
    t = S / (3.0 * lim)
    F = lim * (3.0 * t - 3.0 * t * t + t * t * t) if t < 1.0 else lim
    return F * sx / S, F * sy / S


class BrushModel(Model):
    """The first-principles car; state [v_x, v_y, r, phi, phi', theta, theta', omega_fl, _fr, _rl, _rr]."""

    def __init__(self, car: BrushCar):
        c = car
        m = c.m_s + c.m_uf + c.m_ur
        # per-axle K&C roll stiffness and damping are what a user knows of the car
        super().__init__(
            name="brush",
            car=c.name,
            mass=m,
            wheelbase=c.L,
            wheel_radius=c.r,
            wheel_inertia_axle=2.0 * c.J_w,
            roll_stiffness=c.k_phif + c.k_phir,
            roll_damping=c.c_phif + c.c_phir,
            steering_ratio=c.steering_ratio,
            track=0.5 * (c.t_f + c.t_r),
            g=c.g,
            priors=dict(c.priors),
        )
        self.c = c
        self.m = m
        self.lf = (c.m_s * c.a_s + c.m_ur * c.L) / m
        self.lr = c.L - self.lf
        self.zf0 = m * c.g * self.lr / c.L
        self.zr0 = m * c.g * self.lf / c.L
        self.Fz0f = self.zf0 / 2.0  # nominal wheel loads of the stiffness laws
        self.Fz0r = self.zr0 / 2.0
        h_ra = c.h_rcf + (c.h_rcr - c.h_rcf) * c.a_s / c.L  # roll axis under the sprung CG
        self.d = c.h_s - h_ra
        self.e = c.h_s - c.h_pc
        self.I_xr = c.I_xs + c.m_s * self.d**2
        self.I_yp = c.I_ys + c.m_s * self.e**2
        self.k_phi = c.k_phif + c.k_phir
        self.c_phi = c.c_phif + c.c_phir
        self._acc = [0.0, 0.0]  # last a_x, a_y: the start of the load loop's fixed-point pass
        self._fyf = 0.0  # last front lateral force: the aligning torque's, as _acc (the loop's gain is small)
        # issue 28 (sim.road): the road's gravity along x, y and the share normal to it (set_road);
        # flat by default, where x - 0.0 and x * 1.0 are x exactly
        self.gx = self.gy = 0.0
        self.gz = 1.0

    def kc(self) -> dict[str, float]:
        c = self.c
        out = {"compliance_steer": c.trail / c.k_steer} if c.k_steer > 0.0 and c.trail else {}
        if c.roll_steer_f or c.roll_steer_r:
            out.update(roll_steer_f=c.roll_steer_f, roll_steer_r=c.roll_steer_r)
        return out

    def set_road(self, theta: float, phi: float) -> None:
        """Grade theta (> 0 climbs) and bank phi (> 0 right side down) under the car now: gravity's
        part along the road pulls the body (v_x' = a_x + r v_y - g sin theta, v_y' = a_y - r v_x -
        g cos theta sin phi, a_x and a_y the specific force); the part normal to it carries the
        static loads.  Roll and pitch are relative to the road."""
        g = self.c.g
        self.gx = g * math.sin(theta)
        self.gy = g * math.cos(theta) * math.sin(phi)
        self.gz = math.cos(theta) * math.cos(phi)

    def accel(self, x: list[float], ax: float, ay: float) -> tuple[float, float]:
        """(a_x, a_y) the IMU reads from the specific force (ax, ay) at state x: aligned with the
        road, or (``imu.body``) fixed to the body, pitched by theta and rolled by phi plus the
        mounting offset (the IMU sits on the roll axis, so it sees no tangential part)."""
        imu = self.imu
        if imu is None or not imu.body:
            return ax, ay
        return body_accel(ax, ay, self.c.g * self.gz, x[5] + imu.mount_pitch, x[3] + imu.mount_roll)

    # -- tyre law, for the truth definitions ------------------------------------------
    def _cx(self, Fz: float, axle: str) -> float:
        z0 = self.Fz0f if axle == "front" else self.Fz0r
        return self.c.c_x * Fz * (1.0 - self.c.q_x * (Fz - z0) / z0)

    def _cy(self, Fz: float, axle: str) -> float:
        z0 = self.Fz0f if axle == "front" else self.Fz0r
        c = self.c.c_yf if axle == "front" else self.c.c_yr
        return c * Fz * (1.0 - self.c.q_y * (Fz - z0) / z0)

    def fx(self, kappa: float, F_z: float, axle: str) -> float:
        return brush_force(kappa, 0.0, F_z, self._cx(F_z, axle), self._cy(F_z, axle), self.c.mu)[0]

    def fy(self, alpha: float, F_z: float, axle: str) -> float:
        return brush_force(0.0, alpha, F_z, self._cx(F_z, axle), self._cy(F_z, axle), self.c.mu)[1]

    def static_truth(self) -> dict[str, float]:
        return {"l_f": self.lf, "I_z": self.c.I_z, "I_x": self.I_xr}

    def pitch_shift_height(self) -> float:
        """Quasi-static load-transfer height without drag: h_cg plus the pitch shift m_s g e theta / (m a_x)."""
        c = self.c
        h_cg = (c.m_s * c.h_s + (c.m_uf + c.m_ur) * c.r) / self.m
        return h_cg + c.m_s**2 * c.g * self.e**2 / (self.m * (c.k_th - c.m_s * c.g * self.e))

    def describe(self) -> dict:
        from dataclasses import asdict

        d = asdict(self.c)
        d.pop("priors")
        d.update({"m": self.m, "l_f": self.lf, "d_roll_axis": self.d, "e_pitch_centre": self.e})
        return d

    # -- physics ----------------------------------------------------------------------
    def initial(self, v0: float) -> list[float]:
        """Straight at v0 with the drag and rolling resistance already balanced (near enough)."""
        w = v0 / self.c.r
        self._acc = [0.0, 0.0]
        self._fyf = 0.0
        x = [float(v0), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, w, w, w, w]
        return x + [0.0] * 4 if self.c.relax > 0.0 else x  # each tyre's lagging slip angle

    def deriv(self, x: list[float], T_f: float, T_r: float, delta: float) -> tuple[list[float], tuple]:
        c = self.c
        vx, vy, r, phi, p, th, q, w1, w2, w3, w4 = x[:11]
        lag = x[11:]  # the tyres' lagging slip angles (relax > 0)
        d_lag = [0.0] * len(lag)
        # the front wheels yield to the aligning torque and steer with the roll; the rear steer with it
        delta_r = 0.0
        if c.k_steer > 0.0:
            delta = delta - c.trail * self._fyf / c.k_steer
        if c.roll_steer_f or c.roll_steer_r:
            delta = delta - c.roll_steer_f * phi
            delta_r = c.roll_steer_r * phi
        cr, sr = math.cos(delta_r), math.sin(delta_r)
        ax, ay = self._acc
        m, L, R = self.m, c.L, c.r
        Fd = 0.5 * c.rho * c.cda * vx * abs(vx)
        # loads (axle longitudinal transfer, then per axle lateral transfer to the right wheels)
        dz = ((c.m_uf + c.m_ur) * R * ax + c.m_s * c.h_pc * ax + c.k_th * th + c.c_th * q + Fd * c.h_pc) / L
        zf, zr = self.zf0 * self.gz - dz, self.zr0 * self.gz + dz
        yf = (c.m_uf * R * ay + c.m_s * (c.L - c.a_s) / L * c.h_rcf * ay + c.k_phif * phi + c.c_phif * p) / c.t_f
        yr = (c.m_ur * R * ay + c.m_s * c.a_s / L * c.h_rcr * ay + c.k_phir * phi + c.c_phir * p) / c.t_r
        loads = (0.5 * zf - yf, 0.5 * zf + yf, 0.5 * zr - yr, 0.5 * zr + yr)
        cd, sd = math.cos(delta), math.sin(delta)
        lf, lr = self.lf, self.lr
        pos = ((lf, 0.5 * c.t_f), (lf, -0.5 * c.t_f), (-lr, 0.5 * c.t_r), (-lr, -0.5 * c.t_r))
        ws = (w1, w2, w3, w4)
        torque = (0.5 * T_f, 0.5 * T_f, 0.5 * T_r, 0.5 * T_r)
        sfx = sfy = mz = fyf = 0.0
        dw = [0.0] * 4
        for i in range(4):
            px, py = pos[i]
            Fz = loads[i]
            Fz = max(Fz, 0.0)
            ux, uy = vx - r * py, vy + r * px
            front = i < 2
            if front:
                u, v = ux * cd + uy * sd, -ux * sd + uy * cd
            elif delta_r:
                u, v = ux * cr + uy * sr, -ux * sr + uy * cr
            else:
                u, v = ux, uy
            au = abs(u)
            den = au if au > V_FLOOR else V_FLOOR
            kappa = (ws[i] * R - u) / den
            alpha = -math.atan2(v, au if au > 1e-3 else 1e-3)
            if lag:  # the carcass deflects over the relaxation length: d alpha / dt = |u| / relax (alpha_ss - alpha)
                d_lag[i] = den / c.relax * (alpha - lag[i])
                alpha = lag[i]
            axle = "front" if front else "rear"
            fxw, fyw = brush_force(kappa, alpha, Fz, self._cx(Fz, axle), self._cy(Fz, axle), c.mu)
            if front:
                fx, fy = fxw * cd - fyw * sd, fxw * sd + fyw * cd
                fyf += fyw
            elif delta_r:
                fx, fy = fxw * cr - fyw * sr, fxw * sr + fyw * cr
            else:
                fx, fy = fxw, fyw
            sfx += fx
            sfy += fy
            mz += px * fy - py * fx
            rr = c.f_r * Fz * R * math.tanh(ws[i] * R / 0.5)
            dw[i] = (torque[i] - R * fxw - rr) / c.J_w
        # pitch and roll, each coupled linearly with its translation (solved exactly)
        ms, d, e, g = c.m_s, self.d, self.e, c.g
        qd = (ms * e * ((sfx - Fd) / m + g * th) + Fd * (c.h_aero - c.h_pc) - c.k_th * th - c.c_th * q) / (
            self.I_yp - ms * ms * e * e / m
        )
        pd = (ms * d * (sfy / m + g * phi) - self.k_phi * phi - self.c_phi * p) / (self.I_xr - ms * ms * d * d / m)
        ax = (sfx - Fd + ms * e * qd) / m
        ay = (sfy + ms * d * pd) / m
        self._acc = [ax, ay]
        self._fyf = fyf
        dx = [ax + r * vy - self.gx, ay - r * vx - self.gy, mz / c.I_z, p, pd, q, qd, *dw, *d_lag]
        return dx, (ax, ay, zf, zr)

    def step(
        self, x: list[float], T_f: float, T_r: float, delta: float, dt: float, delta_end: float | None = None
    ) -> tuple[list[float], tuple]:
        """One RK4 step; the steering goes linearly from ``delta`` to ``delta_end`` (held when
        None): a staircase held over each step lags the sampled angle by half a step."""
        d1 = delta if delta_end is None else delta_end
        dm = 0.5 * (delta + d1)
        k1, aux = self.deriv(x, T_f, T_r, delta)
        h = 0.5 * dt
        k2, _ = self.deriv([a + h * b for a, b in zip(x, k1)], T_f, T_r, dm)
        k3, _ = self.deriv([a + h * b for a, b in zip(x, k2)], T_f, T_r, dm)
        k4, _ = self.deriv([a + dt * b for a, b in zip(x, k3)], T_f, T_r, d1)
        s = dt / 6.0
        x1 = [a + s * (b1 + 2.0 * b2 + 2.0 * b3 + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
        ax, ay, zf, zr = aux
        vx, vy = x[0], x[1]
        ax_imu, ay_imu = self.accel(x, ax, ay)
        row = (
            x[7],
            x[8],
            x[9],
            x[10],
            T_f,
            T_r,
            delta,
            ax_imu,
            ay_imu,
            x[2],
            x[4],
            math.hypot(vx, vy),
            zf,
            zr,
            vx,
            ax,
        )
        return x1, row


def loaded(c: BrushCar, kg: float) -> BrushCar:
    """The car with ``kg`` of passengers and luggage (sim.road.placement) in its sprung mass: its
    CG moves back and up, its inertias grow by the parallel-axis theorem."""
    items = placement(kg, c.L, 0.5 * (c.t_f + c.t_r))
    if not items:
        return c
    m = c.m_s + c.m_uf + c.m_ur
    lf = (c.m_s * c.a_s + c.m_ur * c.L) / m
    h = (c.m_s * c.h_s + (c.m_uf + c.m_ur) * c.r) / m
    whole = add_load(m, lf, h, c.I_z, 0.0, 0.0, items)  # the whole car's yaw inertia about its new CG
    sprung = add_load(c.m_s, c.a_s, c.h_s, 0.0, c.I_xs, c.I_ys, items)  # the sprung mass about its own
    return replace(c, m_s=sprung.m, a_s=sprung.l_f, h_s=sprung.h, I_xs=sprung.I_x, I_ys=sprung.I_y, I_z=whole.I_z)


def model(car: str = "saloon", load: float = 0.0, road: Road | None = None, imu: Imu | None = None) -> BrushModel:
    """A brush car; ``load`` kg undeclared (the profile keeps the unloaded mass), ``road`` and ``imu``
    as sim.road has them."""
    from ...errors import ConfigError

    if car not in CARS:
        raise ConfigError(f"brush model: unknown car '{car}'; choose one of {', '.join(CARS)}")
    base = BrushModel(CARS[car])
    if not load and road is None and imu is None:
        return base
    out = BrushModel(loaded(CARS[car], load)) if load else base
    out.declared_mass = base.mass if load else None
    out.load_kg, out.road, out.imu = float(load), road, imu
    return out
