"""More opendbc cars with production layouts: Ford's total drive and brake torque, whole-mph
GPS at 1 Hz and quality flags; VW's brake pressure without a drive torque; Hyundai's CAN-FD."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from vdp import channels
from vdp.io.decoder import FrameDecoder
from vdp.pipeline import Pipeline
from vdp.profile import load_profile
from vdp.sim.run import Simulation

pytest.importorskip("opendbc", reason="the car profiles read their DBCs from the opendbc extra")

ROOT = Path(__file__).resolve().parents[1]
FORD = ROOT / "profiles" / "ford_escape_2020.toml"


@pytest.fixture(autouse=True)
def quiet(tmp_path, monkeypatch):
    monkeypatch.setenv("VDP_CACHE_DIR", str(tmp_path / "cache"))
    logging.getLogger("vdp.sim.encode").setLevel(logging.ERROR)


def test_ford_runs_both_stages_from_its_own_signals():
    prof = load_profile(FORD)
    assert Pipeline(prof).capabilities() == {"1": None, "2": None, "I_x": None}
    assert set(prof.composites) == {"wheel_torque_front", "wheel_torque_rear"}
    assert prof.drivetrain.driven == "front" and prof.speed_reference == "gnss"


def test_ford_layout_round_trips_with_1_hz_whole_mph_gps():
    prof = load_profile(FORD)
    sim = Simulation(prof, "paper", seed=1, duration=12.0)
    pipe = Pipeline(prof)
    gps = 0
    gps_id = pipe.decoder.db.get_message_by_name("APIMGPS_Data_Nav_3_FD1").frame_id
    for msg in sim.frames():
        gps += msg.arbitration_id == gps_id
        pipe.feed(msg)
    st = pipe.decoder.stats.as_dict()
    assert st["errors"] == {} and st["invalid_samples"] == {}
    assert gps == 12  # once a second, as the profile's cycle_ms says
    assert st["samples"]["speed"] == 12 and st["samples"]["wheel_torque_front"] > 1000
    # whole mph: the speed filter carries the rounding (0.447 m/s steps) as a state of its own
    assert pipe.estimator.cfg.speed.gnss_step == pytest.approx(0.44704)


def test_ford_quality_flags_keep_bad_samples_out():
    prof = load_profile(FORD)
    sim = Simulation(prof, "stage2", seed=1, duration=2.0, noise="none")
    dec = FrameDecoder(prof)
    msg_def = dec.db.get_message_by_name("Yaw_Data_FD1")
    bad = 0
    yaw = []
    for msg in sim.frames():
        if msg.arbitration_id == msg_def.frame_id and bad < 30:
            vals = msg_def.decode(msg.data, decode_choices=False)
            vals.update(VehYawWActl_D_Qf=0, VehYaw_W_Actl=6.6)  # "Faulty", saturated
            msg.data = bytearray(msg_def.encode(vals))
            bad += 1
        yaw += [v for i, v in dec.decode(msg) if i == channels.YAW]
    assert dec.stats.as_dict()["invalid_samples"] == {"yaw_rate": {"status VehYawWActl_D_Qf=0": 30}}
    assert max(abs(v) for v in yaw) < 1.0


def test_vw_makes_its_drive_torque_or_names_exactly_that_it_lacks(tmp_path):
    golf = ROOT / "profiles" / "vw_golf_mk7.toml"
    prof = load_profile(golf)  # a DSG Golf: engine torque x the gearbox's ratio
    assert set(prof.sources) == {"drive_torque", "brake_pressure"} and Pipeline(prof).capabilities()["1"] is None
    assert [f.signal for f in prof.composites["wheel_torque_front"].terms[0].factors] == ["GE_Uefkt"]
    # a manual Golf sends no Getriebe_11: without the drive torque, stage 1 names exactly that
    text = golf.read_text()
    manual = tmp_path / "golf_manual.toml"
    manual.write_text(text[: text.index("[channels.drive_torque]")] + text[text.index("[checks]") :])
    prof = load_profile(manual)
    assert "brake_pressure" in prof.sources and not prof.composites
    cap = Pipeline(prof).capabilities()
    assert cap["1"] == "no drive torque at the wheels (the profile maps no drive_torque)"


def test_canfd_car_names_what_it_lacks():
    cap = Pipeline(load_profile(ROOT / "profiles" / "hyundai_ioniq5_2022.toml")).capabilities()
    assert "wheel_torque_front" in cap["1"] and "speed" in cap["1"] and "roll_rate" in cap["I_x"]
    assert "needs l_f" in cap["2"]  # stage 2 needs no GNSS nor roll rate: l_f, which stage 1 cannot give


def test_profile_new_drafts_the_ford_profile_from_its_dbc_and_a_log(tmp_path, capsys):
    import opendbc

    from vdp.cli import main
    from vdp.sim.run import write_log

    dbc = Path(opendbc.__file__).parent / "dbc" / "ford_lincoln_base_pt.dbc"
    log = tmp_path / "ford.log"
    write_log(Simulation(load_profile(FORD), "paper", seed=2, duration=40.0).frames(), log)
    out = tmp_path / "draft.toml"
    assert main(["profile", "new", "--dbc", str(dbc), "--log", str(log), "--out", str(out)]) == 0
    draft = load_profile(out)  # a valid profile as written
    got = {ch: (cm.message, cm.signal) for ch, cm in draft.channels.items()}
    assert got["wheel_speed_rl"] == ("WheelSpeed", "WhlRl_W_Meas")
    assert got["yaw_rate"] == ("Yaw_Data_FD1", "VehYaw_W_Actl")  # by behaviour: it follows steering x speed
    assert got["accel_x"] == ("Accel_Data_FD1", "VehLong2_A_Actl")  # the other candidates are not in the log
    assert draft.sources["drive_torque"].signal == "PrplWhlTot2_Tq_Actl"
    assert draft.sources["brake_torque"].signal == "BrkTot_Tq_Actl"
    assert "follows the wheel speeds" in out.read_text() and "EDIT" in out.read_text()
    capsys.readouterr()
    # the check validates the draft: its placeholders (wheel radius 0.31 m for 0.35 m, mass) show
    assert main(["profile", "check", str(log), "--profile", str(out)]) == 1
    assert "wheel_radius" in capsys.readouterr().out


def test_hyundai_start_up_saturation_never_reaches_the_estimator():
    """A Kona EV's ESC and steering sensor send their ranges' ends while they start up."""
    prof = load_profile(ROOT / "profiles" / "hyundai_elantra_2017.toml")
    sim = Simulation(prof, "stage2", seed=1, duration=2.0, noise="none")
    pipe = Pipeline(prof)
    esp = pipe.decoder.db.get_message_by_name("ESP12")
    sas = pipe.decoder.db.get_message_by_name("SAS11")
    n_esp = n_sas = 0
    for msg in sim.frames():
        if msg.timestamp - sim.start_us / 1e6 < 0.5:  # the first half second: starting up
            for m, sat in (
                (esp, {"YAW_RATE": 40.96, "LAT_ACCEL": -10.23, "LONG_ACCEL": 10.24}),
                (sas, {"SAS_Angle": 3276.7}),
            ):
                if msg.arbitration_id == m.frame_id:
                    vals = m.decode(msg.data, decode_choices=False) | sat
                    msg.data = bytearray(m.encode(vals))
                    n_esp += m is esp
                    n_sas += m is sas
        pipe.feed(msg)
    bad = pipe.decoder.stats.as_dict()["invalid_samples"]
    assert n_esp > 10 and n_sas > 10
    assert bad == {
        "yaw_rate": {"implausible": n_esp},
        "accel_x": {"implausible": n_esp},
        "accel_y": {"implausible": n_esp},
        "steering_angle": {"implausible": n_sas},
    }
    _, ys = pipe.ring.latest()
    for idx, lim in ((channels.YAW, 0.71), (channels.AX, 10.0), (channels.AY, 10.0), (channels.DELTA, 1.0)):
        col = ys[:, idx]
        assert abs(col[col == col]).max() < lim


def tiny_dbc(tmp_path, body: str):
    """(path, cantools database) of a DBC of the given messages, one node ECU."""
    import cantools

    dbc = tmp_path / "car.dbc"
    dbc.write_text('VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_: ECU\n\n' + body)
    return dbc, cantools.database.load_file(str(dbc))


def test_profile_new_does_not_map_an_engine_torque_as_the_wheels(tmp_path):
    """A torque named for the engine (Toyota's GAS_PEDAL.ETQLVSC, VW's MO_Mom_Ist_Summe, Hyundai's
    TQI_ACOR) is taken before the gearbox: mapped as drive_torque, stage 1 read the gear ratio as
    the car's mass (l_f 2.35 m on a 2.65 m wheelbase, a new user's RAV4). The draft names it and
    leaves it unmapped; a signal whose unit is of another quantity is not mapped either."""

    from vdp.scaffold import candidates, draft

    dbc, db = tiny_dbc(
        tmp_path,
        "BO_ 100 GAS_PEDAL: 8 ECU\n"
        ' SG_ ETQLVSC : 0|16@1- (1,0) [-500|500] "Nm" ECU\n\n'
        "BO_ 101 TORQUE_SENSOR: 8 ECU\n"
        ' SG_ TQ_ANGLE : 0|16@1- (0.1,0) [-500|500] "deg" ECU\n\n'
        "BO_ 102 STEER_TORQUE_SENSOR: 8 ECU\n"
        ' SG_ STEER_ANGLE : 0|16@1- (0.1,0) [-500|500] "deg" ECU\n',
    )
    cands = candidates(db)
    got = {c.signal: c for c in cands["drive_torque"]}
    assert got["ETQLVSC"].engine and not got["TQ_ANGLE"].engine and got["TQ_ANGLE"].wrong_kind
    assert "STEER_ANGLE" not in got  # a steering angle by its own name: the steering's, not a torque
    text = draft(dbc, cands)
    mapped = [ln for ln in text.splitlines() if ln.startswith("drive_torque")]
    assert mapped == []  # nothing mapped as the wheels' torque
    assert "# drive_torque = " in text and ("times the gear ratio" in text or "not one of a drive_torque" in text)
    import tomllib

    assert "drive_torque" not in tomllib.loads(text).get("channels", {})  # valid TOML, the line commented


def test_the_check_says_a_mass_several_times_too_small_is_a_torque_before_the_gearbox(tmp_path):
    """An engine torque mapped as the wheels' (here the paper car's torques / 6.5): the mass the
    torques imply is 6.5 x too small, and the check names the gearbox first, not the mass."""
    import dataclasses

    from vdp.profilecheck import check_log
    from vdp.sim.run import write_log

    paper = load_profile(Path(__file__).resolve().parents[1] / "profiles" / "paper.toml")
    path = tmp_path / "p.log"
    write_log(Simulation(paper, "paper", seed=2, duration=70.0).frames(), path)
    ch = dict(paper.channels)
    for name in ("wheel_torque_front", "wheel_torque_rear"):
        ch[name] = dataclasses.replace(ch[name], scale=ch[name].scale / 6.5)
    rep, _ = check_log(path, dataclasses.replace(paper, channels=ch))
    f = next(f for f in rep.findings if f.subject == "vehicle.mass")
    assert "before the gearbox" in f.message and "gear ratio" in f.message and "ratio 6." in f.message


def test_profile_new_sets_the_bus_channel_and_pad_short_from_the_log(tmp_path, capsys):
    """A log like the RAV4's: the same ids on a second bus, and frames shorter than the DBC's
    length. The draft picks the channel that carries them and pads short frames, saying why;
    without them a replay decoded the other bus's frames and refused the short ones."""
    from vdp.cli import main
    from vdp.sim.run import write_log

    root = Path(__file__).resolve().parents[1]
    log = tmp_path / "two.log"
    write_log(Simulation(load_profile(root / "profiles" / "paper.toml"), "paper", seed=2, duration=20.0).frames(), log)
    lines = log.read_text().splitlines()
    out = []
    for i, ln in enumerate(lines):
        if i % 50 == 7:  # now and then a short frame: its last byte left off
            ln = ln[:-2]
        out.append(ln)
        if i % 10 == 3:  # and some frames again on a second bus
            out.append(ln.replace(" can0 ", " can1 "))
    log.write_text("\n".join(out) + "\n")
    draft = tmp_path / "d.toml"
    assert main(["profile", "new", "--dbc", str(root / "dbc" / "vdp.dbc"), "--log", str(log), "--out", str(draft)]) == 0
    text = draft.read_text()
    assert 'channel = "can0"' in text and "the log has frames on can0, can1" in text
    assert "pad_short = true" in text and "shorter than the DBC's length" in text
    assert load_profile(draft).bus_channel == "can0"
    capsys.readouterr()
    # a message that comes only on the other bus: no channel filter, which would drop it
    split = tmp_path / "split.log"
    split.write_text("".join(ln.replace(" can0 ", " can1 ") + "\n" if " 0B1#" in ln else ln + "\n" for ln in lines))
    other = tmp_path / "s.toml"
    assert (
        main(["profile", "new", "--dbc", str(root / "dbc" / "vdp.dbc"), "--log", str(split), "--out", str(other)]) == 0
    )
    assert "channel =" not in other.read_text() and load_profile(other).bus_channel is None
    capsys.readouterr()
    # and a replay without pad_short says on the console which frames it refused, and what to set
    assert main(["replay", str(log), "--profile", str(root / "profiles" / "paper.toml"), "--no-progress"]) == 0
    said = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("decoder: ")]
    assert any("refused: shorter than the DBC says" in ln and "pad_short = true" in ln for ln in said), said
    assert any("another bus (set [can] channel)" in ln for ln in said), said  # can1's frames among can0's


def test_profile_new_completes_a_coarse_signal_with_its_fine_part(tmp_path):
    """Toyota's steering angle is STEER_ANGLE in 1.5 deg steps plus STEER_FRACTION (-0.7...0.7 deg
    in 0.1 deg) of the same message: the draft names the finer part (`fine`), as the shipped RAV4
    profile does; a signal of another unit, or one spanning more than a step, is not taken."""

    from vdp.scaffold import candidates, draft

    dbc, db = tiny_dbc(
        tmp_path,
        "BO_ 37 STEER_ANGLE_SENSOR: 8 ECU\n"
        ' SG_ STEER_ANGLE : 3|12@0- (1.5,0) [-500|500] "deg" ECU\n'
        ' SG_ STEER_FRACTION : 39|4@0- (0.1,0) [-0.7|0.7] "deg" ECU\n'
        ' SG_ STEER_RATE : 35|12@0- (1,0) [-2000|2000] "deg/s" ECU\n\n'
        "BO_ 40 NARROW: 8 ECU\n"
        ' SG_ STEER_ANGLE_N : 3|12@0- (1.5,0) [-500|500] "deg" ECU\n'
        ' SG_ STEER_FRACTION_N : 39|4@0- (0.1,0) [-0.3|0.3] "deg" ECU\n\n'
        "BO_ 39 BODY_CONTROL_STATE_2: 8 ECU\n"
        ' SG_ UI_SPEED : 0|16@1+ (1,0) [0|300] "" ECU\n\n'
        "BO_ 38 OTHER_ANGLE: 8 ECU\n"
        ' SG_ STEER_ANGLE_WHEEL : 0|16@1- (0.5,0) [-500|500] "deg" ECU\n'
        ' SG_ STEER_OFFSET : 16|8@1- (0.1,0) [-12|12] "deg" ECU\n',
    )
    cands = candidates(db)
    by = {c.signal: c for c in cands["steering_angle"]}
    assert by["STEER_ANGLE"].fine == "STEER_FRACTION"
    assert by["STEER_ANGLE_N"].fine is None  # -0.3...0.3 in 0.1 leaves gaps in 1.5-deg steps (the decoder says so)
    assert by["STEER_ANGLE_WHEEL"].fine is None  # its 0.1-deg neighbour spans 24 deg, not one 0.5-deg step
    from vdp.scaffold import _PATTERNS

    roll = _PATTERNS["roll_rate"][0][0]  # Ford's VehRol_W_Actl, not CONTROL, sCROLL or ROLLing
    import re

    hits = {
        n: bool(re.search(roll, n))
        for n in ("vehrol_w_actl", "imu.roll_rate", "ui_scroll", "wheel_rolling", "x.control")
    }
    assert hits == {
        "vehrol_w_actl": True,
        "imu.roll_rate": True,
        "ui_scroll": False,
        "wheel_rolling": False,
        "x.control": False,
    }
    assert cands["roll_rate"] == []  # no signal named for a roll: "CONTROL" in a name is not one
    cands["steering_angle"] = [by["STEER_ANGLE"]]  # (the draft maps its best: that one here)
    text = draft(dbc, cands)
    line = next(ln for ln in text.splitlines() if ln.startswith("steering_angle"))
    assert 'signal = "STEER_ANGLE"' in line and 'fine = "STEER_FRACTION"' in line
    # and the profile's loader takes the pair (io.signals.check_fine) in a draft that maps it
    prof = tmp_path / "d.toml"
    prof.write_text(text.replace('"EDIT"', '"deg"'))
    assert load_profile(prof).channels["steering_angle"].fine == "STEER_FRACTION"


def test_the_log_facts_count_only_what_the_draft_maps(tmp_path):
    """A car with per-axle wheel torques: the draft leaves the brake source out, so a brake
    message's short frames on another bus neither set pad_short nor keep [can] channel away."""

    from vdp.scaffold import behaviour, candidates, draft

    dbc, db = tiny_dbc(
        tmp_path,
        "BO_ 100 AXLE_TQ: 4 ECU\n"
        ' SG_ TQ_FRONT_AXLE : 0|16@1- (1,0) [-5000|5000] "Nm" ECU\n'
        ' SG_ TQ_REAR_AXLE : 16|16@1- (1,0) [-5000|5000] "Nm" ECU\n\n'
        "BO_ 101 BRAKE: 8 ECU\n"
        ' SG_ BRAKE_TQ_ACTL : 0|16@1- (1,0) [-5000|5000] "Nm" ECU\n',
    )
    lines = []
    for i in range(400):
        t = 1700000000.0 + 0.01 * i
        tq = (i % 50) * 10
        lines.append(f"({t:.6f}) can0 064#{tq:04X}{tq:04X}")  # both axles, full length, on can0
        lines.append(f"({t + 0.001:.6f}) can1 065#{tq:04X}")  # the brake: short, and on can1 only
    log = tmp_path / "l.log"
    log.write_text("\n".join(lines) + "\n")
    cands = candidates(db)
    assert cands["wheel_torque_front"] and cands["brake_torque"]
    facts = behaviour(db, cands, log)
    assert facts.channel == "can0" and facts.short == {}
    text = draft(dbc, cands, facts=facts)
    assert 'channel = "can0"' in text and "pad_short" not in text and "brake_torque =" not in text


def test_profile_new_takes_an_opendbc_name_and_the_draft_names_it_so(tmp_path, capsys):
    """`vdp profile new --dbc opendbc:NAME` had said "no such file"; the draft's [can] dbc is the
    same opendbc:NAME a profile uses (not the installed package's path), and loads."""
    from vdp.cli import main

    out = tmp_path / "draft.toml"
    assert main(["profile", "new", "--dbc", "opendbc:ford_lincoln_base_pt", "--out", str(out)]) == 0
    assert 'dbc = "opendbc:ford_lincoln_base_pt"' in out.read_text().splitlines()
    assert load_profile(out).dbc.name == "ford_lincoln_base_pt.dbc"
    assert main(["profile", "new", "--dbc", "opendbc:ford_lincoln_base_ptt", "--out", str(out)]) == 2
    assert "similar: ford_lincoln_base_pt" in capsys.readouterr().err


def test_profile_new_never_proposes_counters_checks_status_or_signals_that_never_move(tmp_path):
    """Signals that are no measurement (a message counter, a validity or quality byte, a speed
    limit, the steering's torque as a drive torque, a status with a value table) are never
    candidates; with a log, neither is one that never moves; a signed, centred angle beats an
    unsigned one, a torque that moves with dv/dt one that does not, and a pressure in kPa and a
    torque in per cent are found."""
    import numpy as np

    from vdp.scaffold import behaviour, candidates, draft

    dbc, db = tiny_dbc(
        tmp_path,
        "BO_ 100 WHEELS: 8 ECU\n"
        ' SG_ WHL_SPD_FL : 0|16@1+ (0.01,0) [0|300] "km/h" ECU\n'
        ' SG_ WHL_SPD_FR : 16|16@1+ (0.01,0) [0|300] "km/h" ECU\n'
        ' SG_ WHL_FL_MsgCount : 32|8@1+ (1,0) [0|255] "km/h" ECU\n'
        ' SG_ WHL_FL_Valid : 40|8@1+ (1,0) [0|255] "km/h" ECU\n'
        ' SG_ WHL_FR_Qual : 48|8@1+ (1,0) [0|255] "km/h" ECU\n\n'
        "BO_ 101 STEERING: 8 ECU\n"
        ' SG_ STEER_ANG_SIGNED : 0|16@1- (0.1,0) [-3000|3000] "deg" ECU\n'
        ' SG_ STEER_ANG_MAG : 16|16@1+ (0.1,0) [0|6000] "deg" ECU\n'
        ' SG_ STEER_ANG_SPARE : 32|16@1- (0.1,0) [-3000|3000] "deg" ECU\n'
        ' SG_ STEER_ANG_MODE : 48|8@1+ (1,0) [0|255] "deg" ECU\n\n'
        "BO_ 102 POWER: 8 ECU\n"
        ' SG_ DRIVE_TQ : 0|16@1- (1,0) [-5000|5000] "Nm" ECU\n'
        ' SG_ WHL_TQ_TOT : 16|16@1- (1,0) [-5000|5000] "Nm" ECU\n'
        ' SG_ MDPS_StrTq : 32|16@1- (1,0) [-5000|5000] "Nm" ECU\n'
        ' SG_ ENG_TQ_PCT : 48|8@1+ (0.5,0) [0|100] "%" ECU\n\n'
        "BO_ 103 BRAKE: 8 ECU\n"
        ' SG_ BRAKE_PRES : 0|16@1+ (1,0) [0|20000] "kPa" ECU\n\n'
        "BO_ 104 NAV: 8 ECU\n"
        ' SG_ NAV_SpeedLim : 0|16@1+ (0.01,0) [0|300] "km/h" ECU\n'
        ' SG_ GPS_SPEED : 16|16@1+ (0.01,0) [0|300] "km/h" ECU\n\n'
        'VAL_ 101 STEER_ANG_MODE 0 "off" 1 "on" ;\n',
    )
    cands = candidates(db, top=10)
    named = {ch: {c.signal for c in cs} for ch, cs in cands.items()}
    assert named["wheel_speed_fl"] == {"WHL_SPD_FL"} and named["wheel_speed_fr"] == {"WHL_SPD_FR"}
    assert "STEER_ANG_MODE" not in named["steering_angle"] and named["speed"] == {"GPS_SPEED"}
    assert "MDPS_StrTq" not in named["drive_torque"] and named["brake_pressure"] == {"BRAKE_PRES"}
    pct = next(c for c in cands["drive_torque"] if c.signal == "ENG_TQ_PCT")
    assert pct.percent and not pct.wrong_kind and not pct.mapped

    rng = np.random.default_rng(1)
    t = np.arange(0, 60, 0.02)
    v = 12 + 5 * np.sin(2 * np.pi * t / 15)  # m/s: speeding up and slowing down
    a = np.gradient(v, t)
    lines = []
    msgs = {m.name: m for m in db.messages}
    for i, ti in enumerate(t):
        vals = {
            "WHEELS": {"WHL_SPD_FL": v[i] * 3.6, "WHL_SPD_FR": v[i] * 3.6 + 0.02},
            "STEERING": {
                "STEER_ANG_SIGNED": 90 * np.sin(2 * np.pi * ti / 7),
                "STEER_ANG_MAG": abs(90 * np.sin(2 * np.pi * ti / 7)) + 5,
                "STEER_ANG_SPARE": 0,
            },
            "POWER": {"DRIVE_TQ": 1500 * a[i] + 200, "WHL_TQ_TOT": rng.normal(300, 150), "ENG_TQ_PCT": 40},
            "BRAKE": {"BRAKE_PRES": max(-a[i], 0) * 2000},
            "NAV": {"GPS_SPEED": v[i] * 3.6},
        }
        for name, sig in vals.items():
            m = msgs[name]
            full = {s.name: 0 for s in m.signals} | sig
            data = m.encode(full, strict=False).hex().upper()
            lines.append(f"({1700000000 + ti:.6f}) can0 {m.frame_id:03X}#{data}")
    log = tmp_path / "car.log"
    log.write_text("\n".join(lines) + "\n")
    facts = behaviour(db, cands, log)
    assert cands["steering_angle"][0].signal == "STEER_ANG_SIGNED"
    assert "STEER_ANG_SPARE" in " ".join(facts.still["steering_angle"])
    assert all(c.signal != "STEER_ANG_SPARE" for c in cands["steering_angle"])
    assert cands["drive_torque"][0].signal == "DRIVE_TQ" and "moves with dv/dt" in cands["drive_torque"][0].note
    text = draft(dbc, cands, facts=facts)
    assert 'signal = "STEER_ANG_SIGNED"' in text and "never moved in the log, so not proposed" in text
    assert 'brake_pressure = { message = "BRAKE", signal = "BRAKE_PRES", unit = "kPa" }' in text
    import tomllib

    tomllib.loads(text)  # valid TOML


def test_a_brake_pressure_beyond_what_a_brake_system_holds_is_a_finding_with_its_range(tmp_path):
    """The brake pressure read 1000x too high (a unit mistake): the values beyond 300 bar were
    dropped by the plausible range, but nothing said so; now the check names them and their range.
    A profile's own narrower plausible range stays as it was."""
    import re

    from vdp.profilecheck import check_log
    from vdp.sim.run import write_log

    prof = load_profile(ROOT / "profiles" / "hyundai_elantra_2017.toml")
    assert prof.sources["brake_pressure"].plausible == (0.0, 2.5e7)
    golf = load_profile(ROOT / "profiles" / "vw_golf_mk7.toml")  # no plausible range of its own
    assert golf.sources["brake_pressure"].plausible == (-5e5, 3e7)  # -5 to 300 bar
    log = tmp_path / "h.log"
    write_log(Simulation(prof, "stage1", seed=2, duration=40.0).frames(), log)
    assert not any(f.subject == "brake_pressure" for f in check_log(log, prof)[0].findings)
    text = (ROOT / "profiles" / "hyundai_elantra_2017.toml").read_text()
    wrong = tmp_path / "wrong.toml"
    wrong.write_text(
        text.replace('signal = "CYL_PRES", unit = "bar",', 'signal = "CYL_PRES", unit = "bar", scale = 1000.0,')
    )
    rep, _ = check_log(log, load_profile(wrong))
    f = next(f for f in rep.findings if f.subject == "brake_pressure")
    lo, hi = (float(x) for x in re.search(r"seen ([\d.e+]+) to ([\d.e+]+) bar", f.message).groups())
    assert 250 < lo <= hi and "outside 0 to 250 bar" in f.message


def test_profile_new_takes_a_signal_by_its_own_name_and_a_measurement_with_no_value_codes(tmp_path):
    """benchmarks/scaffold.py found these first choices wrong: a front-left wheel speed in a message
    named for the front axle proposed for front right (GM's EBCMWheelSpdFront.FLWheelSpd, Nissan's
    WHEEL_SPEEDS_FRONT.WHEEL_SPEED_FL), the roll rate of a message named for the yaw rate as the yaw
    rate (Ford's Yaw_Data_FD1.VehRol_W_Actl), a brake's torque as the drive torque (VW's
    PLA_Bremsmoment), VW's engine torque MO_Mom_Ist_Summe not found at all, and a GPS speed whose
    value table names only its no-value codes (Ford's 254 Unknown, 255 Invalid) taken for a state; and
    where the profile maps nothing, GM's GPSLongitude as accel_x, Hyundai's traffic-sign speed shown
    on a display as the speed, the Ioniq 5's steering torque as its drive torque."""
    from vdp.scaffold import candidates

    dbc, db = tiny_dbc(
        tmp_path,
        "BO_ 100 WheelSpdFront: 8 ECU\n"
        ' SG_ FLWheelSpd : 0|16@1+ (0.01,0) [0|300] "km/h" ECU\n'
        ' SG_ FRWheelSpd : 16|16@1+ (0.01,0) [0|300] "km/h" ECU\n\n'
        "BO_ 101 Yaw_Data: 8 ECU\n"
        ' SG_ VehYaw_W_Actl : 0|16@1- (0.001,0) [-6|6] "rad/s" ECU\n'
        ' SG_ VehRol_W_Actl : 16|16@1- (0.001,0) [-6|6] "rad/s" ECU\n\n'
        "BO_ 102 Motor_11: 8 ECU\n"
        ' SG_ MO_Mom_Ist_Summe : 0|16@1- (1,0) [-5000|5000] "Nm" ECU\n'
        ' SG_ PLA_Bremsmoment : 16|16@1- (1,0) [-5000|5000] "Nm" ECU\n\n'
        "BO_ 103 GPS_Nav: 8 ECU\n"
        ' SG_ GPS_Speed : 0|8@1+ (1,0) [0|253] "mph" ECU\n'
        ' SG_ GPS_Mode : 8|8@1+ (1,0) [0|255] "mph" ECU\n\n'
        "BO_ 104 GPS_Position: 8 ECU\n"
        ' SG_ GPS_Longitude : 0|32@1- (0.001,0) [-648000000|648000000] "milliarcsecond" ECU\n'
        ' SG_ GPS_Latitude : 32|32@1- (0.001,0) [-324000000|324000000] "milliarcsecond" ECU\n\n'
        "BO_ 105 LKAS12: 8 ECU\n"
        ' SG_ TsrSpeed_Display_Navi : 0|8@1+ (1,0) [0|255] "" ECU\n\n'
        "BO_ 106 MDPS: 8 ECU\n"
        ' SG_ MDPS_StrTqSnsrVal : 0|12@1+ (0.1,-204.8) [-204.8|204.7] "" ECU\n\n'
        'VAL_ 103 GPS_Speed 254 "Unknown" 255 "Invalid" ;\n'
        'VAL_ 103 GPS_Mode 0 "off" 1 "2d" 2 "3d" ;\n',
    )
    named = {ch: [c.signal for c in cs] for ch, cs in candidates(db, top=10).items()}
    assert named["wheel_speed_fl"] == ["FLWheelSpd"] and named["wheel_speed_fr"] == ["FRWheelSpd"]
    assert named["yaw_rate"] == ["VehYaw_W_Actl"] and named["roll_rate"] == ["VehRol_W_Actl"]
    assert named["drive_torque"] == ["MO_Mom_Ist_Summe"] and "PLA_Bremsmoment" in named["brake_torque"]
    assert named["speed"] == ["GPS_Speed"]  # the mode, a state with values in its range, stays out
    # and neither a GPS position (its "lon", "lat"), a speed on a display, nor the steering's torque
    # given no unit (the Ioniq 5's MDPS_StrTqSnsrVal) is proposed at all
    assert named["accel_x"] == [] and named["accel_y"] == []
    assert all("StrTq" not in s for s in named["drive_torque"] + named["brake_torque"])


def test_profile_new_ranks_accelerations_and_torques_by_how_they_follow_the_drive(tmp_path):
    """Two longitudinal accelerations or two torques alike by name and unit: the one that follows
    dv/dt of the wheels comes first, though it comes second in the DBC, and an engine's torque that
    does beats a wheel torque that moves unrelated to the drive (benchmarks/scaffold.py --busy)."""
    import numpy as np

    from vdp.scaffold import propose

    dbc, db = tiny_dbc(
        tmp_path,
        "BO_ 100 WHEELS: 8 ECU\n"
        ' SG_ WHL_SPD_FL : 0|16@1+ (0.01,0) [0|300] "km/h" ECU\n'
        ' SG_ WHL_SPD_FR : 16|16@1+ (0.01,0) [0|300] "km/h" ECU\n\n'
        "BO_ 101 DYN_A: 8 ECU\n"
        ' SG_ LONG_ACCEL : 0|16@1- (0.01,0) [-20|20] "m/s^2" ECU\n'
        ' SG_ WHL_TQ : 16|16@1- (1,0) [-5000|5000] "Nm" ECU\n\n'
        "BO_ 102 DYN_B: 8 ECU\n"
        ' SG_ LONG_ACCEL : 0|16@1- (0.01,0) [-20|20] "m/s^2" ECU\n'
        ' SG_ ENG_TQ : 16|16@1- (1,0) [-5000|5000] "Nm" ECU\n',
    )
    t = np.arange(0, 60, 0.02)
    v = 12 + 5 * np.sin(2 * np.pi * t / 15)  # m/s
    a = np.gradient(v, t)
    wave = np.sin(2 * np.pi * t / 4.3 + 1.0)  # moves, unrelated to the drive
    msgs = {m.name: m for m in db.messages}
    lines = []
    for i, ti in enumerate(t):
        vals = {
            "WHEELS": {"WHL_SPD_FL": v[i] * 3.6, "WHL_SPD_FR": v[i] * 3.6},
            "DYN_A": {"LONG_ACCEL": 3 * wave[i], "WHL_TQ": 800 * wave[i]},
            "DYN_B": {"LONG_ACCEL": a[i], "ENG_TQ": 100 * a[i] + 80},
        }
        for name, sig in vals.items():
            m = msgs[name]
            lines.append(f"({1700000000 + ti:.6f}) can0 {m.frame_id:03X}#{m.encode(sig).hex().upper()}")
    log = tmp_path / "car.log"
    log.write_text("\n".join(lines) + "\n")
    by_name, _ = propose(db)
    assert by_name["accel_x"][0].message == "DYN_A" and by_name["drive_torque"][0].signal == "WHL_TQ"
    cands, _ = propose(db, log)
    assert cands["accel_x"][0].message == "DYN_B" and "follows dv/dt" in cands["accel_x"][0].note
    assert cands["drive_torque"][0].signal == "ENG_TQ" and cands["drive_torque"][0].engine
