"""The filters as filterpy's generic steps run them: the reference for vdp.core.filters.

This is vdp's UKF and EKF as they were built on filterpy's UnscentedKalmanFilter
(MerweScaledSigmaPoints) and ExtendedKalmanFilter; vdp.core.filters now writes
the same steps out (tests/test_filters.py compares the two, step by step and over
whole drives).  Same constructor and interface.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter, MerweScaledSigmaPoints, UnscentedKalmanFilter, unscented_transform
from scipy.linalg import LinAlgError

from vdp.core.filters import transition
from vdp.errors import FilterError


def _chol_upper(A: np.ndarray) -> np.ndarray:
    """Upper Cholesky factor (filterpy takes the rows of U with U^T U = A); numpy's is faster than scipy's."""
    try:
        return np.linalg.cholesky(A).T
    except np.linalg.LinAlgError as exc:
        raise LinAlgError(str(exc)) from None


class _PaperPoints(MerweScaledSigmaPoints):
    """filterpy's scaled sigma points, built in three array operations.

    Same points in the same order (x, then x + U_k, then x - U_k for the rows of
    the upper Cholesky factor U of (lambda + n) P); filterpy fills them row by row.
    """

    def sigma_points(self, x, P):
        n = self.n
        U = self.sqrt((self.alpha**2 * (n + self.kappa)) * P)  # lambda + n = alpha^2 (n + kappa)
        return np.concatenate((x[None, :], x + U, x - U))


def paper_points(n: int) -> MerweScaledSigmaPoints:
    """Sigma points of Table 3: alpha = 0.01, beta = 2, kappa = 3 - L."""
    return _PaperPoints(n, alpha=0.01, beta=2.0, kappa=3.0 - n, sqrt_method=_chol_upper)


class _VectorUKF(UnscentedKalmanFilter):
    """filterpy's UKF with the sigma points pushed through fx/hx in one call.

    fx(sigmas, dt, **kw) and hx(sigmas, **kw) take an (n_sigma, dim) array; this
    replaces filterpy's per-point Python loop, which dominates the cost.
    """

    consider: int | None = None  # index of a consider state (module docstring)

    def compute_process_sigmas(self, dt, fx=None, **fx_args):
        fx = self.fx if fx is None else fx
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        self.sigmas_f = fx(sigmas, dt, **fx_args)

    def update_masked(self, z, R, mask, **hx_args):
        sigmas_h = self.hx(self.sigmas_f, **hx_args)[:, mask]
        zp, S = unscented_transform(sigmas_h, self.Wm, self.Wc, R)
        dx = self.sigmas_f - self.x
        dz = sigmas_h - zp
        Pxz = np.einsum("i,ij,ik->jk", self.Wc, dx, dz)
        self.S = S
        self.SI = np.linalg.inv(S)
        self.K = K = Pxz @ self.SI
        self.y = z - zp
        if self.consider is None:
            self.x = self.x + K @ self.y
            self.P = self.P - K @ S @ K.T
            return
        K[self.consider] = 0.0
        self.x = self.x + K @ self.y
        KPxz = K @ Pxz.T
        self.P = self.P - KPxz - KPxz.T + K @ S @ K.T


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
        try:
            self._update(np.asarray(z)[mask], R[np.ix_(mask, mask)], mask, u)
        except (LinAlgError, ValueError, FloatingPointError) as exc:
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
    kind = "ukf"

    def __init__(self, x0, P0, Q_rate, R, scale, fx, hx, consider: int | None = None):
        n = len(x0)
        self._f = _VectorUKF(dim_x=n, dim_z=len(R), dt=0.01, hx=None, fx=None, points=paper_points(n))
        super().__init__(x0, P0, Q_rate, R, scale, fx, hx, consider)
        self._f.consider = consider
        self._f.fx = self._fx_s
        self._f.hx = self._hx_s

    def predict(self, dt: float, u) -> None:
        f = self._f
        f.Q = self.Q_rate * dt
        c = self.consider
        held = None if c is None else f.x[c]
        try:
            f.predict(dt=dt, u=u)
        except (LinAlgError, ValueError, FloatingPointError) as exc:
            raise FilterError(f"ukf predict: {exc}") from None
        if c is not None:
            f.x[c] = held  # the weighted mean returns it only to rounding (weights of ~1e4, both signs)
        self._check()

    def _update(self, z, R, mask, u) -> None:
        # (every update follows a predict, which draws fresh sigma points)
        self._f.update_masked(z, R, mask, u=u)


class _ModelEKF(ExtendedKalmanFilter):
    """filterpy's EKF with a nonlinear state prediction (predict_x is its hook)."""

    fx_step: Callable = None

    def predict_x(self, u=0):
        self.x = self.fx_step(self.x, u)


class EKF(JointFilter):
    """EKF baseline (Table 5): analytic Jacobians; F = exp(A dt) of the linearisation.

    exp(A dt) is taken as a third-order Taylor step of h = dt / 8, raised to the
    8th power by squaring: the fastest mode (roll, ~70 1/s) has |lambda h| < 0.1
    there, and scipy's expm is ~50x slower on these badly scaled matrices.
    """

    kind = "ekf"

    def __init__(self, x0, P0, Q_rate, R, scale, fx, hx, jac_f, jac_h, consider: int | None = None):
        n = len(x0)
        self._f = _ModelEKF(dim_x=n, dim_z=len(R))
        super().__init__(x0, P0, Q_rate, R, scale, fx, hx, consider)
        self._jac_f, self._jac_h = jac_f, jac_h
        self._dt = 0.01

    def predict(self, dt: float, u) -> None:
        f = self._f
        x = self.x
        A = self._jac_f(x, u)
        # scaled coordinates: A_s = S^-1 A S
        A_s = A * self.scale[None, :] / self.scale[:, None]
        try:
            f.F = transition(A_s, dt)
            f.Q = self.Q_rate * dt
            f.fx_step = lambda xs, uu: self._fx_s(xs, dt, uu)
            f.predict(u=u)
        except (LinAlgError, ValueError, FloatingPointError) as exc:
            raise FilterError(f"ekf predict: {exc}") from None
        self._check()

    def _update(self, z, R, mask, u) -> None:
        def H(xs):
            return (self._jac_h(xs * self.scale, u) * self.scale[None, :])[mask]

        def h(xs):
            return self._hx_s(xs, u)[mask]

        if self.consider is None:
            self._f.update(z, H, h, R=R)
            return
        # filterpy's update with the consider row of the gain zeroed; Joseph form holds for any gain
        f = self._f
        Hx = H(f.x)
        S = Hx @ f.P @ Hx.T + R
        K = f.P @ Hx.T @ np.linalg.inv(S)
        K[self.consider] = 0.0
        f.y, f.S = z - h(f.x), S
        f.x = f.x + K @ f.y
        IKH = np.eye(len(f.x)) - K @ Hx
        f.P = IKH @ f.P @ IKH.T + K @ R @ K.T
