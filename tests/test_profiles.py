"""The shipped real-car profiles: their DBCs from opendbc, what they can run, and the
simulator driving each car's own layout (scaling, quantisation, sign bits, counters).

Real buses lack per-axle torque, a roll-rate gyro and GNSS speed.  To exercise both
stages on a car's layout, ``vdp.sim.addons.with_addons`` adds vdp's own torque, roll-rate
and GNSS messages (dbc/vdp.dbc, as a second DBC of the bus), as a retrofitted sensor box would.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import tempfile
from pathlib import Path

import cantools
import pytest

from conftest import REAL
from helpers.sim import Frames
from vdp import channels
from vdp.cli import main
from vdp.core.estimator import EstimatorConfig
from vdp.io.decoder import FrameDecoder
from vdp.pipeline import Pipeline
from vdp.profile import ChannelMap, Profile, load_profile
from vdp.replay import replay
from vdp.result import RunResult
from vdp.sim.addons import CAR_TRUTH, with_addons
from vdp.sim.run import Simulation

pytest.importorskip("opendbc", reason="the car profiles read their DBCs from the opendbc extra")

ROOT = Path(__file__).resolve().parents[1]
PROFILES = ROOT / "profiles"
CARS = ("toyota_rav4", "vw_golf_mk7", "hyundai_elantra_2017")
SHARED_TOYOTA_DBC = REAL / "toyota_new_mc_pt_generated.dbc"
UNMAPPED = {"wheel_torque_front", "wheel_torque_rear", "roll_rate", "speed"}

# opendbc gives Toyota's KINEMATICS signals [0|65535], a range their bits cannot carry;
# sim/encode.py, like the decoder, then takes the bits' own range, so negative yaw rates
# and accelerations survive the round trip.


@pytest.fixture(scope="module", autouse=True)
def cache_dir(tmp_path_factory):
    """Generated and repaired opendbc DBCs go to a private cache, not ~/.cache; and the
    encoder's "no cycle time" warnings (opendbc's DBCs have none) stay out of the output."""
    d = tmp_path_factory.mktemp("vdp-cache")
    enc_log = logging.getLogger("vdp.sim.encode")
    level = enc_log.level
    enc_log.setLevel(logging.ERROR)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("VDP_CACHE_DIR", str(d))
        yield d
    enc_log.setLevel(level)


def car(name: str) -> Profile:
    return load_profile(PROFILES / f"{name}.toml")


# -- the profiles and their DBCs -------------------------------------------------------


@pytest.mark.parametrize("name", CARS)
def test_profile_matches_its_dbc_and_lacks_what_real_buses_lack(name):
    prof = car(name)
    assert prof.dbc.is_file() and prof.bus_channel == "can0"
    FrameDecoder(prof)  # validates every message, signal, sign signal and check
    assert set(channels.NAMES) - set(channels.STATUS) - set(prof.channels) == UNMAPPED  # (status flags: optional)
    # every mapped message is sent by the simulator, so the car's layout can be simulated
    assert {p.name for p in Simulation(prof, "stage1", duration=0.1).encoder.plans} == {
        m.message for cm in prof.channels.values() for m in (cm, cm.alt) if m is not None
    } | {m for c in prof.composites.values() for m in c.messages}


@pytest.mark.parametrize("name", CARS)
def test_capabilities_say_which_stage_cannot_run_and_why(name):
    cap = Pipeline(car(name)).capabilities()
    # the Golf makes its axle torques from its own signals (engine torque x ratio, brake pressure)
    torque = () if car(name).composites else ("wheel_torque_front", "wheel_torque_rear")
    # no GNSS: a front-driven car with the [drivetrain] has its rear wheels as the speed reference
    speed = () if car(name).speed_reference else ("speed",)
    for ch in (*torque, *speed):
        assert ch in cap["1"]
    if not torque and not speed:
        assert cap["1"] is None and cap["2"] is None  # stage 2 takes stage 1's l_f
    # stage 2 needs no roll-rate gyro nor GNSS (its v_x can be the rear wheels'): what it
    # lacks is l_f, which stage 1 cannot give, unless the profile gives a measured one
    elif car(name).vehicle.l_f is None:
        assert "needs l_f" in cap["2"] and "[vehicle] l_f" in cap["2"]
    else:
        assert cap["2"] is None
    assert "roll_rate" in cap["I_x"] and "I_x is not estimated" in cap["I_x"]


@pytest.mark.skipif(not SHARED_TOYOTA_DBC.is_file(), reason=f"no shared Toyota DBC at {SHARED_TOYOTA_DBC}")
def test_toyota_dbc_is_generated_from_opendbc_sources(cache_dir):
    prof = car("toyota_rav4")
    # the DBC opendbc generates, byte for byte the one beside the real drive
    assert prof.dbc.parent.parent == cache_dir
    assert prof.dbc.read_bytes() == SHARED_TOYOTA_DBC.read_bytes()


def test_stale_cached_dbc_is_rewritten():
    first = car("toyota_rav4").dbc
    good = first.read_bytes()
    first.write_text("BO_ broken\n")
    assert car("toyota_rav4").dbc == first and first.read_bytes() == good


def test_unwritable_cache_falls_back_to_the_temp_dir(monkeypatch, tmp_path):
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("")
    monkeypatch.setenv("VDP_CACHE_DIR", str(blocker / "cache"))  # a file where a directory must go
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    dbc = car("toyota_rav4").dbc
    assert tmp_path / "tmp" in dbc.parents and dbc.is_file()


def test_hyundai_dbc_is_a_repaired_copy(cache_dir):
    import opendbc

    shipped = Path(opendbc.__file__).parent / "dbc" / "hyundai_kia_generic.dbc"
    with pytest.raises(Exception, match="Invalid syntax"):
        cantools.database.load_file(str(shipped), strict=False)  # why the copy exists
    prof = car("hyundai_elantra_2017")
    assert prof.dbc.parent.parent == cache_dir
    old, new = shipped.read_text().splitlines(), prof.dbc.read_text().splitlines()
    changed = [(a, b) for a, b in zip(old, new) if a != b]
    assert len(old) == len(new) and len(changed) == 2  # only the two bare message comments
    assert all(b == a.replace("CM_ ", "CM_ BO_ ", 1) for a, b in changed)


def test_vw_uses_the_shipped_dbc():
    import opendbc

    assert car("vw_golf_mk7").dbc == Path(opendbc.__file__).parent / "dbc" / "vw_mqb.dbc"


# -- simulating into a car's layout ----------------------------------------------------


def mapped_ids(prof: Profile) -> set[int]:
    db = cantools.database.load_file(str(prof.dbc), strict=False)
    names = {m.message for cm in prof.channels.values() for m in (cm, cm.alt) if m is not None}
    names |= {m for c in prof.composites.values() for m in c.messages}
    return {db.get_message_by_name(n).frame_id for n in names}


@pytest.mark.parametrize("name", CARS)
def test_simulate_cli_writes_the_cars_layout_and_replay_explains(name, tmp_path, capsys):
    prof = car(name)
    out = tmp_path / "drive.log"
    assert (
        main(
            [
                "simulate",
                "--profile",
                str(prof.path),
                "--scenario",
                "paper",
                "--duration",
                "3",
                "--seed",
                "1",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    truth = json.loads((tmp_path / "drive.truth.json").read_text())
    # the truth vehicle is the car's, so the estimator and the simulator share its constants
    assert truth["vehicle"] == dataclasses.asdict(prof.vehicle)
    db = cantools.database.load_file(str(prof.dbc), strict=False)
    ids = set()
    for line in out.read_text().splitlines():
        _, chan, frame = line.split()
        fid, data = frame.split("#")
        ids.add(int(fid, 16))
        assert chan == "can0"
        db.decode_message(int(fid, 16), bytes.fromhex(data))  # a valid frame of the car's DBC
    assert ids == mapped_ids(prof)
    capsys.readouterr()
    res_path = tmp_path / "res.json"
    assert main(["replay", str(out), "--profile", str(prof.path), "--json", str(res_path), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "I_x cannot run: " in text and "roll_rate" in text
    res = json.loads(res_path.read_text())
    if prof.composites:  # the Golf: stage 1 from engine torque x the DSG's ratio, brake pressure, rear wheels
        assert "stage 1 cannot run" not in text and res["capabilities"]["1"] is None
        assert res["parameters"]["I_x"]["status"] == "not_run" and not res["parameters"]["I_x"]["valid"]
        return
    assert "stage 1 cannot run: " in text and "wheel_torque_front" in text
    # stage 2 needs l_f: from stage 1, which cannot run, or measured in the profile
    if prof.vehicle.l_f is None:
        assert "stage 2 cannot run: " in text and "l_f" in text
        assert res["capabilities"]["1"] and res["capabilities"]["2"]
    else:
        assert res["capabilities"]["1"] and res["capabilities"]["2"] is None
    assert all(p["status"] == "not_run" and not p["valid"] for p in res["parameters"].values())
    assert res["log"]["decode"]["samples"]["steering_angle"] > 250  # decoded, just not usable


def si_step(prof: Profile, db, cm: ChannelMap) -> float:
    """One DBC step of a mapped signal (of its fine part, if split), in canonical SI units."""
    sig = db.get_message_by_name(cm.message).get_signal_by_name(cm.fine or cm.signal)
    return abs(sig.scale * cm.scale * cm.factor(prof.vehicle))


@pytest.mark.parametrize("name", ["toyota_rav4", "vw_golf_mk7", "hyundai_elantra_2017"])
def test_round_trip_has_the_cars_quantisation_and_signs(name):
    """Every decoded value lies within half of the car's own DBC step of what was sent."""
    prof = car(name)
    sim = Simulation(prof, "stage2", seed=2, noise="realistic", duration=14.0)
    dec = FrameDecoder(prof)
    sent: dict[str, float] = {}
    worst = dict.fromkeys(prof.channels, 0.0)
    signs = {ch: set() for ch in prof.channels}
    for msg in sim.frames(tap=lambda t, name, values: sent.update(values)):
        for i, v in dec.decode(msg):
            ch = channels.NAMES[i]
            if ch not in prof.channels:
                continue  # a composite (the Golf's axle torques): tests/test_encode_composite.py
            worst[ch] = max(worst[ch], abs(v - sent[ch]))
            signs[ch].add(math.copysign(1.0, v) if abs(v) > 1e-3 else 0.0)
    assert dec.stats.errors == {} and dec.stats.unknown == {}
    for ch, cm in prof.channels.items():
        step = si_step(prof, dec.db, cm)
        assert worst[ch] <= 0.5 * step * (1 + 1e-6), (ch, worst[ch], step)
        assert worst[ch] > 0.05 * step, (ch, "no quantisation seen: is the car's scaling used?")
    # the sawtooth steers both ways: sign bits and flipped signs must carry both
    for ch in ("steering_angle", "yaw_rate", "accel_y"):
        assert {-1.0, 1.0} <= signs[ch], (ch, signs[ch])


def test_vw_counter_gaps_flag_the_steering_channel():
    prof = car("vw_golf_mk7")
    sim = Simulation(prof, "stage2", seed=1, noise="none", duration=3.0)
    dec = FrameDecoder(prof)
    lwi = dec.db.get_message_by_name("LWI_01").frame_id
    n = 0
    for msg in sim.frames():
        if msg.arbitration_id == lwi:
            n += 1
            if n > 100 and n % 2:
                continue  # every other LWI_01 lost: its 4-bit counter jumps by two
        dec.decode(msg)
    kinds = {k for (_, k) in dec.stats.errors}
    assert kinds == {"counter"} and not dec.is_valid("steering_angle") and dec.is_valid("yaw_rate")


def test_hyundai_falls_back_to_the_yaw_rate_sensor_when_esp12_is_silent():
    prof = car("hyundai_elantra_2017")
    sim = Simulation(prof, "stage2", seed=1, noise="none", duration=4.0)
    dec = FrameDecoder(prof)
    esp12 = dec.db.get_message_by_name("ESP12").frame_id
    yrs11 = dec.db.get_message_by_name("YRS11").frame_id
    from_yrs = 0
    for msg in sim.frames():
        if msg.arbitration_id == esp12 and msg.timestamp - sim.start_us / 1e6 > 2.0:
            continue  # the ESC stops sending
        pairs = dec.decode(msg)
        if msg.arbitration_id == yrs11:
            from_yrs += any(i == channels.YAW for i, _ in pairs)
    # YRS11 runs at 100 Hz: about 2 s of it once ESP12 has been silent for 5 cycles
    assert 150 < from_yrs < 200


# -- both stages on a car's layout, with vdp's add-on sensors --------------------------


def run_drive(prof: Profile, scenario: str, seed: int, params=None, duration=None) -> tuple[RunResult, dict]:
    sim = Simulation(prof, scenario, seed=seed, noise="realistic", params=params, duration=duration)
    res = replay(Frames(sim), Pipeline(prof, EstimatorConfig(baseline=False)))
    return res, sim.truth["parameters"]


@pytest.mark.parametrize("name", CARS)
def test_stage1_runs_on_the_cars_layout_with_addons(name, tmp_path):
    prof = with_addons(car(name))
    assert Pipeline(prof).capabilities() == {"1": None, "2": None, "I_x": None}
    res, _ = run_drive(prof, "stage1", seed=4, duration=12.0)
    assert [w.stage for w in res.windows] == [1]
    assert all(res.parameters[p].samples > 250 for p in ("l_f", "h", "C_K"))
    assert res.decode["errors"] == {}


TOLERANCE = {"l_f": 0.01, "h": 0.03, "C_K": 0.02, "C_alpha": 0.03, "I_z": 0.05}  # the estimator issue's
STAGES = {1: ("l_f", "h", "C_K"), 2: ("C_alpha", "I_z")}
_paper_runs: dict[str, tuple[RunResult, dict]] = {}


def paper_run(name: str, tmp_path_factory) -> tuple[RunResult, dict]:
    """The full paper drive on the car's layout, once per car for both stage checks."""
    if name not in _paper_runs:
        _paper_runs[name] = run_drive(with_addons(car(name)), "paper", seed=11, params=CAR_TRUTH[name])
    return _paper_runs[name]


@pytest.mark.slow
@pytest.mark.parametrize(
    "name,stage",
    [
        ("toyota_rav4", 1),
        ("toyota_rav4", 2),
        ("vw_golf_mk7", 1),
        ("vw_golf_mk7", 2),
        ("hyundai_elantra_2017", 1),
        ("hyundai_elantra_2017", 2),
    ],
)
def test_paper_drive_converges_on_the_cars_layout(name, stage, tmp_path_factory):
    res, truth = paper_run(name, tmp_path_factory)
    if name == "toyota_rav4":
        # The sensor's resolution is STEER_ANGLE (1.5 deg steps) plus STEER_FRACTION, as
        # openpilot reads it; the profile must say so (decoding is tested above).
        assert car(name).channels["steering_angle"].fine == "STEER_FRACTION"
    for p in STAGES[stage]:
        est = res.parameters[p]
        if name == "toyota_rav4" and stage == 2 and not est.valid:
            # stage 2 takes the profile's l_f, 1.17 +- 0.08 m (truth 1.20), and carries that 7 % std:
            # per axle, C_alpha's mean is not pinned to 3 % (-4.5 %, std 6.5 %; BENCHMARKS.md, "Models vdp
            # did not write"); it must then say so, with the truth inside its 2 std
            assert est.status != "converged" and abs(est.value - truth[p]) <= 2.0 * est.std, (p, est, truth[p])
            continue
        assert est.value == pytest.approx(truth[p], rel=TOLERANCE[p]), (p, est, truth[p])
        # And not by luck: the filter's own std is inside the tolerance.  Not half of it, which
        # is what "converged" asks (params.py): the RAV4, heavier and stiffer, gets a C_alpha
        # std of about 2 % of its value from this drive on any bus layout, the paper's
        # included, and so says "uncertain", as it should.
        assert est.status in ("converged", "uncertain") and est.std < TOLERANCE[p] * truth[p], (p, est)


def test_a_copied_profile_whose_dbc_is_not_beside_it_says_where_its_dbc_is_read_from(tmp_path):
    """`cp profiles/paper.toml my.toml` elsewhere keeps `dbc = "../dbc/vdp.dbc"`: the error names the
    folder the path is read from and the fix, not only the path it did not find."""
    from vdp.errors import ProfileError

    mine = tmp_path / "my.toml"
    mine.write_text((ROOT / "profiles" / "paper.toml").read_text())
    with pytest.raises(
        ProfileError, match=r"does not exist \(.* is read from the profile's own folder, .*absolute one\)"
    ):
        load_profile(mine)
