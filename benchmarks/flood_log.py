"""A candump log flooded with distinct unknown ids, for the reader's memory caps.

    python benchmarks/flood_log.py SRC OUT [--ids 1000000] [--per-line 2]

Copies SRC (a candump log) to OUT and after each of its lines writes
``--per-line`` frames of a new extended id (0x00100000 upwards, one data byte,
the line's own timestamp) until ``--ids`` distinct ids are written.  Then, e.g.
``/usr/bin/time -f "%M KB %U s" vdp replay OUT --no-progress --json out.json``.
"""

from __future__ import annotations

import argparse
import sys


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src")
    ap.add_argument("out")
    ap.add_argument("--ids", type=int, default=1_000_000)
    ap.add_argument("--per-line", type=int, default=2)
    a = ap.parse_args()
    k = 0
    with open(a.src, "rb") as src, open(a.out, "wb") as f:
        for ln in src:
            f.write(ln)
            ts = ln.split(b" ")[0]
            for _ in range(a.per_line):
                if k < a.ids:
                    f.write(ts + b" can0 %08X#00\n" % (0x100000 + k))
                    k += 1
    print(f"wrote {a.out}: {k:,} distinct unknown ids")
    return 0


if __name__ == "__main__":
    sys.exit(main())
