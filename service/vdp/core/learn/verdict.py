"""The consistency verdict: innovation tests per window (:class:`Consistency`), the roll
mode's excitation, and what they make of an estimate's std, validity and reason.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from .. import lateral
from ..result import CONVERGED, UNCERTAIN
from . import tuning


def quad_form(y: list[float], S: list[list[float]]) -> float | None:
    """y' S^-1 y of a short vector (an innovation and its covariance, as lists), by a Cholesky
    factor in plain floats; None where S is not positive definite.  For stage 2's 1-3 rows a
    numpy solve cost ~10 us of call overhead per step, a fifth of the step."""
    n = len(y)
    if n == 2:  # stage 2's usual case (yaw rate and a_y): the closed form of the same
        a, b, d = S[0][0], S[0][1], S[1][1]
        det = a * d - b * b
        if not (a > 0.0 and det > 0.0):
            return None
        return (d * y[0] * y[0] - 2.0 * b * y[0] * y[1] + a * y[1] * y[1]) / det
    L = [[0.0] * n for _ in range(n)]
    w = [0.0] * n  # L^-1 y, by forward substitution as L is built
    total = 0.0
    for i in range(n):
        Li = L[i]
        for j in range(i + 1):
            acc = S[i][j] - sum(Li[k] * L[j][k] for k in range(j))
            if i == j:
                if not acc > 0.0:
                    return None
                Li[i] = math.sqrt(acc)
            else:
                Li[j] = acc / L[j][j]
        w[i] = (y[i] - sum(Li[k] * w[k] for k in range(i))) / Li[i]
        total += w[i] * w[i]
    return total


def _widen(rho: float | None, size: float = 1.0) -> float:
    """Factor on the stds: the square root of the sandwich's factor on the filter's variance,
    the residuals' ``size`` against what a matching model leaves (1) times what their colour
    costs, (1 + rho) / (1 - rho): a mean over AR(1) residuals holds n (1 - rho) / (1 + rho)
    independent ones (the effective sample size).  Never below 1: the filter's own std is the
    least.  Continuous in both: no statistic crossing a limit makes the std jump (issue 24).
    Residuals far below the noise (a noise-free drive) cost their colour in proportion: before,
    their colour was either ignored or charged in full, and a noise-free drive of a car vdp
    does not model could sit with l_f's std 6x too wide and stage 2 never starting."""
    k = size
    if rho is not None and rho > 0.0:
        r = min(rho, 0.95)
        k *= (1.0 + r) / (1.0 - r)
    return math.sqrt(max(k, 1.0))


class Consistency:
    """Running innovation tests: mean NIS per measurement row, and the lag-1
    autocorrelation of the a_y innovation scaled by its predicted std (whiteness)."""

    RECENT = 50  # updates in the divergence test (2 s at stage 2's 40 ms)

    def __init__(self):
        self.n = 0
        self.nis = 0.0  # sum of NIS
        self.rows = 0  # sum of the rows behind them
        self.e2 = self.ee = 0.0  # sum e^2, sum e_k e_k-1
        self.ne = 0
        self._e: float | None = None
        self._recent: deque = deque(maxlen=self.RECENT)

    def add(self, nis: float, rows: int, e: float | None) -> None:
        self.n += 1
        self.nis += nis
        self.rows += rows
        self._recent.append(nis / max(rows, 1))
        if e is not None:
            self.e2 += e * e
            self.ne += 1
            if self._e is not None:
                self.ee += e * self._e
        self._e = e

    def drop(self, other: Consistency) -> None:
        """Take a dropped window's sums back out."""
        self.n -= other.n
        self.nis -= other.nis
        self.rows -= other.rows
        self.e2 -= other.e2
        self.ee -= other.ee
        self.ne -= other.ne
        self._e = None

    def recent(self) -> float:
        """Mean NIS per row over the last RECENT updates (0 until there are that many)."""
        q = self._recent
        if len(q) < q.maxlen:
            return 0.0
        total = 0.0
        for v in q:  # in order, plainly (Python 3.12's sum compensates; core.kernels._recent adds as here)
            total += v
        return total / len(q)

    @property
    def ratio(self) -> float | None:
        """Mean NIS per row: about 1 / inflate^2 for a model that explains the data."""
        return self.nis / self.rows if self.rows else None

    @property
    def rho(self) -> float | None:
        """Lag-1 autocorrelation of the scaled a_y innovation (0: white)."""
        return self.ee / self.e2 if self.ne > 10 and self.e2 > 0 else None

    def as_dict(self) -> dict:
        r, w = self.ratio, self.rho
        return {
            "updates": self.n,
            "nis_per_row": None if r is None else round(r, 3),
            "whiteness_lag1": None if w is None else round(w, 3),
        }


class RollExcitation:
    """How much a drive tells of I_x: the roll rate's sensitivity to ln I_x along the drive.

    Eq (9), I_x phi'' + c_phi phi' + (k_phi - m g h) phi = m h a_y, driven by the measured
    a_y; chi = d phi / d ln I_x obeys the same equation forced by -I_x phi''.  Each roll-rate
    measurement then holds chi'^2 / R of information on ln I_x (Fisher), whichever filter
    runs: the EKF's linearised covariance claimed far more on the paper car's over-damped
    roll (I_x 26-46 % off with 2.2-2.6 sigma).  Trapezoidal steps at the sample rate (the
    roll's fast pole is stiff; the trapezoid is A-stable).  Plain floats: a few us a sample.
    """

    def __init__(self, k, i_x: float, phi: float, phi_d: float, t: float):
        self.kp = k.k_phi - k.m * k.g * k.h
        self.c = k.c_phi
        self.mh = k.m * k.h
        self.i = max(i_x, 1.0)
        self.phi, self.w = phi, phi_d
        self.chi = self.chi_d = 0.0
        self.t = t
        self.u: float | None = None

    def step(self, t: float, a_y: float) -> None:
        dt = t - self.t
        self.t = t
        if not (dt > 0.0 and math.isfinite(a_y)):
            return
        u1 = self.mh * a_y
        u0 = u1 if self.u is None else self.u
        self.u = u1
        self.phi, self.w, self.chi, self.chi_d = lateral.roll_sensitivity_step(
            self.phi, self.w, self.chi, self.chi_d, u0, u1, self.i, self.c, self.kp, dt
        )


def accel_noise_excitation(k, i_x: float, dt: float, accel_sd: float) -> float:
    """E[chi'^2] that the accelerometer's white noise alone puts into :class:`RollExcitation`'s
    chi' = d phi' / d ln I_x, per sample, once stationary.

    Eq (9) is driven by the measured a_y (lateral.Known.roll_by_ay), noise and all: the noise
    moves the model's roll rate, and that response depends on I_x, so it counts as information
    on ln I_x, though the car never rolled with it (the gyro does not see it).  It is worse
    than no information: a filter whose model's roll rate answers noise that the gyro does not
    show takes I_x too large, to damp it (an errors-in-variables attenuation,
    docs/decisions/0029).  The same trapezoidal step as RollExcitation's, linear in
    (phi, phi', chi, chi', a_y before, a_y now): its stationary covariance under white a_y
    (variance accel_sd^2 per sample) from the Lyapunov equation P = M P M' + G G' (the state
    carries the previous a_y).  0.0 where the step is not stable (no stationary value)."""
    kp, c, mh, i = k.k_phi - k.m * k.g * k.h, k.c_phi, k.m * k.h, max(i_x, 1.0)
    if not (dt > 0.0 and accel_sd > 0.0 and kp > 0.0 and c > 0.0):
        return 0.0
    cols = []
    for j in range(6):  # the step's columns: the four states, a_y before, a_y now
        e = [0.0] * 6
        e[j] = 1.0
        cols.append(lateral.roll_sensitivity_step(e[0], e[1], e[2], e[3], e[4], e[5], i, c, kp, dt))
    M = np.zeros((5, 5))
    M[:4, :5] = np.array(cols[:5]).T
    G = np.zeros(5)
    G[:4], G[4] = cols[5], 1.0
    if not np.max(np.abs(np.linalg.eigvals(M))) < 1.0:
        return 0.0
    Q = np.outer(G, G) * (mh * accel_sd) ** 2
    P = np.linalg.solve(np.eye(25) - np.kron(M, M), Q.reshape(-1)).reshape(5, 5)
    return max(float(P[3, 3]), 0.0)


def _verdict(c: Consistency, size: str, colour: str, kind: str) -> tuple[float, str | None]:
    """(factor on the stds, reason or None) from innovations' size (NIS) and whiteness.

    ``size`` and ``colour`` name the innovations in the two reasons, ``kind`` heads them.
    """
    nis, rho = c.ratio, c.rho
    if nis is None or c.n < Consistency.RECENT:
        return 1.0, None
    why = []
    if nis > tuning.NIS_MISMATCH:
        why.append(f"{size} {math.sqrt(nis / tuning.NIS_MATCHED):.1f}x the size a matching model leaves")
    # residuals far below the noise (a noise-free drive): their colour is no finding (the factor
    # charges it in proportion to their size)
    if rho is not None and rho > tuning.RHO_MISMATCH_2 and nis >= 0.5 * tuning.NIS_MATCHED:
        why.append(f"{colour} not white (lag-1 correlation {rho:.3f} > {tuning.RHO_MISMATCH_2})")
    return _widen(rho, nis / tuning.NIS_MATCHED), (f"{kind}: " + "; ".join(why)) if why else None


class Hard(str):
    """A reason that makes a value not valid whatever its std (the drive does not excite it: the
    number is the prior's).  Other reasons (a model mismatch) stand beside a valid value."""


def honest_std(spec, value: float, std: float) -> float:
    """The std a user may take: the data's (widened for coloured and oversized innovations, with
    the model's error where a mismatch shows) and the model class's own floor, which no length of
    drive averages out (ParamSpec.floor_rel)."""
    if not (math.isfinite(value) and math.isfinite(std)):
        return std
    return math.hypot(std, spec.floor_rel * abs(value))


def useful(spec, status: str, value: float, std: float) -> bool:
    """The verdict: a finite value in its sane range, learnt from the data (converged or still
    uncertain: not the prior's, not_identifiable), whose honest std is within the parameter's
    usefulness threshold.  Model-mismatch findings widen the std and stay beside the value as
    its reason; they do not veto it (a knife-edge test statistic would flip every parameter)."""
    if status not in (CONVERGED, UNCERTAIN) or not (math.isfinite(value) and math.isfinite(std)):
        return False
    return spec.lo <= value <= spec.hi and std <= spec.useful_rel * abs(value)


def too_wide(spec, value: float, std: float) -> str:
    return (
        f"std {100 * std / abs(value):.1f} % of the value, above the {100 * spec.useful_rel:g} % "
        f"a model can use (the data's spread, the model's error and the model's floor of "
        f"{100 * spec.floor_rel:g} %)"
    )
