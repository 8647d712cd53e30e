"""Caps say when they bite: a shorter drive than asked for, a simulator slower than asked for."""

import logging
import time
from dataclasses import replace
from pathlib import Path

from vdp.cli import main
from vdp.live import Service
from vdp.settings import simulate_settings

PROFILE = Path(__file__).resolve().parents[1] / "profiles" / "paper.toml"


def test_simulate_says_when_duration_is_capped(tmp_path, capsys):
    out = tmp_path / "s.log"
    assert main(["simulate", "--scenario", "stage1", "--duration", "9999", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "--duration 9999 s is longer than scenario 'stage1'" in err


def test_serve_says_when_sim_speed_is_not_reached(tmp_path, caplog):
    # a queue of 64 frames fills at once at 500x: the feed waits for estimation, and says so
    settings = simulate_settings(PROFILE, tmp_path, scenario="stage1", speed=500.0)
    settings = replace(settings, service=replace(settings.service, queue_size=64))
    svc = Service(settings)
    with caplog.at_level(logging.WARNING, logger="vdp.live.simfeed"):
        svc.start()
        try:
            end = time.monotonic() + 20
            while svc.sim.paused_s == 0 and time.monotonic() < end:
                time.sleep(0.05)
            status = svc.status()["simulation"]
        finally:
            svc.stop()
    assert status["paused_s"] > 0
    assert any("cannot keep up with --sim-speed 500" in r.getMessage() for r in caplog.records)
