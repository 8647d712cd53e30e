"""Stage 2's model (core.lateral) on scaled, bounded sigma points, its predict and update,
and its steps over a run of samples (learner.Stage2.steps).
"""

from __future__ import annotations

import math

import numpy as np

from .. import lateral
from .base import F0, F1, F2, F3, FREE, NOT_PD, OK, _geometry, _jit, _max, _pre, _rates, _roll_map, _to_si
from .linalg import _checked, _gain_step, _points, _transform


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
    """lateral.fx of one SI state on the input constants ``g`` of n sub-steps (in place); a state of
    ten carries the road's bank (lateral.BANK: eq 5's g sin(bank), held over the step)."""
    h = dt / n
    v_y, yaw, phi, phi_d = x[lateral.V_Y], x[lateral.YAW], x[lateral.PHI], x[lateral.PHI_D]
    bank = x[lateral.BANK] if x.shape[0] > lateral.BANK else 0.0  # (x - 0.0 is x, to the bit)
    c_f, c_r, i_z, i_x = _lat_params(x, k)
    geo = _geometry(x[lateral.L_F], k)
    T, p, q = _roll_map(i_x, h, k)
    t11, t12, t21, t22 = T
    p1, p2 = p
    q1, q2 = q
    start = _rates(v_y, yaw, c_f, c_r, i_z, _row(g, 0), geo, k, _max)
    for i in range(n):
        vy_d, yaw_d, a0 = start[0] - bank, start[1], start[2]
        if math.isfinite(g[2 * i, 6]):  # eq (9) driven by the measured a_y (lateral.fx's ``ays``)
            a0 = g[2 * i, 6]
        mid = _rates(v_y + h / 2 * vy_d, yaw + h / 2 * yaw_d, c_f, c_r, i_z, _row(g, 2 * i + 1), geo, k, _max)
        v_y = v_y + h * (mid[0] - bank)
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
