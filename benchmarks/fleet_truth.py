"""A fleet of one car: is the truth within 2 std of the combination `vdp batch` gives?

    python benchmarks/fleet_truth.py [--drives 12] [--first-seed 101] [--scenario paper] [--workers 2]

``vdp simulate`` writes the drives (seeds FIRST..FIRST+N-1, realistic noise, profiles/paper.toml's
car), ``vdp batch`` replays and combines them as a user runs it (whole processes), and the
combination in vehicles.parquet is compared with the simulator's truth: its error in its own
std per parameter (issue 24's target: within 2).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def vdp(*args: str) -> None:
    subprocess.run([str(Path(sys.executable).parent / "vdp"), *args], check=True, cwd=ROOT, stdout=subprocess.DEVNULL)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drives", type=int, default=12)
    ap.add_argument("--first-seed", type=int, default=101)
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    import pandas as pd

    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        t0 = time.perf_counter()
        for seed in range(a.first_seed, a.first_seed + a.drives):
            vdp("simulate", "--scenario", a.scenario, "--seed", str(seed), "--out", str(d / f"s{seed}.log"))
        made = time.perf_counter() - t0
        t0 = time.perf_counter()
        vdp("batch", str(d / "*.log"), "--out", str(d / "res"), "--workers", str(a.workers), "--no-progress")
        ran = time.perf_counter() - t0
        truth = json.loads((d / f"s{a.first_seed}.truth.json").read_text())["parameters"]
        veh = pd.read_parquet(d / "res" / "vehicles.parquet")
        runs = pd.read_parquet(d / "res" / "runs.parquet")
    print(f"{a.drives} drives of `{a.scenario}` made in {made:.0f} s, batch {ran:.0f} s")
    print("| parameter | drives used | valid drives | combination | its std | truth | off by |")
    print("|---|---|---|---|---|---|---|")
    for _, row in veh.iterrows():
        p = row["parameter"]
        if p not in truth or row["value"] is None or pd.isna(row["value"]):
            print(f"| `{p}` | {row.get('drives')} | - | - | - | - | - |")
            continue
        valid = int(runs[(runs["parameter"] == p) & runs["valid"]].shape[0])
        z = (row["value"] - truth[p]) / row["std"]
        print(
            f"| `{p}` | {row['drives']} | {valid} | {row['value']:.6g} | {row['std']:.3g} "
            f"({100 * row['std'] / truth[p]:.2f} %) | {truth[p]:.6g} | {z:+.2f} σ |"
        )
    return 0


if __name__ == "__main__":
    import benchenv

    benchenv.announce()
    raise SystemExit(main())
