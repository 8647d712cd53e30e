"""The compiled filter steps against numpy's on whole seeded drives: the largest relative
difference of any estimate and std, and every status.

    python benchmarks/kernels_equal.py [--scenario paper] [--seed 7]

Runs the simulated drive through the pipeline (UKF only) twice, with
``LearnerConfig.compiled`` off (core.filters' numpy steps, the reference) and on
(core.kernels), and prints both CPU times and the differences.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))


def main() -> int:
    from vdp.core.estimator import EstimatorConfig
    from vdp.core.learner import LearnerConfig
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile
    from vdp.sim.run import simulate

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--seed", type=int, default=7)
    a = ap.parse_args()
    prof = load_profile(ROOT / "profiles" / "paper.toml")
    frames = list(simulate(prof, a.scenario, seed=a.seed, noise="realistic")[0])
    out = {}
    for compiled in (False, True):
        pipe = Pipeline(prof, EstimatorConfig(baseline=False, learner=LearnerConfig(compiled=compiled)))
        t0 = time.process_time()
        for m in frames:
            pipe.feed(m)
        pipe.flush()  # the samples held for the gates' look-ahead: the drive has ended
        out[compiled] = pipe.result().parameters
        print(f"compiled={compiled}: {time.process_time() - t0:.2f} s of CPU (compiled: with numba's start-up)")
    worst, same = 0.0, True
    for name, e in out[False].items():
        c = out[True][name]
        dv = abs(c.value - e.value) / abs(e.value)
        ds = abs(c.std - e.std) / e.std
        worst = max(worst, dv, ds)
        same &= (c.status, c.valid, c.reason, c.samples) == (e.status, e.valid, e.reason, e.samples)
        print(f"  {name:8} numpy {e.value!r:>22} compiled {c.value!r:>22}  rel {dv:.1e}, std rel {ds:.1e}  {e.status}")
    print(f"{a.scenario}:{a.seed}: largest relative difference {worst:.1e}; statuses, reasons, samples equal: {same}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
