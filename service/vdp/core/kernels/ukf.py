"""core.filters.UKF with its predict and update compiled, for each stage's model."""

from __future__ import annotations

import math
import typing

import numpy as np

from ...errors import FilterError
from .. import lateral, longitudinal
from ..filters import UKF
from .base import MESSAGES, NON_FINITE, OK, lat_known, lon_known, transforms
from .lat import lat_predict, lat_update
from .lon import lon_predict, lon_update

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
