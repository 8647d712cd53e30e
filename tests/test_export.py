"""Exports: replay --series/--channels, vdp export's formats, --version, caps that say they bite."""

import csv
import dataclasses
import json
import math
import sys
from pathlib import Path

import pytest
import yaml

from vdp import __version__
from vdp.cli import main
from vdp.core.params import NAMES
from vdp.sim.run import simulate, write_log, write_truth

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


@pytest.fixture(scope="module")
def drive(tmp_path_factory, repo_root):
    """The paper drive's first 90 s: stage 1 converges, and stage 2 learns C_alpha and I_z."""
    d = tmp_path_factory.mktemp("export")
    frames, truth = simulate(repo_root / "profiles" / "paper.toml", "paper", seed=3, noise="realistic", duration=90.0)
    log = d / "drive.log"
    write_log(frames, log)
    write_truth(truth, d / "drive.truth.json")
    return d, log


@pytest.fixture(scope="module")
def replayed(drive, repo_root):
    d, log = drive
    out = {k: d / f"r.{k}" for k in ("json", "csv", "parquet")}
    code = main(
        [
            "replay",
            str(log),
            "--profile",
            str(repo_root / "profiles" / "paper.toml"),
            "--no-ekf",
            "--json",
            str(out["json"]),
            "--series",
            str(out["csv"]),
            "--channels",
            str(out["parquet"]),
        ]
    )
    assert code == 0
    return d, out, json.loads(out["json"].read_text())


def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.strip() == f"vdp {__version__}"


def test_series_last_row_is_the_json_result_and_covers_window_time(replayed):
    _, out, res = replayed
    rows = list(csv.DictReader(out["csv"].open()))
    assert list(rows[0])[:4] == ["t", "l_f", "l_f_std", "l_f_status"]
    last = rows[-1]
    for name in NAMES:
        p = res["parameters"][name]
        assert float(last[name]) == p["value"] and float(last[f"{name}_std"]) == p["std"]
        assert last[f"{name}_status"] == p["status"]
    t = [float(r["t"]) for r in rows]
    assert t == sorted(t) and t[0] >= 0
    end = res["log"]["duration_s"]
    for w in res["windows"]:
        lo, hi = w["start"], w["end"] if w["end"] is not None else end
        inside = sum(lo <= x <= hi for x in t)
        assert inside >= int(hi - lo), (w, inside)  # at least one row per second of window time
    # the estimates move over time: the series is not one row repeated
    assert len({r["l_f"] for r in rows}) > 10


def test_channels_are_the_aligned_samples(replayed):
    pq = pytest.importorskip("pyarrow.parquet")
    _, out, res = replayed
    table = pq.read_table(out["parquet"]).to_pydict()
    assert "steering_angle_rad" in table and "v_x_est_m_s" in table
    t = table["t"]
    # one sample per estimator tick (20 ms) over the drive
    assert len(t) == pytest.approx(res["log"]["duration_s"] / 0.02, rel=0.02)
    speed = [v for v in table["speed_m_s"] if v is not None]
    assert 10 < sum(speed) / len(speed) < 40  # m/s: SI units, not km/h


def test_bad_outputs_are_refused_before_the_replay(drive, tmp_path, capsys):
    _, log = drive
    js = tmp_path / "never.json"
    for flag, bad in (("--series", tmp_path / "x.xlsx"), ("--channels", tmp_path / "no" / "dir" / "c.csv")):
        code = main(["replay", str(log), "--json", str(js), flag, str(bad)])
        err = capsys.readouterr().err
        assert code == 2 and flag in err and len(err.strip().splitlines()) == 1
        assert not js.exists()  # refused before any work


def _mass(p: dict) -> float:
    """The mass a file is made with: the learnt one (--mass auto, the default) where it is valid or
    the six were scaled with it (core.mass.scaled's mass_source), else the profile's 1600 kg."""
    put = p["C_K"].get("extra", {}).get("mass_source") == "learnt"
    return p["mass"]["value"] if p["mass"]["valid"] or put else 1600.0


@pytest.mark.parametrize("fmt", ["commonroad", "carla", "json", "toml"])
def test_export_formats(replayed, fmt, tmp_path):
    d, out, res = replayed
    dest = tmp_path / f"car.{fmt}"
    assert main(["export", str(out["json"]), "--format", fmt, "--out", str(dest)]) == 0
    text = dest.read_text()
    p = res["parameters"]
    mass = _mass(p)
    assert p["mass"]["value"] == pytest.approx(1600.0, rel=0.03)
    if fmt == "commonroad":
        y = yaml.safe_load(text)
        # the commonroad-vehicle-models layout: a, b from the CG, h_cg, I_z; tire p_kx1 is C_K
        assert y["a"] == p["l_f"]["value"] and y["a"] + y["b"] == pytest.approx(2.5)
        assert y["m"] == mass and y["tire"]["p_kx1"] == p["C_K"]["value"]
        for name, key in (("h", "h_cg"), ("I_z", "I_z"), ("I_x", "I_Phi_s")):
            usable = p[name]["status"] in ("converged", "uncertain")
            assert (key in y) == usable, (name, p[name]["status"])
    elif fmt == "carla":
        c = json.loads(text)
        assert c["mass"] == mass and len(c["wheels"]) == 4 and c["wheels"][0]["radius"] == 30.0
        assert c["center_of_mass"]["x"] == pytest.approx(1.25 - p["l_f"]["value"])
        # front wheels carry l_r / L of the weight: C_K * F_z / g per wheel
        f_z = mass * 9.8 * (2.5 - p["l_f"]["value"]) / 2.5 / 2
        assert c["wheels"][0]["long_stiff_value"] == pytest.approx(p["C_K"]["value"] * f_z / 9.8)
    else:
        doc = json.loads(text) if fmt == "json" else tomllib.loads(text)
        for name in NAMES:
            e = doc["parameters"][name]
            assert e["value"] == p[name]["value"] and e["std"] == p[name]["std"]
            assert e["unit"] == p[name]["unit"] and e["status"] == p[name]["status"]
            assert e.get("reason") == p[name].get("reason")
        ca, x = doc["parameters"]["C_alpha"], p["C_alpha"]["extra"]
        for k in ("C_alpha_front", "C_alpha_front_std", "C_alpha_rear", "C_alpha_rear_std"):
            assert ca[k] == x[k]  # each axle beside their mean
        assert doc["vehicle"]["wheelbase"] == 2.5


def test_a_simulator_export_says_which_values_are_not_valid(replayed, tmp_path, capsys):
    """A simulator takes the numbers as they are: an estimate the result does not vouch for is
    marked in its comment and named on stderr; valid ones are not."""
    _, out, _ = replayed
    doc = json.loads(out["json"].read_text())
    for name, p in doc["parameters"].items():
        p["valid"] = p["status"] in ("converged", "uncertain") and name != "I_z"
    doc["parameters"]["I_z"].update(status="uncertain", valid=False)
    src = tmp_path / "r.json"
    src.write_text(json.dumps(doc))
    dest = tmp_path / "car.yaml"
    assert main(["export", str(src), "--format", "commonroad", "--out", str(dest)]) == 0
    err = capsys.readouterr().err
    assert "exported but not valid" in err and err.rstrip().endswith(": I_z"), err
    marked = [ln for ln in dest.read_text().splitlines() if "NOT VALID" in ln]
    assert len(marked) == 1 and "moment of inertia in yaw" in marked[0], marked


def test_export_refuses_a_truth_file_with_a_clear_error(replayed, capsys):
    """The truth JSON lies beside the result: exporting it by mistake says so, no traceback."""
    _, out, _ = replayed
    truth = sorted(out["json"].parent.glob("*.truth.json"))
    assert truth, list(out["json"].parent.iterdir())
    assert main(["export", str(truth[0]), "--format", "toml", "--out", "-"]) == 2
    err = capsys.readouterr().err
    assert "plain numbers, not estimates" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--format", "sumo", "--out", "OUT"], "unknown export format"),
        (["--format", "json", "--out", "/nonexistent-dir/x.json"], "does not exist"),
        (["--format", "json", "--out", "DIR"], "is a directory"),
    ],
)
def test_export_refuses_bad_input(replayed, tmp_path, capsys, args, needle):
    _, out, _ = replayed
    args = [str(tmp_path / "o.json") if a == "OUT" else str(tmp_path) if a == "DIR" else a for a in args]
    assert main(["export", str(out["json"]), *args]) == 2
    err = capsys.readouterr().err
    assert needle in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_plot_reads_at_a_glance(drive, repo_root):
    """The paper's Figs 5 and 7: a panel per parameter, truth line, windows in the legend, and
    axes set by the estimate once the data narrowed it, not by the prior's band."""
    import matplotlib.pyplot as plt

    from vdp import report
    from vdp.core.estimator import EstimatorConfig
    from vdp.io.logs import open_log
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile
    from vdp.replay import replay

    d, log = drive
    profile = load_profile(repo_root / "profiles" / "paper.toml")
    pipe = Pipeline(profile, EstimatorConfig())
    truth = report.load_truth(d / "drive.truth.json")
    res = replay(open_log(log, channel=profile.bus_channel), pipe)
    doc = res.estimates_dict()  # windows since the log's start, as the trace below
    fig = report.figure(res.trace_since_start(), doc["windows"], truth, "t", doc["parameters"], profile.priors)
    try:
        axes = fig.axes
        assert len(axes) == 6
        labels = [t.get_text() for t in fig.legends[0].get_texts()]
        for want in ("real value", "UKF", "UKF ±2σ", "EKF", "prior", "stage-1 window", "stage-2 window"):
            assert want in labels
        by_label = {ax.get_ylabel().split(" ")[0]: ax for ax in axes}
        for name, sym in (("l_f", "$l_f$"), ("C_K", "$C_K$"), ("h", "$h$")):
            ax = by_label[sym]
            lo, hi = ax.get_ylim()
            t = truth["parameters"][name]
            assert lo < t < hi  # the real value is on the axes
            # converged: the axes span a few of its stds, far less than the prior's ±2σ
            assert hi - lo < 0.5 * 4 * profile.priors[name].std, (name, lo, hi)
            assert any(abs(line.get_ydata()[0] - t) < 1e-12 for line in ax.get_lines() if len(line.get_ydata()) == 2)
    finally:
        plt.close(fig)


def test_commonroad_file_loads_into_commonroad_vehicle_models(replayed, tmp_path):
    """The file merges over a CommonRoad base set with the package's own structured schema (an
    unknown key or a wrong type is refused there), and its single-track model runs on it."""
    vehiclemodels = pytest.importorskip("vehiclemodels", reason="commonroad-vehicle-models (the bench extra)")
    from omegaconf import OmegaConf
    from vehiclemodels.vehicle_dynamics_st import vehicle_dynamics_st
    from vehiclemodels.vehicle_parameters import VehicleParameters

    _, out, res = replayed
    dest = tmp_path / "car.yaml"
    assert main(["export", str(out["json"]), "--format", "commonroad", "--out", str(dest)]) == 0
    base = Path(vehiclemodels.__file__).parent / "parameters"
    conf = OmegaConf.merge(
        OmegaConf.structured(VehicleParameters),
        OmegaConf.load(base / "parameters_vehicle2.yaml"),
        OmegaConf.load(base / "parameters_tire.yaml"),
        OmegaConf.load(dest),
    )
    p = OmegaConf.to_object(conf)
    est = res["parameters"]
    mass = _mass(est)
    assert p.a == est["l_f"]["value"] and p.m == mass and p.tire.p_kx1 == est["C_K"]["value"]
    # the ST model's cornering stiffness per unit load times the mean axle load is vdp's C_alpha
    if est["C_alpha"]["status"] in ("converged", "uncertain"):
        c_s = -p.tire.p_ky1 / p.tire.p_dy1
        assert c_s * p.tire.p_dy1 * mass * 9.8 / 2 == pytest.approx(est["C_alpha"]["value"])
    else:  # not estimated here: the base set's value stays
        assert p.tire.p_ky1 == OmegaConf.load(base / "parameters_tire.yaml").tire.p_ky1
    dx = vehicle_dynamics_st([0.0, 0.0, 0.02, 15.0, 0.0, 0.0, 0.0], [0.0, 0.0], p)
    assert all(math.isfinite(v) for v in dx) and dx[5] > 0  # steering left builds a left yaw rate


def test_plot_boxes_say_not_valid_and_each_axle():
    """A converged estimate the model does not explain says so in its panel, and C_alpha's panel
    (the axles' mean) gives each axle."""
    import matplotlib.pyplot as plt

    from vdp import report
    from vdp.core.params import NAMES

    vals = {"l_f": 1.2, "h": 0.5, "C_K": 15.0, "C_alpha": 8.8e4, "I_z": 2800.0, "I_x": 790.0}
    rows = [(t, 2, tuple((vals[n], 0.1 * vals[n]) for n in NAMES)) for t in (0.0, 1.0)]
    params = {n: {"value": vals[n], "std": 0.1 * vals[n], "status": "uncertain", "valid": True} for n in NAMES}
    params["l_f"].update(status="converged", valid=False, reason="model mismatch: residuals not white")
    params["C_alpha"]["extra"] = {"C_alpha_front": 8.49e4, "C_alpha_rear": 9.03e4}
    fig = report.figure(rows, [], None, "t", params)
    try:
        texts = [t.get_text() for ax in fig.axes for t in ax.texts]
        assert any(t.startswith("1.2 ± 0.12  converged, not valid") for t in texts), texts
        assert any("mean of front 8.49e+04, rear 9.03e+04" in t for t in texts), texts
        assert not any("h" in t and "not valid" in t for t in texts if t.startswith("0.5 "))
    finally:
        plt.close(fig)


def test_the_plot_marks_what_the_result_reports_beside_the_filters_line():
    """The filter's line can end elsewhere than the reported value (the output-error fit's), with
    a narrower band than the reported std (widened for a mismatch): the reported value ± 2 std is
    drawn at the trace's end, inside the axes."""
    import matplotlib.pyplot as plt

    from vdp import report
    from vdp.core.params import BY_NAME

    vals = {"l_f": 1.2, "h": 0.5, "C_K": 15.0, "C_alpha": 8.8e4, "I_z": 2800.0, "I_x": 790.0}
    rows = [(t, 2, tuple((vals[n], 0.01 * vals[n]) for n in NAMES)) for t in (0.0, 10.0)]
    windows = [{"stage": s, "start": 0.0, "end": 10.0, "samples": 500} for s in (1, 2)]
    params = {n: {"value": vals[n], "std": 0.01 * vals[n], "status": "converged", "valid": True} for n in NAMES}
    params["C_alpha"].update(value=9.6e4, std=6e3, status="uncertain", valid=False)
    fig = report.figure(rows, windows, None, "t", params)
    try:
        ax = next(a for a in fig.axes if a.get_title(loc="left").endswith(BY_NAME["C_alpha"].description))
        marks = [ln for ln in ax.lines if ln.get_marker() == "D"]
        assert len(marks) == 1 and list(marks[0].get_xdata()) == [10.0] and list(marks[0].get_ydata()) == [9.6e4]
        lo, hi = ax.get_ylim()
        assert lo < 8.8e4 < 9.6e4 < hi and ax.get_xlim()[1] > 10.0  # the line's end and the mark both show
        from matplotlib.collections import LineCollection

        bars = [c for c in ax.collections if isinstance(c, LineCollection)]  # the ±2 std bar
        assert len(bars) == 1
        (seg,) = bars[0].get_segments()
        assert seg[:, 1].tolist() == pytest.approx([9.6e4 - 1.2e4, 9.6e4 + 1.2e4])
    finally:
        plt.close(fig)


def test_a_measured_l_f_is_handed_on_where_stage_1_did_not_run(tmp_path, capsys):
    """A car without axle torques runs stage 2 on the profile's measured l_f ([vehicle] l_f): an
    export carries that l_f (marked measured), not nothing; without one, l_f stays left out."""
    from vdp.export import Constants, render

    params = {
        "l_f": {"value": 1.15, "std": 0.3, "unit": "m", "status": "not_run", "valid": False},
        "C_alpha": {"value": 9.0e4, "std": 2e3, "unit": "N/rad", "status": "converged", "valid": True},
    }
    known = Constants("rav4", 1656.0, 2.66, 0.35, 2.4, 1.57, l_f=1.17, l_f_std=0.08)
    text = render("commonroad", params, known)
    assert "a: 1.17\n" in text and "measured: the profile's [vehicle] l_f" in text and "p_ky1:" in text
    carla = json.loads(render("carla", params, known))
    assert carla["center_of_mass"]["x"] == pytest.approx(2.66 / 2 - 1.17)
    plain = render("commonroad", params, Constants("rav4", 1656.0, 2.66, 0.35, 2.4, 1.57))
    assert "a: " not in plain and "left out (not estimated from the data): l_f" in plain
    # through vdp export, from a replay's JSON (whose vehicle block carries the measured l_f)
    result = tmp_path / "r.json"
    result.write_text(json.dumps({"parameters": params, "vehicle": dataclasses.asdict(known)}))
    assert main(["export", str(result), "--format", "commonroad", "--out", str(tmp_path / "c.yaml")]) == 0
    assert "l_f is the profile's measured 1.17 m" in capsys.readouterr().err


@pytest.mark.parametrize("mass", ["learnt", "not_valid", "off", "absent"])
def test_the_exports_take_the_learnt_mass_where_it_is_valid_and_say_which(mass):
    """A result whose mass was learnt and is valid (vdp replay --mass): each format is made with it
    (the mass, the axle loads, C_alpha per unit load); otherwise with the profile's, and each says
    which."""
    from vdp.export import Constants, render

    params = {
        "l_f": {"value": 1.1, "std": 0.003, "unit": "m", "status": "converged", "valid": True},
        "C_K": {"value": 15.0, "std": 0.5, "unit": "1", "status": "converged", "valid": True},
        "C_alpha": {"value": 9.0e4, "std": 2e3, "unit": "N/rad", "status": "converged", "valid": True},
    }
    learnt = {"value": 1900.0, "std": 5.0, "unit": "kg", "status": "converged", "valid": True}
    params["mass"] = {
        "learnt": learnt,
        "not_valid": {**learnt, "std": 90.0, "status": "uncertain", "valid": False},
        "off": {"value": 1600.0, "std": 192.0, "unit": "kg", "status": "not_run", "valid": False, "reason": "off"},
    }.get(mass)
    if params["mass"] is None:  # a result of a vdp before the mass was published
        del params["mass"]
    const = Constants("car", 1600.0, 2.5, 0.3, 2.0, 1.5)
    m = 1900.0 if mass == "learnt" else 1600.0
    source = "learnt" if mass == "learnt" else "profile"
    y = yaml.safe_load(text := render("commonroad", params, const))
    assert y["m"] == m and y["tire"]["p_ky1"] == pytest.approx(-9.0e4 / (m * 9.8 / 2))
    said = {"learnt": "(learnt from the data (+- 5 kg, converged; the profile's [vehicle] mass is 1600))",
            "not_valid": "the learnt mass is not valid (uncertain)", "off": "the mass was not learnt",
            "absent": "the result has no mass"}[mass]  # fmt: skip
    assert said in text.split("\nm: ")[0].splitlines()[-1], text
    c = json.loads(render("carla", params, const))
    f_z = m * 9.8 * (2.5 - 1.1) / 2.5 / 2  # the front wheel's static load, of the mass used
    assert c["mass"] == m and c["wheels"][0]["long_stiff_value"] == pytest.approx(15.0 * f_z / 9.8)
    assert c["vdp"]["mass"]["source"] == source and c["vdp"]["mass"]["value"] == m
    for fmt in ("json", "toml"):
        text = render(fmt, params, const)
        doc = json.loads(text) if fmt == "json" else tomllib.loads(text)
        assert doc["vehicle"]["mass"] == m and doc["vehicle"]["mass_source"] == source
        got = doc["parameters"]["mass"]  # the mass beside the six, as the result has it
        assert got["status"] == params.get("mass", {}).get("status", "not_run") and got["unit"] == "kg"
    assert f"# vehicle.mass: {'learnt' if mass == 'learnt' else 'the profile'}" in text


def _hand_edited(tmp_path, params=None, **vehicle):
    """A result JSON as a user may have edited it (json.dumps writes NaN and Infinity as Python reads them)."""
    p = {
        "l_f": {"value": 1.15, "std": 0.03, "unit": "m", "status": "converged", "valid": True},
        "C_K": {"value": 15.0, "std": 0.5, "unit": "1", "status": "converged", "valid": True},
        "C_alpha": {"value": 9.0e4, "std": 2e3, "unit": "N/rad", "status": "converged", "valid": True},
    }
    for name, change in (params or {}).items():
        p[name] = {**p[name], **change}
    const = {"name": "car", "mass": 1600.0, "wheelbase": 2.5, "wheel_radius": 0.3, "wheel_inertia": 2.0, "track": 1.5}
    src = tmp_path / "edited.json"
    src.write_text(json.dumps({"parameters": p, "vehicle": {**const, **vehicle}}))
    return src


@pytest.mark.parametrize("fmt", ["commonroad", "carla", "json", "toml"])
@pytest.mark.parametrize(
    "params,vehicle,field",
    [
        ({"l_f": {"value": math.nan}}, {}, "parameters.l_f.value is nan"),
        ({"C_K": {"std": math.inf}}, {}, "parameters.C_K.std is inf"),
        ({"C_alpha": {"value": "9.0e4"}}, {}, 'parameters.C_alpha.value is "9.0e4", not a number'),
        ({}, {"mass": math.nan}, "vehicle.mass is nan"),
        ({}, {"wheelbase": 0}, "vehicle.wheelbase is 0: it must be above 0"),
        ({}, {"track": "1.5"}, 'vehicle.track is "1.5", not a number'),
    ],
)
def test_export_refuses_a_number_that_is_not_one_naming_its_field(tmp_path, capsys, fmt, params, vehicle, field):
    """A NaN or inf wrote "a: nan" (YAML reads a string) or "mass = nan"; text or a zero wheelbase
    was a traceback: each is one line naming the file and the field, and no file is written."""
    src = _hand_edited(tmp_path, params, **vehicle)
    dest = tmp_path / f"car.{fmt}"
    assert main(["export", str(src), "--format", fmt, "--out", str(dest)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{src}: {field}" in err and len(err.splitlines()) == 1, err
    assert not dest.exists()


def test_export_writes_a_name_with_quotes_and_newlines_as_text(tmp_path):
    """A newline in the vehicle's name added a line to the YAML and broke the TOML."""
    name = 'Golf "R"\nm: 1\n[vehicle]\\'
    src = _hand_edited(tmp_path, name=name)
    for fmt in ("commonroad", "toml", "json", "carla"):
        dest = tmp_path / f"car.{fmt}"
        assert main(["export", str(src), "--format", fmt, "--out", str(dest)]) == 0
        text = dest.read_text()
        if fmt == "commonroad":
            y = yaml.safe_load(text)
            assert y["m"] == 1600.0 and y["a"] == 1.15 and text.startswith('# Golf "R" m: 1 [vehicle]\\')
        elif fmt == "toml":
            assert tomllib.loads(text)["vehicle"]["name"] == name
        else:
            doc = json.loads(text)
            assert (doc["vehicle"]["name"] if fmt == "json" else doc["vdp"]["vehicle"]) == name


def test_export_over_its_own_result_is_refused(tmp_path, capsys):
    """`vdp export r.json --format json --out r.json` wrote the export over the result."""
    src = _hand_edited(tmp_path)
    before = src.read_bytes()
    assert main(["export", str(src), "--format", "json", "--out", str(src)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"--out {src}: is the result {src}, an input of this run" in err and len(err.splitlines()) == 1, err
    assert src.read_bytes() == before


def test_an_output_is_whole_or_the_old_file(tmp_path):
    """outfile.replacing: a writer that fails leaves the old file and no temporary; one that ends
    replaces it whole, through a symlink, keeping the file's mode."""
    from vdp.outfile import replacing, write_text

    out = tmp_path / "r.json"
    out.write_text("old")
    out.chmod(0o640)
    with pytest.raises(RuntimeError), replacing(out) as tmp:
        tmp.write_text("half")
        raise RuntimeError("the writer failed")
    assert out.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]
    (tmp_path / "link.json").symlink_to(out)
    write_text(tmp_path / "link.json", "new")
    assert out.read_text() == "new" and (tmp_path / "link.json").is_symlink()
    assert out.stat().st_mode & 0o777 == 0o640
    # /dev/stdout on a pipe (a link to /proc/self/fd/1, which names no path) is written in place
    import os

    r, w = os.pipe()
    (tmp_path / "stdout").symlink_to(f"/proc/self/fd/{w}")
    try:
        write_text(tmp_path / "stdout", "through the pipe")
        assert os.read(r, 100) == b"through the pipe"
    finally:
        os.close(r)
        os.close(w)
