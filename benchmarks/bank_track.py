"""How well stage 2's bank state (core.lateral.BANK, with --road) tracks the simulated road's bank.

    python benchmarks/bank_track.py [--cases vdp,brush] [--scenarios paper] [--conditions bank,hills] [--seeds 3]

Each run simulates a drive as benchmarks/load_grade.py does, replays it with the mass and the road
modelled (``vdp replay --mass --road``), and compares the UKF's g sin(bank) at each of its updates,
once its std is below 0.1 m/s^2, with the simulator's g cos(grade) sin(bank) at that time (traced
from the models' ``set_road``, once a step).  Prints one JSON line per run: the rms error, the
correlation, the truth's rms, and C_alpha's error and reason (docs/decisions/0025).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import load_grade  # (it puts the service on the path)

SETTLED_STD = 0.1  # m/s^2
_GY: list[float] = []  # the simulator's g cos(grade) sin(bank), once a step of the run now


def _trace() -> None:
    from vdp.sim import vehicle
    from vdp.sim.independent import brush

    for cls in (vehicle.Model, brush.BrushModel):
        orig = cls.set_road

        def traced(self, theta, phi, _orig=orig):
            _orig(self, theta, phi)
            _GY.append(self.gy)

        cls.set_road = traced


def run(case: str, scenario: str, cond: str, seed: int) -> dict:
    from vdp.core.estimator import EstimatorConfig
    from vdp.core.mass import MassConfig
    from vdp.core.road import RoadConfig
    from vdp.pipeline import Pipeline
    from vdp.sim.run import START_TIME

    if case == "vdp":
        from vdp.sim.run import DT
    else:
        from vdp.sim.independent.common import DT
    _GY.clear()
    sim, profile, truth, _ = load_grade.simulation(case, scenario, cond, seed)
    frames = list(sim.frames())  # the simulators run as their frames are drawn
    g = np.asarray(_GY) if _GY else np.zeros(1)  # a flat road: no set_road
    pipe = Pipeline(profile, EstimatorConfig(mass=MassConfig("on"), road=RoadConfig(on=True)))
    pipe.monitor = None
    l2 = pipe.estimator.s2["ukf"]
    seen, est = [0], []

    def at_update(s):
        if l2.updates != seen[0]:
            seen[0] = l2.updates
            b = l2.bank()
            if b is not None and b[1] < SETTLED_STD:
                est.append((s.t, b[0]))

    pipe.tap(at_update)
    for m in frames:
        pipe.feed(m)
    pipe.flush()  # the samples held for the gates' look-ahead: the drive has ended
    c = pipe.result().parameters["C_alpha"]
    t, b = np.array(est).T
    tru = g[np.clip(np.round((t - START_TIME) / DT).astype(int), 0, len(g) - 1)]
    return {
        "case": case, "scenario": scenario, "cond": cond, "seed": seed, "updates": len(t),
        "true_rms": round(float(np.sqrt(np.mean(tru**2))), 4),
        "rmse": round(float(np.sqrt(np.mean((b - tru) ** 2))), 4),
        "corr": round(float(np.corrcoef(b, tru)[0, 1]), 4) if tru.std() > 0 else None,
        "C_alpha_err": round(c.value / truth["C_alpha"] - 1.0, 4), "C_alpha_valid": c.valid,
        "C_alpha_reason": c.reason,
    }  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="vdp,brush")
    ap.add_argument("--scenarios", default="paper")
    ap.add_argument("--conditions", default="bank,hills")
    ap.add_argument("--seeds", type=int, default=3)
    a = ap.parse_args()
    _trace()
    for case in a.cases.split(","):
        for scenario in a.scenarios.split(","):
            for cond in a.conditions.split(","):
                for seed in range(1, a.seeds + 1):
                    print(json.dumps(run(case, scenario, cond, seed)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
