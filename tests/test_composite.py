"""Composite channels: per-axle torques from a total drive torque and a brake torque or
pressure ([drivetrain]), sums, products and pieces chosen by an enum of another message."""

from __future__ import annotations

from pathlib import Path

import can
import cantools
import pytest

from vdp import channels
from vdp.core.estimator import EstimatorConfig
from vdp.errors import ProfileError
from vdp.io.decoder import FrameDecoder
from vdp.pipeline import Pipeline
from vdp.profile import load_profile
from vdp.sim.run import Simulation

ROOT = Path(__file__).resolve().parents[1]
PAPER = (
    (ROOT / "profiles" / "paper.toml")
    .read_text()
    .replace('dbc = "../dbc/vdp.dbc"', f'dbc = "{ROOT / "dbc" / "vdp.dbc"}"')
)
DB = cantools.database.load_file(str(ROOT / "dbc" / "vdp.dbc"))
TORQUE = DB.get_message_by_name("WHEEL_TORQUE")


def profile(tmp_path, channels_toml: str, drivetrain: str = "", name: str = "p.toml"):
    lines = [ln for ln in PAPER.splitlines() if not ln.startswith(("wheel_torque_front", "wheel_torque_rear"))]
    text = "\n".join(lines).replace("[channels]", "[channels]\n" + channels_toml)
    text = text.replace("[checks]", drivetrain + "\n[checks]")
    p = tmp_path / name
    p.write_text(text)
    return load_profile(p)


TOTALS = """drive_torque = { message = "WHEEL_TORQUE", signal = "TORQUE_FRONT", unit = "Nm" }
brake_torque = { message = "WHEEL_TORQUE", signal = "TORQUE_REAR", unit = "Nm" }"""


def torque_frame(front_sig: float, rear_sig: float, t: float = 0.0, counter: int = 0) -> can.Message:
    data = bytearray(
        TORQUE.encode({"TORQUE_FRONT": front_sig, "TORQUE_REAR": rear_sig, "COUNTER": counter, "CHECKSUM": 0})
    )
    from vdp.io.checks import vdp_checksum

    data[7] = vdp_checksum(TORQUE.frame_id, data)
    return can.Message(timestamp=t, arbitration_id=TORQUE.frame_id, data=data, is_extended_id=False)


def test_drive_and_brake_torque_split_by_the_drivetrain(tmp_path):
    prof = profile(tmp_path, TOTALS, '[drivetrain]\ndriven = "front"\nbrake_balance = 0.7\n')
    assert set(prof.composites) == {"wheel_torque_front", "wheel_torque_rear"}
    assert not Pipeline(prof).capabilities()["1"]  # stage 1 can run on this car's signals
    dec = FrameDecoder(prof)
    got = dict(dec.decode(torque_frame(300.0, 0.0)))
    assert got == {channels.T_F: pytest.approx(300.0), channels.T_R: pytest.approx(0.0)}
    got = dict(dec.decode(torque_frame(0.0, 1000.0, t=0.01, counter=1)))
    assert got == {channels.T_F: pytest.approx(-700.0), channels.T_R: pytest.approx(-300.0)}


def test_brake_pressure_times_gain(tmp_path):
    ch = TOTALS.replace(
        'brake_torque = { message = "WHEEL_TORQUE", signal = "TORQUE_REAR", unit = "Nm" }',
        'brake_pressure = { message = "WHEEL_TORQUE", signal = "TORQUE_REAR", unit = "bar" }',
    )
    prof = profile(tmp_path, ch, '[drivetrain]\ndriven = "rear"\nbrake_balance = 0.6\nbrake_gain = 50.0\n')
    dec = FrameDecoder(prof)
    got = dict(dec.decode(torque_frame(100.0, 20.0)))  # 20 bar -> 1000 N m of brake torque
    assert got == {channels.T_F: pytest.approx(-600.0), channels.T_R: pytest.approx(100.0 - 400.0)}


@pytest.mark.parametrize(
    "drivetrain, msg",
    [
        ("", r"need a \[drivetrain\] section"),
        ('[drivetrain]\ndriven = "left"\n', "'driven' must be"),
        ("[drivetrain]\nbrake_balance = 1.5\n", "front axle's share"),
        ('[drivetrain]\ndriven = "front"\nfront_share = 0.3\n', "applies to driven"),
    ],
)
def test_drivetrain_errors_are_one_line(tmp_path, drivetrain, msg):
    with pytest.raises(ProfileError, match=msg):
        profile(tmp_path, TOTALS, drivetrain)


def test_brake_pressure_needs_a_gain(tmp_path):
    ch = TOTALS.replace("brake_torque", "brake_pressure").replace('unit = "Nm" }\n', 'unit = "Nm" }\n')
    ch = ch.replace('signal = "TORQUE_REAR", unit = "Nm"', 'signal = "TORQUE_REAR", unit = "bar"')
    with pytest.raises(ProfileError, match="brake_gain"):
        profile(tmp_path, ch, '[drivetrain]\ndriven = "front"\n')


def test_general_terms_product_and_pieces_by_an_enum(tmp_path):
    # front torque: +TORQUE_FRONT in "forward" (STEERING.COUNTER even... here values [0]), minus it in
    # "reverse" ([1]); rear torque: 0.5 * TORQUE_FRONT * TORQUE_REAR
    ch = """[channels.wheel_torque_front]
conditions = [{ message = "STEERING", signal = "COUNTER" }]
[[channels.wheel_torque_front.terms]]
message = "WHEEL_TORQUE"
signal = "TORQUE_FRONT"
unit = "Nm"
when = { condition = 0, values = [0] }
[[channels.wheel_torque_front.terms]]
message = "WHEEL_TORQUE"
signal = "TORQUE_FRONT"
unit = "Nm"
weight = -1
when = { condition = 0, values = [1] }
[channels.wheel_torque_rear]
op = "product"
terms = [
  { message = "WHEEL_TORQUE", signal = "TORQUE_FRONT", unit = "Nm", weight = 0.5 },
  { message = "WHEEL_TORQUE", signal = "TORQUE_REAR", unit = "1" },
]
[channels]
"""
    text = "\n".join(ln for ln in PAPER.splitlines() if not ln.startswith(("wheel_torque_front", "wheel_torque_rear")))
    text = text.replace("[channels]", ch, 1).replace("WHEEL_TORQUE       = {", "# WHEEL_TORQUE = {")
    p = tmp_path / "g.toml"
    p.write_text(text)
    prof = load_profile(p)
    dec = FrameDecoder(prof)
    steer = DB.get_message_by_name("STEERING")

    def steering(counter: int, t: float) -> can.Message:
        vals = {sig.name: 0 for sig in steer.signals} | {"COUNTER": counter}
        data = bytearray(steer.encode(vals))
        from vdp.io.checks import vdp_checksum

        data[7] = vdp_checksum(steer.frame_id, data)
        return can.Message(timestamp=t, arbitration_id=steer.frame_id, data=data, is_extended_id=False)

    # the front's condition has not been seen yet; the rear's product needs none
    assert dec.decode(torque_frame(100.0, 4.0)) == [(channels.T_R, pytest.approx(200.0))]
    dec.decode(steering(0, 0.01))
    got = dict(dec.decode(torque_frame(100.0, 4.0, t=0.02, counter=1)))
    assert got == {channels.T_F: pytest.approx(100.0), channels.T_R: pytest.approx(200.0)}
    dec.decode(steering(1, 0.03))
    got = dict(dec.decode(torque_frame(100.0, 4.0, t=0.04, counter=2)))
    assert got[channels.T_F] == pytest.approx(-100.0)
    # a term older than max_age (0.5 s) holds the channel back
    assert channels.T_F not in dict(dec.decode(torque_frame(100.0, 4.0, t=0.7, counter=3)))


@pytest.mark.slow
def test_both_stages_from_total_drive_and_brake_torque(tmp_path):
    """All-wheel drive sending one total drive torque and one brake torque: the paper's accuracy."""
    prof = profile(tmp_path, TOTALS, '[drivetrain]\ndriven = "all"\nfront_share = 0.5\nbrake_balance = 0.6\n')
    sim = Simulation(prof, "paper", seed=4)
    pipe = Pipeline(prof, EstimatorConfig(baseline=False))
    for msg in sim.frames():
        pipe.feed(msg)
    par, truth = pipe.result().parameters, sim.truth["parameters"]
    for name, tol in (("l_f", 0.01), ("h", 0.03), ("C_K", 0.03), ("C_alpha", 0.03), ("I_z", 0.05)):
        assert abs(par[name].value / truth[name] - 1) < tol, (name, par[name], truth[name])


# -- the speed reference without GNSS, and a coarse GNSS ---------------------------------------


def no_gnss(tmp_path, driven: str):
    prof = profile(
        tmp_path, TOTALS, f'[drivetrain]\ndriven = "{driven}"\nbrake_balance = 0.65\n', name=f"{driven}.toml"
    )
    chans = {k: v for k, v in prof.channels.items() if k != "speed"}
    import dataclasses

    return dataclasses.replace(prof, channels=chans)


def test_free_rolling_axle_is_the_speed_reference(tmp_path):
    from vdp.core import passes as ps

    rwd = no_gnss(tmp_path, "rear")
    assert rwd.speed_reference == "wheels" and not Pipeline(rwd).capabilities()["1"]
    est = Pipeline(rwd).estimator
    assert est.cfg.speed.wheel_ref == "front"
    awd = no_gnss(tmp_path, "all")
    assert awd.speed_reference is None and "speed" in Pipeline(awd).capabilities()["1"]
    y = [float("nan")] * channels.N
    y[channels.WS_FL], y[channels.WS_FR] = 30.0, 32.0  # rad/s

    def measured(p, torque):
        y[channels.T_F] = torque
        return ps.speed_measured(p, ps.CHANNELS, y, (False,) * channels.N, (0.0,) * channels.N)  # (no GNSS)

    r, noise = rwd.vehicle.wheel_radius, est.cfg.speed.wheel_noise
    assert measured(est._p, 0.0) == (pytest.approx(31.0 * r), True, noise)
    assert measured(est._p, -500.0)[1] is False  # braked: no reference
    assert measured(Pipeline(awd).estimator._p, 0.0)[1] is False


def test_coarse_gnss_speed_gets_its_rounding_state(tmp_path):
    from vdp.core.speed import gnss_noise

    text = PAPER.replace('dbc = "', 'dbc = ["').replace(
        'vdp.dbc"', f'vdp.dbc", "{ROOT / "tests" / "data" / "gnss_mph.dbc"}"]'
    )
    text = "\n".join(
        'speed = { message = "GPS_MPH", signal = "GPS_SPEED_MPH", unit = "mph" }' if ln.startswith("speed ") else ln
        for ln in text.splitlines()
    )
    p = tmp_path / "mph.toml"
    p.write_text(text)
    cfg = Pipeline(load_profile(p)).estimator.cfg.speed
    # whole mph: 0.447 m/s steps, a rounding-error state of their own (vdp.core.speed)
    assert cfg.gnss_step == pytest.approx(0.44704) and cfg.gnss_noise == 0.05
    fine = Pipeline(load_profile(ROOT / "profiles" / "paper.toml")).estimator.cfg.speed
    assert fine.gnss_step == 0.0 and fine.gnss_noise == pytest.approx(gnss_noise(0.05, 0.001))  # 1 mm/s: as white


@pytest.mark.slow
def test_both_stages_without_gnss_on_a_rear_driven_car(tmp_path):
    """Total drive and brake torque, no GNSS: the front wheels are the speed reference."""
    prof = no_gnss(tmp_path, "rear")
    sim = Simulation(prof, "paper", seed=5)
    pipe = Pipeline(prof, EstimatorConfig(baseline=False))
    for msg in sim.frames():
        pipe.feed(msg)
    par, truth = pipe.result().parameters, sim.truth["parameters"]
    for name, tol in (("l_f", 0.01), ("h", 0.03), ("C_K", 0.03), ("C_alpha", 0.03), ("I_z", 0.05)):
        assert abs(par[name].value / truth[name] - 1) < tol, (name, par[name], truth[name])


def test_a_term_from_another_message_is_carried_to_the_frame_time(tmp_path):
    """Drive torque and brake torque in different messages: each composite sample carries the
    other message's term along its last slope, so the sum does not lag (a few ms of torque lag
    biased stage 1 on Ford's bus: C_K +2.5 %, h +3 % noise-free)."""
    ch = TOTALS.replace(
        'brake_torque = { message = "WHEEL_TORQUE", signal = "TORQUE_REAR", unit = "Nm" }',
        'brake_torque = { message = "GNSS_VELOCITY", signal = "GNSS_COURSE", unit = "Nm" }',
    )
    prof = profile(tmp_path, ch, '[drivetrain]\ndriven = "front"\nbrake_balance = 0.5\n')
    dec = FrameDecoder(prof)
    gnss = DB.get_message_by_name("GNSS_VELOCITY")

    def brake(v: float, t: float, counter: int) -> can.Message:
        data = gnss.encode({"GNSS_SPEED": 10.0, "FIX_TYPE": 3, "NUM_SATS": 9, "GNSS_COURSE": v})
        return can.Message(timestamp=t, arbitration_id=gnss.frame_id, data=data, is_extended_id=False)

    dec.decode(brake(0.0, 0.0, 0))
    dec.decode(torque_frame(100.0, 0.0, t=0.002, counter=0))
    dec.decode(torque_frame(200.0, 0.0, t=0.012, counter=1))  # the drive torque rises 10 N m/ms
    got = dict(dec.decode(brake(4.0, 0.017, 1)))  # brake rises 4 N m over 17 ms
    assert got[channels.T_F] == pytest.approx(250.0 - 0.5 * 4.0)  # the drive torque carried 5 ms on
    got = dict(dec.decode(torque_frame(300.0, 0.0, t=0.022, counter=2)))
    assert got[channels.T_F] == pytest.approx(300.0 - 0.5 * (4.0 + 4.0 / 17.0 * 5.0))
