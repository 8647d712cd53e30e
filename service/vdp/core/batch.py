"""Batch least squares of stage 1's own model over the blocks its filter has seen.

Stage 1 is a parameter-only filter whose random walk is tiny, so the filter is a
recursive version of one nonlinear least-squares problem: the prior plus every
block's wheel-speed residual, weighted by the block's R.  A filter linearised far
from the answer can settle where the problem has no optimum (a prior 40 % off
left C_K 7 % low at 20 sigma on vdp's own simulator; on an independent car the
filter sat far from this optimum while a batch fit of the same model landed
close; docs/decisions/0004).  So the learner solves the batch problem from
several starts (the filter's estimate, the prior and a linear solution that
needs no start at all), compares, and re-seeds the filter when it is off.

The solution also measures how well the model explains the data: the weighted
residual per degree of freedom (reduced chi-square), which the learner uses to
inflate the std or flag a model mismatch.

Everything works on the bounded transform of the parameters (core.bounds).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import longitudinal


@dataclass(frozen=True)
class Fit:
    t: np.ndarray  # transformed parameters at the optimum
    cov: np.ndarray  # their covariance (inverse Gauss-Newton Hessian, prior included)
    cost: float  # data part of the cost: sum of weighted squared residuals
    dof: int  # residuals minus parameters
    rho: float = 0.0  # lag-1 autocorrelation of the whitened residuals (0: white)

    @property
    def chi2(self) -> float:
        """Reduced chi-square of the data."""
        return self.cost / max(self.dof, 1)


def _inv2(R: np.ndarray) -> np.ndarray:
    """Inverses of a stack of 2x2 matrices."""
    a, b, c, d = R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1]
    det = a * d - b * c
    out = np.empty_like(R)
    out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1] = d / det, -b / det, -c / det, a / det
    return out


def _jt_w(J: np.ndarray, W: np.ndarray, X: np.ndarray) -> np.ndarray:
    """sum over blocks of J_n' W_n X_n (X: (N, m, k) or (N, m)): einsum's own loop over the
    three operands took ~0.6 ms per call at 3000 blocks, a fifth of a replay's CPU."""
    WX = W @ X if X.ndim == 3 else (W @ X[:, :, None])[..., 0]
    return np.tensordot(J, WX, axes=([0, 1], [0, 1]))


def damped_step(H: np.ndarray, g: np.ndarray, cost: Callable[[np.ndarray], tuple], x: np.ndarray, c: float, lam: float):
    """One Levenberg-Marquardt step from ``x`` (cost ``c``): (step, cost(x + step), lam) for the
    first damping whose step does not raise the cost (``cost(.)[0]``), the damping then eased;
    (None, None, lam) when none below 1e8 does.  Stage 1's and stage 2's batch fits share it."""
    while lam < 1e8:
        try:
            step = np.linalg.solve(H + lam * np.diag(np.diag(H)), g)
        except np.linalg.LinAlgError:
            lam *= 10.0
            continue
        out = cost(x + step)
        if np.isfinite(out[0]) and out[0] <= c:
            return step, out, max(lam / 10.0, 1e-9)
        lam *= 10.0
    return None, None, lam


def solve(
    h: Callable[[np.ndarray, np.ndarray], np.ndarray],
    U: np.ndarray,
    Z: np.ndarray,
    R: np.ndarray,
    prior_t: np.ndarray,
    prior_P: np.ndarray,
    starts: list[np.ndarray],
    iters: int = 30,
) -> Fit | None:
    """Levenberg-Marquardt on sum r' R^-1 r + (t - t0)' P0^-1 (t - t0) from each start; the best.

    ``h(t, U)`` maps transformed parameters (shape (n,)) and all blocks' inputs to
    the predicted measurements (N, m).  None when no start gives a finite cost.
    """
    W = _inv2(R)
    P0i = np.linalg.inv(prior_P)
    n = len(prior_t)

    def cost(t):
        r = Z - h(t, U)
        data = float(np.einsum("ni,nij,nj->", r, W, r))
        d = t - prior_t
        return data + float(d @ P0i @ d), data, r

    def jac(t, base):
        J = np.empty(base.shape + (n,))
        for i in range(n):
            e = 1e-6 * max(1.0, abs(t[i]))
            tp = t.copy()
            tp[i] += e
            J[..., i] = (h(tp, U) - base) / e
        return J

    best = None
    for t in starts:
        t = np.array(t, dtype=float)
        c, data, r = cost(t)
        if not np.isfinite(c):
            continue
        lam = 1e-3
        for _ in range(iters):
            pred = Z - r
            J = jac(t, pred)
            H = _jt_w(J, W, J) + P0i
            g = _jt_w(J, W, r) - P0i @ (t - prior_t)
            dt, out, lam = damped_step(H, g, cost, t, c, lam)
            if out is None:
                break
            t, (c, data, r) = t + dt, out
            if np.max(np.abs(dt)) < 1e-7:
                break
        J = jac(t, Z - r)
        H = _jt_w(J, W, J) + P0i
        try:
            cov = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            continue
        if best is None or c < best[0]:
            best = (c, Fit(t, 0.5 * (cov + cov.T), data, Z.size - n, whiteness(r, W)))
    return None if best is None else best[1]


def whiteness(r: np.ndarray, W: np.ndarray) -> float:
    """Lag-1 autocorrelation of the front-minus-rear residual.

    A model that explains the data leaves white residuals (about 0); one that misses a
    force leaves them following the manoeuvre (towards 1), and then the blocks are not
    independent evidence: the data's information is overstated by about (1 + rho) / (1 - rho).
    """
    if len(r) < 3:
        return 0.0
    # front minus rear: the speed's slowly varying error, common to both axles, cancels
    e = r[:, 0] - r[:, 1]
    e = e - e.mean()
    num = float(np.sum(e[1:] * e[:-1]))
    den = float(np.sum(e * e))
    return num / den if den > 0 else 0.0


def linear_start(U: np.ndarray, Z: np.ndarray, k: longitudinal.Known) -> np.ndarray | None:
    """(l_f, h, C_K) from a linear least-squares fit that needs no starting point, or None.

    With p = (C_K, C_K l_f, C_K h), eqs (3) and (14) are linear in p for measured
    slips (eq 13 inverted with the speed v_x):
    front  s_f (m g p1 - m g p2 / L - m a_x p3 / L) = F_xf,
    rear   s_r (m g p2 / L + m a_x p3 / L) = F_xr.
    The slips are noisy on the left-hand side (errors in variables), so this is
    only a start for the nonlinear fit.
    """
    v = U[:, longitudinal.U_VX]
    ok = v > 1.0
    if ok.sum() < 10:
        return None
    U, Z, v = U[ok], Z[ok], v[ok]
    s_f = Z[:, 0] * k.r / v - 1.0
    s_r = Z[:, 1] * k.r / v - 1.0
    f_xf, f_xr = longitudinal.tyre_forces(U, k)
    mg, ma = k.m * k.g, k.m * U[:, longitudinal.U_AX]
    A = np.concatenate(
        [
            np.stack([s_f * mg, -s_f * mg / k.L, -s_f * ma / k.L], axis=1),
            np.stack([np.zeros_like(s_r), s_r * mg / k.L, s_r * ma / k.L], axis=1),
        ]
    )
    b = np.concatenate([f_xf, f_xr])
    # rows scaled to unit force: the two axles' equations count alike
    w = 1.0 / np.maximum(np.abs(b), 0.05 * mg)
    try:
        p, *_ = np.linalg.lstsq(A * w[:, None], b * w, rcond=None)
    except np.linalg.LinAlgError:
        return None
    if not p[0] > 0:
        return None
    l_f, h = p[1] / p[0], p[2] / p[0]
    if not (0.0 < l_f < k.L and h > 0.0):
        return None
    return np.array([l_f, h, p[0]])
