"""RSS of the live service over a 1-hour simulated drive, faster than real time.

    python benchmarks/service_rss.py [--minutes 60] [--extra-ids 74] [--every 60]

Simulated `paper` drives back to back (a new seed each, realistic noise), with the
saturated bus's filler IDs unless ``--extra-ids 0``, go onto a python-can virtual
bus as fast as the service keeps up (the sender waits while the estimation queue
is half full, as ``vdp serve --simulate --sim-speed 0`` does, or 4096 frames are
still on the virtual bus), through the whole
service: Notifier, rotating raw log, pipeline, store commits, snapshots.  RSS is
read from /proc/self/status every ``--every`` seconds of bus time.  It prints the
samples, the peak, and the growth from the end of the warm-up (the first 10 % of
the drive, at least 5 minutes) to the end.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import service_common as c


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=60.0, help="bus time")
    ap.add_argument("--extra-ids", type=int, default=c.FILLER_IDS)
    ap.add_argument("--every", type=float, default=60.0, help="seconds of bus time between RSS samples")
    ap.add_argument("--json", type=Path, help="also write the samples here")
    a = ap.parse_args()

    from vdp.live import Service

    tmp = Path(tempfile.mkdtemp(prefix="vdp-bench-"))
    s = c.settings(tmp)
    svc = Service(s)
    svc.start()
    c.wait_up(svc)
    seconds = a.minutes * 60.0
    start = 1700000000.0
    # The virtual bus queues without bound between the sender and the receive thread: pause on
    # frames in flight there too, or a starved receive thread would grow the benchmark's memory.
    sender = c.SenderThread(svc.bus_cfg.channel, seconds, start, extra_ids=a.extra_ids,
                            backlog=lambda: max(svc.backlog(), (sender.sent - svc.intake.received) / 8192))
    w0 = time.monotonic()
    samples = [(0.0, 0.0, c.rss_mb(), 0)]
    print(f"{'bus time':>9} {'wall':>7} {'RSS MB':>7} {'frames':>12}")
    print(f"{0:>8.0f}s {0:>6.0f}s {samples[0][2]:>7.1f} {0:>12,}", flush=True)
    sender.start()
    nxt = a.every
    while not sender.done.is_set() or nxt <= seconds:
        bus_t = (svc.latest.bus_time or start) - start
        if bus_t >= nxt or sender.done.is_set():
            if sender.done.is_set():
                c.drain(svc, sender.sent)
                bus_t = (svc.latest.bus_time or start) - start
            row = (bus_t, time.monotonic() - w0, c.rss_mb(), svc.intake.received)
            samples.append(row)
            print(f"{row[0]:>8.0f}s {row[1]:>6.0f}s {row[2]:>7.1f} {row[3]:>12,}", flush=True)
            nxt = (int(bus_t // a.every) + 1) * a.every
            if sender.done.is_set():
                break
        time.sleep(0.2)
    counts = c.service_counts(svc)
    raw = svc.rawlog.stats()
    svc.stop()
    shutil.rmtree(tmp, ignore_errors=True)

    warm = max(0.1 * seconds, min(300.0, seconds / 2))
    after = [r for r in samples if r[0] >= warm]
    base = after[0][2] if after else float("nan")
    end = samples[-1][2]
    peak = max(r[2] for r in samples)
    lo = min(r[2] for r in after) if after else float("nan")
    hi = max(r[2] for r in after) if after else float("nan")
    wall = samples[-1][1]
    print(f"drive: {samples[-1][0] / 60:.1f} min of bus time in {wall / 60:.1f} min "
          f"({samples[-1][0] / max(wall, 1e-9):.1f}x real time), {counts['received']:,} frames "
          f"({a.extra_ids} filler IDs), dropped {counts['dropped']}, raw log files closed {raw['closed_files']} "
          f"(deleted {raw['deleted_files']}), stage {counts['stage']}")
    print(f"RSS: start {samples[0][2]:.1f} MB, after warm-up ({warm / 60:.0f} min) {base:.1f} MB, end {end:.1f} MB, "
          f"peak {peak:.1f} MB; growth after warm-up {100 * (end - base) / base:+.1f} % "
          f"(range {lo:.1f}..{hi:.1f} MB)")
    if a.json:
        a.json.write_text(json.dumps({"samples": samples, **counts}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
