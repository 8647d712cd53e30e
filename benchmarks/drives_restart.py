"""Across drives (issue 28): does a restart of `vdp serve` carry the learning on exactly?

Two simulated drives of one car (noise-free, SCENARIO, seeds 1 and 2, an hour apart), through
the live service over its in-process virtual bus, two ways:

- restart: the first drive, a stop of the service, the second drive in a new service on the
  same store (it restores the estimates and the learners' own state);
- one run: both drives through one service, the hour between them a silence of the bus (an
  ignition cycle with the logger on).

Prints each parameter's value and std both ways, and the restart's std over the one run's:
1.00 is a restart that neither widens nor tightens what was learnt.

    PYTHONPATH=service python benchmarks/drives_restart.py [paper|stage1]
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
import time
from pathlib import Path

from vdp.live import Service
from vdp.profile import load_profile
from vdp.settings import simulate_settings
from vdp.sim.run import Simulation

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "profiles" / "paper.toml"
GAP = 3600.0


class Chain:
    def __init__(self, sims):
        self.sims = sims

    def frames(self):
        for sim in self.sims:
            yield from sim.frames()


def run(tmp: Path, profile, scenario: str, seeds: list[int], first: int) -> dict:
    settings = simulate_settings(PROFILE, tmp, scenario=scenario, speed=0, noise="none", seed=seeds[0])
    settings = dataclasses.replace(settings, store=dataclasses.replace(settings.store, commit_interval=0.2))
    svc = Service(settings, profile=profile)
    svc.sim._sim = Chain(
        [Simulation(profile, scenario, s, "none", start_time=1.7e9 + (first + k) * GAP) for k, s in enumerate(seeds)]
    )
    svc.start()
    svc.sim.wait(900)
    while svc.intake.received < svc.sim.sent:
        time.sleep(0.01)
    svc.sync()
    svc.housekeeping()
    svc.sync()
    svc.stop()
    return svc.latest.result.parameters


def main() -> None:
    scenario = sys.argv[1] if len(sys.argv) > 1 else "paper"
    profile = load_profile(PROFILE)
    a_dir, b_dir = Path(tempfile.mkdtemp()), Path(tempfile.mkdtemp())
    run(a_dir, profile, scenario, [1], 0)
    a = run(a_dir, profile, scenario, [2], 1)
    b = run(b_dir, profile, scenario, [1, 2], 0)
    print(f"{scenario}: two drives, a restart between them against one run with an ignition cycle")
    print(f"{'':8s} {'restart':>22s} {'one run':>22s}  std ratio")
    for n in ("l_f", "h", "C_K", "C_alpha", "I_z", "I_x"):
        x, y = a[n], b[n]
        if not x.samples:
            continue
        print(
            f"{n:8s} {x.value:12.5g} ± {x.std:7.3g} {y.value:12.5g} ± {y.std:7.3g}  {x.std / y.std:.3f}"
            if x.std and y.std
            else n
        )


if __name__ == "__main__":
    main()
