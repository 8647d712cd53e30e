"""Pure unit tests of the filters' consider state (Schmidt-Kalman), on a linear model.

a is estimated, c is a considered bias: z = a + c.  With priors var_a, var_c and noise
r, the closed form is S = var_a + var_c + r and gain var_a / S for a, none for c;
afterwards var_a - var_a^2 / S, cov(a, c) = -var_a var_c / S, var_c unchanged.
"""

import numpy as np
import pytest

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
    l2.theta_P = np.diag([2000.0, 50.0, 1000.0]) ** 2
    l2.cross = (np.array([0.8 * 2000.0 * 0.001, 0.5 * 50.0 * 0.001, 0.0]), 0.001)  # rho 0.8, 0.5 at sd 1 mm
    P0 = l2._initial_cov()
    c, p = lateral.L_F, lateral.PARAM_SLICE
    assert P0[c, c] == pytest.approx(0.002**2)
    rho = P0[p, c] / np.sqrt(np.diagonal(P0)[p] * P0[c, c])
    np.testing.assert_allclose(rho, [0.8, 0.5, 0.0])
    assert np.all(np.linalg.eigvalsh(P0) > 0)
    l2.set_stage1(1.4, 0.6, 10.0, l_f_std=float("nan"))  # no usable std: the prior's, never exact
    assert l2.l_f_std == profile.priors["l_f"].std
