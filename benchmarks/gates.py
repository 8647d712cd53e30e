"""Gates (issue 28, part 3): a drive with reverse manoeuvres, ABS stops, kerb strikes and wheel spin
against the same drive without them.

    python benchmarks/gates.py --scenarios city,ordinary --seeds 3 --events reverse=2,abs=2,kerb=4,spin=2 [--jobs 2]

Each case is vdp's simulator (profiles/paper_status.toml: the paper car with its status message)
driving a scenario twice from one seed: with the events (``vdp simulate --events``) and without
them (``--events-plain``: a stop where the other reverses, a dry road where the other stops with
ABS, no kerbs, no spin).  Both are replayed as ``vdp replay`` does; the events drive a second
time with the gates counting only (GatesConfig.shut = False): what the gates are worth.

Per case it prints the share of each drive gated out, then per parameter the plain drive's value
and std, and the events drive's difference from it in the plain drive's std, gated and not:
|d| / std <= 1 is "the same estimate within its std".  The last lines count, per parameter, the
cases within 1 and 2 std, and the valid estimates (converged) whose truth lies beyond 3 std, gated
and not.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))

from vdp.core.params import NAMES  # noqa: E402

PROFILE = ROOT / "profiles" / "paper_status.toml"


def _replay(path: Path, prof, shut: bool = True):
    from vdp.core import gates as gt
    from vdp.pipeline import Pipeline
    from vdp.replay import replay_log

    def make():
        pipe = Pipeline(prof)
        su = pipe.estimator.supervisor
        su.gates = gt.Gates(gt.GatesConfig(shut=shut), su.wheel_radius)
        return pipe

    return replay_log(path, make)[0]


def case(args: tuple[str, int, str]) -> dict:
    scenario, seed, events = args
    from vdp.profile import load_profile
    from vdp.sim.events import Events
    from vdp.sim.run import Simulation, write_log

    prof = load_profile(PROFILE)
    out: dict = {"scenario": scenario, "seed": seed}
    with tempfile.TemporaryDirectory() as d:
        for effects in (True, False):
            sim = Simulation(prof, scenario, seed=seed, events=Events.parse(events, effects=effects))
            path = Path(d) / f"{effects}.log"
            write_log(sim.frames(), path)
            res = _replay(path, prof)
            key = "events" if effects else "plain"
            out[key] = {n: (e.value, e.std, e.status) for n, e in res.parameters.items()}
            out[key + "_gated"] = res.supervisor["gated"]["text"]
            out["truth"] = sim.truth["parameters"]
            if effects:
                res = _replay(path, prof, shut=False)
                out["ungated"] = {n: (e.value, e.std, e.status) for n, e in res.parameters.items()}
    return out


def _d(a, b) -> float | None:
    """(a - b) in b's std."""
    if a[0] is None or b[0] is None or not b[1]:
        return None
    return (a[0] - b[0]) / b[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", default="city,ordinary")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seed0", type=int, default=1)
    ap.add_argument("--events", default="reverse=2,abs=2,kerb=4,spin=2")
    ap.add_argument("--jobs", type=int, default=1)
    a = ap.parse_args()
    cases = [(s, k, a.events) for s in a.scenarios.split(",") for k in range(a.seed0, a.seed0 + a.seeds)]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.jobs) as ex:
        results = list(ex.map(case, cases))
    within = {n: [0, 0, 0] for n in NAMES}  # within 1 std, within 2 std, of
    ungated = {n: [0, 0] for n in NAMES}
    bad = dict.fromkeys(NAMES, 0)
    bad_ungated = dict.fromkeys(NAMES, 0)
    for r in results:
        print(f"\n{r['scenario']} seed {r['seed']}, events {a.events}")
        print(f"  with the events:    {r['events_gated']}")
        print(f"  without them:       {r['plain_gated']}")
        head = f"  {'param':8} {'plain value':>12} {'± std':>9} {'events d/std':>13} {'ungated d/std':>14}"
        print(head + "  status (events, ungated)")
        for n in NAMES:
            p, e, u = r["plain"][n], r["events"][n], r["ungated"][n]
            d, du = _d(e, p), _d(u, p)
            if d is not None:
                w = within[n]
                w[0] += abs(d) <= 1.0
                w[1] += abs(d) <= 2.0
                w[2] += 1
            if du is not None:
                ungated[n][0] += abs(du) <= 1.0
                ungated[n][1] += 1
            t = r["truth"].get(n)
            if e[2] == "converged" and t is not None and e[1] and abs(e[0] - t) > 3 * e[1]:
                bad[n] += 1
            if u[2] == "converged" and t is not None and u[1] and abs(u[0] - t) > 3 * u[1]:
                bad_ungated[n] += 1
            ds = "-" if d is None else f"{d:+.2f}"
            dus = "-" if du is None else f"{du:+.2f}"
            val = "-" if p[0] is None else f"{p[0]:.5g}"
            sd = "-" if p[1] is None or not math.isfinite(p[1]) else f"{p[1]:.2g}"
            print(f"  {n:8} {val:>12} {sd:>9} {ds:>13} {dus:>14}  {e[2]}, {u[2]}")
    print(f"\n{len(results)} cases in {time.perf_counter() - t0:.0f} s; the events drive against the plain one:")
    head = f"  {'param':8} {'within 1 std':>13} {'within 2 std':>13} {'ungated, 1 std':>15}"
    print(head + f" {'valid, truth > 3 std':>21} {'ungated: the same':>18}")
    for n in NAMES:
        w, u = within[n], ungated[n]
        row = f"  {n:8} {f'{w[0]}/{w[2]}':>13} {f'{w[1]}/{w[2]}':>13} {f'{u[0]}/{u[1]}':>15}"
        print(row + f" {bad[n]:>21} {bad_ungated[n]:>18}")


if __name__ == "__main__":
    import benchenv

    benchenv.announce()
    main()
