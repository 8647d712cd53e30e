"""Replay throughput against bare python-can log iteration, on one long log.

    python benchmarks/throughput.py --minutes 60 [--log /tmp/vdp-1h.log]

Builds (once) a candump log of simulated `city` drives back to back with
unrelated filler IDs mixed in, about 2000 frames/s as on a real bus, then in
one run measures:

- bare ``can.LogReader`` iteration over the file (frames/s);
- ``vdp replay``'s pipeline over the same file: our reader, decoder, aligner,
  supervisor, UKF and EKF (frames/s, and how many times faster than real time);
- the ratio of the two (target: >= 0.5).

``--layers`` adds the cost of the front of the pipeline alone: our reader (with
the ids nobody decodes passed over, as replay does), then the decoder, then the
aligner; what remains of the replay is the estimator.

Times are the process's CPU time, so that other load on the machine skews them less.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))


def build_log(path: Path, minutes: float, filler_ids: int, filler_rate: float) -> None:
    from vdp.profile import load_profile
    from vdp.sim.run import START_TIME, Simulation

    profile = load_profile(ROOT / "profiles" / "paper.toml")
    t_end = START_TIME + minutes * 60.0
    offset = 0.0
    seed = 1
    with open(path, "w", encoding="ascii") as out:
        while START_TIME + offset < t_end:
            sim = Simulation(
                profile,
                "city",
                seed=seed,
                noise="realistic",
                extra_ids=filler_ids,
                extra_rate=filler_rate,
                start_time=START_TIME + offset,
            )
            last = None
            for msg in sim.frames():
                if msg.timestamp >= t_end:
                    break
                out.write(f"({msg.timestamp:.6f}) can0 {msg.arbitration_id:03X}#{msg.data.hex().upper()}\n")
                last = msg.timestamp
            offset = (last or START_TIME + offset) - START_TIME + 0.01
            seed += 1


# CPU time of this process, not wall time: other work on a shared machine then
# changes the figures far less (both sides are single-threaded)
clock = time.process_time


def bare(path: Path) -> tuple[int, float]:
    import can

    t0 = clock()
    n = 0
    for _ in can.LogReader(str(path)):
        n += 1
    return n, clock() - t0


def ours(path: Path) -> tuple[int, float, float, dict]:
    from vdp.io.logs import open_log
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile
    from vdp.replay import replay

    profile = load_profile(ROOT / "profiles" / "paper.toml")
    pipe = Pipeline(profile)
    t0 = clock()
    result = replay(open_log(path), pipe)
    wall = clock() - t0
    return result.log.frames, wall, result.log.duration_s, result


def layers(path: Path) -> None:
    from vdp.io.logs import open_log
    from vdp.pipeline import Pipeline
    from vdp.profile import load_profile

    profile = load_profile(ROOT / "profiles" / "paper.toml")

    def source(pipe):
        src = open_log(path)
        src.keep_ids(pipe.decoder.ids)
        return src

    def reader():
        for _ in source(Pipeline(profile)):
            pass

    def decoder():
        pipe = Pipeline(profile)
        dec = pipe.decoder.decode
        for msg in source(pipe):
            dec(msg)

    def aligner():
        pipe = Pipeline(profile)
        dec, push = pipe.decoder.decode, pipe.aligner.push
        for msg in source(pipe):
            pairs = dec(msg)
            if pairs:
                for _ in push(msg.timestamp, pairs):
                    pass

    for name, fn in (("reader", reader), ("reader + decoder", decoder), ("reader + decoder + aligner", aligner)):
        t0 = clock()
        fn()
        print(f"  {name}: {clock() - t0:.1f} s of CPU")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--log", type=Path, default=None, help="where to build/keep the log (default /tmp)")
    ap.add_argument("--filler-ids", type=int, default=14, help="unrelated IDs, each at --filler-rate Hz")
    ap.add_argument("--filler-rate", type=float, default=100.0)
    ap.add_argument("--layers", action="store_true", help="also time the reader, decoder and aligner alone")
    a = ap.parse_args()
    path = a.log or Path(f"/tmp/vdp-throughput-{a.minutes:g}min.log")
    if not path.exists():
        t0 = time.perf_counter()
        build_log(path, a.minutes, a.filler_ids, a.filler_rate)
        print(f"built {path} ({path.stat().st_size / 1e6:.0f} MB) in {time.perf_counter() - t0:.0f} s")
    # bare, ours, bare: the two bare runs bracket ours, so load from other work
    # on the machine shows up as a spread instead of skewing the ratio
    n_bare, t_bare1 = bare(path)
    n_ours, t_ours, duration, result = ours(path)
    _, t_bare2 = bare(path)
    t_bare = 0.5 * (t_bare1 + t_bare2)
    print(f"bare runs: {t_bare1:.1f} s and {t_bare2:.1f} s of CPU")
    print(
        f"log: {path}, {n_bare:,} frames, {duration / 60:.1f} min of bus time, "
        f"{n_bare / duration:,.0f} frames/s on the bus"
    )
    print(f"bare can.LogReader: {n_bare / t_bare:,.0f} frames/s ({t_bare:.1f} s)")
    print(f"vdp replay pipeline: {n_ours / t_ours:,.0f} frames/s ({t_ours:.1f} s), {duration / t_ours:.0f}x real time")
    print(f"ratio (replay / bare reader): {(n_ours / t_ours) / (n_bare / t_bare):.2f}")
    windows = result.to_dict()["windows"]  # times since the start of the log
    busy = sum((w["end"] or duration) - w["start"] for w in windows)
    print(f"windows: {len(windows)}, filters ran on {100 * busy / duration:.0f} % of the drive")
    if a.layers:
        print("front of the pipeline alone:")
        layers(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
