"""Pure unit tests of the stage models: analytic Jacobians against finite differences."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vdp.core import lateral, longitudinal

K1 = longitudinal.Known(m=1600.0, L=2.5, r=0.3, J=0.6, g=9.8)
K2 = lateral.Known(
    m=1600.0, L=2.5, r=0.3, k_phi=36000 * 180 / math.pi, c_phi=5737 * 180 / math.pi, l_f=1.4, h=0.637, C_K=10.0
)


def numjac(f, x, eps):
    x = np.asarray(x, dtype=float)
    f0 = f(x)
    J = np.zeros((len(f0), len(x)))
    for i in range(len(x)):
        d = np.zeros_like(x)
        d[i] = eps[i]
        J[:, i] = (f(x + d) - f(x - d)) / (2 * eps[i])
    return J


@settings(max_examples=60, deadline=None)
@given(
    v=st.floats(6, 35),
    l_f=st.floats(0.9, 1.7),
    h=st.floats(0.3, 0.9),
    c_k=st.floats(4, 20),
    tf=st.floats(-2000, 2000),
    tr=st.floats(-2000, 2000),
    ax=st.floats(-6, 6),
)
def test_stage1_measurement_jacobian(v, l_f, h, c_k, tf, tr, ax):
    x = np.array([l_f, h, c_k])
    u = np.array([tf, tr, ax, v, 0.01, ax / 0.3, ax / 0.31])
    H = longitudinal.jac_h(x, u, K1)
    N = numjac(lambda xx: longitudinal.hx(xx, u, K1), x, eps=1e-6 * np.maximum(np.abs(x), 1))
    np.testing.assert_allclose(H, N, rtol=1e-5, atol=1e-7)


@settings(max_examples=60, deadline=None)
@given(
    v=st.floats(6, 35),
    l_f=st.floats(0.9, 1.7),
    h=st.floats(0.3, 0.9),
    c_k=st.floats(4, 20),
    b=st.floats(-0.3, 1.0),
    c=st.floats(-0.3, 1.0),
    s0f=st.floats(-0.005, 0.005),
    s0r=st.floats(-0.005, 0.005),
    tf=st.floats(-2000, 2000),
    tr=st.floats(-2000, 2000),
    ax=st.floats(-6, 6),
)
def test_stage1_measurement_jacobian_with_the_tyre_shape(v, l_f, h, c_k, b, c, s0f, s0r, tf, tr, ax):
    x = np.array([l_f, h, c_k, b, c, s0f, s0r])
    u = np.array([tf, tr, ax, v, 0.01, ax / 0.3, ax / 0.31])
    H = longitudinal.jac_h(x, u, K1)
    assert H.shape == (2, longitudinal.N_X)
    N = numjac(lambda xx: longitudinal.hx(xx, u, K1), x, eps=1e-6 * np.maximum(np.abs(x), [1, 1, 1, 1, 1, 1e-3, 1e-3]))
    np.testing.assert_allclose(H, N, rtol=1e-5, atol=1e-7)


def test_stage1_tyre_law_starts_at_c_k_and_follows_a_brush_tyre():
    """The bend's initial slope is C_K whatever b and c are, and with b = 1 / (3 mu), c = 5 / (27 mu^2)
    it follows the brush tyre's inverse law, s = (3 mu / C_K)(1 - (1 - u / mu)^(1/3)), to half the
    friction limit."""
    mu, c_k = 1.0, 15.0
    b, c = 1.0 / (3.0 * mu), 5.0 / (27.0 * mu * mu)
    u = np.linspace(-0.5, 0.5, 41)
    s = u / c_k * longitudinal.bend(u, b, c)
    brush = np.sign(u) * 3.0 * mu / c_k * (1.0 - (1.0 - np.abs(u) / mu) ** (1.0 / 3.0))
    np.testing.assert_allclose(s, brush, rtol=0.025, atol=1e-12)  # 2.0 % short at u = 0.5
    small = 1e-6
    assert small / c_k * longitudinal.bend(small, 0.8, 0.6) == pytest.approx(small / c_k, rel=1e-5)
    # the paper's linear law is b = 0, and the three-parameter state means exactly that
    x3 = np.array([1.4, 0.637, 10.0])
    x6 = np.array([1.4, 0.637, 10.0, 0.0, 0.0, 0.0, 0.0])
    uu = np.array([900.0, 400.0, 1.2, 18.0, 0.01, 4.0, 4.0])
    np.testing.assert_allclose(longitudinal.hx(x3, uu, K1), longitudinal.hx(x6, uu, K1))


@settings(max_examples=60, deadline=None)
@given(
    vy=st.floats(-1, 1),
    yaw=st.floats(-0.6, 0.6),
    phi=st.floats(-0.02, 0.02),
    phid=st.floats(-0.1, 0.1),
    ca=st.floats(2e4, 2e5),
    split=st.floats(0.6, 1.6),
    iz=st.floats(800, 5000),
    ix=st.floats(800, 8000),
    l_f=st.floats(0.9, 1.6),
    d=st.floats(-0.15, 0.15),
    vx=st.floats(5, 30),
    wf_slip=st.floats(-0.05, 0.05),
    ax=st.floats(-3, 3),
)
def test_stage2_jacobians(vy, yaw, phi, phid, ca, split, iz, ix, l_f, d, vx, wf_slip, ax):
    x = np.array([vy, yaw, phi, phid, ca, ca / split, iz, ix, l_f])  # front and rear stiffness differ
    u = np.array([d, vx, vx * (1 + wf_slip) / K2.r, ax])
    eps = 1e-6 * np.maximum(np.abs(x), lateral.SCALE * 1e-2)
    A = lateral.jac_f(x, u, K2)
    NA = numjac(lambda xx: lateral.deriv(xx, u, K2), x, eps)
    np.testing.assert_allclose(A, NA, rtol=1e-4, atol=1e-6 * np.abs(NA).max())
    H = lateral.jac_h(x, u, K2)
    NH = numjac(lambda xx: lateral.hx(xx, u, K2), x, eps)
    # per column, the central difference's own rounding: a few ulps of the outputs over the step
    # (hypothesis found a 0 read as 2.2e-7 through a yaw-rate step of 1e-8)
    atol = 1e-8 + 8.0 * np.finfo(float).eps * np.abs(lateral.hx(x, u, K2)).max() / eps
    bad = ~np.isclose(H, NH, rtol=1e-4, atol=atol)  # (atol per column: assert_allclose takes one number)
    assert not bad.any(), (np.argwhere(bad), H[bad], NH[bad])
    # one stiffness for both axles: C_alpha_f's column takes the rear's part, C_alpha_r is inert
    tied = dataclasses.replace(K2, per_axle=False)
    A = lateral.jac_f(x, u, tied)
    np.testing.assert_allclose(
        A, numjac(lambda xx: lateral.deriv(xx, u, tied), x, eps), rtol=1e-4, atol=1e-6 * np.abs(NA).max()
    )
    H = lateral.jac_h(x, u, tied)
    np.testing.assert_allclose(H, numjac(lambda xx: lateral.hx(xx, u, tied), x, eps), rtol=1e-4, atol=1e-8)
    assert not A[:, lateral.C_R].any() and not H[:, lateral.C_R].any()
    # eq (9) driven by the measured a_y (a fifth input column): the roll-rate row no longer
    # depends on the lateral states and the stiffnesses, only on the roll states and I_x
    by_ay = dataclasses.replace(K2, roll_by_ay=True)
    u5 = np.append(u, 2.0 * d * vx)
    A = lateral.jac_f(x, u5, by_ay)
    NA = numjac(lambda xx: lateral.deriv(xx, u5, by_ay), x, eps)
    np.testing.assert_allclose(A, NA, rtol=1e-4, atol=1e-6 * np.abs(NA).max())
    assert not A[lateral.PHI_D, [lateral.V_Y, lateral.YAW, lateral.C_F, lateral.C_R, lateral.I_Z, lateral.L_F]].any()
    np.testing.assert_allclose(lateral.jac_h(x, u5, by_ay), lateral.jac_h(x, u, K2))


@settings(max_examples=40, deadline=None)
@given(
    vy=st.floats(-1, 1),
    yaw=st.floats(-0.6, 0.6),
    phid=st.floats(-0.1, 0.1),
    ca=st.floats(2e4, 2e5),
    split=st.floats(0.6, 1.6),
    iz=st.floats(800, 5000),
    l_f=st.floats(0.9, 1.6),
    d=st.floats(-0.15, 0.15),
    vx=st.floats(5, 30),
    bank=st.floats(-0.6, 0.6),
    by_ay=st.booleans(),
)
def test_stage2_jacobians_with_the_road_bank_as_a_tenth_state(vy, yaw, phid, ca, split, iz, l_f, d, vx, bank, by_ay):
    """The bank (lateral.BANK, g sin(bank)) pulls v_y down the road, eq (5), and nothing else; the other
    nine states' rows and columns are the nine-state model's, and so are its measurements."""
    k = dataclasses.replace(K2, roll_by_ay=by_ay)
    x9 = np.array([vy, yaw, 0.01, phid, ca, ca / split, iz, 1500.0, l_f])
    x = np.append(x9, bank)
    u = np.array([d, vx, vx * 1.01 / k.r, 0.5, 2.0 * d * vx])
    # central differences of steps a millionth of each state's scale: rounding stays below 1e-8
    eps = 1e-6 * np.maximum(np.abs(x), np.append(lateral.SCALE, lateral.BANK_SCALE))
    A = lateral.jac_f(x, u, k)
    NA = numjac(lambda xx: lateral.deriv(xx, u, k), x, eps)
    np.testing.assert_allclose(A, NA, rtol=1e-4, atol=1e-6 * np.abs(NA).max())
    H = lateral.jac_h(x, u, k)
    np.testing.assert_allclose(H, numjac(lambda xx: lateral.hx(xx, u, k), x, eps), rtol=1e-4, atol=1e-8)
    assert A[lateral.V_Y, lateral.BANK] == -1.0 and not np.delete(A[:, lateral.BANK], lateral.V_Y).any()
    assert not A[lateral.BANK].any() and not H[:, lateral.BANK].any()
    np.testing.assert_array_equal(A[:9, :9], lateral.jac_f(x9, u, k))
    np.testing.assert_array_equal(H[:, :9], lateral.jac_h(x9, u, k))
    # the derivative and the step: v_y alone moves with the bank; a bank of 0 is the nine-state model's, to the bit
    f, f9 = lateral.deriv(x, u, k), lateral.deriv(x9, u, k)
    assert f[lateral.V_Y] == pytest.approx(f9[lateral.V_Y] - bank) and f[lateral.BANK] == 0.0
    np.testing.assert_array_equal(np.delete(f[:9], lateral.V_Y), np.delete(f9, lateral.V_Y))
    x0 = np.append(x9, 0.0)
    np.testing.assert_array_equal(lateral.fx(x0, 0.04, u, k)[:9], lateral.fx(x9, 0.04, u, k))
    step = lateral.fx(x, 0.04, u, k)
    assert step[lateral.BANK] == bank
    dv = step[lateral.V_Y] - lateral.fx(x0, 0.04, u, k)[lateral.V_Y]  # down the bank, less what the tyres push back
    # (plus the step's own rounding: hypothesis found a bank of 1e-15 moving v_y by 4.2e-17)
    assert dv * bank <= 0.0 and abs(dv) <= 0.04 * abs(bank) * (1.0 + 1e-9) + 1e-15


def test_roll_driven_by_measured_ay():
    """Known.roll_by_ay: eq (9) takes the input's a_y where finite, the model's elsewhere (and
    without the flag); the step agrees with a fine RK4 reference driven the same way."""
    by_ay = dataclasses.replace(K2, roll_by_ay=True)
    x = np.array([0.2, 0.3, 0.002, 0.01, 6.69e4, 5.5e4, 2000.0, 4175.0, 1.4])
    u = np.array([0.06, 10.0, 10.0 / 0.3, 0.0, 1.7])
    model_ay = lateral.hx(x, u, K2)[lateral.Z_AY]
    assert abs(model_ay - 1.7) > 0.5  # the two differ here
    d_meas, d_model = lateral.deriv(x, u, by_ay), lateral.deriv(x, u, K2)
    k = K2
    expect = (k.m * k.h * (1.7 + k.g * x[lateral.PHI]) - k.k_phi * x[lateral.PHI] - k.c_phi * x[lateral.PHI_D]) / x[
        lateral.I_X
    ]
    assert d_meas[lateral.PHI_D] == pytest.approx(expect)
    np.testing.assert_allclose(d_meas[:3], d_model[:3])
    no_ay = u.copy()
    no_ay[lateral.U_AY] = np.nan
    np.testing.assert_allclose(lateral.deriv(x, no_ay, by_ay), d_model)
    np.testing.assert_allclose(lateral.fx(x, 0.02, no_ay, by_ay), lateral.fx(x, 0.02, u, K2))
    np.testing.assert_allclose(lateral.fx(x, 0.02, u[:4], by_ay), lateral.fx(x, 0.02, u, K2))
    dt, n = 0.02, 400
    coarse = lateral.fx(x, dt, u, by_ay)
    ref, h = x.copy(), dt / n
    for _ in range(n):
        k1 = lateral.deriv(ref, u, by_ay)
        k2 = lateral.deriv(ref + h / 2 * k1, u, by_ay)
        k3 = lateral.deriv(ref + h / 2 * k2, u, by_ay)
        k4 = lateral.deriv(ref + h * k3, u, by_ay)
        ref = ref + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose(coarse[:2], ref[:2], rtol=2e-3)
    np.testing.assert_allclose(coarse[2:4], ref[2:4], atol=2e-4)
    assert abs(coarse[3] - lateral.fx(x, dt, u, K2)[3]) > 1e-3  # and it is not the model-driven step
    # sigma points: each row as on its own
    X = np.tile(x, (5, 1))
    X[:, lateral.C_F] *= np.linspace(0.8, 1.2, 5)
    U = np.array([u, u + [0.002, 0.0, 0.0, 0.0, 0.1]])
    out = lateral.fx(X, dt, U, by_ay)
    for i in (0, 4):
        np.testing.assert_allclose(out[i], lateral.fx(X[i], dt, U, by_ay))


def test_models_broadcast_over_sigma_points():
    x1 = np.array([1.4, 0.6, 10.0])
    u1 = np.array([500.0, 300.0, 1.0, 20.0, 0.01, 3.3, 3.3])
    X = np.tile(x1, (7, 1))
    X[:, 0] += np.linspace(-0.1, 0.1, 7)
    batch = longitudinal.hx(X, u1, K1)
    for i in range(7):
        np.testing.assert_allclose(batch[i], longitudinal.hx(X[i], u1, K1))
    x2 = np.array([0.1, 0.2, 0.001, 0.0, 6.69e4, 5.5e4, 2000, 4175, 1.4])
    u2 = np.array([0.05, 10.0, 10.0 / 0.3, 0.0])
    X2 = np.tile(x2, (15, 1))
    X2[:, lateral.C_F] *= np.linspace(0.8, 1.2, 15)
    X2[:, lateral.C_R] *= np.linspace(1.2, 0.8, 15)
    X2[:, lateral.L_F] += np.linspace(-0.05, 0.05, 15)
    out = lateral.fx(X2, 0.01, u2, K2)
    for i in (0, 7, 14):
        np.testing.assert_allclose(out[i], lateral.fx(X2[i], 0.01, u2, K2))


def test_stage2_discrete_step_matches_fine_integration():
    """The sub-stepped transition agrees with a fine RK4 reference of deriv() over one filter step."""
    x = np.array([0.2, 0.3, 0.002, 0.01, 6.69e4, 6.69e4, 2000.0, 4175.0, 1.4])
    u = np.array([0.06, 10.0, 10.0 / 0.3, 0.0])
    dt = 0.02  # stage 2 steps every second 10 ms sample
    coarse = lateral.fx(x, dt, u, K2)
    ref = x.copy()
    n = 400
    h = dt / n
    for _ in range(n):
        k1 = lateral.deriv(ref, u, K2)
        k2 = lateral.deriv(ref + h / 2 * k1, u, K2)
        k3 = lateral.deriv(ref + h / 2 * k2, u, K2)
        k4 = lateral.deriv(ref + h * k3, u, K2)
        ref = ref + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    # v_y and yaw rate to 0.2 %; the roll rate of this hard transient (roll far from its
    # equilibrium) to 2e-4 rad/s, a tenth of the gyro noise
    np.testing.assert_allclose(coarse[:2], ref[:2], rtol=2e-3)
    np.testing.assert_allclose(coarse[2:4], ref[2:4], atol=2e-4)
    # and halving the sub-step brings it closer (second order)
    fine = lateral.fx(x, dt, u, K2, substeps=8)
    assert abs(fine[3] - ref[3]) < 0.5 * abs(coarse[3] - ref[3])


def test_roll_step_stays_stable_for_small_inertia():
    """Trapezoidal roll integration: no blow-up even when c_phi/I_x * dt >> 2."""
    x = np.array([0.0, 0.0, 0.01, 0.5, 6.69e4, 6.69e4, 2000.0, 60.0, 1.4])
    u = np.array([0.0, 10.0, 10.0 / 0.3, 0.0])
    for _ in range(200):
        x = lateral.fx(x, 0.01, u, K2)
    assert abs(x[lateral.PHI]) < 0.01 and abs(x[lateral.PHI_D]) < 0.5


@pytest.mark.parametrize("k_phi, c_phi", [(90000.0, 6000.0), (36000 * 180 / math.pi, 5737 * 180 / math.pi)])
def test_quasi_static_roll_balances_eq9(k_phi, c_phi):
    """The roll angle a stage-2 window starts from leaves no roll acceleration (eq 9)."""
    k = lateral.Known(m=1656.0, L=2.66, r=0.35, k_phi=k_phi, c_phi=c_phi, l_f=1.2, h=0.62, C_K=10.0)
    x = np.array([-0.19, -0.28, 0.0, 0.004, 9.5e4, 9.5e4, 2900.0, 650.0, 1.2])
    u = np.array([-0.079, 10.0, 10.0 / 0.35, 0.0])
    a_y = lateral.hx(x, u, k)[lateral.Z_AY]
    x[lateral.PHI] = lateral.quasi_static_roll(a_y, x[lateral.PHI_D], k)
    assert abs(lateral.deriv(x, u, k)[lateral.PHI_D]) < 1e-9
    if k_phi == 90000.0:  # a production car's roll stiffness: degrees, not the paper's hundredths
        assert math.degrees(abs(x[lateral.PHI])) > 1.0
    assert (
        lateral.quasi_static_roll(
            3.0, 0.0, lateral.Known(m=1656.0, L=2.66, r=0.35, k_phi=5000.0, c_phi=c_phi, l_f=1.2, h=0.62, C_K=10.0)
        )
        == 0.0
    )


def test_stage1_slip_sign_follows_torque():
    x = np.array([1.4, 0.637, 10.0])
    w = longitudinal.hx(x, np.array([800.0, 800.0, 1.0, 20.0, 0.01, 3.3, 3.3]), K1)
    assert w[0] > 20 / 0.3 and w[1] > 20 / 0.3  # driving: wheels faster than the car
    w = longitudinal.hx(x, np.array([-800.0, -500.0, -1.0, 20.0, 0.01, -3.3, -3.3]), K1)
    assert w[0] < 20 / 0.3 and w[1] < 20 / 0.3


def test_ekf_transition_matches_matrix_exponential():
    from scipy.linalg import expm

    from vdp.core.filters import transition

    x = np.array([0.1, 0.3, 0.002, 0.01, 6.69e4, 5.0e4, 2000.0, 4175.0, 1.4])
    u = np.array([0.05, 10.0, 10.0 / 0.3, 0.0])
    A = lateral.jac_f(x, u, K2)
    np.testing.assert_allclose(transition(A, 0.01), expm(A * 0.01), rtol=1e-3, atol=1e-6)
