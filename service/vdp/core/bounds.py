"""Physical bounds held by the filters themselves: they estimate bounded transforms.

A parameter that must be positive (h, stiffnesses, inertias) is estimated as its
logarithm; l_f, which must lie inside the wheelbase, as the logit of l_f / L.
Whatever the update does to the transformed value, the model sees a physical
one: no prior and no bad step can send l_f to 41 m or an inertia below zero.

The models keep working in SI units.  :class:`Bounds` maps a filter state ``t``
to the model's ``x`` and back, and carries a Jacobian through the chain rule
(every map is elementwise, so ``dx/dt`` is a diagonal ``D``); a covariance maps
as ``D P D`` (first order: the std of a log-parameter is the relative std).

The transformed entries must be constants of the model's transition (random-walk
parameters); the others pass through unchanged.
"""

from __future__ import annotations

import numpy as np

EDGE = 1e-9  # keeps a transform of a value on its bound finite
LOGIT_MAX = 30.0  # |logit| beyond this would round the value onto its bound


def _slice(idx: np.ndarray):
    """A slice for sorted contiguous indices, else the index array itself."""
    if idx.size and np.all(np.diff(idx) == 1):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


class Bounds:
    """Elementwise transforms of a state: ``log`` indices (x > 0) and ``logit`` ones (lo < x < hi)."""

    def __init__(self, n: int, log: tuple[int, ...] = (), logit: dict[int, tuple[float, float]] | None = None):
        logit = logit or {}
        self.n = n
        self.log = np.array(sorted(log), dtype=int)
        self.logit = np.array(sorted(logit), dtype=int)
        self.lo = np.array([logit[i][0] for i in self.logit], dtype=float)
        self.span = np.array([logit[i][1] - logit[i][0] for i in self.logit], dtype=float)
        fixed = np.ones(n, dtype=bool)
        fixed[self.log] = False
        fixed[self.logit] = False
        self.free = np.flatnonzero(fixed)  # untransformed indices
        self.transformed = ~fixed
        # contiguous index sets as slices: numpy's fancy indexing costs more than the arithmetic here
        self._log = _slice(self.log)
        self._logit = _slice(self.logit)
        self._free = _slice(self.free)

    def to_si(self, t):
        t = np.asarray(t, dtype=float)
        x = t.copy()
        if self.log.size:
            x[..., self._log] = np.exp(t[..., self._log])  # > 709 is inf: the filter's check catches it
        if self.logit.size:
            q = np.minimum(np.maximum(t[..., self._logit], -LOGIT_MAX), LOGIT_MAX)
            x[..., self._logit] = self.lo + self.span / (1.0 + np.exp(-q))
        return x

    def from_si(self, x):
        x = np.asarray(x, dtype=float)
        t = x.copy()
        if self.log.size:
            t[..., self.log] = np.log(np.maximum(x[..., self.log], EDGE))
        if self.logit.size:
            q = np.clip((x[..., self.logit] - self.lo) / self.span, EDGE, 1.0 - EDGE)
            t[..., self.logit] = np.log(q / (1.0 - q))
        return t

    def grad(self, t):
        """dx/dt elementwise (the diagonal of D)."""
        t = np.asarray(t, dtype=float)
        d = np.ones_like(t)
        if self.log.size:
            d[..., self._log] = np.exp(t[..., self._log])
        if self.logit.size:
            q = 1.0 / (1.0 + np.exp(-np.minimum(np.maximum(t[..., self._logit], -LOGIT_MAX), LOGIT_MAX)))
            d[..., self._logit] = self.span * q * (1.0 - q)
        return d

    def cov_to_si(self, t, P):
        d = self.grad(t)
        return P * np.outer(d, d)

    # -- model functions seen through the transform ---------------------------
    def wrap_fx(self, fx):
        """fx on transformed states: the transformed entries are constants of fx, kept as they are."""
        free = self._free

        def f(t, dt, u):
            y = fx(self.to_si(t), dt, u)
            out = np.array(t, dtype=float, copy=True)
            out[..., free] = y[..., free]
            return out

        return f

    def wrap_hx(self, hx):
        return lambda t, u: hx(self.to_si(t), u)

    def wrap_jac_h(self, jac_h):
        return lambda t, u: jac_h(self.to_si(t), u) * self.grad(t)[None, :]

    def wrap_jac_f(self, jac_f):
        """A_t = D^-1 A D (the transformed rows of A are zero: constants)."""

        def f(t, u):
            d = self.grad(t)
            return jac_f(self.to_si(t), u) * d[None, :] / d[:, None]

        return f
