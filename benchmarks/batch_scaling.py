"""vdp batch on a local cluster: 1 worker against 2, over the same simulated logs.

    python benchmarks/batch_scaling.py [--logs 16] [--workers 1 2]

Simulates (once, in /tmp) ``--logs`` paper drives (112 s each, seeds 1..N, with
4 unrelated ids at 100 Hz), then runs ``vdp batch DIR --out OUT --redo`` once
per worker count and prints the wall time of the whole command and of the
task phase (``ran N logs in X s``, after the cluster is up), and the CPU time
the threads that replayed the logs spent on them (runs.parquet's ``cpu_s``).  Wall time moves with
other load on the machine; CPU time much less.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))


def build(d: Path, n: int) -> None:
    from vdp.sim.run import simulate, write_log

    d.mkdir(parents=True, exist_ok=True)
    for seed in range(1, n + 1):
        p = d / f"drive-{seed:03d}.log"
        if not p.exists():
            frames, _ = simulate(ROOT / "profiles" / "paper.toml", "paper", seed=seed, extra_ids=4, extra_rate=100.0)
            write_log(frames, p)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logs", type=int, default=16)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--dir", type=Path, default=Path("/tmp/vdp-batch-scaling"))
    a = ap.parse_args()
    logs = a.dir / "logs"
    build(logs, a.logs)
    env = dict(os.environ, PYTHONPATH=str(ROOT / "service"))
    base = None
    for w in a.workers:
        t0 = time.perf_counter()
        r = subprocess.run(
            [sys.executable, "-c", "import sys; from vdp.cli import main; sys.exit(main())", "batch", str(logs),
             "--out", str(a.dir / f"out-{w}"), "--workers", str(w), "--redo", "--no-progress"],
            capture_output=True, text=True, env=env,
        )  # fmt: skip
        wall = time.perf_counter() - t0
        m = re.search(r"ran (\d+) logs in ([\d.]+) s", r.stdout)
        if r.returncode != 0 or not m:
            print(r.stdout, r.stderr, file=sys.stderr)
            return 1
        tasks = float(m.group(2))
        base = base or tasks
        import pyarrow.parquet as pq

        runs = pq.read_table(a.dir / f"out-{w}" / "runs.parquet").to_pylist()
        cpu = sum({r["log"]: r["cpu_s"] or 0.0 for r in runs}.values())
        print(
            f"{w} worker(s): {a.logs} logs in {wall:.1f} s (command), tasks {tasks:.1f} s, "
            f"{a.logs / tasks:.2f} logs/s, speed-up {base / tasks:.2f}; CPU of the tasks {cpu:.1f} s "
            f"(wall/CPU {w * tasks / cpu:.2f} per worker)"
        )
    return 0


if __name__ == "__main__":
    import benchenv

    benchenv.announce()
    sys.exit(main())
