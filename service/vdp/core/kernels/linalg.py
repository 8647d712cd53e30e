"""The UKF's linear algebra (core.filters.UKF), compiled: Cholesky, sigma points, the
unscented transform, the gain step.  Loops, not BLAS: the matrices are at most 10 x 10.
"""

from __future__ import annotations

import math

import numpy as np

from .base import LOST_PD, NON_FINITE, OK, SINGULAR, _jit


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
