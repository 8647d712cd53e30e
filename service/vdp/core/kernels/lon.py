"""Stage 1's model (core.longitudinal): its predict and update, a block's step and the steps
over a run of samples (learner.Stage1.steps).
"""

from __future__ import annotations

import math

import numpy as np

from .. import longitudinal
from .base import MIN_LOAD, NOT_PD, OK, _jit, _max, _to_si
from .linalg import _checked, _gain_step, _points, _transform


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
