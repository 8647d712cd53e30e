"""In-process end to end: the simulator on a virtual bus feeds the service, faster than real time.

One simulated `paper` drive (noise none) runs through the live service; then:

- the service's own promises: no frame dropped or lost, the raw log complete, and
  `vdp replay` of the raw log files gives the very same estimates as the live service;
- the API reports stage 1 and stage 2 converged near the truth (the estimator's
  targets; a failure here with the first test passing points at the estimator).
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from vdp.api import create_app
from vdp.cli import main as vdp_main
from vdp.live import Service
from vdp.settings import simulate_settings

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "profiles" / "paper.toml"

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("inprocess")
    settings = simulate_settings(PROFILE, tmp, scenario="paper", speed=0, noise="none")
    # small files, so the drive spans several rotations
    settings = replace(settings, raw_log=replace(settings.raw_log, max_bytes=1 << 20, max_files=32))
    svc = Service(settings)
    svc.start()
    client = TestClient(create_app(settings, svc))
    try:
        assert svc.sim.wait(timeout=600), "the simulation did not finish"
        assert svc.sim.error is None
        end = time.monotonic() + 60
        while svc.intake.received < svc.sim.sent and time.monotonic() < end:
            time.sleep(0.01)  # the last frames are still on their way through the virtual bus
        svc.sync()
        est = client.get("/estimates")
        status = client.get("/status").json()
        health = client.get("/health").json()
    finally:
        svc.stop()
    assert est.status_code == 200 and "NaN" not in est.text
    return {
        "tmp": tmp,
        "settings": settings,
        "sent": svc.sim.sent,
        "truth": svc.sim.truth["parameters"],
        "live": est.json(),
        "status": status,
        "health": health,
    }


def test_every_frame_is_estimated_logged_and_replays_to_the_same_estimates(drive):
    sent, status, live = drive["sent"], drive["status"], drive["live"]
    assert status["queue"]["dropped"] == 0 and status["bus"]["frames"] == sent
    assert status["estimation"]["frames"] == sent and status["estimation"]["errors"] == 0
    assert status["decode"]["decoded"] == sent
    assert status["raw_log"]["frames"] == sent and status["raw_log"]["lost"] == 0

    raw = drive["settings"].raw_log.dir
    files = sorted(raw.glob("vdp-*.log"))
    assert len(files) >= 3 and not (raw / "vdp-current.log").exists()
    log = drive["tmp"] / "drive.log"
    with open(log, "wb") as out:
        for f in files:  # closed files are complete, and in order
            data = f.read_bytes()
            assert data.endswith(b"\n")
            out.write(data)
    out_json = drive["tmp"] / "replay.json"
    args = ["replay", str(log), "--profile", str(PROFILE), "--json", str(out_json), "--no-progress"]
    assert vdp_main([*args, "--baseline", "ekf"]) == 0  # the live service runs the EKF too
    rep = json.loads(out_json.read_text())
    assert rep["log"]["bad_lines"] == 0 and rep["log"]["frames"] == sent
    assert list(live["parameters"]) == list(rep["parameters"]) and "mass" in rep["parameters"]
    for kind in ("parameters", "baseline_ekf"):
        for name, e in rep[kind].items():
            got = live[kind][name]
            assert got["status"] == e["status"] and got["samples"] == e["samples"], (kind, name, got, e)
            # the live service steps its UKF in numpy, a replay compiled (core.kernels): the same
            # numbers to rounding, which a drive's thousands of steps grow to ~1e-9 (per-axle stage 2:
            # I_z 1.2e-9); tests/test_kernels.py holds a drive to DRIVE_RTOL = 1e-7
            assert got["value"] == pytest.approx(e["value"], rel=1e-7), (kind, name)
            assert got["std"] == pytest.approx(e["std"], rel=1e-7), (kind, name)


def test_stage_1_converges_live(drive):
    p, truth = drive["live"]["parameters"], drive["truth"]
    # the estimator issue's noise-free target: within 1 %
    for name in ("l_f", "h", "C_K"):
        assert p[name]["status"] == "converged" and p[name]["valid"], (name, p[name])
        assert p[name]["value"] == pytest.approx(truth[name], rel=0.01), (name, p[name])


def test_stage_2_converges_live(drive):
    live, truth = drive["live"], drive["truth"]
    p = live["parameters"]
    assert live["stage"] in ("stage2", "done")
    # within the estimator issue's tolerances for realistic noise (looser than its noise-free 1 %)
    for name, rel in (("C_alpha", 0.03), ("I_z", 0.05)):
        assert p[name]["status"] == "converged" and p[name]["valid"], (name, p[name])
        assert p[name]["value"] == pytest.approx(truth[name], rel=rel), (name, p[name])
    ix = p["I_x"]  # not identifiable in this scenario (NOTES 5): flagged, with an honest interval
    assert ix["value"] == pytest.approx(truth["I_x"], rel=0.10) or (
        ix["status"] == "not_identifiable" and not ix["valid"] and abs(ix["value"] - truth["I_x"]) <= 2 * ix["std"]
    ), ix
