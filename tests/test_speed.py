"""The speed filter (vdp.core.speed): GNSS + IMU, and a coarse GNSS's rounding error as a state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vdp.core.speed import RoundedSpeedFilter, SpeedConfig, SpeedFilter, speed_filter

MPH = 0.44704  # m/s: one step of a GPS speed in whole mph


def drive(filt, v_of_t, seed: int, T: float = 60.0, gnss_every: float = 1.0, step: float = MPH):
    """Feed ``filt`` 50 Hz a_x (noise 0.05 m/s^2) and a GNSS speed rounded to ``step`` (noise
    0.05 m/s) every ``gnss_every`` s; return (t, true v, estimate, std) at each tick."""
    rng = np.random.default_rng(seed)
    dt, out = 0.02, []
    for k in range(int(T / dt) + 1):
        t = k * dt
        v, a = v_of_t(t)
        g = None
        if k % round(gnss_every / dt) == 0:
            g = round((v + 0.05 * rng.standard_normal()) / step) * step
        filt.step(t, a + 0.05 * rng.standard_normal(), g)
        out.append((t, v, filt.v, filt.std))
    return np.array(out)


def test_a_coarse_step_gets_the_rounding_state_a_fine_one_does_not():
    assert isinstance(speed_filter(SpeedConfig(gnss_step=MPH)), RoundedSpeedFilter)
    assert type(speed_filter(SpeedConfig())) is SpeedFilter


def test_at_constant_speed_the_std_keeps_the_rounding():
    """22.3 mph: nearly every fix reads 22 mph (0.13 m/s low).  Averaging cannot remove a
    constant error, so the std must stay near step / sqrt 12 and cover the error; a white
    GNSS noise of the same size (the two-state filter) shrinks its std as if it could."""
    q = MPH / math.sqrt(12.0)

    def const(t):
        return 22.3 * MPH, 0.0  # the same speed in every seed: what differs is the noise

    white_missed = 0
    for seed in range(6):
        r = drive(speed_filter(SpeedConfig(gnss_step=MPH)), const, seed)
        err, std = r[-1, 2] - r[-1, 1], r[-1, 3]
        assert 0.6 * q < std < 1.5 * q and abs(err) <= 2 * std, seed
        w = drive(SpeedFilter(SpeedConfig(gnss_noise=q)), const, seed)
        white_missed += abs(w[-1, 2] - w[-1, 1]) > 2 * w[-1, 3]
    assert white_missed >= 4  # what the state is for


@pytest.mark.parametrize("seed", range(4))
def test_while_the_speed_changes_the_steps_average_out(seed):
    """20 +- 10 m/s, period 12.5 s (the paper's stage 1): each fix rounds a different speed, so
    the estimate beats a single fix's rounding and its std says so."""
    w = 2 * math.pi / 12.5

    def sine(t):
        return 20 + 10 * math.sin(w * t), 10 * w * math.cos(w * t)

    filt = speed_filter(SpeedConfig(gnss_step=MPH))
    r = drive(filt, sine, seed)
    late = r[:, 0] > 20.0
    err = r[late, 2] - r[late, 1]
    assert np.sqrt(np.mean(err**2)) < 0.75 * MPH / math.sqrt(12.0)
    assert np.mean(np.abs(err) <= 2 * r[late, 3]) > 0.85
    assert 2.0 < filt.corr_time < 20.0  # 1 Hz fixes: the error stays for seconds


@pytest.mark.parametrize("kind", ["plain", "rounded"])
def test_a_turn_is_not_learnt_as_the_accelerometers_bias(kind):
    """A junction turn at 5 m/s: v_x changes by a_x + r v_y, the IMU reads a_x alone, so the
    filter sees r v_y (0.3 m/s^2 for 5 s) as a bias.  Told the car turns (``turn``), it holds
    the bias and follows the GNSS; after the turn, pulling away at 1.5 m/s^2, its v_x stays
    within 1 cm/s of the truth.  Without ``turn`` the bias is learnt and v_x reads several cm/s
    fast (docs/decisions/0028)."""
    r_vy, L = 0.3, 2.75

    def run(told: bool):
        cfg = SpeedConfig(gnss_step=MPH) if kind == "rounded" else SpeedConfig()
        filt = speed_filter(cfg)
        dt, v, worst, bias = 0.02, 5.0, 0.0, 0.0
        for k in range(int(25.0 / dt)):
            t = k * dt
            turn_on = 10.0 <= t < 15.0
            a = 1.5 if 15.5 <= t < 20.0 else 0.0
            a_imu = a - (r_vy if turn_on else 0.0)  # dv/dt = a; the IMU misses r v_y
            g = round(v / cfg.gnss_step) * cfg.gnss_step if cfg.gnss_step else v
            yaw = math.sqrt(r_vy / 0.5) if turn_on else 0.0  # (r^2 L bounds r v_y = r^2 l_r)
            filt.step(t, a_imu, g if k % 5 == 0 else None, turn=yaw * yaw * L if told else 0.0)
            v += a * dt
            if 15.5 <= t < 20.0:
                worst = max(worst, filt.v - v)
            if turn_on:
                bias = filt.bias  # as the turn ends
        return bias, worst

    bias, worst = run(True)
    assert abs(bias) < 0.005 and worst < (0.01 if kind == "plain" else 0.05)
    bias_0, worst_0 = run(False)
    # what holding the bias is for (a coarse GNSS's rounding state takes part of the turn's error)
    assert bias_0 < (-0.1 if kind == "plain" else -0.01) and worst_0 > worst


@pytest.mark.parametrize("kind", ["plain", "rounded"])
def test_reversing_is_not_learnt_as_the_accelerometers_bias(kind):
    """Backing out along a car park's lane: 0.5 m/s^2 backwards for 4 s, 10 s at 2 m/s, braking to a
    stop, then pulling away forwards.  The GNSS speed is a magnitude, so the filter's dv/dt = a_x has
    the wrong sign; told the gates see reverse (core.passes.reversing), it holds the bias, and pulling
    away v_x stays within 5 cm/s of the truth (10 with a whole-mph GNSS).  Untold, the bias and the
    speed take the sign error, and v_x pulling away is over five times further off."""
    from vdp.core import gates, passes

    assert passes._REVERSE == gates.REVERSE

    def accel(t: float) -> float:
        return -0.5 if 5.0 <= t < 9.0 else 1.0 if 19.0 <= t < 21.0 or 26.0 <= t < 30.0 else 0.0

    def run(told: bool):
        cfg = SpeedConfig(gnss_step=MPH) if kind == "rounded" else SpeedConfig()
        filt = speed_filter(cfg)
        dt, v, worst, bias = 0.02, 0.0, 0.0, 0.0
        for k in range(int(32.0 / dt)):
            t = k * dt
            a = accel(t)
            g = round(abs(v) / cfg.gnss_step) * cfg.gnss_step if cfg.gnss_step else abs(v)
            gate = gates.REVERSE if 4.0 <= t < 23.0 and told else 0
            filt.step(t, a, g if k % 5 == 0 else None, turn=passes.reversing(a, gate))
            v += a * dt
            if 26.5 <= t < 30.0:
                worst = max(worst, abs(filt.v - v))
            if t < 23.0:
                bias = filt.bias
        return bias, worst

    bias, worst = run(True)
    assert abs(bias) < 0.005 and worst < (0.05 if kind == "plain" else 0.1)
    bias_0, worst_0 = run(False)  # (plain: 0.38 m/s^2 and 0.35 m/s; rounded: 0.03 m/s^2 and 1.0 m/s)
    assert abs(bias_0) > 0.02 and worst_0 > 5.0 * worst
    assert passes.reversing(0.0, gates.REVERSE) > 0.0 and passes.reversing(math.nan, gates.REVERSE) > 0.0
    assert passes.reversing(1.0, gates.ABS) == passes.reversing(1.0, 0) == 0.0
