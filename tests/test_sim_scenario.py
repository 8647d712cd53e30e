"""Scenarios (segment metadata, command shapes) and the driver (tracking, split, actuators)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vdp.errors import ConfigError
from vdp.sim.driver import Driver, DriverConfig
from vdp.sim.run import trace
from vdp.sim.scenario import KINDS, SCENARIOS, Plan, get_scenario, sawtooth_steer

DEG = math.pi / 180.0


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_segments_tile_the_scenario(name):
    sc = get_scenario(name)
    meta = sc.meta()
    assert meta[0]["start"] == 0.0 and meta[-1]["end"] == pytest.approx(sc.duration)
    for a, b in zip(meta, meta[1:]):
        assert a["end"] == b["start"]
    for m in meta:
        assert set(m) == {"name", "kind", "start", "end"} and m["kind"] in KINDS and m["end"] > m["start"]


def test_paper_scenario_layout():
    meta = {m["name"]: m for m in get_scenario("paper").meta()}
    assert (meta["stage1"]["start"], meta["stage1"]["end"]) == (2.0, 52.0)  # 4 cycles of 12.5 s
    assert meta["transition"]["kind"] == "transition"
    assert meta["transition"]["end"] - meta["transition"]["start"] == pytest.approx(8.0)
    assert meta["stage2"]["end"] - meta["stage2"]["start"] == pytest.approx(50.0)  # 5 periods of 10 s
    assert get_scenario("stage1").meta()[1]["kind"] == "stage1"
    assert get_scenario("stage2").meta()[1]["kind"] == "stage2"


def test_meta_is_clipped_to_a_truncated_run():
    meta = get_scenario("paper").meta(duration=30.0)
    assert [m["name"] for m in meta] == ["settle", "stage1"] and meta[-1]["end"] == 30.0


def test_stage1_command_is_figure4_centred_at_20():
    sc = get_scenario("stage1")
    for t in np.linspace(2.0, 52.0, 37):
        v, a, d, _ = sc.command(float(t))
        assert v == pytest.approx(20.0 + 10.0 * math.sin(2 * math.pi * (t - 2.0) / 12.5), abs=1e-9)
        assert d == 0.0
    assert sc.command(1.0)[:3] == (20.0, 0.0, 0.0)


def test_stage2_command_is_figure6_sawtooth():
    sc = get_scenario("stage2")
    assert sc.command(2.0)[2] == pytest.approx(-5 * DEG)
    assert sc.command(6.99)[2] == pytest.approx(-5 * DEG + 10 * DEG * 0.499, abs=1e-9)
    assert sc.command(11.999)[2] == pytest.approx(5 * DEG, abs=1e-4)
    assert sc.command(12.0)[2] == pytest.approx(-5 * DEG)
    assert all(sc.command(t)[0] == 10.0 for t in np.linspace(0, 52, 50))


def test_city_drive_is_mixed_and_never_steers_fast():
    sc = get_scenario("city")
    assert 200.0 <= sc.duration <= 300.0
    kinds = {m["kind"] for m in sc.meta()}
    assert {"stage1", "stage2", "other"} <= kinds
    hint = 0
    stops = steering_accel = 0
    for t in np.arange(0.0, sc.duration, 0.05):
        v, a, d, hint = sc.command(float(t), hint)
        if abs(d) > 1e-6:
            assert v <= 20.0  # the paper car oversteers; critical speed ~29 m/s
            steering_accel += abs(a) > 0.5
        stops += v == 0.0
    assert stops > 0 and steering_accel > 0


@pytest.mark.slow
def test_city_turns_are_right_angles_and_stops_hold():
    tr = trace("city", every=20)
    sc = get_scenario("city")
    turns = [s for s in sc.segments if "turn" in s.name and s.kind == "other" and "slow" not in s.name]
    assert len(turns) == 3
    for s in turns:
        i0, i1 = np.searchsorted(tr["t"], [s.start, s.end])
        assert abs(math.degrees(tr["heading"][i1] - tr["heading"][i0])) == pytest.approx(90.0, abs=10.0)
    stops = [s for s in sc.segments if s.name == "stop"]
    for s in stops:
        i0, i1 = np.searchsorted(tr["t"], [s.start + 0.5, s.end])
        assert (tr["v_x"][i0:i1] == 0.0).all()
    assert tr["v_x"].min() >= 0.0 and np.abs(tr["v_x"] - tr["v_cmd"]).max() < 0.5


def test_driver_tracks_stage1_and_splits_torque():
    tr = trace("stage1", every=2)
    moving = tr["t"] > 2.5
    assert np.abs(tr["v_x"] - tr["v_cmd"])[moving].max() < 0.3
    total = tr["T_f"] + tr["T_r"]
    drive, brake = total > 50.0, total < -50.0
    assert drive.any() and brake.any()
    assert np.allclose(tr["T_f"][drive] / total[drive], 0.5)
    assert np.allclose(tr["T_f"][brake] / total[brake], 0.6)


def test_driver_split_is_configurable():
    cfg = DriverConfig(drive_front=0.0, brake_front=1.0)
    tr = trace("stage1", every=5, duration=12.0, driver=cfg)
    assert (tr["T_f"] <= 0.0).all() and (tr["T_r"] >= 0.0).all()
    assert tr["T_f"].min() < -500.0 and tr["T_r"].max() > 500.0
    with pytest.raises(ConfigError):
        DriverConfig(drive_front=1.5)


def test_traction_control_keeps_a_front_driven_car_from_spinning():
    """The paper's 5 m/s^2 exceeds a front-driven car's grip (about 3.4 m/s^2 at mu = 1): with
    traction control the front slip stays near the grip's 0.1; without it the wheels spin away."""
    fwd = {"drive_front": 1.0, "brake_front": 0.65}
    tr = trace("stage1", every=5, duration=25.0, driver=DriverConfig(**fwd))
    moving = tr["t"] > 2.0
    assert np.abs(tr["s_f"][moving]).max() < 0.11 and np.abs(tr["s_r"][moving]).max() < 0.11
    assert tr["a_x"][moving].max() > 3.0  # it still accelerates at the tyre's grip
    assert np.abs(tr["v_x"] - tr["v_cmd"])[moving].max() < 4.0  # lags the command where grip runs out
    spin = trace("stage1", every=5, duration=25.0, driver=DriverConfig(**fwd, slip_max=None))
    assert np.abs(spin["s_f"]).max() > 1.0 and spin["omega_f"].max() > 1000.0
    with pytest.raises(ConfigError):
        DriverConfig(slip_max=0.0)


def test_traction_control_leaves_a_drive_within_grip_unchanged():
    """The default (both axles driven) never reaches 0.1 of slip: torques identical with and without."""
    a = trace("stage1", every=7)
    b = trace("stage1", every=7, driver=DriverConfig(slip_max=None))
    np.testing.assert_array_equal(a["T_f"], b["T_f"])
    np.testing.assert_array_equal(a["T_r"], b["T_r"])


def test_steering_is_rate_limited_and_reaches_the_command():
    tr = trace("stage2", every=1, duration=24.0)
    rate = np.abs(np.diff(tr["delta"])) / np.diff(tr["t"])
    assert rate.max() <= 40.0 * DEG * 1.0001
    assert rate.max() > 35.0 * DEG  # the sawtooth's jumps do hit the limit
    # The ramp reaches +5 deg; after a 0.25 s rate-limited jump the ramp has moved on to about -4.75.
    assert tr["delta"].max() > 4.95 * DEG and -4.9 * DEG < tr["delta"].min() < -4.6 * DEG


@settings(max_examples=25, deadline=None)
@given(tau=st.floats(0.01, 0.2), T=st.floats(-3000.0, 3000.0))
def test_torque_lag_is_first_order(tau, T):
    m, r, J = 1600.0, 0.3, 0.6
    drv = Driver(DriverConfig(tau_torque=tau, ki=0.0, kp=0.0, a_max=100.0), m, r, J)
    a = T / (m * r + 2 * J / r)
    n = int(round(tau / 0.001))
    for _ in range(n):
        tf, tr_, _ = drv.update(0.001, 10.0, a, 0.0, 10.0)
    assert tf + tr_ == pytest.approx(T * (1.0 - math.exp(-n * 0.001 / tau)), rel=1e-9, abs=1e-9)


def test_plan_rejects_bad_segments():
    with pytest.raises(ConfigError):
        Plan("x", 5.0).hold(2.0)
    with pytest.raises(ConfigError):
        Plan("x", 5.0).cruise(0.0, "empty")
    with pytest.raises(ConfigError):
        Plan("x", 5.0).cruise(1.0, "bad", kind="stage3")
    with pytest.raises(ConfigError):
        get_scenario("autobahn")
    assert sawtooth_steer(1.0, 10.0)(15.0) == pytest.approx(0.0)
