"""A real car: 15 s of a 2018 Toyota RAV4's bus (comma2k19, MIT; see
tests/data/rav4-2018-highway-15s.README.md) through profiles/toyota_rav4.toml.

vdp must decode it, say why stage 1 and I_x cannot run, and claim nothing: the bus has no
per-axle torque and no roll rate, and the drive has no steering excitation for stage 2 (which
this car can run, from the profile's published l_f).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from conftest import REAL
from vdp import channels
from vdp.cli import main
from vdp.core.supervisor import GateConfig
from vdp.io.decoder import FrameDecoder
from vdp.io.logs import open_log
from vdp.profile import load_profile

pytest.importorskip("opendbc", reason="the Toyota profile generates its DBC with the opendbc extra")

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "profiles" / "toyota_rav4.toml"
TRIMMED = ROOT / "tests" / "data" / "rav4-2018-highway-15s.log.gz"
FULL = REAL / "rav4-2018-highway-60s.log.gz"
POWERTRAIN = {
    "wheel_speed_fl",
    "wheel_speed_fr",
    "wheel_speed_rl",
    "wheel_speed_rr",
    "steering_angle",
    "yaw_rate",
    "accel_x",
    "accel_y",
}


@pytest.fixture(scope="module", autouse=True)
def cache_dir(tmp_path_factory):
    """The generated Toyota DBC goes to a private cache, not ~/.cache."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("VDP_CACHE_DIR", str(tmp_path_factory.mktemp("vdp-cache")))
        yield


def replay_cli(log: Path, tmp_path: Path, capsys) -> tuple[str, dict]:
    out = tmp_path / "result.json"
    capsys.readouterr()
    args = ["replay", str(log), "--profile", str(PROFILE), "--json", str(out), "--no-progress"]
    assert main([*args, "--baseline", "ekf"]) == 0
    return capsys.readouterr().out, json.loads(out.read_text())


def check_no_claims(text: str, res: dict) -> None:
    # which stages cannot run, and why: no per-axle torque for stage 1, no roll rate for I_x;
    # stage 2 can run (the profile's l_f, the rear wheels' speed) but the drive never steers
    cap = res["capabilities"]
    assert "wheel_torque_front" in cap["1"] and "wheel_torque_rear" in cap["1"]
    assert cap["2"] is None and "roll_rate" in cap["I_x"]
    assert f"stage 1 cannot run: {cap['1']}" in text and f"I_x cannot run: {cap['I_x']}" in text
    assert "stage 2 cannot run" not in text
    assert res["supervisor"]["excitation"]["2"]["main_blocker"] == "little steering excitation"
    # no confident estimate, from either filter
    for kind in ("parameters", "baseline_ekf"):
        for name, p in res[kind].items():
            assert p["valid"] is False and p["status"] != "converged", (kind, name, p)
    assert res["windows"] == []


def test_trimmed_drive_decodes_and_claims_nothing(tmp_path, capsys):
    text, res = replay_cli(TRIMMED, tmp_path, capsys)
    log = res["log"]
    assert log["frames"] == 13462 and log["skipped_other_channels"] == 33885 - 13462  # can0 only
    assert log["bad_lines"] == 0 and log["duration_s"] == pytest.approx(15.0, abs=0.01)
    dec = log["decode"]
    assert set(dec["samples"]) == POWERTRAIN
    assert all(n > 1200 for n in dec["samples"].values()), dec["samples"]  # about 82 Hz for 15 s
    assert set(dec["errors_by_kind"]) <= {"unknown_id", "dlc"} and dec["invalid_channels"] == []
    check_no_claims(text, res)


def decoded(log: Path) -> dict[str, np.ndarray]:
    """(t, value) arrays per canonical channel, as the profile converts them."""
    dec = FrameDecoder(load_profile(PROFILE))
    rows: dict[str, list] = {n: [] for n in POWERTRAIN}
    with open_log(log, channel="can0") as src:
        for msg in src:
            for i, v in dec.decode(msg):
                rows[channels.NAMES[i]].append((msg.timestamp, v))
    return {k: np.array(v) for k, v in rows.items()}


@pytest.fixture(scope="module")
def drive():
    return decoded(TRIMMED)


def means(series: np.ndarray, grid: np.ndarray, width: float) -> np.ndarray:
    """Boxcar means of a (t, value) series, ``width`` seconds wide, centred on ``grid``."""
    t, v = series[:, 0], series[:, 1]
    csum = np.concatenate(([0.0], np.cumsum(v)))
    lo, hi = np.searchsorted(t, grid - width / 2), np.searchsorted(t, grid + width / 2)
    return (csum[hi] - csum[lo]) / np.maximum(hi - lo, 1)


def test_values_are_physical_and_signs_right(drive):
    """Units, offsets and signs, checked against the car's own physics."""
    r = load_profile(PROFILE).vehicle.wheel_radius
    t0 = drive["yaw_rate"][0, 0]
    grid = np.arange(t0 + 1.0, t0 + 14.0, 0.1)
    v = 0.5 * (means(drive["wheel_speed_rl"], grid, 1.0) + means(drive["wheel_speed_rr"], grid, 1.0)) * r
    assert v.min() > 7.5 and v.max() < 21.0  # the README: 8 to 20 m/s
    front = 0.5 * (drive["wheel_speed_fl"][:, 1] + drive["wheel_speed_fr"][:, 1])
    assert np.median(front) * r == pytest.approx(np.median(v), rel=0.02)  # the km/h offset is applied
    assert np.abs(drive["steering_angle"][:, 1]).max() < math.radians(5.0) / 16.88 * 1.01  # < 5 deg at the wheel
    yaw = means(drive["yaw_rate"], grid, 1.0)
    assert math.radians(-2.5) < yaw.min() and yaw.max() < math.radians(0.5)
    # accel_x follows d(speed)/dt; accel_y follows speed * yaw rate (both flipped by the profile)
    dv = np.gradient(v, grid)
    ax, ay = means(drive["accel_x"], grid, 1.0), means(drive["accel_y"], grid, 1.0)
    assert np.corrcoef(dv, ax)[0, 1] > 0.95 and 0.8 < np.polyfit(dv, ax, 1)[0] < 1.2
    assert np.corrcoef(v * yaw, ay)[0, 1] > 0.9 and 0.8 < np.polyfit(v * yaw, ay, 1)[0] < 1.4
    # the steering follows the curve: a turn right shows as a negative road-wheel angle
    steer = means(drive["steering_angle"], grid, 1.0)
    assert np.corrcoef(steer, yaw)[0, 1] > 0.7


def test_drive_has_no_steering_excitation(drive):
    """By the supervisor's own stage-2 thresholds, at no time was there enough steering."""
    cfg = GateConfig()
    t0 = drive["steering_angle"][0, 0]
    grid = np.arange(t0 + cfg.tau_steer, t0 + 15.0, 0.1)
    steer, yaw = drive["steering_angle"], drive["yaw_rate"]
    width = 2 * cfg.tau_steer
    d_std = np.sqrt(
        np.maximum(means(np.c_[steer[:, 0], steer[:, 1] ** 2], grid, width) - means(steer, grid, width) ** 2, 0.0)
    )
    yaw_rms = np.sqrt(means(np.c_[yaw[:, 0], yaw[:, 1] ** 2], grid, width))
    assert d_std.max() < 0.2 * cfg.delta_std_min_2 and yaw_rms.max() < 0.5 * cfg.yaw_rms_min_2


def test_replay_says_there_is_no_steering_excitation(tmp_path, capsys):
    text, _ = replay_cli(TRIMMED, tmp_path, capsys)
    assert any(
        line.startswith("stage 2") and "steering" in line and "excitation" in line for line in text.splitlines()
    ), text


@pytest.mark.skipif(not FULL.is_file(), reason=f"the full real drive is not at {FULL}")
def test_full_minute_decodes_and_claims_nothing(tmp_path, capsys):
    text, res = replay_cli(FULL, tmp_path, capsys)
    log = res["log"]
    assert log["frames"] == 53800 and log["skipped_other_channels"] == 135468 - 53800
    dec = log["decode"]
    assert set(dec["samples"]) == POWERTRAIN
    # the log has 100 frames shorter than their DBC length; those of mapped messages are rejected
    # 93 frames lost their trailing zero bytes in comma2k19's arrays: the profile pads them (pad_short)
    assert set(dec["errors_by_kind"]) == {"unknown_id"} and 0 < dec["padded"] <= 100
    check_no_claims(text, res)


def test_a_fleet_row_gives_the_reason_the_car_cannot_learn_a_parameter():
    """runs.parquet's reason for the RAV4's I_x is its missing roll-rate gyro, as the replay says,
    not "its stage had no window" (which asks for more driving that cannot help)."""
    from vdp import fleet

    res, _ = fleet.replay_log(str(TRIMMED), str(PROFILE))
    rows = {r["parameter"]: r for r in fleet.rows_from_result(res, fleet.Task(str(TRIMMED), "rav4", str(PROFILE)))}
    assert rows["I_x"]["status"] == "not_run" and "no roll-rate gyro" in rows["I_x"]["reason"]
    assert "no per-axle wheel torque" in rows["h"]["reason"]  # its stage cannot run on this car


def test_the_readme_says_where_the_real_rav4_capture_is_and_what_it_shows():
    """A new user looked for the real drive the tests replay: the README never named it."""
    from conftest import ROOT

    text = " ".join((ROOT / "README.md").read_text().split())
    assert "../shared/data/real/rav4-2018-highway-60s.log.gz" in text
    assert (
        "tests/data/rav4-2018-highway-15s.log.gz" in text
        and (ROOT / "tests/data/rav4-2018-highway-15s.log.gz").is_file()
    )
    assert "--profile profiles/toyota_rav4.toml" in text and "stage 1 cannot run" in text
