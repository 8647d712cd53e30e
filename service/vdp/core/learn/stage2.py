"""Stage 2: C_alpha (per axle), I_z and I_x from the lateral and roll dynamics
(core.lateral), with its output-error batch check (core.output_error).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import replace

import numpy as np

from ... import channels as ch
from .. import lateral, output_error
from ..bounds import Bounds
from ..compiled import kernel, sig_in, sig_out
from ..params import BY_NAME, STAGE2
from ..result import NOT_IDENTIFIABLE, NOT_RUN, Estimate
from . import tuning
from .axles import AxleSplit
from .base import StageLearner
from .verdict import Consistency, Hard, RollExcitation, _verdict, accel_noise_excitation, quad_form

log = logging.getLogger(__name__)


# the channels core.kernels.lat_run reads, in its order
_STEP_CHANNELS = np.array(
    [ch.WS_FL, ch.WS_FR, ch.WS_RL, ch.WS_RR, ch.T_R, ch.DELTA, ch.AX, ch.AY, ch.YAW, ch.ROLL, ch.SPEED]
)


class Stage2(AxleSplit, StageLearner):
    """Single track with roll: C_alpha per axle, I_z, I_x with v_y, yaw rate, phi, phi_dot as states.

    The filter estimates the front and the rear cornering stiffness (lateral.C_F, C_R); it
    publishes their mean as ``C_alpha`` (the paper's single value, what clients read), with
    the per-axle values, their stds and whether the drive separates them in its ``extra``.
    """

    stage = 2
    names = STAGE2
    model = lateral
    compiled_ukf = "LateralUKF"

    def reset(self) -> None:
        self.known = None
        self.l_f_std = None
        self.h_std = None
        self._settle: deque = deque()
        self.window = Consistency()  # the open (or last) window's innovation tests
        self.total = Consistency()  # over every window kept
        self.roll_window = Consistency()  # the roll-rate row's alone (I_x), the open window's ...
        self.roll_total = Consistency()  # ... and every window kept
        self.restarts = 0  # windows dropped as diverged
        self.updates = 0  # filter updates
        self.roll_info = 0.0  # information on ln I_x from the roll-rate rows (RollExcitation)
        self._info_window = 0.0
        self._excite: RollExcitation | None = None
        self.roll_updates = 0  # of them, those that had a roll-rate measurement
        # of roll_info, what the accelerometer's noise alone puts in (accel_noise_excitation): the
        # windows closed, and the open (or last) window's per roll-rate update since its roll_updates
        self._noise_info = 0.0
        self._noise_rate = 0.0
        self._noise_from = 0
        # the batch check: windows' samples and their output-error fit
        self.check = output_error.Check(compiled=self.cfg.compiled, executor=self.cfg.check_executor)
        super().reset()
        if self.cfg.bank:  # the road's bank, a tenth state (lateral.BANK)
            self._n = lateral.BANK + 1
            self.bounds = self._bounds()
        P = self.theta_P
        self.prior_diff_std = math.sqrt(P[0, 0] + P[1, 1] - 2.0 * P[0, 1])  # of C_alpha_f - C_alpha_r
        # the split starts held (SPLIT_HELD) when it comes from the C_alpha prior, not the profile's per-axle priors
        p = self.priors
        self.split_held = self.cfg.per_axle and (p.get("C_alpha_f") is None or p.get("C_alpha_r") is None)
        if self.split_held:
            c_std = p["C_alpha"].std
            self.theta_P = P - self._difference_cov(c_std) + self._difference_cov(c_std, tuning.SPLIT_HELD)
            self._good = (self.theta.copy(), self.theta_P.copy(), None)

    def set_stage1(
        self, l_f: float, h: float, c_k: float | None, l_f_std: float | None = None, h_std: float | None = None
    ) -> None:
        """Stage 1's results.  ``l_f_std`` is considered (lateral.CONSIDER): stage 2 is
        sensitive to l_f, and its stds would otherwise take stage 1's l_f as exact.

        ``c_k`` None: stage 1 has not run (no axle torques), so the front longitudinal force
        F_xf = C_K F_zf s_f (NOTES 8) has no C_K from data.  It is left out (C_K = 0), not
        taken from the prior: without GNSS and torques, v_x comes from the wheels, and a
        rolling-radius mismatch of 0.5 % between the axles reads as a slip giving
        C_K F_zf 0.005, about 400 N at the prior's C_K, as large as the true force.  What is
        left out is F_xf sin(delta) in eqs (7) and (10): in a stage-2 window (nearly
        constant speed, |mean a_x| < 0.6 m/s^2) F_xf is the drag and rolling resistance, a
        few hundred N, and sin(delta) < 0.06, so under 1 % of the lateral force.
        """
        v = self.vehicle
        self.known = lateral.Known(
            m=v.mass,
            L=v.wheelbase,
            r=v.wheel_radius,
            k_phi=v.roll_stiffness,
            c_phi=v.roll_damping,
            l_f=l_f,
            h=h,
            C_K=0.0 if c_k is None else c_k,
            g=v.g,
            per_axle=self.cfg.per_axle,
            roll_by_ay=self.cfg.roll_by_ay,
        )
        ok = l_f_std is not None and math.isfinite(l_f_std) and l_f_std > 0
        self.l_f_std = max(l_f_std, tuning.L_F_STD_MIN) if ok else self.priors["l_f"].std
        ok = h_std is not None and math.isfinite(h_std) and h_std >= 0
        self.h_std = h_std if ok else self.priors["h"].std

    def _initial_cov(self) -> np.ndarray:
        """Dynamic states, the parameters as kept, l_f as stage 1 gives it, and their correlation."""
        P0 = np.zeros((self._n, self._n))
        P0[:4, :4] = np.diag([0.5**2, 0.02**2, 0.01**2, 0.02**2])
        P0[self._p, self._p] = self.theta_P
        sd, c = self.l_f_std, lateral.L_F
        P0[c, c] = sd * sd
        if self._n > lateral.BANK:
            P0[lateral.BANK, lateral.BANK] = tuning.BANK_STD**2
        if self.cross is not None:
            # correlation kept, scaled to stage 1's std now (a congruence: stays positive definite)
            cov, sd_then = self.cross
            P0[self._p, c] = P0[c, self._p] = cov * (sd / sd_then)
        return P0

    def end_window(self) -> None:
        if self.filter is not None and not self._sane():
            self._drop_window("its parameters left what a car has (a disturbance no gate caught)")
        super().end_window()
        self._settle.clear()

    def _sane(self) -> bool:
        """Whether the open filter's parameters are numbers within what a car has (ParamSpec's range)."""
        x, P = self.filter_state()
        p = self._p
        return self._in_range(x[p]) and bool(np.all(np.isfinite(P[p, p])))

    def _drop_window(self, why: str) -> None:
        """Drop the open window as diverged: the parameters back to its start, its innovations, roll
        information and batch-check rows out of the totals.  What is kept never holds a number no
        car has (an I_x of 2.5e12 kg m^2 after a kerb strike's rise the gate let through)."""
        self.restarts += 1
        self.last_error = f"window dropped: {why}"
        log.warning("stage 2 %s window dropped: %s", self.kind, why)
        self._undo_window()
        self.window, self.roll_window = Consistency(), Consistency()
        self.check.record.drop()

    def _undo_window(self) -> None:
        """The open window undone (a window that diverged, or one dropped): the parameters back to its
        start, its innovations and roll information (with that information's noise share) out of the
        totals, the filter closed."""
        theta, cov, cross = self._win_start
        self.theta, self.theta_P, self.cross = theta.copy(), cov.copy(), cross
        self.total.drop(self.window)
        self.roll_total.drop(self.roll_window)
        self.roll_info -= self._info_window
        self._info_window = 0.0
        self._noise_from = self.roll_updates  # the window's noise share goes with its information
        self.filter = None
        self.t_last = None
        self._settle.clear()

    def l_f_correlation(self) -> np.ndarray | None:
        """Correlation of the published (C_alpha, I_z, I_x) with the considered l_f: the open
        window's, else the kept one; None before any window."""
        if self.filter is not None:
            P, p, c = self.filter_state()[1], self._p, lateral.L_F
            cov, sd, Pp = P[p, c], math.sqrt(P[c, c]), P[p, p]
        elif self.cross is not None:
            (cov, sd), Pp = self.cross, self.theta_P
        else:
            return None
        M = self._M
        return (M @ cov) / (sd * np.sqrt(np.diagonal(M @ Pp @ M.T)))

    flagged = ("C_alpha", "I_z", "I_x")

    NO_ROLL = (
        "no roll-rate measurement reached stage 2 (a roll-rate gyro is needed): the roll mode is "
        "unobservable, so I_x keeps its prior"
    )

    def snapshot(self) -> dict[str, Estimate]:
        """As every stage's, but I_x is not_run, with the reason, while stage 2 has run with no
        roll-rate measurement: a_y has no roll term (eq 7) and the roll does not act back on
        v_y and the yaw rate, so the roll states and I_x take nothing from the other rows (the
        filter keeps them at their prior: frozen, whatever their values) and C_alpha and I_z
        are estimated as with a gyro."""
        out = super().snapshot()
        e = out.get("I_x")
        if e is not None and self.updates > 0 and self.roll_updates == 0:
            out["I_x"] = replace(e, status=NOT_RUN, valid=False, reason=self.NO_ROLL)
        elif e is not None and e.status == NOT_IDENTIFIABLE and e.reason is None:
            out["I_x"] = replace(e, reason=self.NOT_EXCITED)
        return out

    NOT_EXCITED = (
        "roll not excited: the drive's lateral transients have not even halved I_x's prior std "
        "(quick steering reversals at speed excite the roll)"
    )

    def roll_mismatch(self) -> tuple[float, str | None]:
        """(factor on I_x's std, reason or None) from the roll-rate row's own innovations: their
        size (NIS) and whiteness, as :meth:`mismatch` tests all rows."""
        return _verdict(self.roll_total, "roll-rate innovations", "roll-rate innovations", "roll model mismatch")

    def adjust(self, name: str, value: float, std: float) -> tuple[float, float, str | None]:
        """C_alpha and I_z: the batch check's verdict (output_error.compare: where the model
        mismatches, the output-error fit's value with the std widened).

        I_x's std carries what eq (9) takes as known but is not (see ROLL_MODEL_ERROR):

        - stage 1's h: the roll moment m h (a_y + g phi) scales with it, and I_x with the
          moment (the roll rate's response above the roll frequency is m h a_y / (I_x s)),
          so h's relative std is I_x's too (an upper bound: below the roll frequency the
          response does not depend on I_x);
        - when the roll-rate innovations show that eq (9) does not describe this car's roll
          (their size or colour), the std widens by the roll row's own factor and takes
          ROLL_MODEL_ERROR of I_x as model error, and I_x is not valid, with the reason.
        """
        if name in output_error.CHECKED and self.known is not None and self.cfg.batch_check:
            fit = self.batch_fit()
            if fit is None:
                return value, std, None
            return output_error.against(name, value, std, fit, output_error.Z_MAX)  # the bend: cover()
        if name != "I_x" or self.known is None or not (math.isfinite(value) and math.isfinite(std)):
            return value, std, None
        h_rel = (self.h_std or 0.0) / self.known.h if self.known.h > 0 else 0.0
        factor, why = self.roll_mismatch()
        if why is not None:
            std *= max(1.0, factor / self.mismatch()[0])  # the lateral rows' factor is in std already
            h_rel = math.hypot(h_rel, tuning.ROLL_MODEL_ERROR)
            why = (
                f"{why}; eq (9) rolls the whole mass about the ground, a car its sprung mass about a roll "
                f"axis above it: the I_x that fits is an effective one, and its std carries "
                f"{100 * tuning.ROLL_MODEL_ERROR:.0f} % for that"
            )
        quiet = self.not_excited()
        if quiet is not None:  # no filter's covariance may claim more than the drive holds
            std = max(std, abs(value) * quiet)
        std = math.hypot(std, abs(value) * h_rel)
        # the accelerometer's noise through eq (9): I_x read too large by up to this share (accel_share)
        # of its value where the roll-rate rows outweigh the prior, little where they hold next to
        # nothing (the paper car's over-damped roll); and never wider than the prior's std with the
        # distance the rows moved I_x from the prior (a drive whose roll rate is all noise)
        share = self.accel_share()
        weight = self.roll_info / (self.roll_info + self._ix_prior_rel() ** -2) if self.roll_info > 0.0 else 0.0
        p = self.priors["I_x"]
        wide = min(math.hypot(std, abs(value) * share * weight), math.hypot(p.std, value - p.value))
        std = max(std, wide)
        if why is None and quiet is not None:
            why = Hard(
                f"roll not excited: the drive's roll rate tells I_x to {100 * quiet:.0f} % at best "
                f"(its prior: {100 * self._ix_prior_rel():.0f} %); quick steering reversals at speed excite the roll"
            )
        elif why is None and share * weight > BY_NAME["I_x"].useful_rel:  # its std alone is then beyond use
            why = Hard(
                f"roll not excited: the accelerometer's noise makes up {100 * share:.0f} % of what the roll rate "
                f"tells of I_x, the drive's own lateral transients the rest (eq (9) is driven by the measured a_y: "
                f"I_x reads too large by up to that share, which its std carries); quick steering reversals at "
                f"speed excite the roll"
            )
        return value, std, why

    def cover(self, name: str, value: float, std: float) -> tuple[float, str | None]:
        """C_alpha's and I_z's std covers the batch check's fit with a falling secant where the linear
        tyre was kept (output_error.cover_bend, docs/decisions/0019), and C_alpha's the tyres' value
        where the axles are further apart than tyres alike allow (output_error.cover_axles)."""
        if name in output_error.CHECKED and self.known is not None and self.cfg.batch_check:
            fit = self.batch_fit()
            if fit is not None:
                _, std, note = output_error.cover_bend(name, value, std, None, fit)
                if self.cfg.per_axle and not self._axles_given():
                    std, axles = output_error.cover_axles(name, value, std, fit, self.known.l_f, self.known.L)
                    if axles is not None:
                        note = axles if note is None else f"{note}; {axles}"
                return std, note
        return std, None

    def _axles_given(self) -> bool:
        """Whether the profile gives each axle's C_alpha prior (tyres that differ, declared)."""
        return self.priors.get("C_alpha_f") is not None and self.priors.get("C_alpha_r") is not None

    def settle(self) -> None:
        """Let a background check end, and solve now on every row kept: the next snapshot is then
        the same whenever it is taken (LearnerConfig.check_executor), and the same as a replay's of
        the same frames, whose check solves on every row at the log's end (the bend's cover,
        Stage2.cover, reads the fit whether or not the filter agrees with it)."""
        self.check.wait()
        if self.known is not None and self.cfg.batch_check:
            self.batch_fit(now=True, every=True)

    def batch_fit(self, now: bool = False, every: bool = False) -> output_error.Fit | None:
        """The output-error fit of the windows kept (core.output_error), solved again when stale:
        per axle, from the filter's values, with the profile's priors (the mean's, and the
        axles' half-difference AXLE_SPLIT of it, as _prior).  ``now``: not in the background;
        ``every``: solved again on any new row."""
        c = self.check
        if not (c.stale(self.filter is not None) or (every and c.behind)):
            return c.fit
        p, theta = self.priors, self.params()[0]
        rel = np.array([p["C_alpha"].std / p["C_alpha"].value, p["I_z"].std / p["I_z"].value])
        m, d = rel[0] ** 2, (tuning.AXLE_SPLIT * rel[0]) ** 2
        P0 = np.array([[m + d, m - d, 0.0], [m - d, m + d, 0.0], [0.0, 0.0, rel[1] ** 2]])
        t0 = np.log([p["C_alpha"].value, p["C_alpha"].value, p["I_z"].value])
        c_r = theta[1] if self.cfg.per_axle else theta[0]
        n = self.cfg.noise
        sigma = (n.gyro * n.inflate, n.accel * n.inflate)
        return c.solve(self.known, sigma, t0, P0, [np.array([theta[0], c_r, theta[2]])], now=now)

    def _ix_prior_rel(self) -> float:
        p = self.priors["I_x"]
        return p.std / abs(p.value) if p.value else math.inf

    def not_excited(self) -> float | None:
        """I_x's best relative std from the roll-rate rows' information (RollExcitation), less
        what the accelerometer's noise put in (:meth:`noise_info`), and its prior, when that
        does not even halve the prior's (the ``not_identifiable`` rule); None when the drive
        excites the roll that much, or before any roll-rate row."""
        if self.roll_updates == 0:
            return None
        p = self._ix_prior_rel()
        post = 1.0 / math.sqrt(1.0 / (p * p) + max(self.roll_info - self.noise_info(), 0.0))
        return post if post > 0.5 * p else None

    def noise_info(self) -> float:
        """Of :attr:`roll_info`, what the accelerometer's white noise alone is expected to have put
        in (verdict.accel_noise_excitation, per roll-rate update of each window kept)."""
        return self._noise_info + self._noise_rate * (self.roll_updates - self._noise_from)

    def accel_share(self) -> float:
        """The share of the roll-rate rows' information on ln I_x that the accelerometer's noise
        makes up (0 to 1; 0 before any).  Eq (9) is driven by the measured a_y: where the drive's
        own lateral transients are slow and small (an ordinary drive), the noise is most of what
        moves the model's roll rate at the frequencies where I_x matters, and the filter, whose
        gyro does not see that response, takes I_x too large to damp it, by up to this share of
        its value (an errors-in-variables attenuation; docs/decisions/0029)."""
        if not self.roll_info > 0.0:
            return 0.0
        return min(1.0, max(self.noise_info(), 0.0) / self.roll_info)

    def mismatch(self) -> tuple[float, str | None]:
        """From the innovations of every window kept: their size (NIS) and whiteness."""
        return _verdict(self.total, "innovations", "a_y innovations", "model mismatch")

    def _bounds(self) -> Bounds:
        return Bounds(self._n, log=(lateral.C_F, lateral.C_R, lateral.I_Z, lateral.I_X))  # stiffnesses, inertias > 0

    def _scale(self) -> np.ndarray:
        s = lateral.SCALE
        return np.append(s, lateral.BANK_SCALE) if self._n > lateral.BANK else s

    def bank(self) -> tuple[float, float] | None:
        """The open window's road bank, g sin(bank) [m/s^2], and its std; None without the state or
        a window (lateral.BANK; LearnerConfig.bank)."""
        if self.filter is None or self._n <= lateral.BANK:
            return None
        x, P = self.filter_state()
        return float(x[lateral.BANK]), math.sqrt(max(float(P[lateral.BANK, lateral.BANK]), 0.0))

    def _fx(self, x, dt, u):
        return lateral.fx(x, dt, u, self.known)

    def _hx(self, x, u):
        return lateral.hx(x, u, self.known)

    def _jac_f(self, x, u):
        return lateral.jac_f(x, u.mean(axis=0) if u.ndim == 2 else u, self.known)

    def _jac_h(self, x, u):
        return lateral.jac_h(x, u, self.known)

    def _q_rate(self):
        dyn = np.square([tuning.V_Y_WALK, tuning.YAW_WALK, tuning.PHI_WALK, tuning.PHI_D_WALK])
        k = self.known
        if k.roll_by_ay:
            # eq (9) driven by the measured a_y takes the accelerometer's noise in as a roll moment:
            # m h n / I_x on phi'', white over each sample (variance per second: its variance times the tick)
            n = self.cfg.noise
            i_x = max(float(self.theta[self.keys.index("I_x")]), lateral.PARAM_FLOOR[3])
            dyn[3] += (k.m * k.h * n.accel * n.inflate / i_x) ** 2 * self.cfg.tick
        bank = [tuning.BANK_Q] if self._n > lateral.BANK else []  # the road's bank: a random walk
        return np.diag(np.concatenate([dyn, self._param_q(), [0.0], bank]))  # l_f: constant

    def _R(self):
        n = self.cfg.noise
        g, a = (n.gyro * n.inflate) ** 2, (n.accel * n.inflate) ** 2
        return np.diag([g, g, a])

    def inputs(self, s) -> list:
        """The model's input row u of one sample (a list: arrays are built once per step).

        v_x, best first: the rear wheels corrected for their slip, omega r / (1 + s_r)
        (eqs 13-14; smoother than GNSS), when stage 1's C_K and the rear torque are known;
        the speed filter's (GNSS + IMU, or the free-rolling axle); the raw GNSS speed; else
        the rear wheels as they are (a stage-2 window is at nearly constant speed: their
        slip is a few tenths of a percent).
        """
        y = s.values
        w_r = 0.5 * (y[ch.WS_RL] + y[ch.WS_RR])
        k = self.known
        a_x = y[ch.AX]
        if k.C_K > 0.0 and math.isfinite(w_r) and math.isfinite(y[ch.T_R]) and math.isfinite(a_x):
            f_zr = k.m * k.g * k.l_f / k.L + k.m * a_x * k.h / k.L
            s_r = (y[ch.T_R] / k.r) / (k.C_K * max(f_zr, 0.05 * k.m * k.g))
            v_x = w_r * k.r / (1.0 + s_r)
        elif math.isfinite(s.v_x):
            v_x = s.v_x
        elif math.isfinite(y[ch.SPEED]):
            v_x = y[ch.SPEED]
        else:
            v_x = w_r * k.r
        w_f = 0.5 * (y[ch.WS_FL] + y[ch.WS_FR])
        if not k.C_K > 0.0:  # no front drive force in the model: its inputs don't matter
            w_f, a_x = 0.0, 0.0
        return [y[ch.DELTA], v_x, w_f, a_x, y[ch.AY]]  # a_y: eq (9)'s input (lateral.Known.roll_by_ay)

    @staticmethod
    def measurements(s) -> tuple[np.ndarray, np.ndarray]:
        """z = [yaw rate, roll rate, a_y] of one sample, gyro offsets removed, and which are finite."""
        y = s.values
        z = np.array([y[ch.YAW] - s.yaw_bias, y[ch.ROLL] - s.roll_bias, y[ch.AY]])
        return z, np.isfinite(z)

    def _settled(self, t: float, z, mask, u) -> bool:
        """Whether the car is in a settled state to open a window on: the yaw rate and the
        steering have changed little over the last SETTLE_TIME (no step just behind it)."""
        if not mask[0]:
            return False
        q = self._settle
        q.append((t, z[0], u[lateral.U_DELTA]))
        while q and t - q[0][0] > tuning.SETTLE_TIME + 1e-9:
            q.popleft()
        span = t - q[0][0]
        if span < tuning.SETTLE_TIME - 0.5 * self.cfg.tick:
            return False
        yaw_acc = abs(q[-1][1] - q[0][1]) / span
        steer_rate = abs(q[-1][2] - q[0][2]) / span
        return yaw_acc <= tuning.SETTLED_YAW_ACC and steer_rate <= tuning.SETTLED_STEER_RATE

    def _start(self, z, mask, u) -> tuple[np.ndarray, np.ndarray]:
        """(x0, P0) from the data: the steady-state solution at the measured yaw rate and a_y.

        Rear axle in steady cornering: F_yr = m a_y l_f / L (yaw moment balance, eq 10) and
        F_yr = C_alpha_r (l_r r - v_y) / v_x (eq 12b), so v_y = l_r r - m a_y l_f v_x / (L C_alpha_r),
        with the C_alpha_r kept so far; its uncertainty enters v_y's std and their correlation.
        The roll angle from its balance with a_y, the roll rate as measured.
        """
        k = self.known
        yaw = z[0] if mask[0] else 0.0
        roll_rate = z[1] if mask[1] else 0.0
        a_y = z[2] if mask[2] else 0.0
        phi = lateral.quasi_static_roll(a_y, roll_rate, k) if mask[2] else 0.0
        l_f = k.l_f
        v_x = max(u[lateral.U_VX], lateral.V_MIN)
        rear = lateral.C_R if self.cfg.per_axle else lateral.C_F  # the state the rear stiffness is
        c_r = max(self.theta[rear - lateral.C_F], lateral.PARAM_FLOOR[1])
        g = k.m * a_y * l_f * v_x / k.L
        v_y = (k.L - l_f) * yaw - g / c_r
        x0 = np.concatenate([[v_y, yaw, phi, roll_rate], self.theta, [l_f], [0.0] * (self._n - lateral.BANK)])
        P0 = self._initial_cov()
        dv_dc = g / (c_r * c_r)  # d v_y / d C_alpha_r
        rest = slice(lateral.C_F, lateral.L_F + 1)  # the parameters and the considered l_f
        P0[lateral.V_Y, rest] = P0[rest, lateral.V_Y] = dv_dc * P0[rear, rest]
        P0[lateral.V_Y, lateral.V_Y] = tuning.V_Y_START_STD**2 + dv_dc**2 * P0[rear, rear]
        return x0, P0

    def _consistency(self, mask) -> bool:
        """Innovation tests of the last update; True when the window diverged and was restarted.

        Each update's normalised innovation squared (NIS, y' S^-1 y over the rows used)
        and the a_y innovation scaled by its predicted std feed the window's running sums
        (its consistency and whiteness, :class:`Consistency`).  A window whose recent NIS
        is far above what the filter predicts has diverged: it is dropped, the parameters
        go back to where the window started, and a new window opens on the next settled
        state.  A diverged window is never reported.
        """
        y, S = self.filter.innovation()
        y, S = y.tolist(), S.tolist()  # at most 3 rows: Python floats cost less than numpy's per-call overhead
        used = mask.tolist()
        r = sum(used[: lateral.Z_ROLL]) if used[lateral.Z_ROLL] else None
        # With eq (9) driven by the measured a_y the roll-rate row informs the roll states and I_x
        # only: its innovations are tested on their own (below, roll_mismatch), and the lateral
        # rows' alone decide the lateral model's consistency and a divergence.  A roll model that
        # misses a quick steering reversal (0.1 rad/s, 30 sigma, on the multi-body cars) then no
        # longer throws away the window, whose C_alpha and I_z it does not bear on.
        keep = [i for i in range(len(y)) if i != r] if self.known.roll_by_ay and r is not None else range(len(y))
        yk, Sk = [y[i] for i in keep], [[S[i][j] for j in keep] for i in keep]
        nis = quad_form(yk, Sk)
        if nis is None:  # S not positive definite (a degenerate filter): numpy's solve, as before
            try:
                nis = float(np.linalg.solve(np.array(Sk), np.array(yk)) @ np.array(yk))
            except np.linalg.LinAlgError:
                return False
        rows = len(keep)
        a = sum(used[: lateral.Z_AY]) if used[lateral.Z_AY] else None
        e = y[a] / math.sqrt(S[a][a]) if a is not None and S[a][a] > 0 else None
        if rows:
            self.window.add(nis, rows, e)
            self.total.add(nis, rows, e)
        # the roll-rate row on its own: the roll model (eq 9) can fail while the lateral one holds
        if r is not None and S[r][r] > 0:
            e_r = y[r] / math.sqrt(S[r][r])
            self.roll_window.add(e_r * e_r, 1, e_r)
            self.roll_total.add(e_r * e_r, 1, e_r)
        if self.window.recent() > tuning.DIVERGED_NIS:
            self.restarts += 1
            why = f"innovations {self.window.recent():.0f}x their predicted size"
            log.info("stage 2 %s window diverged (%s); restarted from the window's start", self.kind, why)
            self.last_error = f"window restarted: {why}"
            self._undo_window()
            return True
        return False

    def runnable(self) -> bool:
        """Whether :meth:`steps` can take samples now: an open compiled window, its axles' split
        freed (while held, each step may free it: :meth:`_free_split`, in Python)."""
        # cfg.compiled first: asking kernel() loads numba (~120 MB of LLVM) even to say no
        cls = kernel("LateralUKF") if self.cfg.compiled and self.filter is not None else None
        return (
            cls is not None and isinstance(self.filter, cls) and self._excite is not None
            and self.t_last is not None and not self.split_held
        )  # fmt: skip

    def steps(self, T, Y, D, G, a: int, b: int) -> int:
        """Take samples a..b-1 of a block (ticks T, values Y, derived D: v_x, v_std, a_x bias, yaw
        and roll offsets; G: gap flags) in the open window as :meth:`_step` would, compiled
        (core.kernels.lat_run), up to the first that needs :meth:`_step` itself (the window ends
        or restarts, a step fails, diverges or saves a last-good copy): its index, b when none
        did.  Needs :meth:`runnable`."""
        kern = kernel("lat_run")
        f, fs, ex, cfg, n = self.filter, self.filter._f, self._excite, self.cfg, self.cfg.noise
        every = cfg.stage2_every
        nsub = max(1, math.ceil(every * cfg.tick / lateral.MAX_SUBSTEP - 1e-9))
        j, w = f._grid(every + 1, nsub)
        ls = np.array([self.samples, self.updates, self.roll_updates, self.roll_info, self._info_window, self.t_last,
                       len(self._us)], dtype=float)  # fmt: skip
        us = np.zeros((every + 1, lateral.N_U))
        us[: len(self._us)] = self._us
        exa = np.array([ex.phi, ex.w, ex.chi, ex.chi_d, ex.t, math.nan if ex.u is None else ex.u, ex.i, ex.c, ex.kp,
                        ex.mh])  # fmt: skip
        conses = (self.window, self.total, self.roll_window, self.roll_total)
        cons = np.zeros((4, 10))
        ring = np.zeros((4, Consistency.RECENT))
        for q, c in enumerate(conses):
            cons[q] = (c.n, c.nis, c.rows, c.e2, c.ee, c.ne, 0.0 if c._e is None else c._e, c._e is not None,
                       len(c._recent), len(c._recent) % Consistency.RECENT)  # fmt: skip
            ring[q, : len(c._recent)] = c._recent
        settings = np.array([cfg.max_gap, every, cfg.save_every, (n.gyro * n.inflate) ** 2, tuning.DIVERGED_NIS,
                             float(self.known.roll_by_ay)])  # fmt: skip
        rec = np.empty(((b - a) // every + 1, 8))
        r, fs.x, fs.P, sig, y, S, nr = kern(
            T, Y, D, G, a, b, _STEP_CHANNELS, fs.x, fs.P, sig_in(f._sigmas, fs.x), f._lam_n, f._Wm, f._Wc, f.Q_rate,
            f.R, f.scale, f._kind, f._lo, f._span, f._known, f._c, j, w, nsub, ls, settings, us, exa, cons, ring, rec,
        )  # fmt: skip
        f._sigmas = sig_out(sig)
        if nr:
            fs.y, fs.S = y, S
            add = self.check.record.add
            for row in rec[:nr].tolist():
                add(row[0], row[1:5], row[5], row[6], row[7])
        samples, self.updates, self.roll_updates, self.roll_info, self._info_window, self.t_last, n_us = ls.tolist()
        self.samples, self.updates, self.roll_updates = int(samples), int(self.updates), int(self.roll_updates)
        self._us = us[: int(n_us)].tolist()
        ex.phi, ex.w, ex.chi, ex.chi_d, ex.t, u = exa[:6].tolist()
        ex.u = None if math.isnan(u) else u
        for q, c in enumerate(conses):
            row = cons[q].tolist()
            c.n, c.nis, c.rows, c.e2, c.ee, c.ne = int(row[0]), row[1], int(row[2]), row[3], row[4], int(row[5])
            c._e = row[6] if row[7] else None
            count, pos = int(row[8]), int(row[9])
            vals = ring[q].tolist()
            c._recent = deque((vals[pos:] + vals[:pos]) if count == Consistency.RECENT else vals[:count],
                              maxlen=Consistency.RECENT)  # fmt: skip
        return int(r)

    def _step(self, t, s):
        if self.known is None:
            return
        u = self.inputs(s)
        if not math.isfinite(u[0] + u[1] + u[2] + u[3]):
            self.end_window()
            return
        dt = None if self.t_last is None else t - self.t_last
        if self.filter is None or s.gap or dt is None or dt <= 0 or dt > self.cfg.max_gap:
            if self.filter is not None:
                self._keep_params()
                self.filter = None
                self._settle.clear()
            z, mask = self.measurements(s)
            if s.gap:
                self._settle.clear()
            if not self._settled(t, z, mask, u):
                self.t_last = t
                return
            self._win_start = (self.theta.copy(), self.theta_P.copy(), self.cross)
            self.window = Consistency()
            self.roll_window = Consistency()
            x0, P0 = self._start(z, mask, u)
            self.filter = self._new_filter(x0, P0, self._R())
            self.check.record.open()
            self._info_window = 0.0
            ix = self.theta[self.keys.index("I_x")]
            self._excite = RollExcitation(self.known, ix, x0[lateral.PHI], x0[lateral.PHI_D], t)
            n = self.cfg.noise
            self._noise_info = self.noise_info()  # the window before, closed
            noise = accel_noise_excitation(self.known, ix, self.cfg.tick, n.accel)  # per sample, of chi'^2
            self._noise_rate = noise / (n.gyro * n.inflate) ** 2  # per roll-rate update, as roll_info takes it
            self._noise_from = self.roll_updates
            self._us = [u]
            self.t_last = t
            return
        self._us.append(u)
        self.samples += 1
        if self._excite is not None:
            self._excite.step(t, s.values[ch.AY])
        if len(self._us) <= self.cfg.stage2_every:
            return
        # The filter steps every stage2_every samples (CPU) with the newest measurement;
        # the model sees every input sample of the step, interpolated between them:
        # holding the steering at either end (or its mean) would shift it in time,
        # and a yaw inertia would absorb the shift.
        us = np.array(self._us)
        z, mask = self.measurements(s)
        self.filter.predict(dt, us)
        self.filter.update(z, mask, us[-1])
        self.updates += 1
        self.roll_updates += bool(mask[lateral.Z_ROLL])
        roll = z[lateral.Z_ROLL] if mask[lateral.Z_ROLL] else math.nan
        self.check.record.add(t, us[-1], z[lateral.Z_YAW], z[lateral.Z_AY], roll)
        if mask[lateral.Z_ROLL] and self._excite is not None:
            n = self.cfg.noise
            chi_d = self._excite.chi_d  # (squared as a product: core.kernels.lat_run multiplies too)
            j = chi_d * chi_d / (n.gyro * n.inflate) ** 2  # the roll row's R
            self.roll_info += j
            self._info_window += j
        self._us = [u]
        if self._consistency(mask):
            return
        self._free_split()
        self.t_last = t
        if self.samples % self.cfg.save_every < self.cfg.stage2_every:
            self._save_good()
