"""Accuracy of the estimator on vehicle models vdp did not write, beside vdp's own simulator.

    python benchmarks/independent.py --seeds 5 --jobs 2 [--cases brush/small,mb/bmw_320i] [--json runs.json]
        [--one-c] [--no-batch-check] [--kc]

Cases: ``brush/saloon``, ``brush/small`` (vdp.sim.independent.brush, first principles),
``mb/bmw_320i``, ``mb/vw_vanagon`` (CommonRoad's multi-body car, the ``bench`` extra),
and vdp's own simulator ``vdp/paper`` (Table 6), ``vdp/small`` (the small car's
known constants with vdp's own physics) and ``vdp/axles`` (Table 6 with the rear axle's
cornering stiffness 1.3x the front's).  Stage 2 estimates each axle (LearnerConfig.per_axle,
the default; ``--one-c``: one C_alpha for both) and ``C_alpha_front``/``C_alpha_rear`` are the per-axle values in
the estimate's ``extra`` (C_alpha is their mean).  Each case drives the paper's manoeuvre
once noise-free and with realistic noise for ``--seeds`` seeds; every drive goes
DBC -> candump log -> the replay pipeline (UKF and the EKF baseline at once), and only
the log and the profile reach the estimator.

Per parameter, for the UKF and the EKF: the relative error (mean and worst |error|
over the runs), how often truth lies within value +- 2 std, how many estimates
reported valid have the truth more than 3 std away, how many ended converged, and the
time to converge: from the first window of the parameter's stage to the moment its
std fell below the convergence threshold for good (median over the runs that did).

What "truth" means on a model vdp did not write is in vdp.sim.independent.DEFINITIONS
(printed with the tables).  ``--prior-scale 0.6`` multiplies every prior mean.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))

CASES = (
    "brush/saloon",
    "brush/small",
    "brush/compact",
    "mb/bmw_320i",
    "mb/vw_vanagon",
    "vdp/paper",
    "vdp/small",
    "vdp/axles",
)

# vdp's own physics on the paper car with axles that differ: the rear 1.3x the front (the paper
# car carries more of its load behind, l_f > l_r); their mean is Table 6's C_alpha
VDP_AXLES = {"C_alpha_front": 58200.0, "C_alpha_rear": 75600.0}

# vdp's own physics with the small car's known constants (issue 11: about 1,100 kg, wheelbase 2.58 m,
# roll stiffness about 48,000 N m/rad) and realistic, imperfect priors
VDP_SMALL = {
    "vehicle": {
        "mass": 1100.0,
        "wheelbase": 2.58,
        "wheel_radius": 0.29,
        "wheel_inertia": 1.6,
        "roll_stiffness": 48000.0,
        "roll_damping": 3000.0,
        "track": 1.45,
    },
    "truth": {"l_f": 1.02, "h": 0.54, "C_K": 12.0, "C_alpha": 73000.0, "I_z": 1650.0, "I_x": 486.0},
    "priors": {
        "l_f": (1.29, 0.3),
        "h": (0.55, 0.2),
        "C_K": (8.0, 4.0),
        "C_alpha": (80000.0, 40000.0),
        "I_z": (2200.0, 1100.0),
        "I_x": (500.0, 250.0),
    },
}


def _source_hash() -> str:
    h = hashlib.sha256()
    for p in sorted((ROOT / "service" / "vdp" / "sim" / "independent").glob("*.py")):
        h.update(p.read_bytes())
    return h.hexdigest()[:12]


def trace_path(cache: Path, case: str, scenario: str) -> Path:
    return cache / f"{case.replace('/', '-')}-{scenario}-{_source_hash()}.npz"


def make_trace(job) -> tuple[str, float]:
    """Record an independent model's drive once (the physics does not depend on the seed)."""
    case, scenario, cache = job
    from vdp.sim.independent import get_model
    from vdp.sim.independent.common import drive

    path = trace_path(cache, case, scenario)
    if path.exists():
        return case, 0.0
    t0 = time.perf_counter()
    name, car = case.split("/")
    tr = drive(get_model(name, car), scenario)
    tmp = path.with_suffix(".tmp.npz")
    tr.save(tmp)
    tmp.rename(path)
    return case, time.perf_counter() - t0


def _scaled(priors: dict, scale: float) -> dict:
    from vdp.profile import Prior

    return {k: Prior(p.value * scale, p.std) for k, p in priors.items()}


def _simulation(case: str, scenario: str, seed: int, noise: str, cache: Path, prior_scale: float, kc: bool = False):
    """(frames iterator, truth dict, profile) of one run; the profile is all the estimator gets
    (``kc``: with the car's K&C steer figures declared, where its model has any; core.steer)."""
    from vdp.profile import Prior, load_profile

    name, car = case.split("/")
    if name == "vdp":
        from vdp.sim.run import Simulation

        profile = load_profile(ROOT / "profiles" / "paper.toml")
        params = None
        if car == "small":
            veh = dataclasses.replace(profile.vehicle, name="small", **VDP_SMALL["vehicle"])
            priors = {k: Prior(*v) for k, v in VDP_SMALL["priors"].items()}
            profile = dataclasses.replace(profile, vehicle=veh, priors=priors)
            params = VDP_SMALL["truth"]
        elif car == "axles":
            params = VDP_AXLES
        sim = Simulation(profile, scenario, seed, noise, params=params)
        truth = sim.truth
    else:
        from vdp.sim.independent import get_model
        from vdp.sim.independent.common import IndependentSimulation, Trace

        tr = Trace.load(trace_path(cache, case, scenario))
        model = get_model(name, car)
        sim = IndependentSimulation(model, None, scenario, seed, noise, trace=tr)
        profile, truth = sim.profile, sim.truth
        if kc and model.kc():
            profile = dataclasses.replace(profile, vehicle=dataclasses.replace(profile.vehicle, **model.kc()))
    if prior_scale != 1.0:
        profile = dataclasses.replace(profile, priors=_scaled(profile.priors, prior_scale))
    return sim, truth, profile


def truth_value(name: str, truth: dict) -> float | None:
    """A parameter's truth; per-axle names (C_alpha_front or C_alpha_f, ...) from the per-axle table."""
    if name in truth["parameters"]:
        return truth["parameters"][name]
    per = truth.get("per_axle", {})
    if name in per:
        return per[name]
    for short, long in (("_f", "_front"), ("_r", "_rear")):
        base = name[: -len(short)] if name.endswith(short) else name[: -len(long)] if name.endswith(long) else None
        if base is None:
            continue
        if base + long in per:
            return per[base + long]
        if not per and base in truth["parameters"]:  # vdp's own physics: one value for both axles
            return truth["parameters"][base]
    return None


def run_one(job) -> dict:
    case, scenario, seed, noise, cache, prior_scale, per_axle, *rest = job
    batch_check = rest[0] if rest else True
    kc = rest[1] if len(rest) > 1 else False
    import logging

    from vdp.core.estimator import EstimatorConfig
    from vdp.core.learner import LearnerConfig
    from vdp.core.params import BY_NAME
    from vdp.io.logs import open_log
    from vdp.pipeline import Pipeline
    from vdp.replay import replay
    from vdp.sim.run import write_log

    logging.getLogger("vdp").setLevel(logging.ERROR)
    sim, truth, profile = _simulation(case, scenario, seed, noise, cache, prior_scale, kc)
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "drive.log"
        write_log(sim.frames(), log, sim.bus_channel)
        cfg = LearnerConfig(per_axle=per_axle, batch_check=batch_check)
        pipe = Pipeline(profile, EstimatorConfig(learner=cfg))
        spent = [0.0]
        handle = pipe.estimator.handle

        def timed(t, s):  # the estimator's share of the replay (issue 11: it may grow by half at most)
            t1 = time.perf_counter()
            handle(t, s)
            spent[0] += time.perf_counter() - t1

        pipe.estimator.handle = timed
        t0 = time.perf_counter()
        res = replay(open_log(log, channel=profile.bus_channel), pipe).to_dict()
        wall = time.perf_counter() - t0
    est = pipe.estimator
    out = {"case": case, "seed": seed, "noise": noise, "wall": wall, "frames": res["log"]["frames"]}
    out["estimator_s"] = spent[0]
    out["windows"] = {s: sum(1 for w in res["windows"] if w["stage"] == s) for s in (1, 2)}
    first = {s: min((w["start"] for w in res["windows"] if w["stage"] == s), default=None) for s in (1, 2)}
    for kind, key in (("ukf", "parameters"), ("ekf", "baseline_ekf")):
        snap = res.get(key) or {}
        names = list(est.s1[kind].names) + list(est.s2[kind].names) if kind in est.s1 else []
        rows = {}
        for name, e in snap.items():
            tv = truth_value(name, truth)
            v, sd = e.get("value"), e.get("std")
            d = {"truth": tv, "value": v, "std": sd, "status": e.get("status"), "valid": bool(e.get("valid"))}
            d["reason"] = e.get("reason")
            if tv is not None and v is not None:
                d["err"] = (v - tv) / tv
                d["z"] = abs(v - tv) / sd if sd else float("inf")
            # time to converge: from its stage's first window to the last time its std crossed the threshold
            spec = BY_NAME.get(name)
            d["t_conv"] = None
            if spec is not None and name in names and first[spec.stage] is not None:
                i = names.index(name)
                t_in = None
                for row in est.trace:
                    val, s = row[2 + list(est.s1).index(kind)][i]
                    ok = val is not None and s is not None and val != 0 and s / abs(val) < spec.converged_rel
                    if ok and t_in is None:
                        t_in = row[0]
                    elif not ok:
                        t_in = None
                if t_in is not None:
                    # the trace keeps bus time; the result's windows are from the log's start
                    start = res["log"].get("start_time") or 0.0
                    if t_in > 1e6 and first[spec.stage] < 1e6:
                        t_in -= start
                    d["t_conv"] = max(0.0, t_in - first[spec.stage])
            rows[name] = d
            x = e.get("extra") or {}
            for axle in ("C_alpha_front", "C_alpha_rear"):  # C_alpha's per-axle values
                if name == "C_alpha" and x.get(axle) is not None:
                    tv, v, sd = truth_value(axle, truth), x[axle], x.get(axle + "_std")
                    valid = bool(x.get("per_axle_valid"))
                    a = {"truth": tv, "value": v, "std": sd, "status": e.get("status"), "valid": valid, "t_conv": None}
                    if tv is not None:
                        a["err"] = (v - tv) / tv
                        a["z"] = abs(v - tv) / sd if sd else float("inf")
                    rows[axle] = a
        out[kind] = rows
    return out


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:+.1f} %"


def summarise(runs: list[dict], case: str, noise: str) -> list[str]:
    rs = [r for r in runs if r["case"] == case and r["noise"] == noise]
    if not rs:
        return []
    names = list(rs[0]["ukf"])
    lines = []
    for name in names:
        cells = [f"`{name}`", f"{rs[0]['ukf'][name]['truth']:.4g}" if rs[0]["ukf"][name]["truth"] else "–", noise]
        for kind in ("ukf", "ekf"):
            ds = [r[kind][name] for r in rs if name in r.get(kind, {})]
            errs = [d["err"] for d in ds if d.get("err") is not None]
            if not ds:
                cells += ["–"] * 5
                continue
            mean = statistics.fmean(abs(e) for e in errs) if errs else None
            worst = max(errs, key=abs) if errs else None
            cov = sum(1 for d in ds if d.get("z") is not None and d["z"] <= 2.0)
            bad = sum(1 for d in ds if d["valid"] and d.get("z") is not None and d["z"] > 3.0)
            valid = sum(1 for d in ds if d["valid"])
            tc = [d["t_conv"] for d in ds if d.get("t_conv") is not None]
            err_cell = _pct(errs[0]) if len(errs) == 1 else f"{100 * mean:.1f} % ({_pct(worst)})" if errs else "–"
            cells += [
                err_cell,
                f"{cov}/{len(ds)}",
                f"{valid}/{len(ds)}",
                f"**{bad}**" if bad else "0",
                f"{statistics.median(tc):.1f} s ({len(tc)})" if tc else "never",
            ]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


HEADER = (
    "| parameter | truth | noise | UKF error | UKF ±2σ covers | UKF valid | UKF valid, truth > 3σ | UKF t_conv "
    "| EKF error | EKF ±2σ covers | EKF valid | EKF valid, truth > 3σ | EKF t_conv |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|"
)


# issue 11's targets on the independent models: (name, tolerance, or-not-valid-with-truth-inside-2-sigma allowed)
TARGETS = (("l_f", 0.03, False), ("C_K", 0.10, False), ("C_alpha", 0.10, False), ("I_z", 0.10, False))
TARGETS += (("h", 0.10, True), ("I_x", 0.20, True))


KINDS = ("ukf", "ekf")


def _meets(d: dict | None, tol: float, or_honest: bool) -> bool:
    if d is None or d.get("err") is None:
        return False
    if d["valid"] or not or_honest:
        return abs(d["err"]) <= tol
    return d["z"] <= 2.0


def targets(runs: list[dict], cases: list[str]) -> list[str]:
    """Runs meeting each of issue 11's targets, per case, UKF / EKF."""
    per_axle = [n for n in runs[0]["ukf"] if n.startswith("C_alpha_")]
    cols = [f"`{n}` ≤ {100 * t:.0f} %" + (" or not valid, 2σ" if h else "") for n, t, h in TARGETS]
    cols += [f"`{n}` ≤ 10 %" for n in per_axle] + ["nothing valid beyond 3σ", "stage 2 ran"]
    out = ["| case | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for case in cases:
        rs = [r for r in runs if r["case"] == case]
        cells = []
        for n, t, h in TARGETS + tuple((n, 0.10, False) for n in per_axle):
            cells.append(" / ".join(f"{sum(_meets(r[k].get(n), t, h) for r in rs)}" for k in KINDS))
        clean = [sum(all(not (d["valid"] and d.get("z", 0) > 3.0) for d in r[k].values()) for r in rs) for k in KINDS]
        cells += [" / ".join(map(str, clean)), str(sum(1 for r in rs if _stage2_ran(r)))]
        out.append(f"| `{case}` ({len(rs)} runs) | " + " | ".join(cells) + " |")
    return out


def per_car(runs: list[dict], cases: list[str]) -> list[str]:
    """BENCHMARKS.md's accuracy table: per case, stage 1's and I_x's targets met, and stage 2's
    UKF errors (signed mean / worst over the runs; each axle where stage 2 estimates them)."""
    first = ("l_f", "C_K", "h", "I_x")
    rules = {n: (t, h) for n, t, h in TARGETS}
    second = [n for n in ("C_alpha", "C_alpha_front", "C_alpha_rear", "I_z") if n in runs[0]["ukf"]]
    out = [
        "| case | " + ", ".join(f"`{n}`" for n in first) + " | " + " | ".join(f"`{n}`" for n in second) + " |",
        "|---" * (len(second) + 2) + "|",
    ]
    for case in cases:
        rs = [r for r in runs if r["case"] == case]
        met = {n: sum(_meets(r["ukf"].get(n), *rules[n]) for r in rs) for n in first}
        cell = (
            f"every target met, {len(rs)}/{len(rs)}"
            if all(m == len(rs) for m in met.values())
            else ", ".join(f"{n} {m}/{len(rs)}" for n, m in met.items())
        )
        cells = [cell]
        for n in second:
            errs = [r["ukf"][n]["err"] for r in rs if r["ukf"].get(n, {}).get("err") is not None]
            mean = statistics.fmean(errs) if errs else None
            worst = max(errs, key=abs) if errs else None
            cells.append(f"{100 * mean:+.1f} / {_pct(worst)}" if errs else "–")
        out.append(f"| `{case}` | " + " | ".join(cells) + " |")
    return out


def _stage2_ran(r: dict) -> bool:
    w = r["windows"]
    return bool(w.get(2) or w.get("2"))  # int keys in memory, str keys read back from --json


def report(runs: list[dict], cases: list[str], seeds: int, scale: float) -> str:
    from vdp.sim.independent import DEFINITIONS

    out = ["#### Per car against its target (UKF; stage 2: mean / worst error over the runs)", ""]
    out += per_car(runs, cases) + [""]
    out += ["#### Issue 11's targets: runs meeting each (UKF / EKF)", ""]
    out += targets(runs, cases) + [""]
    for case in cases:
        rs = [r for r in runs if r["case"] == case]
        s2 = sum(1 for r in rs if _stage2_ran(r))
        out += [
            f"#### `{case}`: paper drive, noise-free and {seeds} seeds of realistic noise"
            + (f", prior means ×{scale:g}" if scale != 1.0 else ""),
            "",
            HEADER,
        ]
        out += summarise(runs, case, "none") + summarise(runs, case, "realistic")
        share = sum(r.get("estimator_s", 0.0) for r in rs) / max(sum(r["wall"] for r in rs), 1e-9)
        out += [
            "",
            f"Stage 2 opened a window on {s2}/{len(rs)} runs; the estimator took {100 * share:.0f} % of "
            f"the replay time ({statistics.fmean(r.get('estimator_s', 0.0) for r in rs):.1f} s per drive).",
            "",
        ]
    # across every case
    out += ["#### All cases together", "", "| parameter | UKF ±2σ covers | UKF valid, truth > 3σ | EKF ±2σ covers "]
    out[-1] += "| EKF valid, truth > 3σ |"
    out.append("|---|---|---|---|---|")
    names = list(runs[0]["ukf"])
    for name in names:
        cells = [f"`{name}`"]
        for kind in ("ukf", "ekf"):
            ds = [r[kind][name] for r in runs if name in r.get(kind, {})]
            cov = sum(1 for d in ds if d.get("z") is not None and d["z"] <= 2.0)
            bad = sum(1 for d in ds if d["valid"] and d.get("z") is not None and d["z"] > 3.0)
            cells += [f"{cov}/{len(ds)} ({100 * cov / max(len(ds), 1):.0f} %)", str(bad)]
        out.append("| " + " | ".join(cells) + " |")
    out += ["", "Truth, as defined beside the models (vdp.sim.independent.DEFINITIONS):", ""]
    out += [f"- `{k}`: {v}" for k, v in DEFINITIONS.items()]
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, from {', '.join(CASES)}")
    ap.add_argument("--scenario", default="paper", choices=("paper", "ordinary_rolling"))
    ap.add_argument("--seeds", type=int, default=5, help="seeds of realistic noise per case (plus one noise-free)")
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--prior-scale", type=float, default=1.0, help="multiply every prior mean (0.6, 1.6)")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "vdp-independent-traces")
    ap.add_argument("--json", type=Path, help="write every run's figures here")
    ap.add_argument(
        "--per-axle",
        action="store_true",
        help="stage 2 estimates each axle's C_alpha (the default; kept for old commands)",
    )
    ap.add_argument("--one-c", action="store_true", help="one C_alpha for both axles (LearnerConfig.per_axle off)")
    ap.add_argument(
        "--no-batch-check",
        action="store_true",
        help="stage 2's stds without its output-error batch check (LearnerConfig.batch_check off)",
    )
    ap.add_argument(
        "--kc",
        action="store_true",
        help="the profile declares the car's K&C steer where its model has any (brush/compact; core.steer)",
    )
    ap.add_argument("-v", "--verbose", action="store_true", help="one line per run")
    a = ap.parse_args()
    a.per_axle = not a.one_c
    cases = [c.strip() for c in a.cases.split(",") if c.strip()]
    for c in cases:
        if c not in CASES:
            ap.error(f"unknown case {c}; choose from {', '.join(CASES)}")
    a.cache.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        indep = [c for c in cases if not c.startswith("vdp/")]
        for case, wall in ex.map(make_trace, [(c, a.scenario, a.cache) for c in indep]):
            if wall:
                print(f"recorded {case} {a.scenario} in {wall:.0f} s", file=sys.stderr)
        jobs = []
        for c in cases:
            jobs.append((c, a.scenario, 0, "none", a.cache, a.prior_scale, a.per_axle, not a.no_batch_check, a.kc))
            jobs += [
                (c, a.scenario, s, "realistic", a.cache, a.prior_scale, a.per_axle, not a.no_batch_check, a.kc)
                for s in range(a.first_seed, a.first_seed + a.seeds)
            ]
        runs = list(ex.map(run_one, jobs))
    if a.verbose:
        for r in runs:
            errs = " ".join(f"{n}={_pct(d.get('err'))}[{d['status']}]" for n, d in r["ukf"].items())
            print(f"{r['case']} {r['noise']} seed {r['seed']}: {errs} windows={r['windows']}", file=sys.stderr)
    if a.json:
        a.json.write_text(json.dumps(runs, indent=1, default=str) + "\n")
    print(report(runs, cases, a.seeds, a.prior_scale))
    frames = sum(r["frames"] for r in runs)
    wall = sum(r["wall"] for r in runs)
    share = sum(r.get("estimator_s", 0.0) for r in runs) / max(wall, 1e-9)
    est_s = sum(r.get("estimator_s", 0.0) for r in runs)
    print(
        f"\nEstimator: {100 * share:.0f} % of the replay time, {est_s / max(frames, 1) * 1e6:.0f} µs per frame "
        f"({est_s / len(runs):.1f} s per drive)."
    )
    print(
        f"\nReplay (read log + decode + UKF + EKF): {frames / wall:,.0f} frames/s; whole benchmark "
        f"{time.perf_counter() - t0:.0f} s on {a.jobs} processes."
    )
    return 0


if __name__ == "__main__":
    import benchenv

    benchenv.announce()
    sys.exit(main())
