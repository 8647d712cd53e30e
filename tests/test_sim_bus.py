"""Sensors, CAN encoding through the profile, log files, live bus and the CLI."""

from __future__ import annotations

import dataclasses
import json
import math
import re
from collections import defaultdict
from pathlib import Path

import can
import cantools
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vdp import channels
from vdp.cli import main
from vdp.errors import ConfigError, ProfileError
from vdp.io.checks import vdp_checksum
from vdp.io.decoder import FrameDecoder
from vdp.profile import ChannelMap, Composite, load_profile
from vdp.sim.encode import Encoder, signal_range
from vdp.sim.run import (
    START_TIME,
    Simulation,
    open_bus,
    resolve_profile,
    send_live,
    simulate,
    trace,
    truth_path,
    write_log,
)
from vdp.sim.scenario import Plan, sine_steer
from vdp.sim.truth import TRUTH

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "profiles" / "paper.toml"
PROFILE = load_profile(PAPER)
DB = cantools.database.load_file(str(PROFILE.dbc))


def decode_si(profile, db, msg: can.Message) -> dict[str, float]:
    """Canonical SI values carried by one frame, read the way the profile documents."""
    decoded = db.decode_message(msg.arbitration_id, msg.data, decode_choices=False)
    out = {}
    for ch, cm in _maps(profile, db, msg.arbitration_id):
        v = decoded[cm.signal] + (decoded[cm.fine] if cm.fine else 0.0)
        si = cm.factor(profile.vehicle) * (v * cm.scale + cm.offset)
        if cm.sign_signal and decoded[cm.sign_signal]:
            si = -si
        out[ch] = si * _gain(profile, cm)
    return out


def _gain(profile, cm) -> float:
    """A brake pressure stands for the simulator's brake torque: Pa -> N m by [drivetrain] brake_gain."""
    return profile.drivetrain.brake_gain / 1e5 if cm.channel == "brake_pressure" else 1.0


def _maps(profile, db, frame_id: int):
    """(channel, ChannelMap) pairs, primary or alternative source, carried by ``frame_id``."""
    # channels, and the composite channels' sources (drive_torque, brake_torque, ...)
    for ch, cm in [*profile.channels.items(), *profile.sources.items()]:
        if isinstance(cm, Composite):
            continue  # a composite source is solved for (tests/test_encode_composite.py)
        for m in (cm, cm.alt):
            if m is not None and db.get_message_by_name(m.message).frame_id == frame_id:
                yield ("brake_torque" if ch == "brake_pressure" else ch), m


def quantum(profile, db, ch: str, frame_id: int | None = None) -> float:
    """Half a DBC step of channel ``ch`` (in the message ``frame_id``) in SI units."""
    if frame_id is not None:
        cm = dict(_maps(profile, db, frame_id))[ch]
    else:
        cm = profile.channels[ch] if ch in profile.channels else profile.sources[ch]
    sig = db.get_message_by_name(cm.message).get_signal_by_name(cm.fine or cm.signal)
    return 0.5 * abs(sig.scale * cm.scale * cm.factor(profile.vehicle) * _gain(profile, cm)) * (1 + 1e-9) + 1e-12


def run_tapped(profile=PAPER, scenario="stage2", duration=3.0, **kw):
    sim = Simulation(profile, scenario, duration=duration, **kw)
    taps = []
    frames = list(sim.frames(tap=lambda t, name, values: taps.append((t, name, dict(values)))))
    return sim, frames, taps


# -- round trip ---------------------------------------------------------------------------
def test_log_round_trips_through_logreader_and_cantools(tmp_path):
    sim, frames, taps = run_tapped(noise="none", duration=3.0)
    out = tmp_path / "drive.log"
    assert write_log(iter(frames), out) == len(frames) == len(taps)
    lines = out.read_text().splitlines()
    assert re.fullmatch(r"\(1700000000\.\d{6}\) can0 [0-9A-F]{3}#[0-9A-F]{16}", lines[0])
    back = list(can.LogReader(str(out)))
    assert len(back) == len(frames)
    last_counter: dict[int, int] = {}
    last_time: dict[int, float] = {}
    prev_ts = 0.0
    for msg, (t, name, values) in zip(back, taps):
        dbm = DB.get_message_by_frame_id(msg.arbitration_id)
        assert dbm.name == name
        assert msg.timestamp == pytest.approx(START_TIME + t, abs=1e-6) and msg.timestamp >= prev_ts
        prev_ts = msg.timestamp
        decoded = dbm.decode(msg.data, decode_choices=False)  # every frame decodes, in range
        if "CHECKSUM" in decoded:
            assert msg.data[7] == vdp_checksum(msg.arbitration_id, msg.data)
            c = decoded["COUNTER"]
            if msg.arbitration_id in last_counter:
                assert c == (last_counter[msg.arbitration_id] + 1) % 16
            last_counter[msg.arbitration_id] = c
        if msg.arbitration_id in last_time:  # the DBC's cycle time
            assert msg.timestamp - last_time[msg.arbitration_id] == pytest.approx(dbm.cycle_time / 1000, abs=2e-6)
        last_time[msg.arbitration_id] = msg.timestamp
        si = decode_si(PROFILE, DB, msg)
        assert set(si) == set(values)
        for ch, v in values.items():
            assert abs(si[ch] - v) <= quantum(PROFILE, DB, ch), ch
        if name == "GNSS_VELOCITY":
            assert (decoded["FIX_TYPE"], decoded["NUM_SATS"]) == (3, 12)
    assert back[0].timestamp >= START_TIME
    # every message of vdp.dbc but the status message, which only paper_status.toml maps
    assert {m.arbitration_id for m in back} == {m.frame_id for m in DB.messages if m.name != "VEHICLE_STATUS"}


def test_channels_carry_the_truth():
    """noise=none: the single-track wheel speeds, handwheel angle and IMU follow the physics."""
    sim, frames, taps = run_tapped(noise="none", duration=6.0)
    by = defaultdict(list)
    for t, name, values in taps:
        by[name].append((t, values))
    for _t, v in by["WHEEL_SPEEDS_FRONT"]:
        assert v["wheel_speed_fl"] == v["wheel_speed_fr"] == pytest.approx(10.0 / 0.3, rel=0.01)
    steer = [v["steering_angle"] for t, v in by["STEERING"]]
    assert min(steer) < -4.5 * math.pi / 180  # the sawtooth in road-wheel radians
    raw = [DB.decode_message(m.arbitration_id, m.data)["STEER_WHEEL_ANGLE"] for m in frames if m.arbitration_id == 0xD0]
    assert min(raw) == pytest.approx(math.degrees(min(steer)) * 15.0, abs=0.06)  # handwheel, ratio 15
    ay = [v["accel_y"] for t, v in by["IMU_ACCEL"] if t > 5.0]
    yaw = [v["yaw_rate"] for t, v in by["IMU_RATES"] if t > 5.0]
    assert np.mean(ay) == pytest.approx(10.0 * np.mean(yaw), rel=0.1)  # a_y ~ v r


def test_channels_equal_the_physics_at_sample_time():
    """noise=none: every value sent is the truth of that instant (same loop as ``trace``)."""
    sc = Plan("mix", 10.0).ramp(15.0, 3.0, "accelerate while steering", steer=sine_steer(0.05, 2.0)).build()
    sim, frames, taps = run_tapped(noise="none", scenario=sc, duration=3.0)
    tr = trace(sc, every=1)
    expect = {
        "wheel_speed_fl": tr["omega_f"],
        "wheel_speed_fr": tr["omega_f"],
        "wheel_speed_rl": tr["omega_r"],
        "wheel_speed_rr": tr["omega_r"],
        "wheel_torque_front": tr["T_f"],
        "wheel_torque_rear": tr["T_r"],
        "steering_angle": tr["delta"],
        "accel_x": tr["a_x"],
        "accel_y": tr["a_y"],
        "yaw_rate": tr["yaw_rate"],
        "roll_rate": tr["roll_rate"],
        "speed": np.hypot(tr["v_x"], tr["v_y"]),  # GNSS: ground speed of the CG
    }
    seen = set()
    for t, _name, values in taps:
        i = int(round(t / 0.001))
        assert tr["t"][i] == pytest.approx(t)
        for ch, v in values.items():
            assert v == pytest.approx(expect[ch][i], rel=1e-12, abs=1e-12), (ch, t)
            seen.add(ch)
    assert seen == set(channels.NAMES[: channels.N_SENSORS])  # (paper.toml maps no status flag)
    assert np.abs(tr["a_x"]).max() > 1.0 and np.abs(tr["a_y"]).max() > 1.0  # both directions excited


@pytest.mark.parametrize("path", sorted((ROOT / "profiles").glob("*.toml")), ids=lambda p: p.stem)
def test_every_shipped_profile_can_be_simulated(path):
    try:
        prof = load_profile(path)
    except ProfileError as exc:
        if "opendbc" in str(exc) and "install" in str(exc):
            pytest.skip(str(exc))
        raise
    db = cantools.database.load_file(str(prof.dbc), strict=False)
    sim, frames, taps = run_tapped(path, "paper", duration=1.0, noise="none")
    assert len(frames) == len(taps) > 0
    counters: dict[int, int] = {}
    for msg, (_t, name, values) in zip(frames, taps):
        si = decode_si(prof, db, msg)
        values = {ch: v for ch, v in values.items() if not isinstance(prof.sources.get(ch), Composite)}
        assert set(si) == set(values)
        for ch, v in values.items():
            assert abs(si[ch] - v) <= quantum(prof, db, ch, msg.arbitration_id), (name, ch, si[ch], v)
        chk = prof.checks.get(name)
        if chk is not None and chk.counter:
            c = db.decode_message(msg.arbitration_id, msg.data, decode_choices=False)[chk.counter]
            if msg.arbitration_id in counters:  # wraps at the counter's bit width, as the decoder expects
                bits = db.get_message_by_frame_id(msg.arbitration_id).get_signal_by_name(chk.counter).length
                assert c == (counters[msg.arbitration_id] + 1) % (1 << bits)
            counters[msg.arbitration_id] = c


@settings(max_examples=60, deadline=None)
@given(ch=st.sampled_from(channels.NAMES[: channels.N_SENSORS]), u=st.floats(-1.2, 1.2))
def test_encoding_inverts_the_profile_mapping(ch, u):
    enc = Encoder(PROFILE, DB)
    plan = next(p for p in enc.plans if ch in p.channels)
    sp = next(s for s in plan.signals if s.channel == ch)
    f = PROFILE.channels[ch].factor(PROFILE.vehicle)
    lo_si, hi_si = sorted((sp.lo * f, sp.hi * f))
    si = lo_si + (hi_si - lo_si) * (u + 1.0) / 2.0  # up to 10 % outside the range on both sides
    values = dict.fromkeys(plan.channels, 0.0)
    values[ch] = si
    data = enc.encode(plan, values)
    got = decode_si(PROFILE, DB, can.Message(arbitration_id=plan.frame_id, data=data, is_extended_id=False))
    want = min(max(si, lo_si), hi_si)  # clipped into the DBC range
    assert abs(got[ch] - want) <= quantum(PROFILE, DB, ch)


# -- a channel split into a coarse and a fine signal -----------------------------------
FINE_DB = cantools.database.load_file(str(ROOT / "tests" / "data" / "fine.dbc"))
SPLITS = {  # message: (coarse, fine)
    "STEER_ANGLE_SENSOR": ("STEER_ANGLE", "STEER_FRACTION"),  # Toyota: round to 1.5 deg, the rest -0.7..0.7
    "FLOOR_SPLIT": ("ANGLE", "REST"),  # a grid offset by 0.75 deg, the rest 0..1.4
}


def split_profile(message: str, coarse: str, fine: str, **keys):
    """The paper's vehicle with only the steering-wheel angle, read from fine.dbc."""
    cm = ChannelMap(
        "steering_angle",
        message,
        coarse,
        "deg",
        steering_wheel=True,
        fine=fine,
        where="fine.toml [channels.steering_angle]",
        **keys,
    )
    return dataclasses.replace(
        PROFILE, dbc=ROOT / "tests" / "data" / "fine.dbc", channels={"steering_angle": cm}, checks={}
    )


@settings(max_examples=200, deadline=None)
@given(message=st.sampled_from(sorted(SPLITS)), deg=st.floats(-450.0, 450.0), sign=st.sampled_from([1.0, -1.0]))
def test_coarse_and_fine_signals_round_trip(message, deg, sign):
    """The encoder splits a value the way the car does; the decoder's sum is within half a fine step."""
    coarse, fine = SPLITS[message]
    prof = split_profile(message, coarse, fine, sign=sign)
    enc = Encoder(prof, FINE_DB)
    plan = enc.plans[0]
    si = math.radians(deg) / prof.vehicle.steering_ratio
    msg = can.Message(arbitration_id=plan.frame_id, data=enc.encode(plan, {"steering_angle": si}), is_extended_id=False)
    raw = FINE_DB.decode_message(msg.arbitration_id, msg.data, decode_choices=False)
    sig = FINE_DB.get_message_by_name(message).get_signal_by_name(fine)
    assert sig.minimum - 1e-9 <= raw[fine] <= sig.maximum + 1e-9  # never a fraction the car would not send
    if message == "STEER_ANGLE_SENSOR":
        assert abs(raw[coarse] - sign * deg) <= 0.75 + 1e-9  # rounded to the nearest 1.5 deg
    got = FrameDecoder(prof, FINE_DB).decode(msg)
    assert [i for i, _ in got] == [channels.INDEX["steering_angle"]]
    assert abs(got[0][1] - si) <= quantum(prof, FINE_DB, "steering_angle")
    assert decode_si(prof, FINE_DB, msg)["steering_angle"] == pytest.approx(got[0][1], abs=1e-12)


def test_encoder_checks_the_fine_signal():
    with pytest.raises(
        ProfileError,
        match=r"\[channels.steering_angle\]: fine signal 'NOPE' is not in message "
        r"'FLOOR_SPLIT'",
    ):
        Encoder(split_profile("FLOOR_SPLIT", "ANGLE", "NOPE"), FINE_DB)
    with pytest.raises(
        ProfileError,
        match=r"fine signal 'SHORT_REST' carries \[0, 0.7\] in steps of 0.1, "
        r"less than one step of 'ANGLE' \(1.5\)",
    ):
        Encoder(split_profile("FLOOR_SPLIT", "ANGLE", "SHORT_REST"), FINE_DB)


# -- determinism -------------------------------------------------------------------------
def _bytes(tmp_path: Path, seed: int, name: str) -> bytes:
    frames, truth = simulate(
        PAPER, "stage1", seed=seed, noise="realistic", duration=3.0, drop_rate=0.05, extra_ids=3, extra_rate=50.0
    )
    out = tmp_path / name
    write_log(frames, out)
    return out.read_bytes()


def test_same_seed_same_bytes_different_seed_differs(tmp_path):
    a, b, c = _bytes(tmp_path, 7, "a.log"), _bytes(tmp_path, 7, "b.log"), _bytes(tmp_path, 8, "c.log")
    assert a == b
    assert a != c
    sim = Simulation(PAPER, "stage1", seed=7, duration=1.0)
    first = [(m.timestamp, m.arbitration_id, bytes(m.data)) for m in sim.frames()]
    again = [(m.timestamp, m.arbitration_id, bytes(m.data)) for m in sim.frames()]
    assert first == again  # frames() restarts the drive


def test_gzip_log_is_deterministic_too(tmp_path):
    for name in ("a.log.gz", "b.log.gz"):
        write_log(simulate(PAPER, "stage2", seed=3, duration=1.0)[0], tmp_path / name)
    assert (tmp_path / "a.log.gz").read_bytes() == (tmp_path / "b.log.gz").read_bytes()
    assert len(list(can.LogReader(str(tmp_path / "a.log.gz")))) > 500


# -- noise -------------------------------------------------------------------------------
def test_realistic_noise_has_documented_sigma_and_bias():
    sim_n, _, clean = run_tapped(noise="none", duration=10.0, seed=5)
    sim_r, _, noisy = run_tapped(noise="realistic", duration=10.0, seed=5)
    assert len(clean) == len(noisy)
    diff = defaultdict(list)
    for (_, _, a), (_, _, b) in zip(clean, noisy):
        for ch in a:
            diff[ch].append(b[ch] - a[ch])
    sigma = sim_r.truth["noise"]["sigma"]
    bias = sim_r.truth["noise"]["bias"]
    for ch, d in diff.items():
        d = np.array(d)
        assert d.std() == pytest.approx(sigma[ch], rel=0.15), ch
        assert d.mean() == pytest.approx(bias.get(ch, 0.0), abs=4 * sigma[ch] / math.sqrt(len(d))), ch
    assert sigma["steering_angle"] == pytest.approx(math.radians(0.1) / 15.0)
    assert sigma["yaw_rate"] == pytest.approx(math.radians(0.1))
    assert set(bias) == {"accel_x", "accel_y", "yaw_rate", "roll_rate"}
    assert sim_n.truth["noise"]["sigma"] == {} and sim_n.truth["noise"]["bias"] == {}
    # A different seed draws different biases.
    other = Simulation(PAPER, "stage2", seed=6, noise="realistic", duration=1.0)
    assert other.truth["noise"]["bias"] != bias


# -- drops and filler --------------------------------------------------------------------
def test_drops_leave_counter_gaps_and_filler_uses_free_ids():
    sim = Simulation(PAPER, "stage1", seed=2, duration=5.0, drop_rate=0.2, extra_ids=4, extra_rate=100.0)
    frames = list(sim.frames())
    ids = {m.frame_id for m in DB.messages}
    own = [m for m in frames if m.arbitration_id in ids]
    filler = [m for m in frames if m.arbitration_id not in ids]
    expected_own = 5.0 * (6 * 100 + 10)
    assert 0.75 * expected_own < len(own) < 0.85 * expected_own
    assert 0.75 * 2000 < len(filler) < 0.85 * 2000
    assert len({m.arbitration_id for m in filler}) == 4
    assert all(m.arbitration_id < 0x800 and len(m.data) == 8 for m in filler)
    ts = [m.timestamp for m in frames]
    assert ts == sorted(ts)
    gaps = 0
    last = {}
    for m in own:
        if m.arbitration_id == 0x1F0:
            continue
        c = DB.decode_message(m.arbitration_id, m.data)["COUNTER"]
        if m.arbitration_id in last and c != (last[m.arbitration_id] + 1) % 16:
            gaps += 1
        last[m.arbitration_id] = c
    assert gaps > 100  # a receiver can see the loss
    with pytest.raises(ConfigError):
        Simulation(PAPER, "stage1", drop_rate=1.5)


# -- other formats -----------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".asc", ".blf", ".csv", ".trc"])
def test_other_suffixes_go_through_can_logger(tmp_path, suffix):
    frames = list(simulate(PAPER, "stage2", seed=1, duration=0.5)[0])
    out = tmp_path / f"drive{suffix}"
    assert write_log(iter(frames), out) == len(frames)
    back = list(can.LogReader(str(out)))
    assert [(m.arbitration_id, bytes(m.data)) for m in back] == [(m.arbitration_id, bytes(m.data)) for m in frames]


def test_truth_path():
    assert truth_path("out/drive.log") == Path("out/drive.truth.json")
    assert truth_path("drive.log.gz") == Path("drive.truth.json")
    assert truth_path("x.blf") == Path("x.truth.json")


# -- another car's profile and DBC ---------------------------------------------------------
OTHER_DBC = """VERSION ""

NS_ :

BS_:

BU_: ECU

BO_ 1024 WHEELS: 8 ECU
 SG_ WS_FL : 7|16@0+ (0.01,0) [0|300] "km/h" ECU
 SG_ WS_FR : 23|16@0+ (0.01,0) [0|300] "km/h" ECU
 SG_ WS_RL : 39|16@0+ (0.01,0) [0|300] "km/h" ECU
 SG_ WS_RR : 55|16@0+ (0.01,0) [0|300] "km/h" ECU

BO_ 1025 DRIVE: 8 ECU
 SG_ TQ_F : 0|15@1+ (1,0) [0|30000] "Nm" ECU
 SG_ TQ_F_NEG : 15|1@1+ (1,0) [0|1] "" ECU
 SG_ TQ_R : 16|15@1+ (1,0) [0|30000] "Nm" ECU
 SG_ TQ_R_NEG : 31|1@1+ (1,0) [0|1] "" ECU
 SG_ ALIVE : 48|4@1+ (1,0) [0|15] "" ECU
 SG_ CRC : 56|8@1+ (1,0) [0|255] "" ECU

BO_ 1026 CHASSIS: 8 ECU
 SG_ ROAD_ANGLE : 0|16@1- (0.0001,0) [-1|1] "rad" ECU
 SG_ AX_G : 16|16@1- (0.0001,0) [-3|3] "g" ECU
 SG_ AY_HALF : 32|16@1- (0.001,0) [-20|20] "" ECU
 SG_ SPARE : 48|8@1+ (1,5) [10|200] "" ECU

BO_ 1027 RATES: 8 ECU
 SG_ YAW : 0|16@1- (0.0001,0) [-3|3] "rad/s" ECU
 SG_ ROLL_RAW : 16|16@1- (0.01,0) [-200|200] "deg/s" ECU

BO_ %(gnss_id)d GNSS: 8 ECU
 SG_ SPEED_KMH : 0|16@1+ (0.01,0) [0|300] "km/h" ECU

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 10000;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "GenMsgCycleTime" BO_ 1024 20;
BA_ "GenMsgCycleTime" BO_ 1025 10;
BA_ "GenMsgCycleTime" BO_ 1026 10;
BA_ "GenMsgCycleTime" BO_ 1027 30;
BA_ "GenMsgCycleTime" BO_ %(gnss_id)d 100;
"""

OTHER_PROFILE = """
[vehicle]
name = "other"
mass = 1600.0
wheelbase = 2.5
wheel_radius = 0.3
wheel_inertia = 0.6
roll_stiffness_per_deg = 36000.0
roll_damping_per_deg = 5737.0
steering_ratio = 15.0
track = 1.53

[priors]
l_f     = { value = 1.25,    std = 0.3 }
h       = { value = 0.55,    std = 0.2 }
C_K     = { value = 8.0,     std = 4.0 }
C_alpha = { value = 50000.0, std = 25000.0 }
I_z     = { value = 2500.0,  std = 1200.0 }
I_x     = { value = 3000.0,  std = 1500.0 }

[can]
dbc = "other.dbc"
channel = "can1"

[channels]
wheel_speed_fl     = { message = "WHEELS", signal = "WS_FL", unit = "km/h" }
wheel_speed_fr     = { message = "WHEELS", signal = "WS_FR", unit = "km/h" }
wheel_speed_rl     = { message = "WHEELS", signal = "WS_RL", unit = "km/h" }
wheel_speed_rr     = { message = "WHEELS", signal = "WS_RR", unit = "km/h" }
wheel_torque_front = { message = "DRIVE", signal = "TQ_F", unit = "Nm", sign_signal = "TQ_F_NEG" }
wheel_torque_rear  = { message = "DRIVE", signal = "TQ_R", unit = "Nm", sign_signal = "TQ_R_NEG" }
steering_angle     = { message = "CHASSIS", signal = "ROAD_ANGLE", unit = "rad" }
accel_x            = { message = "CHASSIS", signal = "AX_G", unit = "g", sign = -1 }
accel_y            = { message = "CHASSIS", signal = "AY_HALF", unit = "m/s^2", scale = 2.0 }
yaw_rate           = { message = "RATES", signal = "YAW", unit = "rad/s" }
roll_rate          = { message = "RATES", signal = "ROLL_RAW", unit = "deg/s", offset = 1.5 }
speed              = { message = "GNSS", signal = "SPEED_KMH", unit = "km/h" }

[checks]
DRIVE = { counter = "ALIVE", checksum = "CRC" }
"""

GNSS_ID = 0x18FF0001


@pytest.fixture()
def other_profile(tmp_path):
    (tmp_path / "other.dbc").write_text(OTHER_DBC % {"gnss_id": GNSS_ID | 0x80000000})
    p = tmp_path / "other.toml"
    p.write_text(OTHER_PROFILE)
    return p


def test_encodes_into_another_cars_dbc(other_profile, tmp_path):
    prof = load_profile(other_profile)
    db = cantools.database.load_file(str(prof.dbc))
    sim, frames, taps = run_tapped(other_profile, "paper", duration=20.0, noise="none")
    assert sim.truth["bus"]["channel"] == "can1"
    out = tmp_path / "other.log"
    write_log(iter(frames), out)
    back = list(can.LogReader(str(out)))
    assert len(back) == len(taps)
    neg_torque = 0
    for msg, (_t, name, values) in zip(back, taps):
        assert msg.channel == "can1"
        dbm = db.get_message_by_frame_id(msg.arbitration_id)
        assert dbm.name == name
        assert msg.is_extended_id == (name == "GNSS")
        decoded = dbm.decode(msg.data)
        if name == "DRIVE":
            assert msg.data[7] == vdp_checksum(msg.arbitration_id, msg.data)
            neg_torque += decoded["TQ_F_NEG"] == 1
        if name == "CHASSIS":
            assert decoded["SPARE"] == 10  # unmapped: 0 clipped into [10|200]
        si = decode_si(prof, db, msg)
        for ch, v in values.items():
            assert abs(si[ch] - v) <= quantum(prof, db, ch), (ch, si[ch], v)
    assert neg_torque > 50  # braking went through the sign flag
    periods = sim.truth["bus"]["messages"]
    assert periods["WHEELS"]["period_ms"] == 20 and periods["GNSS"]["period_ms"] == 100
    assert periods["RATES"]["period_ms"] == 30  # not a float multiple of 1 ms: 0.03 / 0.001 != 30
    rates = [m.timestamp for m in back if m.arbitration_id == 1027]
    assert np.allclose(np.diff(rates), 0.030, atol=2e-6)


def test_profile_that_does_not_fit_its_dbc_is_rejected(other_profile):
    text = other_profile.read_text().replace('signal = "YAW"', 'signal = "YAW_RATE"')
    other_profile.write_text(text)
    with pytest.raises(ProfileError, match="YAW_RATE"):
        Simulation(other_profile, "stage1")


def test_dbc_override(other_profile):
    with pytest.raises(ProfileError, match="WHEEL_SPEEDS_FRONT"):
        Simulation(PAPER, "stage1", dbc=other_profile.parent / "other.dbc")
    sim = Simulation(PAPER, "stage1", dbc=ROOT / "dbc" / "vdp.dbc", duration=0.1)
    assert len(list(sim.frames())) == 61


def test_signal_range_respects_bits_and_dbc_limits():
    sig = DB.get_message_by_name("STEERING").get_signal_by_name("STEER_WHEEL_RATE")
    assert signal_range(sig) == (-2000.0, 2000.0)
    sig = DB.get_message_by_name("WHEEL_SPEEDS_FRONT").get_signal_by_name("WHEEL_SPEED_FL")
    assert signal_range(sig) == (0.0, 262.0)


# -- live bus ----------------------------------------------------------------------------
def test_live_virtual_bus_receives_every_frame():
    frames = list(simulate(PAPER, "stage2", seed=4, duration=0.5)[0])
    rx = can.Bus(interface="virtual", channel="vdp-sim-test")
    tx = open_bus("virtual", "vdp-sim-test")
    try:
        assert send_live(iter(frames), tx, speed=0) == len(frames)
        got = []
        while (m := rx.recv(timeout=0.2)) is not None:
            got.append((m.arbitration_id, bytes(m.data)))
    finally:
        tx.shutdown()
        rx.shutdown()
    assert got == [(m.arbitration_id, bytes(m.data)) for m in frames]


# -- CLI ---------------------------------------------------------------------------------
def test_cli_writes_log_and_truth_json(tmp_path, capsys):
    out = tmp_path / "drive.log"
    rc = main(
        [
            "simulate",
            "--scenario",
            "stage1",
            "--seed",
            "3",
            "--noise",
            "realistic",
            "--duration",
            "4",
            "--out",
            str(out),
            "--param",
            "h=0.7",
        ]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "frames" in printed and "drive.truth.json" in printed
    truth = json.loads((tmp_path / "drive.truth.json").read_text())
    assert {"parameters", "vehicle", "scenario", "seed", "noise", "start_time", "segments"} <= set(truth)
    assert set(truth["parameters"]) == {"l_f", "h", "C_K", "C_alpha", "I_z", "I_x"}
    assert truth["parameters"]["h"] == 0.7 and truth["parameters"]["l_f"] == TRUTH["l_f"]
    assert truth["vehicle"]["mass"] == 1600.0 and truth["vehicle"]["wheel_inertia"] == 0.6
    assert truth["vehicle"]["roll_stiffness"] == pytest.approx(36000.0 * 180 / math.pi)
    assert (truth["scenario"], truth["seed"], truth["start_time"]) == ("stage1", 3, START_TIME)
    assert truth["noise"]["model"] == "realistic" and truth["noise"]["sigma"]["accel_x"] == 0.05
    assert truth["segments"] == [
        {"name": "settle", "kind": "other", "start": 0.0, "end": 2.0},
        {"name": "stage1", "kind": "stage1", "start": 2.0, "end": 4.0},
    ]
    assert truth["duration"] == 4.0
    back = list(can.LogReader(str(out)))
    assert back[-1].timestamp < START_TIME + 4.0 and len(back) == 4 * 600 + 40


def test_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["simulate", "--scenario", "stage1", "--out", str(tmp_path / "x.log"), "--param", "m=3"]) == 2
    assert "unknown parameter 'm'" in capsys.readouterr().err
    assert main(["simulate", "--scenario", "stage1"]) == 2
    assert "--out" in capsys.readouterr().err
    assert main(["simulate", "--profile", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "x.log")]) == 2


def test_default_profile_is_found_from_anywhere(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_profile().resolve() == PAPER.resolve()
    assert resolve_profile("profiles/paper.toml").resolve() == PAPER.resolve()
    with pytest.raises(ProfileError):
        resolve_profile("profiles/none.toml")
