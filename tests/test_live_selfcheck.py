"""The profile self-check of a running service, on the virtual bus: it runs once 10 s of bus
time have passed (not only every 30 s), and a bus that carries none or few of the profile's
messages is a clear error with the counts and the ids the bus carries most, in the log,
/health, /status and the dashboard's status."""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import can
import pytest
from fastapi.testclient import TestClient

from helpers.live import make_settings, wait_frames, wait_up
from vdp.api import create_app
from vdp.live import Service
from vdp.profile import load_profile
from vdp.profilecheck import PARAMETERS, START_AFTER
from vdp.sim.run import Simulation

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "profiles" / "paper.toml"


def run_service(tmp_path, frames, checks, profile=None):
    """Send ``frames`` to a service on the virtual bus; call ``checks(svc, client)`` after each batch."""
    settings = make_settings(tmp_path)
    svc = Service(settings, profile=profile)
    svc.start()
    wait_up(svc)
    client = TestClient(create_app(settings, svc))
    tx = can.Bus(interface="virtual", channel=svc.bus_cfg.channel, preserve_timestamps=True)
    sent = 0
    try:
        for batch, check in zip(frames, checks):
            for msg in batch:
                tx.send(msg)
                sent += 1
            wait_frames(svc, sent)
            svc.sync()
            check(svc, client)
    finally:
        tx.shutdown()
        svc.stop()


def foreign(t0: float, seconds: float) -> list[can.Message]:
    """Another car's bus: 0x3A0 at 100 Hz, 0x2F0 at 50 Hz, and 0x0B1 (an id of the paper's
    bus, WHEEL_SPEEDS_FRONT, which this car's frames fail the checksum of) at 10 Hz."""
    out = []
    for k in range(int(seconds * 100)):
        t = t0 + 0.01 * k
        out.append(can.Message(timestamp=t, arbitration_id=0x3A0, data=bytes(8), is_extended_id=False))
        if k % 2 == 0:
            out.append(can.Message(timestamp=t, arbitration_id=0x2F0, data=bytes(8), is_extended_id=False))
        if k % 10 == 0:
            out.append(can.Message(timestamp=t, arbitration_id=0x0B1, data=bytes([1] * 8), is_extended_id=False))
    return out


def test_a_bus_of_another_car_is_a_clear_error_after_10_s(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="vdp.profilecheck")

    def before(svc, client):  # 5 s in: not yet checked, so no verdict either way
        st = client.get("/status").json()["profile_check"]
        assert st["checked_at"] is None and st["start_after_s"] == START_AFTER and st["error"] is None
        assert not any("profile check" in r for r in client.get("/health").json()["reasons"])

    def after(svc, client):  # 12 s in: checked once
        st = client.get("/status").json()["profile_check"]
        assert st["checked_at"] is not None and st["checks"] == 1
        assert st["coverage"]["seen"] == 0 and st["coverage"]["wanted"] == 7
        assert st["coverage"]["top_ids"][0] == {"id": "0x3A0", "count": 1200}
        h = client.get("/health").json()
        assert h["status"] == "degraded"
        (reason,) = [r for r in h["reasons"] if r.startswith("profile check")]
        assert re.search(r"does not fit profile .*paper\.toml: 0 of 7 of the profile's messages seen", reason)
        assert "the ids the bus carries most: 0x3A0 (1200), 0x2F0 (600)" in reason and "\n" not in reason
        assert "WHEEL_SPEEDS_FRONT came 120 times, none decoded (checksum 120)" in reason
        assert st["error"] in reason

    run_service(tmp_path, [foreign(1000.0, 5.0), foreign(1005.0, 7.0)], [before, after])
    errors = [r.getMessage() for r in caplog.records if r.levelno == logging.ERROR]
    assert len(errors) == 1 and "0 of 7 of the profile's messages seen" in errors[0]


def drive(seconds: float, drop: set[str] = frozenset()) -> list[can.Message]:
    prof = load_profile(PAPER)
    sim = Simulation(prof, "paper", seed=3, duration=seconds)
    ids = {sim.encoder.db.get_message_by_name(n).frame_id for n in drop}
    return [m for m in sim.frames() if m.arbitration_id not in ids]


def test_the_right_bus_passes_and_missing_messages_are_named(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="vdp.profilecheck")

    def ok(svc, client):
        st = client.get("/status").json()["profile_check"]
        assert st["checks"] == 1 and st["error"] is None and st["findings"] == []
        assert st["coverage"]["seen"] == 7 and st["coverage"]["missing"] == []
        assert not any("profile check" in r for r in client.get("/health").json()["reasons"])

    run_service(tmp_path / "a", [drive(12.0)], [ok])

    def partial(svc, client):
        st = client.get("/status").json()["profile_check"]
        assert st["error"] is None and st["coverage"]["seen"] == 5
        reasons = [r for r in client.get("/health").json()["reasons"] if r.startswith("profile check")]
        assert reasons == [
            "profile check: 5 of 7 of the profile's messages seen (missing: IMU_RATES, GNSS_VELOCITY); "
            "the ids the bus carries most: none"
        ]

    caplog.clear()
    run_service(tmp_path / "b", [drive(12.0, {"GNSS_VELOCITY", "IMU_RATES"})], [partial])
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("5 of 7 of the profile's messages seen" in w for w in warned)


@pytest.mark.parametrize("seconds", [9.0, 11.0])
def test_the_first_check_waits_for_10_s_of_bus_time(tmp_path, seconds):
    def check(svc, client):
        st = svc.status()["profile_check"]
        assert (st["checked_at"] is not None) == (seconds > START_AFTER)

    run_service(tmp_path, [foreign(1000.0, seconds)], [check])


def test_replay_says_the_same(tmp_path, capsys):
    """vdp replay checks the log's first minutes: fewer than half of the messages stop it with
    the counts, a few missing are named and the replay goes on."""
    from vdp.cli import main
    from vdp.sim.run import write_log

    few = tmp_path / "few.log"
    write_log(drive(12.0, {"GNSS_VELOCITY", "IMU_RATES", "IMU_ACCEL", "STEERING"}), few)
    assert main(["replay", str(few), "--profile", str(PAPER), "--no-progress"]) != 0
    err = capsys.readouterr().err
    assert "3 of 7 of the profile's messages seen (missing: STEERING, IMU_ACCEL, IMU_RATES, GNSS_VELOCITY)" in err
    some = tmp_path / "some.log"
    write_log(drive(12.0, {"GNSS_VELOCITY"}), some)
    out = tmp_path / "some.json"
    assert main(["replay", str(some), "--profile", str(PAPER), "--no-progress", "--json", str(out)]) == 0
    assert "profile check: " + str(some) + ": 6 of 7 of the profile's messages seen (missing: GNSS_VELOCITY)" in (
        capsys.readouterr().out
    )
    assert json.loads(out.read_text())["profile_check"]["coverage"]["missing"] == ["GNSS_VELOCITY"]


def test_a_finding_shows_in_health_and_the_estimates_it_doubts_are_not_valid(tmp_path):
    """A sign-flipped a_x on a live bus: the check's finding is a /health reason, and every
    parameter (all rest on a_x) is reported not valid, from the first check on."""
    import dataclasses

    paper = load_profile(PAPER)
    chans = dict(paper.channels)
    chans["accel_x"] = dataclasses.replace(chans["accel_x"], sign=-1.0)
    flipped = dataclasses.replace(paper, channels=chans)

    def check(svc, client):
        reasons = client.get("/health").json()["reasons"]
        assert any(r.startswith("profile check: accel_x looks sign-flipped") for r in reasons), reasons
        st = client.get("/status").json()["profile_check"]
        assert [f["subject"] for f in st["findings"]] == ["accel_x"] and st["coverage"]["seen"] == 7
        params = client.get("/estimates").json()["parameters"]
        for name in PARAMETERS:
            e = params[name]
            assert e["valid"] is False and "profile check: accel_x" in e["reason"], (name, e)
        m = params["mass"]  # learnt by default ([service] mass = "auto"), on a_x: the finding marks it too
        assert m["valid"] is False and "profile check: accel_x" in m["reason"], m

    run_service(tmp_path, [drive(30.0)], [check], profile=flipped)


def test_frames_on_another_bus_channel_are_named(tmp_path, capsys):
    """The profile reads [can] channel = "can0", the bus (or the log) is another: the error
    says so, instead of "the ids the bus carries most: none".  A real bus's frames carry its
    [bus] channel; a virtual or udp_multicast bus's carry the profile's (issue 26: a sender
    does not choose the channel the raw log writes), so there the profile's channel fits."""
    import dataclasses

    from vdp.cli import main
    from vdp.live.bus import frame_channel
    from vdp.settings import BusSettings
    from vdp.sim.run import write_log

    assert frame_channel(BusSettings(interface="socketcan", channel="can1"), "can0") == "can1"
    can0 = dataclasses.replace(load_profile(PAPER), bus_channel="can0")
    frames = drive(11.0)

    def check(svc, client):
        pc = svc.status()["profile_check"]
        assert pc["error"] is None, pc  # the virtual bus's frames are on the profile's channel

    run_service(tmp_path / "live", [frames], [check], profile=can0)
    log = tmp_path / "can1.log"
    frames = drive(11.0)
    for m in frames:
        m.channel = "can1"
    write_log(frames, log)
    text = PAPER.read_text().replace("[can]\n", '[can]\nchannel = "can0"\n')
    prof = tmp_path / "can0.toml"
    prof.write_text(text.replace('dbc = "../dbc/vdp.dbc"', f'dbc = "{ROOT / "dbc" / "vdp.dbc"}"'))
    capsys.readouterr()
    assert main(["profile", "check", str(log), "--profile", str(prof)]) != 0
    err = capsys.readouterr().err
    assert "0 of 7 of the profile's messages seen" in err
    assert f"{len(frames)} frames came on other bus channels (can1 ({len(frames)}))" in err


def test_the_real_rav4_capture_passes_the_live_self_check(tmp_path, monkeypatch):
    """comma2k19's RAV4 (15 s, tests/data) on a live bus: its 3 messages seen, a_x against
    dv/dt judged and right, no finding, nothing in /health."""
    import dataclasses

    from vdp.io.logs import open_log

    pytest.importorskip("opendbc")
    monkeypatch.setenv("VDP_CACHE_DIR", str(tmp_path / "cache"))
    # the virtual bus names its own channel: the profile's "can0" is for the log, not this bus
    prof = dataclasses.replace(load_profile(ROOT / "profiles" / "toyota_rav4.toml"), bus_channel=None)
    with open_log(ROOT / "tests" / "data" / "rav4-2018-highway-15s.log.gz", channel="can0") as src:
        frames = list(src)

    def check(svc, client):
        st = client.get("/status").json()["profile_check"]
        assert st["error"] is None and st["findings"] == [] and st["coverage"]["seen"] == 3
        assert 0.8 < st["measured"]["accel_x_per_dv_dt"] < 1.25
        assert not any("profile check" in r for r in client.get("/health").json()["reasons"])

    run_service(tmp_path, [frames], [check], profile=prof)
