"""Learners: one per stage and filter kind, with openpilot's interface.

``handle(t, sample)`` feeds one aligned sample (only inside the stage's
window), ``snapshot()`` publishes value, std, validity and status per
parameter, ``reset()`` returns to the priors.  A non-finite state or a failed
Cholesky resets the stage to its last good estimate and says so; it never
raises.

Convergence and identifiability are judged on the filter's own uncertainty,
never on a truth value:

- ``converged``: std below the parameter's ``converged_rel`` share of its value;
- ``not_identifiable``: after ``min_samples`` in windows the data has not even
  halved the prior std (NOTES 12), so the number is the prior's, not the data's;
- ``uncertain``: in between.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from .. import channels as ch
from ..errors import FilterError
from . import batch, lateral, longitudinal, output_error
from .bounds import Bounds
from .compiled import kernel
from .filters import EKF, UKF
from .params import BY_NAME, STAGE1, STAGE2
from .result import CONVERGED, INVALID, NOT_IDENTIFIABLE, NOT_RUN, UNCERTAIN, Estimate, finite

log = logging.getLogger(__name__)

_BOTH_AXLES = np.ones(2, dtype=bool)  # stage 1 steps only on blocks with both axles' speeds

# Stage 2's dynamic states walk by model error only (std per sqrt(s), eqs (5), (8), (9)).
# v_y has no sensor: the filter sees it through a_y alone, so its walk decides how much
# of the accelerometer's noise it takes for v_y, and a noisy v_y is a noisy slip angle,
# which pulls C_alpha and I_z low (errors in variables).  0.05 m/s per sqrt(s) let v_y
# move in one 40 ms filter step as if pushed by 0.25 m/s^2 of unmodelled lateral
# acceleration, five times the accelerometer's noise, and took 3 % off C_alpha and I_z
# on the RAV4's drive (8 % with 0.1 m/s^2 of noise); 0.005 allows 0.025 m/s^2.
V_Y_WALK = 0.005  # m/s per sqrt(s)
YAW_WALK = 0.02  # rad/s per sqrt(s)
PHI_WALK = 1e-4  # rad per sqrt(s)
PHI_D_WALK = 0.005  # rad/s per sqrt(s)
L_F_STD_MIN = 1e-4  # m: stage 1's l_f is never taken as exact (keeps the covariance positive definite)

# A stage-2 window opens on a settled state: over the last SETTLE_TIME the yaw rate and the
# road-wheel angle changed by less than these rates (a window opening just after a steering
# step drove C_alpha and I_x the wrong way, measured on the independent models)
SETTLE_TIME = 0.2  # s
SETTLED_YAW_ACC = 0.15  # rad/s^2
SETTLED_STEER_RATE = math.radians(3.0)  # rad/s of road-wheel angle
V_Y_START_STD = 0.05  # m/s: the steady-state start's own error (transients, slopes), beside C_alpha's share
# Model mismatch (BENCHMARKS.md, "The independent models after est's work"): on vdp's own simulator, whose model
# is the estimator's, stage 2's NIS per row is about 0.18 and both lag-1 autocorrelations
# about 0; on the independent models they reached 1.2 and 0.65.  Beyond these the model
# does not explain the data: the stds widen by sqrt((1 + rho) / (1 - rho)) (the evidence
# of correlated residuals is overstated by that much) and by sqrt(NIS / NIS_MATCHED), and
# the parameters the mismatch bears on are not valid, with the reason.
NIS_MATCHED = 0.2
NIS_MISMATCH = 0.6
# stage 1's front-minus-rear batch residuals with the bending tyre and the slip offsets
# (core.longitudinal): -0.05 to 0.08 on vdp's own simulator with realistic noise, 0.15-0.39
# on the independent models (BENCHMARKS.md, "A stage 1 that holds with a real tyre")
RHO_MISMATCH = 0.12
# A tyre whose stiffness per unit load falls with load (by q per unit of relative load) shows
# only (1 - q) of the load transfer in its slips, and nothing in the slips tells q from h.
# When the data say the tyre law does not explain them, h's std takes q's typical size
# (0.1 on the brush cars, 0-0.3 for road tyres) as a consider term.
LOAD_SENSITIVITY = 0.1
# Below this reduced chi-square the batch residuals are far under the noise R assumes (a
# noise-free drive) and their colour is numerical: 0.003 and 0.011 on vdp's own noise-free
# drives, where the lag-1 correlation reached 0.27; 0.06-0.22 on the independent models'.
CHI2_QUIET = 0.03
# The reduced chi-square of stage 1's batch residuals that a matching model leaves with realistic
# noise (R is the sensors' noise inflated by Noise.inflate): 0.22 and 0.32 on vdp/paper seed 1 and
# vdp/small seed 2 (the tuning cases, docs/decisions/0001-honest-std.md).  The size in _widen.
CHI2_MATCHED = 0.3
RHO_MISMATCH_2 = 0.45  # stage 2's a_y innovations (0.31 on one vdp seed with its a_y bias, 0.65 on brush tyres)
# I_x's model error when the roll-rate innovations show a mismatch (relative, 1 sigma): eq (9)
# puts the whole mass at the CG height h, rolling about the ground.  A car rolls its sprung
# mass (85-90 % of m) about a roll axis 0.05-0.15 m above the ground, so the true roll moment
# is about 0.6-0.85 of the model's, and the sprung mass's sideways motion as it rolls (a
# term eq 7 leaves out) moved I_x by +45 % on one independent model
# (notes/estimation-findings.md).  The I_x that fits the data is then an effective value,
# off the inertia by as much as these: 0.3 of it as one sigma.
ROLL_MODEL_ERROR = 0.3
DIVERGED_NIS = 25.0  # mean NIS per row over Consistency.RECENT updates beyond which a window has diverged

# Stage 1's batch check (core.batch): the blocks kept, how often the batch optimum is
# solved, and how far (squared Mahalanobis distance, 3 parameters) the filter may sit
# from it before it is re-seeded there (chi-square, 3 dof, 0.999: 16.3)
BATCH_BLOCKS = 3000  # 5 min of stage-1 windows in 0.1 s blocks
# blocks between checks: 20 (2 s of window), or a quarter of the blocks kept once that is more,
# at most BATCH_EVERY_MAX (Stage1.check_due).  A check costs about in proportion to the blocks
# kept, so at every 20 it grew with the square of the drive until the record was full: 27 % of
# an hour's replay, 2.1 s of CPU (BENCHMARKS.md, "scan").  The early checks, which re-seed a
# filter started far off, come as often as before; the cap keeps what a live service commits
# and hands to stage 2 at most 20 s of window behind the check; the log's end solves once more
# on every block (TwoStageEstimator.finish).  The far check (the prior's mean as a start, the
# tyre-shape test, the model's error) comes every BATCH_FAR_EVERY x BATCH_EVERY blocks, as before.
BATCH_EVERY = 20
BATCH_EVERY_MAX = 200
BATCH_FAR_EVERY = 4  # every this many dense checks' blocks, a far one (the far start costs the most)
RESEED_M2 = 16.3

# Stage 2's cornering stiffness per axle (Stage2): the profile's C_alpha prior is the mean's;
# the half-difference (C_f - C_r) / 2 gets this share of its std, independently (a real
# car's axles differ by up to about a third; a tight C_alpha prior means a known car)
AXLE_SPLIT = 0.5
AXLE_CORR_MAX = 0.95  # |correlation| of the two beyond this: the data know one combination of them
# The split is held (one C_alpha in effect: its half-difference's std SPLIT_HELD of C_alpha's prior
# std) until the data know the axles' mean to SPLIT_FREE_REL, then freed to AXLE_SPLIT.  In a steady
# corner the data fix each axle's force, F = C alpha, not C and the slip angle (v_y, no sensor)
# apart; one C_alpha closes that, two leave a curve (C_f, C_r, v_y) along which a filter started
# far off (priors x0.6 on vdp's `suv`) slid to C_alpha 0.1x with a std of 1 % and never came back.
SPLIT_HELD = 0.1
SPLIT_FREE_REL = 0.05

# Stage 1's tyre shape (core.longitudinal), estimated beside l_f, h, C_K and not reported:
# priors (mean, std).  The bend b = 1 / (3 mu) of a brush tyre is 0.28-0.42 for mu 0.8-1.2;
# the prior is centred on the paper's linear tyre (b = 0) and wide enough for any of them.
# The slip offsets: rolling resistance f_r / C_K (about 0.001) and a rolling radius a few
# tenths of a per cent off, mostly common to both axles (the same tyres, one radius in the
# profile); their front-minus-rear half-difference is smaller (0.00014 on the multi-body
# car).  A free difference costs l_f its information where one axle only brakes (a
# front-driven car: l_f's std 0.8 % instead of 0.5 %).
BEND_PRIOR = (0.0, 0.5)
CUBIC_PRIOR = (0.0, 1.0)  # c = 5 / (27 mu^2) of a brush tyre, 0.13-0.29; a Magic-Formula tyre's 0.3-0.6
OFFSET_STD = 0.002  # their common part
OFFSET_SPLIT_STD = 0.0005  # (s_0f - s_0r) / 2
# Three more parameters cost l_f, h and C_K precision (a front-driven car on vdp's own tyre:
# l_f's std 0.8 % instead of 0.5 %), so stage 1 starts on the paper's straight line (the
# shape held at 0 by a prior this tight) and frees the shape once the data demand it: the
# batch cost falls by more than SHAPE_LR times the residuals' noise level (reduced chi-square,
# times (1 + rho) / (1 - rho) for their correlation) when the shape is free.  On vdp's own
# simulator that drop stayed at 0.3-25, on the independent models 119-1,001 (BENCHMARKS.md,
# "A stage 1 that holds with a real tyre").
SHAPE_OFF_STD = (1e-4, 1e-4, 1e-6)  # b, c, each offset
SHAPE_LR = 60.0


@dataclass(frozen=True)
class Noise:
    """Measurement noise (1-sigma, SI) assumed by the filters."""

    wheel_speed: float = 0.03  # rad/s, per wheel
    accel: float = 0.05  # m/s^2
    gyro: float = math.radians(0.1)  # rad/s
    speed: float = 0.05  # m/s, GNSS
    # model error added on top, as a fraction of the sensor noise
    inflate: float = 1.5


@dataclass(frozen=True)
class LearnerConfig:
    noise: Noise = field(default_factory=Noise)
    max_gap: float = 0.05  # s; a longer step restarts the dynamic states
    min_samples: int = 500  # samples in windows before identifiability is judged
    save_every: int = 50  # keep a "last good" copy this often
    # random walk of the parameters, std per sqrt(s), as a fraction of the prior std
    param_walk: float = 1e-4
    # the speed error is correlated over many samples; inflate its std for the filter
    speed_corr: float = 20.0
    tick: float = 0.01  # s between aligned samples (set by the estimator from its config)
    block_time: float = 0.1  # s: stage 1 averages the samples of this long a block per filter step
    stage2_step: float = 0.04  # s: stage 2 steps its filter this often (CPU), inputs in between still used
    # Stage 2 estimates the front and the rear cornering stiffness separately (published:
    # their mean as C_alpha, each in its extra); off: one C_alpha for both axles.  On by default
    # since eq (9) is driven by the measured a_y (roll_by_ay): one C_alpha cannot fit a car whose
    # axles differ (its best fit of mb/bmw_320i's drive is C_alpha +46 %, I_z +53 %), and the
    # roll row no longer pulls it back (BENCHMARKS.md, "Stage 2 on the independent models")
    per_axle: bool = True
    # Stage 2's roll, eq (9), driven by the measured a_y (lateral.Known.roll_by_ay): the roll-rate
    # row then informs the roll states and I_x, not C_alpha and I_z
    roll_by_ay: bool = True
    # Stage 2's batch check (core.output_error): C_alpha's and I_z's stds widen where an output-error
    # fit of the windows disagrees with the filter or with itself (off: the filter's own stds)
    batch_check: bool = True
    # Stage 1 reads C_K as the small-slip (initial) stiffness of a tyre law that bends
    # (core.longitudinal), so it takes only blocks where both axles use at most this share of
    # their load (|F_x| / F_z): beyond it the law's third-order series leaves the brush curve
    # (and near the friction limit no series holds).
    small_slip: float = 0.5
    # a block in which an axle's slip changed faster than this [1/s] saw a wheel spin or
    # lock (Stage1._spun); None: no such check.  The paper drive's stage 1 changes the
    # slip by at most about 0.15/s (a front axle at its grip, traction control holding it).
    spin_rate: float | None = 1.0
    spin_slip: float = 0.2  # beyond this |slip| a road tyre is past its grip (about 0.1-0.2)
    # the UKF's steps compiled (core.kernels: the same numbers, ~N x less CPU); False: numpy
    # (core.filters with the models as written), the reference the tests compare them with
    compiled: bool = True
    # stage 2's batch check solved on this executor (concurrent.futures' submit), the last finished
    # fit reported meanwhile: the live service's one background thread, since a full record of a
    # bending tyre costs ~20 s of numpy CPU; None: in line.  The caller owns and shuts it down.
    check_executor: object | None = field(default=None, compare=False, repr=False)

    @property
    def block(self) -> int:
        return max(3, round(self.block_time / self.tick))

    @property
    def stage2_every(self) -> int:
        return max(1, round(self.stage2_step / self.tick))


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


def _verdict(c: Consistency, size: str, colour: str, kind: str) -> tuple[float, str | None]:
    """(factor on the stds, reason or None) from innovations' size (NIS) and whiteness.

    ``size`` and ``colour`` name the innovations in the two reasons, ``kind`` heads them.
    """
    nis, rho = c.ratio, c.rho
    if nis is None or c.n < Consistency.RECENT:
        return 1.0, None
    why = []
    if nis > NIS_MISMATCH:
        why.append(f"{size} {math.sqrt(nis / NIS_MATCHED):.1f}x the size a matching model leaves")
    # residuals far below the noise (a noise-free drive): their colour is no finding (the factor
    # charges it in proportion to their size)
    if rho is not None and rho > RHO_MISMATCH_2 and nis >= 0.5 * NIS_MATCHED:
        why.append(f"{colour} not white (lag-1 correlation {rho:.3f} > {RHO_MISMATCH_2})")
    return _widen(rho, nis / NIS_MATCHED), (f"{kind}: " + "; ".join(why)) if why else None


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


class StageLearner:
    """Common machinery: filter life cycle, last-good copies, snapshot."""

    stage = 0
    names: tuple[str, ...] = ()
    model = None
    compiled_ukf: str | None = None  # the model's compiled UKF in core.kernels, if it has one

    def __init__(self, kind: str, vehicle, priors, cfg: LearnerConfig | None = None):
        self.kind = kind
        self.vehicle = vehicle
        self.priors = priors
        self.cfg = cfg or LearnerConfig()
        self.resets = 0
        self.last_error: str | None = None
        self.reset()

    # -- interface -----------------------------------------------------
    def reset(self) -> None:
        p = self.model.PARAM_SLICE
        n = len(self.model.STATE_NAMES)
        self.theta, self.theta_P = self._prior()
        self.prior_std = np.sqrt(np.diagonal(self.theta_P))  # of the filter's parameters (their walk)
        self.pub_prior_std = np.sqrt(np.diagonal(self._publish(self.theta, self.theta_P)[1]))  # of names
        # covariance of the parameters with the model's consider state, and that state's std
        # then (a window keeps it for the next one); None for a model without one
        self.cross: tuple[np.ndarray, float] | None = None
        self.filter = None
        self.samples = 0
        self.t_last: float | None = None
        self._good = (self.theta.copy(), self.theta_P.copy(), None)
        self._n, self._p = n, p
        self.bounds = self._bounds()

    def handle(self, t: float, s) -> None:
        try:
            self._step(t, s)
        except FilterError as exc:
            self._recover(str(exc))

    def set_params(self, theta, cov, samples: int) -> None:
        """Start from given estimates of the published parameters (a restart restoring stored values)."""
        theta, cov = np.asarray(theta, dtype=float), np.array(cov, dtype=float)
        if samples > 0:  # a published std holds the model's floor (honest_std): the snapshot adds it again
            for i, name in enumerate(self.names):
                f = BY_NAME[name].floor_rel * abs(theta[i])
                cov[i, i] = max(cov[i, i] - f * f, 0.01 * cov[i, i])
        self.theta, self.theta_P = self._unpublish(theta, cov)
        self.cross = None
        self._good = (self.theta.copy(), self.theta_P.copy(), None)
        self.samples = max(self.samples, int(samples))
        self.filter = None
        self.t_last = None

    def end_window(self) -> None:
        """Close the window: keep the parameters, drop the dynamic states."""
        if self.filter is not None:
            self._keep_params()
        self.filter = None
        self.t_last = None

    def filter_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The open filter's (x, P) in the model's SI units (the filter estimates bounded transforms)."""
        t = self.filter.x
        return self.bounds.to_si(t), self.bounds.cov_to_si(t, self.filter.P)

    def params(self) -> tuple[np.ndarray, np.ndarray]:
        """(value, covariance) of the filter's parameters (SI): the open filter's, else the kept ones."""
        if self.filter is not None:
            x, P = self.filter_state()
            return x[self._p], P[self._p, self._p]
        return self.theta, self.theta_P

    def status(self, spec, value: float, std: float, prior_std: float) -> str:
        """A parameter's status from its value and std (judged on the filter's own uncertainty)."""
        if self.samples == 0:
            return NOT_RUN
        if not (math.isfinite(value) and math.isfinite(std)) or not (spec.lo <= value <= spec.hi):
            return INVALID
        if std <= spec.converged_rel * abs(value):
            return CONVERGED
        if self.samples >= self.cfg.min_samples and std > 0.5 * prior_std:
            return NOT_IDENTIFIABLE
        return UNCERTAIN

    def snapshot(self) -> dict[str, Estimate]:
        theta, cov = self.params()
        pub, pcov = self._publish(theta, cov)
        out = {}
        factor, why = self.mismatch()
        err = self.model_error()  # None, or weighted by how strongly the data show the mismatch
        for i, name in enumerate(self.names):
            spec = BY_NAME[name]
            value = float(pub[i])
            std = factor * math.sqrt(pcov[i, i]) if pcov[i, i] > 0 else math.nan
            if err is not None:
                std = math.hypot(std, err[i])
            filtered = value
            value, std, own = self.adjust(name, value, std)
            status = self.status(spec, value, std, self.pub_prior_std[i])
            reason = why if name in self.flagged and status not in (NOT_RUN, INVALID) else None
            if own is not None and status not in (NOT_RUN, INVALID):
                if reason is None:
                    reason = own
                elif value != filtered:  # a value that is not the filter's says where it came from first
                    reason = f"{own}; {reason}"
            if status != NOT_RUN:  # a prior alone keeps its own std
                std = honest_std(spec, value, std)
            valid = useful(spec, status, value, std) and not isinstance(own, Hard)
            if not valid and reason is None and status in (CONVERGED, UNCERTAIN) and math.isfinite(std):
                reason = too_wide(spec, value, std)
            out[name] = Estimate(
                name=name,
                value=finite(value),
                std=finite(std),
                unit=spec.unit,
                status=status,
                valid=valid,
                stage=self.stage,
                samples=self.samples,
                reason=reason,
                extra=self._extra(name, theta, cov, factor, valid, reason),
            )
        return out

    # -- the filter's parameters and the published ones -------------------
    # A learner may estimate other parameters than it publishes (stage 2: C_alpha per axle,
    # published as their mean).  The identity here; a learner that differs overrides these.
    def _prior(self) -> tuple[np.ndarray, np.ndarray]:
        """(value, covariance) of the filter's parameters from the profile's priors."""
        return (
            np.array([self.priors[k].value for k in self.names]),
            np.diag([self.priors[k].std ** 2 for k in self.names]),
        )

    def _publish(self, theta, cov) -> tuple[np.ndarray, np.ndarray]:
        """(value, covariance) of the published parameters (``names``) from the filter's."""
        return theta, cov

    def _unpublish(self, theta, cov) -> tuple[np.ndarray, np.ndarray]:
        """The filter's parameters from published ones (a restore)."""
        return theta.copy(), cov.copy()

    def _in_range(self, theta) -> bool:
        return all(BY_NAME[n].lo <= v <= BY_NAME[n].hi for n, v in zip(self.names, theta))

    def _extra(self, name, theta, cov, factor, valid, reason) -> dict:
        """Further named numbers of a published parameter (Estimate.extra)."""
        return {}

    # parameters a model mismatch makes not valid (the others only get the wider std)
    flagged: tuple[str, ...] = ()

    def mismatch(self) -> tuple[float, str | None]:
        """(factor on the stds, reason the model does not explain the data or None)."""
        return 1.0, None

    def model_error(self) -> np.ndarray | None:
        """Per parameter, a std for the model's own error, added when it mismatches (or None)."""
        return None

    def adjust(self, name: str, value: float, std: float) -> tuple[float, float, str | None]:
        """One parameter's (value, std, reason it is not valid or None) after what the stage knows
        of it beyond the filter's covariance; by default both as they are."""
        return value, std, None

    def values(self) -> tuple:
        """((value, std), ...) of the parameters: the trace's cheap view of snapshot()."""
        theta, var = self._publish(*self.params())
        var = np.diagonal(var)
        k = self.mismatch()[0]
        return tuple((float(v), k * math.sqrt(c) if c > 0 else None) for v, c in zip(theta, var))

    def converged(self) -> bool:
        return all(e.valid for e in self.snapshot().values())

    # -- machinery -----------------------------------------------------
    def _keep_params(self) -> None:
        x, P = self.filter_state()
        self.theta = x[self._p].copy()
        self.theta_P = P[self._p, self._p].copy()
        self.cross = self._cross(P)

    def _cross(self, P) -> tuple[np.ndarray, float] | None:
        c = self.model.CONSIDER
        return None if c is None else (P[self._p, c].copy(), math.sqrt(P[c, c]))

    def _recover(self, why: str) -> None:
        self.resets += 1
        self.last_error = why
        log.warning("stage %d %s diverged (%s); reset to the last good estimate", self.stage, self.kind, why)
        theta, cov, self.cross = self._good
        self.theta, self.theta_P = theta.copy(), cov.copy()
        self.filter = None
        self.t_last = None

    def _save_good(self) -> None:
        x, P = self.filter_state()
        theta, cov = x[self._p], P[self._p, self._p]
        if self._in_range(theta) and np.all(np.isfinite(cov)) and np.all(np.linalg.eigvalsh(cov) > 0):
            self._good = (theta.copy(), cov.copy(), self._cross(P))

    def _q_rate(self) -> np.ndarray:
        raise NotImplementedError

    def _bounds(self) -> Bounds:
        raise NotImplementedError

    def _new_filter(self, x0, P0, R):
        """A filter over the bounded transform of the state (core.bounds), started at SI x0, P0."""
        m, b = self.model, self.bounds
        x0 = np.asarray(x0, dtype=float)
        t0 = b.from_si(x0)
        d = b.grad(t0)
        P0 = np.asarray(P0, dtype=float) / np.outer(d, d)
        Q = self._q_rate() / np.outer(d, d)  # the walk stated in SI, at the start's slope
        scale = np.where(b.transformed, 1.0, m.SCALE)
        fx, hx = b.wrap_fx(self._fx), b.wrap_hx(self._hx)
        if self.kind == "ukf":
            cls = kernel(self.compiled_ukf) if self.cfg.compiled and self.compiled_ukf else None
            if cls is not None:
                return cls(t0, P0, Q, R, scale, fx, hx, b, self.known, m.CONSIDER)
            return UKF(t0, P0, Q, R, scale, fx, hx, m.CONSIDER)
        jf, jh = b.wrap_jac_f(self._jac_f), b.wrap_jac_h(self._jac_h)
        return EKF(t0, P0, Q, R, scale, fx, hx, jf, jh, m.CONSIDER)

    def _param_q(self) -> np.ndarray:
        return (self.cfg.param_walk * self.prior_std) ** 2


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
        b, c, s = SHAPE_OFF_STD
        return np.zeros(4), np.diag([b * b, c * c, s * s, s * s])
    c, d = OFFSET_STD**2, OFFSET_SPLIT_STD**2  # s_0f = common + split, s_0r = common - split
    P = np.diag([BEND_PRIOR[1] ** 2, CUBIC_PRIOR[1] ** 2, c + d, c + d])
    P[2, 3] = P[3, 2] = c - d
    return np.array([BEND_PRIOR[0], CUBIC_PRIOR[0], 0.0, 0.0]), P


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
        self._blocks = _Blocks(BATCH_BLOCKS)  # (u, z, R) of each block the filter took
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
        quiet = f.chi2 < CHI2_QUIET  # residuals far below the noise: their colour says nothing
        if not quiet and f.rho > RHO_MISMATCH:
            why.append(
                f"stage 1's front-minus-rear residuals follow the manoeuvre "
                f"(lag-1 correlation {f.rho:.2f} > {RHO_MISMATCH}); the tyre law or a force it leaves out"
            )
        if self.shaped:
            why.append(
                "the tyre's force-slip curve bends or is offset at zero torque (a real tyre): its "
                "stiffness's load sensitivity, which the slips cannot tell from h, is not in the model"
            )
        return _widen(f.rho, f.chi2 / CHI2_MATCHED), ("model mismatch: " + "; ".join(why)) if why else None

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
        return None if self.spread is None or w == 0.0 else w * self.spread

    def spread_weight(self) -> float:
        """0-1: how much of the halves' spread (model_error) the stds take."""
        f = self.fit
        if f is None:
            return 0.0
        if self.shaped:
            return 1.0
        # from 0.75 RHO_MISMATCH (0.09: vdp's own simulator's residuals reach 0.08, the tuning
        # cases) to RHO_MISMATCH in proportion
        colour = min(1.0, max(0.0, 4.0 * f.rho / RHO_MISMATCH - 3.0))
        # residuals far below the noise (a noise-free drive: chi2 0.003-0.011 on vdp's own model,
        # 0.06-0.22 on the independent ones) say nothing by their colour; from CHI2_QUIET to twice
        # it the spread comes in
        size = min(1.0, max(0.0, f.chi2 / CHI2_QUIET - 1.0))
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
        drop = (fit.cost - free.cost) / max(free.chi2, CHI2_QUIET) * (1.0 - rho) / (1.0 + rho)
        if drop <= SHAPE_LR:
            return None
        self.shaped = True
        self.shape_prior = mean, P
        log.info(
            "stage 1 %s: the tyre bends or has a slip offset (cost down %.0f x the noise); shape freed", self.kind, drop
        )
        return free, t0, P0

    def _model_error(self, U, Z, R, t0, P0, fit) -> np.ndarray:
        """The larger spread of two splits of the blocks (SI), with the tyre's unknown load
        sensitivity added to h's.

        Low against high slip shows what the tyre law misses; slow against fast what grows
        with speed and the law leaves out (drag's pitching moment and lift move load from
        axle to axle with v^2: on the brush cars l_f read 0.9 % long).
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
        h = longitudinal.H
        out[h] = math.hypot(out[h], LOAD_SENSITIVITY * x[h])
        return out

    def _split(self, U, Z, R, t0, P0, fit, lo) -> np.ndarray | None:
        """How far the parameters of the blocks in ``lo`` and of the others differ beyond their
        noise (SI), or None: sqrt(max(0, d^2 - var_1 - var_2)) per parameter."""
        b = self.bounds
        halves, var = [], 0.0
        for m in (lo, ~lo):
            if m.sum() < BATCH_EVERY:
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
        cls = kernel("LongitudinalUKF") if self.filter is not None else None
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
            [c.max_gap, block, c.save_every, BATCH_EVERY, BATCH_EVERY_MAX, self._blocks.cap], dtype=float
        )
        m = (b - a) // block + 1
        out_u, out_z, out_r = np.empty((m, longitudinal.N_U)), np.empty((m, 2)), np.empty((m, 2, 2))
        r, f._f.x, f._f.P, f._sigmas, y, S, nb = kernel("lon_run")(
            T, Y, D, G, a, b, _BLOCK_CHANNELS, f._f.x, f._f.P, f._sigmas, f._lam_n, f._Wm, f._Wc, f.Q_rate, f.scale,
            f._kind, f._lo, f._span, f._known, self._R0(), self._block_settings(), ls, settings, acc, out_u, out_z,
            out_r,
        )  # fmt: skip
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
        return self._since_batch >= min(max(BATCH_EVERY, len(self._blocks) // 4), BATCH_EVERY_MAX)

    def check_batch(self, full: bool = False) -> batch.Fit | None:
        """Solve the batch problem of the blocks kept; re-seed the filter if it sits off the optimum.
        The first, then one every BATCH_FAR_EVERY x BATCH_EVERY blocks, and where ``full`` (the
        data's end) is a far one: from the prior's mean too, with the tyre-shape test and the
        model's error (spread) on the blocks as they are now."""
        self._since_batch = 0
        if len(self._blocks) < 2 * BATCH_EVERY or self.filter is None:
            return None
        U, Z, R = self._blocks.arrays()
        b, k = self.bounds, self.known
        prior, cov = self.prior()
        t0 = b.from_si(prior)
        d = b.grad(t0)
        P0 = cov / np.outer(d, d)
        self._checks += 1
        # a far check every BATCH_FAR_EVERY dense checks' worth of blocks, whatever the checks' spacing
        far = full or self._checks == 1 or self._since_far >= BATCH_FAR_EVERY * BATCH_EVERY
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
        if m2 > RESEED_M2:
            self.reseeds += 1
            log.info("stage 1 %s sat %.1f sigma off its batch optimum; re-seeded there", self.kind, math.sqrt(m2))
            self.filter.set_state(fit.t, fit.cov)
        return fit


# the channels core.kernels.lon_run reads, in its order, and what lon_block did with a block
_BLOCK_CHANNELS = np.array([ch.WS_FL, ch.WS_FR, ch.WS_RL, ch.WS_RR, ch.T_F, ch.T_R, ch.AX])
_TAKEN, _GATED, _PREDICT_FAILED, _UPDATE_FAILED = range(4)  # (core.kernels' TAKEN, ...: tests/test_batched.py)
# the channels core.kernels.lat_run reads, in its order
_STEP_CHANNELS = np.array(
    [ch.WS_FL, ch.WS_FR, ch.WS_RL, ch.WS_RR, ch.T_R, ch.DELTA, ch.AX, ch.AY, ch.YAW, ch.ROLL, ch.SPEED]
)


class Stage2(StageLearner):
    """Single track with roll: C_alpha per axle, I_z, I_x with v_y, yaw rate, phi, phi_dot as states.

    The filter estimates the front and the rear cornering stiffness (lateral.C_F, C_R); it
    publishes their mean as ``C_alpha`` (the paper's single value, what clients read), with
    the per-axle values, their stds and whether the drive separates them in its ``extra``.
    """

    stage = 2
    names = STAGE2
    model = lateral
    compiled_ukf = "LateralUKF"
    keys = ("C_alpha_f", "C_alpha_r", "I_z", "I_x")  # the filter's parameters (lateral.PARAM_SLICE)
    # published = _MEAN @ filter's: C_alpha = (C_alpha_f + C_alpha_r) / 2, I_z, I_x
    _MEAN = np.array([[0.5, 0.5, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    # one C_alpha for both axles (LearnerConfig.per_axle off): C_alpha_f is it, C_alpha_r inert
    _ONE = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    # filter's = _SPLIT @ published + the half-difference (a restore from published values)
    _SPLIT = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])

    @property
    def _M(self) -> np.ndarray:
        return self._MEAN if self.cfg.per_axle else self._ONE

    def _prior(self) -> tuple[np.ndarray, np.ndarray]:
        """Per axle from the profile's ``C_alpha_f``/``C_alpha_r`` priors when it gives both
        (independent), else from its C_alpha prior: that is the mean's, and the half-difference
        (C_f - C_r) / 2 is independent of it with AXLE_SPLIT of its std (zero mean).  With one
        C_alpha for both axles, C_alpha_f starts from the C_alpha prior (C_alpha_r is inert)."""
        p = self.priors
        iz, ix = p["I_z"], p["I_x"]
        f, r = p.get("C_alpha_f"), p.get("C_alpha_r")
        if not self.cfg.per_axle:
            c = p["C_alpha"]
            return np.array([c.value, c.value, iz.value, ix.value]), np.diag(np.square([c.std, c.std, iz.std, ix.std]))
        if f is not None and r is not None:
            return np.array([f.value, r.value, iz.value, ix.value]), np.diag(np.square([f.std, r.std, iz.std, ix.std]))
        c = p["C_alpha"]
        return np.array([c.value, c.value, iz.value, ix.value]), self._SPLIT @ np.diag(
            np.square([c.std, iz.std, ix.std])
        ) @ self._SPLIT.T + self._difference_cov(c.std)

    @staticmethod
    def _difference_cov(c_std: float, share: float = AXLE_SPLIT) -> np.ndarray:
        """Covariance of (+D, -D, 0, 0), D the axles' half-difference, std ``share`` c_std."""
        d = np.zeros((4, 4))
        d[:2, :2] = (share * c_std) ** 2 * np.array([[1.0, -1.0], [-1.0, 1.0]])
        return d

    def _free_split(self) -> None:
        """Free the held half-difference (SPLIT_HELD) to AXLE_SPLIT once the data know the
        axles' mean to SPLIT_FREE_REL: its variance goes into the open filter's covariance."""
        if not self.split_held or self.filter is None:
            return
        x, P = self.filter_state()
        f, r = x[lateral.C_F], x[lateral.C_R]
        mean_sd = 0.5 * math.sqrt(
            max(P[lateral.C_F, lateral.C_F] + P[lateral.C_R, lateral.C_R] + 2.0 * P[lateral.C_F, lateral.C_R], 0.0)
        )
        if not mean_sd < SPLIT_FREE_REL * 0.5 * (f + r):
            return
        c_std = self.priors["C_alpha"].std
        var = (AXLE_SPLIT**2 - SPLIT_HELD**2) * c_std**2
        # (C_f, C_r) = (M + D, M - D): D's variance along (+1, -1), in the filter's coordinates
        # (log C: d log C = dC / C)
        v = np.zeros(self._n)
        v[lateral.C_F], v[lateral.C_R] = 1.0 / f, -1.0 / r
        self.filter.set_state(self.filter.x, self.filter.P + var * np.outer(v, v))
        self.split_held = False
        log.info(
            "stage 2 %s: axles' mean known to %.1f %%; their split freed", self.kind, 100 * mean_sd / (0.5 * (f + r))
        )

    def _publish(self, theta, cov):
        M = self._M
        return M @ theta, M @ cov @ M.T

    def _unpublish(self, theta, cov):
        """Both axles at the stored mean, their difference as uncertain as the prior says."""
        S, c_std = self._SPLIT, self.priors["C_alpha"].std
        if not self.cfg.per_axle:  # C_alpha_r inert: uncorrelated, at the prior's std
            P = S @ cov @ S.T
            P[1, :] = P[:, 1] = 0.0
            P[1, 1] = c_std**2
            return S @ theta, P
        share = SPLIT_HELD if self.split_held else AXLE_SPLIT
        return S @ theta, S @ cov @ S.T + self._difference_cov(c_std, share)

    def _in_range(self, theta) -> bool:
        return all(BY_NAME[n].lo <= v <= BY_NAME[n].hi for n, v in zip(("C_alpha",) * 2 + STAGE2[1:], theta))

    def _extra(self, name, theta, cov, factor, valid, reason) -> dict:
        """C_alpha's per-axle values and stds, their correlation, and whether the drive separates them.

        The axles are separated when the data have at least halved the prior std of their
        difference (the rule ``not_identifiable`` uses) and the two are not nearly perfectly
        correlated (then the data know one combination of them, usually their mean, and the
        per-axle values are the prior's split of it).
        """
        if name != "C_alpha" or not self.cfg.per_axle:
            return {}
        var_f, var_r, cov_fr = cov[0, 0], cov[1, 1], cov[0, 1]
        sf, sr = factor * math.sqrt(max(var_f, 0.0)), factor * math.sqrt(max(var_r, 0.0))
        corr = cov_fr / math.sqrt(var_f * var_r) if var_f > 0 and var_r > 0 else math.nan
        diff = factor * math.sqrt(max(var_f + var_r - 2.0 * cov_fr, 0.0))
        f, r = float(theta[0]), float(theta[1])
        axle_why = None  # the batch check (core.output_error) per axle, as adjust() does for the mean
        if self.cfg.batch_check and self.known is not None and (fit := self.batch_fit()) is not None:
            f, sf, why_f = output_error.compare("C_alpha_front", f, sf, fit, output_error.Z_MAX)
            r, sr, why_r = output_error.compare("C_alpha_rear", r, sr, fit, output_error.Z_MAX)
            # whether the drive separates the axles stays the filter's verdict (its covariance: what the
            # drive excited), also where the values are the fit's: the fit's common-mode model error
            # correlates its axles (0.99 on brush/small) without saying the drive could not tell them apart
            axle_why = why_f or why_r
        spec = BY_NAME["C_alpha"]
        if self.samples > 0:
            sf, sr = honest_std(spec, f, sf), honest_std(spec, r, sr)
        why = None
        if self.samples == 0:
            why = "stage 2 has not run"
        elif not (diff <= 0.5 * self.prior_diff_std and abs(corr) <= AXLE_CORR_MAX):
            why = (
                f"the drive does not separate the axles: front minus rear is known to +-{diff:,.0f} N/rad "
                f"(prior +-{self.prior_diff_std:,.0f}), correlation {corr:+.2f}; only their mean is"
            )
        elif not valid:
            why = reason or "the mean C_alpha is not valid yet (each axle waits for it)"
        elif not (sf <= spec.useful_rel * abs(f) and sr <= spec.useful_rel * abs(r)):
            why = f"a per-axle std is above the {100 * spec.useful_rel:g} % a model can use"
        # a valid pair keeps the batch check's finding beside it, as the mean does
        note = why if why is not None else axle_why
        return {
            "C_alpha_front": finite(f),
            "C_alpha_front_std": finite(sf),
            "C_alpha_rear": finite(r),
            "C_alpha_rear_std": finite(sr),
            "C_alpha_axle_corr": finite(corr),
            "C_alpha_front_minus_rear_std": finite(diff),
            "per_axle_valid": why is None,
            "per_axle_reason": note,
        }

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
        # the batch check: windows' samples and their output-error fit
        self.check = output_error.Check(compiled=self.cfg.compiled, executor=self.cfg.check_executor)
        super().reset()
        P = self.theta_P
        self.prior_diff_std = math.sqrt(P[0, 0] + P[1, 1] - 2.0 * P[0, 1])  # of C_alpha_f - C_alpha_r
        # the split starts held (SPLIT_HELD) when it comes from the C_alpha prior, not the profile's per-axle priors
        p = self.priors
        self.split_held = self.cfg.per_axle and (p.get("C_alpha_f") is None or p.get("C_alpha_r") is None)
        if self.split_held:
            c_std = p["C_alpha"].std
            self.theta_P = P - self._difference_cov(c_std) + self._difference_cov(c_std, SPLIT_HELD)
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
        self.l_f_std = max(l_f_std, L_F_STD_MIN) if ok else self.priors["l_f"].std
        ok = h_std is not None and math.isfinite(h_std) and h_std >= 0
        self.h_std = h_std if ok else self.priors["h"].std

    def _initial_cov(self) -> np.ndarray:
        """Dynamic states, the parameters as kept, l_f as stage 1 gives it, and their correlation."""
        P0 = np.zeros((self._n, self._n))
        P0[:4, :4] = np.diag([0.5**2, 0.02**2, 0.01**2, 0.02**2])
        P0[self._p, self._p] = self.theta_P
        sd, c = self.l_f_std, lateral.L_F
        P0[c, c] = sd * sd
        if self.cross is not None:
            # correlation kept, scaled to stage 1's std now (a congruence: stays positive definite)
            cov, sd_then = self.cross
            P0[self._p, c] = P0[c, self._p] = cov * (sd / sd_then)
        return P0

    def end_window(self) -> None:
        super().end_window()
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
            return output_error.compare(name, value, std, fit, output_error.Z_MAX)
        if name != "I_x" or self.known is None or not (math.isfinite(value) and math.isfinite(std)):
            return value, std, None
        h_rel = (self.h_std or 0.0) / self.known.h if self.known.h > 0 else 0.0
        factor, why = self.roll_mismatch()
        if why is not None:
            std *= max(1.0, factor / self.mismatch()[0])  # the lateral rows' factor is in std already
            h_rel = math.hypot(h_rel, ROLL_MODEL_ERROR)
        quiet = self.not_excited()
        if quiet is not None:  # no filter's covariance may claim more than the drive holds
            std = max(std, abs(value) * quiet)
        std = math.hypot(std, abs(value) * h_rel)
        if why is None and quiet is not None:
            why = Hard(
                f"roll not excited: the drive's roll rate tells I_x to {100 * quiet:.0f} % at best "
                f"(its prior: {100 * self._ix_prior_rel():.0f} %); quick steering reversals at speed excite the roll"
            )
        return value, std, why

    def settle(self) -> None:
        """Let a background check end, and solve a stale one now: the next snapshot is then the
        same whenever it is taken (LearnerConfig.check_executor)."""
        self.check.wait()
        if self.known is not None and self.cfg.batch_check:
            self.batch_fit(now=True)

    def batch_fit(self, now: bool = False) -> output_error.Fit | None:
        """The output-error fit of the windows kept (core.output_error), solved again when stale:
        per axle, from the filter's values, with the profile's priors (the mean's, and the
        axles' half-difference AXLE_SPLIT of it, as _prior).  ``now``: not in the background."""
        c = self.check
        if not c.stale(self.filter is not None):
            return c.fit
        p, theta = self.priors, self.params()[0]
        rel = np.array([p["C_alpha"].std / p["C_alpha"].value, p["I_z"].std / p["I_z"].value])
        m, d = rel[0] ** 2, (AXLE_SPLIT * rel[0]) ** 2
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
        """I_x's best relative std from the roll-rate rows' information (RollExcitation) and its
        prior, when that does not even halve the prior's (the ``not_identifiable`` rule); None
        when the drive excites the roll that much, or before any roll-rate row."""
        if self.roll_updates == 0:
            return None
        p = self._ix_prior_rel()
        post = 1.0 / math.sqrt(1.0 / (p * p) + self.roll_info)
        return post if post > 0.5 * p else None

    def mismatch(self) -> tuple[float, str | None]:
        """From the innovations of every window kept: their size (NIS) and whiteness."""
        return _verdict(self.total, "innovations", "a_y innovations", "model mismatch")

    def _bounds(self) -> Bounds:
        return Bounds(
            lateral.N_X, log=(lateral.C_F, lateral.C_R, lateral.I_Z, lateral.I_X)
        )  # stiffnesses, inertias > 0

    def _fx(self, x, dt, u):
        return lateral.fx(x, dt, u, self.known)

    def _hx(self, x, u):
        return lateral.hx(x, u, self.known)

    def _jac_f(self, x, u):
        return lateral.jac_f(x, u.mean(axis=0) if u.ndim == 2 else u, self.known)

    def _jac_h(self, x, u):
        return lateral.jac_h(x, u, self.known)

    def _q_rate(self):
        dyn = np.square([V_Y_WALK, YAW_WALK, PHI_WALK, PHI_D_WALK])
        k = self.known
        if k.roll_by_ay:
            # eq (9) driven by the measured a_y takes the accelerometer's noise in as a roll moment:
            # m h n / I_x on phi'', white over each sample (variance per second: its variance times the tick)
            n = self.cfg.noise
            i_x = max(float(self.theta[self.keys.index("I_x")]), lateral.PARAM_FLOOR[3])
            dyn[3] += (k.m * k.h * n.accel * n.inflate / i_x) ** 2 * self.cfg.tick
        return np.diag(np.concatenate([dyn, self._param_q(), [0.0]]))  # l_f: constant

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
        while q and t - q[0][0] > SETTLE_TIME + 1e-9:
            q.popleft()
        span = t - q[0][0]
        if span < SETTLE_TIME - 0.5 * self.cfg.tick:
            return False
        yaw_acc = abs(q[-1][1] - q[0][1]) / span
        steer_rate = abs(q[-1][2] - q[0][2]) / span
        return yaw_acc <= SETTLED_YAW_ACC and steer_rate <= SETTLED_STEER_RATE

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
        x0 = np.concatenate([[v_y, yaw, phi, roll_rate], self.theta, [l_f]])
        P0 = self._initial_cov()
        dv_dc = g / (c_r * c_r)  # d v_y / d C_alpha_r
        rest = slice(lateral.C_F, self._n)  # the parameters and the considered l_f
        P0[lateral.V_Y, rest] = P0[rest, lateral.V_Y] = dv_dc * P0[rear, rest]
        P0[lateral.V_Y, lateral.V_Y] = V_Y_START_STD**2 + dv_dc**2 * P0[rear, rear]
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
        if self.window.recent() > DIVERGED_NIS:
            self.restarts += 1
            why = f"innovations {self.window.recent():.0f}x their predicted size"
            log.info("stage 2 %s window diverged (%s); restarted from the window's start", self.kind, why)
            self.last_error = f"window restarted: {why}"
            theta, cov, cross = self._win_start
            self.theta, self.theta_P, self.cross = theta.copy(), cov.copy(), cross
            self.total.drop(self.window)
            self.roll_total.drop(self.roll_window)
            self.roll_info -= self._info_window
            self._info_window = 0.0
            self.filter = None
            self.t_last = None
            self._settle.clear()
            return True
        return False

    def runnable(self) -> bool:
        """Whether :meth:`steps` can take samples now: an open compiled window, its axles' split
        freed (while held, each step may free it: :meth:`_free_split`, in Python)."""
        cls = kernel("LateralUKF") if self.filter is not None else None
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
        settings = np.array([cfg.max_gap, every, cfg.save_every, (n.gyro * n.inflate) ** 2, DIVERGED_NIS,
                             float(self.known.roll_by_ay)])  # fmt: skip
        rec = np.empty(((b - a) // every + 1, 8))
        r, fs.x, fs.P, sig, y, S, nr = kern(
            T, Y, D, G, a, b, _STEP_CHANNELS, fs.x, fs.P, f._sigmas, f._lam_n, f._Wm, f._Wc, f.Q_rate, f.R, f.scale,
            f._kind, f._lo, f._span, f._known, f._c, j, w, nsub, ls, settings, us, exa, cons, ring, rec,
        )  # fmt: skip
        f._sigmas = sig
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
