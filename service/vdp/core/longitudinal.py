"""Stage 1: the longitudinal model, eqs (1)-(3), (13), (14), for a parameter-only filter.

Filter state: the parameters ``x = [l_f, h, C_K]`` (a random walk, Table 4).
Inputs ``u = [T_f, T_r, a_x, v_x]``: axle torques, IMU a_x, and v_x from the
speed filter (:mod:`vdp.core.speed`, GNSS + IMU).  Measurements
``z = [omega_f, omega_r]``: the axle wheel speeds [rad/s].

The wheel spin dynamics (eq 2) are stiff: tau = J v / (r^2 C_K F_z) is about
1 ms at 10 m/s, far below the 10 ms logging period (NOTES item 10).  Instead of
propagating omega with forward Euler, the wheel speed is an algebraic output:
the quasi-static torque balance of eq (2) gives the tyre force
``F_x = (T - J*omega_dot)/r`` with ``omega_dot ~= a_x / r``, eq (14) gives the slip
``s = F_x / (C_K F_z)``, and eq (13) inverted gives ``omega = v_x (1 + s) / r``.

v_x is deliberately *not* estimated from the wheel speeds here: a speed that
has seen the wheels carries their torque-noise-driven innovations back into
the slip and biases C_K upward (errors in variables).  GNSS + IMU give a v_x
whose error is independent of the torques; its std enters R as a noise common
to both axles, so C_K (common mode) is trusted less than l_f and h (the
front/rear difference).

All functions broadcast over leading axes, so a whole set of sigma points is
evaluated in one call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# state indices
L_F, H, C_K = range(3)
STATE_NAMES = ("l_f", "h", "C_K")
STATE_UNITS = ("m", "m", "1")
PARAM_SLICE = slice(0, 3)
CONSIDER = None  # no consider state (see lateral)
# typical magnitudes: the filter works in x / SCALE for a well-conditioned covariance
SCALE = np.array([1.0, 1.0, 10.0])

# input columns
U_TF, U_TR, U_AX, U_VX, U_VX_STD, U_WDF, U_WDR = range(7)
N_U = 7

# measurement rows
Z_WF, Z_WR = range(2)
N_Z = 2

MIN_LOAD_FRACTION = 0.05  # clamp F_z so a wild sigma point cannot divide by ~0


@dataclass(frozen=True)
class Known:
    """Known constants of stage 1 (SI)."""

    m: float
    L: float
    r: float
    J: float
    g: float = 9.8


def axle_loads(l_f, h, a_x, k: Known):
    """Eq (3): static plus dynamic axle loads [N]."""
    mg = k.m * k.g
    shift = k.m * a_x * h / k.L
    f_zf = mg * (k.L - l_f) / k.L - shift
    f_zr = mg * l_f / k.L + shift
    lo = MIN_LOAD_FRACTION * mg
    return np.maximum(f_zf, lo), np.maximum(f_zr, lo)


def tyre_forces(u, k: Known):
    """Eq (2) solved for the tyre force: F_x = (T - J omega_dot) / r per axle [N].

    omega_dot is the measured wheel acceleration (a slope over a block of
    samples); front and rear differ while their slips change, and stage 1 reads
    l_f and h from that front/rear difference, so a_x / r is not close enough.
    """
    return ((u[..., U_TF] - k.J * u[..., U_WDF]) / k.r, (u[..., U_TR] - k.J * u[..., U_WDR]) / k.r)


def slips(x, u, k: Known):
    """Eq (14) solved for the slip of each axle."""
    f_zf, f_zr = axle_loads(x[..., L_F], x[..., H], u[..., U_AX], k)
    f_xf, f_xr = tyre_forces(u, k)
    c_k = np.maximum(x[..., C_K], 1e-3)
    return f_xf / (c_k * f_zf), f_xr / (c_k * f_zr)


def fx(x, dt, u, k: Known):
    """Transition: the parameters are a random walk (Table 4); the noise is in Q."""
    return np.array(x, dtype=float, copy=True)


def hx(x, u, k: Known):
    """Measurement: eq (13) inverted for both axles."""
    s_f, s_r = slips(x, u, k)
    v = u[..., U_VX]
    return np.stack([v * (1.0 + s_f) / k.r, v * (1.0 + s_r) / k.r], axis=-1)


def speed_sensitivity(x, u, k: Known) -> np.ndarray:
    """d omega / d v_x for both axles: how an error of v_x moves both measurements."""
    s_f, s_r = slips(x, u, k)
    return np.array([(1.0 + s_f) / k.r, (1.0 + s_r) / k.r])


def jac_h(x, u, k: Known):
    """d hx / d x, analytic (replaces the paper's eqs (20)-(21), which have typos; NOTES 7)."""
    l_f, h, c_k = x[L_F], x[H], x[C_K]
    a_x, v = u[U_AX], u[U_VX]
    f_zf, f_zr = axle_loads(l_f, h, a_x, k)
    s_f, s_r = slips(x, u, k)
    mg_l = k.m * k.g / k.L
    ma_l = k.m * a_x / k.L
    free_f = f_zf > MIN_LOAD_FRACTION * k.m * k.g
    free_r = f_zr > MIN_LOAD_FRACTION * k.m * k.g
    # d s / d F_z = -s / F_z ; d s / d C_K = -s / C_K
    dfzf = np.array([-mg_l, -ma_l]) * free_f  # d F_zf / d (l_f, h)
    dfzr = np.array([mg_l, ma_l]) * free_r
    g = v / k.r
    out = np.zeros((2, 3))
    out[Z_WF, L_F:C_K] = g * (-s_f / f_zf) * dfzf
    out[Z_WF, C_K] = -g * s_f / c_k
    out[Z_WR, L_F:C_K] = g * (-s_r / f_zr) * dfzr
    out[Z_WR, C_K] = -g * s_r / c_k
    return out
