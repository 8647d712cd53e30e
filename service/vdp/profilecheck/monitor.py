"""The self-check of a running service (Monitor)."""

from __future__ import annotations

import logging
import math

import numpy as np

from .. import channels as ch
from ..profile import Profile
from .coverage import Coverage, check_refused, coverage, primary_messages
from .limits import check_bounds, check_profile
from .report import lines_of, mark_invalid
from .samples import check_samples

log = logging.getLogger(__name__)


START_AFTER = 10.0  # s of bus time before a running service's first check
START_CYCLES = 3.0  # ... or this many periods of the profile's slowest message, if longer


class Monitor:
    """The self-check of a running service.

    It keeps the aligned samples it is shown (10 Hz, the newest ``keep`` seconds) and checks
    once ``start`` seconds of bus time have passed since the first frame (START_AFTER, or three
    periods of the profile's slowest message if that is longer: a 1 Hz GPS is seen three
    times), then every ``every`` seconds of bus time.  Each check also counts which of the
    profile's messages the bus carried (:func:`coverage`): a bus that carries none or few of
    them (fewer than half) is an :attr:`error` with the counts and the ids the bus carries
    most; after the first check the counts are kept current at every update.  Each new
    finding, and each change of which messages are seen, is logged once; :meth:`mark`
    applies the newest report to estimates.
    """

    def __init__(
        self,
        profile: Profile,
        decoder=None,
        keep: float = 600.0,
        every: float = 30.0,
        rate: float = 0.1,
        start: float | None = None,
        aligner=None,
    ):
        self.aligner = aligner  # its values beyond a car's limits are findings too
        self.profile, self.decoder, self.keep, self.every, self.rate = profile, decoder, keep, every, rate
        self.start = start if start is not None else start_after(profile, decoder)
        self.t: list[float] = []
        self.y: list[np.ndarray] = []
        self.last_t = -math.inf
        self.next_check: float | None = None
        self.checked_at: float | None = None  # bus time of the newest check
        self.checks = 0
        self.report = check_profile(profile)
        self.coverage: Coverage | None = None
        self._said: set[str] = set()
        self._said_coverage: tuple | None = None
        self._say()

    @property
    def error(self) -> str | None:
        """The bus does not fit the profile: none or fewer than half of its messages seen."""
        cov = self.coverage
        if cov is None or cov.seen * 2 >= len(cov.wanted):
            return None
        return f"the bus does not fit profile {self.profile.path}: {cov.message()}"

    def update(self, ring, first: float | None = None, now: float | None = None) -> None:
        """Take the samples ``ring`` (a SampleRing) got since the last call; check when due.

        ``first`` and ``now`` are the bus times of the first and the newest frame (decoded or
        not); without them the samples' times stand in.
        """
        ts, ys = ring.latest()
        new = ts > self.last_t
        for t, y in zip(ts[new], ys[new]):
            if not self.t or t - self.t[-1] >= self.rate:
                self.t.append(float(t))
                self.y.append(y.copy())
        if len(ts) and new.any():
            self.last_t = float(ts[-1])
        while self.t and self.t[-1] - self.t[0] > self.keep:
            self.t.pop(0)
            self.y.pop(0)
        if first is None or now is None:
            if not self.t:
                return
            first, now = self.t[0], self.t[-1]
        if self.next_check is None:
            self.next_check = first + self.start
        if now >= self.next_check:
            self.next_check = now + self.every
            self.check(now)
        elif self.checks and self.decoder is not None:  # the counts stay current between checks
            self.coverage = coverage(self.decoder, source="bus")
            self._say()

    def check(self, now: float) -> None:
        """Check now: the messages seen so far, and the profile against the samples kept."""
        self.checked_at = now
        self.checks += 1
        if self.decoder is not None:
            self.coverage = coverage(self.decoder, source="bus")
        y = np.vstack(self.y) if self.y else np.empty((0, ch.N))
        self.report = check_samples(self.profile, np.asarray(self.t), y)
        if self.aligner is not None:
            decoded = None if self.decoder is None else self.decoder.stats.samples
            check_bounds(self.aligner.refused, decoded, self.report)
        if self.coverage is not None and self.error is None:  # (a bus of another car: the error says it all)
            check_refused(self.profile, self.coverage, self.decoder.db, self.report)
        self._say()

    def _say(self) -> None:
        for f in self.report.findings:
            if f.check not in self._said:
                self._said.add(f.check)
                log.warning("%s", lines_of([f])[0])
        cov = self.coverage
        if cov is None:
            return
        said = (cov.seen, tuple(cov.missing), tuple(cov.refused))  # a change of what is seen, not of counts
        if said == self._said_coverage:
            return
        self._said_coverage = said
        if self.error:
            log.error("profile check: %s", self.error)
        elif cov.seen < len(cov.wanted):
            log.warning("profile check: %s", cov.message())
        else:
            log.info("profile check: %s", cov.message(top=False))

    def mark(self, params):
        """``params`` (name -> Estimate) with those the newest report doubts marked not valid."""
        return None if params is None else mark_invalid(params, self.report)

    def status(self) -> dict:
        """What /status shows: when the check ran, its findings, the messages seen, the error."""
        doc = self.report.as_dict()
        doc.update(
            checked_at=self.checked_at,
            checks=self.checks,
            start_after_s=self.start,
            every_s=self.every,
            coverage=None if self.coverage is None else self.coverage.as_dict(),
            error=self.error,
        )
        return doc


def start_after(profile: Profile, decoder=None) -> float:
    """Bus time [s] a running service waits before its first check (see :class:`Monitor`)."""
    longest = 0.0
    if decoder is not None:
        names = primary_messages(profile)
        for plan in decoder._plans.values():
            if plan.name in names and plan.fixed_period:
                longest = max(longest, plan.period)
    return max(START_AFTER, START_CYCLES * longest)
