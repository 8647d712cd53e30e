"""Stage 1: the longitudinal model, eqs (1)-(3), (13), (14), for a parameter-only filter.

Filter state: the parameters ``x = [l_f, h, C_K, b, c, s_0f, s_0r]`` (a random walk,
Table 4).  ``C_K`` is the small-slip (initial) stiffness per unit load; the bend ``b, c``
and the offsets ``s_0`` are the two things a real tyre adds to eq (14), estimated beside
it and not reported:

* **the bend** ``b``, ``c``: a real tyre's force-slip curve bends long before the
  friction limit, so at the loads of brisk driving eq (14)'s straight line reads a
  stiffness 12-24 % low (brush tyres, docs/decisions/0005).  The slip is taken as eq (14)
  times ``1 + b|u| + c u^2`` with ``u = F_x / F_z``, the inverse law's series to third
  order: a brush tyre's has ``b = 1 / (3 mu)`` and ``c = 5 / (27 mu^2)``; a Magic-Formula
  tyre's is odd and smooth at zero slip, ``b = 0`` and ``c > 0`` (with c tied to b, C_K
  came out 5-9 % high on the multi-body cars; free, within 2 %).  ``b = c = 0`` is the
  paper's linear tyre.  The initial slope is C_K whatever the bend.
* **the slip offsets** ``s_0f``, ``s_0r``: each axle's slip at zero wheel torque.
  Rolling resistance takes ``f_r F_z`` from the force the torque gives (a braking slip
  of ``-f_r / C_K``), a tyre's own shift (Pacejka's S_Hx) adds to it, and a rolling
  radius 0.1 % off reads as 0.001 of slip.  Beside slips of 0.5-1 % they moved C_K by
  tens of per cent where the data held one sign of force more than the other; the
  front and rear ones differ (tyres, pressures, wear, and on the multi-body car by
  0.0003), and that difference moved h by 10 %, since stage 1 reads l_f and h from the
  front-minus-rear slip.

A state vector of only ``[l_f, h, C_K]`` is the paper's model (``b = c = s_0 = 0``).
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
L_F, H, C_K, BEND, CUBIC, S_0F, S_0R = range(7)
N_X = 7
STATE_NAMES = ("l_f", "h", "C_K", "b", "c", "s_0f", "s_0r")
STATE_UNITS = ("m", "m", "1", "1", "1", "1", "1")
PARAM_SLICE = slice(0, 3)  # the reported parameters; b and the offsets are the tyre's shape, not reported
CONSIDER = None  # no consider state (see lateral)
# typical magnitudes: the filter works in x / SCALE for a well-conditioned covariance
SCALE = np.array([1.0, 1.0, 10.0, 0.3, 0.3, 1e-3, 1e-3])

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


def _shape(x):
    """(b, c, s_0f, s_0r) of a state; zeros for the paper's three-parameter state."""
    if x.shape[-1] > BEND:
        return x[..., BEND], x[..., CUBIC], x[..., S_0F], x[..., S_0R]
    return 0.0, 0.0, 0.0, 0.0


def bend(u, b, c):
    """Slip over eq (14)'s linear slip at load share u = F_x / F_z: 1 + b|u| + c u^2.

    The inverse law's series to third order: the brush tyre's,
    ``s = (3 mu / C_K)(1 - (1 - |u| / mu)^(1/3))``, has ``b = 1 / (3 mu)``,
    ``c = 5 / (27 mu^2)``.  A polynomial has no pole at the friction limit for a wild sigma
    point to fall into.
    """
    a = np.abs(u)
    return 1.0 + b * a + c * a * a


def slips(x, u, k: Known):
    """Eq (14) with the bend and the offset, solved for the slip of each axle."""
    f_zf, f_zr = axle_loads(x[..., L_F], x[..., H], u[..., U_AX], k)
    f_xf, f_xr = tyre_forces(u, k)
    c_k = np.maximum(x[..., C_K], 1e-3)
    b, c, s0f, s0r = _shape(x)
    u_f, u_r = f_xf / f_zf, f_xr / f_zr
    return s0f + u_f / c_k * bend(u_f, b, c), s0r + u_r / c_k * bend(u_r, b, c)


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
    """d hx / d x, analytic (replaces the paper's eqs (20)-(21), which have typos; NOTES 7).

    Per axle, with ``u = F_x / F_z`` and ``s = s_0 + (u / C_K) bend(u)``:
    ``ds/du = (1 + 2 b|u| + 3 c u^2) / C_K`` and ``du/dF_z = -u / F_z``;
    ``ds/dC_K = -(s - s_0) / C_K``; ``ds/db = (u / C_K)|u|``; ``ds/dc = (u / C_K) u^2``;
    ``ds/ds_0 = 1`` for the axle's own offset.
    """
    n = x.shape[-1]
    l_f, h, c_k = x[L_F], x[H], max(x[C_K], 1e-3)
    b, c = _shape(x)[:2]
    a_x, v = u[U_AX], u[U_VX]
    f_zf, f_zr = axle_loads(l_f, h, a_x, k)
    f_xf, f_xr = tyre_forces(u, k)
    mg_l = k.m * k.g / k.L
    ma_l = k.m * a_x / k.L
    free_f = f_zf > MIN_LOAD_FRACTION * k.m * k.g
    free_r = f_zr > MIN_LOAD_FRACTION * k.m * k.g
    dfzf = np.array([-mg_l, -ma_l]) * free_f  # d F_zf / d (l_f, h)
    dfzr = np.array([mg_l, ma_l]) * free_r
    g = v / k.r
    out = np.zeros((2, n))
    for row, f_x, f_z, dfz, off in ((Z_WF, f_xf, f_zf, dfzf, S_0F), (Z_WR, f_xr, f_zr, dfzr, S_0R)):
        q = f_x / f_z
        a = abs(q)
        lin = q / c_k  # eq (14)'s slip
        ds_du = (1.0 + 2.0 * b * a + 3.0 * c * a * a) / c_k
        out[row, L_F:C_K] = g * ds_du * (-q / f_z) * dfz
        out[row, C_K] = -g * lin * bend(q, b, c) / c_k
        if n > BEND:
            out[row, BEND] = g * lin * a
            out[row, CUBIC] = g * lin * a * a
            out[row, off] = g
    return out
