"""Careless and hostile inputs around the logs (issue 13): nonsense profiles, outputs that cannot
be written, a raw log disk that fills, a simulator whose DBC goes away for a moment.

Each is a one-line error before any work starts, or a fault the service rides out.
"""

from __future__ import annotations

import collections
import errno
import logging
import re
import shutil
import time
from pathlib import Path

import can
import pytest

from vdp.cli import main
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
    rl.flush()  # written once a flush has put it in a file found in place
    assert rl.stats()["active"] and rl.accepted == 3 and rl.frames == 2 and rl.lost == 1
    rl.close()


def test_a_filling_disk_rotates_out_the_oldest_raw_logs_and_says_so(tmp_path, monkeypatch, caplog):
    Usage = collections.namedtuple("Usage", "total used free")
    capacity = 200_000  # bytes of a pretend disk holding only the raw logs

    def usage(path):
        used = sum(p.stat().st_size for p in Path(tmp_path).iterdir() if p.is_file())
        return Usage(capacity, used, max(capacity - used, 0))

    monkeypatch.setattr(shutil, "disk_usage", usage)  # the one every module of vdp.live.rawlog asks
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


# -- raw logging cannot be unlinked from under itself; its counts are exact (issue 26) ------------


def _lines(d: Path) -> list[str]:
    """Every complete line of the raw logs in ``d``, in file order (a cut last line is not one)."""
    out = []
    for f in sorted(d.glob("*.log")):
        text = f.read_text()
        out += text[: text.rfind("\n") + 1].splitlines()
    return out


def _sent(lines: list[str]) -> list[int]:
    """The frame numbers ``_frame(k)`` wrote, from their timestamps."""
    return [round((float(ln[1 : ln.index(")")]) - 1.7e9) * 1000) for ln in lines]


def test_the_raw_log_directory_deleted_under_vdp_serve_is_made_again_and_health_says_so(tmp_path):
    import shutil

    from fastapi.testclient import TestClient

    from helpers.live import FakePipeline, make_settings, wait_up
    from vdp.api import create_app
    from vdp.live import Service

    settings = make_settings(tmp_path)
    raw = settings.raw_log.dir
    svc = Service(settings, pipeline=FakePipeline())
    svc.start()
    wait_up(svc)
    client = TestClient(create_app(settings, svc))
    rl = svc.rawlog
    try:
        for k in range(100):
            rl.on_message_received(_frame(k))
        rl.flush()
        assert rl.written == 100
        for k in range(100, 150):  # pending: in the buffer, or flushed into the file about to go
            rl.on_message_received(_frame(k))
        shutil.rmtree(raw)  # `rm -rf raw` while the service records
        for k in range(150, 200):
            rl.on_message_received(_frame(k))
        rl.flush()  # the keeper's flush, once a second
        st = client.get("/status").json()["raw_log"]
        assert st["active"] and st["reopened"] == 1 and "deleted" in st["detached"], st
        # nothing after the last check was lost: the 100 pending frames went into the new file
        assert (st["accepted"], st["frames"], st["lost"], st["pending"]) == (200, 200, 0, 0), st
        assert _sent(_lines(raw)) == list(range(100, 200))
        h = client.get("/health").json()
        assert h["status"] == "degraded" and any("recording again in a new file" in r for r in h["reasons"]), h
        for k in range(200, 300):
            rl.on_message_received(_frame(k))
    finally:
        svc.stop()
    assert _sent(_lines(raw)) == list(range(100, 300))  # closed, complete, in order
    assert not (raw / "vdp-current.log").exists()


def test_raw_logs_moved_away_keep_their_frames_and_logging_goes_on_in_a_new_file(tmp_path):
    raw, away = tmp_path / "raw", tmp_path / "elsewhere"
    away.mkdir()
    rl = RawLog(raw, max_bytes=1 << 20, max_files=8)
    rl.open()
    for k in range(100):
        rl.on_message_received(_frame(k))
    rl.flush()
    for k in range(100, 150):
        rl.on_message_received(_frame(k))
    for f in raw.glob("*.log"):  # `mv raw/*.log /elsewhere/`, the open file among them
        f.rename(away / f.name)
    for k in range(150, 200):
        rl.on_message_received(_frame(k))
    rl.flush()
    assert rl.reopened == 1 and "moved away" in rl.detached
    for k in range(200, 250):
        rl.on_message_received(_frame(k))
    rl.close()
    # the moved file holds all it was given (its descriptor followed it), nothing is written twice,
    # and logging goes on in the directory
    assert _sent(_lines(away)) == list(range(200)) and _sent(_lines(raw)) == list(range(200, 250))
    assert (rl.accepted, rl.written, rl.lost) == (250, 250, 0)


def test_a_raw_log_directory_deleted_before_a_rotation_does_not_stop_logging(tmp_path):
    import shutil

    raw = tmp_path / "raw"
    rl = RawLog(raw, max_bytes=4096, max_files=100)  # ~75 lines a file: a rotation every 128 frames
    rl.open()
    for k in range(50):
        rl.on_message_received(_frame(k))
    shutil.rmtree(raw)
    for k in range(50, 1000):  # no flush: the rotation is the first to find the file gone
        rl.on_message_received(_frame(k))
    assert rl.error is None and rl.reopened == 1
    rl.close()
    assert _sent(_lines(raw)) == list(range(1000))  # the 50 frames of the deleted file written again
    assert (rl.accepted, rl.written, rl.lost) == (1000, 1000, 0)
    assert len(rl.closed_files()) > 5


FULL_DISK = r"""
import json, subprocess, sys
from pathlib import Path
import can
from vdp.live.rawlog import RawLog
d = Path(sys.argv[1])
subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "none", str(d)], check=True)
rl = RawLog(d / "raw", max_bytes=1 << 20, max_files=4, min_free=0)
rl.open()
k = 0
while rl.error is None and k < 100_000:
    rl.on_message_received(can.Message(timestamp=1.7e9 + k * 0.001, arbitration_id=0xB1,
                                       is_extended_id=False, data=bytes(8)))
    k += 1
for j in range(10):  # and a few more while it is stopped
    rl.on_message_received(can.Message(timestamp=1.8e9 + j, arbitration_id=0xB1, is_extended_id=False, data=bytes(8)))
rl.close()
text = b"".join(f.read_bytes() for f in sorted((d / "raw").glob("*.log")))
print(json.dumps({"accepted": rl.accepted, "written": rl.written, "lost": rl.lost, "error": rl.error,
                  "lines": text.count(b"\n")}))
"""


def test_on_a_full_disk_the_frames_left_in_the_write_buffer_count_as_lost(tmp_path):
    import json
    import os
    import shutil
    import subprocess
    import sys

    if not shutil.which("unshare") or os.geteuid() != 0:
        pytest.skip("needs root and unshare (util-linux) to mount a small tmpfs")
    d = tmp_path / "small"
    d.mkdir()
    env = {**os.environ, "PYTHONPATH": str(ROOT / "service")}
    r = subprocess.run(
        ["unshare", "-m", sys.executable, "-c", FULL_DISK, str(d)], capture_output=True, text=True, timeout=120, env=env
    )
    if r.returncode != 0 and "mount" in r.stderr:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr[-300:]}")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["error"] == "disk full"
    # exact: what counts as written is what the disk holds, every other frame is lost
    assert out["written"] == out["lines"] and out["accepted"] == out["written"] + out["lost"], out
    assert out["lost"] > 10, out  # the buffer's frames as well as those after the stop


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
