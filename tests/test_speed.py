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
