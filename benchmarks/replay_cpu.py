"""CPU time of one bulk replay (UKF alone, no trace), of this checkout or another; or where it goes.

    python benchmarks/replay_cpu.py LOG [--tree CHECKOUT] [--profile]

Runs ``vdp.io.bulk.replay_log(LOG, bulk=True)`` with the paper profile, as
``vdp replay LOG`` does without ``--plot`` (and ``vdp batch`` per log), on the
vdp of ``--tree`` (a git checkout or worktree of any commit; default this one),
and prints its CPU time and two of its estimates.  ``--profile`` runs it under
cProfile instead and prints where the time went (cumulative shares; cProfile
inflates many small calls).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log")
    ap.add_argument("--tree", type=Path, default=ROOT)
    ap.add_argument("--profile", action="store_true")
    a = ap.parse_args()
    sys.path.insert(0, str(a.tree / "service"))
    from vdp.core.estimator import EstimatorConfig
    from vdp.io.bulk import replay_log
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile

    prof = load_profile(a.tree / "profiles" / "paper.toml")

    def run():
        return replay_log(a.log, lambda: Pipeline(prof, EstimatorConfig(baseline=False, trace_len=0)), bulk=True)[0]

    if a.profile:
        import cProfile
        import pstats

        pr = cProfile.Profile()
        pr.enable()
        run()
        pr.disable()
        st = pstats.Stats(pr).stats

        def cum(file, name):
            return sum(v[3] for (f, _, n), v in st.items() if f.endswith(file) and n == name)

        tot = cum("io/bulk.py", "replay_log")
        model2 = cum("core/lateral.py", "fx") + cum("core/lateral.py", "hx")
        model1 = cum("core/longitudinal.py", "fx") + cum("core/longitudinal.py", "hx")
        steps = cum("core/filters.py", "predict") + cum("core/filters.py", "update")
        est = cum("core/estimator.py", "handle")
        for label, v in (
            ("estimator (estimator.handle)", est),
            ("  learners (both stages)", cum("core/learner.py", "handle")),
            ("    stage-2 model (lateral fx + hx)", model2),
            ("    filter steps, both stages, models excluded", steps - model2 - model1),
            ("    stage 1's batch check (batch.solve)", cum("core/batch.py", "solve")),
            ("  supervisor", cum("core/supervisor.py", "update")),
            (
                "  speed filter and gyro offsets",
                cum("core/estimator.py", "_speed") + cum("core/estimator.py", "update"),
            ),
            ("reader, decoder, aligner (the rest)", tot - est),
        ):
            print(f"{label:48} {100 * v / tot:5.1f} %")
        return 0
    t0 = time.process_time()
    res = run()
    cpu = time.process_time() - t0
    p = res.parameters
    print(f"{a.tree}: {cpu:.2f} s of CPU; l_f {p['l_f'].value:.6f}, C_alpha {p['C_alpha'].value:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
