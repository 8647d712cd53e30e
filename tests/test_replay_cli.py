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
    for kind in ("parameters", "baseline_ekf"):
        assert set(res[kind]) == set(NAMES)
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
    assert set(res["parameters"]) == set(NAMES)


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
