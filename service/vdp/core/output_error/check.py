"""The learner's side: the record, the latest fit, and when to solve again (in the background live)."""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from .. import lateral
from .problem import MAX_ROWS, N_THETA, SHAPE_B, Fit, Problem, Record
from .solve import SHAPE_GAIN, STRUCTURE_MIN, departs, mismatched, solve, spread, structured

log = logging.getLogger(__name__)


REFIT_ROWS = 250  # new rows (10 s of windows) before an open window's fit is solved again


class Check:
    """The learner's side: the record, the latest fit, and when to solve again.

    A fit costs about 0.1 s of CPU per minute of windows kept (numpy; a sixth of that with
    ``compiled``, core.kernels.oe_states), so it is solved when asked
    for (a snapshot), and again only once enough new rows have come (:meth:`stale`) or the
    window has closed: a replay solves it once, a live service at most every 10 s of
    stage-2 windows (every 75 s with a full record).
    """

    def __init__(self, cap: int = MAX_ROWS, compiled: bool = False, executor=None):
        self.record = Record(cap)
        self.compiled = compiled  # the fit's states by core.kernels (Problem.compiled)
        # anything with concurrent.futures' submit(): solves in the background (solve).  The caller
        # owns it (the live service's one thread): the core starts no thread of its own, and the
        # job is only ever looked at from the thread that calls this Check
        self.executor = executor
        self._job = None  # the background solve running, if any
        self.solved = 0  # fits finished (a live service publishes again when one lands)
        self.fit: Fit | None = None
        self._at = 0  # record.added at the last solve
        self._open_at = -1
        # the record is complete (a log's end, TwoStageEstimator.finish): the next fit takes
        # every row, so a replay's result does not depend on how often it was asked for before
        self.complete = False

    @property
    def behind(self) -> bool:
        """Rows have come since the last solve (a settled snapshot solves on every one: stale()
        lets an open window's fit lag by up to a quarter of its rows)."""
        return self.record.added > self._at

    def stale(self, window_open: bool) -> bool:
        """Whether to solve again: new rows, and no fit yet, the window closed, or new rows
        REFIT_ROWS and a quarter of those kept (a solve costs about in proportion to the
        rows kept, so a long drive's live cost per row stays bounded: ~0.4 s of CPU for a
        full record, three times that with the halves)."""
        new = self.record.added - self._at
        every = max(REFIT_ROWS, self.record.rows // 4)
        return new > 0 and (self.fit is None or not window_open or self.complete or new >= every)

    def solve(self, k: lateral.Known, sigma, prior_t, prior_P, starts, now: bool = False) -> Fit | None:
        """Fit the rows kept; return the fit.  With an ``executor`` (the live service) and not
        ``now``, the solve runs there on a copy of the rows and the last finished fit is returned
        meanwhile: a full record of a car whose tyres bend costs ~20 s of numpy CPU, which must
        not stop the estimation worker (its queue holds ~8 s of a saturated bus).  One solve at a
        time; while one runs the check stays stale and asks again later."""
        background = self.executor is not None and not now and not self.complete
        job = self._job
        if job is not None:
            if background and not job.done():
                return self.fit
            self._take()  # (ended, or waited for: in line now)
        self._at = self.record.added
        a = self.record.arrays()
        if a is None:
            self.fit = None
            return None
        args = (a, k, sigma, prior_t, prior_P, starts)
        if background:
            try:
                self._job = self.executor.submit(self._fit, *args)
                return self.fit
            except RuntimeError:  # the executor was shut down (a service stopping): solve in line
                pass
        self.fit = self._fit(*args)
        self.solved += 1
        return self.fit

    def poll(self) -> int:
        """Take a background solve's fit if it has ended; return the fits finished so far (the
        live service publishes again when this grows)."""
        job = self._job
        if job is not None and job.done():
            self._take()
        return self.solved

    def _take(self) -> None:
        """The background solve has ended (or is waited for here): its fit becomes the check's."""
        job, self._job = self._job, None
        if job.cancelled():
            return
        exc = job.exception()  # blocks until it ends
        if exc is not None:  # numeric failures give no fit inside _fit: this is a bug
            log.error("stage 2's batch check failed in the background: %r", exc)
            return
        self.fit = job.result()
        self.solved += 1

    def wait(self) -> None:
        """Until a background solve has ended and its fit is taken."""
        if self._job is not None:
            self._take()

    @property
    def busy(self) -> bool:
        job = self._job
        return job is not None and not job.done()

    def _fit(self, a, k, sigma, prior_t, prior_P, starts) -> Fit | None:
        t, u, z, bounds = a
        try:
            prob = Problem(t, u, z, bounds, k, sigma)
            prob.compiled = self.compiled
            fit = solve(prob, prior_t, prior_P, starts)
            used = max(int(np.count_nonzero(prob.w[:, 1])), 1)
            left = structured(prob, fit.p) if fit is not None else 0.0
            if left > STRUCTURE_MIN * used:
                # the tyre's shape, kept where it explains most of what the linear law leaves
                bent_prob = prob.shaping(True)
                bent = solve(bent_prob, prior_t, prior_P, [fit.p])
                if bent is not None and structured(bent_prob, bent.p) < SHAPE_GAIN * left:
                    prob, fit = bent_prob, bent
            if fit is not None and fit.shape is None:
                # the linear law kept: the data did not show the tyre bends, nor that it does not (too
                # little structure, or structure the shape does not explain: brush/saloon's ordinary
                # drive, where the shape took 1-9 % of it and moved C_alpha +4 %).  The fit with the
                # secant's first-order fall b free (a brush tyre's 1/(3 mu); c held: second order at
                # these slips, and freeing it too widened the light car's C_alpha to 6 %) is the
                # answer if it bends, and compare covers it.  Only a secant that falls (b > 0): no tyre's
                # rises from zero slip, and a b below 0 is the noise's (the light car's paper drive, seed
                # 2 at priors x1.6: b -0.12 read C_alpha -4.5 %, against the linear fit's +1.0 %)
                bent = solve(prob._variant(shaped=True, bend_only=True), prior_t, prior_P, [fit.p])
                if bent is not None and bent.p[SHAPE_B] > 0.0:
                    fit = dataclasses.replace(fit, bent=bent)
            if fit is not None and (mismatched(fit) or departs(fit)):  # two more solves, only where the model errs
                fit = dataclasses.replace(fit, spread=spread(prob, fit, prior_t, prior_P))
        except (np.linalg.LinAlgError, FloatingPointError, ValueError):
            fit = None
        return fit

    def as_dict(self) -> dict | None:
        """The latest fit, plainly (the learners' diagnostics), or None before any."""
        f = self.fit
        if f is None:
            return None
        spread = f.spread if f.spread is not None else np.zeros(N_THETA)
        out = {"rows": f.rows, "chi2_per_dof": round(f.chi2, 3), "whiteness_lag1": round(f.rho, 3)}
        for i, name in enumerate(("C_alpha_front", "C_alpha_rear", "I_z")):
            out[name] = float(f.theta[i])
            out[name + "_rel_std"] = round(math.sqrt(f.cov[i, i]), 4)
            out[name + "_halves_spread"] = round(float(spread[i]), 4)
        out["a_y_offset"] = round(f.offset, 4)
        out["roll_swing_m"] = round(f.swing, 4) if math.isfinite(f.swing_std) else None  # None: no roll gyro
        out["tyre_shape_bc"] = None if f.shape is None else [round(v, 4) for v in f.shape]
        return out
