"""Where stage 2's cornering stiffness goes wrong on the independent models.

    python benchmarks/stage2_mismatch.py fit [--cases brush/saloon,...]
    python benchmarks/stage2_mismatch.py replay [--cases ...] [--pin] [--no-roll] [--no-fxf] [--per-axle]

``fit``: on the noise-free recorded drive (the traces benchmarks/independent.py records,
made here if missing), the stage-2 part from 62 s: the linear single-track model without
roll (eqs 5, 7, 10, 12 with F_xf left out), driven by the drive's road-wheel angle and
speed, is fitted by least squares to its yaw rate and a_y (weights 0.01 rad/s, 0.1 m/s^2)
over C_f, C_r and I_z.  Prints the residuals at the truth's values and the best fit as
multiples of the truth: what the best linear single track makes of the car.

``replay``: the noise-free drive through the replay pipeline; ``--pin`` hands stage 2 the
truth's l_f, h and C_K (stage 1's errors out of the way), ``--no-roll`` leaves the roll-rate
row out of stage 2's updates (what eq 9's roll model does to the other parameters),
``--no-fxf`` leaves the front longitudinal force out of stage 2's model (C_K = 0 there, as
the fit does: what the wheel-speed slip does to it).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from independent import make_trace, trace_path  # noqa: E402

CASES = ("brush/saloon", "brush/small", "mb/bmw_320i", "mb/vw_vanagon")
T_STAGE2 = 62.0  # s: the paper drive's stage-2 part starts here
STEP = 5  # ms: the fit's integration step (semi-implicit Euler; the yaw modes are ~10x slower)


def _trace(case: str, cache: Path):
    from vdp.sim.independent.common import Trace

    make_trace((case, "paper", cache))
    return Trace.load(trace_path(cache, case, "paper"))


def _truth(case: str):
    from vdp.sim.independent.common import IndependentSimulation

    model, car = case.split("/")
    s = IndependentSimulation(model, car, "paper", seed=1, noise="none", duration=1.0)
    return s.truth, s.profile.vehicle


def single_track(theta, d, v_x, dt: float, m: float, L: float, l_f: float):
    """Yaw rate and a_y of the linear single track (no roll, no F_xf) from rest, per sample."""
    c_f, c_r, i_z = theta
    l_r = L - l_f
    v_y = r = 0.0
    yaw, a_y = np.empty(len(d)), np.empty(len(d))
    for i in range(len(d)):
        v, cd = v_x[i], math.cos(d[i])
        f_yf = c_f * (d[i] - (v_y + l_f * r) / v)
        f_yr = c_r * (l_r * r - v_y) / v
        ay = (f_yf * cd + f_yr) / m
        yaw[i], a_y[i] = r, ay
        v_y += dt * (ay - v * r)
        r += dt * (l_f * f_yf * cd - l_r * f_yr) / i_z
    return yaw, a_y


def fit(case: str, cache: Path) -> str:
    from scipy.optimize import least_squares

    from vdp import channels as ch
    from vdp.sim.independent.common import AUX

    tr = _trace(case, cache)
    truth, veh = _truth(case)
    m, L, l_f = veh.mass, veh.wheelbase, truth["parameters"]["l_f"]
    sel = slice(int(T_STAGE2 * 1000), None, STEP)
    d, v_x = tr.values[sel, ch.DELTA], tr.aux[sel, AUX.index("v_x")]
    yaw, a_y = tr.values[sel, ch.YAW], tr.values[sel, ch.AY]
    skip = int(3000 / STEP)  # the model starts from rest: its first 3 s are left out
    t0 = np.array([truth["per_axle"]["C_alpha_front"], truth["per_axle"]["C_alpha_rear"], truth["parameters"]["I_z"]])

    def res(k):
        y, a = single_track(k * t0, d, v_x, STEP / 1000.0, m, L, l_f)
        return np.concatenate([(y - yaw)[skip:] / 0.01, (a - a_y)[skip:] / 0.1])

    def rms(e):
        n = len(e) // 2
        return math.sqrt(np.mean((e[:n] * 0.01) ** 2)), math.sqrt(np.mean((e[n:] * 0.1) ** 2))

    at_truth = rms(res(np.ones(3)))
    best = least_squares(res, np.ones(3), diff_step=1e-3)
    k, r = best.x, rms(best.fun)
    return (
        f"| `{case}` | {at_truth[0]:.4f} / {at_truth[1]:.3f} | {k[0]:.3f} | {k[1]:.3f} | {k[2]:.3f} "
        f"| {r[0]:.4f} / {r[1]:.3f} |"
    )


def replay_one(case: str, cache: Path, pin: bool, no_roll: bool, per_axle: bool, no_fxf: bool = False) -> list[str]:
    import logging

    from vdp.core.estimator import EstimatorConfig
    from vdp.core.learner import LearnerConfig, Stage2
    from vdp.io.logs import open_log
    from vdp.pipeline import Pipeline
    from vdp.replay import replay
    from vdp.sim.independent.common import IndependentSimulation
    from vdp.sim.run import write_log

    logging.getLogger("vdp").setLevel(logging.ERROR)
    model, car = case.split("/")
    sim = IndependentSimulation(model, car, "paper", seed=0, noise="none", trace=_trace(case, cache))
    t = sim.truth["parameters"]
    set_stage1, measurements = Stage2.set_stage1, Stage2.measurements
    if pin or no_fxf:

        def pinned(self, l_f, h, c_k, l_f_std=None, *rest):
            if pin:
                l_f, h, c_k, l_f_std = t["l_f"], t["h"], t["C_K"], 1e-4
            set_stage1(self, l_f, h, None if no_fxf else c_k, l_f_std)

        Stage2.set_stage1 = pinned
    if no_roll:

        def without_roll(s):
            z, mask = measurements(s)
            mask = mask.copy()
            mask[1] = False  # lateral.Z_ROLL
            return z, mask

        Stage2.measurements = staticmethod(without_roll)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            log = Path(tmp) / "drive.log"
            write_log(sim.frames(), log, sim.bus_channel)
            pipe = Pipeline(sim.profile, EstimatorConfig(learner=LearnerConfig(per_axle=per_axle)))
            res = replay(open_log(log, channel=sim.profile.bus_channel), pipe).to_dict()
    finally:
        Stage2.set_stage1, Stage2.measurements = set_stage1, staticmethod(measurements)
    out = []
    for kind, key in (("UKF", "parameters"), ("EKF", "baseline_ekf")):
        p = res.get(key) or {}
        if not p:
            continue
        cells = [f"{100 * (p[n]['value'] / t[n] - 1):+.1f} %" for n in ("C_alpha", "I_z", "I_x")]
        out.append(f"| `{case}` | {kind} | " + " | ".join(cells) + " |")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=("fit", "replay"))
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--pin", action="store_true", help="stage 2 gets the truth's l_f, h, C_K")
    ap.add_argument("--no-roll", action="store_true", help="stage 2 leaves the roll-rate row out")
    ap.add_argument("--no-fxf", action="store_true", help="stage 2 leaves the front longitudinal force out")
    ap.add_argument("--per-axle", action="store_true")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "vdp-independent-traces")
    a = ap.parse_args()
    a.cache.mkdir(parents=True, exist_ok=True)
    cases = [c for c in a.cases.split(",") if c]
    if a.what == "fit":
        print("| model | rms yaw / a_y error at the truth | C_f | C_r | I_z (best fit / truth) | rms at the best fit |")
        print("|---|---|---|---|---|---|")
        for c in cases:
            print(fit(c, a.cache))
        return 0
    # the replay runs with the EKF baseline too (EstimatorConfig's default)
    print("| model | filter | C_alpha | I_z | I_x |")
    print("|---|---|---|---|---|")
    for c in cases:
        print("\n".join(replay_one(c, a.cache, a.pin, a.no_roll, a.per_axle, a.no_fxf)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
