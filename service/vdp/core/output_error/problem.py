"""The fit's record, problem and result: the single track by output error over the windows' samples."""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from .. import lateral
from ..compiled import kernel

log = logging.getLogger(__name__)


# parameters: ln C_alpha_f, ln C_alpha_r, ln I_z, a_y offset, the swing length, the tyre's
# shape (b, c), then (v_y0, yaw0) per window
N_THETA = 3
OFFSET = 3
SWING = 4
SHAPE_B, SHAPE_C = 5, 6
N_GLOBAL = 7
OFFSET_STD = 0.3  # m/s^2: accelerometer bias and road bank (g sin 2 deg = 0.34)
# The roll-sideslip coupling: where the accelerometer and the axles sit on the roll axis and the
# sprung mass rolls above it, m a_y = sum F_y + m_s d phi'' (the three-DOF roll model's term the
# single track lacks; shared/notes: it biased I_z +11...+24 % on the brush cars).  s = m_s d / m is
# fitted with phi'' from the roll-rate gyro: on the brush cars it lands within 3.4 % of m_s d / m,
# and where the IMU rides the sprung mass (the multi-body cars) it ends small and negative
# (docs/decisions/0017).
SWING_STD = 0.5  # m
HELD = 1e-6  # the prior std of a parameter the fit holds (its shape while the tyre is linear)
# The tyre's shape, freed only where the data need it (Check.solve): F_y = C alpha (1 - b u + c u^2),
# u = C |alpha| / F_z at the axle's static load.  C stays the initial (small-slip) slope, the truth's
# definition; a brush tyre has b = 1/(3 mu), c = 1/(27 mu^2), a Magic-Formula tyre b near 0.
SHAPE_STD = 1.0
# fixed-point passes: each axle's secant stiffness at the previous pass's slip angles, until the
# factors move by less than SHAPE_TOL; each call starts from the last converged factors (Problem._warm),
# so a Levenberg-Marquardt step or a Jacobian column takes 1-3 passes, a cold start 5-10
SHAPE_ITERS = 30
SHAPE_TOL = 1e-8
V_Y0_STD = 2.0  # m/s, only to keep the normal equations regular
YAW0_STD = 1.0  # rad/s

MAX_ROWS = 7500  # samples kept (5 min of windows at stage 2's 40 ms step)
MIN_ROWS = 50  # a window shorter than this (2 s) is not kept: two initial states for little
MAX_SUBSTEP = lateral.MAX_SUBSTEP
DIFF = 1e-4  # step of the numerical derivatives in the logs
_NO_BEND = np.empty((0, 0))  # the linear law, to the compiled states (no secant factors)


class Record:
    """The stage-2 windows' samples, bounded: the newest ``cap`` rows in windows of at least
    ``min_rows`` (older rows are dropped from the oldest window's start: its initial state is
    fitted anyway).  Row: t, the model's input row (lateral's U columns), yaw rate, a_y and
    roll rate (NaN when missing)."""

    def __init__(self, cap: int = MAX_ROWS, min_rows: int = MIN_ROWS):
        self.cap, self.min_rows = cap, min_rows
        self.windows: deque[list] = deque()
        self.rows = 0
        self.added = 0  # rows ever added (for staleness)

    def open(self) -> None:
        """Start a new window (the previous one ends)."""
        if self.windows and len(self.windows[-1]) < self.min_rows:
            self.rows -= len(self.windows.pop())
        self.windows.append([])

    def drop(self) -> None:
        """Drop the newest window's rows (a window that left the data); the fit is stale after."""
        if self.windows:
            self.rows -= len(self.windows.pop())
            self.added += 1

    def add(self, t: float, u, yaw: float, a_y: float, roll: float = math.nan) -> None:
        if not self.windows:
            self.windows.append([])
        self.windows[-1].append((t, u[0], u[1], u[2], u[3], yaw, a_y, roll))
        self.rows += 1
        self.added += 1
        while self.rows > self.cap:
            w = self.windows[0]
            drop = min(len(w), self.rows - self.cap) if len(w) > self.min_rows else len(w)
            if len(self.windows) == 1:
                drop = self.rows - self.cap
            del w[:drop]
            self.rows -= drop
            if not w or (len(w) < self.min_rows and len(self.windows) > 1):
                self.rows -= len(w)
                self.windows.popleft()

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[int, int]]] | None:
        """(t (N,), U (N, 4), Z (N, 3): yaw rate, a_y, roll rate, [(start, end) per window]) of the
        windows long enough, or None."""
        ws = [w for w in self.windows if len(w) >= self.min_rows]
        if not ws:
            return None
        a = np.array([r for w in ws for r in w], dtype=float)
        bounds, i = [], 0
        for w in ws:
            bounds.append((i, i + len(w)))
            i += len(w)
        return a[:, 0], a[:, 1:5], a[:, 5:8], bounds


@dataclass(frozen=True)
class Fit:
    """The output-error optimum."""

    theta: np.ndarray  # C_alpha_f, C_alpha_r, I_z (SI)
    offset: float  # a_y offset, m/s^2
    cov: np.ndarray  # covariance of (ln C_f, ln C_r, ln I_z), widened for the residuals (_robust_scale)
    chi2: float  # reduced chi-square of the data (1: the residuals are the sensors' noise)
    rho: float  # lag-1 autocorrelation of the a_y residuals (0: white)
    rows: int
    iters: int
    p: np.ndarray | None = None  # every parameter at the optimum (the logs, the offset, the windows' x0)
    # relative (log) spread of (C_f, C_r, I_z) between the fits of the gentle and the brisk half
    # of the samples beyond their noise (spread()): the model's own error in this drive; None: not solved
    spread: np.ndarray | None = None
    swing: float = 0.0  # m: the roll-sideslip length s (a_y += s phi'')
    swing_std: float = math.inf  # m
    shape: tuple[float, float] | None = None  # the tyre's (b, c) where the data freed it, else None (linear)
    # the same windows fitted with the tyre's shape free, where the linear law was kept (Check._fit):
    # the other answer the data allow (compare covers it)
    bent: Fit | None = None

    @property
    def c_alpha(self) -> float:
        """The mean of the two axles (the published C_alpha)."""
        return 0.5 * float(self.theta[0] + self.theta[1])

    def _w(self, name: str) -> np.ndarray:
        """d ln(name) / d (ln C_f, ln C_r, ln I_z); C_alpha is the axles' mean."""
        one = {"C_alpha_front": 0, "C_alpha_rear": 1, "I_z": 2}
        if name in one:
            return np.eye(N_THETA)[one[name]]
        return np.array([self.theta[0], self.theta[1], 0.0]) / (self.theta[0] + self.theta[1])

    def rel_std(self, name: str) -> float:
        """Relative (log) std of the published C_alpha (the axles' mean) or I_z, from the data."""
        w = self._w(name)
        return math.sqrt(float(w @ self.cov @ w))

    def rel_spread(self, name: str) -> float:
        """The model's own error in the published C_alpha or I_z (relative), 0 when not seen:
        half the halves' spread, as the full fit sits between them (on the brush cars the
        gentle half's stiffness was 10-20 % above the truth, the brisk half's 27-29 % below)."""
        return 0.0 if self.spread is None else 0.5 * float(abs(self._w(name)) @ self.spread)

    def value(self, name: str) -> float:
        """C_alpha (the axles' mean), C_alpha_front, C_alpha_rear or I_z."""
        one = {"C_alpha_front": 0, "C_alpha_rear": 1, "I_z": 2}
        return float(self.theta[one[name]]) if name in one else self.c_alpha


class _Pre:
    """What the model needs of the inputs, independent of the parameters, at the sample
    points and at each interval's sub-step points (start, mid, end of each sub-step)."""

    def __init__(self, u: np.ndarray, k: lateral.Known, phi_dd: np.ndarray):
        self.phi_dd = phi_dd  # the roll acceleration from the roll-rate gyro (0 where none)
        self.d = u[..., lateral.U_DELTA]
        self.v_x = np.maximum(u[..., lateral.U_VX], lateral.V_MIN)
        sd, self.cd = np.sin(self.d), np.cos(self.d)
        ck_fz = k.C_K * k.m / k.L * (k.g * k.L - u[..., lateral.U_AX] * k.h) - k.ck_slope * k.l_f
        xs = ck_fz * sd  # C_sigma sin(d) (NOTES 8)
        w_r = u[..., lateral.U_WF] * k.r
        v_w = self.v_x * self.cd  # the front wheel's speed at zero slip angle
        ok = v_w > lateral.V_MIN
        v_w = np.maximum(v_w, lateral.V_MIN)
        # F_xf sin(d) = X0 + alpha p + O(p^2), p = v_y + l_f r (lateral._rates, linearised at p = 0)
        self.x0 = xs * w_r / v_w - xs
        self.alpha = np.where(ok, -xs * w_r * sd / (v_w * v_w), 0.0)


def _system(pre: _Pre, theta: np.ndarray, k: lateral.Known, swing=None, bend=None):
    """x_dot = A x + b and a_y = c x + a0 for x = (v_y, r); eqs (5), (7), (10)-(12).

    ``theta`` (S, 3): S parameter sets (C_f, C_r, I_z) at once; the results broadcast to
    (S,) + the inputs' shape, as (a11, a12, a21, a22, b1, b2, c1, c2, a0).  ``swing`` (S,):
    a_y gains s phi'' (SWING); ``bend``: each axle's secant factor on its stiffness, (S,) + the
    inputs' shape each (the tyre's shape at frozen slip angles, Problem.outputs).
    """
    l_f, l_r, m = k.l_f, k.L - k.l_f, k.m
    extra = (1,) * pre.v_x.ndim
    c_f, c_r, i_z = (theta[:, i].reshape((-1,) + extra) for i in range(3))
    if bend is not None:
        c_f, c_r = c_f * bend[0], c_r * bend[1]
    v = pre.v_x
    e = pre.alpha - c_f * (pre.cd / v)  # d Y_f / d p
    y0 = pre.x0 + c_f * (pre.d * pre.cd)  # Y_f at p = 0
    cr = c_r / v
    c1, c2 = (e - cr) / m, (e * l_f + cr * l_r) / m  # a_y = c1 v_y + c2 r + y0 / m
    a0 = y0 / m
    # eq (5) corrected: v_y_dot = a_y - v_x r; eq (10): r_dot = (l_f Y_f - l_r F_yr) / I_z
    a21, a22 = (l_f * e + l_r * cr) / i_z, (l_f * l_f * e - l_r * l_r * cr) / i_z
    yaw0 = l_f * y0 / i_z
    if swing is not None:  # the reference point's a_y, and so v_y_dot, carry s phi''
        a0 = a0 + swing.reshape((-1,) + extra) * pre.phi_dd
    return c1, c2 - v, a21, a22, a0, yaw0, c1, c2, a0


class Problem:
    """One output-error problem: the recorded windows and the constants.

    The state at each sample is x_i = Phi_i x0 + G_i, x0 its window's initial state, where
    (Phi_i, G_i) composes the maps x_j = F_j x_j-1 + g_j of the window's steps so far: a
    segmented prefix scan (log2 n rounds of array operations, no Python loop over samples),
    or the same products left to right in one compiled pass (``compiled``, :meth:`_states`).
    """

    def __init__(self, t: np.ndarray, u: np.ndarray, z: np.ndarray, bounds, k: lateral.Known, sigma):
        self.k = k
        self.bounds = list(bounds)
        self.n = n = len(t)
        z = np.asarray(z, dtype=float)
        roll = z[:, 2] if z.shape[1] > 2 else np.full(n, np.nan)
        z = z[:, :2]
        self.w = np.where(np.isfinite(z), 1.0 / np.asarray(sigma, dtype=float), 0.0)  # per row's 1/sigma
        self.zf = np.where(np.isfinite(z), z, 0.0)
        # phi'' per row from the roll-rate gyro: central differences over each window's finite
        # samples, linear between them (a slower gyro or dropouts leave gaps); 0 where none
        phi_dd = np.zeros(n)
        self.has_roll = False
        for a, b in self.bounds:
            ok = np.isfinite(roll[a:b])
            if np.count_nonzero(ok) < 3:
                continue
            tt = t[a:b][ok]
            with np.errstate(invalid="ignore", divide="ignore"):  # a clock that stood still: not finite, 0
                g = np.gradient(roll[a:b][ok], tt)
            g = np.where(np.isfinite(g), g, 0.0)
            phi_dd[a:b] = np.interp(t[a:b], tt, g)
            self.has_roll = True
        phi_dd = np.where(np.isfinite(phi_dd), phi_dd, 0.0)
        # the static axle loads (u of the tyre's shape): F_zf = m g l_r / L, F_zr = m g l_f / L
        self.fz = (k.m * k.g * (k.L - k.l_f) / k.L, k.m * k.g * k.l_f / k.L)
        seg = np.zeros(n, dtype=int)
        first = np.zeros(n, dtype=bool)
        for s, (a, b) in enumerate(self.bounds):
            seg[a:b] = s
            first[a] = True
        self.seg = seg
        self.first = first
        # the rows reached by a step (every row but a window's first) and the step's start row
        self.to = np.flatnonzero(~first)
        idx = self.to - 1
        dt = t[self.to] - t[idx]
        self.sub = max(1, math.ceil(float(dt.max(initial=0.0)) / MAX_SUBSTEP - 1e-9))
        self.h = dt / self.sub
        # inputs at the 2 sub + 1 points of each step, linear between the samples (lateral.fx)
        f = np.linspace(0.0, 1.0, 2 * self.sub + 1)
        self.frac = f
        self.idx = idx
        ui = u[idx, None, :] + f[None, :, None] * (u[self.to] - u[idx])[:, None, :]
        pi = phi_dd[idx, None] + f[None, :] * (phi_dd[self.to] - phi_dd[idx])[:, None]
        self.pre_steps = _Pre(ui, k, pi)
        self.pre_rows = _Pre(u, k, phi_dd)
        # the scan's rounds: which rows combine with the row d before them (same window)
        self.rounds = []
        d = 1
        while d < n:
            self.rounds.append((d, seg[d:] == seg[:-d]))
            d *= 2

    # -- the model ------------------------------------------------------------
    def _maps(self, theta: np.ndarray, swing: np.ndarray, bend=None):
        """(f11, f12, f21, f22, g1, g2), each (S, n): row i's map from row i-1 (identity and
        zero at a window's first row); midpoint sub-steps as lateral.fx."""
        a11, a12, a21, a22, b1, b2, _, _, _ = _system(self.pre_steps, theta, self.k, swing, bend)
        h = self.h[None, :]
        hh = 0.5 * h * h
        S = theta.shape[0]
        f11, f12, f21, f22 = np.ones((S, len(h[0]))), 0.0, 0.0, 1.0
        g1 = g2 = 0.0
        for j in range(self.sub):
            p, q = 2 * j, 2 * j + 1
            m11, m12, m21, m22 = a11[..., q], a12[..., q], a21[..., q], a22[..., q]
            n11, n12, n21, n22 = a11[..., p], a12[..., p], a21[..., p], a22[..., p]
            # midpoint: x1 = x + h (Am (x + h/2 (A0 x + b0)) + bm) = M x + w
            M11 = 1.0 + h * m11 + hh * (m11 * n11 + m12 * n21)
            M12 = h * m12 + hh * (m11 * n12 + m12 * n22)
            M21 = h * m21 + hh * (m21 * n11 + m22 * n21)
            M22 = 1.0 + h * m22 + hh * (m21 * n12 + m22 * n22)
            w1 = h * b1[..., q] + hh * (m11 * b1[..., p] + m12 * b2[..., p])
            w2 = h * b2[..., q] + hh * (m21 * b1[..., p] + m22 * b2[..., p])
            f11, f12, f21, f22 = (
                M11 * f11 + M12 * f21,
                M11 * f12 + M12 * f22,
                M21 * f11 + M22 * f21,
                M21 * f12 + M22 * f22,
            )
            g1, g2 = M11 * g1 + M12 * g2 + w1, M21 * g1 + M22 * g2 + w2
        out = np.zeros((6, S, self.n))
        out[0] = out[3] = 1.0
        for i, v in enumerate((f11, f12, f21, f22, g1, g2)):
            out[i][:, self.to] = v
        return out

    def _states(self, theta: np.ndarray, swing: np.ndarray, bend=None) -> np.ndarray:
        """(Phi, G) per row, (6, S, n); ``bend``: each axle's secant factor per row (S, n), or None.
        Compiled (core.kernels.oe_states) where numba is and ``compiled`` is on, else
        :meth:`_scan` of :meth:`_maps` (the reference; the two differ by rounding,
        tests/test_kernels.py)."""
        fn = kernel("oe_states") if self.compiled else None
        if fn is None:
            return self._scan(self._maps(theta, swing, None if bend is None else [self._at_steps(b) for b in bend]))
        pre, k = self.pre_steps, self.k
        bf, br = (_NO_BEND, _NO_BEND) if bend is None else bend
        args = (np.ascontiguousarray(pre.d), pre.cd, pre.v_x, pre.x0, pre.alpha, pre.phi_dd, self.h, self.frac)
        # floats whatever the profile wrote (an integer mass would be another signature to compile)
        return fn(*args, self.first, theta, np.ascontiguousarray(swing), bf, br, float(k.l_f), float(k.L), float(k.m))

    def _scan(self, m: np.ndarray) -> np.ndarray:
        """Inclusive segmented prefix scan of the maps: (Phi, G) per row, (6, S, n)."""
        m = m.copy()
        for d, same in self.rounds:
            f11, f12, f21, f22, g1, g2 = m[:, :, d:]
            e11, e12, e21, e22, h1, h2 = m[:, :, :-d]
            new = np.stack(
                [
                    f11 * e11 + f12 * e21,
                    f11 * e12 + f12 * e22,
                    f21 * e11 + f22 * e21,
                    f21 * e12 + f22 * e22,
                    f11 * h1 + f12 * h2 + g1,
                    f21 * h1 + f22 * h2 + g2,
                ]
            )
            m[:, :, d:] = np.where(same, new, m[:, :, d:])
        return m

    def _bend(self, theta, shape, v_y, r):
        """Each axle's secant factor 1 - b u + c u^2 at the rows' slip angles (S, n) each."""
        k, pre = self.k, self.pre_rows
        a_f = pre.d - (v_y + k.l_f * r) / pre.v_x
        a_r = ((k.L - k.l_f) * r - v_y) / pre.v_x
        out = []
        for j, a in enumerate((a_f, a_r)):
            u = theta[:, j, None] * np.abs(a) / self.fz[j]
            # kept within physical bounds: a wild trial step must not reverse a tyre's force
            out.append(np.clip(1.0 - shape[:, 0, None] * u + shape[:, 1, None] * u * u, 0.2, 1.5))
        return out

    def _at_steps(self, rows: np.ndarray) -> np.ndarray:
        """A per-row quantity (S, n) at each step's sub-step points, linear between the rows."""
        return rows[:, self.idx, None] + self.frac[None, None, :] * (rows[:, self.to] - rows[:, self.idx])[..., None]

    def outputs(self, p: np.ndarray) -> tuple[np.ndarray, tuple]:
        """Predicted (yaw rate, a_y) (S, n, 2) for parameter sets p (S, len): and (Phi, c) of the first.

        With a tyre shape (SHAPE_B, SHAPE_C not 0) the model is not linear in the state; each
        axle's secant stiffness is then frozen at the previous pass's slip angles and the
        linear scan repeated (SHAPE_ITERS passes: the factors move by a few per cent, the
        slip angles by less)."""
        p = np.atleast_2d(p)
        theta = np.exp(p[:, :N_THETA])
        swing = p[:, SWING]
        shape = p[:, SHAPE_B : SHAPE_C + 1]
        x0 = p[:, N_GLOBAL:].reshape(len(p), -1, 2)[:, self.seg, :]  # (S, n, 2): each row's window's x0
        bent = bool(np.any(shape != 0.0))
        rows = None  # the secant factors per row the pass freezes (None: the linear law)
        if bent and self._warm is not None:
            rows = [np.repeat(w[None, :], len(p), axis=0) for w in self._warm]
        for _ in range(SHAPE_ITERS if bent else 1):
            phi = self._states(theta, swing, rows)
            v_y = phi[0] * x0[..., 0] + phi[1] * x0[..., 1] + phi[4]
            r = phi[2] * x0[..., 0] + phi[3] * x0[..., 1] + phi[5]
            if not bent:
                break
            new = self._bend(theta, shape, v_y, r)
            moved = math.inf if rows is None else max(float(np.max(np.abs(x - y))) for x, y in zip(new, rows))
            rows = new
            if moved < SHAPE_TOL:
                break
        if bent:
            self._warm = [b[0].copy() for b in rows]
        *_, c1, c2, a0 = _system(self.pre_rows, theta, self.k, swing, rows)
        a_y = c1 * v_y + c2 * r + a0 + p[:, OFFSET, None]
        return np.stack([r, a_y], axis=-1), (phi[:4, 0], c1[0], c2[0])

    def residuals(self, p) -> tuple[np.ndarray, tuple]:
        y, aux = self.outputs(p)
        return ((self.zf - y[0]) * self.w).ravel(), aux

    def jacobian(self, p, aux) -> np.ndarray:
        """d residuals / d p (n * 2, len(p)): numerical in the logs (one batch), exact in the rest."""
        (p11, p12, p21, p22), c1, c2 = aux
        cols = list(range(N_THETA)) + [SWING] * self.swung + [SHAPE_B] * self.shaped + [SHAPE_C] * self.curved
        q = np.repeat(p[None, :], len(cols) + 1, axis=0)
        q[np.arange(1, len(cols) + 1), cols] += DIFF
        y = self.outputs(q)[0]
        J = np.zeros((self.n, 2, len(p)))
        J[:, :, cols] = -((y[1:] - y[0]) / DIFF * self.w).transpose(1, 2, 0)
        J[:, 1, OFFSET] = -self.w[:, 1]
        # the initial state: d r / d x0 = Phi's second row; d a_y / d x0 = c Phi (the secant
        # factors' own dependence on x0 left out: a few per cent of a few per cent)
        cols = N_GLOBAL + 2 * self.seg
        rows = np.arange(self.n)
        for j, (dv, dr) in enumerate(((p11, p21), (p12, p22))):
            J[rows, 0, cols + j] = -dr * self.w[:, 0]
            J[rows, 1, cols + j] = -(c1 * dv + c2 * dr) * self.w[:, 1]
        return J.reshape(self.n * 2, len(p))

    compiled = False  # core.kernels' pass for the states (Check sets it from LearnerConfig.compiled)
    shaped = False  # whether the tyre's shape is free (Check.solve frees it where the data need it)
    bend_only = False  # with the shape free, its quadratic term c held at 0 (Check._fit's cover of a bend)

    @property
    def curved(self) -> bool:
        """Whether the shape's quadratic term c is free."""
        return self.shaped and not self.bend_only

    _warm: list[np.ndarray] | None = None  # the last converged secant factors per axle (outputs())

    @property
    def swung(self) -> bool:
        """Whether the swing is free: wherever there is a roll-rate gyro, in the linear fit too
        (held at 0 there, the multi-body cars' structure made the shaped fit look better and it
        bent their C_alpha +8...+12 %, I_z +19 %: docs/decisions/0013)."""
        return self.has_roll

    def _variant(self, **changes) -> Problem:
        """The same problem (its arrays shared) with some attributes changed."""
        out = object.__new__(Problem)
        out.__dict__.update(self.__dict__)
        out.__dict__.update(changes)
        return out

    def shaping(self, on: bool) -> Problem:
        """The same problem with the tyre's shape free (on) or held at the linear law."""
        return self._variant(shaped=on)

    def only(self, keep: np.ndarray) -> Problem:
        """The same problem with the residuals of the rows not in ``keep`` weighted out."""
        return self._variant(w=self.w * keep[:, None])

    # -- starts -----------------------------------------------------------------
    def start(self, theta) -> np.ndarray:
        """Parameters at ``theta`` (SI), no offset, each window at its steady state (Stage2._start)."""
        k = self.k
        p = np.zeros(N_GLOBAL + 2 * len(self.bounds))
        p[:N_THETA] = np.log(theta[:N_THETA])
        for s, (a, _) in enumerate(self.bounds):
            yaw = self.zf[a, 0]
            a_y = self.zf[a, 1]
            v_x = max(float(self.pre_rows.v_x[a]), lateral.V_MIN)
            p[N_GLOBAL + 2 * s : N_GLOBAL + 2 * s + 2] = (
                (k.L - k.l_f) * yaw - k.m * a_y * k.l_f * v_x / (k.L * theta[1]),
                yaw,
            )
        return p
