"""Careless and hostile inputs around the logs (issue 13): nonsense profiles, outputs that cannot
be written, a raw log disk that fills, a simulator whose DBC goes away for a moment.

Each is a one-line error before any work starts, or a fault the service rides out.
"""

from __future__ import annotations

import collections
import errno
import logging
import re
import time
from pathlib import Path

import can
import pytest

from vdp.cli import main
from vdp.live import rawlog as rawlog_mod
from vdp.live import simfeed as simfeed_mod
from vdp.live.rawlog import RawLog
from vdp.live.simfeed import SimFeed
from vdp.profile import load_profile
from vdp.settings import SimulateSettings
from vdp.sim.run import Simulation

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "profiles" / "paper.toml"
GOOD_LOG = "(1700000000.000000) can0 0B1#0000000000000000\n"


def one_line_error(capsys, command: str = "replay") -> str:
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"vdp {command}: error: "), cap.err
    assert "Traceback" not in cap.err and cap.out == "", cap.out
    return lines[0]


# -- profiles: nonsense numbers and shapes -------------------------------------------------

PROFILE_NONSENSE = {
    "deep nesting": (lambda t: t + "\n[deep]\nx = " + "[" * 5000 + "]" * 5000 + "\n", "nested too deeply"),
    "a 400-digit prior": (lambda t: t.replace("value = 2500.0,", "value = 1" + "0" * 400 + ","), "'value'"),
    "a prior of 1e308": (lambda t: t.replace("value = 2500.0,", "value = 1e308,"), "[priors.I_z]: 'value'"),
    "a 30-digit mass": (lambda t: t.replace("mass = 1600.0 ", "mass = " + "9" * 30 + " "), "'mass'"),
    "a wheelbase of 1e300": (lambda t: t.replace("wheelbase = 2.5 ", "wheelbase = 1e300 "), "'wheelbase'"),
    "a wheelbase of 1e6": (lambda t: t.replace("wheelbase = 2.5 ", "wheelbase = 1e6 "), "'wheelbase' = 1e+06 is not"),
    "a NaN mass": (lambda t: t.replace("mass = 1600.0 ", "mass = nan "), "'mass' must be a finite number"),
    "a negative mass": (lambda t: t.replace("mass = 1600.0 ", "mass = -1600.0 "), "'mass' must be positive"),
    "a mass of 1.6 (tonnes?)": (lambda t: t.replace("mass = 1600.0 ", "mass = 1.6 "), "'mass' = 1.6 is not plausible"),
    "a roll stiffness of 1e12 per deg": (
        lambda t: t.replace("roll_stiffness_per_deg = 36000.0", "roll_stiffness_per_deg = 1e11"),
        "'roll_stiffness_per_deg'",
    ),
}


@pytest.mark.parametrize("case", sorted(PROFILE_NONSENSE))
def test_a_nonsense_profile_is_one_line_naming_the_key(tmp_path, capsys, case):
    change, needle = PROFILE_NONSENSE[case]
    text = PROFILE.read_text().replace('"../dbc/vdp.dbc"', f'"{ROOT / "dbc" / "vdp.dbc"}"')
    p = tmp_path / "bad.toml"
    p.write_text(change(text))
    log = tmp_path / "d.log"
    log.write_text(GOOD_LOG)
    assert main(["replay", str(log), "--profile", str(p), "--no-progress"]) == 2
    assert needle in one_line_error(capsys)


def test_every_shipped_profile_is_within_the_plausible_ranges():
    for p in sorted((ROOT / "profiles").glob("*.toml")):
        assert load_profile(p).vehicle.mass > 0, p


# -- outputs are checked before any work ---------------------------------------------------


@pytest.mark.parametrize(
    "flag,path,needle",
    [
        ("--json", "/nonexistent-dir/out.json", "does not exist"),
        ("--plot", "/proc/out.png", "cannot write"),
        ("--series", "/proc/est.csv", "cannot write"),
        ("--channels", "/nonexistent-dir/s.parquet", "does not exist"),
        ("--json", "/", "is a directory"),
    ],
)
def test_an_unwritable_output_fails_before_the_replay(tmp_path, capsys, flag, path, needle):
    log = tmp_path / "d.log"
    log.write_text(GOOD_LOG)
    assert main(["replay", str(log), "--profile", str(PROFILE), "--no-progress", flag, path]) == 2
    line = one_line_error(capsys)  # nothing on stdout: no replay ran
    assert flag in line and needle in line


def test_an_unwritable_export_path_fails_at_once(tmp_path, capsys):
    res = tmp_path / "r.json"
    res.write_text("{}")
    assert main(["export", str(res), "--format", "json", "--out", "/proc/car.json"]) == 2
    assert "--out /proc/car.json" in one_line_error(capsys, "export")


# -- raw logging: resumes within seconds, keeps the newest data under a free-space floor ----------


def _frame(k: int) -> can.Message:
    return can.Message(timestamp=1.7e9 + k * 0.001, arbitration_id=0xB1, is_extended_id=False, data=bytes(8))


def test_raw_logging_resumes_within_seconds_of_an_error(tmp_path):
    rl = RawLog(tmp_path, max_bytes=1 << 20, max_files=4)
    rl.open()
    rl.on_message_received(_frame(0))
    rl._fail(OSError(errno.EIO, "I/O error"))
    assert rl.error and not rl.stats()["active"]
    t = rl._failed_at
    rl.on_message_received(_frame(1))  # lost while stopped, and counted
    assert not rl.maybe_resume(now=t + 0.5)
    assert rl.maybe_resume(now=t + 1.5)  # was 30 s
    rl.on_message_received(_frame(2))
    assert rl.stats()["active"] and rl.frames == 2 and rl.lost == 1
    rl.close()


def test_a_filling_disk_rotates_out_the_oldest_raw_logs_and_says_so(tmp_path, monkeypatch, caplog):
    Usage = collections.namedtuple("Usage", "total used free")
    capacity = 200_000  # bytes of a pretend disk holding only the raw logs

    def usage(path):
        used = sum(p.stat().st_size for p in Path(tmp_path).iterdir() if p.is_file())
        return Usage(capacity, used, max(capacity - used, 0))

    monkeypatch.setattr(rawlog_mod.shutil, "disk_usage", usage)
    rl = RawLog(tmp_path, max_bytes=8192, max_files=1000, min_free=50_000)
    rl.open()
    caplog.set_level(logging.WARNING, "vdp.live.rawlog")
    n = 20_000  # ~900 KB of lines: four times the pretend disk
    for k in range(n):
        rl.on_message_received(_frame(k))
    rl.close()
    st = rl.stats()
    assert st["lost"] == 0 and st["error"] is None and rl.frames == n
    assert st["deleted_for_space"] > 50 and usage(tmp_path).free >= 50_000 - 8192 - 4096
    assert any("under the floor" in r.message for r in caplog.records)
    # the newest data is what is kept: the files left hold the last frames, in order
    files = rl.closed_files()
    last = files[-1].read_text().strip().splitlines()[-1]
    assert last.startswith(f"({_frame(n - 1).timestamp:.6f})")
    seqs = [int(re.match(r"vdp-(\d+)-", p.name).group(1)) for p in files]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))


# -- the simulator survives a DBC it cannot reopen for a while ---------------------------------


def test_the_simulator_retries_when_it_cannot_start_a_loop_again(monkeypatch):
    monkeypatch.setattr(simfeed_mod, "RETRY_MIN", 0.01)
    cfg = SimulateSettings(enabled=True, scenario="stage1", speed=0.0, loop=True)
    feed = SimFeed(PROFILE, cfg, "rel-simfeed-test", backlog=lambda: 0.0)
    calls = {"n": 0}

    def make(start):
        calls["n"] += 1
        if calls["n"] in (1, 2):  # the DBC is away for the first two attempts
            raise OSError(errno.ENOENT, "No such file or directory", "dbc/vdp.dbc")
        return Simulation(PROFILE, "stage1", 1, start_time=start, duration=1.0)

    feed._sim = Simulation(PROFILE, "stage1", 1, start_time=1.7e9, duration=1.0)
    feed._make = make
    feed.start(ready=lambda: True)
    try:
        deadline = time.monotonic() + 30
        while feed.loops < 3 and time.monotonic() < deadline and feed._thread.is_alive():
            time.sleep(0.02)
    finally:
        feed.stop()
    assert feed.loops >= 3 and feed.retries == 2 and feed.error is None


def test_the_free_space_floor_is_read_from_the_config(tmp_path):
    from dataclasses import replace

    from vdp.live.ingest import Ingest
    from vdp.settings import load_settings

    cfg = tmp_path / "vdp.toml"
    cfg.write_text((ROOT / "deploy" / "vdp.toml").read_text().replace("# min_free_mb = 256", "min_free_mb = 256"))
    s = load_settings(cfg)
    assert s.raw_log.min_free_mb == 256
    s = replace(s, raw_log=replace(s.raw_log, dir=tmp_path / "raw"))
    assert Ingest(s, load_profile(PROFILE)).rawlog.min_free == 256 << 20


def test_each_loop_of_the_simulated_demo_drives_with_the_next_seed(monkeypatch):
    """`vdp serve --simulate --loop` fed the very same drive (one seed) on every loop."""
    import vdp.sim.run as run_mod

    made = []

    class Short(Simulation):
        def __init__(self, profile, scenario, seed, **kw):
            made.append(seed)
            super().__init__(profile, scenario, seed, **dict(kw, duration=1.0))

    monkeypatch.setattr(run_mod, "Simulation", Short)
    cfg = SimulateSettings(enabled=True, scenario="stage1", speed=0.0, seed=7, loop=True)
    feed = SimFeed(PROFILE, cfg, "rel-simfeed-seed", backlog=lambda: 0.0)
    feed.start(ready=lambda: True)
    try:
        deadline = time.monotonic() + 60
        while len(made) < 3 and time.monotonic() < deadline and feed._thread.is_alive():
            time.sleep(0.02)
    finally:
        feed.stop()
    assert made[:3] == [7, 8, 9] and feed.status()["seed"] == 7 + feed.loops >= 9
