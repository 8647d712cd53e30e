"""Issue 28's world in the simulators (vdp.sim.road): grade, bank, an undeclared load and a
body-fixed IMU, in vdp's own simulator and in the independent brush model.  Each is off by
default; these check the physics when it is on."""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

from vdp import channels as ch
from vdp.errors import ConfigError
from vdp.sim.independent import get_model
from vdp.sim.independent.common import AUX, IndependentSimulation, drive
from vdp.sim.road import DEG, Imu, Road, add_load, body_accel, placement
from vdp.sim.run import Simulation
from vdp.sim.scenario import Plan

G = 9.8  # profiles/paper.toml's g
GRADE = Road(grade=0.08, constant=True)
BANK = Road(bank=3.0 * DEG, constant=True)


def _last(sim: Simulation) -> dict:
    """The last value of every channel the simulation sent (noise-free, before quantisation)."""
    vals: dict = {}
    for _ in sim.frames(lambda t, name, v: vals.update(v)):
        pass
    return vals


def _held(**kw) -> dict:
    sc = Plan("standing", 0.0).hold(3.0).build()
    return _last(Simulation("profiles/paper.toml", sc, noise="none", **kw))


def test_a_car_standing_on_an_8_percent_grade_reads_g_sin_theta():
    v = _held(road=GRADE)
    assert v["accel_x"] == pytest.approx(G * math.sin(math.atan(0.08)), rel=1e-9)
    assert v["accel_y"] == 0.0


def test_a_car_standing_on_a_bank_reads_g_sin_phi():
    v = _held(road=BANK)
    assert v["accel_y"] == pytest.approx(G * math.sin(3.0 * DEG), rel=1e-9)
    assert v["accel_x"] == 0.0


def test_a_car_cruising_up_a_grade_needs_the_force_and_reads_it():
    """At a steady speed up 8 %, the driver's torque carries m g sin(theta) and the road-aligned
    accelerometer reads g sin(theta) (dv/dt = 0)."""
    sc = Plan("climb", 15.0).cruise(25.0, "climb").build()
    sim = Simulation("profiles/paper.toml", sc, noise="none", road=GRADE)
    v = _last(sim)
    g_sin = G * math.sin(math.atan(0.08))
    assert v["speed"] == pytest.approx(15.0, abs=0.05)
    assert v["accel_x"] == pytest.approx(g_sin, rel=0.01)
    force = (v["wheel_torque_front"] + v["wheel_torque_rear"]) / sim.model.params.r
    assert force == pytest.approx(sim.model.params.m * g_sin, rel=0.02)


def test_a_body_fixed_imu_pitches_and_its_mounting_offset_shows_at_rest():
    tilt = 1.0 * DEG
    v = _held(imu=Imu(body=True, mount_pitch=tilt, mount_roll=-0.5 * DEG))
    assert v["accel_x"] == pytest.approx(G * math.sin(tilt), rel=1e-6)
    assert v["accel_y"] == pytest.approx(-G * math.sin(0.5 * DEG), rel=1e-3)
    # accelerating on a flat road: the body pitches 0.2 deg per m/s^2 and a_x reads g sin of it more
    sc = Plan("go", 10.0).ramp(20.0, 6.0, "accelerate").build()
    road = _last(Simulation("profiles/paper.toml", sc, noise="none", duration=3.0))
    body = _last(Simulation("profiles/paper.toml", sc, noise="none", duration=3.0, imu=Imu(body=True)))
    f_x = road["accel_x"]
    assert f_x > 2.0
    assert body["accel_x"] == pytest.approx(f_x * math.cos(0.2 * DEG * f_x) + G * math.sin(0.2 * DEG * f_x), rel=1e-9)


def test_body_accel_rotates_the_specific_force():
    # nose up by p: x reads f_x cos p + f_z sin p; right side down by r: y reads f_y cos r + f_z sin r
    assert body_accel(0.0, 0.0, G, 0.1, 0.0) == pytest.approx((G * math.sin(0.1), 0.0))
    assert body_accel(0.0, 0.0, G, 0.0, 0.05) == pytest.approx((0.0, G * math.sin(0.05)))
    ax, ay = body_accel(3.0, -2.0, G, 0.02, 0.03)
    assert math.hypot(ax, ay) <= math.sqrt(9.0 + 4.0 + G * G)


def test_an_undeclared_load_moves_the_cg_back_and_up_and_the_profile_keeps_its_mass():
    plain = Simulation("profiles/paper.toml", "paper", noise="none")
    for kg in (150.0, 300.0):
        sim = Simulation("profiles/paper.toml", "paper", noise="none", load=kg)
        t, p0 = sim.truth["parameters"], plain.truth["parameters"]
        assert sim.truth["mass"] == pytest.approx(1600.0 + kg)
        assert sim.model.params.m == pytest.approx(1600.0 + kg)
        assert sim.profile.vehicle.mass == 1600.0  # what the estimator is told: undeclared
        assert t["l_f"] > p0["l_f"] and t["h"] > p0["h"]
        assert t["I_z"] > p0["I_z"] and t["I_x"] > p0["I_x"]
        assert (t["C_K"], t["C_alpha"]) == (p0["C_K"], p0["C_alpha"])  # the tyres' law is per unit load
    assert "mass" not in plain.truth and "road" not in plain.truth  # off: the truth file is as before


def test_add_load_is_the_parallel_axis_theorem():
    items = placement(300.0, 2.5, 1.5)
    assert sum(i.kg for i in items) == pytest.approx(300.0)
    c = add_load(1600.0, 1.4, 0.637, 2000.0, 500.0, 2500.0, items)
    xs = [1.4] + [i.x for i in items]
    ms = [1600.0] + [i.kg for i in items]
    assert c.l_f == pytest.approx(np.dot(ms, xs) / sum(ms))
    # moments about the new CG: the old car's own plus its shift, each item's own plus its offset
    iz = 2000.0 + 1600.0 * (1.4 - c.l_f) ** 2 + sum(i.own + i.kg * ((i.x - c.l_f) ** 2 + i.y**2) for i in items)
    assert c.I_z == pytest.approx(iz)
    assert placement(0.0, 2.5, 1.5) == ()
    with pytest.raises(ConfigError, match="load"):
        placement(-5.0, 2.5, 1.5)


def test_road_profile_stays_within_its_peaks_and_is_smooth():
    road = Road(grade=0.08, bank=3.0 * DEG)
    s = np.arange(0.0, 5000.0, 1.0)
    th, ph = np.array([road.angles(x) for x in s]).T
    assert np.abs(np.tan(th)).max() <= 0.08 + 1e-12 and np.abs(np.tan(th)).max() > 0.07
    assert np.abs(ph).max() <= 3.0 * DEG + 1e-12
    assert np.abs(np.diff(np.tan(th))).max() < 0.002  # per metre: a smooth road, no steps
    assert np.percentile(np.abs(np.tan(th)), 90) > 0.05  # typically several per cent
    with pytest.raises(ConfigError, match="grade"):
        Road(grade=0.5)


def test_the_options_off_leave_the_bus_bit_identical():
    def digest(**kw) -> str:
        h = hashlib.sha256()
        for msg in Simulation("profiles/paper.toml", "paper", seed=3, duration=8.0, **kw).frames():
            h.update(bytes(msg.data))
        return h.hexdigest()

    assert digest() == digest(road=None, load=0.0, imu=None) == digest(imu=Imu(body=False))


# -- the brush model --------------------------------------------------------------------
def test_brush_car_climbing_reads_g_sin_theta_beyond_dv_dt():
    sc = Plan("climb", 15.0).cruise(6.0, "climb").build()
    model = get_model("brush", "saloon", road=GRADE)
    tr = drive(model, sc)
    a_x = tr.values[:, ch.AX]
    dv = np.gradient(tr.aux[:, AUX.index("v_x")], 0.001)
    assert (a_x - dv)[-2000:].mean() == pytest.approx(model.c.g * math.sin(math.atan(0.08)), rel=1e-3)


def test_brush_bank_pulls_the_body_sideways_and_a_body_imu_reads_its_tilt():
    flat = get_model("brush", "saloon")
    banked = get_model("brush", "saloon", road=BANK)
    banked.set_road(0.0, 3.0 * DEG)
    x = flat.initial(15.0)
    d0, _ = flat.deriv(list(x), 100.0, 100.0, 0.0)
    d1, _ = banked.deriv(list(x), 100.0, 100.0, 0.0)
    assert d1[1] - d0[1] == pytest.approx(-flat.c.g * math.sin(3.0 * DEG), rel=1e-9)
    # a body-fixed IMU on a body pitched nose up and rolled right side down
    body = get_model("brush", "saloon", imu=Imu(body=True))
    x = body.initial(15.0)
    x[3], x[5] = 0.01, 0.004  # roll, pitch
    _, row = body.step(list(x), 0.0, 0.0, 0.0, 0.001)
    _, ref = flat.step(list(x), 0.0, 0.0, 0.0, 0.001)
    want = body_accel(ref[ch.AX], ref[ch.AY], flat.c.g, 0.004, 0.01)
    assert (row[ch.AX], row[ch.AY]) == pytest.approx(want, rel=1e-12)
    assert row[ch.AY] - ref[ch.AY] == pytest.approx(flat.c.g * 0.01, rel=0.02)


def test_brush_load_is_undeclared_and_its_truth_is_the_loaded_cars():
    base = get_model("brush", "saloon")
    car = get_model("brush", "saloon", load=300.0)
    assert car.mass == pytest.approx(base.mass + 300.0)
    assert car.vehicle().mass == base.mass  # the profile a user writes: kerb plus driver
    t0, t = base.static_truth(), car.static_truth()
    assert t["l_f"] > t0["l_f"] and t["I_z"] > t0["I_z"] and t["I_x"] > t0["I_x"]
    sim = IndependentSimulation(car, scenario="stage1", duration=20.0, noise="none")
    assert sim.truth["mass"] == pytest.approx(base.mass + 300.0)
    assert sim.truth["declared_mass"] == base.mass
    assert sim.profile.vehicle.mass == base.mass
    with pytest.raises(ConfigError, match="mb"):
        get_model("mb", load=150.0)
