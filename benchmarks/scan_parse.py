"""The bulk reader's block parse: numpy's whole-array passes against the compiled scan (vdp.io.scan).

    python benchmarks/scan_parse.py LOG [--repeat 3]

Cuts a candump -L log into the reader's 2 MB blocks (at line ends) and times, in one
process, CPU time: ``BulkSource._parse`` (numpy) and ``scan.lines`` (numba, compiled or
loaded from the cache before timing) over every block, best of ``--repeat``; then checks
that both give the same arrays for every block.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))

from vdp.io import bulk, scan  # noqa: E402


def blocks(path: Path) -> list[bytes]:
    raw = path.read_bytes()
    out, lo = [], 0
    while lo < len(raw):
        hi = raw.rfind(b"\n", 0, lo + bulk.BLOCK) + 1
        out.append(raw[lo:hi])
        lo = hi
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    bs = blocks(a.log)
    n = sum(b.count(b"\n") for b in bs)
    scan.warm()
    best = {}
    for name, fn in (("numpy", lambda b: bulk.BulkSource._parse(b, 0)), ("scan", scan.lines)):
        times = []
        for _ in range(a.repeat):
            t0 = time.process_time()
            for b in bs:
                fn(b)
            times.append(time.process_time() - t0)
        best[name] = min(times)
        print(f"{name:6}: {best[name]:.3f} s of CPU for {n:,} lines ({1e9 * best[name] / n:.0f} ns a line)")
    same = True
    for b in bs:
        want, got = bulk.BulkSource._parse(b, 0), scan.lines(b)
        same &= want[0] == got[2] and all(np.array_equal(x, y) for x, y in zip(want[1:], got[3:]))
    print(f"scan {best['numpy'] / best['scan']:.1f}x numpy's parse; same arrays for every block: {same}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
