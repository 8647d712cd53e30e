"""CPU time of the estimator against the whole in-memory pipeline, on the `paper` drive.

    PYTHONPATH=TREE/service python benchmarks/estimator_cost.py LABEL [--per-axle] [--no-batch-check]

Run it with PYTHONPATH on two trees (say, before and after a change), back to back: it
prints, per seed, the pipeline's CPU time (with the final result, as a replay ends), the
part spent inside ``TwoStageEstimator.handle`` and in that final result (stage 2's batch
check is solved when a result is asked for), and that part's share.  ``--per-axle``: stage 2 estimates
each axle's cornering stiffness (LearnerConfig.per_axle; a tree that has it);
``--no-batch-check``: without stage 2's output-error batch check (LearnerConfig.batch_check).
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile
    from vdp.sim.run import simulate

    logging.disable(logging.WARNING)
    prof = load_profile(ROOT / "profiles" / "paper.toml")
    flags = ("--per-axle", "--no-batch-check")
    args = [a for a in sys.argv[1:] if a not in flags]
    cfg = None
    if any(f in sys.argv for f in flags):
        from vdp.core.estimator import EstimatorConfig
        from vdp.core.learner import LearnerConfig

        kw = {"batch_check": False} if "--no-batch-check" in sys.argv else {}
        if "--per-axle" in sys.argv:
            kw["per_axle"] = True
        cfg = EstimatorConfig(learner=LearnerConfig(**kw))
    cells = []
    for seed in (1, 2):
        frames = list(simulate(prof, "paper", seed=seed, noise="realistic")[0])
        pipe = Pipeline(prof, cfg)
        est = pipe.estimator
        spent = [0.0]

        def timed(t, s, _handle=est.handle, spent=spent):
            t0 = time.process_time()
            _handle(t, s)
            spent[0] += time.process_time() - t0

        est.handle = timed
        t0 = time.process_time()
        for m in frames:
            pipe.feed(m)
        # the result a replay ends with: stage 2's batch check (core.output_error) is solved here
        pipe.flush()  # the samples held for the gates' look-ahead: the drive has ended
        t1 = time.process_time()
        pipe.result()
        snap = time.process_time() - t1
        total = time.process_time() - t0
        est_s = spent[0] + snap
        cells.append(
            f"seed {seed}: pipeline {total:.2f} s, estimator {est_s:.2f} s ({est_s / total:.0%}; "
            f"of it the final result {snap:.2f} s)"
        )
    print((args[0] + ": " if args else "") + "; ".join(cells))
    return 0


if __name__ == "__main__":
    sys.exit(main())
