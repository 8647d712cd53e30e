"""The understeer gradient an independent model's drive shows, against its truth's stiffnesses.

    python benchmarks/understeer.py [--cases brush/saloon,brush/small,mb/bmw_320i,mb/vw_vanagon]

On the noise-free recorded drive (the traces benchmarks/independent.py records, made here if
missing), over the stage-2 part after its first period (t > 70 s): the least-squares slope
K_us of (delta - L r / v_x) against a_y, for samples with |a_y| below 1, 2 and 4 m/s^2, and
K_us = m / L (l_r / C_f - l_f / C_r) of the truth's per-axle small-slip cornering stiffness.
A single-track model with the true C_f, C_r fits the drive's slow steering only where the
two agree (stage 2's manoeuvre is slow against the yaw modes: K_us is what it measures best).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from independent import make_trace, trace_path  # noqa: E402

CASES = ("brush/saloon", "brush/small", "mb/bmw_320i", "mb/vw_vanagon")
T_FROM = 70.0  # s: stage 2 starts at 62 s; its first period is left out


def main() -> int:
    from vdp import channels as ch
    from vdp.sim.independent.common import AUX, IndependentSimulation, Trace

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "vdp-independent-traces")
    a = ap.parse_args()
    a.cache.mkdir(parents=True, exist_ok=True)
    print("| model | K_us [rad/(m/s^2)], abs(a_y) < 1 m/s^2 | < 2 | < 4 | K_us of the truth's C_f, C_r |")
    print("|---|---|---|---|---|")
    for case in a.cases.split(","):
        make_trace((case, "paper", a.cache))
        tr = Trace.load(trace_path(a.cache, case, "paper"))
        model, car = case.split("/")
        sim = IndependentSimulation(model, car, "paper", seed=1, noise="none", duration=1.0)
        truth, veh = sim.truth, sim.profile.vehicle
        L, m, l_f = veh.wheelbase, veh.mass, truth["parameters"]["l_f"]
        c_f, c_r = truth["per_axle"]["C_alpha_front"], truth["per_axle"]["C_alpha_rear"]
        v = tr.values
        d, r, a_y, v_x = v[:, ch.DELTA], v[:, ch.YAW], v[:, ch.AY], tr.aux[:, AUX.index("v_x")]
        cells = []
        for lim in (1.0, 2.0, 4.0):
            s = (tr.t > T_FROM) & (np.abs(a_y) < lim)
            y = d[s] - L * r[s] / v_x[s]
            cells.append(f"{np.linalg.lstsq(a_y[s][:, None], y, rcond=None)[0][0]:.2e}")
        k_truth = m / L * ((L - l_f) / c_f - l_f / c_r)
        print(f"| `{case}` | " + " | ".join(cells) + f" | {k_truth:.2e} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
