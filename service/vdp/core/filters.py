"""UKF and EKF for a joint state-parameter model.

Both filters work on the state divided by the model's ``SCALE`` so that a state
of metres next to one of 6e4 N/rad keeps a well-conditioned covariance; the
model functions always see SI values.

The UKF uses the paper's sigma points (Table 3): alpha = 0.01, beta = 2,
kappa = 3 - L.  With alpha this small the weights are large and of both signs,
so the covariance is symmetrised after every step and a failed Cholesky or a
non-finite state raises :class:`FilterError`; the learner then resets.

A *consider* state (Schmidt-Kalman) is one the update never moves: it enters the
model with its prior uncertainty, which the covariance carries into the other
states, but the measurements are not allowed to re-estimate it.  Its gain row is
zero, so the covariance update takes the general form for any gain,
P - K Pxz^T - Pxz K^T + K S K^T (with an optimal gain it reduces to P - K S K^T).

The steps are filterpy's (UnscentedKalmanFilter with MerweScaledSigmaPoints,
ExtendedKalmanFilter), written out for this use: the sigma points go through the
model in one vectorised call, the weights are computed once, and nothing is
copied that the next step does not read.  filterpy's own generic steps cost
several times the model's evaluation here (Python per call, copies of every
prior and posterior); tests/helpers/filterpy_ref.py keeps them as the reference
the tests compare these against (tests/test_filters.py).  Importing filterpy
also imports scipy.stats (0.8 s of start-up), which no step needs.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..errors import FilterError

# the paper's sigma-point parameters (Table 3); kappa = 3 - L
ALPHA, BETA = 0.01, 2.0


def paper_weights(n: int) -> tuple[float, np.ndarray, np.ndarray]:
    """(lambda + n, Wm, Wc) of the scaled sigma points, as filterpy's MerweScaledSigmaPoints
    computes them (the same expressions, so the same floats)."""
    kappa = 3.0 - n
    lam = ALPHA**2 * (n + kappa) - n
    c = 0.5 / (n + lam)
    Wc = np.full(2 * n + 1, c)
    Wm = np.full(2 * n + 1, c)
    Wc[0] = lam / (n + lam) + (1 - ALPHA**2 + BETA)
    Wm[0] = lam / (n + lam)
    return ALPHA**2 * (n + kappa), Wm, Wc


class _State:
    """A filter's working state in scaled coordinates, and its last innovation (y, S)."""

    __slots__ = ("P", "S", "x", "y")

    def __init__(self):
        self.x = self.P = self.y = self.S = None


class JointFilter:
    """Common face of the UKF and the EKF: predict(dt, u), update(z, mask, u).

    ``fx(x, dt, u)``, ``hx(x, u)`` are the model's functions in SI units with the
    known constants already bound; ``jac_f(x, u)`` (continuous A) and
    ``jac_h(x, u)`` are needed by the EKF only.
    """

    kind = "base"

    def __init__(self, x0, P0, Q_rate, R, scale, fx: Callable, hx: Callable, consider: int | None = None):
        self.consider = consider  # index of a consider state (module docstring), or None
        self.scale = np.asarray(scale, dtype=float)
        self._scale2 = np.outer(self.scale, self.scale)
        self.Q_rate = np.asarray(Q_rate, dtype=float) / self._scale2
        self.R = np.asarray(R, dtype=float)
        self._fx, self._hx = fx, hx
        self._set(np.asarray(x0, dtype=float), np.asarray(P0, dtype=float))

    # -- state in SI ---------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        return self._f.x * self.scale

    @property
    def P(self) -> np.ndarray:
        return self._f.P * self._scale2

    def set_state(self, x, P) -> None:
        self._set(np.asarray(x, dtype=float), np.asarray(P, dtype=float))

    def _set(self, x, P):
        self._f.x = x / self.scale
        self._f.P = P / self._scale2

    def _check(self) -> None:
        f = self._f
        f.P = 0.5 * (f.P + f.P.T)
        # one reduction catches NaN and inf anywhere in x or P
        if not math.isfinite(float(f.x.sum()) + float(f.P.sum())):
            raise FilterError(f"{self.kind}: non-finite state or covariance")
        if np.diagonal(f.P).min() <= 0.0:
            raise FilterError(f"{self.kind}: covariance lost positive definiteness")
        if self.kind == "ukf":
            return  # its next sigma points take the Cholesky factor, and fail on an indefinite P
        try:  # a positive diagonal is not enough (the EKF's update keeps it while P turns indefinite)
            np.linalg.cholesky(f.P)
        except np.linalg.LinAlgError:
            raise FilterError(f"{self.kind}: covariance lost positive definiteness") from None

    def update(self, z, mask, u, R=None) -> None:
        """Measurement update with the rows in ``mask`` (a sensor may be missing or not new)."""
        mask = np.asarray(mask, dtype=bool)
        if not mask.any():
            return
        R = self.R if R is None else R
        z = np.asarray(z)
        if not mask.all():  # (the selection costs as much as a Cholesky factor: not when all rows are in)
            z, R = z[mask], R[np.ix_(mask, mask)]
        try:
            self._update(z, R, mask, u)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            raise FilterError(f"{self.kind} update: {exc}") from None
        self._check()

    def _update(self, z, R, mask, u) -> None:
        raise NotImplementedError

    def innovation(self) -> tuple[np.ndarray, np.ndarray]:
        """(y, S) of the last update: the innovation of the rows used and its predicted covariance."""
        return np.atleast_1d(self._f.y), np.atleast_2d(self._f.S)

    # scaled wrappers of the model
    def _fx_s(self, xs, dt, u):
        return self._fx(xs * self.scale, dt, u) / self.scale

    def _hx_s(self, xs, u):
        return self._hx(xs * self.scale, u)


class UKF(JointFilter):
    """filterpy's UnscentedKalmanFilter step by step, with the sigma points pushed through
    fx/hx in one call each: fx(sigmas, dt, u) and hx(sigmas, u) take an (n_sigma, dim) array."""

    kind = "ukf"

    def __init__(self, x0, P0, Q_rate, R, scale, fx, hx, consider: int | None = None):
        self._f = _State()
        self._lam_n, self._Wm, self._Wc = paper_weights(len(x0))
        self._Wc_col = self._Wc[:, None]
        self._sigmas: np.ndarray | None = None
        super().__init__(x0, P0, Q_rate, R, scale, fx, hx, consider)

    def _points(self, x, P) -> np.ndarray:
        """x, then x + U_k, then x - U_k for the rows of the upper Cholesky factor U of (lambda + n) P."""
        U = np.linalg.cholesky(self._lam_n * P).T
        return np.concatenate((x[None, :], x + U, x - U))

    def _transform(self, sigmas, noise) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(mean, covariance + noise, deviations) of transformed sigma points (filterpy's
        unscented_transform: the same products in the same order)."""
        mean = self._Wm @ sigmas
        d = sigmas - mean[None, :]
        return mean, d.T @ (self._Wc_col * d) + noise, d

    def predict(self, dt: float, u) -> None:
        self._predict(dt, u)

    def _predict(self, dt: float, u) -> None:
        # (the step itself: core.kernels' compiled filters replace this, not predict)
        f = self._f
        c = self.consider
        held = None if c is None else f.x[c]
        try:
            sigmas = self._fx_s(self._points(f.x, f.P), dt, u)
            f.x, f.P, _ = self._transform(sigmas, self.Q_rate * dt)
            # filterpy draws the update's points afresh from the predicted x and P
            self._sigmas = self._points(f.x, f.P)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            raise FilterError(f"ukf predict: {exc}") from None
        if c is not None:
            f.x[c] = held  # the weighted mean returns it only to rounding (weights of ~1e4, both signs)
        self._check()

    def _update(self, z, R, mask, u) -> None:
        # (every update follows a predict, which drew the points)
        f = self._f
        sigmas = self._sigmas
        zp, S, dz = self._transform(self._hx_s(sigmas, u)[:, mask], R)
        Pxz = (sigmas - f.x).T @ (self._Wc_col * dz)
        K = Pxz @ np.linalg.inv(S)
        f.y = z - zp
        f.S = S
        if self.consider is None:
            f.x = f.x + K @ f.y
            f.P = f.P - K @ S @ K.T
            return
        K[self.consider] = 0.0
        f.x = f.x + K @ f.y
        KPxz = K @ Pxz.T
        f.P = f.P - KPxz - KPxz.T + K @ S @ K.T


def transition(A: np.ndarray, dt: float) -> np.ndarray:
    """exp(A dt) by eight third-order Taylor steps (see EKF)."""
    n = len(A)
    if not np.any(A):
        return np.eye(n)
    Ah = A * (dt / 8.0)
    Ah2 = Ah @ Ah
    M = np.eye(n) + Ah + Ah2 / 2.0 + (Ah2 @ Ah) / 6.0
    for _ in range(3):
        M = M @ M
    return M


class EKF(JointFilter):
    """EKF baseline (Table 5): analytic Jacobians; F = exp(A dt) of the linearisation.

    exp(A dt) is taken as a third-order Taylor step of h = dt / 8, raised to the
    8th power by squaring: the fastest mode (roll, ~70 1/s) has |lambda h| < 0.1
    there, and scipy's expm is ~50x slower on these badly scaled matrices.
    """

    kind = "ekf"

    def __init__(self, x0, P0, Q_rate, R, scale, fx, hx, jac_f, jac_h, consider: int | None = None):
        self._f = _State()
        super().__init__(x0, P0, Q_rate, R, scale, fx, hx, consider)
        self._jac_f, self._jac_h = jac_f, jac_h
        self._eye = np.eye(len(x0))

    def predict(self, dt: float, u) -> None:
        f = self._f
        A = self._jac_f(self.x, u)
        # scaled coordinates: A_s = S^-1 A S
        A_s = A * self.scale[None, :] / self.scale[:, None]
        try:
            F = transition(A_s, dt)
            f.x = self._fx_s(f.x, dt, u)  # the nonlinear prediction, not F x
            f.P = (F @ f.P) @ F.T + self.Q_rate * dt
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            raise FilterError(f"ekf predict: {exc}") from None
        self._check()

    def _update(self, z, R, mask, u) -> None:
        f = self._f
        H = (self._jac_h(f.x * self.scale, u) * self.scale[None, :])[mask]
        PHT = f.P @ H.T
        S = H @ PHT + R
        K = PHT @ np.linalg.inv(S)
        f.y, f.S = z - self._hx_s(f.x, u)[mask], S
        if self.consider is not None:
            K[self.consider] = 0.0  # the Joseph form below holds for any gain
        f.x = f.x + K @ f.y
        IKH = self._eye - K @ H
        f.P = (IKH @ f.P) @ IKH.T + (K @ R) @ K.T
