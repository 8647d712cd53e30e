"""I_x's honesty rules (issue 11): its std carries stage 1's h, a roll model that the roll-rate
innovations reject makes it not valid with a model error, unexcited roll says so, and no
roll-rate gyro makes it not_run.  Fast, on a Stage2 learner's bookkeeping; the benchmark of
the same rules on the independent models is in BENCHMARKS.md ("I_x: honest uncertainty")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vdp.core.learner import NIS_MATCHED, ROLL_MODEL_ERROR, Consistency, Stage2
from vdp.core.result import CONVERGED, NOT_IDENTIFIABLE, NOT_RUN
from vdp.profile import load_profile

IX = Stage2.keys.index("I_x")  # I_x among the filter's parameters


@pytest.fixture()
def learner(repo_root):
    prof = load_profile(repo_root / "profiles" / "paper.toml")
    l2 = Stage2("ukf", prof.vehicle, prof.priors)
    return l2


def ran(l2, i_x: float, i_x_std: float, h: float = 0.6, h_std: float = 0.0, roll: bool = True):
    """As if stage 2 had run its windows: I_x at (value, std), with or without roll-rate rows."""
    l2.set_stage1(1.4, h, 10.0, l_f_std=0.005, h_std=h_std)
    l2.theta[IX] = i_x
    l2.theta_P[IX, IX] = i_x_std**2
    l2.samples = l2.cfg.min_samples + 100
    l2.updates = 400
    l2.roll_updates = 400 if roll else 0
    return l2


def feed(c: Consistency, nis: float, rho: float, n: int = 400, seed: int = 1) -> None:
    """Scaled innovations with mean square ``nis`` and lag-1 correlation ``rho``."""
    rng = np.random.default_rng(seed)
    e = 0.0
    for _ in range(n):
        e = rho * e + math.sqrt(1 - rho * rho) * rng.standard_normal()
        v = e * math.sqrt(nis)
        c.add(v * v, 1, v)


def test_a_matching_roll_model_leaves_i_x_as_the_filter_has_it(learner):
    l2 = ran(learner, 480.0, 4.0)
    feed(l2.roll_total, NIS_MATCHED, 0.0)
    e = l2.snapshot()["I_x"]
    assert e.status == CONVERGED and e.valid and e.reason is None
    assert e.std == pytest.approx(4.0, rel=0.01)


def test_i_x_std_carries_stage_1_h(learner):
    l2 = ran(learner, 480.0, 4.0, h=0.6, h_std=0.06)  # h known to 10 %
    feed(l2.roll_total, NIS_MATCHED, 0.0)
    e = l2.snapshot()["I_x"]
    assert e.std == pytest.approx(math.hypot(4.0, 48.0), rel=0.01)
    assert e.status != CONVERGED and not e.valid  # 10 % is beyond I_x's 5 % threshold


def test_a_roll_model_mismatch_makes_i_x_not_valid_with_its_model_error(learner):
    l2 = ran(learner, 480.0, 4.0)
    feed(l2.roll_total, 3.0, 0.85)  # the independent models: roll NIS 2-8 per row, lag-1 0.8-0.93
    e = l2.snapshot()["I_x"]
    assert not e.valid and e.reason.startswith("roll model mismatch") and "not white" in e.reason
    assert e.std >= ROLL_MODEL_ERROR * 480.0
    # C_alpha and I_z are not judged by the roll row
    assert l2.snapshot()["C_alpha"].reason is None


def test_unexcited_roll_is_named(learner):
    l2 = ran(learner, 3000.0, 0.9 * learner.prior_std[IX])
    feed(l2.roll_total, NIS_MATCHED, 0.0)
    e = l2.snapshot()["I_x"]
    assert e.status == NOT_IDENTIFIABLE and not e.valid and e.reason.startswith("roll not excited")


def test_without_roll_rate_rows_i_x_is_not_run(learner):
    l2 = ran(learner, 3000.0, 1500.0, roll=False)
    e = l2.snapshot()["I_x"]
    assert e.status == NOT_RUN and not e.valid and "roll-rate" in e.reason
    assert l2.snapshot()["C_alpha"].status != NOT_RUN
