"""What both stages' learners share: their configuration, the measurement noise, and
:class:`StageLearner` (filter life cycle, last-good copies, snapshot).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from ...errors import FilterError
from ..bounds import Bounds
from ..compiled import kernel
from ..filters import EKF, UKF
from ..params import BY_NAME
from ..result import CONVERGED, INVALID, NOT_IDENTIFIABLE, NOT_RUN, UNCERTAIN, Estimate, finite
from .verdict import Hard, honest_std, too_wide, useful

log = logging.getLogger(__name__)


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
    # roll row no longer pulls it back (docs/decisions/0008)
    per_axle: bool = True
    # Stage 2's roll, eq (9), driven by the measured a_y (lateral.Known.roll_by_ay): the roll-rate
    # row then informs the roll states and I_x, not C_alpha and I_z
    roll_by_ay: bool = True
    # Stage 2's batch check (core.output_error): C_alpha's and I_z's stds widen where an output-error
    # fit of the windows disagrees with the filter or with itself (off: the filter's own stds)
    batch_check: bool = True
    # Stage 2 carries the road's bank as a tenth state (lateral.BANK; on with the road modelled,
    # RoadConfig.bank: the estimator sets it); off: nine states, today's numbers to the bit
    bank: bool = False
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
            if status not in (NOT_RUN, INVALID):  # after the status, as the floor: the model class's, not the data's
                std, note = self.cover(name, value, std)
                if note is not None:
                    reason = note if reason is None else f"{reason}; {note}"
            if status != NOT_RUN:  # a prior alone keeps its own std
                std = honest_std(spec, value, std)
            valid = useful(spec, status, value, std) and not isinstance(own, Hard)
            if not valid and reason is None and status in (CONVERGED, UNCERTAIN) and math.isfinite(std):
                reason = too_wide(spec, value, std)
            if status == INVALID and reason is None:  # (said, never left bare: a user must see why)
                reason = beyond(spec, value)
            if status == INVALID and not spec.lo <= value <= spec.hi:  # (NaN too)
                value = std = math.nan  # no number that no car has is published as a value: the reason says it
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

    def cover(self, name: str, value: float, std: float) -> tuple[float, str | None]:
        """(std, finding or None): the std widened for another model class the data cannot rule out
        (stage 2: a tyre whose secant falls).  Applied after the status, as the floor is: the status
        says what the data have taught; this and the floor, what the model class may be off by."""
        return std, None

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
        scale = np.where(b.transformed, 1.0, self._scale())
        fx, hx = b.wrap_fx(self._fx), b.wrap_hx(self._hx)
        if self.kind == "ukf":
            cls = kernel(self.compiled_ukf) if self.cfg.compiled and self.compiled_ukf else None
            if cls is not None:
                return cls(t0, P0, Q, R, scale, fx, hx, b, self.known, m.CONSIDER)
            return UKF(t0, P0, Q, R, scale, fx, hx, m.CONSIDER)
        jf, jh = b.wrap_jac_f(self._jac_f), b.wrap_jac_h(self._jac_h)
        return EKF(t0, P0, Q, R, scale, fx, hx, jf, jh, m.CONSIDER)

    def _scale(self) -> np.ndarray:
        """The filter's scale per state (core.filters), of the untransformed states."""
        return self.model.SCALE

    def _param_q(self) -> np.ndarray:
        return (self.cfg.param_walk * self.prior_std) ** 2


def beyond(spec, value: float) -> str:
    """Why an estimate is invalid: not a number, or beyond what any car has (ParamSpec's range)."""
    if not math.isfinite(value):
        return "not a number: the filter diverged from the data"
    return (
        f"{value:.3g} {spec.unit} is beyond what a car has ({spec.lo:g} to {spec.hi:g}): the filter left the data "
        "(a disturbance no gate caught, e.g. a kerb strike, can do it)"
    )
