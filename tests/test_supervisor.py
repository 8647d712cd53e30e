"""The gating supervisor: Table 2 conditions, excitation, hand-over and hysteresis."""

import math

import numpy as np
import pytest

from vdp import channels as ch
from vdp.buffer import Sample
from vdp.core.supervisor import Supervisor


def sample(t, ax=0.0, delta=0.0, yaw=0.0, speed=20.0, missing=()):
    y = np.zeros(ch.N)
    y[[ch.WS_FL, ch.WS_FR, ch.WS_RL, ch.WS_RR]] = speed / 0.3
    y[ch.AX], y[ch.DELTA], y[ch.YAW], y[ch.SPEED] = ax, delta, yaw, speed
    for name in missing:
        y[ch.INDEX[name]] = math.nan
    return Sample(t, tuple(y.tolist()), (True,) * ch.N, (0.0,) * ch.N, v_x=speed)


def run(sup, n, f, done=False, t0=0.0):
    stages = []
    for k in range(n):
        t = t0 + k * 0.01
        stages.append(sup.update(t, f(t), done))
    return stages


def accel(t):
    return sample(t, ax=3.0 * math.sin(2 * math.pi * t / 12.5))


def weave(t):
    return sample(
        t, delta=math.radians(3) * math.sin(2 * math.pi * t / 4), yaw=0.1 * math.sin(2 * math.pi * t / 4), speed=10.0
    )


def test_straight_acceleration_opens_stage_1_only():
    sup = Supervisor()
    stages = run(sup, 1000, accel)
    assert stages[-1] == 1 and 2 not in stages
    assert sup.reason[2] == "waiting for stage 1's l_f"


def test_steering_closes_stage_1_at_once_and_no_window_below_min_speed():
    sup = Supervisor()
    run(sup, 1000, accel)
    assert sup.update(10.0, sample(10.0, ax=2.0, delta=math.radians(1.0)), False) is None
    slow = Supervisor()
    assert set(run(slow, 800, lambda t: sample(t, ax=3 * math.sin(t), speed=3.0))) == {None}
    assert "speed below" in slow.reason[1]


def test_stage_2_needs_the_hand_over_and_steering_at_steady_speed():
    sup = Supervisor()
    assert set(run(sup, 800, weave, done=False)) == {None}
    stages = run(sup, 800, weave, done=True, t0=8.0)
    assert stages[-1] == 2
    assert sup.excitation()["2"]["seconds"] > 5.0


def test_constant_offset_is_not_longitudinal_excitation():
    sup = Supervisor()
    stages = run(sup, 800, lambda t: sample(t, ax=0.8))  # grade or bias: a_x constant
    assert 1 not in stages
    assert "little longitudinal excitation" in sup.reason[1]


def test_missing_channel_closes_the_window_and_says_which():
    sup = Supervisor()
    run(sup, 1000, accel)
    assert sup.update(10.0, sample(10.0, ax=2.0, missing=("wheel_torque_front",)), False) is None
    assert "wheel_torque_front" in sup.reason[1]


def test_hysteresis_does_not_flicker_on_brief_dips():
    sup = Supervisor()
    run(sup, 1000, accel)
    n_before = sup.window_count
    # a_x spread dips for 0.2 s (shorter than t_off): the window stays open
    for k in range(20):
        sup._ax_sq = sup._ax_m**2  # no spread
        assert sup.update(10.0 + k * 0.01, sample(10.0 + k * 0.01, ax=0.0), False) == 1
    assert sup.window_count == n_before


def test_the_excitation_averages_follow_uneven_steps():
    """The EMA gains are kept for the last step length (nearly every step is one tick): steps of
    other lengths in between still get their own gain, 1 - exp(-dt / tau)."""
    sup = Supervisor()
    rng = np.random.default_rng(3)
    t, ax_m, d_m = 0.0, 0.0, 0.0
    for k in range(400):
        dt = 0.02 if k % 7 else float(rng.uniform(0.001, 0.09))
        t += dt
        ax, delta = float(rng.normal(0, 2)), float(rng.normal(0, 0.02))
        sup.update(t, sample(t, ax=ax, delta=delta), True)
        if k:  # (the first sample's step is taken as 0.01 s)
            ax_m += (1 - math.exp(-dt / sup.cfg.tau_ax)) * (ax - ax_m)
            d_m += (1 - math.exp(-dt / sup.cfg.tau_steer)) * (delta - d_m)
        else:
            ax_m += (1 - math.exp(-0.01 / sup.cfg.tau_ax)) * ax
            d_m += (1 - math.exp(-0.01 / sup.cfg.tau_steer)) * delta
    assert sup._ax_m == pytest.approx(ax_m, rel=1e-12)
    assert sup._d_m == pytest.approx(d_m, rel=1e-12)
