"""vdp replay end to end: the JSON contract scripts rely on, the table, the plot."""

import json

import pytest

from vdp.cli import main
from vdp.core.params import NAMES
from vdp.sim.run import simulate, write_log, write_truth


@pytest.fixture(scope="module")
def drive(tmp_path_factory, repo_root):
    d = tmp_path_factory.mktemp("replay")
    frames, truth = simulate(repo_root / "profiles" / "paper.toml", "stage1", seed=5, noise="realistic", duration=20.0)
    log = d / "drive.log"
    write_log(frames, log)
    write_truth(truth, d / "drive.truth.json")
    return d, log


def test_replay_writes_the_documented_json_and_a_plot(drive, repo_root, capsys):
    d, log = drive
    out, png = d / "out.json", d / "out.png"
    code = main(
        [
            "replay",
            str(log),
            "--profile",
            str(repo_root / "profiles" / "paper.toml"),
            "--json",
            str(out),
            "--plot",
            str(png),
            "--truth",
            str(d / "drive.truth.json"),
            "--baseline",
            "ekf",
        ]
    )
    assert code == 0
    res = json.loads(out.read_text())
    for key in ("parameters", "baseline_ekf", "windows", "log"):
        assert key in res
    # the six and the mass after them (learnt by default: core.mass); the EKF baseline is of the six
    assert list(res["parameters"]) == [*NAMES, "mass"] and list(res["baseline_ekf"]) == list(NAMES)
    m = res["parameters"]["mass"]
    assert m["status"] != "not_run" and m["extra"]["profile_mass"] == 1600.0 and m["extra"]["rows"] > 0
    for kind in ("parameters", "baseline_ekf"):
        for p in res[kind].values():
            assert {"value", "std", "unit", "valid", "stage"} <= set(p)
    assert res["parameters"]["l_f"]["stage"] == 1 and res["parameters"]["I_z"]["stage"] == 2
    assert res["log"]["frames"] > 10000 and "decode" in res["log"]
    assert any(w["stage"] == 1 for w in res["windows"])
    # 20 s of the sinusoid are enough for stage 1; stage 2 never ran and says so
    assert res["parameters"]["l_f"]["valid"]
    assert res["parameters"]["C_alpha"]["status"] == "not_run" and not res["parameters"]["C_alpha"]["valid"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20000
    text = capsys.readouterr().out
    assert "l_f" in text and "truth" in text and "stage 2: the drive had" in text
    assert "EKF value" in text and "EKF err" in text
    # without the baseline, no column of dashes for it
    assert main(["replay", str(log), "--profile", str(repo_root / "profiles" / "paper.toml"), "--no-progress"]) == 0
    text = capsys.readouterr().out
    head = next(ln for ln in text.splitlines() if ln.startswith("param "))
    assert "EKF" not in head and "C_K" in text and " - " in next(ln for ln in text.splitlines() if ln.startswith("C_K"))


def test_json_never_carries_nan(drive, repo_root):
    d, log = drive
    out = d / "nan.json"
    # stage 2 never runs here: its std comes from the prior, value and std are finite, never NaN
    main(["replay", str(log), "--profile", str(repo_root / "profiles" / "paper.toml"), "--json", str(out)])
    text = out.read_text()
    assert "NaN" not in text and "Infinity" not in text
    res = json.loads(text)
    # the EKF baseline runs only when asked (--baseline ekf); its key is there, empty
    assert "baseline_ekf" in res and res["baseline_ekf"] is None
    assert list(res["parameters"]) == [*NAMES, "mass"]


def test_per_axle_reports_each_axle_in_c_alphas_extra(drive, repo_root, capsys):
    d, log = drive
    out = d / "axles.json"
    prof = str(repo_root / "profiles" / "paper.toml")
    assert main(["replay", str(log), "--profile", prof, "--json", str(out), "--per-axle", "--no-progress"]) == 0
    e = json.loads(out.read_text())["parameters"]["C_alpha"]
    x = e["extra"]
    # stage 2 never ran in this drive: both axles are the prior's, and not valid, with the reason
    assert x["C_alpha_front"] == x["C_alpha_rear"] == e["value"]
    assert x["per_axle_valid"] is False and x["per_axle_reason"] == "stage 2 has not run"
    text = capsys.readouterr().out
    assert "C_alpha per axle (C_alpha is their mean): front" in text and "not valid: stage 2 has not run" in text
    # per axle is the default: the same numbers without the flag
    main(["replay", str(log), "--profile", prof, "--json", str(out), "--no-progress"])
    assert json.loads(out.read_text())["parameters"]["C_alpha"]["extra"] == x
    # --one-c: one C_alpha for both axles, no per-axle numbers
    main(["replay", str(log), "--profile", prof, "--json", str(out), "--one-c", "--no-progress"])
    assert "extra" not in json.loads(out.read_text())["parameters"]["C_alpha"]


def test_baseline_flags_that_contradict_are_refused(drive, capsys):
    _, log = drive
    assert main(["replay", str(log), "--baseline", "ekf", "--no-ekf", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "--baseline ekf and --no-ekf" in err


@pytest.mark.parametrize("bad,needle", [("missing.log", "no such"), ("empty.log", "empty")])
def test_bad_input_is_one_line_and_exit_2(drive, capsys, bad, needle):
    d, _ = drive
    path = d / bad
    if bad == "empty.log":
        path.write_text("")
    code = main(["replay", str(path)])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and needle in err.lower() and "Traceback" not in err


def test_the_plots_trace_is_thinned_not_grown(drive, repo_root, monkeypatch):
    """With trace_max, a long log's trace keeps at most that many rows, spread over the whole
    drive (every other row dropped and the spacing doubled each time it fills)."""
    from vdp.core.estimator import EstimatorConfig
    from vdp.io.logs import open_log
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile
    from vdp.replay import replay

    _, log = drive
    profile = load_profile(repo_root / "profiles" / "paper.toml")
    full = replay(open_log(log), Pipeline(profile, EstimatorConfig(baseline=False))).trace
    thin = replay(open_log(log), Pipeline(profile, EstimatorConfig(baseline=False, trace_max=50))).trace
    assert len(full) > 190  # a row every 0.1 s of the 20 s drive
    assert 25 <= len(thin) < 50
    assert thin[0] == full[0] and full[-1][0] - thin[-1][0] < 20.0 / 25
    dt = [b[0] - a[0] for a, b in zip(thin, thin[1:])]
    assert max(dt) < 4 * 0.1 * 2**3  # three thinnings at most: 200 rows into fewer than 50
    assert all(d > 0 for d in dt)
    # vdp replay --plot caps its trace so
    from vdp import pipeline

    seen = {}
    orig = pipeline.EstimatorConfig

    def spy(*a, **kw):
        seen.update(kw)
        return orig(*a, **kw)

    monkeypatch.setattr(pipeline, "EstimatorConfig", spy)  # (pipeline.run_config makes every run's)
    png = log.parent / "thin.png"
    assert main(["replay", str(log), "--profile", str(repo_root / "profiles" / "paper.toml"), "--plot", str(png)]) == 0
    assert seen["trace_max"] == pipeline.PLOT_ROWS and png.stat().st_size > 20000


def test_the_readmes_profile_path_works_from_any_directory(drive, monkeypatch, capsys):
    d, log = drive
    monkeypatch.chdir(d)  # not the checkout: profiles/paper.toml is the shipped one
    assert main(["replay", str(log), "--profile", "profiles/paper.toml", "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["replay", str(log), "--profile", "profiles/nosuch.toml", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "no such profile file" in err and str(d) in err


def test_a_skipped_line_is_warned_of_once(drive, repo_root, tmp_path, caplog):
    """The profile check reads the log before the replay does: only the replay warns."""
    _, log = drive
    cut = tmp_path / "cut.log"
    text = log.read_text()
    cut.write_text(text[: len(text) // 2].rsplit("#", 1)[0] + "#ABC\n")  # the last line cut to an odd payload
    with caplog.at_level("WARNING", logger="vdp.io.logs"):
        assert main(["replay", str(cut), "--profile", str(repo_root / "profiles" / "paper.toml"), "--no-progress"]) == 0
    assert caplog.text.count("skipped 1 bad line") == 1, caplog.text


def test_the_hints_do_not_repeat_the_reason_the_table_gave():
    """Each "!" line under the table gives a parameter's reason; its hint under progress then says
    only what to do, not the reason again (a new user read every reason twice)."""
    from types import SimpleNamespace

    from vdp.cli.replay import _coaching

    why = "model mismatch: innovations 1.9x the size a matching model leaves"
    hint = f"not valid: {why}; more of the same will not fix it"
    params = {
        "C_alpha": SimpleNamespace(status="uncertain", reason=why, hint=hint),
        "I_x": SimpleNamespace(status="uncertain", reason=None, hint="weave at 0.5-1 Hz"),
        "l_f": SimpleNamespace(status="converged", reason=None, hint="done"),
    }
    coaching = {"stages": {"1": {"progress": 1.0}, "2": {"progress": 0.5}}, "next": "weave"}
    res = SimpleNamespace(coaching=coaching, parameters=params)
    assert _coaching(res) == [
        "progress: stage 1 100 %, stage 2 50 %; next: weave",
        "  C_alpha: not valid (reason above); more of the same will not fix it",
        "  I_x: weave at 0.5-1 Hz",
    ]
    # a stage this car cannot run shows no percentage (a new user read "stage 2 33 %" as on its way)
    stages = {"1": {"progress": 1.0, "can_run": True}, "2": {"progress": 0.5, "can_run": False}}
    res = SimpleNamespace(coaching={**coaching, "stages": stages}, parameters={})
    assert _coaching(res) == ["progress: stage 1 100 %, stage 2 cannot run; next: weave"]


@pytest.mark.parametrize(
    "name, said",
    [("d.txt", "vdp cannot replay '.txt' logs; write one of .log"), ("d.db", "vdp cannot replay '.db'")],
)
def test_simulate_refuses_a_format_vdp_cannot_read_back_before_writing_anything(tmp_path, capsys, name, said):
    """python-can writes .txt (a printout) and .db, which no reader of vdp's takes back: a new user
    simulated into one and then could not replay it."""
    assert main(["simulate", "--scenario", "stage1", "--duration", "2", "--out", str(tmp_path / name)]) == 2
    assert said in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # no truth file left behind without its log


def test_simulate_names_the_wheelbase_for_an_l_f_beyond_it(tmp_path, capsys):
    assert main(["simulate", "--param", "l_f=13", "--out", str(tmp_path / "d.log")]) == 2
    err = capsys.readouterr().err
    assert "must lie inside the wheelbase" in err and "give --param l_f between 0 and" in err
    assert "Traceback" not in err


def test_replay_of_a_folder_or_another_tools_csv_says_what_it_is(tmp_path, capsys, repo_root):
    prof = str(repo_root / "profiles" / "paper.toml")
    assert main(["replay", str(tmp_path), "--profile", prof]) == 2
    assert "is a directory, not a log file; vdp batch replays a folder's logs" in capsys.readouterr().err
    other = tmp_path / "other.csv"
    other.write_text("time,id,data\n1.0,0x123,00\n")
    assert main(["replay", str(other), "--profile", prof]) == 2
    assert "timestamp,arbitration_id,extended,remote,error,dlc,data" in capsys.readouterr().err


def test_a_closed_pipe_does_not_cost_the_files(drive, repo_root):
    """`vdp replay LOG --json F | head -1`: head closes the pipe before the table is printed; the
    JSON was written all the same (it had been written after the table, and lost with exit 0)."""
    import subprocess
    import sys

    d, log = drive
    out = d / "piped.json"
    vdp = f"{sys.executable} -c 'import sys; from vdp.cli import main; sys.exit(main(sys.argv[1:]))'"
    cmd = f"{vdp} replay {log} --profile {repo_root / 'profiles' / 'paper.toml'} --json {out} --no-progress | head -1"
    run = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, timeout=300)
    assert run.stdout.count("\n") == 1 and out.is_file(), run.stderr[-2000:]
    assert json.loads(out.read_text())["parameters"]["l_f"]["value"] is not None


def test_simulate_repeat_makes_one_long_log_of_one_car(tmp_path, capsys):
    """vdp simulate --repeat N: N drives of the scenario, seeds SEED.., 1 s apart in one log; the
    truth holds every drive's seed, start and segments on the log's clock."""
    from vdp.io.logs import open_log
    from vdp.sim.run import REPEAT_GAP

    out = tmp_path / "long.log"
    args = ["simulate", "--scenario", "stage1", "--duration", "6", "--seed", "4", "--repeat", "3", "--out", str(out)]
    assert main(args) == 0
    assert "simulated stage1 x 3: 20.0 s" in capsys.readouterr().out
    truth = json.loads(out.with_name("long.truth.json").read_text())
    assert [(d["seed"], d["start"]) for d in truth["repeat"]] == [
        (4, 0.0),
        (5, 6 + REPEAT_GAP),
        (6, 12 + 2 * REPEAT_GAP),
    ]
    assert truth["duration"] == 20.0 and truth["segments"][-1]["end"] == 20.0
    t = [m.timestamp for m in open_log(out)]
    assert t == sorted(t) and t[-1] - t[0] < 20.0 + 1e-6
    gaps = [b - a for a, b in zip(t, t[1:]) if b - a > 0.5]
    assert len(gaps) == 2  # the silence between drives
    assert main(["simulate", "--model", "brush", "--repeat", "2", "--out", str(tmp_path / "b.log")]) == 2
    assert "--repeat applies to --model vdp only" in capsys.readouterr().err


def test_a_name_that_reads_as_math_is_plotted_as_text(drive, repo_root, tmp_path, capsys):
    """A vehicle (and a log) named "$^$" went to matplotlib's math parser through the plot's
    title and raised after the whole replay; the title is the names as given."""
    import matplotlib.pyplot as plt

    from vdp import report

    _, log = drive
    prof = tmp_path / "car.toml"
    paper = repo_root / "profiles" / "paper.toml"
    text = paper.read_text().replace('"../dbc/vdp.dbc"', f'"{repo_root / "dbc" / "vdp.dbc"}"')
    prof.write_text(text.replace('name = "paper"', 'name = "$^$"', 1))
    odd = tmp_path / "a$^$.log"
    odd.symlink_to(log)
    png = tmp_path / "p.png"
    assert main(["replay", str(odd), "--profile", str(prof), "--plot", str(png), "--no-progress"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    fig = report.figure([], [], title="a$^$.log: $^$")
    try:
        fig.canvas.draw()
        assert fig.get_suptitle() == "a$^$.log: $^$"
    finally:
        plt.close(fig)


@pytest.mark.parametrize("which", ["the log", "a symlink to the log", "the profile", "the truth"])
def test_an_output_that_is_an_input_is_refused_before_the_replay(drive, repo_root, tmp_path, capsys, which):
    """`vdp replay drive.log --json drive.log` wrote the JSON over the log and exited 0: an output
    that is an input (by name, or the same file by another) is one line, exit 2, nothing touched."""
    d, log = drive
    copy = tmp_path / "drive.log"
    copy.write_bytes(log.read_bytes())
    prof = tmp_path / "car.toml"
    paper = (repo_root / "profiles" / "paper.toml").read_text()
    prof.write_text(paper.replace('"../dbc/vdp.dbc"', f'"{repo_root / "dbc" / "vdp.dbc"}"'))
    truth = tmp_path / "drive.truth.json"
    truth.write_text((d / "drive.truth.json").read_text())
    (tmp_path / "alias.json").symlink_to(copy)
    out = {"the log": copy, "a symlink to the log": tmp_path / "alias.json", "the profile": prof, "the truth": truth}
    before = {p: p.read_bytes() for p in (copy, prof, truth)}
    args = ["replay", str(copy), "--profile", str(prof), "--truth", str(truth), "--json", str(out[which])]
    assert main([*args, "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--json {out[which]}: is " in err and "give --json another file" in err, err
    assert {p: p.read_bytes() for p in before} == before


def test_two_outputs_on_one_file_are_refused(drive, tmp_path, capsys):
    _, log = drive
    same = tmp_path / "t.csv"
    assert main(["replay", str(log), "--series", str(same), "--channels", str(same), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--channels" in err and "is also the file of --series" in err and not same.exists()


@pytest.mark.parametrize(
    "argv, usage, hint",
    [
        (["replay", "drive.log", "--profle", "P"], "usage: vdp replay", "--profle (did you mean --profile?)"),
        (["profile", "check", "d.log", "--profile", "P", "--jsn", "o"], "usage: vdp profile check", "--jsn (did"),
        (["replay", "drive.log", "--per_axle"], "usage: vdp replay", "--per_axle (did you mean --per-axle?)"),
    ],
)
def test_an_unknown_flag_gets_the_subcommands_usage_and_a_did_you_mean(capsys, argv, usage, hint):
    """`vdp replay drive.log --profle P` had printed vdp's top-level usage, which names no
    option of replay, and no guess."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and err.startswith(usage) and hint in err


def test_a_log_that_does_not_fit_the_default_profile_says_it_was_only_the_default(tmp_path, capsys):
    """`vdp replay LOG` without --profile had failed with "does not fit profile .../paper.toml",
    as though the user had chosen paper.toml."""
    log = tmp_path / "other.log"
    log.write_text("".join(f"({1000 + 0.01 * i:.6f}) can0 3A0#0000000000000000\n" for i in range(500)))
    assert main(["replay", str(log), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "does not fit profile" in err and "no --profile was given" in err and "taken by default" in err
    assert "\n" not in err.strip()
    assert main(["replay", str(log), "--no-progress", "--profile", "profiles/paper.toml"]) == 2
    assert "taken by default" not in capsys.readouterr().err  # a profile chosen is not called the default


def test_a_plain_replay_imports_only_what_it_uses(drive, repo_root, tmp_path):
    """`vdp replay LOG` loads no web, storage, dataframe or plotting library and not the
    simulator: only the chosen subcommand's module is imported, and each output's library
    only when that output is asked for (start-up is most of a short log's replay).  A log
    shorter than vdp.replay.COMPILED_FROM (this one: 20 s) runs numpy's filter steps and never
    loads numba (~1 s of CPU); from there on, the compiled ones."""
    import os
    import subprocess
    import sys

    _, log = drive
    code = (
        "import json, sys\n"
        "from vdp.cli import main\n"
        f"main(['replay', {str(log)!r}, '--no-progress', '--json', {str(tmp_path / 'o.json')!r}])\n"
        "heavy = ('fastapi', 'uvicorn', 'starlette', 'pyarrow', 'dask', 'pandas', 'matplotlib', 'vdp.sim',\n"
        "         'vdp.api', 'vdp.live', 'vdp.fleet', 'vdp.cli.simulate', 'vdp.cli.serve', 'vdp.cli.batch',\n"
        "         'numba', 'llvmlite')\n"
        "print(json.dumps([m for m in heavy if m in sys.modules]))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(repo_root / "service")}
    run = [sys.executable, "-c", code]
    out = subprocess.run(run, capture_output=True, text=True, env=env, cwd=tmp_path, check=True)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []
    numpy_steps = json.loads((tmp_path / "o.json").read_text())["parameters"]
    assert numpy_steps  # it did replay
    # a log past the threshold (here: any) loads the compiled steps, with the same estimates to ~1e-10
    out = subprocess.run(run, capture_output=True, text=True, env={**env, "VDP_COMPILED_FROM": "0"}, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout.strip().splitlines()[-1]) == ["numba", "llvmlite"]
    compiled = json.loads((tmp_path / "o.json").read_text())["parameters"]
    for name, e in numpy_steps.items():
        assert compiled[name]["status"] == e["status"] and compiled[name]["valid"] == e["valid"], name
        assert compiled[name]["value"] == pytest.approx(e["value"], rel=1e-8), name
        assert compiled[name]["std"] == pytest.approx(e["std"], rel=1e-8), name


def test_replay_after_earlier_drives_names_the_changes_as_batch_and_serve_do(tmp_path, repo_root, capsys):
    """`vdp replay LOG --after EARLIER.json ...`: the earlier drives' replays (their JSON carries each
    drive's own mass, wheel-speed scale and bus print) and this one, in time order, through the
    rules of vdp serve and vdp batch (vdp.across.changes): +300 kg is named a mass step, another
    car's bus another car; an earlier document it cannot use is refused before the replay."""
    from vdp.sim.run import Simulation

    prof = str(repo_root / "profiles" / "paper.toml")
    drives = {"a": {}, "loaded": {"load": 300.0}, "other": {"extra_ids": 12, "extra_rate": 50.0}}
    docs = {}
    for k, (name, kw) in enumerate(drives.items()):
        log = tmp_path / f"{name}.log"
        sim = Simulation(prof, "stage1", k + 1, "realistic", duration=40.0, start_time=1.7e9 + 3600.0 * k, **kw)
        write_log(sim.frames(), log)
        after = [a for n in docs for a in ("--after", str(tmp_path / f"{n}.json"))]
        out = tmp_path / f"{name}.json"
        assert main(["replay", str(log), "--profile", prof, "--json", str(out), "--no-progress", *after]) == 0
        docs[name] = json.loads(out.read_text())
        docs[name]["text"] = capsys.readouterr().out
    first = docs["a"]
    assert "changes" not in first and "changes:" not in first["text"]  # no --after, no comparison
    d = first["drive"]
    assert abs(d["mass"] - 1600.0) < 3 * d["mass_std"] and d["bus_print"] and d["start_time"] == 1.7e9
    (c,) = docs["loaded"]["changes"]
    assert c["kind"] == "mass" and 0.12 < c["size"] < 0.26 and c["log"].endswith("loaded.log"), c
    assert "change at this drive: mass step of +" in docs["loaded"]["text"]
    kinds = [(x["kind"], x["log"].rsplit("/", 1)[-1]) for x in docs["other"]["changes"]]
    assert kinds == [("mass", "loaded.log"), ("car", "other.log")], kinds
    assert "change at this drive: a different car:" in docs["other"]["text"]
    assert set(docs["other"]["changes"][-1]["params"]) == {"mass", "l_f", "h", "C_K", "C_alpha", "I_z", "I_x"}
    # an earlier drive that is no replay's JSON, or one without its drive's measures: refused, said why
    old = tmp_path / "old.json"
    old.write_text(json.dumps({k: v for k, v in first.items() if k not in ("drive", "text")}))
    for bad, said in ((tmp_path / "none.json", "no such file"), (old, "no 'drive' section")):
        assert main(["replay", str(tmp_path / "a.log"), "--profile", prof, "--after", str(bad)]) == 2
        assert said in capsys.readouterr().err


def test_every_run_takes_its_estimator_settings_from_one_place():
    """pipeline.run_config: replay, batch and the live service differ only where their runs do
    (compiled steps, trace, EKF, the checks' executor); the user's keys reach each alike."""
    from vdp.pipeline import PLOT_ROWS, run_config

    rep = run_config("replay", compiled=True, ekf=True, plot=True, mass="on", road=True, per_axle=False)
    assert (rep.learner.compiled, rep.baseline, rep.trace_len, rep.trace_max) == (True, True, None, PLOT_ROWS)
    assert (rep.mass.mode, rep.road.on, rep.learner.per_axle) == ("on", True, False)
    bat = run_config("batch", compiled=True, ekf=True, plot=True)
    assert (bat.learner.compiled, bat.baseline, bat.trace_len, bat.mass.mode) == (True, False, 0, "auto")
    checks = object()
    live = run_config("live", compiled=True, checks=checks, mass="off")
    assert (live.learner.compiled, live.trace_len, live.learner.check_executor) == (False, 600, checks)
    assert live.baseline  # the live service serves the EKF beside (/estimates' baseline_ekf)
    assert live.mass.mode == "off" and not live.mass.learn
    with pytest.raises(ValueError, match="one of replay, batch, live"):
        run_config("serve")
    with pytest.raises(ValueError, match="mass mode"):
        run_config("replay", mass="yes")


def test_a_message_the_log_lacks_names_the_channels_the_run_goes_without(drive, repo_root, capsys):
    """The status profile on a log without its status message: the coverage line names the message,
    and the next line what it carries (a user saw reverse and ABS go ungated, and no word of it)."""
    prof = repo_root / "profiles" / "paper_status.toml"
    assert main(["replay", str(drive[1]), "--profile", str(prof), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "(missing: VEHICLE_STATUS)" in out
    assert "  VEHICLE_STATUS carries abs_active, esc_active, reverse, tcs_active: the run has none of them" in out
