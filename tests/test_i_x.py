"""I_x's honesty rules (issue 11): its std carries stage 1's h, a roll model that the roll-rate
innovations reject makes it not valid with a model error, unexcited roll says so, and no
roll-rate gyro makes it not_run.  Fast, on a Stage2 learner's bookkeeping; the benchmark of
the same rules on the independent models is in docs/decisions/0015."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from vdp.core.learner import NIS_MATCHED, ROLL_MODEL_ERROR, Consistency, Stage2, honest_std
from vdp.core.params import BY_NAME
from vdp.core.result import CONVERGED, NOT_IDENTIFIABLE, NOT_RUN
from vdp.profile import load_profile

IX = Stage2.keys.index("I_x")  # I_x among the filter's parameters


@pytest.fixture()
def learner(repo_root):
    prof = load_profile(repo_root / "profiles" / "paper.toml")
    l2 = Stage2("ukf", prof.vehicle, prof.priors)
    return l2


def ran(l2, i_x: float, i_x_std: float, h: float = 0.6, h_std: float = 0.0, roll: bool = True, info: float = 1e5):
    """As if stage 2 had run its windows: I_x at (value, std), with or without roll-rate rows,
    which held ``info`` on ln I_x (vdp's small car's paper drive: about 6e5; the paper car's: 0.7)."""
    l2.set_stage1(1.4, h, 10.0, l_f_std=0.005, h_std=h_std)
    l2.theta[IX] = i_x
    l2.theta_P[IX, IX] = i_x_std**2
    l2.samples = l2.cfg.min_samples + 100
    l2.updates = 400
    l2.roll_updates = 400 if roll else 0
    l2.roll_info = info if roll else 0.0
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
    assert e.std == pytest.approx(honest_std(BY_NAME["I_x"], 480.0, 4.0), rel=0.01)  # the model's floor beside


def test_i_x_std_carries_stage_1_h(learner):
    l2 = ran(learner, 480.0, 4.0, h=0.6, h_std=0.06)  # h known to 10 %
    feed(l2.roll_total, NIS_MATCHED, 0.0)
    e = l2.snapshot()["I_x"]
    assert e.std == pytest.approx(honest_std(BY_NAME["I_x"], 480.0, math.hypot(4.0, 48.0)), rel=0.01)
    assert e.status != CONVERGED and not e.valid  # 10.4 % is beyond I_x's 10 % usefulness threshold


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


def test_a_filter_cannot_claim_more_of_i_x_than_the_roll_rate_holds(learner):
    """The paper car's over-damped roll: the drive holds almost nothing of I_x, whatever std a
    filter's covariance says (the EKF's said 17 % there, 38-46 % off)."""
    prior = learner.priors["I_x"]
    l2 = ran(learner, 2300.0, 0.17 * 2300.0, info=0.7)
    feed(l2.roll_total, NIS_MATCHED, 0.0)
    e = l2.snapshot()["I_x"]
    rel = prior.std / prior.value
    assert e.std >= 2300.0 / math.sqrt(1 / rel**2 + 0.7) and not e.valid
    assert e.reason.startswith("roll not excited") and "at best" in e.reason
    assert abs(e.value - 4175.0) <= 2 * e.std  # Table 6's I_x is inside 2 sigma now
    # with the information of an excited drive the filter's std stands
    l2.roll_info = 5e5
    assert l2.snapshot()["I_x"].std == pytest.approx(honest_std(BY_NAME["I_x"], 2300.0, 0.17 * 2300.0), rel=1e-6)


def test_without_roll_rate_rows_i_x_is_not_run(learner):
    l2 = ran(learner, 3000.0, 1500.0, roll=False)
    e = l2.snapshot()["I_x"]
    assert e.status == NOT_RUN and not e.valid and "roll-rate" in e.reason
    assert l2.snapshot()["C_alpha"].status != NOT_RUN


def test_roll_excitation_is_the_roll_rates_derivative_in_ln_i_x(learner):
    """chi' against a finite difference of two roll responses to the same a_y (eq 9)."""
    from vdp.core.learner import RollExcitation

    l2 = ran(learner, 480.0, 4.0)
    k = l2.known
    t = np.arange(0.0, 6.0, 0.01)
    a_y = 3.0 * np.sign(np.sin(2 * np.pi * t / 2.0))  # steering reversals: a_y steps
    eps = 1e-4
    runs = [RollExcitation(k, 480.0 * f, 0.0, 0.0, 0.0) for f in (1.0, 1.0 + eps)]
    got, want = [], []
    for ti, a in zip(t[1:], a_y[1:]):
        for r in runs:
            r.step(ti, a)
        got.append(runs[0].chi_d)
        want.append((runs[1].w - runs[0].w) / math.log(1.0 + eps))
    got, want = np.array(got), np.array(want)
    assert np.abs(want).max() > 1e-3  # the reversals do excite the roll
    assert np.abs(got - want).max() <= 0.01 * np.abs(want).max()


def test_accel_noise_excitation_is_what_white_a_y_puts_into_chi(learner):
    """The stationary E[chi'^2] from the Lyapunov equation against RollExcitation driven by
    white a_y alone (no lateral motion: all of it is the accelerometer's noise)."""
    from vdp.core.learn.verdict import RollExcitation, accel_noise_excitation

    l2 = ran(learner, 480.0, 4.0)
    k = dataclasses.replace(l2.known, k_phi=48000.0, c_phi=3500.0, m=1100.0, h=0.55)  # an ordinary roll
    want = accel_noise_excitation(k, 480.0, 0.01, 0.05)
    assert want > 0.0
    ex = RollExcitation(k, 480.0, 0.0, 0.0, 0.0)
    noise = np.random.default_rng(7).standard_normal(60000) * 0.05
    got = []
    for n, a in enumerate(noise, start=1):
        ex.step(n * 0.01, float(a))
        if n > 500:
            got.append(ex.chi_d * ex.chi_d)
    assert np.mean(got) == pytest.approx(want, rel=0.1)
    # a quieter accelerometer puts in less, by its variance; the paper car's over-damped roll
    # (Table 6) takes in far less than an ordinary one
    assert accel_noise_excitation(k, 480.0, 0.01, 0.025) == pytest.approx(want / 4, rel=1e-9)
    assert accel_noise_excitation(l2.known, 480.0, 0.01, 0.05) < 0.1 * want


def test_roll_information_mostly_the_accelerometers_noise_makes_i_x_not_valid(learner):
    """An ordinary drive: slow, small lateral transients, so the accelerometer's noise is most of
    what moves eq (9)'s roll rate where I_x matters; the filter then reads I_x too large, and its
    std must carry that share of the value."""
    l2 = ran(learner, 480.0, 4.0, info=1e4)
    feed(l2.roll_total, NIS_MATCHED, 0.0)
    l2._noise_info = 0.6e4  # the drive's own: 4e3, which alone would make I_x's std tiny
    assert l2.accel_share() == pytest.approx(0.6)
    e = l2.snapshot()["I_x"]
    assert not e.valid and e.reason.startswith("roll not excited") and "accelerometer" in e.reason
    assert e.std >= 0.6 * 480.0
    assert abs(e.value - 480.0 / 1.6) <= 2 * e.std  # I_x read 60 % too large is still inside 2 sigma


def test_a_small_noise_share_only_widens_i_x(learner):
    l2 = ran(learner, 480.0, 4.0, info=1e5)
    feed(l2.roll_total, NIS_MATCHED, 0.0)
    l2._noise_info = 3e3  # 3 %: an excited drive (the paper's manoeuvres: well under 3 %)
    e = l2.snapshot()["I_x"]
    assert e.valid and e.reason is None
    assert e.std == pytest.approx(honest_std(BY_NAME["I_x"], 480.0, math.hypot(4.0, 0.03 * 480.0)), rel=0.01)


def test_the_accelerometers_noise_is_not_counted_as_the_drives_excitation(learner):
    """The 'roll not excited' rule reads the information less the noise's share."""
    l2 = ran(learner, 3000.0, 300.0, info=5e3)
    feed(l2.roll_total, NIS_MATCHED, 0.0)
    assert not (l2.snapshot()["I_x"].reason or "").startswith("roll not excited")
    l2._noise_info = 5e3 - 0.7  # the paper car's own information, the rest noise
    e = l2.snapshot()["I_x"]
    assert not e.valid and e.reason.startswith("roll not excited") and "at best" in e.reason


def test_noise_that_barely_moved_i_x_off_its_prior_leaves_it_the_priors_std(learner):
    """The paper car's over-damped roll: the roll rate holds next to nothing, all of it the
    accelerometer's noise; I_x is then its prior, and its std the prior's, not more."""
    prior = learner.priors["I_x"]
    l2 = ran(learner, prior.value, 0.95 * prior.std, info=0.7)
    feed(l2.roll_total, NIS_MATCHED, 0.0)
    l2._noise_info = 0.7
    e = l2.snapshot()["I_x"]
    assert not e.valid and e.reason.startswith("roll not excited")
    assert prior.std <= e.std <= 1.1 * prior.std


def test_a_roll_rate_of_noise_alone_widens_i_x_no_further_than_it_moved_it(learner):
    """A long drive whose roll rate holds noise alone moves I_x off its prior; the std then takes
    the prior's with that distance, not the whole value's share."""
    prior = learner.priors["I_x"]
    l2 = ran(learner, 4200.0, 100.0, info=50.0)
    feed(l2.roll_total, NIS_MATCHED, 0.0)
    l2._noise_info = 50.0
    e = l2.snapshot()["I_x"]
    assert not e.valid and e.reason.startswith("roll not excited")
    cap = math.hypot(prior.std, 4200.0 - prior.value)
    quiet = prior.std / prior.value * 4200.0  # the drive's own information is none: the prior's relative std
    assert cap <= e.std <= 1.01 * max(cap, quiet) < 4200.0 * 50.0 / 54.0  # the whole share: 3,900
