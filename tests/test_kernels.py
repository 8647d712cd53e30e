"""The compiled UKF steps (core.kernels) give the numpy path's numbers (core.filters on the
models as written in core.lateral and core.longitudinal).

A change to a model's source that the compiled glue does not follow shows here first: the
single steps differ, then the drive's estimates.  The tolerances are floating-point noise
(below): ~1e-9 of a std per step, ~1e-9 of a whole drive's estimates.
"""

from __future__ import annotations

import numpy as np
import pytest

from vdp.core import kernels, lateral, longitudinal, output_error
from vdp.core.bounds import Bounds
from vdp.core.estimator import EstimatorConfig
from vdp.core.filters import UKF
from vdp.core.learner import LearnerConfig
from vdp.errors import FilterError
from vdp.pipeline import Pipeline
from vdp.profile import load_profile
from vdp.sim.run import simulate

# One step from the same state, in units of the state's std (x) and of the product of stds (P).
# The paper's alpha = 0.01 gives weights of ~3e4 of both signs, which cancel: a last-bit
# difference in a propagated sigma point (sin, exp, a sum's order) comes out at ~1e-9 of a std,
# (the points sit 0.017 std from the mean); the tolerance is ten times that.
STEP_TOL = 1e-8
MEAN_ROUNDING = 1e-10  # and the weighted mean rounds to ~3e4 x 2e-16 of the state's own size
DRIVE_RTOL = 1e-7


def _lat_pair(per_axle: bool, roll_by_ay: bool = False, bank: bool = False):
    """The numpy and the compiled UKF on stage 2's model; ``bank``: with the road's bank as a tenth
    state (lateral.BANK, as LearnerConfig.bank gives it)."""
    k = lateral.Known(
        m=1600.0,
        L=2.7,
        r=0.31,
        k_phi=9e4,
        c_phi=6e3,
        l_f=1.25,
        h=0.55,
        C_K=11.0,
        per_axle=per_axle,
        roll_by_ay=roll_by_ay,
    )
    b = Bounds(lateral.N_X, log=(lateral.C_F, lateral.C_R, lateral.I_Z, lateral.I_X))
    x0 = b.from_si(np.array([0.1, 0.15, 0.01, 0.02, 7e4, 6e4, 2500.0, 600.0, 1.25]))
    P0 = np.diag([0.3**2, 0.02**2, 0.01**2, 0.02**2, 0.3**2, 0.3**2, 0.2**2, 0.5**2, 1e-4])
    P0[4, 6] = P0[6, 4] = 0.01
    Q = np.diag([1e-5, 4e-4, 1e-8, 2.5e-5, 1e-8, 1e-8, 1e-8, 1e-8, 0.0])
    R = np.diag([3e-6, 3e-6, 5e-3])
    scale = np.where(b.transformed, 1.0, lateral.SCALE)
    if bank:
        b = Bounds(lateral.BANK + 1, log=(lateral.C_F, lateral.C_R, lateral.I_Z, lateral.I_X))
        x0, scale = np.append(x0, 0.2), np.append(scale, lateral.BANK_SCALE)
        P0 = np.pad(P0, ((0, 1), (0, 1)))
        P0[lateral.BANK, lateral.BANK] = 0.25
        Q = np.pad(Q, ((0, 1), (0, 1)))
        Q[lateral.BANK, lateral.BANK] = 0.0018
    fx = b.wrap_fx(lambda x, dt, u: lateral.fx(x, dt, u, k))
    hx = b.wrap_hx(lambda x, u: lateral.hx(x, u, k))
    ref = UKF(x0, P0, Q, R, scale, fx, hx, lateral.CONSIDER)
    fast = kernels.LateralUKF(x0, P0, Q, R, scale, fx, hx, b, k, lateral.CONSIDER)
    return ref, fast


def _lon_pair(n_x: int):
    k = longitudinal.Known(m=1600.0, L=2.7, r=0.31, J=1.2)
    b = Bounds(n_x, log=(longitudinal.H, longitudinal.C_K), logit={longitudinal.L_F: (0.0, 2.7)})
    x0 = b.from_si(np.array([1.3, 0.6, 9.0, 0.2, 0.1, 1e-3, -5e-4][:n_x]))
    P0 = np.diag([0.3, 0.2, 0.2, 0.5**2, 1.0, 4e-6, 4e-6][:n_x])
    Q = np.eye(n_x) * 1e-9
    R = np.array([[1e-3, 4e-4], [4e-4, 1e-3]])
    scale = np.where(b.transformed, 1.0, longitudinal.SCALE[:n_x])
    fx = b.wrap_fx(lambda x, dt, u: longitudinal.fx(x, dt, u, k))
    hx = b.wrap_hx(lambda x, u: longitudinal.hx(x, u, k))
    return UKF(x0, P0, Q, R, scale, fx, hx), kernels.LongitudinalUKF(x0, P0, Q, R, scale, fx, hx, b, k)


def _sync(ref, fast):
    """Start the compiled filter's next step from the numpy one's state: each step is compared
    on its own (over many steps the weights' amplification of rounding compounds, see the drive)."""
    fast._f.x, fast._f.P = ref._f.x.copy(), ref._f.P.copy()
    if ref._sigmas is not None:
        fast._sigmas = ref._sigmas.copy()


def _same(ref, fast):
    sd = np.sqrt(np.diagonal(ref._f.P))  # scaled coordinates, where the filter works
    tol = STEP_TOL * sd + MEAN_ROUNDING * np.abs(ref._f.x)
    assert np.all(np.abs(fast._f.x - ref._f.x) <= tol), (fast._f.x - ref._f.x) / tol
    assert np.all(np.abs(fast._f.P - ref._f.P) <= STEP_TOL * np.outer(sd, sd))
    _sync(ref, fast)


@pytest.mark.parametrize(
    ("per_axle", "roll_by_ay", "bank"),
    [(False, False, False), (True, False, False), (True, True, False), (True, True, True)],
)
def test_stage2_steps_are_the_numpy_steps(per_axle, roll_by_ay, bank):
    ref, fast = _lat_pair(per_axle, roll_by_ay, bank)
    assert len(fast.x) == (10 if bank else 9)  # the compiled steps size the state by its array
    rng = np.random.default_rng(3)
    for i in range(40):
        # inputs sampled over the step (steering ramp, speed, front wheel speed, a_x, a_y), as Stage2 passes them
        a_y = rng.normal(2.5, 0.3, 3)
        if i % 6 == 0:
            a_y[1] = np.nan  # an accelerometer sample missing: eq (9) takes the model's a_y there
        us = np.column_stack(
            [
                0.05 * np.sin(0.3 * i + np.arange(3) * 0.1),
                np.full(3, 18.0 + 0.1 * i),
                np.full(3, 18.0 / 0.31 * 1.002),
                rng.normal(0.0, 0.2, 3),
                a_y,
            ]
        )
        dt = 0.04 if i % 7 else 0.02  # one and several sub-steps
        _sync(ref, fast)
        ref.predict(dt, us)
        fast.predict(dt, us)
        _same(ref, fast)
        z = np.array([0.15 + 0.01 * rng.normal(), 0.01 * rng.normal(), 2.5 + 0.1 * rng.normal()])
        mask = np.array([True, i % 5 != 0, True])  # a row missing now and then
        ref.update(z, mask, us[-1])
        fast.update(z, mask, us[-1])
        _same(ref, fast)
        (y, S), (y2, S2) = ref.innovation(), fast.innovation()
        sd = np.sqrt(np.diagonal(S))
        assert np.all(np.abs(y2 - y) <= STEP_TOL * sd + MEAN_ROUNDING * np.abs(z[mask]))
        assert np.all(np.abs(S2 - S) <= STEP_TOL * np.outer(sd, sd))
    # the considered l_f never moves, on either path
    assert fast.x[lateral.L_F] == ref.x[lateral.L_F]


@pytest.mark.parametrize("roll_by_ay", [False, True])
def test_stage2_held_input_row(roll_by_ay):
    ref, fast = _lat_pair(False, roll_by_ay)
    u = np.array([0.03, 20.0, 20.0 / 0.31, 0.1, 1.2])
    ref.predict(0.04, u)
    fast.predict(0.04, u)
    _same(ref, fast)


@pytest.mark.parametrize("n_x", [3, longitudinal.N_X])
def test_stage1_steps_are_the_numpy_steps(n_x):
    ref, fast = _lon_pair(n_x)
    rng = np.random.default_rng(5)
    for i in range(40):
        u = np.array([400.0 * np.sin(0.2 * i), 150.0, rng.normal(0.5, 0.3), 15.0 + 0.2 * i, 0.05, 1.0, 1.1])
        _sync(ref, fast)
        ref.predict(0.1, u)
        fast.predict(0.1, u)
        _same(ref, fast)
        z = u[3] / 0.31 * (1.0 + rng.normal(0.0, 0.003, 2))
        ref.update(z, np.ones(2, dtype=bool), u)
        fast.update(z, np.ones(2, dtype=bool), u)
        _same(ref, fast)


@pytest.mark.parametrize("n_x", [3, longitudinal.N_X])
def test_stage1_batch_model_is_numpys_to_the_bit(n_x):
    """Stage 1's batch check evaluates longitudinal.hx on every kept block, compiled: the
    same operations elementwise, so the same floats."""
    k = longitudinal.Known(m=1600.0, L=2.7, r=0.31, J=1.2)
    rng = np.random.default_rng(9)
    U = np.column_stack(
        [
            rng.normal(0, 600, 3000),
            rng.normal(0, 400, 3000),
            rng.normal(0, 2, 3000),
            rng.uniform(3, 40, 3000),
            np.full(3000, 0.05),
            rng.normal(0, 3, 3000),
            rng.normal(0, 3, 3000),
        ]
    )
    x = np.array([1.3, 0.6, 9.0, 0.2, 0.1, 1e-3, -5e-4][:n_x])
    got = kernels.lon_hx_rows(x, U, kernels.lon_known(k))
    assert np.array_equal(got, longitudinal.hx(x, U, k))


@pytest.mark.parametrize("n_x", [3, longitudinal.N_X])
def test_stage1_batch_check_is_numpys(n_x):
    """Stage 1's batch least squares (core.batch.solve) compiled: the same iterations to the
    same optimum, covariance, cost and residual whiteness."""
    from vdp.core import batch

    k = longitudinal.Known(m=1600.0, L=2.7, r=0.31, J=1.2)
    b = Bounds(n_x, log=(longitudinal.H, longitudinal.C_K), logit={longitudinal.L_F: (0.0, 2.7)})
    rng = np.random.default_rng(11)
    N = 1500
    U = np.column_stack(
        [
            rng.normal(0, 500, N),
            rng.normal(0, 300, N),
            rng.normal(0, 1.5, N),
            rng.uniform(5, 35, N),
            np.full(N, 0.05),
            rng.normal(0, 2, N),
            rng.normal(0, 2, N),
        ]
    )
    truth = np.array([1.25, 0.55, 10.5, 0.3, 0.2, 1e-3, 8e-4][:n_x])
    Z = longitudinal.hx(truth, U, k) + rng.normal(0, 0.01, (N, 2))
    R = np.tile(np.array([[1e-4, 2e-5], [2e-5, 1e-4]]), (N, 1, 1))
    prior = np.array([1.4, 0.6, 9.0, 0.0, 0.0, 0.0, 0.0][:n_x])
    t0 = b.from_si(prior)
    P0 = np.diag([0.3, 0.3, 0.3, 0.25, 1.0, 4e-6, 4e-6][:n_x])
    starts = [t0, b.from_si(truth * 1.05)]
    ref = batch.solve(lambda t, u: longitudinal.hx(b.to_si(t), u, k), U, Z, R, t0, P0, starts)
    got = kernels.lon_solve(b, k, U, Z, R, t0, P0, starts)
    assert abs(b.to_si(ref.t)[0] - truth[0]) < 0.02  # the fit found the car (the test is not vacuous)
    # the sums run in another order, and the shape's parameters (b, c) are poorly conditioned,
    # which amplifies that into the iterates: compared in units of the fit's own std
    sd = np.sqrt(np.diagonal(ref.cov))
    assert np.all(np.abs(got.t - ref.t) <= 1e-6 * sd), (got.t - ref.t) / sd
    np.testing.assert_allclose(got.cov, ref.cov, rtol=1e-6, atol=1e-9 * np.abs(ref.cov).max())
    assert got.cost == pytest.approx(ref.cost, rel=1e-9) and got.dof == ref.dof
    assert got.rho == pytest.approx(ref.rho, rel=1e-6, abs=1e-12)


def test_a_broken_covariance_fails_as_the_numpy_step_does():
    ref, fast = _lat_pair(False)
    bad = -np.eye(lateral.N_X)
    for f in (ref, fast):
        f.set_state(f.x, bad)
    u = np.array([0.03, 20.0, 20.0 / 0.31, 0.1])
    msgs = []
    for f in (ref, fast):
        with pytest.raises(FilterError) as e:
            f.predict(0.04, u)
        msgs.append(str(e.value))
    assert msgs[0] == msgs[1] == "ukf predict: Matrix is not positive definite"


@pytest.fixture(scope="module")
def drive(repo_root):
    prof = load_profile(repo_root / "profiles" / "paper.toml")
    frames, _ = simulate(prof, "paper", seed=7, noise="realistic")
    return prof, list(frames)


def _estimates(prof, frames, compiled: bool, bank: bool = False):
    pipe = Pipeline(prof, EstimatorConfig(baseline=False, learner=LearnerConfig(compiled=compiled, bank=bank)))
    for m in frames:
        pipe.feed(m)
    l1, l2 = pipe.estimator.s1["ukf"], pipe.estimator.s2["ukf"]
    return pipe.result(), l1, l2


@pytest.mark.parametrize("bank", [False, True])
def test_a_drive_gives_the_same_estimates_compiled_or_not(drive, bank):
    """Also with stage 2's tenth state, the road's bank (LearnerConfig.bank; here without the road's
    tilt, so that the drive takes the block pass and core.kernels.lat_run steps ten states)."""
    prof, frames = drive
    ref, r1, r2 = _estimates(prof, frames, compiled=False, bank=bank)
    fast, f1, f2 = _estimates(prof, frames, compiled=True, bank=bank)
    assert type(f1.filter).__name__ == "LongitudinalUKF" and type(r1.filter).__name__ == "UKF"
    assert f2._n == r2._n == (10 if bank else 9)
    assert f2.updates > 1000 and f2.updates == r2.updates  # stage 2 ran, step for step
    assert f1.reseeds == r1.reseeds and f1.gated == r1.gated and len(f1._blocks) == len(r1._blocks)
    for name, e in ref.parameters.items():
        c = fast.parameters[name]
        assert (c.status, c.valid, c.samples, c.reason) == (e.status, e.valid, e.samples, e.reason), name
        assert c.value == pytest.approx(e.value, rel=DRIVE_RTOL), name
        assert c.std == pytest.approx(e.std, rel=DRIVE_RTOL), name


def test_stage1_keeps_its_blocks_oldest_first_and_the_newest_only():
    """Stage 1's ring of blocks for the batch check gives what a deque of the newest ``cap`` did."""
    from collections import deque

    from vdp.core.learner import _Blocks

    rng = np.random.default_rng(0)
    ring, ref = _Blocks(50), deque(maxlen=50)
    for _ in range(137):
        block = (rng.normal(size=7), rng.normal(size=2), rng.normal(size=(2, 2)))
        ring.append(*block)
        ref.append(block)
        for got, i in zip(ring.arrays(), range(3)):
            assert np.array_equal(got, np.array([b[i] for b in ref]))
    assert len(ring) == len(ref) == 50


def test_a_replay_says_when_it_compiles_the_steps_first_and_once(monkeypatch, capsys, caplog, tmp_path):
    """A fresh install's first replay compiles before it starts, and says so once, on stdout, with
    the one figure (core.jit.FIRST_COMPILE): a new user saw two messages with two figures."""
    from vdp.cli.replay import compile_note
    from vdp.core import jit, warm

    warm.warm()
    monkeypatch.chdir(tmp_path)  # a user replays from anywhere, not from the checkout
    assert jit.cached()  # warm() left them on disk: nothing to say
    compile_note()
    assert capsys.readouterr().out == ""
    done = []
    monkeypatch.setattr(jit, "cached", lambda: bool(done))  # a fresh checkout, until warm() has run
    monkeypatch.setattr(warm, "warm", lambda: done.append(1))
    with caplog.at_level("WARNING"):
        compile_note()
        warm.ensure()  # what the first compiled step calls: the cache is complete now, nothing more said
    out = capsys.readouterr().out
    assert out.count("compiling the estimator's steps once") == 1 and jit.FIRST_COMPILE in out
    assert done == [1] and not [r for r in caplog.records if "compiling" in r.getMessage()]


def _oe_record(seed: int = 3):
    """(known, t, U, Z, windows): three windows (one of a single row) of sine steering with a roll gyro,
    steps of 40-100 ms (the states' inputs only)."""
    rng = np.random.default_rng(seed)
    k = lateral.Known(m=1500.0, L=2.6, r=0.3, k_phi=6e4, c_phi=4e3, l_f=1.2, h=0.5, C_K=10.0, per_axle=True)
    # uneven steps (ten sub-steps each, of 4-10 ms, as the longest step needs) and a one-row window
    t = np.cumsum(rng.choice([0.04, 0.04, 0.04, 0.08, 0.1], 501))
    t[300:] += 30.0
    d = 0.05 * np.sin(0.6 * t) + 0.02 * np.sin(4.0 * t)
    v = 12.0 + 0.5 * np.sin(0.3 * t)
    U = np.stack([d, v, v / k.r, 0.2 * np.sin(0.5 * t)], axis=1)
    Z = np.stack([0.3 * d, 3.0 * d, 0.02 * np.sin(4.0 * t + 0.3)], axis=1)
    Z += rng.normal(0.0, 1.0, Z.shape) * [0.002, 0.05, 0.002]
    return k, t, U, Z, [(0, 300), (300, 301), (301, 501)]


@pytest.mark.parametrize("bent", [False, True])
def test_the_fits_states_compiled_equal_the_prefix_scan(bent):
    """core.kernels.oe_states gives Problem._scan(Problem._maps(...)): the same products, summed
    left to right instead of in a tree, so equal to rounding."""
    k, t, U, Z, windows = _oe_record()
    prob = output_error.Problem(t, U, Z, windows, k, (0.003, 0.08))
    rng = np.random.default_rng(1)
    theta = np.exp(np.log([7e4, 9e4, 2500.0]) + 0.2 * rng.normal(size=(4, 3)))
    swing = rng.normal(0.0, 0.3, 4)
    bend = [rng.uniform(0.7, 1.0, (4, prob.n)) for _ in range(2)] if bent else None
    ref = prob._states(theta, swing, bend)
    prob.compiled = True
    got = prob._states(theta, swing, bend)
    assert got.shape == ref.shape == (6, 4, prob.n)
    assert np.abs(ref[4]).max() > 1e-3  # the states move (the comparison is not of zeros)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-13 * np.abs(ref).max())
