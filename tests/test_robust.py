"""The estimator against priors that are off, and its bounded parameters.

Tolerances here are looser than benchmarks/robust.py's figures (BENCHMARKS.md):
short seeded drives, asserting the behaviour, not the Monte Carlo numbers.
"""

import dataclasses

import numpy as np
import pytest

from vdp.core import batch, lateral, longitudinal
from vdp.core.bounds import Bounds
from vdp.pipeline import Pipeline
from vdp.profile import Prior, load_profile
from vdp.sim.run import simulate
from vdp.sim.truth import TRUTH


@pytest.fixture(scope="module")
def profile(repo_root):
    return load_profile(repo_root / "profiles" / "paper.toml")


def scaled(profile, scale):
    return dataclasses.replace(profile, priors={k: Prior(p.value * scale, p.std) for k, p in profile.priors.items()})


# -- bounds -------------------------------------------------------------------------------
def test_bounds_map_any_filter_value_inside_and_back():
    b = Bounds(3, log=(1, 2), logit={0: (0.0, 2.5)})
    t = np.array([[-40.0, -30.0, 30.0], [0.3, 0.1, 2.0], [40.0, 5.0, -5.0]])
    x = b.to_si(t)
    assert np.all((x[:, 0] > 0.0) & (x[:, 0] < 2.5)) and np.all(x[:, 1:] > 0.0)
    mid = np.array([1.4, 0.637, 10.0])
    np.testing.assert_allclose(b.to_si(b.from_si(mid)), mid, rtol=1e-12)
    # the slope is dx/dt
    t = b.from_si(mid)
    e = 1e-7
    fd = (b.to_si(t + e) - b.to_si(t - e)) / (2 * e)
    np.testing.assert_allclose(b.grad(t), fd, rtol=1e-6)


def test_wrapped_jacobians_match_finite_differences():
    k = longitudinal.Known(m=1600.0, L=2.5, r=0.3, J=0.6)
    b = Bounds(3, log=(1, 2), logit={0: (0.0, 2.5)})
    t = b.from_si(np.array([1.3, 0.6, 9.0]))
    u = np.array([800.0, 300.0, 1.5, 15.0, 0.05, 2.0, 1.0])
    H = b.wrap_jac_h(lambda x, uu: longitudinal.jac_h(x, uu, k))(t, u)
    h = b.wrap_hx(lambda x, uu: longitudinal.hx(x, uu, k))
    fd = np.stack([(h(t + e, u) - h(t - e, u)) / 2e-6 for e in np.eye(3) * 1e-6], axis=1)
    np.testing.assert_allclose(H, fd, rtol=1e-5, atol=1e-9)

    kl = lateral.Known(m=1600.0, L=2.5, r=0.3, k_phi=2.06e6, c_phi=3.3e5, l_f=1.4, h=0.637, C_K=10.0)
    bl = Bounds(lateral.N_X, log=(lateral.C_A, lateral.I_Z, lateral.I_X))
    x = np.array([0.1, 0.2, 0.01, 0.02, 6.0e4, 2.1e3, 900.0, 1.4])
    tl = bl.from_si(x)
    ul = np.array([0.03, 12.0, 40.0, 0.1])
    A = bl.wrap_jac_f(lambda xx, uu: lateral.jac_f(xx, uu, kl))(tl, ul)

    def f(tt):  # continuous dynamics in transformed coordinates: D^-1 f(x)
        return lateral.deriv(bl.to_si(tt), ul, kl) / bl.grad(tt)

    eps = 1e-6 * np.maximum(np.abs(tl), 1.0)
    fd = np.stack([(f(tl + e) - f(tl - e)) / (2 * e[i]) for i, e in enumerate(np.diag(eps))], axis=1)
    np.testing.assert_allclose(A, fd, rtol=1e-4, atol=1e-6)


# -- batch optimum ------------------------------------------------------------------------
def test_batch_solution_finds_the_truth_from_a_far_start_and_linear_start_needs_none():
    k = longitudinal.Known(m=1600.0, L=2.5, r=0.3, J=0.6)
    rng = np.random.default_rng(3)
    n = 400
    a_x = 3.0 * np.sin(np.linspace(0, 12, n))
    truth = np.array([1.4, 0.637, 10.0])
    f_zf, f_zr = longitudinal.axle_loads(truth[0], truth[1], a_x, k)
    share = 0.6  # front share of the drive force
    f = k.m * a_x
    U = np.zeros((n, longitudinal.N_U))
    U[:, longitudinal.U_TF] = share * f * k.r
    U[:, longitudinal.U_TR] = (1 - share) * f * k.r
    U[:, longitudinal.U_AX] = a_x
    U[:, longitudinal.U_VX] = 20.0
    Z = longitudinal.hx(truth, U, k) + rng.normal(0, 0.01, (n, 2))
    R = np.broadcast_to(np.eye(2) * 0.01**2, (n, 2, 2)).copy()
    b = Bounds(3, log=(1, 2), logit={0: (0.0, 2.5)})
    prior = b.from_si(np.array([2.0, 0.9, 12.8]))  # the paper's priors x1.6
    P0 = np.diag([1.0, 1.0, 1.0])
    lin = batch.linear_start(U, Z, k)
    assert lin is not None and np.allclose(lin, truth, rtol=0.05)
    fit = batch.solve(lambda t, u: longitudinal.hx(b.to_si(t), u, k), U, Z, R, prior, P0, [prior])
    np.testing.assert_allclose(b.to_si(fit.t), truth, rtol=0.01)
    assert 0.7 < fit.chi2 < 1.3  # the noise is what R says


# -- whole drives with priors off -----------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("scale", [0.6, 1.6])
def test_stage1_stays_physical_and_reaches_the_truth_with_priors_off(profile, scale):
    prof = scaled(profile, scale)
    frames, truth = simulate(prof, "stage1", seed=3, noise="realistic")
    pipe = Pipeline(prof)
    L = prof.vehicle.wheelbase
    for msg in frames:
        pipe.feed(msg)
    for row in pipe.estimator.trace:
        for kind_values in row[2:]:
            (l_f, _), (h, _), (c_k, _) = kind_values[:3]
            assert 0.0 < l_f < L and h > 0.0 and c_k > 0.0
    snap = pipe.result().to_dict()
    for key in ("parameters", "baseline_ekf"):
        for name, tol in (("l_f", 0.01), ("h", 0.03), ("C_K", 0.02)):
            e = snap[key][name]
            assert abs(e["value"] - TRUTH[name]) <= tol * TRUTH[name], (key, name, e)
            if e["valid"]:
                assert abs(e["value"] - TRUTH[name]) <= 3 * e["std"], (key, name, e)
