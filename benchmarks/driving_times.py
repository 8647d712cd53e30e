"""How much driving each parameter needs: drive time and window time until it first reads converged.

nice -n 10 python benchmarks/driving_times.py paper city     # figures in docs/DRIVING.md
"""

from __future__ import annotations

import sys
from pathlib import Path

from vdp.core.estimator import EstimatorConfig
from vdp.pipeline import Pipeline
from vdp.profile import load_profile
from vdp.sim.run import simulate

PROFILE = Path(__file__).resolve().parents[1] / "profiles" / "paper.toml"
CHECK_EVERY = 500  # frames between snapshots


def times(scenario: str, seed: int) -> tuple[float, dict]:
    frames, _ = simulate(PROFILE, scenario, seed=seed)
    pipe = Pipeline(load_profile(PROFILE), EstimatorConfig(baseline=False))
    first = t = None
    done: dict = {}
    for n, msg in enumerate(frames, 1):
        pipe.feed(msg)
        t = msg.timestamp
        first = t if first is None else first
        if n % CHECK_EVERY == 0:
            snap = pipe.result().to_dict()
            for name, e in snap["parameters"].items():
                if name not in done and e["status"] == "converged":
                    done[name] = (round(t - first, 1), snap["coaching"]["parameters"][name]["window_s"])
    pipe.flush()  # the samples held for the gates' look-ahead: the drive has ended
    final = pipe.result().to_dict()["parameters"]
    return t - first, {k: done.get(k, final[k]["status"]) for k in final}


def main(scenarios: list[str]) -> None:
    print("scenario seed drive_s  {parameter: (drive s, window s) at first converged, or final status}")
    for scenario in scenarios:
        for seed in (1, 2, 3):
            drive, res = times(scenario, seed)
            print(f"{scenario:8} {seed:4} {drive:7.0f}  {res}")


if __name__ == "__main__":
    import benchenv

    benchenv.announce()
    main(sys.argv[1:] or ["paper", "city"])
