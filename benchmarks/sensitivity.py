"""How much stage 2's results move with the stage-1 values it is handed.

    python benchmarks/sensitivity.py --scenario paper --seed 1 --noise none [--step 0.01]

Runs one simulated drive through the replay pipeline several times.  Each time,
stage 2 is handed the true l_f, h and C_K, except one of them moved by ``--step``
(relative).  Prints the final C_alpha, I_z and I_x (UKF) as errors against the
truth, and their shift per 1 % of each stage-1 value.  This is why stage 2 carries
l_f as a consider state (core.lateral): its uncertainty matters, h's and C_K's do not.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))

from vdp.core.learner import Stage2  # noqa: E402
from vdp.pipeline import Pipeline  # noqa: E402
from vdp.profile import load_profile  # noqa: E402
from vdp.sim.run import simulate  # noqa: E402

STAGE1 = ("l_f", "h", "C_K")
STAGE2 = ("C_alpha", "I_z", "I_x")


def run(profile, frames, truth: dict, moved: str | None, step: float) -> tuple[dict, Pipeline]:
    """Final stage-2 errors (relative) with stage 1's values replaced by the truth, one moved."""
    handed = {n: truth[n] * (1.0 + step if n == moved else 1.0) for n in STAGE1}
    original = Stage2.set_stage1

    def set_stage1(self, l_f, h, c_k, l_f_std=None, h_std=None):
        original(self, handed["l_f"], handed["h"], handed["C_K"], l_f_std, h_std)

    Stage2.set_stage1 = set_stage1
    try:
        pipe = Pipeline(profile)
        for msg in frames:
            pipe.feed(msg)
        pipe.flush()  # the samples held for the gates' look-ahead: the drive has ended
    finally:
        Stage2.set_stage1 = original
    p = pipe.result().parameters
    return {n: (p[n].value - truth[n]) / truth[n] for n in STAGE2}, pipe


def correlation(pipe) -> str:
    """Stage 1's l_f std as stage 2 considers it, and stage 2's correlation with it (UKF)."""
    l2 = pipe.estimator.s2["ukf"]
    rho = l2.l_f_correlation()
    if rho is None:
        return "stage 2 did not run"
    return f"stage 1's l_f std {100 * l2.l_f_std / l2.known.l_f:.3f} %; correlation with l_f at the end: " + ", ".join(
        f"{n} {r:+.2f}" for n, r in zip(STAGE2, rho)
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--noise", default="none")
    ap.add_argument("--step", type=float, default=0.01, help="relative move of one stage-1 value (0.01 = 1 %%)")
    args = ap.parse_args()

    profile = load_profile(ROOT / "profiles" / "paper.toml")
    frames, truth = simulate(profile, args.scenario, seed=args.seed, noise=args.noise)
    frames = list(frames)
    truth = truth["parameters"]
    base, pipe = run(profile, frames, truth, None, args.step)
    print(f"`{args.scenario}`, seed {args.seed}, noise `{args.noise}`; stage 2 handed the true stage-1 values")
    print("(one moved by %g %%); UKF error at the end, and shift per 1 %% of the moved value\n" % (100 * args.step))
    print(
        "| stage-1 value handed | "
        + " | ".join(f"`{n}` error" for n in STAGE2)
        + " | "
        + " | ".join(f"`{n}` shift per 1 %" for n in STAGE2)
        + " |"
    )
    print("|---" * (1 + 2 * len(STAGE2)) + "|")
    print("| all true | " + " | ".join(f"{100 * base[n]:+.2f} %" for n in STAGE2) + " |" + " - |" * len(STAGE2))
    for moved in STAGE1:
        r, _ = run(profile, frames, truth, moved, args.step)
        shift = {n: (r[n] - base[n]) / (100 * args.step) for n in STAGE2}
        print(
            f"| `{moved}` +{100 * args.step:g} % | "
            + " | ".join(f"{100 * r[n]:+.2f} %" for n in STAGE2)
            + " | "
            + " | ".join(f"{100 * shift[n]:+.2f} %" for n in STAGE2)
            + " |"
        )
    print(f"\nWith all true: {correlation(pipe)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
