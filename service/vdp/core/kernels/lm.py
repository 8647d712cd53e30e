"""Stage 1's batch check (core.batch.solve on longitudinal.hx), compiled: Levenberg-Marquardt."""

from __future__ import annotations

import math

import numpy as np

from .. import batch, longitudinal
from .base import MIN_LOAD, _jit, _to_si, lon_known, transforms
from .linalg import _mv


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
