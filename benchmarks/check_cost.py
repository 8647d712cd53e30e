"""CPU time of one solve of stage 2's batch check (core.output_error), numpy against compiled.

    python benchmarks/check_cost.py [--model brush --car small] [--seed 1] [--rounds 3]
                                    [--scenario stage2 --duration 330]

Replays one drive of an independent model (``paper`` scenario unless given, realistic noise; the brush cars
free the tyre's shape, the multi-body cars and vdp's own do not), then solves the UKF's stage-2
check on its full record again and again: with the fit's states by the prefix scan (numpy, what
the live service runs) and by core.kernels.oe_states (what a replay and ``vdp batch`` run),
alternated.  Prints each solve's CPU time and the two fits' C_alpha and I_z.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="brush")
    ap.add_argument("--car", default="small")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--scenario", default="paper", choices=("paper", "stage2"))
    ap.add_argument("--duration", type=float, default=None, help="s of drive (the scenario's own length at most)")
    ap.add_argument(
        "--repeat", type=int, default=1, help="the record's windows this many times, shifted in time (a fuller record)"
    )
    a = ap.parse_args()
    from vdp.core.estimator import EstimatorConfig
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile
    from vdp.sim.independent.common import IndependentSimulation

    logging.disable(logging.WARNING)
    sim = IndependentSimulation(a.model, a.car, a.scenario, a.seed, "realistic", duration=a.duration)
    with tempfile.TemporaryDirectory() as d:  # the car's profile, as vdp simulate --model writes it
        path = Path(d) / "car.profile.toml"
        path.write_text(sim.profile_toml(), encoding="utf-8")
        prof = load_profile(path)
    if a.scenario == "stage2":  # no stage 1 to learn l_f: the profile gives it, as axle scales would
        import dataclasses

        l_f = sim.truth["parameters"]["l_f"]
        prof = dataclasses.replace(prof, vehicle=dataclasses.replace(prof.vehicle, l_f=l_f, l_f_std=0.01 * l_f))
    pipe = Pipeline(prof, EstimatorConfig(baseline=False, trace_len=0))
    for m in sim.frames():
        pipe.feed(m)
    l2 = pipe.estimator.s2["ukf"]
    check = l2.check
    rec = check.record
    if a.repeat > 1:  # the same windows again later: a record as full as a longer drive's, for the cost
        span = rec.windows[-1][-1][0] - rec.windows[0][0][0] + 100.0
        first = [list(w) for w in rec.windows]
        for k in range(1, a.repeat):
            for w in first:
                rec.windows.append([(r[0] + k * span, *r[1:]) for r in w])
                rec.rows += len(w)
    print(f"{a.model}/{a.car} {a.scenario} seed {a.seed}: {check.record.rows} rows in the record")
    if not check.record.rows:
        print("no stage-2 windows: nothing to solve")
        return 1
    for r in range(a.rounds):
        for compiled in (False, True):
            check.compiled, check._at, check.fit = compiled, 0, None  # stale: solved again
            t0 = time.process_time()
            fit = l2.batch_fit()
            cpu = time.process_time() - t0
            shape = "linear" if fit.shape is None else f"shape b {fit.shape[0]:.3f} c {fit.shape[1]:.3f}"
            print(
                f"round {r + 1} {'compiled' if compiled else 'numpy   '}: {cpu:6.3f} s of CPU; "
                f"C_alpha {fit.c_alpha:.6g}, I_z {fit.theta[2]:.6g}, {shape}",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
