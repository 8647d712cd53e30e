"""CPU time of one bulk replay (UKF alone, no trace), of this checkout or another; or where it goes.

    python benchmarks/replay_cpu.py LOG [--tree CHECKOUT] [--profile] [--numpy]

Runs ``vdp.replay.replay_log(LOG, bulk=True)`` with the paper profile, as
``vdp replay LOG`` does without ``--plot`` (and ``vdp batch`` per log), on the
vdp of ``--tree`` (a git checkout or worktree of any commit; default this one),
and prints its CPU time and two of its estimates.  ``--profile`` runs it under
cProfile instead and prints where the time went (cumulative shares; cProfile
inflates many small calls).  ``--numpy`` runs the learners' numpy filter steps instead of
the compiled ones (LearnerConfig.compiled off: the reference, same estimates); ``--parts``
prints, besides the whole replay, its CPU with parts of the estimator left out (their
share without cProfile's inflation; the estimates then differ).
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
    ap.add_argument("--numpy", action="store_true", help="numpy's filter steps, not the compiled ones")
    ap.add_argument("--parts", action="store_true", help="also the CPU with parts of the estimator left out")
    a = ap.parse_args()
    sys.path.insert(0, str(a.tree / "service"))
    from vdp.core.estimator import EstimatorConfig
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile
    from vdp.replay import replay_log

    prof = load_profile(a.tree / "profiles" / "paper.toml")
    cfg = EstimatorConfig(baseline=False, trace_len=0)
    if a.numpy:
        from dataclasses import replace

        cfg = replace(cfg, learner=replace(cfg.learner, compiled=False))

    def run():
        return replay_log(a.log, lambda: Pipeline(prof, cfg), bulk=True)[0]

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

        tot = cum("io/bulk/run.py", "replay_log")
        model2 = cum("core/lateral.py", "fx") + cum("core/lateral.py", "hx")
        model1 = cum("core/longitudinal.py", "fx") + cum("core/longitudinal.py", "hx")
        steps = cum("core/filters.py", "predict") + cum("core/filters.py", "update")
        est = cum("core/estimator.py", "handle")
        for label, v in (
            ("estimator (estimator.handle)", est),
            ("  learners (both stages)", cum("core/learn/", "handle")),
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
    print(f"{a.tree}: {cpu:.2f} s of CPU; l_f {p['l_f'].value:.6f}, C_alpha {p['C_alpha'].value:.2f}", flush=True)
    if a.parts:
        parts(run, cpu)
    return 0


def parts(run, full: float) -> None:
    """The replay again with parts of the estimator left out, in the same process (warm)."""
    from vdp.core import learner as lm
    from vdp.core.estimator import TwoStageEstimator

    def cpu():
        t0 = time.process_time()
        run()
        return time.process_time() - t0

    saved = (lm.Stage1.check_batch, lm.Stage2.handle, lm.Stage1.handle, TwoStageEstimator.l_f_known)
    rows = [("whole replay (again, warm)", cpu())]

    def no_check(self, full=False):  # (the blocks' count restarts, as after a check: none is due for 20 more)
        self._since_batch = 0

    lm.Stage1.check_batch = no_check
    rows.append(("without stage 1's batch check", cpu()))
    lm.Stage2.handle = lambda self, t, s: None
    rows.append(("... and without stage 2", cpu()))
    lm.Stage1.handle = lambda self, t, s: None
    TwoStageEstimator.l_f_known = lambda self: False
    rows.append(("... and without stage 1 (compiled pass, glue left)", cpu()))
    handle, block = TwoStageEstimator.handle, TwoStageEstimator.handle_block
    TwoStageEstimator.handle = lambda self, t, s: s
    TwoStageEstimator.handle_block = lambda self, *a: None
    rows.append(("front only (reader, decoder, aligner)", cpu()))
    TwoStageEstimator.handle, TwoStageEstimator.handle_block = handle, block
    lm.Stage1.check_batch, lm.Stage2.handle, lm.Stage1.handle, TwoStageEstimator.l_f_known = saved
    for label, t in rows:
        print(f"{label:58} {t:6.2f} s of CPU")


if __name__ == "__main__":
    sys.exit(main())
