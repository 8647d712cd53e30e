"""C_alpha's std where the axles are further apart than tyres alike allow (output_error.cover_axles)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vdp.core.output_error import Fit, cover_axles

L = 2.6
L_F = 1.06  # front-heavy: the loads' ratio l_r / l_f = 1.45


def fit(c_f: float, c_r: float, rel_std: float) -> Fit:
    """A fit whose axles' log difference has ``rel_std`` (uncorrelated axles, each rel_std / sqrt 2)."""
    cov = np.diag([rel_std**2 / 2, rel_std**2 / 2, 0.01**2])
    return Fit(theta=np.array([c_f, c_r, 2000.0]), offset=0.0, cov=cov, chi2=1.0, rho=0.0, rows=1000, iters=5)


@pytest.mark.parametrize("ratio", [1.0, 1.13, 1.45])
def test_axles_within_what_tyres_alike_allow_leave_the_std(ratio):
    std, note = cover_axles("C_alpha", 80_000.0, 2_000.0, fit(80_000.0 * ratio, 80_000.0, 0.01), L_F, L)
    assert (std, note) == (2_000.0, None)


def test_a_front_axle_softer_than_the_rear_on_a_front_heavy_car_widens_the_std():
    # brush/compact's ordinary drive: front/rear 0.89 with the front carrying 1.45x the rear's load
    value, std0 = 67_000.0, 2_000.0
    std, note = cover_axles("C_alpha", value, std0, fit(63_300.0, 71_000.0, 0.01), L_F, L)
    d = math.log(71_000.0 / 63_300.0)
    assert std == pytest.approx(math.hypot(std0, 0.5 * d * value))  # the tyres' mean: d / 2 above
    assert std / value > 0.05  # beyond C_alpha's usefulness threshold: not valid
    assert "front axle" in note and "K&C steer" in note and "0.89" in note


def test_a_rear_axle_softer_than_its_load_allows_names_the_rear():
    std, note = cover_axles("C_alpha", 80_000.0, 2_000.0, fit(80_000.0 * 1.8, 80_000.0, 0.01), L_F, L)
    assert std > 2_000.0 and "rear axle" in note


def test_the_cover_ramps_in_between_two_and_three_of_the_ratio_stds():
    # no knife edge: just outside the interval by 2 stds nothing, by 2.5 half the term, by 3 all of it
    value, std0, s = 80_000.0, 1_000.0, 0.02
    out = []
    for k in (1.9, 2.0, 2.5, 3.0, 4.0):
        c_f = 80_000.0 * math.exp(-k * s)  # below 1 (the front-heavy car's lower bound) by k stds
        out.append(cover_axles("C_alpha", value, std0, fit(c_f, 80_000.0, s), L_F, L)[0])
    d = [k * s for k in (2.5, 3.0, 4.0)]
    assert out[0] == out[1] == std0
    assert out[2] == pytest.approx(math.hypot(std0, 0.25 * d[0] * value))
    assert out[3] == pytest.approx(math.hypot(std0, 0.5 * d[1] * value))
    assert out[4] == pytest.approx(math.hypot(std0, 0.5 * d[2] * value))


def test_only_c_alpha_and_a_physical_geometry_are_covered():
    f = fit(50_000.0, 90_000.0, 0.01)
    assert cover_axles("I_z", 2000.0, 20.0, f, L_F, L) == (20.0, None)
    assert cover_axles("C_alpha", 70_000.0, 2_000.0, f, 0.0, L) == (2_000.0, None)
    assert cover_axles("C_alpha", 70_000.0, 2_000.0, f, L, L) == (2_000.0, None)
