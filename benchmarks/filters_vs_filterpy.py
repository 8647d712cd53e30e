"""vdp's written-out UKF/EKF steps against filterpy's generic ones: same estimates, CPU time.

    python benchmarks/filters_vs_filterpy.py [--drives paper:1 paper:2 city:3]

Each drive (scenario:seed, realistic noise, the paper profile) is simulated once
and run through the pipeline (UKF and the EKF baseline) twice: with
vdp.core.filters, and with tests/helpers/filterpy_ref.py (the same filters on
filterpy's UnscentedKalmanFilter / ExtendedKalmanFilter steps).  Prints every
final value and std side by side, the largest relative difference, whether every
status agrees, and the CPU time of each run.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))
sys.path.insert(0, str(ROOT / "tests"))


def run(profile, frames) -> tuple[dict, float]:
    from vdp.pipeline import Pipeline

    pipe = Pipeline(profile)
    t0 = time.process_time()
    for m in frames:
        pipe.feed(m)
    pipe.flush()  # the samples held for the gates' look-ahead: the drive has ended
    r = pipe.result()
    cpu = time.process_time() - t0
    return {
        k: {n: (e.value, e.std, e.status) for n, e in p.items()}
        for k, p in (("ukf", r.parameters), ("ekf", r.baseline_ekf))
    }, cpu


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drives", nargs="+", default=["paper:1", "paper:2", "city:3"])
    a = ap.parse_args()
    from helpers import filterpy_ref
    from vdp.core import filters
    from vdp.core.learn import base as learner  # where the learners build their filters
    from vdp.profile import load_profile
    from vdp.sim.run import simulate

    profile = load_profile(ROOT / "profiles" / "paper.toml")
    worst, same_status = 0.0, True
    cpu = {"vdp": 0.0, "filterpy": 0.0}
    for d in a.drives:
        scenario, seed = d.split(":")
        frames = list(simulate(profile, scenario, seed=int(seed), noise="realistic")[0])
        out = {}
        for name, (ukf, ekf) in (
            ("vdp", (filters.UKF, filters.EKF)),
            ("filterpy", (filterpy_ref.UKF, filterpy_ref.EKF)),
        ):
            learner.UKF, learner.EKF = ukf, ekf
            out[name], c = run(profile, frames)
            cpu[name] += c
            print(f"{d}: {name} filters, {c:.1f} s of CPU")
        for kind in ("ukf", "ekf"):
            for n, (v, s, st) in out["filterpy"][kind].items():
                v2, s2, st2 = out["vdp"][kind][n]
                rv = abs(v2 - v) / abs(v) if v else abs(v2)
                rs = abs(s2 - s) / abs(s) if s else abs(s2)
                worst = max(worst, rv, rs)
                same_status &= st == st2
                print(
                    f"  {kind} {n:8} filterpy {v!r:>22} ± {s:.6g}  vdp {v2!r:>22} ± {s2:.6g}  rel {rv:.1e} / {rs:.1e}"
                )
    learner.UKF, learner.EKF = filters.UKF, filters.EKF
    print(f"largest relative difference (values and stds): {worst:.1e}; every status the same: {same_status}")
    print(f"CPU of the pipeline (UKF + EKF): filterpy steps {cpu['filterpy']:.1f} s, vdp's {cpu['vdp']:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
