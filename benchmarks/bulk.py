"""The bulk candump reader against bare python-can, in one process; and a long log's time and memory.

    python benchmarks/bulk.py --minutes 60                  # throughput, all in one run
    python benchmarks/bulk.py --minutes 240 --one bulk      # one replay: CPU time and peak RSS

Builds (once, in /tmp) a candump log of simulated `city` drives back to back
with 4 unrelated ids at 100 Hz beside vdp's ~610 frames/s, so about 40 % of
the frames carry ids the profile does not use.  Then, on CPU time:

- bare ``can.LogReader`` iteration (run first and last: the spread shows the
  machine's other load);
- the front of the pipeline alone (reader, decoder, aligner; the estimator is
  handed nothing), per-frame and bulk;
- the whole replay, per-frame and bulk, with the UKF alone (as ``vdp batch`` and
  ``vdp replay`` run) and with the EKF baseline beside it (``vdp replay --baseline ekf``),
  keeping no history of the estimates, as both do without ``--plot`` (``--trace``: keep it).

``--one MODE`` runs one replay (bulk or per-frame, UKF only) and prints its CPU
time and the process's peak RSS, for a memory and linearity check per length;
``--no-trace`` keeps no history of the estimates, as ``vdp batch`` (and ``vdp
replay`` without ``--plot``) do.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))
sys.path.insert(0, str(ROOT / "benchmarks"))

clock = time.process_time  # CPU time of this process: other load on a shared machine skews it less


def bare(path: Path) -> tuple[int, float]:
    import can

    t0 = clock()
    n = sum(1 for _ in can.LogReader(str(path)))
    return n, clock() - t0


def replay(path: Path, bulk: bool, ekf: bool, front_only: bool = False, trace: bool = True) -> tuple[float, dict]:
    from vdp.core.estimator import EstimatorConfig
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile
    from vdp.replay import replay_log

    profile = load_profile(ROOT / "profiles" / "paper.toml")

    def make():
        pipe = Pipeline(profile, EstimatorConfig(baseline=ekf, trace_len=None if trace else 0))
        if front_only:
            pipe.estimator.handle = lambda t, s: None
            pipe.estimator.handle_block = lambda *a: None
        return pipe

    t0 = clock()
    res, _ = replay_log(path, make, bulk=bulk)
    return clock() - t0, res.to_dict()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--log", type=Path, default=None, help="where to build/keep the log (default /tmp)")
    ap.add_argument("--one", choices=("bulk", "per-frame"), help="one replay (UKF only): CPU time and peak RSS")
    ap.add_argument(
        "--no-trace", action="store_true", help="with --one: keep no history of the estimates (as vdp batch)"
    )
    ap.add_argument(
        "--trace",
        action="store_true",
        help="the throughput rows keep the history of the estimates (as vdp replay --plot); by default "
        "none, as vdp replay without --plot and vdp batch run (before 2026-11-27 these rows kept it)",
    )
    a = ap.parse_args()
    path = a.log or Path(f"/tmp/vdp-bulk-{a.minutes:g}min.log")
    if not path.exists():
        from throughput import build_log

        t0 = time.perf_counter()
        build_log(path, a.minutes, 4, 100.0)
        print(f"built {path} ({path.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t0:.0f} s")
    if a.one:
        t, doc = replay(path, a.one == "bulk", ekf=False, trace=not a.no_trace)
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        lg = doc["log"]
        print(
            f"{a.one} replay of {path.name}: {lg['frames']:,} frames, {lg['duration_s'] / 3600:.2f} h of bus time, "
            f"{t:.1f} s of CPU ({lg['frames'] / t:,.0f} frames/s), peak RSS {rss:.0f} MB"
        )
        return 0
    n, tb1 = bare(path)
    print(f"log: {path}, {n:,} frames; bare can.LogReader (first): {tb1:.1f} s of CPU", flush=True)
    rows = []
    for label, bulk, ekf, front in (
        ("front only, per-frame", False, False, True),
        ("front only, bulk", True, False, True),
        ("replay UKF, per-frame", False, False, False),
        ("replay UKF, bulk", True, False, False),
        ("replay UKF+EKF, per-frame", False, True, False),
        ("replay UKF+EKF, bulk", True, True, False),
    ):
        t, doc = replay(path, bulk, ekf, front, trace=a.trace)
        rows.append((label, t, doc))
        print(f"{label:27}: {t:6.1f} s of CPU, {n / t:10,.0f} frames/s, {tb1 / t:5.2f}x the first", flush=True)
    _, tb2 = bare(path)
    tb = 0.5 * (tb1 + tb2)
    dec = rows[0][2]["log"]["decode"]
    unused = dec["errors_by_kind"].get("unknown_id", 0) / max(dec["frames"], 1)
    dur = rows[0][2]["log"]["duration_s"]
    print(f"log: {path}, {n:,} frames, {dur / 60:.1f} min of bus time, {100 * unused:.0f} % of frames unused ids")
    print(f"bare can.LogReader: {tb1:.1f} s and {tb2:.1f} s of CPU, {n / tb:,.0f} frames/s")
    for label, t, _ in rows:
        print(f"{label:27}: {t:6.1f} s of CPU, {n / t:10,.0f} frames/s, {tb / t:5.2f}x bare can.LogReader")
    same = rows[2][2]["parameters"] == rows[3][2]["parameters"] and rows[4][2]["parameters"] == rows[5][2]["parameters"]
    print(f"bulk and per-frame estimates identical: {same}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
