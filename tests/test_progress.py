"""Progress and coaching (core.progress): from the learners' state, never from a clock."""

import math
from types import SimpleNamespace

import pytest

from vdp.core import progress
from vdp.core.params import NAMES, STAGE1, STAGE2
from vdp.core.supervisor import LITTLE_AX, LITTLE_STEER, SPEED_LOW, WAITING, Supervisor
from vdp.io.logs import open_log
from vdp.pipeline import Pipeline
from vdp.profile import load_profile
from vdp.sim.run import simulate, write_log

PRIORS = {
    n: SimpleNamespace(value=v, std=s)
    for n, v, s in zip(NAMES, (1.25, 0.55, 8, 5e4, 2500, 3000), (0.3, 0.2, 4, 2.5e4, 1200, 1500))
}


# the supervisor's reasons as it gives them (typed: core.progress reads their codes, never their text)
WHY = Supervisor().why


def snap(stage="stage1", reasons=None, caps=None, **params):
    base = {n: {"value": PRIORS[n].value, "std": PRIORS[n].std, "status": "not_run", "samples": 0} for n in NAMES}
    for n, p in params.items():
        base[n] = {**base[n], **p}
    return {
        "parameters": base,
        "stage": stage,
        "supervisor": {"reasons": reasons or {"1": "open", "2": WHY(WAITING)}, "excitation": {}},
        "capabilities": caps or {"1": None, "2": None},
    }


def test_information_runs_from_prior_to_threshold_on_a_log_scale():
    # l_f: converged at 0.7 % of 1.4 m = 0.0098 m; the prior's std is 0.3 m
    f = [progress.information(1.4, sd, 0.3, 0.007) for sd in (0.3, 0.1, 0.03, 0.0098, 0.001)]
    assert f[0] == 0 and f[-2] == pytest.approx(1.0) and f[-1] == 1.0
    assert f == sorted(f)
    assert f[2] == pytest.approx(math.log(10) / math.log(0.3 / 0.0098))
    assert progress.information(None, 0.1, 0.3, 0.007) == 0.0


def test_seconds_to_go_follows_one_over_root_n():
    # std twice the target after 10 s: four times the samples, 30 s more
    assert progress.seconds_to_go(1.0, 0.02, 10.0, 0.01) == pytest.approx(30.0)
    assert progress.seconds_to_go(1.0, 0.005, 10.0, 0.01) == 0.0
    assert progress.seconds_to_go(1.0, 0.02, 0.0, 0.01) is None


def test_nothing_driven_is_zero_and_says_what_to_drive():
    out = progress.assess(snap(reasons={"1": WHY(LITTLE_AX)}), PRIORS, 0.02)
    assert all(p["progress"] == 0 for p in out["parameters"].values())
    assert out["stages"]["1"]["progress"] == 0 and out["stages"]["2"]["progress"] == 0
    assert "accelerate" in out["next"] and "not changing enough" in out["next"]
    assert "stage 1" in out["parameters"]["I_z"]["hint"]


def test_progress_comes_from_the_std_not_from_time():
    half = {"value": 1.4, "std": 0.05, "status": "uncertain", "samples": 1000}
    a = progress.assess(snap(l_f=half), PRIORS, 0.02)["parameters"]["l_f"]
    b = progress.assess(snap(l_f={**half, "samples": 100000}), PRIORS, 0.02)["parameters"]["l_f"]
    assert 0 < a["progress"] < 1 and a["progress"] == b["progress"]  # more time, same information: same progress
    assert a["window_s"] == 20.0 and "keep doing this" in a["hint"]


def test_converged_and_not_identifiable():
    done = {"value": 1.4, "std": 0.005, "status": "converged", "samples": 900}
    stuck = {"value": 2900.0, "std": 1400.0, "status": "not_identifiable", "samples": 900}
    conv = {"value": 6.7e4, "std": 500.0, "status": "converged", "samples": 900}
    s = snap(stage="done", l_f=done, h=done, C_K=done, C_alpha=conv, I_z=conv, I_x=stuck)
    out = progress.assess(s, PRIORS, 0.02)
    assert out["parameters"]["l_f"]["progress"] == 1.0 and out["parameters"]["l_f"]["hint"].startswith("enough")
    assert out["parameters"]["I_x"]["progress"] < 0.2 and "roll" in out["parameters"]["I_x"]["hint"]
    assert out["stages"]["2"]["progress"] == 1.0 and out["next"].startswith("done")


def test_a_stage_this_car_cannot_run_says_why():
    why = "no roll-rate gyro (the profile maps no roll_rate)"
    out = progress.assess(snap(caps={"1": None, "2": why}), PRIORS, 0.02)
    for n in STAGE2:
        assert why in out["parameters"][n]["hint"]
    assert not out["stages"]["2"]["can_run"]


def test_a_parameter_this_car_cannot_learn_is_not_counted_as_learnt():
    """I_x without a roll-rate gyro leaves stage 2's progress to C_alpha and I_z: a stage 2 that never
    ran reads 0 %, not 33 % (the RAV4's replay had said 33 %); once they converge, 100 %."""
    caps = {"1": None, "2": None, "I_x": "no roll-rate gyro (the profile maps no roll_rate)"}
    out = progress.assess(snap(caps=caps), PRIORS, 0.02)
    assert out["stages"]["2"]["progress"] == 0.0 and out["stages"]["2"]["can_run"]
    done = {n: {"status": "converged", "std": 0.001 * PRIORS[n].value} for n in ("C_alpha", "I_z")}
    assert progress.assess(snap(caps=caps, **done), PRIORS, 0.02)["stages"]["2"]["progress"] == 1.0


@pytest.mark.slow
def test_progress_grows_while_the_paper_drive_goes_on(tmp_path, repo_root):
    profile = load_profile(repo_root / "profiles" / "paper.toml")
    frames, _ = simulate(repo_root / "profiles" / "paper.toml", "paper", seed=2, duration=80.0)
    log = tmp_path / "d.log"
    write_log(frames, log)
    pipe = Pipeline(profile)
    seen = []
    for i, msg in enumerate(open_log(log, channel=profile.bus_channel)):
        pipe.feed(msg)
        if i % 4000 == 0:
            c = pipe.result().coaching
            seen.append((c["stages"]["1"]["progress"], c["stages"]["2"]["progress"]))
    s1 = [a for a, _ in seen]
    assert s1[0] < 0.5 and s1[-1] == 1.0
    assert max(b for _, b in seen) > 0.3  # stage 2 learns in the weaving that follows
    final = pipe.result()
    for n in STAGE1:
        assert final.parameters[n].progress == 1.0 and final.parameters[n].status == "converged"


def test_a_flagged_estimate_is_not_learnt_whatever_its_std():
    mismatch = {
        "value": 1.4,
        "std": 0.001,
        "status": "converged",
        "valid": False,
        "samples": 900,
        "reason": "model mismatch: residuals not white",
    }
    out = progress.assess(snap(l_f=mismatch), PRIORS, 0.02)["parameters"]["l_f"]
    assert out["progress"] < 1.0 and "model mismatch" in out["hint"] and out["hint"].startswith("not valid")


def test_a_parameter_the_drive_did_not_excite_is_not_called_a_model_mismatch():
    quiet = {
        "value": 3300.0,
        "std": 1500.0,
        "status": "not_identifiable",
        "valid": False,
        "samples": 900,
        "reason": "roll not excited: quick steering reversals at speed excite the roll",
    }
    hint = progress.assess(snap(I_x=quiet), PRIORS, 0.02)["parameters"]["I_x"]["hint"]
    assert hint.startswith("not valid: roll not excited") and "differs from the model" not in hint


def test_next_names_the_stage_behind_or_the_one_being_driven():
    conv = {"value": 1.4, "std": 0.001, "status": "converged", "samples": 900}
    half = {"value": 10.0, "std": 0.5, "status": "uncertain", "samples": 900}
    c2 = {"value": 6.7e4, "std": 500.0, "status": "converged", "samples": 900}
    # stage 2 started once l_f was known; C_K is still uncertain: stage 1's driving is next
    s = snap(stage="done", reasons={"1": WHY(SPEED_LOW), "2": "open"}, l_f=conv, h=conv, C_K=half)
    s["parameters"].update({"C_alpha": c2, "I_z": c2, "I_x": {**c2, "status": "not_identifiable"}})
    out = progress.assess(s, PRIORS, 0.02)
    assert out["stages"]["2"]["progress"] == 1.0 and out["stages"]["1"]["progress"] < 1.0
    assert "accelerate" in out["next"] and "too slow" in out["next"]
    # while a window is open, the driver is told to keep going with it
    s["supervisor"]["reasons"] = {"1": "open", "2": WHY(LITTLE_STEER)}
    assert progress.assess(s, PRIORS, 0.02)["next"].startswith("keep going: on a straight")


def test_a_model_mismatch_does_not_ask_for_more_of_the_same_driving():
    conv = {"value": 1.4, "std": 0.001, "status": "converged", "valid": True, "samples": 900}
    off = {"status": "uncertain", "valid": False, "samples": 900, "reason": "model mismatch: filter and fit differ"}
    s = snap(stage="done", reasons={"1": "open", "2": "open"}, l_f=conv, h=conv, C_K=conv)
    s["parameters"].update(
        {
            "C_alpha": {**off, "value": 6.0e4, "std": 6.0e3},
            "I_z": {**off, "value": 2.2e3, "std": 300.0},
            "I_x": {"value": 500.0, "std": 200.0, "status": "not_identifiable", "samples": 900},
        }
    )
    out = progress.assess(s, PRIORS, 0.02)
    # not learnt (its own progress says so), but driving more of stage 2 will not fix it
    assert out["parameters"]["C_alpha"]["progress"] < 1.0
    assert out["stages"]["2"]["progress"] == 1.0 and out["next"].startswith("done:")
    # one stage-2 parameter still learning: keep going with it
    s["parameters"]["I_z"] = {"value": 2.2e3, "std": 500.0, "status": "uncertain", "samples": 900}
    assert progress.assess(s, PRIORS, 0.02)["next"].startswith("keep going")


def test_what_the_learners_report_is_used():
    half = {"value": 10.0, "std": 0.5, "status": "uncertain", "samples": 10}
    s = snap(C_K=half, reasons={"1": "open", "2": WHY(WAITING)})
    s["supervisor"]["learners"] = {
        "ukf": {"stage1": {"seconds_in_windows": 42.0, "blocks_used": 30, "blocks_beyond_small_slip": 90}}
    }
    out = progress.assess(s, PRIORS, 0.02)
    c_k = out["parameters"]["C_K"]
    assert c_k["window_s"] == 42.0  # the learner's own seconds, not samples x tick
    assert "ease off" in c_k["hint"] and "75 %" in c_k["hint"]
    assert out["stages"]["1"]["blocks_beyond_small_slip"] == 90 and out["stages"]["1"]["window_s"] == 42.0
    s["supervisor"]["learners"]["ukf"]["stage1"]["blocks_beyond_small_slip"] = 5
    assert "ease off" not in progress.assess(s, PRIORS, 0.02)["parameters"]["C_K"]["hint"]


def test_a_reason_is_its_text_and_its_code():
    """What a user reads is the reason's text, unchanged in JSON; the code is what code reads, and
    survives a pickle (a process pool hands the estimator's state back)."""
    import json
    import pickle

    from vdp.core.supervisor import MISSING, Code, Reason

    r = WHY(SPEED_LOW)
    assert r == "speed below 5.0 m/s" and json.dumps({"1": r}) == '{"1": "speed below 5.0 m/s"}'
    assert r.code is Code.SPEED_LOW and r.hard and not WHY(LITTLE_AX).hard
    gone = Reason(MISSING, "channels missing or stale: ax, yaw_rate", ("ax", "yaw_rate"))
    back = pickle.loads(pickle.dumps(gone))
    assert back == gone and back.code is Code.MISSING and back.channels == ("ax", "yaw_rate")
    assert progress._fix(gone) == "check the bus: ax, yaw_rate silent or stale"
    assert progress._fix("speed below 5.0 m/s") is None  # an untyped text is never parsed
