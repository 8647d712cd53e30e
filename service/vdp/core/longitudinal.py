"""Stage 1: the longitudinal model, eqs (1)-(3), (13), (14), as a joint state-parameter model.

Filter state (SI units)::

    x = [v_x, l_f, h, C_K]

Inputs ``u`` (one row per step, columns below) and measurements
``z = [omega_f, omega_r, v_gnss]`` (axle wheel speeds in rad/s, GNSS speed).

The wheel spin dynamics (eq 2) are stiff: tau = J v / (r^2 C_K F_z) is about
1 ms at 10 m/s, far below the 10 ms logging period (NOTES item 10).  Instead of
propagating omega with forward Euler, the wheel speed is an algebraic output:
the quasi-static torque balance of eq (2) gives the tyre force
``F_x = (T - J*omega_dot)/r`` with ``omega_dot ~= a_x / r``, eq (14) gives the slip
``s = F_x / (C_K F_z)``, and eq (13) inverted gives ``omega = v_x (1 + s) / r``.
Only v_x is propagated, by the measured a_x (eq 1 with the IMU's a_x).

This departs from the paper's parameter-only filter (Table 4, eq 15), which
predicts measured states from measured states and so differentiates noisy wheel
speeds; keeping v_x as a state lets GNSS and the wheels average each other.

All functions broadcast over leading axes, so a whole set of sigma points is
evaluated in one call.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# state indices
V_X, L_F, H, C_K = range(4)
STATE_NAMES = ("v_x", "l_f", "h", "C_K")
STATE_UNITS = ("m/s", "m", "m", "1")
PARAM_SLICE = slice(1, 4)
# typical magnitudes: the filter works in x / SCALE for a well-conditioned covariance
SCALE = np.array([10.0, 1.0, 1.0, 10.0])

# input columns
U_TF, U_TR, U_AX = range(3)
N_U = 3

# measurement rows
Z_WF, Z_WR, Z_V = range(3)
N_Z = 3

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
    """Quasi-static eq (2): F_x = (T - J a_x / r) / r per axle [N]."""
    a_x = u[..., U_AX]
    spin = k.J * a_x / k.r
    return (u[..., U_TF] - spin) / k.r, (u[..., U_TR] - spin) / k.r


def slips(x, u, k: Known):
    """Eq (14) solved for the slip of each axle."""
    f_zf, f_zr = axle_loads(x[..., L_F], x[..., H], u[..., U_AX], k)
    f_xf, f_xr = tyre_forces(u, k)
    c_k = np.maximum(x[..., C_K], 1e-3)
    return f_xf / (c_k * f_zf), f_xr / (c_k * f_zr)


def fx(x, dt, u, k: Known):
    """Transition: v_x integrates a_x (eq 1); parameters are a random walk (Table 4)."""
    out = np.array(x, dtype=float, copy=True)
    out[..., V_X] = x[..., V_X] + dt * u[..., U_AX]
    return out


def hx(x, u, k: Known):
    """Measurement: eq (13) inverted for both axles, and the GNSS speed."""
    s_f, s_r = slips(x, u, k)
    v = x[..., V_X]
    return np.stack([v * (1.0 + s_f) / k.r, v * (1.0 + s_r) / k.r, v], axis=-1)


def jac_f(x, dt, u, k: Known):
    """d fx / d x: v_x does not depend on the state, so it is the identity."""
    return np.eye(4)


def jac_h(x, u, k: Known):
    """d hx / d x, analytic (replaces the paper's eqs (20)-(21), which have typos; NOTES 7)."""
    v, l_f, h, c_k = x[V_X], x[L_F], x[H], x[C_K]
    a_x = u[U_AX]
    f_zf, f_zr = axle_loads(l_f, h, a_x, k)
    s_f, s_r = slips(x, u, k)
    mg_l = k.m * k.g / k.L
    ma_l = k.m * a_x / k.L
    free_f = f_zf > MIN_LOAD_FRACTION * k.m * k.g
    free_r = f_zr > MIN_LOAD_FRACTION * k.m * k.g
    # d s / d F_z = -s / F_z ; d s / d C_K = -s / C_K
    dsf_dfz, dsr_dfz = -s_f / f_zf, -s_r / f_zr
    dfzf = np.array([-mg_l, -ma_l]) * free_f  # d F_zf / d (l_f, h)
    dfzr = np.array([mg_l, ma_l]) * free_r
    g = v / k.r
    out = np.zeros((3, 4))
    out[Z_WF, V_X] = (1.0 + s_f) / k.r
    out[Z_WF, L_F:C_K] = g * dsf_dfz * dfzf
    out[Z_WF, C_K] = -g * s_f / c_k
    out[Z_WR, V_X] = (1.0 + s_r) / k.r
    out[Z_WR, L_F:C_K] = g * dsr_dfz * dfzr
    out[Z_WR, C_K] = -g * s_r / c_k
    out[Z_V, V_X] = 1.0
    return out
