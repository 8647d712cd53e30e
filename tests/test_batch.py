"""vdp batch: logs on a local Dask cluster into Parquet, drives combined per vehicle."""

import dataclasses
import gzip
import json
import math
import os
import subprocess
import sys

import pytest

pq = pytest.importorskip("pyarrow.parquet", reason="vdp batch needs the 'fleet' extra")
pytest.importorskip("distributed", reason="vdp batch needs the 'fleet' extra")

from vdp.cli import main  # noqa: E402
from vdp.cli.batch import read_manifest  # noqa: E402
from vdp.errors import ConfigError  # noqa: E402
from vdp.fleet import COMMON, Z_FLAG, combine, combined, weighted  # noqa: E402
from vdp.sim.run import simulate, write_log  # noqa: E402


def run_row(log, value, std, vehicle="car", parameter="l_f", status="converged", valid=True, frames=None):
    return {"log": log, "vehicle": vehicle, "parameter": parameter, "value": value, "std": std, "status": status,
            "valid": valid, "frames": frames, "duration_s": None if frames is None else frames / 600.0}  # fmt: skip


# -- the combiner ----------------------------------------------------------------


def test_combination_is_the_inverse_variance_mean_and_agreeing_drives_pass():
    rows = [run_row("a", 1.40, 0.002), run_row("b", 1.403, 0.003), run_row("c", 1.398, 0.002)]
    (veh,), zs = combine(rows)
    w = [1 / 0.002**2, 1 / 0.003**2, 1 / 0.002**2]
    mean = (1.40 * w[0] + 1.403 * w[1] + 1.398 * w[2]) / sum(w)
    assert veh["value"] == pytest.approx(mean, rel=1e-12)
    # the std: the independent part shrinks with the drives, the error they share (COMMON of the best
    # drive's std) does not
    c = COMMON
    assert veh["std"] == pytest.approx(math.sqrt((1 - c * c) / sum(w) + (c * 0.002) ** 2), rel=1e-12)
    assert veh["drives"] == 3 and veh["dof"] == 2
    assert veh["consistent"] and veh["flagged"] == []
    assert all(abs(z) < Z_FLAG for z in zs.values()) and len(zs) == 3


def test_a_disagreeing_drive_fails_the_chi2_test_and_is_flagged_alone():
    rows = [run_row(f"d{i}", 1.40 + 0.001 * (-1) ** i, 0.002) for i in range(4)]
    rows.append(run_row("odd", 1.43, 0.002))  # 15 sigma off the others
    (veh,), zs = combine(rows)
    assert not veh["consistent"] and veh["p_value"] < 1e-6
    assert veh["flagged"] == ["odd"]
    assert zs[("odd", "car", "l_f")] > Z_FLAG
    assert all(abs(zs[(f"d{i}", "car", "l_f")]) < Z_FLAG for i in range(4))
    assert veh["scale"] > 1  # the std the scatter supports is larger than the formal one
    # the combination is of the four that agree, and the retest is theirs
    assert veh["drives"] == 4 and veh["value"] == pytest.approx(1.40, abs=1e-9)
    assert veh["dof_kept"] == 3 and veh["chi2_kept"] == pytest.approx(4 * 0.5**2, rel=1e-9)
    assert veh["p_value_kept"] > 0.5 and veh["dof"] == 4


def test_two_drives_that_disagree_are_both_flagged():
    (veh,), _ = combine([run_row("a", 1.40, 0.002), run_row("b", 1.45, 0.002)])
    assert not veh["consistent"] and sorted(veh["flagged"]) == ["a", "b"] and veh["drives"] == 2


def test_only_converged_drives_enter_and_vehicles_are_kept_apart():
    rows = [
        run_row("a", 1.40, 0.002),
        run_row("b", 9.0, 0.3, status="not_identifiable"),  # the prior's number: left out
        run_row("c", math.nan, math.nan, status="invalid"),
        run_row("x", 1.20, 0.002, vehicle="other"),
        {"log": "gone", "vehicle": "car", "parameter": None, "status": "error"},
    ]
    out, zs = combine(rows)
    by = {v["vehicle"]: v for v in out}
    assert by["car"]["drives"] == 1 and by["car"]["runs"] == 3 and by["car"]["value"] == 1.40
    assert by["car"]["consistent"] is None and math.isnan(by["car"]["chi2"])  # one drive: nothing to test
    assert by["other"]["value"] == 1.20
    assert zs == {}


def test_weighted_of_one_drive_is_that_drive():
    assert weighted([2.0], [0.5]) == (2.0, 0.5)
    assert combined([2.0], [0.5]) == pytest.approx((2.0, 0.5), rel=1e-15)


def test_many_drives_do_not_shrink_the_std_below_what_they_share():
    """Drives of one car share the model's error, the profile's constants and the priors: n drives
    of std s combine to s sqrt((1 - c^2) / n + c^2), never below c s (independent: s / sqrt(n))."""
    for n in (2, 12, 400):
        rows = [run_row(f"d{i}", 1.40 + 0.001 * (i % 2), 0.002) for i in range(n)]
        (veh,), _ = combine(rows)
        assert veh["std"] == pytest.approx(0.002 * math.sqrt((1 - COMMON**2) / n + COMMON**2), rel=1e-9)
        assert veh["std"] > COMMON * 0.002 and veh["std"] > 0.002 / math.sqrt(n)
    # a drive added, however noisy, never widens the combination (nor leaves it wider than the best drive)
    stds = [0.002]
    for s in (0.004, 0.004, 0.004, 0.01, 0.0025):
        before = combined([1.4] * len(stds), stds)[1]
        stds.append(s)
        assert combined([1.4] * len(stds), stds)[1] <= before <= 0.002


def test_drives_not_valid_are_left_out_and_counted():
    """A converged drive vdp called not valid (a model mismatch, a profile the check found wrong)
    does not enter the combination; vehicles.parquet counts it."""
    rows = [run_row("a", 1.40, 0.002), run_row("b", 1.30, 0.002, valid=False), run_row("c", 1.25, 0.004, valid=False)]
    (veh,), _ = combine(rows)
    assert veh["drives"] == 1 and veh["value"] == 1.40 and veh["not_valid"] == 2 and veh["runs"] == 3
    (none,), _ = combine(rows[1:])
    assert none["drives"] == 0 and math.isnan(none["value"]) and none["not_valid"] == 2


def test_a_copy_of_a_log_counts_once():
    """A backup or a .gz of the same log replays to the very same result: one drive, not two."""
    rows = [run_row("a.log", 1.401, 0.002, frames=60000), run_row("b.log", 1.399, 0.002, frames=61000)]
    rows += [run_row("a-backup.log", 1.401, 0.002, frames=60000), run_row("a.log.gz", 1.401, 0.002, frames=60000)]
    (veh,), _ = combine(rows)
    assert veh["drives"] == 2 and veh["copies"] == ["a-backup.log", "a.log.gz"]
    assert veh["std"] == pytest.approx(combined([1.401, 1.399], [0.002, 0.002])[1], rel=1e-12)
    from vdp.cli.batch import combination_notes

    notes = combination_notes([veh])
    assert notes == ["car: 2 log(s) gave the very result of another and were counted once (a-backup.log, a.log.gz)"]
    # a copy of a drive vdp called not valid is one not-valid drive, not two
    bad = [run_row("n.log", 1.3, 0.002, valid=False, frames=9), run_row("n.log.gz", 1.3, 0.002, valid=False, frames=9)]
    (veh,), _ = combine(rows + bad)
    assert veh["not_valid"] == 1 and veh["copies"] == ["a-backup.log", "a.log.gz", "n.log.gz"]


def test_a_manifest_column_misspelt_is_refused(tmp_path):
    m = tmp_path / "m.csv"
    m.write_text("log,car,profile\na.log,carA,\n")
    with pytest.raises(ConfigError, match=r"unknown manifest column\(s\) 'car'.*columns are log,vehicle,profile"):
        read_manifest(str(m))
    m.write_text("log,vehicle_name\na.log,carA\n")
    with pytest.raises(ConfigError, match=r"'vehicle_name' \(did you mean 'vehicle'\?\)"):
        read_manifest(str(m))
    # as spreadsheets write them: names in any case, a trailing comma; a note beside all three columns
    m.write_text("Log,Vehicle,Profile,\na.log,carA,,\n")
    assert read_manifest(str(m)) == [(str(tmp_path / "a.log"), "carA", None)]
    m.write_text("log,vehicle,profile,notes\na.log,carA,,rainy\n")
    assert read_manifest(str(m)) == [(str(tmp_path / "a.log"), "carA", None)]


# -- inputs ------------------------------------------------------------------------


def test_manifest_paths_are_relative_to_it_and_a_bad_header_is_one_clear_error(tmp_path):
    m = tmp_path / "m.csv"
    (tmp_path / "p.toml").write_text("")
    m.write_text("log,vehicle,profile\nruns/a.log,car1,\n/abs/b.log,car2,p.toml\n\n")
    assert read_manifest(str(m)) == [
        (str(tmp_path / "runs" / "a.log"), "car1", None),
        ("/abs/b.log", "car2", str(tmp_path / "p.toml")),
    ]
    bad = tmp_path / "bad.csv"
    bad.write_text("file,car\na.log,x\n")
    with pytest.raises(ConfigError, match="log,vehicle,profile"):
        read_manifest(str(bad))


# -- end to end on a local cluster --------------------------------------------------


@pytest.fixture(scope="module")
def fleet(tmp_path_factory, repo_root):
    d = tmp_path_factory.mktemp("fleet")
    prof = repo_root / "profiles" / "paper.toml"
    for seed in (1, 2):
        frames, _ = simulate(prof, "stage1", seed=seed, noise="realistic", duration=20.0)
        write_log(frames, d / f"car1-{seed}.log")
    frames, _ = simulate(prof, "stage1", seed=3, noise="realistic", duration=20.0)
    write_log(frames, d / "car2-3.log")
    # truncated: a gzip cut in the middle of its stream (what it holds is read, the loss recorded)
    raw = (d / "car2-3.log").read_bytes()
    (d / "cut.log.gz").write_bytes(gzip.compress(raw)[:60000])
    (d / "garbage.log").write_bytes(bytes(range(256)) * 40)  # damaged beyond reading: an error
    (d / "manifest.csv").write_text(
        "log,vehicle,profile\n"
        f"car1-1.log,car1,{prof}\n"
        f"car1-2.log,car1,{prof}\n"
        f"car2-3.log,car2,{prof}\n"
        f"cut.log.gz,car2,{prof}\n"
        f"garbage.log,car2,{prof}\n"
        f"missing.log,car2,{prof}\n"
    )
    return d


def batch(d, workers=2):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
    return subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from vdp.cli import main; sys.exit(main())",
            "batch",
            "--manifest",
            str(d / "manifest.csv"),
            "--out",
            str(d / "out"),
            "--workers",
            str(workers),
            "--no-progress",
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )


@pytest.mark.slow
def test_batch_runs_the_fleet_records_bad_logs_and_resumes(fleet, repo_root):
    d = fleet
    first = batch(d)
    assert first.returncode == 1, first.stderr  # two logs failed, the rest went on
    assert "6 logs: 0 already done, 6 to run" in first.stdout
    runs = pq.read_table(d / "out" / "runs.parquet").to_pylist()
    logs = [r["log"] for r in runs]
    assert logs == sorted(logs)  # the table reads in the logs' order, each log's rows together
    by_log = {}
    for r in runs:
        by_log.setdefault(os.path.basename(r["log"]), []).append(r)
    assert set(by_log) == {"car1-1.log", "car1-2.log", "car2-3.log", "cut.log.gz", "garbage.log", "missing.log"}
    (miss,) = by_log["missing.log"]
    assert miss["status"] == "error" and "no such file" in miss["error"] and miss["parameter"] is None
    (bad,) = by_log["garbage.log"]
    assert bad["status"] == "error" and "garbage.log" in bad["error"]
    cut = by_log["cut.log.gz"]
    assert len(cut) == 7 and all(r["error"] is None and "ends early" in r["damage"] for r in cut)
    assert 0 < cut[0]["frames"] < by_log["car2-3.log"][0]["frames"]
    good = by_log["car1-1.log"]
    assert [r["parameter"] for r in good] == ["l_f", "h", "C_K", "C_alpha", "I_z", "I_x", "mass"]
    assert all(r["error"] is None and r["damage"] is None and r["frames"] > 10000 for r in good)
    assert all(r["duration_s"] > 19 for r in good)
    # a stage-1 drive: stage 2's parameters did not run, and their rows say why
    assert all(r["reason"] and "no window" in r["reason"] for r in good[:6] if r["status"] == "not_run")
    assert any(r["status"] == "not_run" for r in good[:6])
    # the mass's row: batch learns it by default (--mass auto), and says how far (a 20-s drive: not valid yet)
    m = good[6]
    assert m["status"] == "uncertain" and not m["valid"] and m["mass_mode"] == "auto" and "known to" in m["reason"]

    # the same numbers as vdp replay --json on the same log and profile
    out = d / "one.json"
    assert main(["replay", str(d / "car1-1.log"), "--profile", str(repo_root / "profiles" / "paper.toml"),
                 "--json", str(out), "--no-progress"]) == 0  # fmt: skip
    doc = json.loads(out.read_text())
    for r in good:
        p = doc["parameters"][r["parameter"]]
        std = None if r["std"] is None or r["std"] != r["std"] else r["std"]  # NaN in Parquet: not known
        assert (r["value"], std, r["status"], r["stage"]) == (p["value"], p["std"], p["status"], p["stage"])
        assert (r["valid"], r["reason"] if p.get("reason") else p.get("reason")) == (p["valid"], p.get("reason"))
    assert good[0]["frames"] == doc["log"]["frames"]
    for r in runs:  # each axle on C_alpha's row only (a stage-1 drive: none here)
        assert (r["C_alpha_front"] is None) or r["parameter"] == "C_alpha"

    veh = {(v["vehicle"], v["parameter"]): v for v in pq.read_table(d / "out" / "vehicles.parquet").to_pylist()}
    lf = veh[("car1", "l_f")]
    assert lf["drives"] == 2 and lf["runs"] == 2
    xs = [r["value"] for r in runs if r["vehicle"] == "car1" and r["parameter"] == "l_f"]
    assert min(xs) <= lf["value"] <= max(xs)
    car2 = [r for r in runs if r["vehicle"] == "car2" and r["parameter"] == "l_f"]
    assert veh[("car2", "l_f")]["runs"] == len(car2) == 2  # car2-3 and its cut copy
    assert veh[("car2", "l_f")]["drives"] == sum(r["status"] == "converged" for r in car2) >= 1

    # rerun: the four logs read are skipped, the two that failed are tried again;
    # the missing one has turned up meanwhile
    (d / "missing.log").write_bytes((d / "car1-2.log").read_bytes())
    parts = {p.name: p.stat().st_mtime_ns for p in (d / "out" / "parts").glob("*.parquet")}
    again = batch(d, workers=1)
    assert again.returncode == 1, again.stderr  # the garbage still fails
    assert "6 logs: 4 already done, 2 to run" in again.stdout, again.stdout + again.stderr
    after = {p.name: p.stat().st_mtime_ns for p in (d / "out" / "parts").glob("*.parquet")}
    assert sum(parts[k] == after[k] for k in parts) == 4
    runs = pq.read_table(d / "out" / "runs.parquet").to_pylist()
    assert {r["status"] for r in runs if r["log"].endswith("missing.log")} >= {"converged"}
    assert sum(r["log"].endswith("missing.log") for r in runs) == 7
    assert veh[("car1", "l_f")]["runs"] == 2  # the earlier vehicles.parquet
    veh = {(v["vehicle"], v["parameter"]): v for v in pq.read_table(d / "out" / "vehicles.parquet").to_pylist()}
    assert veh[("car2", "l_f")]["runs"] == 3  # car2-3, the cut copy, and car1-2's bytes as missing.log

    # the README's pandas lines read them (pandas comes with the fleet extra)
    import pandas as pd

    runs, veh = pd.read_parquet(d / "out" / "runs.parquet"), pd.read_parquet(d / "out" / "vehicles.parquet")
    lf = veh[(veh.vehicle == "car2") & (veh.parameter == "l_f")]
    assert list(lf.runs) == [3] and list(lf.columns[:2]) == ["vehicle", "parameter"]
    errors = runs[runs.status == "error"][["log", "error"]]
    assert len(errors) == 1 and errors.log.iloc[0].endswith("garbage.log")


@pytest.mark.slow
def test_local_cluster_listens_on_loopback_only():
    psutil = pytest.importorskip("psutil")
    import argparse

    from vdp.cli.batch import client

    cl, cluster = client(argparse.Namespace(scheduler=None, workers=1))
    try:
        me = psutil.Process()
        addrs = [
            c.laddr.ip
            for p in [me, *me.children(recursive=True)]
            for c in p.net_connections(kind="inet")
            if c.status == psutil.CONN_LISTEN
        ]
        assert addrs and set(addrs) == {"127.0.0.1"}
        assert cl.scheduler.address.startswith("tcp://127.0.0.1:")
    finally:
        cl.close()
        cluster.close()


def test_c_alphas_row_carries_each_axle():
    from types import SimpleNamespace

    from vdp.core.params import BY_NAME, NAMES
    from vdp.core.result import Estimate
    from vdp.fleet import Task, rows_from_result

    axles = {"C_alpha_front": 7e4, "C_alpha_front_std": 700.0, "C_alpha_rear": 6e4, "C_alpha_rear_std": 400.0}
    params = {
        n: Estimate(
            n,
            1.0,
            0.1,
            BY_NAME[n].unit,
            "uncertain",
            False,
            BY_NAME[n].stage,
            10,
            extra=axles if n == "C_alpha" else {},
        )
        for n in NAMES
    }
    res = SimpleNamespace(log=None, decode={}, windows=[], bus_time=None, frames=0, parameters=params, capabilities={})
    rows = {r["parameter"]: r for r in rows_from_result(res, Task("a.log", "car", "p.toml"))}
    assert {k: rows["C_alpha"][k] for k in axles} == axles
    assert all(rows[n]["C_alpha_front"] is None for n in NAMES if n != "C_alpha")


@pytest.mark.slow
def test_a_log_rerun_under_another_profile_counts_once(tmp_path, repo_root):
    """An edited profile (here a copy elsewhere) and a rerun: the log's earlier part is not
    combined with the new one (the drive would count twice and its std shrink by sqrt 2)."""
    prof = repo_root / "profiles" / "paper.toml"
    frames, _ = simulate(prof, "stage1", seed=1, noise="realistic", duration=20.0)
    write_log(frames, tmp_path / "a.log")
    (tmp_path / "manifest.csv").write_text(f"log,vehicle,profile\na.log,car,{prof}\n")
    assert batch(tmp_path, workers=1).returncode == 0
    copy = tmp_path / "edited.toml"
    copy.write_text(prof.read_text().replace('"../dbc/vdp.dbc"', f'"{repo_root / "dbc" / "vdp.dbc"}"'))
    (tmp_path / "manifest.csv").write_text(f"log,vehicle,profile\na.log,car,{copy}\n")
    again = batch(tmp_path, workers=1)
    assert again.returncode == 0 and "left out 1 earlier result" in again.stdout, again.stdout + again.stderr
    assert len(list((tmp_path / "out" / "parts" / "superseded").glob("*.parquet"))) == 1  # moved aside, not lost
    assert "left out" not in batch(tmp_path, workers=1).stdout  # said once
    runs = pq.read_table(tmp_path / "out" / "runs.parquet").to_pylist()
    assert len(runs) == 7 and {r["profile"] for r in runs} == {str(copy)}  # the six and the mass
    veh = pq.read_table(tmp_path / "out" / "vehicles.parquet").to_pylist()
    assert all(v["runs"] == 1 for v in veh)
    # the profile corrected in place (its wheel radius): the log runs again, not "1 already done"
    copy.write_text(copy.read_text().replace("wheel_radius = 0.3", "wheel_radius = 0.32", 1))
    again = batch(tmp_path, workers=1)
    assert "1 logs: 0 already done, 1 to run (1: its profile changed)" in again.stdout, again.stdout + again.stderr
    rerun = pq.read_table(tmp_path / "out" / "runs.parquet").to_pylist()
    assert len(rerun) == 7 and rerun[0]["profile_hash"] != runs[0]["profile_hash"]
    assert [r["value"] for r in rerun] != [r["value"] for r in runs]  # the new radius's result, not the old one


def test_a_result_is_done_only_for_the_same_log_profile_dbc_and_vdp(tmp_path, repo_root, monkeypatch):
    """A batch's result stands for the log's bytes, the profile's and its DBC's, and vdp's version:
    size and mtime alone kept the result of a profile corrected since.  A part written before
    these keys existed is run again."""
    import vdp
    from vdp.cli.batch import rerun_reason
    from vdp.fleet import RUN_COLUMNS, Task, profile_hash, run_key
    from vdp.profile import load_profile

    dbc = tmp_path / "car.dbc"
    dbc.write_bytes((repo_root / "dbc" / "vdp.dbc").read_bytes())
    prof = tmp_path / "car.toml"
    prof.write_text((repo_root / "profiles" / "paper.toml").read_text().replace('"../dbc/vdp.dbc"', '"car.dbc"'))
    log = tmp_path / "a.log"
    log.write_text("(1.000000) can0 123#00\n" * 10)
    t = Task(str(log), "car", str(prof))

    def key():
        return profile_hash(load_profile(prof))

    rows = [{**dict.fromkeys(RUN_COLUMNS), "parameter": "l_f", "error": None, "mass_mode": "auto"}]
    rows[0].update(run_key(t.log, key()))
    assert rerun_reason(rows, t, key()) is None
    assert rerun_reason([], t, key()) == "new"
    old = [{k: v for k, v in rows[0].items() if k not in ("log_hash", "profile_hash", "vdp_version")}]
    assert rerun_reason(old, t, key()) == "an earlier vdp's result"
    monkeypatch.setattr(vdp, "__version__", "0.0.1")
    assert rerun_reason(rows, t, key()) == "another vdp version"
    monkeypatch.undo()
    # the log's bytes changed, its size and mtime put back as they were
    st = log.stat()
    log.write_text("(1.000000) can0 124#00\n" * 10)
    os.utime(log, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert rerun_reason(rows, t, key()) == "the log changed"
    rows = [{**rows[0], **run_key(t.log, key())}]
    assert rerun_reason(rows, t, key()) is None
    prof.write_text(prof.read_text().replace("wheel_radius = 0.3", "wheel_radius = 0.32", 1))
    assert rerun_reason(rows, t, key()) == "its profile changed"
    rows = [{**rows[0], **run_key(t.log, key())}]
    with dbc.open("a") as f:
        f.write('\nCM_ "a comment added to the DBC";\n')
    assert rerun_reason(rows, t, key()) == "its profile changed"
    # a result made with another mass mode is run again (vdp batch --mass MODE); one from before the
    # modes says only whether the mass was put in: on, or off
    rows = [{**rows[0], **run_key(t.log, key()), "mass_learnt": True, "mass_mode": "auto"}]
    assert t.mass == "auto" and rerun_reason(rows, t, key()) is None
    assert rerun_reason(rows, dataclasses.replace(t, mass="on"), key()) == "--mass on now"
    rows = [{**rows[0], "mass_learnt": False, "mass_mode": None}]
    assert rerun_reason(rows, t, key()) == "--mass auto now"
    assert rerun_reason(rows, dataclasses.replace(t, mass="off"), key()) is None
    assert t.key == dataclasses.replace(t, mass="on").key  # one part per log: the rerun replaces it


def test_batch_mass_makes_each_task_learn_the_mass(tmp_path, repo_root):
    """`vdp batch --mass MODE`: each log's task takes the mass so (fleet.replay_log with that mode);
    auto without it, on for the bare flag (a switch before the modes)."""
    from vdp.cli import build_parser
    from vdp.cli.batch import tasks

    prof = repo_root / "profiles" / "paper.toml"
    m = tmp_path / "m.csv"
    m.write_text(f"log,vehicle,profile\na.log,car,{prof}\n")
    for flags, mode in (([], "auto"), (["--mass"], "on"), (["--mass", "off"], "off")):
        args = build_parser("batch").parse_args(["batch", "--manifest", str(m), "--out", str(tmp_path), *flags])
        (t,) = tasks(args)
        assert t.mass == mode


def test_an_out_folder_that_takes_no_file_is_refused_before_the_batch(tmp_path, capsys):
    """--out on a folder nothing can be written in ran the first log, then a traceback."""
    code = main(["batch", str(tmp_path / "a.log"), "--out", "/proc", "--workers", "1", "--no-progress"])
    err = capsys.readouterr()
    assert code == 2 and "logs:" not in err.out, err.out  # before the batch starts
    assert err.err.startswith("vdp batch: error: --out /proc: cannot write in it") and len(err.err.splitlines()) == 1


def test_a_tasks_warnings_name_its_log(monkeypatch, caplog):
    """Many logs run at once in a worker: a warning from deep in the pipeline names its log, and
    records outside a task (or of other libraries) are left as they are."""
    import logging

    from vdp import fleet

    def replay(path, profile, mass="auto"):
        logging.getLogger("vdp.profilecheck").warning("vehicle.mass is %d kg", 1600)
        logging.getLogger("vdp.io.logs").warning("%s: %s", path, "damaged in 1 place(s)")  # names it already
        logging.getLogger("vdp.io.decoder").warning("3 bad frames in a row")  # no arguments
        logging.getLogger("otherlib").warning("not ours")  # (dask's own loggers do not propagate to caplog)
        raise ConfigError("stop here")

    monkeypatch.setattr(fleet, "replay_log", replay)
    # the factory stays for the process (a worker's): put back this test process's own
    monkeypatch.setattr(logging, "_logRecordFactory", logging.getLogRecordFactory())
    path = "/data/car%1/drive.log"  # a '%' in the path must not meet the record's formatting
    with caplog.at_level(logging.WARNING):
        rows = fleet.run_task(fleet.Task(path, "car", "p.toml"))
        logging.getLogger("vdp.pipeline").warning("after the task")
    assert rows[0]["error"] == "stop here"
    got = [r.getMessage() for r in caplog.records]
    assert got == [
        f"{path}: vehicle.mass is 1600 kg",
        f"{path}: damaged in 1 place(s)",
        f"{path}: 3 bad frames in a row",
        "not ours",
        "after the task",
    ]


def test_a_manifest_in_a_log_directory_is_not_taken_for_a_log(tmp_path, capsys):
    """``vdp batch DIR`` where DIR also holds the manifest (a .csv, as python-can's CSV logs are):
    the manifest is left out with a word, a CSV log of frames is kept."""
    from vdp.cli.batch import expand

    (tmp_path / "fleet.csv").write_text("log,vehicle,profile\na.log,car,p.toml\n")
    (tmp_path / "quoted.csv").write_text('"log","vehicle"\na.log,car\n')  # csv's quoting, as read_manifest reads it
    (tmp_path / "frames.csv").write_text("timestamp,arbitration_id,extended,remote,error,dlc,data\n")
    (tmp_path / "a.log").write_text("(1.0) can0 123#00\n")
    got = expand([str(tmp_path)])
    assert got == [str(tmp_path / "a.log"), str(tmp_path / "frames.csv")]
    err = capsys.readouterr().err
    assert "fleet.csv is a manifest, not a log; left out (give it as --manifest)" in err
    assert "quoted.csv is a manifest" in err


def test_a_manifests_missing_profile_names_its_line_and_where_it_was_looked_for(tmp_path):
    m = tmp_path / "m.csv"
    m.write_text("log,vehicle,profile\na.log,car,\nb.log,car,nope.toml\n")
    with pytest.raises(ConfigError, match=r"line 3: profile nope.toml: no such file .*manifest's folder"):
        read_manifest(str(m))


def test_a_log_listed_under_two_vehicles_is_refused(tmp_path, repo_root):
    """A drive under two names would count for both vehicles: one clear error before any run."""
    from argparse import Namespace

    from vdp.cli.batch import tasks

    prof = repo_root / "profiles" / "paper.toml"
    m = tmp_path / "m.csv"
    m.write_text(f"log,vehicle,profile\na.log,carA,{prof}\nb.log,carA,{prof}\na.log,carB,{prof}\na.log,carA,{prof}\n")
    args = Namespace(manifest=str(m), logs=[], profile=None, vehicle=None)
    with pytest.raises(ConfigError, match=r"a\.log is listed 2 times, as vehicle 'carA' .*'carB'.*list it once"):
        tasks(args)
    m.write_text(f"log,vehicle,profile\na.log,carA,{prof}\na.log,carA,{prof}\n")  # the very same twice: one task
    assert len(tasks(args)) == 1


def test_a_glob_that_matches_nothing_is_reported_not_passed_over(tmp_path, repo_root):
    from argparse import Namespace

    from vdp.cli.batch import expand, tasks

    (tmp_path / "a.log").write_text("")
    missed: list[str] = []
    assert expand([str(tmp_path / "*.log"), str(tmp_path / "typo*.log")], missed) == [str(tmp_path / "a.log")]
    assert missed == [f"{tmp_path / 'typo*.log'}: no file matches"]
    args = Namespace(manifest=None, logs=[str(tmp_path / "typo*.log")], profile=None, vehicle=None)
    with pytest.raises(ConfigError, match=r"no logs to run: .*typo.*no file matches"):
        tasks(args, [])


def test_simulate_makes_the_folder_it_writes_into(tmp_path):
    out = tmp_path / "new" / "sub" / "d.log"
    assert main(["simulate", "--scenario", "stage1", "--duration", "3", "--out", str(out)]) == 0
    assert out.is_file() and out.with_name("d.truth.json").is_file()


def test_the_fleet_picture_shows_each_drive_its_combination_and_the_one_that_disagrees(tmp_path):
    """vdp batch --plot: per vehicle and parameter, each drive ± 2σ, the combination as a band,
    the flagged drive red, a drive that did not converge hollow (it is not used)."""
    from matplotlib.colors import to_rgba

    from vdp.report import fleet_figure, fleet_plot

    rows = [run_row(f"d{i}.log", 1.40 + 0.001 * (-1) ** i, 0.002) for i in range(4)]
    rows.append(run_row("odd.log", 1.43, 0.002))
    rows.append(run_row("loose.log", 1.2, 0.3, status="not_identifiable"))
    vehicles, _ = combine(rows)
    fig = fleet_figure(rows, vehicles)
    (ax,) = fig.axes
    marks = {c.lines[0].get_ydata()[0]: c.lines[0] for c in ax.containers}  # y = the drive's row
    logs = sorted(r["log"] for r in rows)
    odd, loose, d0 = (marks[logs.index(n)] for n in ("odd.log", "loose.log", "d0.log"))
    assert to_rgba(odd.get_color()) == to_rgba("tab:red")  # flagged: disagrees with the others
    assert to_rgba(d0.get_color()) == to_rgba("black") and to_rgba(d0.get_mfc()) == to_rgba("black")
    assert to_rgba(loose.get_mfc()) == to_rgba("white")  # not converged: hollow
    band = list(ax.patches)  # the combination ± 2σ
    assert len(band) == 1
    x0, x1 = band[0].get_x(), band[0].get_x() + band[0].get_width()
    (veh,) = vehicles
    assert x0 == pytest.approx(veh["value"] - 2 * veh["std"]) and x1 == pytest.approx(veh["value"] + 2 * veh["std"])
    assert [t.get_text().split(" =")[0] for t in ax.texts] == ["χ² p of the rest"]  # odd.log left out
    pair = [run_row("a.log", 1.40, 0.002), run_row("b.log", 1.45, 0.002)]  # both flagged, both kept
    (pax,) = fleet_figure(pair, combine(pair)[0]).axes
    assert [t.get_text().split(" =")[0] for t in pax.texts] == ["χ² p"]
    fleet_plot(rows, vehicles, tmp_path / "fleet.png")
    assert (tmp_path / "fleet.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_names_that_read_as_math_are_drawn_as_text(tmp_path):
    """A vehicle or log named "$^$" raised in matplotlib's math parser at the end of a batch."""
    from vdp.report import fleet_plot

    rows = [run_row("a$^$.log", 1.40, 0.002, vehicle="$^$"), run_row("b.log", 1.41, 0.002, vehicle="$^$")]
    fleet_plot(rows, combine(rows)[0], tmp_path / "fleet.png")
    assert (tmp_path / "fleet.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_vehicle_of_hundreds_of_drives_keeps_the_fleet_picture_readable():
    """Beyond NAMED_DRIVES a vehicle's drives are still each drawn, but no longer named a row each,
    and the figure stops growing (300 drives had made it ~90 inches tall)."""
    from vdp.report import NAMED_DRIVES, fleet_figure

    few = [run_row(f"d{i:03d}.log", 1.40 + 0.001 * (i % 3), 0.002) for i in range(NAMED_DRIVES)]
    many = [run_row(f"d{i:03d}.log", 1.40 + 0.001 * (i % 3), 0.002) for i in range(300)]
    (ax_few,), (ax_many,) = (fleet_figure(r, combine(r)[0]).axes for r in (few, many))
    assert len(ax_many.containers) == 300 and len(ax_few.containers) == NAMED_DRIVES  # every drive drawn
    assert ax_many.figure.get_figheight() == ax_few.figure.get_figheight() < 15
    assert [t.get_text() for t in ax_few.get_yticklabels()][:2] == ["d000.log", "d001.log"]
    assert ax_many.get_yticklabels() == [] and "300 drives" in ax_many.get_ylabel()


def test_one_vehicle_under_two_profiles_is_named(tmp_path, repo_root, capsys):
    """Two cars under one vehicle name would be combined as one: said on stderr (a copy of the
    same profile file is not another profile)."""
    from argparse import Namespace

    from vdp.cli.batch import tasks

    paper = repo_root / "profiles" / "paper.toml"
    (tmp_path / "copy.toml").write_bytes(paper.read_bytes())
    m = tmp_path / "m.csv"
    m.write_text(f"log,vehicle,profile\na.log,car,{paper}\nb.log,car,copy.toml\n")
    args = Namespace(manifest=str(m), logs=[], profile=None, vehicle=None)
    assert len(tasks(args)) == 2 and "profiles" not in capsys.readouterr().err
    m.write_text(f"log,vehicle,profile\na.log,car,{paper}\nb.log,car,{repo_root / 'profiles' / 'toyota_rav4.toml'}\n")
    assert len(tasks(args)) == 2
    assert "vehicle 'car' has drives under 2 profiles" in capsys.readouterr().err
