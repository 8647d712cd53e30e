"""One simulated drive in every log format python-can writes replays to the same estimates.

The drive: 20 s of the paper's stage-1 manoeuvre (stage 1 opens a window and converges
in that time), written by the simulator's writer (candump directly, the rest through
can.Logger) and replayed with ``open_log`` on bus channel can0, so each format's
channel naming must map back to can0 (tests/test_logs.py checks the frames themselves).
"""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import pytest

from vdp.core.estimator import EstimatorConfig
from vdp.io.logs import open_log
from vdp.pipeline import Pipeline
from vdp.profile import load_profile
from vdp.replay import replay
from vdp.result import RunResult
from vdp.sim.run import Simulation, write_log

ROOT = Path(__file__).resolve().parents[1]
PROFILE = dataclasses.replace(load_profile(ROOT / "profiles" / "paper.toml"), bus_channel="can0")
FORMATS = [
    ".log.gz",
    ".asc",
    ".asc.gz",
    ".blf",
    ".trc",
    ".trc.gz",
    ".csv",
    ".csv.gz",
    pytest.param(
        ".mf4",
        marks=pytest.mark.skipif(
            importlib.util.find_spec("asammdf") is None,
            reason="python-can writes and reads .mf4 only with asammdf (pip install 'vdp[mf4]')",
        ),
    ),
]


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    frames = list(Simulation(PROFILE, "stage1", seed=3, noise="realistic", duration=20.0).frames())
    return frames, tmp_path_factory.mktemp("formats")


def estimate(path: Path) -> RunResult:
    return replay(open_log(path, channel=PROFILE.bus_channel), Pipeline(PROFILE, EstimatorConfig(baseline=True)))


@pytest.fixture(scope="module")
def candump(drive):
    frames, d = drive
    path = d / "drive.log"
    assert write_log(iter(frames), path) == len(frames)
    res = estimate(path)
    # a drive that moves the estimates, so equal results mean something: stage 1 learnt
    # each parameter far past its prior (whether it calls it converged is not this test's)
    assert [w.stage for w in res.windows] == [1]
    for name in ("l_f", "h", "C_K"):
        e = res.parameters[name]
        assert e.samples > 500 and e.std < 0.1 * PROFILE.priors[name].std, e
    return res


@pytest.mark.parametrize("suffix", FORMATS)
def test_format_replays_like_candump(drive, candump, suffix):
    frames, d = drive
    path = d / f"drive{suffix}"
    assert write_log(iter(frames), path) == len(frames)
    res = estimate(path)
    assert res.log.frames == len(frames) and res.log.source["bad_lines"] == 0
    assert res.decode["errors"] == {} and res.decode["skipped_channel"] == 0
    assert len(res.windows) == len(candump.windows)
    for kind in ("parameters", "baseline_ekf"):
        for name, ref in getattr(candump, kind).items():
            got = getattr(res, kind)[name]
            # Timestamps are exact to the microsecond in every format; .asc restarts the
            # clock at 0, and time differences of absolute Unix times carry ~2e-7 s of
            # float rounding that relative times do not: the filters' results then differ
            # by a sample at the window's edge: a fraction of their own std, never in status.
            asc = suffix.startswith(".asc")
            assert got.status == ref.status, (kind, name)
            assert abs(got.samples - ref.samples) <= (2 if asc else 0), (kind, name)
            if asc:
                assert abs(got.value - ref.value) <= 0.25 * ref.std, (kind, name, got.value, ref.value, ref.std)
            else:
                assert got.value == pytest.approx(ref.value, rel=1e-6), (kind, name)
            assert got.std == pytest.approx(ref.std, rel=1e-2 if asc else 1e-4), (kind, name)
