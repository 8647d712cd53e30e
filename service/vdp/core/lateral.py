"""Stage 2: the single-track model with roll, eqs (4)-(12), as a joint state-parameter model.

Filter state (SI units)::

    x = [v_y, yaw_rate, phi, phi_dot, C_alpha_f, C_alpha_r, I_z, I_x, l_f(, g_sin_bank)]

v_y and the roll angle phi have no sensor on a production car, so they are
filter states estimated jointly with the parameters (NOTES item 13; the
paper's "future work").  Inputs ``u`` (columns below) and measurements
``z = [yaw_rate, roll_rate, a_y]``.

C_alpha_f and C_alpha_r are the front and the rear axle's cornering stiffness
(eq 11b per axle): a real car's differ, and their ratio sets its understeer,
which one C_alpha for both cannot fit.  Their mean is the paper's single C_alpha.

With the road modelled (``vdp replay --road``: LearnerConfig.bank) a tenth state, ``BANK``, is
the road's bank as gravity's pull down it, g sin(bank) [m/s^2], a random walk: on a banked road
the accelerometer (road axes) reads the tyres' force, which holds the car against that pull,
while v_y does not turn with it, so eq (5) is v_y_dot = a_y - v_x r - g sin(bank)
(docs/decisions/0025).  Every function here takes a state of nine or of ten (sized by the
state it is given); with nine the numbers are those of the model without the bank, to the bit.

l_f is stage 1's estimate, carried as a *consider* state (Schmidt): the filter
never updates it, but its stage-1 uncertainty flows into C_alpha and I_z
through the covariance.  Stage 2 is sensitive to it: 1 % of l_f moves
C_alpha by 3.4 % and I_z by 4.5 % on the paper's drive (more in the city
drive), while h and C_K hardly matter, so they stay constants in ``Known``
(benchmarks/sensitivity.py).

Errata applied (NOTES.md):
- eq (5): v_y_dot = a_y - v_x * yaw_rate (the paper has +);
- eq (6)/(7): front forces rotate by delta: body-x gets F_xf cos(d) - F_yf sin(d),
  body-y gets F_xf sin(d) + F_yf cos(d);
- eq (10): yaw moment l_f (F_xf sin(d) + F_yf cos(d)) - l_r F_yr (paper swaps sin/cos);
- eq (12): alpha_f = d - (v_y + l_f r)/v_x, alpha_r = -(v_y - l_r r)/v_x, F_y = C_alpha alpha
  (per axle: F_yf = C_alpha_f alpha_f, F_yr = C_alpha_r alpha_r);
- eq (9): phi is the roll angle; total mass and CG height as in the paper (strictly
  sprung mass and height above the roll axis), driven by the *measured* a_y (input U_AY)
  where there is one (Known.roll_by_ay): the accelerometer measures a_y directly, so the
  roll-rate row need not re-estimate it through C_alpha and I_z.  Driven by the model's
  a_y, the roll row pulled C_alpha 20-50 % either way on cars whose roll eq (9) describes
  only roughly (a sprung mass rolling about a roll axis; docs/decisions/0008, "Stage 2 on the
  independent models");
- Table 6: k_phi, c_phi per radian.
- NOTES 8: the front longitudinal force is C_sigma s_f with C_sigma = F_zf C_K from
  stage 1 and the current load; the slip uses the wheel-frame speed.

The roll mode is stiff for small I_x (poles near -c/I_x), so it is integrated
with the trapezoidal rule, which is A-stable; yaw and lateral states use
midpoint (RK2) sub-steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

V_Y, YAW, PHI, PHI_D, C_F, C_R, I_Z, I_X, L_F = range(9)
N_X = 9
STATE_NAMES = ("v_y", "yaw_rate", "phi", "phi_dot", "C_alpha_f", "C_alpha_r", "I_z", "I_x", "l_f")
STATE_UNITS = ("m/s", "rad/s", "rad", "rad/s", "N/rad", "N/rad", "kg*m^2", "kg*m^2", "m")
PARAM_SLICE = slice(4, 8)
CONSIDER = L_F  # a state the filters never update (its prior uncertainty is considered)
SCALE = np.array([0.5, 0.2, 0.005, 0.02, 5.0e4, 5.0e4, 2.0e3, 3.0e3, 0.01])
# the road's bank, g sin(bank) [m/s^2]: the tenth state, only with the road modelled (module docstring)
BANK = 9
BANK_SCALE = 0.3  # m/s^2: the filters' scale of it (SCALE)

# input columns; U_AY, the measured a_y, drives eq (9) (Known.roll_by_ay; a row may stop at U_AX)
U_DELTA, U_VX, U_WF, U_AX, U_AY = range(5)
N_U = 5

# measurement rows
Z_YAW, Z_ROLL, Z_AY = range(3)
N_Z = 3

V_MIN = 1.0  # m/s, guards the slip-angle denominators
MAX_SUBSTEP = 0.01  # s: midpoint steps this short keep the yaw/lateral error well below the noise
ROLL_SPLIT = 4  # roll steps per sub-step: its fast pole (~70 1/s) wants ~2.5 ms (a power of 2)
_ROLL_SQUARINGS = ROLL_SPLIT.bit_length() - 1  # S^ROLL_SPLIT by squaring (a constant: core.kernels compiles _roll_map)
PARAM_FLOOR = np.array([1.0e3, 1.0e3, 50.0, 50.0])  # keeps a wild sigma point physical
_FLOOR = tuple(PARAM_FLOOR.tolist())


@dataclass(frozen=True)
class Known:
    """Known constants of stage 2, including stage 1's results (SI).

    ``l_f`` is stage 1's value, used outside the filter state (the rear load in
    the learner's v_x); the model itself takes l_f from the state (``L_F``).
    """

    m: float
    L: float
    r: float
    k_phi: float
    c_phi: float
    l_f: float
    h: float
    C_K: float
    g: float = 9.8
    # False: one cornering stiffness for both axles, C_alpha_f's (C_alpha_r is then inert)
    per_axle: bool = True
    # True: eq (9) is driven by the measured a_y (input U_AY, where finite), so the roll-rate
    # row informs the roll states and I_x only, not C_alpha and I_z through the model's a_y
    roll_by_ay: bool = False

    @property
    def ck_slope(self) -> float:
        """C_K F_zf = base - ck_slope l_f, as F_zf = m (g (L - l_f) - a_x h) / L (eq 3a)."""
        return self.C_K * self.m * self.g / self.L


def _pre(d: float, v_x: float, w_f: float, a_x: float, k: Known):
    """``_inputs`` of one row in plain floats (core.kernels compiles this as it is).

    The fifth is C_K F_zf at l_f = 0 (eq 3a); ``_geometry`` takes the l_f part off.
    """
    fz0 = k.C_K * k.m / k.L * (k.g * k.L - a_x * k.h)
    return d, max(v_x, V_MIN), math.sin(d), math.cos(d), fz0, w_f * k.r


def _inputs(u, k: Known):
    """Per-step constants from the inputs (they do not depend on the state); floats for one row."""
    if np.ndim(u) == 1:
        d, v_x, w_f, a_x = np.asarray(u, dtype=float).tolist()[:4]
        return _pre(d, v_x, w_f, a_x, k)
    base = k.C_K * k.m / k.L
    d = u[..., U_DELTA]
    v_x = np.maximum(u[..., U_VX], V_MIN)
    # NOTES 8: C_sigma = C_K F_zf; the slip uses the front wheel-frame speed (eq 13)
    return d, v_x, np.sin(d), np.cos(d), base * (k.g * k.L - u[..., U_AX] * k.h), u[..., U_WF] * k.r


def _geometry(l_f, k: Known):
    """(l_f, l_r, the l_f part of C_K F_zf) of a state or of each sigma point."""
    return l_f, k.L - l_f, k.ck_slope * l_f


def _rates(v_y, yaw, c_f, c_r, i_z, pre, geo, k: Known, clamp=np.maximum):
    """(v_y_dot, yaw_acc, a_y, Y_f, F_yr) for given lateral states; eqs (5), (7), (10)-(12).

    ``clamp`` is np.maximum for arrays of sigma points, the builtin max for one state
    in plain floats (the EKF's), where numpy's per-call cost would dominate.
    """
    d, v_x, sd, cd, ck_fz0, w_r = pre
    l_f, l_r, ck_cut = geo
    p = v_y + l_f * yaw
    v_w = clamp(v_x * cd + p * sd, V_MIN)
    # Y_f = F_xf sin(d) + F_yf cos(d) with F_xf = C_sigma (w_r / v_w - 1) (NOTES 8) and
    # F_yf = C_alpha_f (d - p / v_x) (eq 12a, corrected), constants folded (fewer array operations)
    xs = (ck_fz0 - ck_cut) * sd
    y_f = (xs * w_r) / v_w - xs + c_f * (d * cd - p * (cd / v_x))
    f_yr = c_r * (l_r * yaw - v_y) / v_x  # eq (12b), corrected
    a_y = (y_f + f_yr) / k.m  # eq (7)
    return a_y - v_x * yaw, (l_f * y_f - l_r * f_yr) / i_z, a_y, y_f, f_yr  # eqs (5), (8), (10)


def _bank(x):
    """The bank state g sin(bank) of a state or of each sigma point; 0.0 for a state of nine."""
    return x[..., BANK] if np.shape(x)[-1] > BANK else 0.0


def _unpack(x, tied: bool = False):
    """(v_y, yaw, phi, phi_dot, C_alpha_f, C_alpha_r, I_z, I_x, l_f, clamp), the parameters floored
    (the bank, a tenth state, is read apart: :func:`_bank`).

    Plain floats and the builtin max for one state (the EKF's: numpy's per-call cost
    would dominate), arrays and np.maximum for many (the UKF's sigma points).
    ``tied``: both axles take C_alpha_f (Known.per_axle off).
    """
    r = C_F if tied else C_R
    if np.ndim(x) == 1:
        v_y, yaw, phi, phi_d, c_f, c_r, i_z, i_x, l_f = np.asarray(x, dtype=float).tolist()[:9]
        c_r = c_f if tied else c_r
        fl = _FLOOR
        return v_y, yaw, phi, phi_d, max(c_f, fl[0]), max(c_r, fl[1]), max(i_z, fl[2]), max(i_x, fl[3]), l_f, max
    return (
        x[..., V_Y],
        x[..., YAW],
        x[..., PHI],
        x[..., PHI_D],
        np.maximum(x[..., C_F], _FLOOR[0]),
        np.maximum(x[..., r], _FLOOR[1]),
        np.maximum(x[..., I_Z], _FLOOR[2]),
        np.maximum(x[..., I_X], _FLOOR[3]),
        x[..., L_F],
        np.maximum,
    )


def quasi_static_roll(a_y: float, phi_dot: float, k: Known) -> float:
    """Roll angle at which eq (9) has no roll acceleration for this a_y and roll rate.

    m h (a_y + g phi) - k_phi phi - c_phi phi_dot = 0 (known constants and stage 1's h
    only).  A stage-2 window can open in a steady corner, where phi is far from 0 on
    a car of ordinary roll stiffness (about 2 deg at 3 m/s^2): starting the filter at
    this value keeps its first steps from bending C_alpha to explain a roll it has
    put in itself.  0 when k_phi does not exceed m g h (no static roll balance).
    """
    stiff = k.k_phi - k.m * k.g * k.h
    if not stiff > 0.0:
        return 0.0
    return (k.m * k.h * a_y - k.c_phi * phi_dot) / stiff


def forces(x, u, k: Known):
    """Lateral force terms: (front body-y force Y_f, rear F_yr, a_y)."""
    v_y, yaw, _, _, c_f, c_r, i_z, _, l_f, clamp = _unpack(x, not k.per_axle)
    _, _, a_y, y_f, f_yr = _rates(v_y, yaw, c_f, c_r, i_z, _inputs(u, k), _geometry(l_f, k), k, clamp)
    return y_f, f_yr, a_y


def _measured_ay(u, k: Known):
    """The measured a_y that drives eq (9) (Known.roll_by_ay), or None: the model's a_y does.

    One row: a float, None when not finite.  Rows: an array, NaN where not finite (the
    caller falls back to the model's a_y there)."""
    u = np.asarray(u, dtype=float)
    if not k.roll_by_ay or u.shape[-1] <= U_AY:
        return None
    m = u[..., U_AY]
    if np.ndim(m) == 0:
        return float(m) if math.isfinite(m) else None
    return m


def deriv(x, u, k: Known):
    """Continuous-time dynamics x_dot = f(x, u), eqs (5), (8)-(10) corrected."""
    v_y, yaw, phi, phi_d, c_f, c_r, i_z, i_x, l_f, clamp = _unpack(x, not k.per_axle)
    vy_d, yaw_d, a_y, _, _ = _rates(v_y, yaw, c_f, c_r, i_z, _inputs(u, k), _geometry(l_f, k), k, clamp)
    m = _measured_ay(u, k)
    if m is not None:
        a_y = np.where(np.isfinite(m), m, a_y) if np.ndim(m) else m
    out = np.zeros(np.shape(x))
    out[..., V_Y] = vy_d - _bank(x)  # eq (5) with the road's bank (0 without the state)
    out[..., YAW] = yaw_d
    out[..., PHI] = phi_d
    out[..., PHI_D] = (k.m * k.h * (a_y + k.g * phi) - k.k_phi * phi - k.c_phi * phi_d) / i_x  # eq (9)
    return out


@lru_cache(maxsize=64)
def _grid_weights(rows: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Row index and weight of the 2n+1 sub-step points among ``rows`` even input samples."""
    pos = np.linspace(0.0, rows - 1, 2 * n + 1)
    j = np.minimum(pos.astype(int), rows - 2)
    return j, (pos - j)[:, None]


def _input_grid(u, n: int) -> np.ndarray:
    """Inputs at the 2n+1 start, mid and end points of n sub-steps.

    ``u`` is one row (held) or rows sampled evenly over the step, first at its
    start and last at its end (linearly interpolated).
    """
    if u.ndim == 1:
        return np.broadcast_to(u, (2 * n + 1, len(u)))
    j, w = _grid_weights(len(u), n)
    return u[j] + w * (u[j + 1] - u[j])


def _roll_map(i_x, h: float, k: Known):
    """One sub-step of the roll, eq (9), as r' = T r + p a_y0 + q a_y1 with r = (phi, phi_dot).

    It is ROLL_SPLIT trapezoidal steps of g = h / ROLL_SPLIT (A-stable: the roll pole is
    the fastest mode) with a_y linear from a_y0 to a_y1 over the sub-step.  The roll is
    linear and i_x fixed over a step, so the steps collapse into this map, once per step.
    One step: (I - g/2 A) r' = (I + g/2 A) r + g/2 b (a_y + a_y'), i.e. r' = S r + w (a_y + a_y'),
    with A = [[0, 1], [-c y, -d y]], b = [0, m h y], y = 1 / i_x, c = k_phi - m g h, d = c_phi.
    """
    n = ROLL_SPLIT
    e = h / n / 2  # g/2
    c, d = k.k_phi - k.m * k.g * k.h, k.c_phi
    y = 1.0 / i_x
    inv = 1.0 / (1.0 + (e * d + e * e * c) * y)  # 1 / det(I - g/2 A)
    yd = y * inv
    s11, s12 = inv + (e * d - e * e * c) * yd, 2.0 * e * inv
    s21, s22 = (-2.0 * e * c) * yd, inv - (e * d + e * e * c) * yd
    w2 = (e * k.m * k.h) * yd
    w1 = e * w2
    # r_n = S^n r_0 + sum_j S^(n-1-j) w (b_j + b_j+1), b_j = a_y0 + (a_y1 - a_y0) j / n:
    # with V_m = S^m w, p = sum_m (2 - c_m) V_m and q = sum_m c_m V_m, c_m = (2 (n-1-m) + 1) / n
    v1, v2 = w1, w2
    c0 = (2 * (n - 1) + 1) / n
    p1, p2, q1, q2 = (2.0 - c0) * v1, (2.0 - c0) * v2, c0 * v1, c0 * v2
    for m in range(1, n):
        v1, v2 = s11 * v1 + s12 * v2, s21 * v1 + s22 * v2
        cm = (2 * (n - 1 - m) + 1) / n
        p1, p2, q1, q2 = p1 + (2.0 - cm) * v1, p2 + (2.0 - cm) * v2, q1 + cm * v1, q2 + cm * v2
    # T = S^n by squaring (n a power of two)
    t11, t12, t21, t22 = s11, s12, s21, s22
    for _ in range(_ROLL_SQUARINGS):
        t11, t12, t21, t22 = (t11 * t11 + t12 * t21, t12 * (t11 + t22), t21 * (t11 + t22), t21 * t12 + t22 * t22)
    return (t11, t12, t21, t22), (p1, p2), (q1, q2)


def roll_sensitivity_step(phi, w, chi, chi_d, u0, u1, i, c, kp, dt):
    """One trapezoidal step of eq (9), I_x phi'' + c_phi phi' + kp phi = u (u = m h a_y from
    ``u0`` to ``u1``, kp = k_phi - m g h), and of chi = d phi / d ln I_x, which obeys the same
    equation forced by -I_x phi'': (phi, phi', chi, chi') after ``dt``.  The trapezoid is
    A-stable (the roll's fast pole is stiff).  Plain floats, compiled as written by core.kernels."""
    e = 0.5 * dt
    det = 1.0 + e * c / i + e * e * kp / i
    acc0 = (u0 - c * w - kp * phi) / i
    # (I - e A) x1 = (I + e A) x0 + e b (u0 + u1), A = [[0, 1], [-kp / i, -c / i]], b = [0, 1 / i]
    r0, r1 = phi + e * w, w - e * (kp * phi + c * w) / i + e * (u0 + u1) / i
    phi1, w1 = ((1.0 + e * c / i) * r0 + e * r1) / det, (r1 - e * kp / i * r0) / det
    acc1 = (u1 - c * w1 - kp * phi1) / i
    r0, r1 = chi + e * chi_d, chi_d - e * (kp * chi + c * chi_d) / i - e * (acc0 + acc1)
    return phi1, w1, ((1.0 + e * c / i) * r0 + e * r1) / det, (r1 - e * kp / i * r0) / det


def fx(x, dt, u, k: Known, substeps: int | None = None):
    """Discrete transition: midpoint sub-steps for (v_y, yaw), trapezoidal for roll.

    ``u`` is one input row, held over the step, or the inputs sampled evenly
    over it (first row at the start, last at the end), interpolated at each
    sub-step: a steering ramp held at its mean would lag the real one.
    """
    if substeps is None:
        substeps = max(1, math.ceil(dt / MAX_SUBSTEP - 1e-9))
    u = np.asarray(u, dtype=float)
    x = np.array(x, dtype=float, copy=True)
    h = dt / substeps
    v_y, yaw, phi, phi_d, c_f, c_r, i_z, i_x, l_f, clamp = _unpack(x, not k.per_axle)
    bank = _bank(x)  # eq (5)'s g sin(bank), constant over the step (a random walk); 0.0: none
    if np.ndim(bank) == 0:
        bank = float(bank)
    geo = _geometry(l_f, k)
    (t11, t12, t21, t22), (p1, p2), (q1, q2) = _roll_map(i_x, h, k)
    # per-step input constants at every start, mid and end point, as plain floats
    grid = _input_grid(u, substeps)
    pres = list(zip(*(a.tolist() for a in _inputs(grid, k))))
    # eq (9)'s a_y at the sub-step ends: measured (Known.roll_by_ay) where finite, else the model's
    ays = _measured_ay(grid, k)
    ays = None if ays is None else [a if math.isfinite(a) else None for a in ays[0::2].tolist()]
    start = _rates(v_y, yaw, c_f, c_r, i_z, pres[0], geo, k, clamp)
    for i in range(substeps):
        vy_d, yaw_d, a0 = start[0] - bank, start[1], start[2]  # (x - 0.0 is x, to the bit)
        if ays is not None and ays[i] is not None:
            a0 = ays[i]
        vy_d1, yaw_d1, _, _, _ = _rates(
            v_y + h / 2 * vy_d, yaw + h / 2 * yaw_d, c_f, c_r, i_z, pres[2 * i + 1], geo, k, clamp
        )
        v_y = v_y + h * (vy_d1 - bank)
        yaw = yaw + h * yaw_d1
        start = _rates(v_y, yaw, c_f, c_r, i_z, pres[2 * i + 2], geo, k, clamp)
        a1 = start[2] if ays is None or ays[i + 1] is None else ays[i + 1]
        # the roll does not act back on v_y and yaw (a_y has no phi term), so it follows
        phi, phi_d = (t11 * phi + t12 * phi_d + p1 * a0 + q1 * a1, t21 * phi + t22 * phi_d + p2 * a0 + q2 * a1)
    x[..., V_Y], x[..., YAW], x[..., PHI], x[..., PHI_D] = v_y, yaw, phi, phi_d
    return x


def hx(x, u, k: Known):
    """Measurements: yaw-rate gyro, roll-rate gyro, lateral accelerometer (eq 7)."""
    _, _, a_y = forces(x, u, k)
    if np.ndim(x) == 1:
        return np.array([x[YAW], x[PHI_D], a_y])
    return np.stack([x[..., YAW], x[..., PHI_D], a_y], axis=-1)


def _dforces(x, u, k: Known):
    """Gradients of (Y_f, F_yr) with respect to the state (single state only)."""
    d, v_x, sd, cd, ck_fz0, w_r = _inputs(u, k)
    v_y, yaw, _, _, c_f, c_r, _, _, l_f, _ = _unpack(x, not k.per_axle)
    l_r = k.L - l_f
    ck_fz = ck_fz0 - k.ck_slope * l_f
    alpha_f = d - (v_y + l_f * yaw) / v_x
    alpha_r = -(v_y - l_r * yaw) / v_x
    v_w = v_x * cd + (v_y + l_f * yaw) * sd
    # d F_xf / d v_w through s_f = omega r / v_w - 1 (zero where v_w is clamped)
    dfx_dvw = -ck_fz * w_r / v_w**2 if v_w > V_MIN else 0.0
    n = len(x)
    dyf = np.zeros(n)
    dyf[V_Y] = dfx_dvw * sd * sd + c_f * (-1.0 / v_x) * cd  # d Y_f / d p, p = v_y + l_f r
    dyf[YAW] = l_f * dyf[V_Y]
    dyf[C_F] = alpha_f * cd if x[C_F] > PARAM_FLOOR[0] else 0.0
    # l_f moves p and, through the front load (eq 3a), C_sigma
    dyf[L_F] = yaw * dyf[V_Y] - k.ck_slope * sd * (w_r / max(v_w, V_MIN) - 1.0)
    dfr = np.zeros(n)
    dfr[V_Y] = -c_r / v_x
    dfr[YAW] = c_r * l_r / v_x
    rear = C_R if k.per_axle else C_F  # the state the rear axle's stiffness is
    dfr[rear] = alpha_r if x[rear] > PARAM_FLOOR[1] else 0.0
    dfr[L_F] = -c_r * yaw / v_x
    return dyf, dfr


def jac_f(x, u, k: Known):
    """A = d deriv / d x, analytic (the paper's eqs (25)-(27) have typos; NOTES 7)."""
    x = np.asarray(x, dtype=float)
    v_x = max(u[U_VX], V_MIN)
    dyf, dfr = _dforces(x, u, k)
    day = (dyf + dfr) / k.m
    f = deriv(x, u, k)
    y_f, f_yr, _ = forces(x, u, k)
    i_z, i_x = max(x[I_Z], PARAM_FLOOR[2]), max(x[I_X], PARAM_FLOOR[3])
    l_f = x[L_F]
    A = np.zeros((len(x), len(x)))
    A[V_Y] = day
    A[V_Y, YAW] -= v_x
    if len(x) > BANK:
        A[V_Y, BANK] = -1.0  # eq (5): the bank's pull on v_y
    A[YAW] = (l_f * dyf - (k.L - l_f) * dfr) / i_z
    A[YAW, L_F] += (y_f + f_yr) / i_z  # the moment arms, eq (10)
    if x[I_Z] > PARAM_FLOOR[2]:
        A[YAW, I_Z] = -f[YAW] / i_z
    A[PHI, PHI_D] = 1.0
    if _measured_ay(u, k) is None:  # eq (9) driven by the model's a_y (else by the measured: no state moves it)
        A[PHI_D] = k.m * k.h * day / i_x
    A[PHI_D, PHI] += (k.m * k.g * k.h - k.k_phi) / i_x
    A[PHI_D, PHI_D] += -k.c_phi / i_x
    if x[I_X] > PARAM_FLOOR[3]:
        A[PHI_D, I_X] = -f[PHI_D] / i_x
    return A


def jac_h(x, u, k: Known):
    """H = d hx / d x, analytic."""
    dyf, dfr = _dforces(np.asarray(x, dtype=float), u, k)
    H = np.zeros((3, np.shape(x)[-1]))
    H[Z_YAW, YAW] = 1.0
    H[Z_ROLL, PHI_D] = 1.0
    H[Z_AY] = (dyf + dfr) / k.m
    return H
