"""Stage 2 on its own: a car whose bus cannot feed stage 1 (no axle torque, no GNSS) runs
stage 2 from steering, yaw rate, a_y and the wheels' speed, with l_f measured in the profile;
without a roll-rate gyro I_x is not_run with the reason, and C_alpha and I_z are still
estimated.  Seeded simulated drives through vdp's own bus (the paper car's layout, channels
taken away); the 5-seed figures: `benchmarks/standalone.py`.
"""

from __future__ import annotations

import dataclasses

import pytest

from vdp.core.estimator import EstimatorConfig
from vdp.core.learner import LearnerConfig
from vdp.core.result import NOT_RUN
from vdp.pipeline import Pipeline
from vdp.profile import load_profile
from vdp.sim.run import simulate

# loose bounds for a 30 s drive: the 5-seed benchmark gives within 2.5 % on 52 s
TOL = {"C_alpha": 0.06, "I_z": 0.08}
NO_STAGE1 = ("wheel_torque_front", "wheel_torque_rear", "speed")


def layout(repo_root, drop: tuple[str, ...], l_f: float | None) -> object:
    """The paper car's profile without the ``drop`` channels, with a measured l_f (or none)."""
    prof = load_profile(repo_root / "profiles" / "paper.toml")
    chans = {k: v for k, v in prof.channels.items() if k not in drop}
    msgs = {v.message for v in chans.values()}
    veh = dataclasses.replace(prof.vehicle, l_f=l_f, l_f_std=None if l_f is None else 0.01 * l_f)
    checks = {k: v for k, v in prof.checks.items() if k in msgs}
    return dataclasses.replace(prof, channels=chans, checks=checks, vehicle=veh)


def drive(prof, seed: int, duration: float = 30.0, cfg=None):
    frames, truth = simulate(prof, "stage2", seed=seed, noise="realistic", duration=duration)
    pipe = Pipeline(prof, cfg)
    for m in frames:
        pipe.feed(m)
    return pipe, pipe.result(), truth["parameters"]


def scale_l_f(truth_l_f: float) -> float:
    """An axle-scale l_f: the truth off by half a percent (a good weighing, not a perfect one)."""
    return 1.005 * truth_l_f


@pytest.fixture(scope="module")
def truth_l_f():
    from vdp.sim.truth import truth_parameters

    return truth_parameters()["l_f"]


def test_without_roll_rate_i_x_is_not_run_and_c_alpha_i_z_are_estimated(repo_root, truth_l_f):
    prof = layout(repo_root, NO_STAGE1 + ("roll_rate",), scale_l_f(truth_l_f))
    pipe = Pipeline(prof)
    cap = pipe.capabilities()
    assert "torque" in cap["1"] and cap["2"] is None and "roll_rate" in cap["I_x"]
    # One C_alpha for both axles: per axle (the default) the mean's std with l_f known to 1 % is
    # 1.96 % on this drive (truth inside 1 std), above C_alpha's convergence threshold (1.5 %), so
    # it stays "uncertain" and the last assertion (I_x not_run does not hold back "done") could
    # not be made; the per-axle accuracy on this layout is from `benchmarks/standalone.py`
    one = EstimatorConfig(learner=LearnerConfig(per_axle=False))
    pipe, res, truth = drive(prof, seed=4, duration=52.0, cfg=one)
    assert {w.stage for w in res.windows} == {2}
    for kind, params in (("ukf", res.parameters), ("ekf", res.baseline_ekf)):
        ix = params["I_x"]
        assert ix.status == NOT_RUN and not ix.valid and "roll-rate" in ix.reason, kind
        assert ix.value == pytest.approx(prof.priors["I_x"].value, rel=0.01)  # frozen at the prior
        for name, tol in TOL.items():
            e = params[name]
            err = (e.value - truth[name]) / truth[name]
            assert abs(err) <= tol, f"{kind} {name}: {100 * err:+.2f} %"
            assert e.samples > 0 and e.status != NOT_RUN
        for name in ("l_f", "h", "C_K"):  # stage 1 never ran: no front drive force from its prior
            assert params[name].status == NOT_RUN
        assert f"the profile's l_f = {prof.vehicle.l_f:.3g}" in params["l_f"].reason
    for l2 in pipe.estimator.s2.values():
        assert l2.known.C_K == 0.0 and l2.known.l_f == prof.vehicle.l_f and l2.roll_updates == 0
    # I_x not_run for want of a gyro does not hold the estimator back from "done"
    assert res.parameters["C_alpha"].valid and res.parameters["I_z"].valid and res.stage == "done"


def test_stage2_runs_without_stage1_when_the_profile_gives_l_f(repo_root, truth_l_f):
    """No axle torque and no GNSS, but a roll-rate gyro: stage 2 runs, I_x is estimated."""
    prof = layout(repo_root, NO_STAGE1, scale_l_f(truth_l_f))
    pipe, res, truth = drive(prof, seed=5)
    assert {w.stage for w in res.windows} == {2}
    l2 = pipe.estimator.s2["ukf"]
    assert l2.roll_updates > 0 and l2.roll_updates == l2.updates
    p = res.parameters
    assert p["I_x"].status != NOT_RUN and "roll-rate" not in (p["I_x"].reason or "")
    for name, tol in TOL.items():
        assert abs(p[name].value - truth[name]) <= tol * truth[name], name


def test_without_l_f_stage2_waits_and_says_what_it_needs(repo_root):
    prof = layout(repo_root, NO_STAGE1, None)
    cap = Pipeline(prof).capabilities()
    assert "needs l_f" in cap["2"] and "[vehicle] l_f" in cap["2"] and cap["I_x"] is None
    _, res, _ = drive(prof, seed=1, duration=8.0)
    assert res.windows == () or all(w.stage != 2 for w in res.windows)
    assert all(res.parameters[n].status == NOT_RUN for n in ("C_alpha", "I_z", "I_x"))
