"""Truth physics of the simulator: the source of ground truth for every other test."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import Phase, given, settings
from hypothesis import strategies as st

from vdp.profile import load_profile
from vdp.sim.run import trace
from vdp.sim.scenario import Plan
from vdp.sim.truth import TRUTH, truth_parameters
from vdp.sim.vehicle import PHI, VX, VY, WF, WR, WZ, Model, Params

ROOT = Path(__file__).resolve().parents[1]
VEH = load_profile(ROOT / "profiles" / "paper.toml").vehicle
P = Params.from_vehicle(VEH, truth_parameters())
MODEL = Model(P)
K_US = P.m / P.L * (P.l_r / P.C_alpha - P.l_f / P.C_alpha)  # rad per m/s^2 (negative: oversteer)


def test_params_take_known_constants_from_profile_and_unknowns_from_table6():
    assert (P.m, P.L, P.r, P.J, P.g) == (1600.0, 2.5, 0.3, 0.6, 9.8)
    assert P.k_phi == pytest.approx(36000.0 * 180.0 / math.pi)  # per degree -> per radian
    assert P.c_phi == pytest.approx(5737.0 * 180.0 / math.pi)
    assert (P.l_f, P.h, P.C_K, P.C_alpha, P.I_z, P.I_x) == tuple(TRUTH[k] for k in TRUTH)
    assert P.l_r == pytest.approx(1.1)
    q = Params.from_vehicle(VEH, truth_parameters({"l_f": 1.2, "I_z": 2500}))
    assert (q.l_f, q.I_z, q.h) == (1.2, 2500.0, 0.637)


def test_per_axle_cornering_stiffness_is_optional_and_c_alpha_is_their_mean():
    from vdp.errors import ConfigError
    from vdp.sim.truth import axle_parameters

    assert axle_parameters() == {"C_alpha_front": TRUTH["C_alpha"], "C_alpha_rear": TRUTH["C_alpha"]}
    axles = {"C_alpha_front": 58200.0, "C_alpha_rear": 75600.0}
    assert truth_parameters(axles)["C_alpha"] == pytest.approx(66900.0)
    assert axle_parameters(axles) == axles
    q = Params.from_vehicle(VEH, {**truth_parameters(axles), **axles})
    e = Model(q).evaluate([10.0, 0.1, 0.2, 0.0, 0.0, 10.0 / q.r, 10.0 / q.r], 0.0, 0.0, 0.03)
    assert e.F_yf == pytest.approx(58200.0 * e.alpha_f) and e.F_yr == pytest.approx(75600.0 * e.alpha_r)
    for bad, word in (({"C_alpha_front": 6e4}, "both"), ({**axles, "C_alpha": 6e4}, "not both")):
        with pytest.raises(ConfigError, match=word):
            truth_parameters(bad)


NO_SHRINK = (Phase.explicit, Phase.reuse, Phase.generate)  # each example simulates seconds


@settings(max_examples=8, deadline=None, phases=NO_SHRINK)
@given(v=st.floats(4.0, 14.0), deg=st.floats(0.3, 2.0), left=st.booleans())
def test_steady_cornering_matches_understeer_gradient(v, deg, left):
    delta = math.radians(deg) * (1 if left else -1)
    sc = Plan("circle", v).cruise(10.0, "hold", steer=lambda t: delta).build()
    tr = trace(sc, every=50)
    vx, r, ay, d = tr["v_x"][-1], tr["yaw_rate"][-1], tr["a_y"][-1], tr["delta"][-1]
    assert abs(tr["yaw_rate"][-1] - tr["yaw_rate"][-20]) < 1e-3 * abs(r)  # steady state reached
    assert abs(ay) < 4.0  # linear range
    R = vx / r
    assert ay == pytest.approx(vx * r, rel=1e-3)  # eq 5 at steady state: a_y = v_x r
    assert d == pytest.approx(P.L / R + K_US * ay, rel=3e-3)
    # Rear axle balance (eqs 11b, 12b): F_yr = m a_y l_f / L = C_alpha (l_r r - v_y) / v_x.
    vy_lin = P.l_r * r - P.m * ay * P.l_f * vx / (P.L * P.C_alpha)
    assert tr["v_y"][-1] == pytest.approx(vy_lin, rel=2e-3, abs=1e-4)


def test_static_axle_loads():
    e = MODEL.evaluate(MODEL.straight(15.0), 0.0, 0.0, 0.0)
    assert e.F_zf == pytest.approx(P.m * P.g * P.l_r / P.L)
    assert e.F_zr == pytest.approx(P.m * P.g * P.l_f / P.L)
    assert e.a_x == 0.0 and e.F_xf == 0.0 and e.F_xr == 0.0


state = st.tuples(
    st.floats(0.5, 35.0),  # v_x
    st.floats(-1.0, 1.0),  # v_y
    st.floats(-0.6, 0.6),  # yaw rate
    st.floats(0.9, 1.1),
    st.floats(0.9, 1.1),  # omega r / v_x per axle: slip ~ +-10 %
    st.floats(-0.15, 0.15),  # delta
)


@settings(max_examples=200, deadline=None)
@given(s=state)
def test_dynamic_axle_loads_solve_eq3_with_the_body_acceleration(s):
    vx, vy, r, kf, kr, delta = s
    x = [vx, vy, r, 0.0, 0.0, kf * vx / P.r, kr * vx / P.r]
    e = MODEL.evaluate(x, 100.0, 100.0, delta)
    # a_x is the body acceleration of eq 6 computed from the returned tyre forces ...
    ax = (e.F_xf * math.cos(delta) - e.F_yf * math.sin(delta) + e.F_xr) / P.m
    assert e.a_x == pytest.approx(ax, rel=1e-9, abs=1e-9)
    # ... and the loads are eq 3 at that same a_x (the loop is solved, not lagged).
    assert e.F_zf == pytest.approx(P.m * P.g * P.l_r / P.L - P.m * ax * P.h / P.L, rel=1e-9)
    assert e.F_zr == pytest.approx(P.m * P.g * P.l_f / P.L + P.m * ax * P.h / P.L, rel=1e-9)
    # Pitch moment balance about the CG, an independent check of eq 3.
    assert e.F_zf * P.l_f - e.F_zr * P.l_r + P.h * P.m * ax == pytest.approx(0.0, abs=1e-6 * P.m * P.g)
    # eq 14 with the friction limit; eq 7.
    assert abs(e.F_xf) <= e.F_zf * (1 + 1e-12) and abs(e.F_xr) <= e.F_zr * (1 + 1e-12)
    if abs(P.C_K * e.s_f) < 1.0:
        assert e.F_xf == pytest.approx(P.C_K * e.F_zf * e.s_f, rel=1e-12, abs=1e-9)
    assert e.a_y == pytest.approx((e.F_xf * math.sin(delta) + e.F_yf * math.cos(delta) + e.F_yr) / P.m)


def test_slip_angle_and_slip_ratio_conventions():
    # Steering left at zero yaw: positive front slip angle and a positive (leftward) F_yf.
    e = MODEL.evaluate([10.0, 0.0, 0.0, 0.0, 0.0, 10.0 / P.r, 10.0 / P.r], 0.0, 0.0, 0.02)
    assert e.alpha_f == pytest.approx(0.02) and e.F_yf == pytest.approx(P.C_alpha * 0.02)
    assert e.alpha_r == 0.0
    # Yawing left at zero v_y: front slips right (alpha_f < 0), rear slips left (alpha_r > 0).
    e = MODEL.evaluate([10.0, 0.0, 0.1, 0.0, 0.0, 10.0 / P.r, 10.0 / P.r], 0.0, 0.0, 0.0)
    assert e.alpha_f == pytest.approx(-P.l_f * 0.1 / 10.0) and e.alpha_r == pytest.approx(P.l_r * 0.1 / 10.0)
    # Slip ratio (eq 13) on the wheel-frame speed: the front wheel sees v_x cos d + (v_y + l_f r) sin d.
    d = 0.1
    vw = 10.0 * math.cos(d) + (0.3 + P.l_f * 0.2) * math.sin(d)
    e = MODEL.evaluate([10.0, 0.3, 0.2, 0.0, 0.0, 1.02 * vw / P.r, 10.0 / P.r], 0.0, 0.0, d)
    assert e.s_f == pytest.approx(0.02) and e.s_r == pytest.approx(0.0, abs=1e-12)


def test_yaw_moment_uses_corrected_eq10():
    x = [10.0, 0.0, 0.0, 0.0, 0.0, 1.01 * 10.0 / P.r, 10.0 / P.r]
    d = 0.05
    der = MODEL.derivatives(x, 0.0, 0.0, d)
    e = MODEL.evaluate(x, 0.0, 0.0, d)
    yaw = P.l_f * (e.F_xf * math.sin(d) + e.F_yf * math.cos(d)) - P.l_r * e.F_yr
    assert der[WZ] == pytest.approx(yaw / P.I_z)
    assert der[VY] == pytest.approx(e.a_y - x[VX] * x[WZ])  # eq 5 corrected
    assert der[VX] == pytest.approx(e.a_x + x[VY] * x[WZ])  # eq 4


def test_roll_equation_is_eq9_with_roll_angle():
    x = [10.0, 0.0, 0.2, 0.01, 0.02, 10.0 / P.r, 10.0 / P.r]
    der = MODEL.derivatives(x, 0.0, 0.0, 0.03)
    ay = MODEL.evaluate(x, 0.0, 0.0, 0.03).a_y
    assert der[PHI] == 0.02
    expect = (P.m * P.h * (ay + P.g * 0.01) - P.k_phi * 0.01 - P.c_phi * 0.02) / P.I_x
    assert der[PHI + 1] == pytest.approx(expect)


def test_step_agrees_with_derivatives_for_small_steps():
    x = [12.0, 0.1, 0.05, 0.002, 0.001, 12.2 / P.r, 12.1 / P.r]
    dt = 1e-6
    der = MODEL.derivatives(x, 300.0, 200.0, 0.02)
    x1 = MODEL.step(x, 300.0, 200.0, 0.02, dt)
    for i in range(5):  # the non-stiff states
        assert (x1[i] - x[i]) / dt == pytest.approx(der[i], rel=1e-3, abs=1e-6)


def test_a_steering_ramp_is_continuous_within_the_step():
    """The road-wheel angle goes linearly to the next step's (delta_end): a fast steering ramp
    at 1-ms steps lands where 20x finer steps do, while an angle held over each step (a
    staircase half a step behind its samples) is far off."""
    rate, v = 0.7, 10.0  # rad/s at the road wheel (the driver's rate limit), m/s

    def run(dt: float, ramp: bool) -> list[float]:
        x = MODEL.straight(v)
        for n in range(int(round(0.2 / dt))):
            d0, d1 = rate * n * dt, rate * (n + 1) * dt
            x = MODEL.step(x, 0.0, 0.0, d0, dt, d1 if ramp else None)
        return x

    ref = run(5e-5, True)
    err = {ramp: abs(run(1e-3, ramp)[WZ] - ref[WZ]) for ramp in (True, False)}
    assert err[True] < 0.02 * err[False]
    assert err[False] > 1e-4  # the staircase: 1.3e-3 rad/s off after 0.2 s, the ramp 1.2e-6


# -- stiffness --------------------------------------------------------------------------
def _torque(t: float) -> tuple[float, float]:
    if t < 0.5:
        return 300.0, 300.0
    if t < 1.0:
        return -300.0, -200.0
    return 150.0 * math.sin(2.0 * math.pi * t), 100.0


def _integrate(step, dt: float, T: float = 2.0, v0: float = 2.0) -> np.ndarray:
    x = MODEL.straight(v0)
    out = []
    every = int(round(0.01 / dt))
    for i in range(int(round(T / dt))):
        if i % every == 0:
            out.append(list(x))
        tf, tr = _torque(i * dt)
        x = step(x, tf, tr, 0.02 * math.sin(3.0 * i * dt), dt)
        if not all(math.isfinite(v) and abs(v) < 1e6 for v in x):
            out.append([math.inf] * len(x))
            break
    return np.array(out)


def _euler(model: Model):
    def step(x, tf, tr, d, dt):
        return [u + dt * v for u, v in zip(x, model.derivatives(x, tf, tr, d))]

    return step


def test_wheels_are_stable_and_accurate_beyond_their_time_constant():
    # At 2 m/s the wheel-slip time constant is well below the 1 ms step (NOTES 10).
    tau = P.J * 2.0 / (P.r**2 * P.C_K * MODEL.zf0)
    assert tau < 0.3e-3
    a = _integrate(MODEL.step, 1e-3)
    ref = _integrate(MODEL.step, 1e-4)
    assert a.shape == ref.shape and np.isfinite(a).all()
    assert np.abs(a[:, VX] - ref[:, VX]).max() < 2e-3
    assert np.abs(a[:, WF] - ref[:, WF]).max() < 5e-3
    assert np.abs(a[:, WR] - ref[:, WR]).max() < 5e-3
    assert np.abs(a[:, WZ] - ref[:, WZ]).max() < 1e-3
    # Quasi-static slip stays small although tau << dt.
    slip = np.abs(a[:, WF] * P.r / a[:, VX] - 1.0)
    assert slip.max() < 0.05
    # Even at the 10 ms logging rate the implicit wheel step stays stable and close.
    c = _integrate(MODEL.step, 1e-2)
    assert np.abs(c[:, WF] - ref[:, WF]).max() < 0.1


def test_naive_explicit_euler_at_logging_rate_diverges():
    ref = _integrate(MODEL.step, 1e-4)
    # Pure eq 14 (friction limit lifted): forward Euler at 10 ms runs away to infinity ...
    free = Model(dataclasses.replace(P, mu=1e9))
    assert not np.isfinite(_integrate(_euler(free), 1e-2)).all()
    assert np.isfinite(_integrate(free.step, 1e-2)).all()
    # ... and with the friction limit it rattles between +-mu F_z, omega off by tens of rad/s.
    b = _integrate(_euler(MODEL), 1e-2)
    assert np.abs(b[:, WF] - ref[:, WF]).max() > 20.0


@settings(max_examples=30, deadline=None, phases=NO_SHRINK)
@given(
    v0=st.floats(0.0, 30.0),
    wf=st.floats(0.0, 120.0),
    wr=st.floats(0.0, 120.0),
    tf=st.floats(-3000, 3000),
    tr=st.floats(-3000, 3000),
    d=st.floats(-0.3, 0.3),
)
def test_step_never_blows_up(v0, wf, wr, tf, tr, d):
    x = [v0, 0.0, 0.0, 0.0, 0.0, wf, wr]
    for _ in range(300):
        x = MODEL.step(x, tf, tr, d, 1e-3)
        assert all(math.isfinite(v) for v in x)
        assert x[VX] >= 0.0 and x[WF] >= 0.0 and x[WR] >= 0.0
    assert abs(x[VY]) < 40.0 and abs(x[WZ]) < 10.0


# -- scenarios through the physics ------------------------------------------------------
@pytest.mark.slow
def test_slip_small_and_bounded_in_paper_scenario():
    tr = trace("paper", every=5)
    assert np.isfinite(np.column_stack(list(tr.values()))).all()
    moving = tr["v_x"] > 5.0
    assert moving.mean() > 0.99
    for k in ("s_f", "s_r"):
        assert np.abs(tr[k]).max() < 0.12  # below the friction limit 1 / C_K = 0.1 ... with margin
    assert np.abs(P.C_K * tr["s_f"]).max() < 1.0 and np.abs(P.C_K * tr["s_r"]).max() < 1.0
    assert np.abs(tr["alpha_f"]).max() < 0.06 and np.abs(tr["alpha_r"]).max() < 0.06
    # Stage 1 excites a_x both ways; stage 2 excites a_y both ways.
    s1 = (tr["t"] > 2) & (tr["t"] < 52)
    assert tr["a_x"][s1].max() > 4.0 and tr["a_x"][s1].min() < -4.0
    assert np.abs(tr["yaw_rate"][s1]).max() < 1e-12
    s2 = tr["t"] > 62
    assert tr["a_y"][s2].max() > 3.0 and tr["a_y"][s2].min() < -2.0


def test_axle_loads_follow_measured_acceleration_in_stage1():
    tr = trace("stage1", every=1, duration=15.0)
    dt = tr["t"][1] - tr["t"][0]
    ax = np.gradient(tr["v_x"], dt)  # straight line: dv_x/dt = a_x (eq 4 with v_y = 0)
    sl = slice(100, -100)
    fzf = P.m * P.g * P.l_r / P.L - P.m * ax * P.h / P.L
    assert np.abs(tr["F_zf"][sl] - fzf[sl]).max() < 0.01 * P.m * P.g * P.h / P.L
    assert np.allclose(tr["F_zf"] + tr["F_zr"], P.m * P.g)
    assert tr["F_zf"].min() < 0.8 * P.m * P.g * P.l_r / P.L  # the test saw real load transfer


def test_standstill_hold_no_rollback_no_chatter():
    sc = Plan("stop", 5.0).ramp(0.0, 3.0, "brake").hold(3.0).ramp(3.0, 3.0, "go").build()
    tr = trace(sc, every=1)
    t, vx = tr["t"], tr["v_x"]
    assert vx.min() >= 0.0 and tr["omega_f"].min() >= 0.0 and tr["omega_r"].min() >= 0.0
    held = (t > 3.3) & (t < 6.0)
    assert (vx[held] == 0.0).all() and (tr["omega_f"][held] == 0.0).all()
    assert (tr["a_x"][held] == 0.0).all() and (tr["yaw_rate"][held] == 0.0).all()
    stopped = np.flatnonzero(vx == 0.0)
    assert stopped.size and np.all(np.diff(stopped[stopped < np.searchsorted(t, 6.0)]) == 1)  # one stop
    assert vx[-1] == pytest.approx(3.0, abs=0.1)  # and it drives off again
