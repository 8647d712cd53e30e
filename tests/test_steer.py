"""core.steer: the front wheels' compliance and roll steer a profile declares.

The physics is checked against the brush model's compact car, which steers its front wheels
by its tyres' aligning torque on a compliant steering and both axles by the roll (its own
code, not vdp's): in a steady turn, the angle core.steer takes off must be the one the model
turns its wheels by.  Then the plumbing: the profile's keys, their errors, the fingerprint
of a profile that declares none, and the estimator's two entry points agreeing.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from vdp import channels as ch
from vdp.core import steer
from vdp.core.estimator import TwoStageEstimator
from vdp.core.sample import Sample
from vdp.errors import ProfileError
from vdp.profile import load_profile
from vdp.sim.independent import get_model
from vdp.store import profile_fingerprint

ROOT = Path(__file__).resolve().parents[1]
BASE = (
    (ROOT / "profiles" / "paper.toml")
    .read_text()
    .replace('dbc = "../dbc/vdp.dbc"', f'dbc = "{ROOT / "dbc" / "vdp.dbc"}"')
)


PAPER_FINGERPRINT = "8b07e0baf0134ff300cb348ded475d7edc7d81a81577ba935bebd8195b3bc050"


def _steady_turn(model, delta: float, v0: float = 15.0, seconds: float = 4.0):
    """The model held at road-wheel angle ``delta`` (the torque that holds the speed): its state and
    the last row's a_y once the turn is steady."""
    x = model.initial(v0)
    dt = 0.001
    row = None
    for _ in range(int(seconds / dt)):
        tf = 400.0 * (v0 - x[0])  # a driver holding the speed (N m per m/s)
        x, row = model.step(x, tf, 0.0, delta, dt)
    return x, row[ch.AY]


@pytest.mark.parametrize("delta", [0.04, 0.06])
def test_the_angle_taken_off_is_the_one_the_compact_car_steers_by(delta):
    model = get_model("brush", "compact")
    c = model.c
    x, ay = _steady_turn(model, delta)
    phi = x[3]
    # the model's own steer in the turn: the aligning torque's at the front, the roll's at both
    # axles (a rear steer is a front steer of the opposite sign in a steady turn: core.steer)
    true = c.trail * model._fyf / c.k_steer + (c.roll_steer_f + c.roll_steer_r) * phi
    p = model.profile()
    veh = dataclasses.replace(p.vehicle, **model.kc())
    k = steer.gain(veh, p.priors["l_f"].value, p.priors["h"].value)
    assert 2.0 < ay < 6.0  # a corner well inside the tyres' grip (the test's premise)
    assert true > 0.1 * delta  # the effect is large enough to test: the steer is 10 % of the angle or more
    # within 10 % (4.4 % measured): the profile's l_f prior (1.30 against 1.06 m) and eq (9)'s roll of the whole mass
    # about the ground (the model rolls its sprung mass about its roll axis) err either way
    assert k * ay == pytest.approx(true, rel=0.10)


def test_kc_figures_read_from_the_profile_in_si(tmp_path):
    kc = "compliance_steer_deg_per_kN = 0.11\nroll_steer_front = 0.08\nroll_steer_rear = 0.04"
    text = BASE.replace("track = 1.53", f"track = 1.53\n{kc}")
    f = tmp_path / "car.toml"
    f.write_text(text)
    v = load_profile(f).vehicle
    assert v.compliance_steer == pytest.approx(0.11 * math.pi / 180.0 / 1000.0)
    assert (v.roll_steer_f, v.roll_steer_r) == (0.08, 0.04)


@pytest.mark.parametrize(
    "line, says",
    [
        ("compliance_steer_deg_per_kN = 110.0", "'compliance_steer_deg_per_kN' = 110 is not plausible"),
        ("roll_steer_front = 8.0", "per deg of body roll"),
        ('roll_steer_rear = "0.04"', "'roll_steer_rear' must be a finite number"),
        ("compliance_steer = 0.1", "unknown key(s) ['compliance_steer']"),
    ],
)
def test_a_bad_kc_figure_is_named(tmp_path, line, says):
    f = tmp_path / "car.toml"
    f.write_text(BASE.replace("track = 1.53", f"track = 1.53\n{line}"))
    with pytest.raises(ProfileError) as e:
        load_profile(f)
    assert says in str(e.value)


def test_a_profile_without_kc_keeps_its_fingerprint():
    """Stores key their learning by the profile's fingerprint: the new fields, unset, leave it as
    it was; declared, they change it (the estimates are then of another model of the car)."""
    p = load_profile(ROOT / "profiles" / "paper.toml")
    assert steer.gain(p.vehicle, 1.25, 0.5) == 0.0
    # paper.toml's fingerprint before the K&C fields existed (main at 06e364a)
    assert profile_fingerprint(p) == PAPER_FINGERPRINT
    declared = dataclasses.replace(p, vehicle=dataclasses.replace(p.vehicle, roll_steer_f=0.05))
    assert profile_fingerprint(declared) != PAPER_FINGERPRINT


def _samples(n: int, k_ay: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    T = 0.02 * np.arange(n)
    Y = np.full((n, ch.N), np.nan)
    Y[:, ch.DELTA] = 0.02 * np.sin(T)
    Y[:, ch.AY] = k_ay * np.sin(T) + 0.05 * rng.standard_normal(n)
    Y[5, ch.AY] = np.nan  # a missing a_y leaves the angle as it was
    return T, Y


def test_sample_and_block_take_off_the_same_angle():
    k = 2.6e-3
    T, Y = _samples(50, 4.0)
    B = steer.block(Y, k)
    assert not np.shares_memory(B, Y)
    for i in range(len(T)):
        s = Sample(float(T[i]), tuple(Y[i].tolist()), (True,) * ch.N, (0.0,) * ch.N)
        got = steer.sample(s, k).values[ch.DELTA]
        assert got == B[i, ch.DELTA]  # to the bit
    assert B[5, ch.DELTA] == Y[5, ch.DELTA]
    assert B[6, ch.DELTA] == pytest.approx(Y[6, ch.DELTA] - k * Y[6, ch.AY])


def test_the_estimator_hands_its_learners_the_corrected_angle():
    p = load_profile(ROOT / "profiles" / "paper.toml")
    veh = dataclasses.replace(p.vehicle, compliance_steer=2e-6, roll_steer_f=0.08)
    est = TwoStageEstimator(veh, p.priors)
    plain = TwoStageEstimator(p.vehicle, p.priors)
    assert est.steer_k > 0.0 and plain.steer_k == 0.0
    y = [0.0] * ch.N
    y[ch.DELTA], y[ch.AY] = 0.03, 3.0
    s = Sample(0.0, tuple(y), (True,) * ch.N, (0.0,) * ch.N)
    assert est.handle(0.0, s).values[ch.DELTA] == pytest.approx(0.03 - est.steer_k * 3.0)
    assert plain.handle(0.0, s).values[ch.DELTA] == 0.03
