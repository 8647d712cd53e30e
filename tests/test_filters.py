"""Pure unit tests of the filters' consider state (Schmidt-Kalman), on a linear model.

a is estimated, c is a considered bias: z = a + c.  With priors var_a, var_c and noise
r, the closed form is S = var_a + var_c + r and gain var_a / S for a, none for c;
afterwards var_a - var_a^2 / S, cov(a, c) = -var_a var_c / S, var_c unchanged.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vdp.core.filters import EKF, UKF

VAR_A, VAR_C, R = 4.0, 1.0, 0.25
X0 = np.array([1.0, 0.5])
Z = np.array([3.0])


def fx(x, dt, u):
    return np.array(x, dtype=float, copy=True)


def hx(x, u):
    x = np.asarray(x)
    return (x[..., 0] + x[..., 1])[..., None]


def make(kind: str, consider):
    args = (X0, np.diag([VAR_A, VAR_C]), np.zeros((2, 2)), np.array([[R]]), np.ones(2), fx, hx)
    if kind == "ukf":
        return UKF(*args, consider=consider)
    return EKF(*args, lambda x, u: np.zeros((2, 2)), lambda x, u: np.array([[1.0, 1.0]]), consider=consider)


@pytest.mark.parametrize("kind", ["ukf", "ekf"])
def test_consider_state_is_not_updated_but_its_uncertainty_is_carried(kind):
    f = make(kind, consider=1)
    f.predict(0.01, np.zeros(1))
    f.update(Z, np.array([True]), np.zeros(1))
    s = VAR_A + VAR_C + R
    np.testing.assert_allclose(f.x, [X0[0] + VAR_A / s * (Z[0] - X0.sum()), X0[1]], rtol=1e-6)
    np.testing.assert_allclose(
        f.P, [[VAR_A - VAR_A**2 / s, -VAR_A * VAR_C / s], [-VAR_A * VAR_C / s, VAR_C]], rtol=1e-6
    )


@pytest.mark.parametrize("kind", ["ukf", "ekf"])
def test_without_consider_both_states_are_estimated(kind):
    f = make(kind, consider=None)
    f.predict(0.01, np.zeros(1))
    f.update(Z, np.array([True]), np.zeros(1))
    s = VAR_A + VAR_C + R
    assert f.x[1] == pytest.approx(X0[1] + VAR_C / s * (Z[0] - X0.sum()), rel=1e-6)
    assert f.P[1, 1] == pytest.approx(VAR_C - VAR_C**2 / s, rel=1e-6)


def test_considering_a_bias_keeps_the_filters_std_honest():
    """Over many drives with a biased c, the UKF that considers c's uncertainty claims the
    variance of a it really has; one that takes c as exact claims under half of it."""
    rng = np.random.default_rng(0)

    def run(var_c, a, c, z):
        f = UKF(
            np.array([X0[0], X0[1]]),
            np.diag([VAR_A, var_c]),
            np.zeros((2, 2)),
            np.array([[R]]),
            np.ones(2),
            fx,
            hx,
            consider=1,
        )
        f.predict(0.01, np.zeros(1))
        f.update(np.array([z]), np.array([True]), np.zeros(1))
        return f.x[0] - a, f.P[0, 0]

    honest, naive = [], []
    for _ in range(2000):
        a, c = X0[0] + rng.normal(0, VAR_A**0.5), X0[1] + rng.normal(0, VAR_C**0.5)
        z = a + c + rng.normal(0, R**0.5)
        honest.append(run(VAR_C, a, c, z))
        naive.append(run(1e-12, a, c, z))
    for runs, ratio in ((honest, (0.9, 1.1)), (naive, (2.0, np.inf))):
        err, claimed = np.array(runs).T
        assert ratio[0] < np.mean(err**2) / np.mean(claimed) < ratio[1]


def test_a_new_stage2_window_keeps_the_parameters_correlation_with_l_f(repo_root):
    """What one window learnt about C_alpha's dependence on l_f is kept for the next,
    rescaled to stage 1's std then, and the starting covariance stays positive definite."""
    from vdp.core import lateral
    from vdp.core.learner import Stage2
    from vdp.profile import load_profile

    profile = load_profile(repo_root / "profiles" / "paper.toml")
    l2 = Stage2("ukf", profile.vehicle, profile.priors)
    l2.set_stage1(1.4, 0.6, 10.0, l_f_std=0.002)
    l2.theta_P = np.diag([2000.0, 3000.0, 50.0, 1000.0]) ** 2
    # rho 0.6, 0.5, 0.4 at sd 1 mm (their squares sum below 1: a valid covariance)
    l2.cross = (np.array([0.6 * 2000.0 * 0.001, 0.5 * 3000.0 * 0.001, 0.4 * 50.0 * 0.001, 0.0]), 0.001)
    P0 = l2._initial_cov()
    c, p = lateral.L_F, lateral.PARAM_SLICE
    assert P0[c, c] == pytest.approx(0.002**2)
    rho = P0[p, c] / np.sqrt(np.diagonal(P0)[p] * P0[c, c])
    np.testing.assert_allclose(rho, [0.6, 0.5, 0.4, 0.0])
    assert np.all(np.linalg.eigvalsh(P0) > 0)
    l2.set_stage1(1.4, 0.6, 10.0, l_f_std=float("nan"))  # no usable std: the prior's, never exact
    assert l2.l_f_std == profile.priors["l_f"].std


# -- the written-out steps against filterpy's own (tests/helpers/filterpy_ref.py) --------------
@pytest.fixture(scope="module")
def profile(repo_root):
    from vdp.profile import load_profile

    return load_profile(repo_root / "profiles" / "paper.toml")


def _stage2_pair(kind: str, profile, monkeypatch):
    """A stage-2 filter (bounded transforms, consider state l_f) built twice on the same
    start: once as vdp.core.filters runs it, once on filterpy's generic steps.  (The compiled
    steps are held to vdp.core.filters' in tests/test_kernels.py.)"""
    from helpers import filterpy_ref
    from vdp.core.learn import base as lm  # where the learners build their filters
    from vdp.core.learner import LearnerConfig, Stage2

    l2 = Stage2(kind, profile.vehicle, profile.priors, LearnerConfig(compiled=False))
    l2.set_stage1(1.4, 0.6, 10.0, l_f_std=0.002)
    x0, P0 = l2._start(np.array([0.1, 0.01, 2.0]), np.ones(3, dtype=bool), [0.05, 15.0, 50.0, 0.3])
    lean = l2._new_filter(x0, P0, l2._R())
    monkeypatch.setattr(lm, "UKF", filterpy_ref.UKF)
    monkeypatch.setattr(lm, "EKF", filterpy_ref.EKF)
    ref = l2._new_filter(x0, P0, l2._R())
    assert type(lean) is not type(ref)
    return l2, lean, ref


@pytest.mark.parametrize("kind", ["ukf", "ekf"])
def test_written_out_steps_match_filterpys_on_the_stage2_model(kind, profile, monkeypatch):
    """40 predict/update steps of the roll model with changing inputs and a missing sensor
    now and then: the same state and covariance as filterpy's generic steps, to float noise."""
    l2, lean, ref = _stage2_pair(kind, profile, monkeypatch)
    rng = np.random.default_rng(3)
    for k in range(40):
        u = np.array([[0.05 + 0.02 * np.sin(0.1 * k), 15.0, 50.0 + rng.normal(0, 0.1), 0.3]] * 3)
        z = np.array([0.1 + rng.normal(0, 0.002), 0.01 + rng.normal(0, 0.002), 2.0 + rng.normal(0, 0.05)])
        mask = np.array([True, k % 7 != 3, True])
        for f in (lean, ref):
            f.predict(0.04, u)
            f.update(z, mask, u[-1])
        np.testing.assert_allclose(lean.x, ref.x, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(lean.P, ref.P, rtol=1e-6, atol=1e-9 * np.abs(ref.P).max())
        y1, S1 = lean.innovation()
        y2, S2 = ref.innovation()
        np.testing.assert_allclose(y1, y2, rtol=1e-6, atol=1e-8)  # z of ~2: 1e-8 is float noise of the sums
        np.testing.assert_allclose(S1, S2, rtol=1e-6, atol=1e-9 * np.abs(S2).max())
    assert abs(lean.x[4] - l2.theta[0]) > 1e-6 * l2.theta[0], "the data never moved C_alpha: the test saw nothing"


@pytest.mark.parametrize("kind", ["ukf", "ekf"])
def test_written_out_steps_fail_as_filterpys_do(kind, profile, monkeypatch):
    """An indefinite covariance is caught by both, as a FilterError."""
    from vdp.errors import FilterError

    _, lean, ref = _stage2_pair(kind, profile, monkeypatch)
    u = np.array([0.05, 15.0, 50.0, 0.3])
    for f in (lean, ref):
        P = f._f.P.copy()
        P[0, 1] = P[1, 0] = 2.0 * np.sqrt(P[0, 0] * P[1, 1])
        f._f.P = P
        with pytest.raises(FilterError, match=r"positive definite|Matrix"):
            f.predict(0.04, u)
            f.update(np.array([0.1, 0.01, 2.0]), np.ones(3, dtype=bool), u)


@pytest.mark.slow
def test_a_drive_gives_the_same_estimates_as_on_filterpys_steps(profile, monkeypatch):
    """The first 72 s of the paper drive (both stages), UKF and EKF: every estimate and
    every trace row as on filterpy's steps, to float noise (vdp.core.filters' numpy steps;
    tests/test_kernels.py holds the compiled ones to these)."""
    from helpers import filterpy_ref
    from vdp.core.estimator import EstimatorConfig
    from vdp.core.learn import base as lm  # where the learners build their filters
    from vdp.core.learner import LearnerConfig
    from vdp.pipeline import Pipeline
    from vdp.sim.run import Simulation

    frames = list(Simulation(profile, "paper", 2, "realistic", duration=72.0).frames())

    def run():
        pipe = Pipeline(profile, EstimatorConfig(learner=LearnerConfig(compiled=False)))
        for m in frames:
            pipe.feed(m)
        return pipe.result(trace=True)

    lean = run()
    monkeypatch.setattr(lm, "UKF", filterpy_ref.UKF)
    monkeypatch.setattr(lm, "EKF", filterpy_ref.EKF)
    ref = run()
    assert any(w.stage == 2 for w in ref.windows), "the drive never reached stage 2"
    for a, b in ((lean.parameters, ref.parameters), (lean.baseline_ekf, ref.baseline_ekf)):
        for name, e in b.items():
            assert a[name].status == e.status, name
            assert a[name].value == pytest.approx(e.value, rel=1e-7), name
            assert a[name].std == pytest.approx(e.std, rel=1e-5), name
    assert len(lean.trace) == len(ref.trace)
    for r1, r2 in zip(lean.trace, ref.trace):
        assert r1[:2] == r2[:2]
        v1 = [x if x is not None else np.nan for kind in r1[2:] for p in kind for x in p]
        v2 = [x if x is not None else np.nan for kind in r2[2:] for p in kind for x in p]
        np.testing.assert_allclose(v1, v2, rtol=1e-5, equal_nan=True)


@settings(max_examples=200, deadline=None)
@given(
    n=st.integers(1, 3),
    seed=st.integers(0, 2**32 - 1),
    cond=st.floats(1e-6, 1.0),
)
def test_stage2s_innovation_test_in_plain_floats_equals_a_numpy_solve(n, seed, cond):
    """learner.quad_form (the NIS of stage 2's 1-3 rows, without numpy's per-call overhead) is
    y' S^-1 y as np.linalg.solve gives it, down to a badly conditioned S; None where S is not
    positive definite."""
    from vdp.core.learner import quad_form

    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    S = Q @ np.diag(np.linspace(cond, 1.0, n)) @ Q.T * 10.0 ** rng.uniform(-6, 6)
    S = 0.5 * (S + S.T)
    y = rng.normal(size=n) * math.sqrt(S[0, 0])
    want = float(y @ np.linalg.solve(S, y))
    got = quad_form(y.tolist(), S.tolist())
    assert got == pytest.approx(want, rel=1e-6 / cond)
    bad = S.copy()
    bad[-1, -1] = -abs(bad[-1, -1])  # a negative variance: no covariance
    assert quad_form(y.tolist(), bad.tolist()) is None
