"""Stage 2 standalone: C_alpha, I_z (and I_x) on cars whose bus cannot feed stage 1.

    python benchmarks/standalone.py --seeds 5 [--scenario stage2] [--jobs 1] [--cases ...]

Each case is a bus layout without per-axle torque and without GNSS (so stage 1 cannot run),
with l_f given in the profile ([vehicle] l_f, l_f_std), through the same pipeline as
``vdp replay``; realistic noise, one simulated drive per seed:

- ``paper/no-stage1``: the paper car on vdp's bus, torques and GNSS taken away, roll rate kept;
  l_f as an axle-scale weighing gives it: the truth +0.5 %, std 1 %;
- ``paper/no-stage1-no-roll``: the same without the roll-rate gyro (I_x must be not_run);
- ``rav4/scale``: the Toyota RAV4's own DBC layout (opendbc extra), nothing added: no torque,
  no GNSS, no roll rate; v_x from its rear wheels; l_f as an axle-scale weighing (truth +0.5 %, 1 %);
- ``rav4/published``: the same with the profile's own published l_f (1.17 m, std 0.08 m)
  against the simulated car's 1.2 m (vdp.sim.addons.CAR_TRUTH): a generic value, 2.5 % off.

Per parameter and filter: mean and worst relative error, +-2 sigma coverage, how many
ended valid, valid with the truth beyond 3 sigma, and the statuses.

``--true-stage1`` (a diagnostic, never the estimator's way): hand stage 2 the simulator's h
and C_K as if stage 1 had found them exactly, so that the front drive force is in the model;
the difference to a plain run is what leaving it out costs.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))

CASES = ("paper/no-stage1", "paper/no-stage1-no-roll", "rav4/scale", "rav4/published")
NO_STAGE1 = ("wheel_torque_front", "wheel_torque_rear", "speed")
NAMES = ("C_alpha", "I_z", "I_x")
SCALE_ERROR = 0.005  # an axle-scale l_f: half a percent off the truth, std 1 %


def _profile(case: str):
    """(profile, simulator truth overrides or None) of a case."""
    from vdp.profile import load_profile
    from vdp.sim.addons import CAR_TRUTH
    from vdp.sim.truth import truth_parameters

    car, variant = case.split("/")
    if car == "paper":
        prof = load_profile(ROOT / "profiles" / "paper.toml")
        drop = NO_STAGE1 + (("roll_rate",) if variant.endswith("no-roll") else ())
        chans = {k: v for k, v in prof.channels.items() if k not in drop}
        msgs = {v.message for v in chans.values()}
        prof = dataclasses.replace(prof, channels=chans, checks={k: c for k, c in prof.checks.items() if k in msgs})
        params = None
        l_f = truth_parameters()["l_f"]
    else:
        prof = load_profile(ROOT / "profiles" / "toyota_rav4.toml")
        params = CAR_TRUTH["toyota_rav4"]
        l_f = params["l_f"]
        if variant == "published":
            return prof, params
    veh = dataclasses.replace(prof.vehicle, l_f=l_f * (1 + SCALE_ERROR), l_f_std=0.01 * l_f)
    return dataclasses.replace(prof, vehicle=veh), params


def run_one(job) -> dict:
    case, scenario, seed, true_stage1 = job
    import logging

    from vdp.core.learner import Stage2
    from vdp.pipeline import Pipeline
    from vdp.sim.run import simulate

    logging.getLogger("vdp").setLevel(logging.ERROR)
    prof, params = _profile(case)
    frames, truth = simulate(prof, scenario, seed=seed, noise="realistic", params=params)
    if true_stage1:  # the diagnostic: stage 2 gets the simulator's h and C_K
        tp, original = truth["parameters"], Stage2.set_stage1

        def handed(self, l_f, h, c_k, l_f_std=None, h_std=None):
            original(self, l_f, tp["h"], tp["C_K"], l_f_std, 0.0)

        Stage2.set_stage1 = handed
    try:
        pipe = Pipeline(prof)
        for m in frames:
            pipe.feed(m)
        pipe.flush()  # the samples held for the gates' look-ahead: the drive has ended
        res = pipe.result()
    finally:
        if true_stage1:
            Stage2.set_stage1 = original
    out = {"case": case, "seed": seed, "capabilities": pipe.capabilities(), "stage2_windows": 0}
    out["stage2_windows"] = sum(1 for w in res.windows if w.stage == 2)
    for kind, params_ in (("ukf", res.parameters), ("ekf", res.baseline_ekf or {})):
        rows = {}
        for name in NAMES:
            e, t = params_.get(name), truth["parameters"][name]
            if e is None:
                continue
            rows[name] = {
                "truth": t,
                "value": e.value,
                "std": e.std,
                "status": e.status,
                "valid": e.valid,
                "reason": e.reason,
                "err": None if e.value is None else (e.value - t) / t,
                "z": None if e.value is None or not e.std else abs(e.value - t) / e.std,
            }
        out[kind] = rows
    return out


def summarise(runs: list[dict], case: str) -> list[str]:
    rs = [r for r in runs if r["case"] == case]
    lines = [
        f"#### `{case}`: {len(rs)} seeds, realistic noise; stage-2 windows per run: "
        + ", ".join(str(r["stage2_windows"]) for r in rs),
        "",
        "| parameter | filter | mean abs error | worst error | ±2σ covers | valid | valid, truth > 3σ | statuses |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name in NAMES:
        for kind in ("ukf", "ekf"):
            ds = [r[kind][name] for r in rs if name in r.get(kind, {})]
            if not ds:
                continue
            errs = [d["err"] for d in ds if d["err"] is not None]
            worst = max(errs, key=abs) if errs else None
            cover = sum(1 for d in ds if d["z"] is not None and d["z"] <= 2)
            valid = sum(1 for d in ds if d["valid"])
            bad = sum(1 for d in ds if d["valid"] and d["z"] is not None and d["z"] > 3)
            st: dict[str, int] = {}
            for d in ds:
                st[d["status"]] = st.get(d["status"], 0) + 1
            mean = f"{100 * statistics.fmean(abs(e) for e in errs):.2f} %" if errs else "–"
            lines.append(
                f"| `{name}` | {kind.upper()} | {mean} | {'–' if worst is None else f'{100 * worst:+.2f} %'} | "
                f"{cover}/{len(ds)} | {valid}/{len(ds)} | {bad} | "
                + ", ".join(f"{k} {v}" for k, v in sorted(st.items()))
                + " |"
            )
    reasons = {d["reason"] for r in rs for d in r["ukf"].values() if d.get("reason")}
    for why in sorted(reasons):
        lines.append(f"\nreason given: {why}")
    lines.append("")
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, from {', '.join(CASES)}")
    ap.add_argument("--scenario", default="stage2", choices=("stage2", "paper", "city"))
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("-v", "--verbose", action="store_true", help="one line per run")
    ap.add_argument("--true-stage1", action="store_true", help="diagnostic: stage 2 gets the true h and C_K")
    a = ap.parse_args()
    cases = [c for c in a.cases.split(",") if c]
    for c in cases:
        if c not in CASES:
            ap.error(f"unknown case {c!r}; choose from {', '.join(CASES)}")
    jobs = [(c, a.scenario, s, a.true_stage1) for c in cases for s in range(a.first_seed, a.first_seed + a.seeds)]
    if a.jobs > 1:
        with ProcessPoolExecutor(a.jobs) as ex:
            runs = list(ex.map(run_one, jobs))
    else:
        runs = [run_one(j) for j in jobs]
    if a.verbose:
        for r in runs:
            cells = [
                f"{n} {100 * d['err']:+.2f}% z {d['z']:.1f} {d['status']}"
                for n, d in r["ukf"].items()
                if d["err"] is not None and d["z"] is not None
            ]
            print(f"{r['case']} seed {r['seed']}: " + "; ".join(cells))
    diag = " (diagnostic: true h and C_K handed to stage 2)" if a.true_stage1 else ""
    print(f"### Stage 2 standalone, scenario `{a.scenario}`{diag}\n")
    for c in cases:
        print("\n".join(summarise(runs, c)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
