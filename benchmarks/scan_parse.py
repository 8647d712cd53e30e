"""The one candump parser (vdp.io.scan), compiled, against the per-frame reader's tolerant rules.

    python benchmarks/scan_parse.py LOG [--repeat 3]

In one process, CPU time, best of ``--repeat``: ``scan.lines`` (numba, compiled or loaded
from the cache before timing) over the log cut into the bulk reader's 2 MB blocks; then the
per-frame reader (``open_log``, every ``can.Message``) with the scan and with every line read
by its tolerant rules (``CandumpReader.slow``), and whether the two gave the same frames.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))

from vdp.io import bulk, logs, scan  # noqa: E402
from vdp.io.formats import candump  # noqa: E402


def blocks(path: Path) -> list[bytes]:
    raw = path.read_bytes()
    out, lo = [], 0
    while lo < len(raw):
        hi = raw.rfind(b"\n", 0, lo + bulk.BLOCK) + 1
        out.append(raw[lo:hi])
        lo = hi
    return out


def best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return min(times)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    bs = blocks(a.log)
    n = sum(b.count(b"\n") for b in bs)
    scan.warm()
    t = best(lambda: [scan.lines(b) for b in bs], a.repeat)
    print(f"scan, blocks      : {t:.3f} s of CPU for {n:,} lines ({1e9 * t / n:.0f} ns a line)")
    read: dict[bool, list] = {}
    for fast in (True, False):
        candump._use_scan = lambda size, fast=fast: fast

        def run(fast=fast):
            read[fast] = [(m.timestamp, m.arbitration_id, bytes(m.data), m.channel) for m in logs.open_log(a.log)]

        t = best(run, a.repeat)
        what = "scan + messages" if fast else "tolerant rules  "
        print(f"reader, {what}: {t:.3f} s of CPU ({1e9 * t / n:.0f} ns a line)")
    print(f"same frames both ways: {read[True] == read[False]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
