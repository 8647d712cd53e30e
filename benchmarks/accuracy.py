"""Monte Carlo accuracy of the two-stage estimator on simulated drives.

    python benchmarks/accuracy.py --scenario paper --noise realistic --seeds 20 [--jobs 2]
    python benchmarks/accuracy.py --car toyota_rav4 --seeds 5   # a shipped car's own DBC layout

For each seed: simulate the drive in-process, run it through the same
pipeline as `vdp replay`, and compare the final estimates with the truth.
Prints a markdown table for BENCHMARKS.md: per parameter the mean and max
absolute relative error of the UKF and the EKF, the share of runs within the
target tolerance, the +-2 sigma coverage, and how often the estimator flagged
the parameter (converged / not identifiable); plus the time stage 1 took to
get all three parameters within 2 % after its first window opened.

``--car NAME`` drives profiles/NAME.toml's own DBC layout (scaling, quantisation,
signs) with vdp's add-on torque, roll-rate and GNSS messages beside it, and that
car's plausible truth (vdp.sim.addons) instead of Table 6.
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))

from vdp.core.learner import LearnerConfig  # noqa: E402
from vdp.core.params import NAMES  # noqa: E402

TOL = {"l_f": 0.01, "h": 0.03, "C_K": 0.02, "C_alpha": 0.03, "I_z": 0.05, "I_x": 0.10}


def run_one(args) -> dict:
    scenario, seed, noise, every, car, coarse = args
    import dataclasses
    import logging

    from vdp.core.estimator import EstimatorConfig
    from vdp.core.learner import LearnerConfig
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile
    from vdp.sim.addons import CAR_TRUTH, with_addons
    from vdp.sim.run import simulate

    logging.getLogger("vdp.sim.encode").setLevel(logging.ERROR)  # a car DBC's odd ranges, said once per run
    if car is None:
        profile, params = load_profile(ROOT / "profiles" / "paper.toml"), None
    else:
        profile, params = with_addons(load_profile(ROOT / "profiles" / f"{car}.toml")), CAR_TRUTH[car]
    if coarse:  # each channel's coarse signal alone, as a profile without `fine` reads it
        chans = {n: dataclasses.replace(cm, fine=None) for n, cm in profile.channels.items()}
        profile = dataclasses.replace(profile, channels=chans)
    frames, truth = simulate(profile, scenario, seed=seed, noise=noise, params=params)
    pipe = Pipeline(profile, EstimatorConfig(learner=LearnerConfig(stage2_step=every)))
    t0 = time.perf_counter()
    first = None
    n = 0
    for msg in frames:
        if first is None:
            first = msg.timestamp
        pipe.feed(msg)
        n += 1
    pipe.flush()  # the samples held for the gates' look-ahead: the drive has ended
    wall = time.perf_counter() - t0
    res = pipe.result(trace=True)
    tp = truth["parameters"]
    out = {"seed": seed, "frames": n, "wall": wall, "ukf": {}, "ekf": {}}
    for kind, params in (("ukf", res.parameters), ("ekf", res.baseline_ekf)):
        for name in NAMES:
            e = params[name]
            v, sd = e.value, e.std
            err = None if v is None else (v - tp[name]) / tp[name]
            out[kind][name] = {
                "err": err,
                "std": sd,
                "status": e.status,
                "covered": bool(v is not None and sd is not None and abs(v - tp[name]) <= 2 * sd),
            }
    # time for stage 1 to get within 2 % and stay there, from its first window
    wins = [w for w in res.windows if w.stage == 1]
    t_open = wins[0].start if wins else None
    t_in = None
    if t_open is not None:
        for row in res.trace:
            t, ukf = row[0], row[2]
            ok = all(
                ukf[i][0] is not None and abs(ukf[i][0] - tp[n_]) <= 0.02 * tp[n_]
                for i, n_ in enumerate(NAMES)
                if n_ in ("l_f", "h", "C_K")
            )
            if t >= t_open and ok and t_in is None:
                t_in = t
            elif not ok and t >= t_open:
                t_in = None
    out["t_stage1_2pct"] = None if t_in is None else t_in - t_open
    out["windows"] = [
        (w.stage, round(w.start - first, 1), None if w.end is None else round(w.end - first, 1)) for w in res.windows
    ]
    return out


def summarise(runs: list[dict], scenario: str, noise: str, car: str | None = None) -> str:
    where = f" on the `{car}` layout" if car else ""
    lines = [
        f"### `{scenario}`{where}, noise `{noise}`, {len(runs)} seeds",
        "",
        "| parameter | target | UKF mean abs err | UKF max abs err | UKF within target | ±2σ covers truth | "
        "EKF mean abs err | EKF max abs err | UKF status (runs) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name in NAMES:
        u = [r["ukf"][name] for r in runs]
        e = [r["ekf"][name] for r in runs]
        ue = [abs(x["err"]) for x in u if x["err"] is not None]
        ee = [abs(x["err"]) for x in e if x["err"] is not None]
        within = sum(1 for x in ue if x <= TOL[name])
        cov = sum(1 for x in u if x["covered"])
        status: dict[str, int] = {}
        for x in u:
            status[x["status"]] = status.get(x["status"], 0) + 1
        st = ", ".join(f"{k} {v}" for k, v in sorted(status.items()))
        pct = lambda xs, f: f"{100 * f(xs):.2f} %" if xs else "-"  # noqa: E731
        lines.append(
            f"| `{name}` | {100 * TOL[name]:.0f} % | {pct(ue, lambda a: sum(a) / len(a))} | {pct(ue, max)} | "
            f"{within}/{len(runs)} | {cov}/{len(runs)} | {pct(ee, lambda a: sum(a) / len(a))} | "
            f"{pct(ee, max)} | {st} |"
        )
    ts = [r["t_stage1_2pct"] for r in runs]
    got = [t for t in ts if t is not None]
    lines += [
        "",
        f"Stage 1 within 2 % (and staying there) after its window opened: "
        f"{len(got)}/{len(runs)} runs; "
        + (f"median {sorted(got)[len(got) // 2]:.1f} s, max {max(got):.1f} s." if got else "never."),
    ]
    frames = sum(r["frames"] for r in runs)
    wall = sum(r["wall"] for r in runs)
    lines.append(f"Pipeline (decode + UKF + EKF) on in-memory frames: {frames / wall:,.0f} frames/s.")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--noise", default="realistic")
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument(
        "--stage2-step",
        type=float,
        default=LearnerConfig().stage2_step,
        help="s between stage 2's filter steps (default: the estimator's)",
    )
    ap.add_argument(
        "--car",
        default=None,
        help="a shipped car profile (e.g. toyota_rav4): its DBC layout "
        "plus vdp's add-on sensors, and its plausible truth",
    )
    ap.add_argument(
        "--coarse",
        action="store_true",
        help="ignore the profile's `fine` signals (the RAV4's steering then reads STEER_ANGLE alone, in 1.5 deg steps)",
    )
    ap.add_argument("-v", "--verbose", action="store_true", help="one line per run")
    a = ap.parse_args()
    if a.car is not None and not (ROOT / "profiles" / f"{a.car}.toml").exists():
        ap.error(f"no profile profiles/{a.car}.toml")
    from vdp.sim.addons import CAR_TRUTH

    if a.car is not None and a.car not in CAR_TRUTH:
        ap.error(f"no simulation truth for {a.car}; cars with one: {', '.join(CAR_TRUTH)}")
    jobs = [
        (a.scenario, s, a.noise, a.stage2_step, a.car, a.coarse) for s in range(a.first_seed, a.first_seed + a.seeds)
    ]
    with ProcessPoolExecutor(max_workers=a.jobs) as ex:
        runs = list(ex.map(run_one, jobs))
    if a.verbose:
        for r in runs:
            errs = " ".join(
                f"{n}={100 * r['ukf'][n]['err']:+.2f}%" if r["ukf"][n]["err"] is not None else f"{n}=-" for n in NAMES
            )
            print(f"seed {r['seed']}: {errs} t2%={r['t_stage1_2pct']} windows={r['windows']}")
    print(summarise(runs, a.scenario, a.noise, a.car) + f"\n(stage 2 filter step every {a.stage2_step * 1000:g} ms)")
    return 0


if __name__ == "__main__":
    import benchenv

    benchenv.announce()
    sys.exit(main())
