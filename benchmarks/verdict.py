"""Issue 24's targets from runs another benchmark wrote: is "valid" right, and reachable?

    python benchmarks/independent.py --seeds 5 --jobs 2 --json runs.json
    python benchmarks/verdict.py runs.json

Per case set (the tuning cases the constants were chosen on, and the held-out ones), per
parameter: the share of (run x parameter) cells reported valid, valid values outside the
issue's accuracy band, valid values with the truth beyond 3 std, and how often the truth lies
within value +- 2 std.  Only the UKF's estimates, and only parameters the car lets vdp learn
(not_run is left out: a car without a roll-rate gyro has no I_x cell).
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

PARAMS = ("l_f", "h", "C_K", "C_alpha", "I_z", "I_x")
BAND = {"l_f": 0.03, "h": 0.10, "C_K": 0.10, "C_alpha": 0.10, "I_z": 0.10, "I_x": 0.20}  # issue 24's
# docs/decisions/0001-honest-std.md: which cases chose which constant
TUNING = ("brush/saloon", "mb/bmw_320i", "vdp/paper", "vdp/small", "vdp/axles")
HELD_OUT = ("brush/small", "brush/compact", "mb/vw_vanagon")


def cells(runs: list[dict], cases: tuple[str, ...]) -> dict[str, list[dict]]:
    out = defaultdict(list)
    for r in runs:
        if r["case"] not in cases:
            continue
        for p in PARAMS:
            c = r["ukf"].get(p)
            if c is None or c.get("value") is None or c.get("status") == "not_run":
                continue
            out[p].append(c)
    return out


def table(title: str, by: dict[str, list[dict]]) -> list[str]:
    rows = [
        f"#### {title}",
        "",
        "| parameter | cells | valid | valid outside the band | valid, truth > 3σ | ±2σ covers |",
        "|---|---|---|---|---|---|",
    ]
    tot = [0, 0, 0, 0, 0]
    for p in PARAMS:
        cs = by.get(p, [])
        if not cs:
            continue
        valid = [c for c in cs if c["valid"]]
        off = sum(1 for c in valid if abs(c["err"]) > BAND[p])
        beyond = sum(1 for c in valid if c.get("z") is not None and c["z"] > 3.0)
        cover = sum(1 for c in cs if c.get("z") is not None and c["z"] <= 2.0)
        for i, v in enumerate((len(cs), len(valid), off, beyond, cover)):
            tot[i] += v
        rows.append(
            f"| `{p}` ({100 * BAND[p]:g} %) | {len(cs)} | {len(valid)} ({100 * len(valid) / len(cs):.0f} %) "
            f"| {off} | {beyond} | {cover} ({100 * cover / len(cs):.0f} %) |"
        )
    n = max(tot[0], 1)
    share = f"{tot[1]} ({100 * tot[1] / n:.0f} %)"
    rows.append(f"| all | {tot[0]} | {share} | {tot[2]} | {tot[3]} | {tot[4]} ({100 * tot[4] / n:.0f} %) |")
    return [*rows, ""]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", type=Path, nargs="+", help="--json files of benchmarks/independent.py")
    a = ap.parse_args()
    runs = [r for f in a.runs for r in json.loads(f.read_text())]
    seen = sorted({r["case"] for r in runs})
    tuning = tuple(c for c in seen if c in TUNING)
    held = tuple(c for c in seen if c not in TUNING)
    indep = tuple(c for c in seen if not c.startswith("vdp/"))
    print("\n".join(table(f"Independent models, every case: {', '.join(indep)}", cells(runs, indep))))
    print("\n".join(table(f"Tuning cases: {', '.join(tuning)}", cells(runs, tuning))))
    print("\n".join(table(f"Held-out cases: {', '.join(held)}", cells(runs, held))))
    return 0


if __name__ == "__main__":
    import benchenv

    benchenv.announce()
    raise SystemExit(main())
