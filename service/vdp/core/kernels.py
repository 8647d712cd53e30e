"""Compiled (numba) UKF steps on vdp's two models: the numpy filters' numbers, without numpy's per-call cost.

Also stage 2's output-error pass (``oe_states``: core.output_error.Problem's prefix scan as
one loop over the rows, the same products associated left to right).

The UKF's arrays are tiny (stage 2: 19 sigma points of 9 states; stage 1: 15 of 7), so
the numpy path (core.filters with core.lateral / core.longitudinal) spends its time in
the per-call overhead of ~100 array operations per step, not in arithmetic.  Here one
compiled call does a whole predict or update: the sigma points, the bounded transform
(core.bounds), the model on each point, the unscented transform and the gain.

The physics is not copied where numba can compile it as written: lateral's ``_rates``
(eqs 5, 7, 10-12), ``_roll_map`` (eq 9) and ``_geometry`` are compiled from their own
source.  What is written out again here is the glue numba cannot take as it is (numpy's
broadcasting over sigma points, ``tolist``): lateral.fx's sub-step loop, the floors of
``_unpack``, the input grid of ``_inputs``, longitudinal.slips and hx, and the filter
steps of core.filters.UKF, in the same operations and order.  tests/test_kernels.py
holds both paths to the same numbers (models, filter steps, and the estimates of whole
drives); a change to the models there must be followed here, and that test says so.

Every function is cached on disk by core.jit (the next process loads it instead of compiling);
core.warm compiles every signature the learners use at once, the first time one is wanted
(core.compiled.kernel).  The learners import this module only when they build their first
filter (numba's import costs ~0.5 s), and take the numpy path when numba cannot be imported
or ``LearnerConfig.compiled`` is off.  Small matrix products are loops here, not BLAS, so
nothing pulls in scipy's BLAS wrappers.
"""

from __future__ import annotations

import collections
import logging
import math
import typing

import numpy as np

from ..errors import FilterError
from . import batch, lateral, longitudinal
from .filters import UKF
from .jit import jit

log = logging.getLogger(__name__)

# status codes of a step (the learner's FilterError messages, as the numpy path words them)
OK, NOT_PD, SINGULAR, NON_FINITE, LOST_PD = 0, 1, 2, 3, 4
MESSAGES = {
    NOT_PD: "Matrix is not positive definite",
    SINGULAR: "Singular matrix",
    NON_FINITE: "non-finite state or covariance",
    LOST_PD: "covariance lost positive definiteness",
}

# a model's constants as numba takes them (attribute access on a named tuple)
Lat = collections.namedtuple("Lat", "m L r k_phi c_phi l_f h C_K g per_axle ck_slope roll_by_ay")
Lon = collections.namedtuple("Lon", "m L r J g")

# bounded transforms per state (core.bounds): 0 free, 1 log, 2 logit
FREE, LOG, LOGIT = 0, 1, 2


def lat_known(k: lateral.Known) -> Lat:
    """As floats and a bool whatever the profile wrote (an integer mass would be another
    signature: another compile for another profile)."""
    f = float
    return Lat(f(k.m), f(k.L), f(k.r), f(k.k_phi), f(k.c_phi), f(k.l_f), f(k.h), f(k.C_K), f(k.g),
               bool(k.per_axle), f(k.ck_slope), bool(k.roll_by_ay))  # fmt: skip


def lon_known(k: longitudinal.Known) -> Lon:
    """As floats (see lat_known)."""
    return Lon(float(k.m), float(k.L), float(k.r), float(k.J), float(k.g))


def transforms(bounds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(kind per state, lo, span) of a core.bounds.Bounds, as the kernels take them."""
    kind = np.zeros(bounds.n, dtype=np.int64)
    lo = np.zeros(bounds.n)
    span = np.ones(bounds.n)
    kind[bounds.log] = LOG
    kind[bounds.logit] = LOGIT
    lo[bounds.logit] = bounds.lo
    span[bounds.logit] = bounds.span
    return kind, lo, span


_jit = jit()

# the physics, compiled from core.lateral's own source
_rates = _jit(lateral._rates)
_roll_map = _jit(lateral._roll_map)
_geometry = _jit(lateral._geometry)
_pre = _jit(lateral._pre)

V_MIN = lateral.V_MIN
F0, F1, F2, F3 = (float(v) for v in lateral.PARAM_FLOOR)
LOGIT_MAX = 30.0
MIN_LOAD = longitudinal.MIN_LOAD_FRACTION


@_jit
def _max(a, b):
    """The builtin max of two floats (the second only when it is larger)."""
    return b if b > a else a


@_jit
def _to_si(t, kind, lo, span, out):
    """core.bounds.Bounds.to_si of one state."""
    for i in range(t.shape[0]):
        if kind[i] == LOG:
            out[i] = np.exp(t[i])
        elif kind[i] == LOGIT:
            q = min(max(t[i], -LOGIT_MAX), LOGIT_MAX)
            out[i] = lo[i] + span[i] / (1.0 + np.exp(-q))
        else:
            out[i] = t[i]


# -- the UKF's linear algebra (core.filters.UKF) ------------------------------
@_jit
def _cholesky(A, L):
    """Lower Cholesky factor of A (its lower triangle, as LAPACK reads it); False if not PD."""
    n = A.shape[0]
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if s <= 0.0:  # (a NaN goes on, as numpy's does: the filter's check names it non-finite)
            return False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
        for i in range(j):
            L[i, j] = 0.0
    return True


@_jit
def _points(x, P, lam_n, sig):
    """x, x + U_k, x - U_k for the rows U_k of the upper Cholesky factor of (lambda + n) P."""
    n = x.shape[0]
    L = np.empty((n, n))
    if not _cholesky(lam_n * P, L):
        return False
    for j in range(n):
        sig[0, j] = x[j]
    for k in range(n):
        for j in range(n):
            sig[1 + k, j] = x[j] + L[j, k]
            sig[1 + n + k, j] = x[j] - L[j, k]
    return True


@_jit
def _transform(sig, Wm, Wc, noise):
    """(mean, Wc-weighted covariance + noise, deviations) of transformed sigma points."""
    m, n = sig.shape
    mean = np.zeros(n)
    for i in range(m):
        for j in range(n):
            mean[j] += Wm[i] * sig[i, j]
    d = np.empty((m, n))
    for i in range(m):
        for j in range(n):
            d[i, j] = sig[i, j] - mean[j]
    cov = np.zeros((n, n))
    for i in range(m):
        w = Wc[i]
        for a in range(n):
            da = d[i, a]
            for b in range(n):
                cov[a, b] += da * (w * d[i, b])
    return mean, cov + noise, d


@_jit
def _inv(S):
    """Inverse by Gauss-Jordan with partial pivoting; None-like (ok False) when singular."""
    n = S.shape[0]
    A = S.copy()
    out = np.eye(n)
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(A[r, c]) > abs(A[p, c]):
                p = r
        if A[p, c] == 0.0 or not math.isfinite(A[p, c]):
            return out, False
        if p != c:
            for j in range(n):
                A[c, j], A[p, j] = A[p, j], A[c, j]
                out[c, j], out[p, j] = out[p, j], out[c, j]
        piv = A[c, c]
        for j in range(n):
            A[c, j] /= piv
            out[c, j] /= piv
        for r in range(n):
            if r != c:
                f = A[r, c]
                if f != 0.0:
                    for j in range(n):
                        A[r, j] -= f * A[c, j]
                        out[r, j] -= f * out[c, j]
    return out, True


@_jit
def _checked(x, P):
    """core.filters.JointFilter._check for the UKF: (P symmetrised, status)."""
    P = 0.5 * (P + P.T)
    if not math.isfinite(x.sum() + P.sum()):
        return P, NON_FINITE
    for i in range(P.shape[0]):
        if P[i, i] <= 0.0:
            return P, LOST_PD
    return P, OK


@_jit
def _mm(A, B):
    """A @ B (small: loops, no BLAS)."""
    out = np.zeros((A.shape[0], B.shape[1]))
    for i in range(A.shape[0]):
        for k in range(A.shape[1]):
            a = A[i, k]
            for j in range(B.shape[1]):
                out[i, j] += a * B[k, j]
    return out


@_jit
def _mmt(A, B):
    """A @ B.T"""
    out = np.zeros((A.shape[0], B.shape[0]))
    for i in range(A.shape[0]):
        for j in range(B.shape[0]):
            s = 0.0
            for k in range(A.shape[1]):
                s += A[i, k] * B[j, k]
            out[i, j] = s
    return out


@_jit
def _mv(A, v):
    """A @ v"""
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        s = 0.0
        for k in range(A.shape[1]):
            s += A[i, k] * v[k]
        out[i] = s
    return out


@_jit
def _gain_step(x, P, sig, hz, z, R, Wm, Wc, consider):
    """The UKF's update from the measurement sigma points ``hz`` (rows already selected):
    (x, P, y, S, status).  core.filters.UKF._update, operation by operation."""
    zp, S, dz = _transform(hz, Wm, Wc, R)
    m, n = sig.shape
    nz = hz.shape[1]
    Pxz = np.zeros((n, nz))
    for i in range(m):
        w = Wc[i]
        for a in range(n):
            da = sig[i, a] - x[a]
            for b in range(nz):
                Pxz[a, b] += da * (w * dz[i, b])
    Si, ok = _inv(S)
    y = z - zp
    if not ok:
        return x, P, y, S, SINGULAR
    K = _mm(Pxz, Si)
    if consider >= 0:
        K[consider, :] = 0.0
    x = x + _mv(K, y)
    KSK = _mmt(_mm(K, S), K)
    if consider < 0:
        P = P - KSK
    else:
        KPxz = _mmt(K, Pxz)
        P = P - KPxz - KPxz.T + KSK
    P, status = _checked(x, P)
    return x, P, y, S, status


# -- stage 2: core.lateral on scaled, bounded sigma points ---------------------
@_jit
def _lat_grid(us, j, w, n, k):
    """lateral._inputs of lateral._input_grid(us, n): (2n+1, 7) per-step input constants; the
    seventh is the measured a_y that drives eq (9) (lateral.Known.roll_by_ay; NaN: the model's)."""
    g = np.empty((2 * n + 1, 7))
    by_ay = k.roll_by_ay and us.shape[1] > lateral.U_AY
    for i in range(2 * n + 1):
        a_y = np.nan
        if us.shape[0] == 1:  # one row, held over the step
            d, v_x, w_f, a_x = us[0, 0], us[0, 1], us[0, 2], us[0, 3]
            if by_ay:
                a_y = us[0, lateral.U_AY]
        else:
            a, b, c = j[i], j[i] + 1, w[i]
            d = us[a, 0] + c * (us[b, 0] - us[a, 0])
            v_x = us[a, 1] + c * (us[b, 1] - us[a, 1])
            w_f = us[a, 2] + c * (us[b, 2] - us[a, 2])
            a_x = us[a, 3] + c * (us[b, 3] - us[a, 3])
            if by_ay:
                a_y = us[a, lateral.U_AY] + c * (us[b, lateral.U_AY] - us[a, lateral.U_AY])
        g[i, 6] = a_y
        g[i, 0], g[i, 1], g[i, 2], g[i, 3], g[i, 4], g[i, 5] = _pre(d, v_x, w_f, a_x, k)
    return g


@_jit
def _row(g, i):
    return (g[i, 0], g[i, 1], g[i, 2], g[i, 3], g[i, 4], g[i, 5])


@_jit
def _lat_params(x, k):
    """_unpack's floors: (c_f, c_r, i_z, i_x) of an SI state."""
    c_r = x[lateral.C_R] if k.per_axle else x[lateral.C_F]
    return _max(x[lateral.C_F], F0), _max(c_r, F1), _max(x[lateral.I_Z], F2), _max(x[lateral.I_X], F3)


@_jit
def _lat_fx(x, dt, g, n, k):
    """lateral.fx of one SI state on the input constants ``g`` of n sub-steps (in place)."""
    h = dt / n
    v_y, yaw, phi, phi_d = x[lateral.V_Y], x[lateral.YAW], x[lateral.PHI], x[lateral.PHI_D]
    c_f, c_r, i_z, i_x = _lat_params(x, k)
    geo = _geometry(x[lateral.L_F], k)
    T, p, q = _roll_map(i_x, h, k)
    t11, t12, t21, t22 = T
    p1, p2 = p
    q1, q2 = q
    start = _rates(v_y, yaw, c_f, c_r, i_z, _row(g, 0), geo, k, _max)
    for i in range(n):
        vy_d, yaw_d, a0 = start[0], start[1], start[2]
        if math.isfinite(g[2 * i, 6]):  # eq (9) driven by the measured a_y (lateral.fx's ``ays``)
            a0 = g[2 * i, 6]
        mid = _rates(v_y + h / 2 * vy_d, yaw + h / 2 * yaw_d, c_f, c_r, i_z, _row(g, 2 * i + 1), geo, k, _max)
        v_y = v_y + h * mid[0]
        yaw = yaw + h * mid[1]
        start = _rates(v_y, yaw, c_f, c_r, i_z, _row(g, 2 * i + 2), geo, k, _max)
        a1 = start[2] if not math.isfinite(g[2 * i + 2, 6]) else g[2 * i + 2, 6]
        phi, phi_d = (t11 * phi + t12 * phi_d + p1 * a0 + q1 * a1, t21 * phi + t22 * phi_d + p2 * a0 + q2 * a1)
    x[lateral.V_Y], x[lateral.YAW], x[lateral.PHI], x[lateral.PHI_D] = v_y, yaw, phi, phi_d


@_jit
def _lat_ay(x, pre, k):
    """lateral.hx's a_y (eq 7) of one SI state."""
    c_f, c_r, i_z, _ = _lat_params(x, k)
    return _rates(x[lateral.V_Y], x[lateral.YAW], c_f, c_r, i_z, pre, _geometry(x[lateral.L_F], k), k, _max)[2]


@_jit
def lat_predict(x, P, lam_n, Wm, Wc, Q, scale, kind, lo, span, dt, us, j, w, n, k, consider):
    """core.filters.UKF.predict on lateral.fx: (x, P, sigmas of the update, status)."""
    m, nx = 2 * x.shape[0] + 1, x.shape[0]
    sig = np.empty((m, nx))
    if not _points(x, P, lam_n, sig):
        return x, P, sig, NOT_PD
    held = x[consider] if consider >= 0 else 0.0
    g = _lat_grid(us, j, w, n, k)
    t = np.empty(nx)
    s = np.empty(nx)
    for i in range(m):
        for a in range(nx):
            t[a] = sig[i, a] * scale[a]
        _to_si(t, kind, lo, span, s)
        _lat_fx(s, dt, g, n, k)
        for a in range(nx):  # Bounds.wrap_fx: the transformed entries are constants of fx
            sig[i, a] = (s[a] if kind[a] == FREE else t[a]) / scale[a]
    x, P, _ = _transform(sig, Wm, Wc, Q * dt)
    out = np.empty((m, nx))
    if not _points(x, P, lam_n, out):
        return x, P, out, NOT_PD
    if consider >= 0:
        x[consider] = held
    P, status = _checked(x, P)
    return x, P, out, status


@_jit
def lat_update(x, P, sig, Wm, Wc, R, scale, kind, lo, span, z, rows, u, k, consider):
    """core.filters.UKF._update on lateral.hx, measurement rows ``rows``: (x, P, y, S, status)."""
    m, nx = sig.shape
    pre = _pre(u[lateral.U_DELTA], u[lateral.U_VX], u[lateral.U_WF], u[lateral.U_AX], k)
    hz = np.empty((m, rows.shape[0]))
    t = np.empty(nx)
    s = np.empty(nx)
    for i in range(m):
        for a in range(nx):
            t[a] = sig[i, a] * scale[a]
        _to_si(t, kind, lo, span, s)
        full = (s[lateral.YAW], s[lateral.PHI_D], _lat_ay(s, pre, k))
        for r in range(rows.shape[0]):
            hz[i, r] = full[rows[r]]
    return _gain_step(x, P, sig, hz, z, R, Wm, Wc, consider)


# -- stage 2's steps over a run of samples (learner.Stage2.steps) ----------------------
_roll_step = _jit(lateral.roll_sensitivity_step)

# the learner's scalars (ls) and settings (cfg) arrays, and a Consistency's (learner.Consistency) row
(L_SAMPLES, L_UPDATES, L_ROLL_UPDATES, L_ROLL_INFO, L_INFO_WINDOW, L_T_LAST, L_N_US) = range(7)
(C_MAX_GAP, C_EVERY, C_SAVE_EVERY, C_ROLL_DEN, C_DIVERGED, C_ROLL_BY_AY) = range(6)
(E_PHI, E_W, E_CHI, E_CHI_D, E_T, E_U, E_I, E_C, E_KP, E_MH) = range(10)
(K_N, K_NIS, K_ROWS, K_E2, K_EE, K_NE, K_E, K_HAS_E, K_COUNT, K_POS) = range(10)
WINDOW, TOTAL, ROLL_WINDOW, ROLL_TOTAL = range(4)


@_jit
def _nis(y, S, keep, nk):
    """learner.quad_form of the rows ``keep[:nk]``: y' S^-1 y by a Cholesky factor, its
    operations in its order; NaN where S is not positive definite (the learner then solves)."""
    if nk == 2:
        i0, i1 = keep[0], keep[1]
        a, b, d = S[i0, i0], S[i0, i1], S[i1, i1]
        det = a * d - b * b
        if not (a > 0.0 and det > 0.0):
            return np.nan
        y0, y1 = y[i0], y[i1]
        return (d * y0 * y0 - 2.0 * b * y0 * y1 + a * y1 * y1) / det
    L = np.zeros((3, 3))
    w = np.zeros(3)
    total = 0.0
    for i in range(nk):
        for j in range(i + 1):
            acc = 0.0
            for q in range(j):
                acc += L[i, q] * L[j, q]
            acc = S[keep[i], keep[j]] - acc
            if i == j:
                if not acc > 0.0:
                    return np.nan
                L[i, i] = math.sqrt(acc)
            else:
                L[i, j] = acc / L[j, j]
        acc = 0.0
        for q in range(i):
            acc += L[i, q] * w[q]
        w[i] = (y[keep[i]] - acc) / L[i, i]
        total += w[i] * w[i]
    return total


@_jit
def _cons_add(cons, ring, j, nis, rows, e, has_e):
    """learner.Consistency.add on row ``j`` of the arrays (its deque of recent values: a ring)."""
    cons[j, K_N] += 1
    cons[j, K_NIS] += nis
    cons[j, K_ROWS] += rows
    m = ring.shape[1]
    ring[j, int(cons[j, K_POS])] = nis / max(rows, 1)
    cons[j, K_POS] = (cons[j, K_POS] + 1) % m
    cons[j, K_COUNT] = min(cons[j, K_COUNT] + 1, m)
    if has_e:
        cons[j, K_E2] += e * e
        cons[j, K_NE] += 1
        if cons[j, K_HAS_E] != 0.0:
            cons[j, K_EE] += e * cons[j, K_E]
    cons[j, K_E] = e
    cons[j, K_HAS_E] = 1.0 if has_e else 0.0


@_jit
def _recent(cons, ring, j):
    """learner.Consistency.recent: the mean of a full ring, summed oldest first (0 until full)."""
    m = ring.shape[1]
    if cons[j, K_COUNT] < m:
        return 0.0
    total = 0.0
    pos = int(cons[j, K_POS])
    for q in range(m):
        total += ring[j, (pos + q) % m]
    return total / m


@_jit
def lat_run(T, Y, D, G, a, b, c, x, P, sig, lam_n, Wm, Wc, Q, R, scale, kind, lo, span, k, consider, j, w, nsub,
            ls, cfg, us, ex, cons, ring, rec):  # fmt: skip
    """Stage 2's samples a..b-1 of a block, an open window's, as learner.Stage2._step takes them
    (inputs, roll excitation, the filter's predict and update every cfg[C_EVERY] samples, the
    record's rows, the innovation tests), until a sample needs the learner's own step: one
    that ends or restarts the window (a gap, a late or non-finite input), whose step would
    fail, diverge, save a last-good copy or need another input grid, or that has no
    measurement.  Nothing of that sample is taken.  Returns (its index, x, P, sig, y, S,
    record rows written); ``ls``, ``us``, ``ex``, ``cons``, ``ring`` are updated in place.
    Y: the samples' channel values; D: their derived v_x, v_std, a_x bias, yaw and roll
    offsets; c: the channel indices (WS_FL, WS_FR, WS_RL, WS_RR, T_R, DELTA, AX, AY, YAW, ROLL, SPEED)."""
    every = int(cfg[C_EVERY])
    nr = 0
    y_out = np.zeros(0)
    S_out = np.zeros((0, 0))
    u = np.empty(5)
    z = np.empty(3)
    keep = np.empty(3, dtype=np.int64)
    for i in range(a, b):
        t = T[i]
        yv = Y[i]
        # -- Stage2.inputs
        w_r = 0.5 * (yv[c[2]] + yv[c[3]])
        a_x = yv[c[6]]
        if k.C_K > 0.0 and math.isfinite(w_r) and math.isfinite(yv[c[4]]) and math.isfinite(a_x):
            f_zr = k.m * k.g * k.l_f / k.L + k.m * a_x * k.h / k.L
            s_r = (yv[c[4]] / k.r) / (k.C_K * _max(f_zr, 0.05 * k.m * k.g))
            v_x = w_r * k.r / (1.0 + s_r)
        elif math.isfinite(D[i, 0]):
            v_x = D[i, 0]
        elif math.isfinite(yv[c[10]]):
            v_x = yv[c[10]]
        else:
            v_x = w_r * k.r
        w_f = 0.5 * (yv[c[0]] + yv[c[1]])
        if not k.C_K > 0.0:
            w_f, a_x = 0.0, 0.0
        u[0], u[1], u[2], u[3], u[4] = yv[c[5]], v_x, w_f, a_x, yv[c[7]]
        # -- Stage2._step: what ends or restarts the window is the learner's
        if not math.isfinite(u[0] + u[1] + u[2] + u[3]) or G[i]:
            return i, x, P, sig, y_out, S_out, nr
        dt = t - ls[L_T_LAST]
        if dt <= 0 or dt > cfg[C_MAX_GAP]:
            return i, x, P, sig, y_out, S_out, nr
        n_us = int(ls[L_N_US])
        # the roll excitation of this sample (RollExcitation.step), kept aside until it is taken
        e_phi, e_w, e_chi, e_chi_d, e_u = ex[E_PHI], ex[E_W], ex[E_CHI], ex[E_CHI_D], ex[E_U]
        a_y = yv[c[7]]
        edt = t - ex[E_T]
        if edt > 0.0 and math.isfinite(a_y):
            u1 = ex[E_MH] * a_y
            u0 = u1 if math.isnan(e_u) else e_u
            e_u = u1
            e_phi, e_w, e_chi, e_chi_d = _roll_step(e_phi, e_w, e_chi, e_chi_d, u0, u1, ex[E_I], ex[E_C], ex[E_KP], edt)
        if n_us + 1 <= every:  # between filter steps: the input is kept for the next
            for q in range(5):
                us[n_us, q] = u[q]
            ls[L_N_US] = n_us + 1
            ls[L_SAMPLES] += 1
            ex[E_PHI], ex[E_W], ex[E_CHI], ex[E_CHI_D], ex[E_T], ex[E_U] = e_phi, e_w, e_chi, e_chi_d, t, e_u
            continue
        samples = ls[L_SAMPLES] + 1
        if samples % cfg[C_SAVE_EVERY] < every:  # the learner keeps a last-good copy after this step
            return i, x, P, sig, y_out, S_out, nr
        # -- Stage2.measurements
        z[0] = yv[c[8]] - D[i, 3]
        z[1] = yv[c[9]] - D[i, 4]
        z[2] = yv[c[7]]
        nrows = 0
        for q in range(3):
            if math.isfinite(z[q]):
                keep[nrows] = q
                nrows += 1
        n_step = max(1, math.ceil(dt / lateral.MAX_SUBSTEP - 1e-9))
        if nrows == 0 or n_step != nsub:
            return i, x, P, sig, y_out, S_out, nr
        for q in range(5):
            us[n_us, q] = u[q]
        steps_u = us[: n_us + 1]
        x1, P1, sig1, status = lat_predict(x, P, lam_n, Wm, Wc, Q, scale, kind, lo, span, dt, steps_u, j, w, nsub, k,
                                           consider)  # fmt: skip
        if status != OK:
            return i, x, P, sig, y_out, S_out, nr
        rows = keep[:nrows].copy()
        zs = np.empty(nrows)
        Rs = np.empty((nrows, nrows))
        for p in range(nrows):
            zs[p] = z[rows[p]]
            for q in range(nrows):
                Rs[p, q] = R[rows[p], rows[q]]
        x2, P2, yi, Si, status = lat_update(x1, P1, sig1, Wm, Wc, Rs, scale, kind, lo, span, zs, rows, u, k, consider)
        if status != OK:
            return i, x, P, sig, y_out, S_out, nr
        # -- Stage2._consistency, on copies until the step is taken
        has_roll = math.isfinite(z[1])
        r = (1 if math.isfinite(z[0]) else 0) if has_roll else -1  # the roll row's place in y
        nk = 0
        kept = np.empty(3, dtype=np.int64)
        for q in range(nrows):
            if not (cfg[C_ROLL_BY_AY] != 0.0 and q == r):
                kept[nk] = q
                nk += 1
        nis = _nis(yi, Si, kept, nk) if nk else 0.0
        if math.isnan(nis):
            return i, x, P, sig, y_out, S_out, nr
        ai = -1
        if math.isfinite(z[2]):
            ai = (1 if math.isfinite(z[0]) else 0) + (1 if has_roll else 0)
        has_e = ai >= 0 and Si[ai, ai] > 0
        e = yi[ai] / math.sqrt(Si[ai, ai]) if has_e else np.nan
        cons1, ring1 = cons.copy(), ring.copy()
        if nk:
            _cons_add(cons1, ring1, WINDOW, nis, nk, e, has_e)
            _cons_add(cons1, ring1, TOTAL, nis, nk, e, has_e)
        if r >= 0 and Si[r, r] > 0:
            e_r = yi[r] / math.sqrt(Si[r, r])
            _cons_add(cons1, ring1, ROLL_WINDOW, e_r * e_r, 1, e_r, True)
            _cons_add(cons1, ring1, ROLL_TOTAL, e_r * e_r, 1, e_r, True)
        if _recent(cons1, ring1, WINDOW) > cfg[C_DIVERGED]:
            return i, x, P, sig, y_out, S_out, nr
        # -- the step is taken
        cons[:, :] = cons1
        ring[:, :] = ring1
        ex[E_PHI], ex[E_W], ex[E_CHI], ex[E_CHI_D], ex[E_T], ex[E_U] = e_phi, e_w, e_chi, e_chi_d, t, e_u
        x, P, sig, y_out, S_out = x2, P2, sig1, yi, Si
        ls[L_SAMPLES] = samples
        ls[L_UPDATES] += 1
        rec[nr, 0], rec[nr, 1], rec[nr, 2], rec[nr, 3], rec[nr, 4] = t, u[0], u[1], u[2], u[3]
        rec[nr, 5], rec[nr, 6], rec[nr, 7] = z[0], z[2], z[1] if has_roll else np.nan
        nr += 1
        if has_roll:
            ls[L_ROLL_UPDATES] += 1
            jr = e_chi_d * e_chi_d / cfg[C_ROLL_DEN]
            ls[L_ROLL_INFO] += jr
            ls[L_INFO_WINDOW] += jr
        for q in range(5):
            us[0, q] = u[q]
        ls[L_N_US] = 1
        ls[L_T_LAST] = t
    return b, x, P, sig, y_out, S_out, nr


# -- stage 1: core.longitudinal -------------------------------------------------
@_jit
def _lon_slips(x, u, k):
    """longitudinal.slips of one SI state: eqs (3) and (14) with the bend and the offsets."""
    l_f, h = x[longitudinal.L_F], x[longitudinal.H]
    a_x = u[longitudinal.U_AX]
    mg = k.m * k.g
    shift = k.m * a_x * h / k.L
    lo_ = MIN_LOAD * mg
    f_zf = max(mg * (k.L - l_f) / k.L - shift, lo_)
    f_zr = max(mg * l_f / k.L + shift, lo_)
    f_xf = (u[longitudinal.U_TF] - k.J * u[longitudinal.U_WDF]) / k.r
    f_xr = (u[longitudinal.U_TR] - k.J * u[longitudinal.U_WDR]) / k.r
    c_k = max(x[longitudinal.C_K], 1e-3)
    if x.shape[0] > longitudinal.BEND:
        b, c, s0f, s0r = x[longitudinal.BEND], x[longitudinal.CUBIC], x[longitudinal.S_0F], x[longitudinal.S_0R]
    else:
        b, c, s0f, s0r = 0.0, 0.0, 0.0, 0.0
    u_f, u_r = f_xf / f_zf, f_xr / f_zr
    a_f, a_r = abs(u_f), abs(u_r)
    return s0f + u_f / c_k * (1.0 + b * a_f + c * a_f * a_f), s0r + u_r / c_k * (1.0 + b * a_r + c * a_r * a_r)


@_jit
def _lon_hx(x, u, k, out):
    """longitudinal.hx of one SI state: eq (13) on the slips."""
    s_f, s_r = _lon_slips(x, u, k)
    v = u[longitudinal.U_VX]
    out[0] = v * (1.0 + s_f) / k.r
    out[1] = v * (1.0 + s_r) / k.r


# stage 1's block (learner.Stage1._step), compiled: its settings array, and what became of the block
(B_SMALL_SLIP, B_SPIN_RATE, B_SPIN_SLIP, B_H_LO, B_H_HI, B_CORR) = range(6)
TAKEN, GATED, PREDICT_FAILED, UPDATE_FAILED = range(4)


@_jit
def lon_block(x, P, lam_n, Wm, Wc, Q, scale, kind, lo, span, k, ts, us, zs, dt, R0, prm):
    """Stage1._step's work on a full block of samples (ts, us, zs: their times, input and
    measurement rows): the block's means and wheel accelerations (a least-squares slope), the
    gates (a load share beyond the small-slip range, a wheel that spun or locked), the
    filter's predict over ``dt`` (the block's span), the block's R (wheel noise and the
    speed's common error) and the update.
    Returns (what became of it: TAKEN, GATED, PREDICT_FAILED or UPDATE_FAILED; the step's
    status; x, P, sigmas, y, S after it; the block's u, z, R).  Plain sums in order, so the
    per-sample learner and the compiled run (lon_run) give the same floats."""
    n = ts.shape[0]
    u = np.zeros(us.shape[1])
    z = np.zeros(2)
    tm = 0.0
    for i in range(n):
        tm += ts[i]
        for q in range(us.shape[1]):
            u[q] += us[i, q]
        z[0] += zs[i, 0]
        z[1] += zs[i, 1]
    tm /= n
    for q in range(us.shape[1]):
        u[q] /= n
    z[0] /= n
    z[1] /= n
    num_f = num_r = den = 0.0
    for i in range(n):
        kk = ts[i] - tm
        num_f += kk * (zs[i, 0] - z[0])
        num_r += kk * (zs[i, 1] - z[1])
        den += kk * kk
    u[longitudinal.U_WDF], u[longitudinal.U_WDR] = num_f / den, num_r / den
    nx = x.shape[0]
    R = np.empty((2, 2))
    y = np.zeros(2)
    S = np.zeros((2, 2))
    sig = np.empty((2 * nx + 1, nx))
    # Stage1._load_share at l_f and h held to their sane ranges
    t = np.empty(nx)
    si = np.empty(nx)
    for q in range(nx):
        t[q] = x[q] * scale[q]
    _to_si(t, kind, lo, span, si)
    h = min(max(si[longitudinal.H], prm[B_H_LO]), prm[B_H_HI])
    a_x = u[longitudinal.U_AX]
    mg = k.m * k.g
    shift = k.m * a_x * h / k.L
    f_zf = _max(mg * (k.L - si[longitudinal.L_F]) / k.L - shift, MIN_LOAD * mg)
    f_zr = _max(mg * si[longitudinal.L_F] / k.L + shift, MIN_LOAD * mg)
    f_xf = (u[longitudinal.U_TF] - k.J * u[longitudinal.U_WDF]) / k.r
    f_xr = (u[longitudinal.U_TR] - k.J * u[longitudinal.U_WDR]) / k.r
    if _max(abs(f_xf / f_zf), abs(f_xr / f_zr)) > prm[B_SMALL_SLIP]:
        return GATED, OK, x, P, sig, y, S, u, z, R
    # Stage1._spun
    if not math.isnan(prm[B_SPIN_RATE]):
        r, v = k.r, _max(u[longitudinal.U_VX], 1.0)
        if _max(abs(z[0] * r / v - 1.0), abs(z[1] * r / v - 1.0)) > prm[B_SPIN_SLIP]:
            return GATED, OK, x, P, sig, y, S, u, z, R
        dev = _max(abs(r * u[longitudinal.U_WDF] - a_x), abs(r * u[longitudinal.U_WDR] - a_x))
        if dev > prm[B_SPIN_RATE] * v:
            return GATED, OK, x, P, sig, y, S, u, z, R
    x1, P1, sig1, status = lon_predict(x, P, lam_n, Wm, Wc, Q, scale, dt)
    if status != OK:
        return PREDICT_FAILED, status, x, P, sig, y, S, u, z, R
    # Stage1._R at the predicted state
    for q in range(nx):
        t[q] = x1[q] * scale[q]
    _to_si(t, kind, lo, span, si)
    s_f, s_r = _lon_slips(si, u, k)
    c0, c1 = (1.0 + s_f) / k.r, (1.0 + s_r) / k.r
    e = u[longitudinal.U_VX_STD] * prm[B_CORR]
    e2 = e * e
    R[0, 0] = R0[0, 0] / n + c0 * c0 * e2
    R[0, 1] = R0[0, 1] / n + c0 * c1 * e2
    R[1, 0] = R0[1, 0] / n + c1 * c0 * e2
    R[1, 1] = R0[1, 1] / n + c1 * c1 * e2
    x2, P2, y2, S2, status = lon_update(x1, P1, sig1, Wm, Wc, R, scale, kind, lo, span, z, u, k)
    if status != OK:
        return UPDATE_FAILED, status, x1, P1, sig1, y, S, u, z, R
    return TAKEN, OK, x2, P2, sig1, y2, S2, u, z, R


# the stage-1 learner's scalars (ls1) and settings (cfg1) for lon_run
(A_SAMPLES, A_T_LAST, A_N_ACC, A_SINCE_BATCH, A_SINCE_FAR, A_GATED, A_BLOCKS) = range(7)
(D_MAX_GAP, D_BLOCK, D_SAVE_EVERY, D_EVERY, D_EVERY_MAX, D_BLOCKS_CAP) = range(6)


@_jit
def lon_run(T, Y, D, G, a, b, c, x, P, sig, lam_n, Wm, Wc, Q, scale, kind, lo, span, k, R0, prm, ls, cfg, acc,
            out_u, out_z, out_r):  # fmt: skip
    """Stage 1's samples a..b-1 of a block, in a window, as learner.Stage1._step takes them
    (inputs, blocks, lon_block), up to the first that needs the learner's own step: one that
    completes a block whose step fails, after which the batch check is due or a last-good copy
    is kept.  Nothing of that sample is taken.  Returns (its index, x, P, sig, y, S, blocks
    taken); ``ls``, ``acc`` (the open block's rows: t, u, z) are updated in place and the
    blocks taken written to out_u, out_z, out_r.  c: the channel indices (WS_FL, WS_FR,
    WS_RL, WS_RR, T_F, T_R, AX); D: the derived v_x, v_std, a_x bias."""
    block = int(cfg[D_BLOCK])
    nb = 0
    y = np.zeros(2)
    S = np.zeros((2, 2))
    u = np.empty(7)
    for i in range(a, b):
        t = T[i]
        yv = Y[i]
        # -- Stage1.inputs
        u[0], u[1], u[2], u[3], u[4], u[5], u[6] = yv[c[4]], yv[c[5]], yv[c[6]] - D[i, 2], D[i, 0], D[i, 1], 0.0, 0.0
        z0, z1 = 0.5 * (yv[c[0]] + yv[c[1]]), 0.5 * (yv[c[2]] + yv[c[3]])
        total = 0.0
        for q in range(7):
            total += u[q]
        if not math.isfinite(total + z0 + z1):
            continue
        n_acc = int(ls[A_N_ACC])
        if not math.isnan(ls[A_T_LAST]) and (G[i] or t - ls[A_T_LAST] > cfg[D_MAX_GAP]):
            n_acc = 0
        if n_acc + 1 < block:
            acc[n_acc, 0] = t
            for q in range(7):
                acc[n_acc, 1 + q] = u[q]
            acc[n_acc, 8], acc[n_acc, 9] = z0, z1
            ls[A_N_ACC] = n_acc + 1
            ls[A_T_LAST] = t
            ls[A_SAMPLES] += 1
            continue
        samples = ls[A_SAMPLES] + 1
        if samples % cfg[D_SAVE_EVERY] < block:  # a last-good copy after this block: the learner's
            return i, x, P, sig, y, S, nb
        acc[n_acc, 0] = t
        for q in range(7):
            acc[n_acc, 1 + q] = u[q]
        acc[n_acc, 8], acc[n_acc, 9] = z0, z1
        ts = acc[:block, 0]
        what, _, x1, P1, sig1, y1, S1, ub, zb, Rb = lon_block(
            x, P, lam_n, Wm, Wc, Q, scale, kind, lo, span, k, ts, acc[:block, 1:8], acc[:block, 8:10],
            ts[block - 1] - ts[0] + (ts[block - 1] - ts[0]) / (block - 1), R0, prm,
        )  # fmt: skip
        if what >= PREDICT_FAILED:  # (or UPDATE_FAILED): the learner raises it
            return i, x, P, sig, y, S, nb
        if what == TAKEN:
            blocks = min(ls[A_BLOCKS] + 1, cfg[D_BLOCKS_CAP])
            since = ls[A_SINCE_BATCH] + 1
            if since >= min(max(cfg[D_EVERY], blocks // 4), cfg[D_EVERY_MAX]):  # Stage1.check_due: the learner's
                return i, x, P, sig, y, S, nb
            x, P, sig, y, S = x1, P1, sig1, y1, S1
            out_u[nb] = ub
            out_z[nb] = zb
            out_r[nb] = Rb
            nb += 1
            ls[A_BLOCKS] = blocks
            ls[A_SINCE_BATCH] = since
            ls[A_SINCE_FAR] += 1
        else:
            ls[A_GATED] += 1
        ls[A_N_ACC] = 0
        ls[A_T_LAST] = t
        ls[A_SAMPLES] = samples
    return b, x, P, sig, y, S, nb


@_jit
def _lon_forces(U, k):
    """Each block's tyre forces (eq 2 solved, longitudinal.tyre_forces): they do not depend
    on the parameters, so the batch check takes them once per solve."""
    F = np.empty((U.shape[0], 2))
    for i in range(U.shape[0]):
        F[i, 0] = (U[i, longitudinal.U_TF] - k.J * U[i, longitudinal.U_WDF]) / k.r
        F[i, 1] = (U[i, longitudinal.U_TR] - k.J * U[i, longitudinal.U_WDR]) / k.r
    return F


@_jit
def _lon_rows(x, U, F, k, out):
    """_lon_hx on every block, what does not change from block to block taken once (the
    same operations on the same operands: the same floats)."""
    l_f, h = x[longitudinal.L_F], x[longitudinal.H]
    mg = k.m * k.g
    lo_ = MIN_LOAD * mg
    zf0 = mg * (k.L - l_f) / k.L
    zr0 = mg * l_f / k.L
    c_k = max(x[longitudinal.C_K], 1e-3)
    if x.shape[0] > longitudinal.BEND:
        b, c, s0f, s0r = x[longitudinal.BEND], x[longitudinal.CUBIC], x[longitudinal.S_0F], x[longitudinal.S_0R]
    else:
        b, c, s0f, s0r = 0.0, 0.0, 0.0, 0.0
    for i in range(U.shape[0]):
        shift = k.m * U[i, longitudinal.U_AX] * h / k.L
        u_f = F[i, 0] / max(zf0 - shift, lo_)
        u_r = F[i, 1] / max(zr0 + shift, lo_)
        a_f, a_r = abs(u_f), abs(u_r)
        s_f = s0f + u_f / c_k * (1.0 + b * a_f + c * a_f * a_f)
        s_r = s0r + u_r / c_k * (1.0 + b * a_r + c * a_r * a_r)
        v = U[i, longitudinal.U_VX]
        out[i, 0] = v * (1.0 + s_f) / k.r
        out[i, 1] = v * (1.0 + s_r) / k.r


@_jit
def lon_hx_rows(x, U, k):
    """longitudinal.hx of one SI state on many blocks' inputs, as the batch check evaluates it."""
    out = np.empty((U.shape[0], 2))
    _lon_rows(x, U, _lon_forces(U, k), k, out)
    return out


@_jit
def _lon_h(t, U, F, kind, lo, span, k, out):
    """longitudinal.hx of transformed parameters t on every block (the batch check's h)."""
    x = np.empty(t.shape[0])
    _to_si(t, kind, lo, span, x)
    _lon_rows(x, U, F, k, out)


@_jit
def _lon_cost(t, U, F, Z, W, prior_t, P0i, kind, lo, span, k):
    """core.batch.solve's cost: (data + prior term, data, residuals r = Z - h(t))."""
    r = np.empty(Z.shape)
    _lon_h(t, U, F, kind, lo, span, k, r)
    data = 0.0
    for i in range(Z.shape[0]):
        r0, r1 = Z[i, 0] - r[i, 0], Z[i, 1] - r[i, 1]
        r[i, 0], r[i, 1] = r0, r1
        data += r0 * (W[i, 0, 0] * r0 + W[i, 0, 1] * r1) + r1 * (W[i, 1, 0] * r0 + W[i, 1, 1] * r1)
    d = t - prior_t
    return data + d @ _mv(P0i, d), data, r


@_jit
def _lon_normal(t, base, r, U, F, W, P0i, prior_t, kind, lo, span, k, J, want_g):
    """H = J'WJ + P0^-1 and g = J'Wr - P0^-1 (t - t0), J by core.batch.solve's forward differences
    from ``base`` (its Z - r).  J'WJ is symmetric: its upper triangle, mirrored."""
    n = t.shape[0]
    N = U.shape[0]
    hp = np.empty((N, 2))
    tp = np.empty(n)
    for i in range(n):
        e = 1e-6 * max(1.0, abs(t[i]))
        tp[:] = t
        tp[i] += e
        _lon_h(tp, U, F, kind, lo, span, k, hp)
        for m in range(N):
            J[m, 0, i] = (hp[m, 0] - base[m, 0]) / e
            J[m, 1, i] = (hp[m, 1] - base[m, 1]) / e
    D = np.zeros((n, n))
    g = np.zeros(n)
    if want_g:
        g = -_mv(P0i, t - prior_t)
    for m in range(N):
        w00, w01, w10, w11 = W[m, 0, 0], W[m, 0, 1], W[m, 1, 0], W[m, 1, 1]
        for a in range(n):
            wa0 = J[m, 0, a] * w00 + J[m, 1, a] * w10  # (J' W)[a, 0]
            wa1 = J[m, 0, a] * w01 + J[m, 1, a] * w11
            for b in range(a, n):
                D[a, b] += wa0 * J[m, 0, b] + wa1 * J[m, 1, b]
            if want_g:
                g[a] += wa0 * r[m, 0] + wa1 * r[m, 1]
    for a in range(n):
        for b in range(a):
            D[a, b] = D[b, a]
    return D + P0i, g


@_jit
def _solve(A, b):
    """A x = b by Gaussian elimination with partial pivoting; (x, False) when A is singular."""
    n = A.shape[0]
    M = A.copy()
    x = b.copy()
    for c in range(n):
        p = c
        for q in range(c + 1, n):
            if abs(M[q, c]) > abs(M[p, c]):
                p = q
        if M[p, c] == 0.0:
            return x, False
        if p != c:
            for j in range(n):
                M[c, j], M[p, j] = M[p, j], M[c, j]
            x[c], x[p] = x[p], x[c]
        for q in range(c + 1, n):
            f = M[q, c] / M[c, c]
            if f != 0.0:
                for j in range(c, n):
                    M[q, j] -= f * M[c, j]
                x[q] -= f * x[c]
    for c in range(n - 1, -1, -1):
        s = x[c]
        for j in range(c + 1, n):
            s -= M[c, j] * x[j]
        x[c] = s / M[c, c]
    return x, True


@_jit
def lon_lm(t, U, Z, W, prior_t, P0i, iters, kind, lo, span, k):
    """core.batch.solve's Levenberg-Marquardt from one start on stage 1's model, step for step:
    (finite start, t, cost, data, r, H at the end)."""
    n = t.shape[0]
    J = np.empty((U.shape[0], 2, n))
    F = _lon_forces(U, k)
    c, data, r = _lon_cost(t, U, F, Z, W, prior_t, P0i, kind, lo, span, k)
    if not math.isfinite(c):
        return False, t, c, data, r, P0i
    lam = 1e-3
    for _ in range(iters):
        H, g = _lon_normal(t, Z - r, r, U, F, W, P0i, prior_t, kind, lo, span, k, J, True)
        step_ok = False
        dt = np.zeros(n)
        while lam < 1e8:
            A = H.copy()
            for i in range(n):
                A[i, i] += lam * H[i, i]
            dt, ok = _solve(A, g)
            if not ok:
                lam *= 10.0
                continue
            c2, data2, r2 = _lon_cost(t + dt, U, F, Z, W, prior_t, P0i, kind, lo, span, k)
            if math.isfinite(c2) and c2 <= c:
                t, c, data, r = t + dt, c2, data2, r2
                lam = max(lam / 10.0, 1e-9)
                step_ok = True
                break
            lam *= 10.0
        if not step_ok or np.max(np.abs(dt)) < 1e-7:
            break
    H, _ = _lon_normal(t, Z - r, r, U, F, W, P0i, prior_t, kind, lo, span, k, J, False)
    return True, t, c, data, r, H


def lon_solve(bounds, known: longitudinal.Known, U, Z, R, prior_t, prior_P, starts, iters: int = 30):
    """core.batch.solve on stage 1's own model (longitudinal.hx of bounds.to_si(t)), compiled:
    the same iterations, the same Fit."""
    kind, lo, span = transforms(bounds)
    k = lon_known(known)
    W = batch._inv2(R)
    P0i = np.linalg.inv(prior_P)
    U, Z = np.ascontiguousarray(U, dtype=float), np.ascontiguousarray(Z, dtype=float)
    n = len(prior_t)
    best = None
    for t in starts:
        ok, t, c, data, r, H = lon_lm(
            np.array(t, dtype=float), U, Z, W, np.asarray(prior_t, dtype=float), P0i, iters, kind, lo, span, k
        )
        if not ok:
            continue
        try:
            cov = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            continue
        if best is None or c < best[0]:
            best = (c, batch.Fit(t, 0.5 * (cov + cov.T), data, Z.size - n, batch.whiteness(r, W)))
    return None if best is None else best[1]


@_jit
def lon_predict(x, P, lam_n, Wm, Wc, Q, scale, dt):
    """core.filters.UKF.predict on longitudinal.fx (a random walk): (x, P, sigmas, status)."""
    m, nx = 2 * x.shape[0] + 1, x.shape[0]
    sig = np.empty((m, nx))
    if not _points(x, P, lam_n, sig):
        return x, P, sig, NOT_PD
    for i in range(m):
        for a in range(nx):
            sig[i, a] = sig[i, a] * scale[a] / scale[a]  # _fx_s: fx(xs * scale) / scale
    x, P, _ = _transform(sig, Wm, Wc, Q * dt)
    out = np.empty((m, nx))
    if not _points(x, P, lam_n, out):
        return x, P, out, NOT_PD
    P, status = _checked(x, P)
    return x, P, out, status


@_jit
def lon_update(x, P, sig, Wm, Wc, R, scale, kind, lo, span, z, u, k):
    """core.filters.UKF._update on longitudinal.hx, both rows: (x, P, y, S, status)."""
    m, nx = sig.shape
    hz = np.empty((m, 2))
    t = np.empty(nx)
    s = np.empty(nx)
    for i in range(m):
        for a in range(nx):
            t[a] = sig[i, a] * scale[a]
        _to_si(t, kind, lo, span, s)
        _lon_hx(s, u, k, hz[i])
    return _gain_step(x, P, sig, hz, z, R, Wm, Wc, -1)


# -- the filters: core.filters.UKF with its steps compiled ---------------------------


def _raise(step: str, status: int) -> None:
    """The numpy steps' FilterError: a linear-algebra failure names its step, the check does not."""
    raise FilterError(f"ukf {step}: {MESSAGES[status]}" if status < NON_FINITE else f"ukf: {MESSAGES[status]}")


class _CompiledUKF(UKF):
    """UKF whose predict and update run compiled (one call each); ``fx``/``hx`` stay the
    numpy model's (the reference), unused by the steps."""

    def __init__(self, x0, P0, Q_rate, R, scale, fx, hx, bounds, known, consider: int | None = None):
        super().__init__(x0, P0, Q_rate, R, scale, fx, hx, consider)
        self._kind, self._lo, self._span = transforms(bounds)
        self._c = -1 if consider is None else int(consider)
        self._Wm = np.ascontiguousarray(self._Wm)
        self._Wc = np.ascontiguousarray(self._Wc)
        self._known = known

    def _check(self) -> None:
        """(the compiled steps check their result themselves, as the numpy steps' _check does)"""


class LateralUKF(_CompiledUKF):
    """Stage 2's UKF (core.lateral) compiled."""

    _grids: typing.ClassVar[dict] = {}  # lateral._grid_weights per (rows, sub-steps), contiguous

    def __init__(self, x0, P0, Q_rate, R, scale, fx, hx, bounds, known: lateral.Known, consider=None):
        super().__init__(x0, P0, Q_rate, R, scale, fx, hx, bounds, lat_known(known), consider)

    @classmethod
    def _grid(cls, rows: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        g = cls._grids.get((rows, n))
        if g is None:
            if rows > 1:
                j, w = lateral._grid_weights(rows, n)
                g = (np.ascontiguousarray(j, dtype=np.int64), np.ascontiguousarray(w[:, 0]))
            else:
                g = (np.zeros(2 * n + 1, dtype=np.int64), np.zeros(2 * n + 1))
            cls._grids[(rows, n)] = g
        return g

    def _predict(self, dt: float, u) -> None:
        f = self._f
        us = np.asarray(u, dtype=float)
        if us.ndim == 1:
            us = us[None, :]
        n = max(1, math.ceil(dt / lateral.MAX_SUBSTEP - 1e-9))  # lateral.fx's sub-steps
        j, w = self._grid(len(us), n)
        x, P, sig, status = lat_predict(
            f.x, f.P, self._lam_n, self._Wm, self._Wc, self.Q_rate, self.scale,
            self._kind, self._lo, self._span, float(dt), us, j, w, n, self._known, self._c,
        )  # fmt: skip
        if status != OK:
            _raise("predict", status)
        f.x, f.P, self._sigmas = x, P, sig

    def _update(self, z, R, mask, u) -> None:
        f = self._f
        rows = np.flatnonzero(mask)
        x, P, y, S, status = lat_update(
            f.x, f.P, self._sigmas, self._Wm, self._Wc, np.ascontiguousarray(R, dtype=float), self.scale,
            self._kind, self._lo, self._span, np.asarray(z, dtype=float), rows,
            np.asarray(u, dtype=float), self._known, self._c,
        )  # fmt: skip
        if status != OK:
            _raise("update", status)
        f.x, f.P, f.y, f.S = x, P, y, S


class LongitudinalUKF(_CompiledUKF):
    """Stage 1's UKF (core.longitudinal) compiled."""

    def __init__(self, x0, P0, Q_rate, R, scale, fx, hx, bounds, known: longitudinal.Known, consider=None):
        super().__init__(x0, P0, Q_rate, R, scale, fx, hx, bounds, lon_known(known), consider)

    def _predict(self, dt: float, u) -> None:
        f = self._f
        x, P, sig, status = lon_predict(f.x, f.P, self._lam_n, self._Wm, self._Wc, self.Q_rate, self.scale, float(dt))
        if status != OK:
            _raise("predict", status)
        f.x, f.P, self._sigmas = x, P, sig

    def _update(self, z, R, mask, u) -> None:
        f = self._f
        x, P, y, S, status = lon_update(
            f.x, f.P, self._sigmas, self._Wm, self._Wc, np.ascontiguousarray(R, dtype=float), self.scale,
            self._kind, self._lo, self._span, np.asarray(z, dtype=float), np.asarray(u, dtype=float), self._known,
        )  # fmt: skip
        if status != OK:
            _raise("update", status)
        f.x, f.P, f.y, f.S = x, P, y, S


# -- stage 2's output-error fit (core.output_error.Problem) ---------------------
@_jit
def _oe_system(c_f, c_r, i_z, swing, d, cd, v, x0, alpha, phi_dd, l_f, l_r, m):
    """output_error._system at one point: (a11, a12, a21, a22, b1, b2)."""
    e = alpha - c_f * (cd / v)
    y0 = x0 + c_f * (d * cd)
    cr = c_r / v
    c1, c2 = (e - cr) / m, (e * l_f + cr * l_r) / m
    a0 = y0 / m + swing * phi_dd
    return c1, c2 - v, (l_f * e + l_r * cr) / i_z, (l_f * l_f * e - l_r * l_r * cr) / i_z, a0, l_f * y0 / i_z


@_jit
def oe_states(d, cd, v_x, x0, alpha, phi_dd, h, frac, first, theta, swing, bend_f, bend_r, l_f, L, m):
    """Problem._scan(Problem._maps(...)) as one sequential pass: (Phi, G) per row, (6, S, n).

    ``d`` ... ``phi_dd``: the _Pre of the steps (n_steps, 2 sub + 1); ``h`` (n_steps,) the
    sub-step; ``frac`` (2 sub + 1,) the points' place in it; ``first`` (n,) a window's first row
    (identity, zero); ``theta`` (S, 3) C_f, C_r, I_z; ``swing`` (S,); ``bend_f``/``bend_r`` (S, n)
    each axle's secant factor per row, linear between the rows (Problem._at_steps), or empty for
    the linear law.  Row i composes its step's map onto row i-1's, x_i = F x_i-1 + g:
    the prefix scan's products, associated left to right instead of in a tree."""
    S, n = theta.shape[0], first.shape[0]
    sub = (d.shape[1] - 1) // 2
    l_r = L - l_f
    bent = bend_f.shape[0] > 0
    out = np.empty((6, S, n))
    for s in range(S):
        i_z, sw = theta[s, 2], swing[s]
        p11, p12, p21, p22, q1, q2 = 1.0, 0.0, 0.0, 1.0, 0.0, 0.0
        j = -1  # the step reaching this row
        for i in range(n):
            if first[i]:
                p11, p12, p21, p22, q1, q2 = 1.0, 0.0, 0.0, 1.0, 0.0, 0.0
            else:
                j += 1
                hj = h[j]
                hh = 0.5 * hj * hj
                f11, f12, f21, f22, g1, g2 = 1.0, 0.0, 0.0, 1.0, 0.0, 0.0
                for k in range(sub):
                    p, q = 2 * k, 2 * k + 1  # the sub-step's start and midpoint (midpoint rule)
                    cf_p, cr_p, cf_q, cr_q = theta[s, 0], theta[s, 1], theta[s, 0], theta[s, 1]
                    if bent:
                        bf0, bf1, br0, br1 = bend_f[s, i - 1], bend_f[s, i], bend_r[s, i - 1], bend_r[s, i]
                        cf_p *= bf0 + frac[p] * (bf1 - bf0)
                        cr_p *= br0 + frac[p] * (br1 - br0)
                        cf_q *= bf0 + frac[q] * (bf1 - bf0)
                        cr_q *= br0 + frac[q] * (br1 - br0)
                    n11, n12, n21, n22, nb1, nb2 = _oe_system(
                        cf_p, cr_p, i_z, sw, d[j, p], cd[j, p], v_x[j, p], x0[j, p], alpha[j, p], phi_dd[j, p],
                        l_f, l_r, m,
                    )  # fmt: skip
                    m11, m12, m21, m22, mb1, mb2 = _oe_system(
                        cf_q, cr_q, i_z, sw, d[j, q], cd[j, q], v_x[j, q], x0[j, q], alpha[j, q], phi_dd[j, q],
                        l_f, l_r, m,
                    )  # fmt: skip
                    M11 = 1.0 + hj * m11 + hh * (m11 * n11 + m12 * n21)
                    M12 = hj * m12 + hh * (m11 * n12 + m12 * n22)
                    M21 = hj * m21 + hh * (m21 * n11 + m22 * n21)
                    M22 = 1.0 + hj * m22 + hh * (m21 * n12 + m22 * n22)
                    w1 = hj * mb1 + hh * (m11 * nb1 + m12 * nb2)
                    w2 = hj * mb2 + hh * (m21 * nb1 + m22 * nb2)
                    f11, f12, f21, f22 = (
                        M11 * f11 + M12 * f21,
                        M11 * f12 + M12 * f22,
                        M21 * f11 + M22 * f21,
                        M21 * f12 + M22 * f22,
                    )
                    g1, g2 = M11 * g1 + M12 * g2 + w1, M21 * g1 + M22 * g2 + w2
                p11, p12, p21, p22, q1, q2 = (
                    f11 * p11 + f12 * p21,
                    f11 * p12 + f12 * p22,
                    f21 * p11 + f22 * p21,
                    f21 * p12 + f22 * p22,
                    f11 * q1 + f12 * q2 + g1,
                    f21 * q1 + f22 * q2 + g2,
                )
            out[0, s, i], out[1, s, i], out[2, s, i], out[3, s, i] = p11, p12, p21, p22
            out[4, s, i], out[5, s, i] = q1, q2
    return out
