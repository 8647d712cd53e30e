"""Long drives: does the std keep up with the bias once data pile up?

    python benchmarks/long_drive.py --repeat 8 32 [--scenario paper] [--model vdp] [--seeds 1]

Per repeat count, ``vdp simulate --repeat N`` writes N drives of the scenario back to back
(realistic noise) and ``vdp replay`` estimates from the log alone, as a user would run them
(whole processes).  Per parameter: the error, the std, the truth's distance in stds, and the
verdict.  The targets (issue 24): nothing valid with the truth beyond 3 sigma, and the truth
within 2 sigma for at least 90 % of the (drive x parameter) cells.
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
PARAMS = ("l_f", "h", "C_K", "C_alpha", "I_z", "I_x", "mass")  # the mass: learnt by default (core.mass)


def vdp(*args: str) -> None:
    cmd = [str(Path(sys.executable).parent / "vdp"), *args]  # the installed command, as a user runs it
    subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)


def one(tmp: Path, scenario: str, model: str, car: str | None, repeat: int, seed: int) -> dict:
    log = tmp / f"{scenario}-{model}-x{repeat}-s{seed}.log"
    sim = ["simulate", "--scenario", scenario, "--seed", str(seed), "--noise", "realistic"]
    sim += ["--repeat", str(repeat), "--out", str(log), "--model", model]
    if car:
        sim += ["--car", car]
    t0 = time.perf_counter()
    vdp(*sim)
    made = time.perf_counter() - t0
    truth = log.with_name(log.name.removesuffix(".log") + ".truth.json")
    out = tmp / (log.stem + ".json")
    t0 = time.perf_counter()
    rep = ["replay", str(log), "--json", str(out), "--no-progress"]
    if model != "vdp":  # the independent models write the profile their drive needs beside the truth
        prof = json.loads(truth.read_text()).get("profile")
        if prof:
            rep += ["--profile", prof]
    vdp(*rep)
    replayed = time.perf_counter() - t0
    res = json.loads(out.read_text())
    doc = json.loads(truth.read_text())
    tv = dict(doc["parameters"])
    m = doc.get("mass") or (doc.get("vehicle") or {}).get("mass")  # the car as driven (no load: its profile's)
    if m:
        tv["mass"] = m
    rows = {}
    for p in PARAMS:
        e = res["parameters"][p]
        v, s = e.get("value"), e.get("std")
        if v is None or p not in tv or e.get("status") == "not_run":
            continue
        rows[p] = {
            "err": v / tv[p] - 1.0,
            "rel_std": s / abs(tv[p]) if s else None,
            "z": abs(v - tv[p]) / s if s else None,
            "valid": bool(e.get("valid")),
            "status": e.get("status"),
            "reason": e.get("reason"),
        }
    return {"repeat": repeat, "seed": seed, "made_s": made, "replay_s": replayed, "rows": rows}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, nargs="+", default=[8, 32])
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--model", default="vdp")
    ap.add_argument("--car")
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--json", type=Path, help="write every run's figures here")
    a = ap.parse_args()
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in a.repeat:
            for seed in range(a.first_seed, a.first_seed + a.seeds):
                r = one(Path(tmp), a.scenario, a.model, a.car, n, seed)
                runs.append(r)
                cells = " ".join(
                    f"{p}={100 * c['err']:+.2f}%±{100 * (c['rel_std'] or 0):.2f}"
                    f"/{(c['z'] or 0):.1f}σ{'' if c['valid'] else '(not valid)'}"
                    for p, c in r["rows"].items()
                )
                print(f"x{n} seed {seed} ({r['replay_s']:.0f} s replay): {cells}", flush=True)
    cells = [c for r in runs for c in r["rows"].values()]
    valid = [c for c in cells if c["valid"]]
    beyond = sum(1 for c in valid if c["z"] is not None and c["z"] > 3.0)
    cover = sum(1 for c in cells if c["z"] is not None and c["z"] <= 2.0)
    print(
        f"\n{a.scenario} ({a.model}) x {a.repeat}: {len(valid)}/{len(cells)} cells valid, "
        f"{beyond} valid beyond 3σ, ±2σ covers {cover}/{len(cells)}"
    )
    if a.json:
        a.json.write_text(json.dumps(runs, indent=1))
    return 0


if __name__ == "__main__":
    import benchenv

    benchenv.announce()
    raise SystemExit(main())
