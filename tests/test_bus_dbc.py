"""Real-world DBCs: the ones cantools refuses load repaired (with a warning naming the file and
why), the simulator's counters wrap where the decoder expects, and CAN-FD cars round-trip
through their own log."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest

from vdp.cli import main
from vdp.errors import ProfileError
from vdp.io import dbcfix
from vdp.io.decoder import FrameDecoder
from vdp.io.logs import open_log
from vdp.profile import load_profile
from vdp.sim.encode import Encoder
from vdp.sim.run import Simulation, write_log

pytest.importorskip("opendbc", reason="these DBCs come from the opendbc extra")

ROOT = Path(__file__).resolve().parents[1]
IONIQ5 = ROOT / "profiles" / "hyundai_ioniq5_2022.toml"


@pytest.fixture(autouse=True)
def cache_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("VDP_CACHE_DIR", str(tmp_path / "cache"))
    logging.getLogger("vdp.sim.encode").setLevel(logging.ERROR)  # opendbc's DBCs have no cycle times


# Generated opendbc DBCs that cantools refuses as they are, and the fault in each.
REFUSED = {
    "acura_ilx_2016_can_generated": "signal comment without a signal name",
    "honda_civic_touring_2016_can_generated": "signal comment without a signal name",
    "honda_crv_ex_2017_body_generated": "id above 11 bits",
    "chrysler_pacifica_2017_hybrid_generated": "number without its leading zero",
    "chrysler_ram_dt_generated": "without its closing ';'",
    "gm_global_a_powertrain_generated": "value table of an undefined signal",
    "hyundai_palisade_2023_generated": "value table of an undefined signal",
}


@pytest.mark.parametrize("name", sorted(REFUSED))
def test_refused_opendbc_dbcs_load_repaired_with_a_warning(name, tmp_path, caplog):
    import cantools

    from vdp.opendbc import _opendbc_generated

    text = _opendbc_generated()[name]
    path = tmp_path / f"{name}.dbc"
    path.write_text(text)
    with pytest.raises(Exception):  # noqa: B017 - cantools' parser errors have many types
        cantools.database.load_string(text, database_format="dbc", strict=False)
    with caplog.at_level(logging.WARNING, logger="vdp.io.dbcfix"):
        db = dbcfix.load(path)
    assert len(db.messages) == text.count("\nBO_ ") > 0  # every message kept
    warn = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warn) == 1 and str(path) in warn[0] and REFUSED[name] in warn[0]


@pytest.mark.slow
def test_shipped_opendbc_dbcs_all_load():
    import opendbc

    bad = []
    for path in sorted((Path(opendbc.__file__).parent / "dbc").glob("*.dbc")):
        try:
            dbcfix.load(path)
        except ProfileError as exc:
            bad.append(str(exc))
    assert bad == []


def test_ids_too_wide_are_extended_and_references_follow():
    text = (
        'VERSION ""\n\nBS_:\n\nBU_: X\n\nBO_ 316461991 WIDE: 8 X\n SG_ A : 0|8@1+ (1,0) [0|255] "" X\n\n'
        'CM_ SG_ 316461991 A "a wide one";\nVAL_ 316461991 A 1 "on" 0 "off" ;\nVAL_ 5 GONE 1 "x" ;\n'
    )
    fixed, reasons = dbcfix.repair(text)
    assert any("11 bits" in r for r in reasons) and any("GONE" in r for r in reasons)
    import cantools

    db = cantools.database.load_string(fixed, database_format="dbc")
    m = db.get_message_by_name("WIDE")
    assert m.is_extended_frame and m.frame_id == 316461991 and m.get_signal_by_name("A").comment == "a wide one"


def test_a_dbc_beyond_repair_is_one_clear_error(tmp_path):
    path = tmp_path / "broken.dbc"
    path.write_text('VERSION ""\n\nBO_ 12 X: 8 Y\n SG_ A : 0|8@1+ (1,0) [0|255 "" Y\n')
    with pytest.raises(ProfileError) as exc:
        dbcfix.load(path, "car.toml [can]")
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("car.toml [can]: cannot load DBC") and "broken.dbc" in msg
    assert "fix that line" in msg


# -- the simulator on a CAN-FD car with 8-bit counters ---------------------------------------


def test_canfd_car_round_trips_through_its_own_log(tmp_path):
    prof = load_profile(IONIQ5)
    sim = Simulation(prof, "stage2", seed=3, duration=9.0)  # steers left and right
    assert all(p.is_fd for p in sim.encoder.plans)  # 16- to 32-byte messages
    path = tmp_path / "fd.log"
    n = write_log(sim.frames(), path)
    lines = path.read_text().splitlines()
    assert len(lines) == n and all("##" in line for line in lines)
    dec = FrameDecoder(prof)
    steer = []
    with open_log(path) as src:
        for msg in src:
            assert msg.is_fd
            for idx, v in dec.decode(msg):
                if idx == 6:  # steering_angle
                    steer.append(v)
        assert src.stats.as_dict()["bad_lines"] == 0
    st = dec.stats.as_dict()
    # 900 frames per message: the 8-bit counters wrapped, and the decoder agrees with every step
    assert st["decoded"] == st["frames"] == n and st["errors"] == {}
    assert min(steer) < -0.01 < 0.01 < max(steer)  # right turns pass the profile's range
    # vdp replay (its bulk reader) decodes the same log with the same range override
    out = tmp_path / "r.json"
    assert main(["replay", str(path), "--profile", str(IONIQ5), "--json", str(out), "--no-progress", "--no-ekf"]) == 0
    dec2 = json.loads(out.read_text())["log"]["decode"]
    assert dec2["errors"] == {} and dec2["decoded"] == n


def test_counters_wrap_at_their_bit_width():
    prof = load_profile(IONIQ5)
    enc = Encoder(prof)
    plan = next(p for p in enc.plans if p.name == "WHEEL_SPEEDS")
    assert plan.counter_modulo == 256
    msg = plan.message
    values = dict.fromkeys(plan.channels, 10.0)
    counts = [msg.decode(enc.encode(plan, values))["COUNTER"] for _ in range(260)]
    assert counts[:3] == [0, 1, 2] and counts[255] == 255 and counts[256] == 0


def test_range_override_replaces_the_dbcs(tmp_path):
    text = IONIQ5.read_text().replace(", range = [-800, 800]", "")
    p = tmp_path / "no_range.toml"
    p.write_text(text)
    prof = load_profile(p)
    # without the override the DBC's [0|255] leaves no room for a right turn
    plan = next(p for p in Encoder(prof).plans if p.name == "STEERING_SENSORS")
    assert plan.signals[0].lo >= 0.0
    bad = tmp_path / "bad_range.toml"
    bad.write_text(IONIQ5.read_text().replace("range = [-800, 800]", "range = [800, -800]"))
    with pytest.raises(ProfileError, match=r"steering_angle\]: 'range' must be \[minimum, maximum\]"):
        load_profile(bad)


def test_status_signals_keep_invalid_samples_from_the_estimator():
    """The ESC's start-up values (saturated, status non-zero) never become samples; counted."""
    from vdp.pipeline import Pipeline

    prof = load_profile(IONIQ5)
    sim = Simulation(prof, "stage2", seed=3, duration=3.0, noise="none")
    esc = prof.channels["yaw_rate"].message
    db = sim.encoder.db
    msg_def = db.get_message_by_name(esc)
    pipe = Pipeline(prof)
    bad = 0
    for msg in sim.frames():
        if msg.arbitration_id == msg_def.frame_id and msg.timestamp - 1700000000.0 < 1.0:
            vals = msg_def.decode(msg.data, decode_choices=False)
            vals.update(ESC_YawSigSta=1, ESC_YawRtVal=163.83, ESC_LatAccelSigSta=2, ESC_LatAccelVal=4.1)
            msg.data = bytearray(msg_def.encode(vals, strict=False))
            bad += 1
        pipe.feed(msg)
    st = pipe.decoder.stats.as_dict()
    assert bad > 50
    assert st["invalid_samples"] == {
        "yaw_rate": {"status ESC_YawSigSta=1": bad},
        "accel_y": {"status ESC_LatAccelSigSta=2": bad},
    }
    assert st["samples"]["yaw_rate"] == st["samples"]["accel_x"] - bad  # accel_x's status stayed 0
    _, ys = pipe.ring.latest()
    assert abs(ys[:, 9][~np.isnan(ys[:, 9])]).max() < 1.0  # no 163.8 deg/s reached a sample


def test_validity_keys_are_checked(tmp_path):
    base = IONIQ5.read_text()
    for bad, match in (
        ('valid_when = { signal = "ESC_YawSigSta", values = [0] }', None),
        ('valid_when = { signal = "ESC_YawSigSta", values = "0" }', "'valid_when' must be"),
        ('valid_when = { signal = "NOPE", values = [0] }', "status signal 'NOPE' is not in message"),
        ("plausible = [2, 1]", "'plausible' must be"),
    ):
        p = tmp_path / "v.toml"
        p.write_text(base.replace('valid_when = { signal = "ESC_YawSigSta", values = [0] }', bad))
        if match is None:
            FrameDecoder(load_profile(p))
            continue
        with pytest.raises(ProfileError, match=match):
            FrameDecoder(load_profile(p))
