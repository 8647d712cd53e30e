"""The estimator on cars it was not derived from (issue 11's targets, on short seeded drives).

Each case drives the paper's manoeuvre (cut to DURATION s: all of stage 1, the transition
and the start of stage 2) on an independent model, encodes it through vdp's DBC into a
candump log and replays that log; the estimator gets the car's profile (known constants,
imperfect priors) and never the truth file.

The assertions without a mark hold today.  The targets of issue 11 that today's
estimator misses are stated as they are meant and marked xfail(strict=False): when the
estimator meets one, it shows as XPASS; then drop its mark.
"""

from __future__ import annotations

import pytest

from vdp.core.estimator import EstimatorConfig
from vdp.core.learner import LearnerConfig
from vdp.io.logs import open_log
from vdp.pipeline import Pipeline
from vdp.replay import replay
from vdp.sim.independent.common import IndependentSimulation
from vdp.sim.run import write_log

try:
    import vehiclemodels  # noqa: F401

    HAVE_MB = True
except ImportError:  # the bench extra; bootstrap installs it, so CI runs these
    HAVE_MB = False

DURATION = 85.0
CASES = ["brush/small", pytest.param("mb/bmw_320i", marks=pytest.mark.skipif(not HAVE_MB, reason="bench extra"))]

pytestmark = pytest.mark.slow

_cache: dict[tuple[str, bool], tuple[dict, dict]] = {}


def _run(case: str, tmp_path_factory, per_axle: bool = True) -> tuple[dict, dict]:
    """(replay result, truth) of one seeded drive, made once per session; ``per_axle``: stage 2
    estimates each axle's cornering stiffness (LearnerConfig.per_axle, the default)."""
    if (case, per_axle) not in _cache:
        model, car = case.split("/")
        sim = IndependentSimulation(model, car, "paper", seed=1, noise="realistic", duration=DURATION)
        log = tmp_path_factory.mktemp(case.replace("/", "-")) / "drive.log"
        write_log(sim.frames(), log, sim.bus_channel)
        pipe = Pipeline(sim.profile, EstimatorConfig(learner=LearnerConfig(per_axle=per_axle)))
        _cache[case, per_axle] = (replay(open_log(log, channel=sim.profile.bus_channel), pipe).to_dict(), sim.truth)
    return _cache[case, per_axle]


def _est(res: dict, name: str, kind: str = "parameters") -> tuple[float, float, bool]:
    e = res[kind][name]
    return e["value"], e["std"], bool(e["valid"])


@pytest.mark.parametrize("case", CASES)
def test_stage_1_runs_and_l_f_is_near(case, tmp_path_factory):
    res, truth = _run(case, tmp_path_factory)
    assert any(w["stage"] == 1 for w in res["windows"])
    for kind in ("parameters", "baseline_ekf"):
        v, sd, _ = _est(res, "l_f", kind)
        # loose: the static load split is the best-observed quantity even with a real tyre (EKF today < 2 %)
        assert v == pytest.approx(truth["parameters"]["l_f"], rel=0.05), kind
        assert sd > 0
    # issue 11's target for l_f (3 %), which the UKF meets today on these two cars
    assert _est(res, "l_f")[0] == pytest.approx(truth["parameters"]["l_f"], rel=0.03)


# -- issue 11's targets ---------------------------------------------------------------
TODAY = 'issue 11: a target this drive does not meet yet (BENCHMARKS.md, "Models vdp did not write")'
# (case, what) that today's estimator misses on these drives (measured at 8a6a448; checked
# again at a86f469: bmw_320i's C_alpha -4.4 % and brush/small's rear C_alpha +1.1 % meet their
# targets and are plain tests now).  With each axle estimated and eq (9) driven by the measured
# a_y (lat), brush/small's C_alpha and front axle and both of bmw_320i's axles meet theirs too
# (UKF on this drive: brush/small C_alpha -4.5 %, front -8 %; bmw_320i front +8 %, rear +4 %)
# brush/small's I_z (+19 %, the roll swing) meets its target since stage 2's output-error fit
# carries the swing and the tyre's shape and is reported where the shape is freed (s2shape).
# (case, parameter) a target misses today; empty since mb/bmw_320i's I_z (+12 % on this short
# drive) came within 10 % once l_f's std carried the axles' split (docs/decisions/0021)
MISSES: set[tuple[str, str]] = set()


def _cases(*what):
    """Every (case, *what) as a test parameter; xfail(strict=False) where it misses today."""
    out = []
    for c in CASES:
        marks = list(c.marks) if hasattr(c, "marks") else []
        case = c.values[0] if hasattr(c, "values") else c
        for w in what:
            key = w if isinstance(w, tuple) else (w,)
            m = marks + ([pytest.mark.xfail(strict=False, reason=TODAY)] if (case, key[0]) in MISSES else [])
            out.append(pytest.param(case, *key, marks=m, id=f"{case}-{key[0]}"))
    return out


@pytest.mark.parametrize(("case", "name", "tol"), _cases(("C_K", 0.10), ("C_alpha", 0.10), ("I_z", 0.10)))
def test_target_accuracy(case, name, tol, tmp_path_factory):
    res, truth = _run(case, tmp_path_factory)
    v, _, _ = _est(res, name)
    assert v is not None
    assert v == pytest.approx(truth["parameters"][name], rel=tol)


@pytest.mark.parametrize(("case", "name"), _cases("C_alpha_front", "C_alpha_rear"))
def test_target_per_axle_cornering_stiffness(case, name, tmp_path_factory):
    res, truth = _run(case, tmp_path_factory)
    want = truth["per_axle"][name]
    axles = res["parameters"]["C_alpha"].get("extra", {})  # C_alpha is the mean; per axle in its extra
    assert axles.get(name) is not None, f"the estimator reports no {name} in C_alpha's extra"
    assert axles[name] == pytest.approx(want, rel=0.10)


@pytest.mark.parametrize(("case", "name", "tol"), _cases(("h", 0.10), ("I_x", 0.20)))
def test_target_accurate_or_honestly_not_valid(case, name, tol, tmp_path_factory):
    res, truth = _run(case, tmp_path_factory)
    v, sd, valid = _est(res, name)
    t = truth["parameters"][name]
    assert v is not None
    if valid:
        assert v == pytest.approx(t, rel=tol)
    else:
        assert abs(v - t) <= 2 * sd


@pytest.mark.parametrize(("case", "kind"), _cases("parameters", "baseline_ekf"))
def test_target_nothing_valid_with_truth_beyond_3_sigma(case, kind, tmp_path_factory):
    res, truth = _run(case, tmp_path_factory)
    bad = []
    for name, t in truth["parameters"].items():
        v, sd, valid = _est(res, name, kind)
        if valid and abs(v - t) > 3 * sd:
            bad.append(f"{name}: {v:.4g} ± {sd:.2g}, truth {t:.4g}")
    assert not bad, "; ".join(bad)


@pytest.mark.parametrize("case", CASES)
def test_stage_2_runs_where_the_drive_excites_it(case, tmp_path_factory):
    res, _ = _run(case, tmp_path_factory)
    assert any(w["stage"] == 2 for w in res["windows"])


@pytest.mark.parametrize("name", ["C_alpha", "I_z", "C_alpha_front", "C_alpha_rear"])
@pytest.mark.parametrize("kind", ["parameters", "baseline_ekf"])
@pytest.mark.parametrize("case", CASES)
def test_target_stage_2_truth_within_2_sigma(case, kind, name, tmp_path_factory):
    """Issue 11's +-2 sigma coverage for stage 2, per axle too (core.output_error's batch check widens a
    std the model cannot support).  On these short drives at 8510aeb the filter's own stds hold the truth
    as well (without the check, LearnerConfig(batch_check=False), the worst is 1.9 sigma: bmw_320i's EKF
    rear axle); where the check is what covers it: tests/test_output_error.py and BENCHMARKS.md."""
    res, truth = _run(case, tmp_path_factory)
    if name.startswith("C_alpha_"):  # per axle: in C_alpha's extra
        x = res[kind]["C_alpha"]["extra"]
        v, sd, t = x[name], x[name + "_std"], truth["per_axle"][name]
    else:
        v, sd, _ = _est(res, name, kind)
        t = truth["parameters"][name]
    assert abs(v - t) <= 2 * sd, f"{name} {v:.4g} ± {sd:.2g}, truth {t:.4g}"


def _l_f(status, value, std):
    from vdp.core.result import Estimate

    return Estimate("l_f", value, std, "m", status, status == "converged", 1, 100)


def test_stage_2_starts_on_an_l_f_known_to_2_percent():
    """Stage 2 needs l_f only, and carries its std: an l_f whose std a model mismatch widened
    (uncertain, 0.8-1.8 % on the independent models) still hands over; a vaguer one does not,
    nor one stage 1 has not estimated."""
    from vdp.core import estimator as est

    assert est._known(_l_f("converged", 1.2, 0.005))
    assert est._known(_l_f("uncertain", 1.2, 0.019 * 1.2))
    assert not est._known(_l_f("uncertain", 1.2, 0.03 * 1.2))
    assert not est._known(_l_f("not_identifiable", 1.2, 0.001))
    assert not est._known(_l_f("not_run", None, None))
    assert not est._known(_l_f("uncertain", 1.2, None))


@pytest.mark.parametrize("case", CASES)
def test_where_the_tyre_bends_the_mean_is_the_axles_mean(case, tmp_path_factory):
    """C_alpha is the mean of the two axles it publishes, whichever source (filter or fit) they
    come from."""
    res, _ = _run(case, tmp_path_factory)
    for kind in ("parameters", "baseline_ekf"):
        e = res[kind]["C_alpha"]
        x = e["extra"]
        assert e["value"] == pytest.approx(0.5 * (x["C_alpha_front"] + x["C_alpha_rear"]), rel=1e-9), kind
