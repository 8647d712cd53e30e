"""How stage 2's input sampling biases C_alpha and I_z where the model is exact (issue 24).

    python benchmarks/stage2_sampling.py [--car light] [--every 1,2,5,10,20,40] [--staircase]

vdp's own simulator, noise-free truth (no CAN, no quantisation, no filter): the paper drive's
stage-2 segment, sampled every N ms, fitted by stage 2's output-error fit
(core.output_error) with the true l_f, h and C_K.  At 1 ms the fit must land on the truth (the
simulator and the model agree); what remains at 20 ms (the estimator's tick) and 40 ms (the
fit's record) is the cost of interpolating the inputs linearly between samples while the
steering turns faster than the lateral mode settles.  ``--staircase``: the simulator as it was
before, the road-wheel angle held over each 1-ms step (half a step behind its samples).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))
sys.path.insert(0, str(ROOT / "benchmarks"))

import robust  # noqa: E402
from vdp.core import lateral, output_error  # noqa: E402
from vdp.sim.run import trace  # noqa: E402
from vdp.sim.scenario import get_scenario  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--car", default="light", choices=sorted(robust.CARS))
    ap.add_argument("--every", default="1,2,5,10,20,40", help="sample spacings, ms")
    ap.add_argument("--staircase", action="store_true", help="hold the steering over each 1-ms step (the old sim)")
    a = ap.parse_args()
    if a.staircase:
        from vdp.sim.driver import Driver

        Driver.next_delta = lambda self, cmd: None  # vehicle.Model.advance then holds the angle
    prof, truth = robust.car_profile(a.car, 1.0)
    v = prof.vehicle
    tr = trace("paper", prof, params=truth, every=1)
    seg = next(s for s in get_scenario("paper", v.wheelbase).segments if s.kind == "stage2")
    k = lateral.Known(
        m=v.mass, L=v.wheelbase, r=v.wheel_radius, k_phi=v.roll_stiffness, c_phi=v.roll_damping,
        l_f=truth["l_f"], h=truth["h"], C_K=truth["C_K"], g=v.g,
    )  # fmt: skip
    c, i_z = truth["C_alpha"], truth["I_z"]
    prior_t, prior_p = np.log([c, c, i_z]), np.diag([0.25, 0.25, 0.25])
    how = "held over each 1-ms step" if a.staircase else "continuous"
    print(f"car {a.car}: C_alpha {c:g} N/rad per axle, I_z {i_z:g} kg m^2, m {v.mass:g} kg; steering {how}")
    print("| samples every | C_alpha front | rear | I_z |")
    print("|---|---|---|---|")
    inside = np.flatnonzero((tr["t"] >= seg.start + 1.0) & (tr["t"] < seg.end))
    for ms in (int(s) for s in a.every.split(",")):
        n = inside[::ms]
        u = np.column_stack([tr["delta"][n], tr["v_x"][n], tr["omega_f"][n], tr["a_x"][n]])
        z = np.column_stack([tr["yaw_rate"][n], tr["a_y"][n], np.full(len(n), np.nan)])
        prob = output_error.Problem(tr["t"][n], u, z, [(0, len(n))], k, (0.1 * np.pi / 180, 0.05))
        fit = output_error.solve(prob, prior_t, prior_p, [np.array([c, c, i_z])])
        e = 100 * (fit.theta / np.array([c, c, i_z]) - 1)
        print(f"| {ms} ms | {e[0]:+.2f} % | {e[1]:+.2f} % | {e[2]:+.2f} % |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
