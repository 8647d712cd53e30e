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
    np.testing.assert_allclose(f.P, [[VAR_A - VAR_A ** 2 / s, -VAR_A * VAR_C / s],
                                     [-VAR_A * VAR_C / s, VAR_C]], rtol=1e-6)


@pytest.mark.parametrize("kind", ["ukf", "ekf"])
def test_without_consider_both_states_are_estimated(kind):
    f = make(kind, consider=None)
    f.predict(0.01, np.zeros(1))
    f.update(Z, np.array([True]), np.zeros(1))
    s = VAR_A + VAR_C + R
    assert f.x[1] == pytest.approx(X0[1] + VAR_C / s * (Z[0] - X0.sum()), rel=1e-6)
    assert f.P[1, 1] == pytest.approx(VAR_C - VAR_C ** 2 / s, rel=1e-6)


def test_considering_a_bias_keeps_the_filters_std_honest():
    """Over many drives with a biased c, the UKF that considers c's uncertainty claims the
    variance of a it really has; one that takes c as exact claims under half of it."""
    rng = np.random.default_rng(0)

    def run(var_c, a, c, z):
        f = UKF(np.array([X0[0], X0[1]]), np.diag([VAR_A, var_c]), np.zeros((2, 2)), np.array([[R]]),
                np.ones(2), fx, hx, consider=1)
        f.predict(0.01, np.zeros(1))
        f.update(np.array([z]), np.array([True]), np.zeros(1))
        return f.x[0] - a, f.P[0, 0]

    honest, naive = [], []
    for _ in range(2000):
        a, c = X0[0] + rng.normal(0, VAR_A ** 0.5), X0[1] + rng.normal(0, VAR_C ** 0.5)
        z = a + c + rng.normal(0, R ** 0.5)
        honest.append(run(VAR_C, a, c, z))
        naive.append(run(1e-12, a, c, z))
    for runs, ratio in ((honest, (0.9, 1.1)), (naive, (2.0, np.inf))):
        err, claimed = np.array(runs).T
        assert ratio[0] < np.mean(err ** 2) / np.mean(claimed) < ratio[1]
