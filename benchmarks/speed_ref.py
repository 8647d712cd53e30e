"""Stage 1 and its speed reference: how the speed's error reaches l_f, h and C_K.

    python benchmarks/speed_ref.py --case mph --seeds 5                       # the filter's speed
    python benchmarks/speed_ref.py --case mph --seeds 5 --speed true          # the simulator's speed instead
    python benchmarks/speed_ref.py --case per-axle --seeds 5 --speed-std 0.5  # stage 1 discounts the speed

Runs the paper drive of a ``benchmarks/bus.py`` case per seed and prints, over stage 1's
windows, the speed filter's error against the simulator's speed (mean, RMS, the std it
claims, autocorrelation after removing the mean), the GNSS fixes' error in the window, and
stage 1's errors with their stds.  ``--speed true`` hands stage 1 the simulator's speed in
place of the filter's; ``--speed-std`` replaces the speed std stage 1 is given (a large
value takes away the absolute slip level, leaving the front-minus-rear information).
Both replace ``TwoStageEstimator._speed`` in this process only: a measurement, not a mode.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bus  # noqa: E402  (the cases)
from vdp import channels as ch  # noqa: E402
from vdp.core import estimator as est  # noqa: E402
from vdp.sim import vehicle  # noqa: E402


def run(case: str, seed: int, noise: str, speed: str, speed_std: float | None) -> dict:
    from vdp.core.estimator import EstimatorConfig
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile
    from vdp.sim.run import START_TIME, STEP_MS, Simulation

    true_v: list[float] = []
    rows: list[tuple] = []
    fixes: list[tuple] = []
    advance, speed_fn = vehicle.Model.advance, est.TwoStageEstimator._speed

    def record(self, x, *a):  # the simulator's speed at every step
        true_v.append(x[0])
        return advance(self, x, *a)

    def speed_of(self, t, s):
        v, sd, b = speed_fn(self, t, s)
        n = int(round((t - START_TIME) / (STEP_MS / 1000.0)))
        if s.fresh[ch.SPEED] and np.isfinite(s.values[ch.SPEED]):
            fixes.append((t - s.age[ch.SPEED], s.values[ch.SPEED]))
        rows.append((n, v, sd, self.supervisor.active == 1))
        if speed == "true" and n < len(true_v):
            v = true_v[n]
        return v, (sd if speed_std is None else speed_std), b

    vehicle.Model.advance, est.TwoStageEstimator._speed = record, speed_of
    try:
        prof = load_profile(bus.CASES[case])
        sim = Simulation(prof, "paper", seed=seed, noise=noise)
        pipe = Pipeline(prof, EstimatorConfig(baseline=False))
        for msg in sim.frames():
            pipe.feed(msg)
    finally:
        vehicle.Model.advance, est.TwoStageEstimator._speed = advance, speed_fn
    tv = np.array(true_v)
    r = np.array([row for row in rows if row[3] and row[0] < len(tv) and np.isfinite(row[1])])
    err = r[:, 1] - tv[r[:, 0].astype(int)]
    ec = err - err.mean()
    lag = {k: float(ec[:-k] @ ec[k:] / (ec @ ec)) for k in (50, 100, 250)}  # 1, 2, 5 s at 20 ms
    win = (r[0, 0], r[-1, 0])
    f = np.array(fixes)
    n_fix = np.round((f[:, 0] - START_TIME) / (STEP_MS / 1000.0)).astype(int)
    inside = (n_fix >= win[0]) & (n_fix <= win[1])
    fix_err = f[inside, 1] - tv[n_fix[inside]]
    pipe.flush()  # the samples held for the gates' look-ahead: the drive has ended
    par, truth = pipe.result().parameters, sim.truth["parameters"]
    return {
        "v": (err.mean(), np.sqrt(np.mean(err**2)), r[:, 2].mean(), lag),
        "fix": (fix_err.mean(), fix_err.std(), len(fix_err)),
        "est": {p: (par[p].value / truth[p] - 1, par[p].std / truth[p]) for p in ("l_f", "h", "C_K")},
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", default="mph", help="a benchmarks/bus.py case (a part of its name)")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--noise", default="realistic")
    ap.add_argument("--speed", choices=("filter", "true"), default="filter")
    ap.add_argument("--speed-std", type=float, help="the speed std stage 1 is given [m/s] (default: the filter's)")
    a = ap.parse_args()
    logging.getLogger("vdp.sim.encode").setLevel(logging.ERROR)
    logging.getLogger("vdp.profilecheck").setLevel(logging.ERROR)
    bus._cases(Path(tempfile.mkdtemp(prefix="vdp-speed-")))
    case = next(c for c in bus.CASES if a.case in c)
    print(f"{case}, paper drive, {a.noise} noise, speed: {a.speed}, speed std to stage 1: {a.speed_std or 'filter'}")
    print(
        "| seed | v err mean | v err RMS | std to stage 1 | autocorr 1/2/5 s | fixes: mean, std (n) | l_f | h | C_K |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for seed in range(a.first_seed, a.first_seed + a.seeds):
        o = run(case, seed, a.noise, a.speed, a.speed_std)
        m, rms, sd, lag = o["v"]
        fm, fs, fn = o["fix"]
        e = " | ".join(
            f"{100 * v:+.2f} ± {100 * s:.2f} %{'' if abs(v) <= 2 * s else ' (miss)'}" for v, s in o["est"].values()
        )
        print(
            f"| {seed} | {m:+.4f} | {rms:.4f} | {sd:.4f} | {lag[50]:.2f}/{lag[100]:.2f}/{lag[250]:.2f} | "
            f"{fm:+.4f}, {fs:.3f} ({fn}) | {e} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
