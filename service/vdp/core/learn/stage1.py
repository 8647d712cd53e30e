"""Stage 1: l_f, h and C_K from the wheel speeds while accelerating and braking
(core.longitudinal), with its batch check (core.batch).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from ... import channels as ch
from .. import batch, longitudinal
from ..bounds import Bounds
from ..compiled import kernel, sig_in, sig_out
from ..params import BY_NAME, STAGE1
from . import tuning
from .base import StageLearner
from .verdict import _widen

log = logging.getLogger(__name__)


_BOTH_AXLES = np.ones(2, dtype=bool)  # stage 1 steps only on blocks with both axles' speeds


class _Blocks:
    """The newest ``cap`` blocks' (u, z, R), oldest first, in ring arrays.

    The batch check reads them all at every check (Stage1.check_due); stacking a deque of 3,000 small
    arrays took ~4 ms each time, a third of the batch checks' CPU on an hour's replay.
    """

    def __init__(self, cap: int):
        self.cap, self.n, self.head = cap, 0, 0
        self.U = np.empty((cap, longitudinal.N_U))
        self.Z = np.empty((cap, longitudinal.N_Z))
        self.R = np.empty((cap, longitudinal.N_Z, longitudinal.N_Z))

    def __len__(self) -> int:
        return self.n

    def append(self, u, z, R) -> None:
        i = self.head
        self.U[i], self.Z[i], self.R[i] = u, z, R
        self.head = (i + 1) % self.cap
        self.n = min(self.n + 1, self.cap)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(U, Z, R) of the blocks kept, oldest first (copies)."""
        if self.n < self.cap:
            return self.U[: self.n].copy(), self.Z[: self.n].copy(), self.R[: self.n].copy()
        h = self.head
        return tuple(np.concatenate((a[h:], a[:h])) for a in (self.U, self.Z, self.R))


def _shape_prior(free: bool) -> tuple[np.ndarray, np.ndarray]:
    """(mean, covariance) of stage 1's tyre shape (b, c, s_0f, s_0r): free, or held at the straight line."""
    if not free:
        b, c, s = tuning.SHAPE_OFF_STD
        return np.zeros(4), np.diag([b * b, c * c, s * s, s * s])
    c, d = tuning.OFFSET_STD**2, tuning.OFFSET_SPLIT_STD**2  # s_0f = common + split, s_0r = common - split
    P = np.diag([tuning.BEND_PRIOR[1] ** 2, tuning.CUBIC_PRIOR[1] ** 2, c + d, c + d])
    P[2, 3] = P[3, 2] = c - d
    return np.array([tuning.BEND_PRIOR[0], tuning.CUBIC_PRIOR[0], 0.0, 0.0]), P


class Stage1(StageLearner):
    """Longitudinal stage: l_f, h, C_K, a parameter-only filter (Table 4, core.longitudinal)."""

    stage = 1
    names = STAGE1
    model = longitudinal
    compiled_ukf = "LongitudinalUKF"

    def reset(self) -> None:
        v = self.vehicle
        self.known = longitudinal.Known(m=v.mass, L=v.wheelbase, r=v.wheel_radius, J=v.wheel_inertia, g=v.g)
        super().reset()
        self._acc: list = []
        self._blocks = _Blocks(tuning.BATCH_BLOCKS)  # (u, z, R) of each block the filter took
        self._since_batch = 0
        self._since_far = 0  # blocks since the last far check (check_batch)
        self.fit: batch.Fit | None = None
        self.reseeds = 0
        self._checks = 0
        self.gated = 0  # blocks left out: beyond the small-slip range, or a wheel spun or locked (_spun)
        self.spread: np.ndarray | None = None  # model_error()
        self.shaped = False  # the tyre's shape is free (the data showed it), else held at the straight line
        self.shape_prior = _shape_prior(False)
        self.shape = self.shape_prior  # (b, c, s_0f, s_0r) and their covariance when the filter was last dropped
        self._good_shape = self.shape
        self.filter = self._start_filter()

    def _start_filter(self):
        """A filter at the kept parameters and tyre shape (no correlation between the two kept)."""
        x0 = np.concatenate([self.theta, self.shape[0]])
        P0 = np.zeros((longitudinal.N_X, longitudinal.N_X))
        P0[:3, :3] = self.theta_P
        P0[3:, 3:] = self.shape[1]
        return self._new_filter(x0, P0, self._R0())

    def tyre(self) -> dict:
        """The tyre's shape as estimated (core.longitudinal): the bend b, the friction it
        implies (mu = 1 / (3 b), a brush tyre's; None when b <= 0) and each axle's slip offset."""
        x = self.filter_state()[0] if self.filter is not None else np.concatenate([self.theta, self.shape[0]])
        b = float(x[longitudinal.BEND])
        return {
            "law": "bending, with slip offsets" if self.shaped else "linear (eq 14)",
            "bend": round(b, 4),
            "bend_cubic": round(float(x[longitudinal.CUBIC]), 4),
            # (a linear law's bend is its prior's 0 to rounding: 1/(3 b) of it read as mu = 4.5e6)
            "mu_brush": round(1.0 / (3.0 * b), 3) if self.shaped and b > 0.0 else None,
            "slip_offset_front": round(float(x[longitudinal.S_0F]), 6),
            "slip_offset_rear": round(float(x[longitudinal.S_0R]), 6),
        }

    def prior(self) -> tuple[np.ndarray, np.ndarray]:
        """(mean, covariance) of the whole state's prior in SI: the parameters' and the tyre shape's."""
        mean = np.concatenate([[self.priors[n].value for n in self.names], self.shape_prior[0]])
        cov = np.zeros((longitudinal.N_X, longitudinal.N_X))
        cov[:3, :3] = np.diag(np.square(self.prior_std))
        cov[3:, 3:] = self.shape_prior[1]
        return mean, cov

    def _save_good(self) -> None:
        super()._save_good()
        x, P = self.filter_state()
        self._good_shape = x[3:].copy(), P[3:, 3:].copy()

    def _recover(self, why: str) -> None:
        super()._recover(why)
        self.shape = self._good_shape

    flagged = ("l_f", "h", "C_K")

    def mismatch(self) -> tuple[float, str | None]:
        """From the batch fit's front-minus-rear residuals (white when the model explains the
        data) and from the tyre's shape: once the data have freed it (a real tyre), what comes
        with a real tyre and the slips cannot separate is in play too (its stiffness's load
        sensitivity against h, speed-dependent load shifts against l_f).  On the brush cars the
        residuals of the bending law were white enough (lag-1 0.11) with l_f 0.8 % and h 8 %
        off at 13 and 10 std."""
        f = self.fit
        if f is None:
            return 1.0, None
        why = []
        quiet = f.chi2 < tuning.CHI2_QUIET  # residuals far below the noise: their colour says nothing
        if not quiet and f.rho > tuning.RHO_MISMATCH:
            why.append(
                f"stage 1's front-minus-rear residuals follow the manoeuvre "
                f"(lag-1 correlation {f.rho:.2f} > {tuning.RHO_MISMATCH}); the tyre law or a force it leaves out"
            )
        if self.shaped:
            why.append(
                "the tyre's force-slip curve bends or is offset at zero torque (a real tyre): its "
                "stiffness's load sensitivity, which the slips cannot tell from h, is not in the model: "
                f"a tyre whose stiffness per unit load falls with load (by q, 0-0.3 on road tyres) makes h "
                f"read low by about q x h, so h's std carries {100 * tuning.LOAD_SENSITIVITY:.0f} % for it, "
                "and l_f's the split of the axles' stiffness per unit load the same q makes"
            )
        return _widen(f.rho, f.chi2 / tuning.CHI2_MATCHED), ("model mismatch: " + "; ".join(why)) if why else None

    def model_error(self) -> np.ndarray | None:
        """How far apart the batch optima of the low- and the high-slip half of the blocks are.

        A model that explains the data gives the same parameters on both halves (within
        noise); a bending tyre gives a lower C_K on the high-slip half, and l_f and h take
        part of it.  The difference is the size of the model's error in this drive, taken in
        full once the residuals' colour reaches RHO_MISMATCH (or the tyre's shape is free), and
        from three quarters of it in proportion: a std that steps up as a statistic crosses its limit
        would flip l_f, h and C_K at once (issue 24).
        """
        w = self.spread_weight()
        if self.spread is None or w == 0.0:
            return None
        out = w * self.spread
        if self.shaped and self.fit is not None:  # a real tyre: its load sensitivity splits the axles
            l_f = float(self.bounds.to_si(self.fit.t)[longitudinal.L_F])
            out = out.copy()
            split = axle_split_shift(l_f, self.known.L, tuning.LOAD_SENSITIVITY)
            out[longitudinal.L_F] = math.hypot(out[longitudinal.L_F], split)
        return out

    def spread_weight(self) -> float:
        """0-1: how much of the halves' spread (model_error) the stds take."""
        f = self.fit
        if f is None:
            return 0.0
        if self.shaped:
            return 1.0
        # from 0.75 RHO_MISMATCH (0.09: vdp's own simulator's residuals reach 0.08, the tuning
        # cases) to RHO_MISMATCH in proportion
        colour = min(1.0, max(0.0, 4.0 * f.rho / tuning.RHO_MISMATCH - 3.0))
        # residuals far below the noise (a noise-free drive: chi2 0.003-0.011 on vdp's own model,
        # 0.06-0.22 on the independent ones) say nothing by their colour; from CHI2_QUIET to twice
        # it the spread comes in
        size = min(1.0, max(0.0, f.chi2 / tuning.CHI2_QUIET - 1.0))
        return colour * size

    def _test_shape(self, U, Z, R, prior, fit):
        """Free the tyre's shape if the data demand it (SHAPE_LR): (fit, t0, P0) with it free, or None."""
        b = self.bounds
        mean, P = _shape_prior(True)
        x0 = np.concatenate([prior[:3], mean])
        cov = np.zeros((longitudinal.N_X, longitudinal.N_X))
        cov[:3, :3] = np.diag(np.square(self.prior_std))
        cov[3:, 3:] = P
        t0 = b.from_si(x0)
        d = b.grad(t0)
        P0 = cov / np.outer(d, d)
        free = self._solve(U, Z, R, t0, P0, [fit.t], iters=20)
        if free is None:
            return None
        rho = min(max(free.rho, 0.0), 0.95)
        drop = (fit.cost - free.cost) / max(free.chi2, tuning.CHI2_QUIET) * (1.0 - rho) / (1.0 + rho)
        if drop <= tuning.SHAPE_LR:
            return None
        self.shaped = True
        self.shape_prior = mean, P
        log.info(
            "stage 1 %s: the tyre bends or has a slip offset (cost down %.0f x the noise); shape freed", self.kind, drop
        )
        return free, t0, P0

    def _model_error(self, U, Z, R, t0, P0, fit) -> np.ndarray:
        """The larger spread of two splits of the blocks (SI), with the tyre's unknown load
        sensitivity as a consider parameter.

        Low against high slip shows what the tyre law misses; slow against fast what grows
        with speed and the law leaves out (drag's pitching moment and lift move load from
        axle to axle with v^2: on the brush cars l_f read 0.9 % long).

        The load sensitivity moves h by about LOAD_SENSITIVITY x h, and nothing else by h
        (:func:`load_sensitivity_shift`, docs/decisions/0031).
        """
        b, k = self.bounds, self.known
        x = b.to_si(fit.t)
        f_zf, f_zr = longitudinal.axle_loads(x[longitudinal.L_F], x[longitudinal.H], U[:, longitudinal.U_AX], k)
        f_xf, f_xr = longitudinal.tyre_forces(U, k)
        used = np.maximum(np.abs(f_xf / f_zf), np.abs(f_xr / f_zr))
        out = np.zeros(longitudinal.N_X)
        for by in (used, U[:, longitudinal.U_VX]):
            spread = self._split(U, Z, R, t0, P0, fit, by <= np.median(by))
            if spread is not None:
                out = np.maximum(out, spread)
        return np.hypot(out, load_sensitivity_shift(x, tuning.LOAD_SENSITIVITY))

    def _split(self, U, Z, R, t0, P0, fit, lo) -> np.ndarray | None:
        """How far the parameters of the blocks in ``lo`` and of the others differ beyond their
        noise (SI), or None: sqrt(max(0, d^2 - var_1 - var_2)) per parameter."""
        b = self.bounds
        halves, var = [], 0.0
        for m in (lo, ~lo):
            if m.sum() < tuning.BATCH_EVERY:
                return None
            h = self._solve(U[m], Z[m], R[m], t0, P0, [fit.t], iters=15)
            if h is None:
                return None
            halves.append(b.to_si(h.t))
            var = var + np.diagonal(b.cov_to_si(h.t, h.cov))
        return np.sqrt(np.maximum(np.square(halves[0] - halves[1]) - var, 0.0))

    def _bounds(self) -> Bounds:
        # 0 < l_f < L, h > 0, C_K > 0; the tyre's bend and slip offset are free
        L_F, H, C_K = longitudinal.L_F, longitudinal.H, longitudinal.C_K
        return Bounds(longitudinal.N_X, log=(H, C_K), logit={L_F: (0.0, self.vehicle.wheelbase)})

    def _fx(self, x, dt, u):
        return longitudinal.fx(x, dt, u, self.known)

    def _hx(self, x, u):
        return longitudinal.hx(x, u, self.known)

    def _jac_f(self, x, u):
        return np.zeros((longitudinal.N_X, longitudinal.N_X))  # parameters: a random walk

    def _jac_h(self, x, u):
        return longitudinal.jac_h(x, u, self.known)

    def _solve(self, U, Z, R, t0, P0, starts, iters: int = 30) -> batch.Fit | None:
        """core.batch.solve on this stage's model (longitudinal.hx of the transformed parameters);
        compiled (core.kernels.lon_solve, the same iterations) when the filter steps are."""
        b, k = self.bounds, self.known
        if self.cfg.compiled and kernel("lon_solve") is not None:
            return kernel("lon_solve")(b, k, U, Z, R, t0, P0, starts, iters)
        return batch.solve(lambda t, u: longitudinal.hx(b.to_si(t), u, k), U, Z, R, t0, P0, starts, iters)

    def _q_rate(self):
        return np.diag(self.cfg.param_walk**2 * np.diagonal(self.prior()[1]))

    def _R0(self):
        n = self.cfg.noise
        return np.eye(2) * (n.wheel_speed * n.inflate) ** 2 / 2.0  # mean of the two wheels of an axle

    def _load_share(self, u) -> np.ndarray:
        """|F_x| / F_z of each axle for a block's inputs, at the current l_f and h held to their
        sane ranges: an EKF started far off (priors x1.6) once sat at h = 845 m, where every
        block looked beyond the small-slip range and none reached the filter or the batch
        check that would have re-seeded it."""
        x = self.bounds.to_si(self.filter.x)
        h = min(max(x[longitudinal.H], BY_NAME["h"].lo), BY_NAME["h"].hi)
        f_zf, f_zr = longitudinal.axle_loads(x[longitudinal.L_F], h, u[longitudinal.U_AX], self.known)
        f_xf, f_xr = longitudinal.tyre_forces(u, self.known)
        return np.abs([f_xf / f_zf, f_xr / f_zr])

    def _spun(self, u, z) -> bool:
        """Whether a wheel spun or locked in the block: an axle's slip beyond ``cfg.spin_slip``
        (eq 13 with the block's mean wheel speed and v_x), or changing faster than
        ``cfg.spin_rate``, its rate read as (r omega_dot - a_x) / v_x (eq 13 differentiated,
        the a_x s term left out).

        A tyre in its linear range changes its slip as the force changes, a few per cent a
        second (jerk / (C_K g)), and stays within the small-slip range; a wheel that
        traction control or ABS has to catch runs away from the body within milliseconds.
        Such a block's F_x = (T - J omega_dot) / r rests on a wheel acceleration that is not
        linear over the block (or on a wheel speed clipped at its signal's range), and its
        slip on a tyre past its grip.
        """
        c = self.cfg
        if c.spin_rate is None:
            return False
        r, a, v = self.known.r, u[longitudinal.U_AX], max(u[longitudinal.U_VX], 1.0)
        if max(abs(z[0] * r / v - 1.0), abs(z[1] * r / v - 1.0)) > c.spin_slip:
            return True
        dev = max(abs(r * u[longitudinal.U_WDF] - a), abs(r * u[longitudinal.U_WDR] - a))
        return dev > c.spin_rate * v

    def _R(self, u):
        """Wheel noise and the speed's error common to both axles (rank-one term)."""
        x = self.bounds.to_si(self.filter.x)
        c = longitudinal.speed_sensitivity(x, u, self.known)
        n = self.cfg.block
        # averaging n samples shrinks the wheel noise, not the slowly varying speed
        # error; speed_corr is stated per 10 ms of data, so the block's span counts
        corr = self.cfg.speed_corr / math.sqrt(n * self.cfg.tick / 0.01)
        return self._R0() / n + np.outer(c, c) * (u[longitudinal.U_VX_STD] * corr) ** 2

    @staticmethod
    def inputs(s) -> tuple[list, list, bool]:
        """(u, z, all finite) of one sample, as lists: arrays are built once per block."""
        y = s.values
        u = [y[ch.T_F], y[ch.T_R], y[ch.AX] - s.ax_bias, s.v_x, s.v_std, 0.0, 0.0]
        z = [0.5 * (y[ch.WS_FL] + y[ch.WS_FR]), 0.5 * (y[ch.WS_RL] + y[ch.WS_RR])]
        return u, z, math.isfinite(sum(u) + z[0] + z[1])  # a NaN or inf anywhere makes the sum so

    def set_params(self, theta, cov, samples: int) -> None:
        super().set_params(theta, cov, samples)
        self._acc = []
        self.filter = self._start_filter()

    def end_window(self) -> None:
        self.t_last = None  # parameter-only: nothing dynamic to drop
        self._acc = []

    def _step(self, t, s):
        u, z, ok = self.inputs(s)
        if not ok:
            return
        if self.t_last is not None and (s.gap or t - self.t_last > self.cfg.max_gap):
            self._acc = []  # a block never spans a gap or a clock jump (the grid restarts with gap set)
        self.t_last = t
        self.samples += 1
        # Block averages of inputs and measurements: the torque noise is input
        # noise, and averaging it before the filter keeps its errors-in-variables
        # bias on C_K small (the relation is close to linear over 50 ms).
        self._acc.append((t, u, z))
        if len(self._acc) < max(self.cfg.block, 3):
            return
        ts = np.array([a[0] for a in self._acc])
        us = np.array([a[1] for a in self._acc])
        zs = np.array([a[2] for a in self._acc])
        dt = ts[-1] - ts[0] + (ts[-1] - ts[0]) / (len(ts) - 1)  # the block's span (as core.kernels.lon_run)
        if self.filter is None:
            self.filter = self._start_filter()
        if self._compiled():  # the block's whole step in one compiled call (core.kernels.lon_block)
            self._acc = []
            f = self.filter
            what, status, x, P, sig, y, S, u, z, R = kernel("lon_block")(
                f._f.x, f._f.P, f._lam_n, f._Wm, f._Wc, f.Q_rate, f.scale, f._kind, f._lo, f._span, f._known,
                ts, us, zs, dt, self._R0(), self._block_settings(),
            )  # fmt: skip
            if what == _GATED:
                self.gated += 1
                return
            if what != _TAKEN:
                f._f.x, f._f.P, f._sigmas = x, P, sig  # (predicted, where the update failed)
                kernel("_raise")("predict" if what == _PREDICT_FAILED else "update", status)
            f._f.x, f._f.P, f._sigmas, f._f.y, f._f.S = x, P, sig, y, S
            self._taken(u, z, R)
            return
        u, z = us.mean(axis=0), zs.mean(axis=0)
        # wheel accelerations: least-squares slope over the block, centred like the means
        k = ts - ts.mean()
        u[longitudinal.U_WDF], u[longitudinal.U_WDR] = (k @ (zs - z)) / (k @ k)
        self._acc = []
        if self._load_share(u).max() > self.cfg.small_slip or self._spun(u, z):
            self.gated += 1
            return
        self.filter.predict(dt, u)
        R = self._R(u)
        self.filter.update(z, _BOTH_AXLES, u, R=R)
        self._taken(u, z, R)

    def _taken(self, u, z, R) -> None:
        """A block the filter took: kept for the batch check, which runs when due."""
        self._blocks.append(u, z, R)
        self._since_batch += 1
        self._since_far += 1
        if self.check_due():
            self.check_batch()
        if self.samples % self.cfg.save_every < self.cfg.block:
            self._save_good()

    def _compiled(self) -> bool:
        """Whether the filter is the compiled UKF (its blocks stepped by core.kernels.lon_block)."""
        # cfg.compiled first: asking kernel() loads numba (~120 MB of LLVM) even to say no
        cls = kernel("LongitudinalUKF") if self.cfg.compiled and self.filter is not None else None
        return cls is not None and isinstance(self.filter, cls)

    def _block_settings(self) -> np.ndarray:
        """lon_block's settings: the gates' limits, h's sane range and the speed error's factor (_R)."""
        c, h = self.cfg, BY_NAME["h"]
        corr = c.speed_corr / math.sqrt(c.block * c.tick / 0.01)
        spin = math.nan if c.spin_rate is None else c.spin_rate
        return np.array([c.small_slip, spin, c.spin_slip, h.lo, h.hi, corr])

    def runnable(self) -> bool:
        """Whether :meth:`steps` can take samples now (the compiled UKF, started)."""
        return self._compiled()

    def steps(self, T, Y, D, G, a: int, b: int) -> int:
        """Take samples a..b-1 of a block (ticks T, values Y, derived D: v_x, v_std, a_x bias;
        G: gap flags) in a window as :meth:`_step` would, compiled (core.kernels.lon_run), up
        to the first that needs :meth:`_step` itself (its block's step fails, or the batch
        check or a last-good copy comes after it): its index, b when none did.  Needs
        :meth:`runnable`."""
        f, c = self.filter, self.cfg
        block = c.block
        ls = np.array([self.samples, math.nan if self.t_last is None else self.t_last, len(self._acc),
                       self._since_batch, self._since_far, self.gated, len(self._blocks)], dtype=float)  # fmt: skip
        acc = np.zeros((block, 10))
        for q, (t, u, z) in enumerate(self._acc):
            acc[q, 0], acc[q, 1:8], acc[q, 8:] = t, u, z
        settings = np.array(
            [c.max_gap, block, c.save_every, tuning.BATCH_EVERY, tuning.BATCH_EVERY_MAX, self._blocks.cap], dtype=float
        )
        m = (b - a) // block + 1
        out_u, out_z, out_r = np.empty((m, longitudinal.N_U)), np.empty((m, 2)), np.empty((m, 2, 2))
        r, f._f.x, f._f.P, sig, y, S, nb = kernel("lon_run")(
            T, Y, D, G, a, b, _BLOCK_CHANNELS, f._f.x, f._f.P, sig_in(f._sigmas, f._f.x), f._lam_n, f._Wm, f._Wc,
            f.Q_rate, f.scale, f._kind, f._lo, f._span, f._known, self._R0(), self._block_settings(), ls, settings,
            acc, out_u, out_z, out_r,
        )  # fmt: skip
        f._sigmas = sig_out(sig)
        if nb:
            f._f.y, f._f.S = y, S
            for q in range(nb):
                self._blocks.append(out_u[q], out_z[q], out_r[q])
        samples, t_last, n_acc, since_batch, since_far, gated, _ = ls.tolist()
        self.samples, self._since_batch, self._since_far, self.gated = (
            int(samples), int(since_batch), int(since_far), int(gated)
        )  # fmt: skip
        self.t_last = None if math.isnan(t_last) else t_last
        self._acc = [(row[0], row[1:8], row[8:]) for row in acc[: int(n_acc)].tolist()]
        return int(r)

    def check_due(self, final: bool = False) -> bool:
        """Whether the batch check solves now: BATCH_EVERY new blocks, or a quarter of those kept
        when that is more, at most BATCH_EVERY_MAX; ``final`` (the data have ended): any new block."""
        if final:
            return self._since_batch > 0
        return self._since_batch >= min(max(tuning.BATCH_EVERY, len(self._blocks) // 4), tuning.BATCH_EVERY_MAX)

    def check_batch(self, full: bool = False) -> batch.Fit | None:
        """Solve the batch problem of the blocks kept; re-seed the filter if it sits off the optimum.
        The first, then one every BATCH_FAR_EVERY x BATCH_EVERY blocks, and where ``full`` (the
        data's end) is a far one: from the prior's mean too, with the tyre-shape test and the
        model's error (spread) on the blocks as they are now."""
        self._since_batch = 0
        if len(self._blocks) < 2 * tuning.BATCH_EVERY or self.filter is None:
            return None
        U, Z, R = self._blocks.arrays()
        b, k = self.bounds, self.known
        prior, cov = self.prior()
        t0 = b.from_si(prior)
        d = b.grad(t0)
        P0 = cov / np.outer(d, d)
        self._checks += 1
        # a far check every BATCH_FAR_EVERY dense checks' worth of blocks, whatever the checks' spacing
        far = full or self._checks == 1 or self._since_far >= tuning.BATCH_FAR_EVERY * tuning.BATCH_EVERY
        if far:
            self._since_far = 0
        starts = [self.filter.x.copy()]
        if far:
            starts.append(t0)
        lin = batch.linear_start(U, Z, k)
        if lin is not None:
            starts.append(b.from_si(np.concatenate([lin, prior[3:]])))
        fit = self._solve(U, Z, R, t0, P0, starts)
        if fit is None:
            return None
        if not self.shaped and far:
            shaped = self._test_shape(U, Z, R, prior, fit)
            if shaped is not None:
                fit, t0, P0 = shaped
                self.filter.set_state(fit.t, fit.cov)
        self.fit = fit
        if self.spread_weight() == 0.0:
            self.spread = None
        elif self.spread is None or far:
            # four more solves: the model's error in a drive changes slowly, so not at every check
            self.spread = self._model_error(U, Z, R, t0, P0, fit)
        d = self.filter.x - fit.t
        try:
            m2 = float(d @ np.linalg.solve(fit.cov, d))
        except np.linalg.LinAlgError:
            return fit
        if m2 > tuning.RESEED_M2:
            self.reseeds += 1
            log.info("stage 1 %s sat %.1f sigma off its batch optimum; re-seeded there", self.kind, math.sqrt(m2))
            self.filter.set_state(fit.t, fit.cov)
        return fit


def axle_split_shift(l_f: float, wheelbase: float, q: float) -> float:
    """How far l_f moves (m, 1 sigma) when one tyre on both axles has a stiffness per unit load
    that falls with load by ``q``: the more loaded axle's is lower by e = q (F_zf - F_zr) / mean F_z
    = 2 q |L - 2 l_f| / L, and stage 1, which sees the slips through one C_K for both axles, reads
    that split as l_f (L - l_f) / L x e (docs/decisions/0021: mb/bmw_320i's ordinary drive, its
    tyre's load-moving zero-force slip splitting the axles by 2.6 %, l_f -1.2 % at a std of 0.4 %).
    0 on a car with equal axle loads."""
    e = 2.0 * q * abs(wheelbase - 2.0 * l_f) / wheelbase
    return l_f * (wheelbase - l_f) / wheelbase * e


def load_sensitivity_shift(x: np.ndarray, q: float) -> np.ndarray:
    """How far each stage-1 parameter (``x``, SI) moves, 1 sigma, with the tyre's unknown load
    sensitivity q: h by q h, the others not by it.  A
    stiffness per unit load that falls by q with the load shows (1 - q) of the load transfer in the
    slips, so h reads low.  At the axle loads the drive runs at (where C_K is defined) the stiffness is
    what the slips show, so C_K takes none of it; l_f takes the axles' split the same q makes
    (:func:`axle_split_shift`, docs/decisions/0021).  A Schmidt share of h's move by each one's
    regression on h had been kept too, for a C_K +15 % on the ordinary drive that was the speed
    filter's (0028): it counted the load sensitivity twice (docs/decisions/0031)."""
    out = np.zeros(len(x))
    out[longitudinal.H] = q * x[longitudinal.H]
    return out


# the channels core.kernels.lon_run reads, in its order, and what lon_block did with a block
_BLOCK_CHANNELS = np.array([ch.WS_FL, ch.WS_FR, ch.WS_RL, ch.WS_RR, ch.T_F, ch.T_R, ch.AX])
_TAKEN, _GATED, _PREDICT_FAILED, _UPDATE_FAILED = range(4)  # (core.kernels' TAKEN, ...: tests/test_batched.py)
