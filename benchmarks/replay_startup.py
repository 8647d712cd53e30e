"""Whole-process cost of `vdp replay` against a floor, pair by pair (issue 29's start-up targets).

    python benchmarks/replay_startup.py LOG [--runs 5] [--against import|reader] [--phases]

Runs, in turn and each in a fresh process, ``vdp replay LOG --no-progress`` and a floor:
``--against import`` (default), ``python -c 'import can, numpy, cantools'``; ``--against
reader``, a bare ``can.LogReader`` loop over LOG.  Prints each one's CPU (user + sys, from
the operating system's accounting of the finished child) and wall time, median of
``--runs`` after one warm-up, and the ratio vdp / floor pair by pair (median).
``--phases`` instead times, in one process, where a replay's CPU goes: imports, numba's
import and first cached load, the profile check, the replay itself.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import benchenv  # noqa: E402

FLOORS = {
    "import": ["-c", "import can, numpy, cantools"],
    "reader": ["-c", "import can, sys\nfor m in can.LogReader(sys.argv[1]): pass"],
}


def timed(cmd: list[str], env: dict) -> tuple[float, float]:
    """(CPU s, wall s) of one child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, wall


def phases(log: str) -> None:
    sys.path.insert(0, str(ROOT / "service"))
    marks = [("start", time.process_time())]

    def mark(name: str) -> None:
        marks.append((name, time.process_time()))

    from vdp import profilecheck
    from vdp.core.estimator import EstimatorConfig
    from vdp.core.learner import LearnerConfig
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile
    from vdp.replay import replay_log

    mark("imports (vdp, can, numpy, cantools)")
    import numba  # noqa: F401

    mark("numba's import")
    from vdp.io import scan

    scan.warm()
    mark("numba's first cached function (its CPU target's set-up)")
    prof = load_profile(ROOT / "profiles" / "paper.toml")
    check, _ = profilecheck.check_log(log, prof, quiet=True)
    mark("profile and its check (the log's first 300 s)")
    cfg = EstimatorConfig(learner=LearnerConfig(), baseline=False, trace_len=0)
    replay_log(log, lambda: Pipeline(prof, cfg), channel=prof.bus_channel)
    mark("the replay (read, decode, align, estimate)")
    for (_, t0), (name, t1) in zip(marks, marks[1:]):
        print(f"{name:58s} {t1 - t0:6.3f} s CPU")
    print(f"{'total':58s} {marks[-1][1] - marks[0][1]:6.3f} s CPU")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--against", choices=sorted(FLOORS), default="import")
    ap.add_argument("--phases", action="store_true")
    a = ap.parse_args()
    benchenv.announce()
    if a.phases:
        phases(a.log)
        return 0
    env = {**os.environ, "PYTHONPATH": str(ROOT / "service")}
    cli = "import sys; from vdp.cli import main; sys.exit(main())"
    vdp = [sys.executable, "-c", cli, "replay", a.log, "--no-progress"]
    floor = [sys.executable, *FLOORS[a.against]] + ([a.log] if a.against == "reader" else [])
    timed(vdp, env), timed(floor, env)  # warm-up: caches, the disk
    got: dict[str, list] = {"vdp": [], "floor": []}
    for _ in range(a.runs):
        got["vdp"].append(timed(vdp, env))
        got["floor"].append(timed(floor, env))
    med = {k: [statistics.median(x[i] for x in v) for i in (0, 1)] for k, v in got.items()}
    ratio = [statistics.median(v[i] / f[i] for v, f in zip(got["vdp"], got["floor"])) for i in (0, 1)]
    print(f"vdp replay {a.log}: {med['vdp'][0]:.3f} s CPU, {med['vdp'][1]:.3f} s wall (median of {a.runs})")
    print(f"floor ({a.against}): {med['floor'][0]:.3f} s CPU, {med['floor'][1]:.3f} s wall")
    print(f"vdp / floor, pair by pair (median): {ratio[0]:.2f}x CPU, {ratio[1]:.2f}x wall")
    return 0


if __name__ == "__main__":
    sys.exit(main())
