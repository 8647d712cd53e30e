"""Each shipped car, from its own signals only: a simulated drive through its own DBC
decodes cleanly, and each stage (and I_x) either runs or says exactly which channel the
car lacks.  No add-on sensors here (tests/test_profiles.py adds them to reach both stages
on every layout)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from vdp import channels
from vdp.core.estimator import EstimatorConfig
from vdp.pipeline import Pipeline
from vdp.profile import load_profile
from vdp.replay import replay_log
from vdp.sim.run import Simulation, write_log

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted(p.stem for p in (ROOT / "profiles").glob("*.toml"))
STAGES = {"1": ("l_f", "h", "C_K"), "2": ("C_alpha", "I_z"), "I_x": ("I_x",)}
# what each car runs from its own signals (docs/PROFILES.md's table says why)
RUNS = {
    "paper": {"1", "2", "I_x"},
    "paper_status": {"1", "2", "I_x"},  # paper with the gates' status flags mapped (core.gates)
    "ford_escape_2020": {"1", "2", "I_x"},
    "vw_golf_mk7": {"1", "2"},  # drive torque = engine torque x the DSG's ratio; no roll-rate gyro
    "toyota_rav4": {"2"},  # stage 2 standalone on the published l_f; no wheel torque
    "hyundai_elantra_2017": {"1", "2"},  # engine torque % x the ratio of the reported gear; no roll-rate gyro
    "hyundai_ioniq5_2022": set(),
}


@pytest.fixture(autouse=True)
def cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("VDP_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "vdp-cache"))
    logging.getLogger("vdp.sim.encode").setLevel(logging.ERROR)


def car(name):
    prof = load_profile(ROOT / "profiles" / f"{name}.toml")
    if prof.dbc.suffix == ".dbc" and "opendbc" in str(prof.dbc):
        pytest.importorskip("opendbc")
    return prof


def needs(prof, stage: str) -> tuple[str, ...]:
    return {"1": channels.STAGE1_NEEDS, "2": channels.STAGE2_NEEDS, "I_x": channels.IX_NEEDS}[stage]


def test_every_shipped_profile_is_listed():
    assert set(RUNS) == set(SHIPPED)


@pytest.mark.parametrize("name", SHIPPED)
def test_each_stage_runs_or_names_exactly_what_the_car_lacks(name):
    prof = car(name)
    caps = Pipeline(prof).capabilities()
    for stage in STAGES:
        missing = prof.missing(needs(prof, stage))
        if stage in RUNS[name]:
            assert caps[stage] is None, (stage, caps[stage])
        elif missing:
            # each lacking channel by name, and only those
            assert f"(the profile maps no {', '.join(missing)})" in caps[stage], (stage, caps[stage])
        else:  # stage 2 waits for stage 1's l_f: it says what to give instead
            assert stage == "2" and "l_f" in caps[stage] and "stage 1 cannot run" in caps[stage]


@pytest.mark.parametrize("name", SHIPPED)
def test_a_drive_through_its_own_dbc_decodes_every_mapped_channel(name):
    prof = car(name)
    pipe = Pipeline(prof, EstimatorConfig(baseline=False))
    for msg in Simulation(prof, "stage1", seed=3, duration=4.0).frames():
        pipe.feed(msg)
    st = pipe.decoder.stats.as_dict()
    assert st["errors"] == {} and st["invalid_samples"] == {} and st["unknown_ids"] == []
    mapped = set(prof.channels) | set(prof.composites)
    assert set(st["samples"]) == mapped  # composites (the axle torques from the sources) too


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in SHIPPED if n != "paper"])  # the paper car: everywhere else
def test_the_paper_drive_through_its_own_dbc_runs_what_it_can(name, tmp_path):
    """The whole paper drive (112 s) through the car's own DBC, logged and replayed as a user
    does (a block at a time where the log allows): each stage that can run, runs (its
    parameters took samples); the others are not_run with the capability's reason."""
    prof = car(name)
    log = tmp_path / "paper.log"
    write_log(Simulation(prof, "paper", seed=5, noise="realistic").frames(), log, prof.bus_channel or "can0")
    res, _ = replay_log(log, lambda: Pipeline(prof, EstimatorConfig(baseline=False)), channel=prof.bus_channel)
    assert res.decode["errors"] == {}
    for stage, params in STAGES.items():
        for p in params:
            e = res.parameters[p]
            if stage in RUNS[name]:
                assert e.status != "not_run" and e.samples > 0, (p, e)
            else:
                assert e.status == "not_run" and not e.valid, (p, e)
                if stage != "I_x":  # I_x shares stage 2's samples, run or not
                    assert e.samples == 0, (p, e)
