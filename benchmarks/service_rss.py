"""RSS of the live service over a 1-hour simulated drive, faster than real time.

    python benchmarks/service_rss.py [--minutes 60] [--extra-ids 74] [--every 60]
    python benchmarks/service_rss.py --serve [--minutes 60]     # `vdp serve --simulate` itself

Simulated `paper` drives back to back (a new seed each, realistic noise), with the
saturated bus's filler IDs unless ``--extra-ids 0``, go onto a python-can virtual
bus as fast as the service keeps up (the sender waits while 2048 frames are queued
for estimation or still on the virtual bus: a car's real-time bus keeps the queue
near empty), through the whole
service: Notifier, rotating raw log, pipeline, store commits, snapshots.  RSS is
read from /proc/self/status every ``--every`` seconds of bus time.  It prints the
samples, the peak, and the growth from the end of the warm-up (the first 10 % of
the drive, at least 5 minutes) to the end.

With ``--serve`` it runs the main job itself instead, ``vdp serve --simulate
--sim-speed 0 --loop`` (the `paper` drive again and again, vdp's frames only), as a
separate process on 127.0.0.1, and reads that process's RSS from /proc/PID/status;
bus time comes from its /status.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import service_common as c


def rss_of(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def serve(seconds: float, every: float, tmp: Path, speed: float = 0.0) -> tuple[list, dict]:
    """`vdp serve --simulate --sim-speed 0 --loop` in its own process; (samples, last /status)."""
    err = tmp / "serve.err"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys; from vdp.cli import main; sys.exit(main())",
            "serve",
            "--simulate",
            "--sim-speed",
            str(speed),
            "--loop",
            "--port",
            "0",
            "--db",
            str(tmp / "state.sqlite"),
            "--raw-dir",
            str(tmp / "raw"),
        ],
        stdout=subprocess.DEVNULL,
        stderr=open(err, "w"),
        cwd=tmp,
        env={**os.environ, "PYTHONPATH": str(c.ROOT / "service")},
    )
    try:
        while not (m := re.search(r"http://127\.0\.0\.1:(\d+)/", err.read_text())):
            if proc.poll() is not None:
                raise SystemExit(err.read_text()[-2000:])
            time.sleep(0.1)
        url = f"http://127.0.0.1:{m.group(1)}/status"
        w0 = time.monotonic()
        samples = [(0.0, 0.0, rss_of(proc.pid), 0)]
        print(f"{0:>8.0f}s {0:>6.0f}s {samples[0][2]:>7.1f} {0:>12,}", flush=True)
        nxt = every
        while True:
            with urllib.request.urlopen(url, timeout=30) as r:
                st = json.loads(r.read())
            sim = st["simulation"]
            bus_t = sim["loops"] * sim["duration"] + sim["sim_time"]
            if bus_t >= nxt:
                row = (bus_t, time.monotonic() - w0, rss_of(proc.pid), st["bus"]["frames"])
                samples.append(row)
                print(f"{row[0]:>8.0f}s {row[1]:>6.0f}s {row[2]:>7.1f} {row[3]:>12,}", flush=True)
                nxt = (int(bus_t // every) + 1) * every
                if bus_t >= seconds:
                    return samples, st
            time.sleep(0.5)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(120)
        except subprocess.TimeoutExpired:
            proc.kill()


def report(samples: list, seconds: float, what: str) -> None:
    warm = max(0.1 * seconds, min(300.0, seconds / 2))
    after = [r for r in samples if r[0] >= warm]
    base = after[0][2] if after else float("nan")
    end = samples[-1][2]
    peak = max(r[2] for r in samples)
    lo = min(r[2] for r in after) if after else float("nan")
    hi = max(r[2] for r in after) if after else float("nan")
    wall = samples[-1][1]
    print(
        f"drive: {samples[-1][0] / 60:.1f} min of bus time in {wall / 60:.1f} min "
        f"({samples[-1][0] / max(wall, 1e-9):.1f}x real time), {samples[-1][3]:,} frames; {what}"
    )
    print(
        f"RSS: start {samples[0][2]:.1f} MB, after warm-up ({warm / 60:.0f} min) {base:.1f} MB, end {end:.1f} MB, "
        f"peak {peak:.1f} MB; growth after warm-up {100 * (end - base) / base:+.1f} % "
        f"(range {lo:.1f}..{hi:.1f} MB)"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=60.0, help="bus time")
    ap.add_argument("--extra-ids", type=int, default=c.FILLER_IDS)
    ap.add_argument("--every", type=float, default=60.0, help="seconds of bus time between RSS samples")
    ap.add_argument(
        "--commit-interval",
        type=float,
        default=0.25,
        help="store commits [s]; the default gives a 3.5x-real-time run the car's one commit per "
        "second of drive, so the store grows as it would",
    )
    ap.add_argument("--serve", action="store_true", help="run `vdp serve --simulate --sim-speed S --loop`")
    ap.add_argument(
        "--sim-speed", type=float, default=0.0, help="--serve: S (0: as fast as it keeps up; the README's is 20)"
    )
    ap.add_argument("--json", type=Path, help="also write the samples here")
    a = ap.parse_args()
    seconds = a.minutes * 60.0
    print(f"{'bus time':>9} {'wall':>7} {'RSS MB':>7} {'frames':>12}")
    if a.serve:
        tmp = Path(tempfile.mkdtemp(prefix="vdp-bench-"))
        samples, st = serve(seconds, a.every, tmp, a.sim_speed)
        shutil.rmtree(tmp, ignore_errors=True)
        report(
            samples,
            seconds,
            f"vdp serve --simulate --sim-speed {a.sim_speed:g} --loop (ran at "
            f"{st['simulation'].get('running_speed')}x at the end): dropped {st['queue']['dropped']}, "
            f"raw log files closed {st['raw_log']['closed_files']} (deleted "
            f"{st['raw_log']['deleted_files']}), stage {st['estimation']['stage']}",
        )
        if a.json:
            a.json.write_text(json.dumps({"samples": samples}, indent=1))
        return 0

    from dataclasses import replace

    from vdp.live import Service

    tmp = Path(tempfile.mkdtemp(prefix="vdp-bench-"))
    s = c.settings(tmp)
    s = replace(s, store=replace(s.store, commit_interval=a.commit_interval))
    svc = Service(s)
    svc.start()
    c.wait_up(svc)
    start = 1700000000.0
    # Back-pressure as a car gives it: a real-time bus keeps the estimation queue near empty
    # (see service_saturated.py), so pause at 2048 frames queued, not at half the queue, and on
    # frames still in flight on the virtual bus (that queue has no bound).
    sender = c.SenderThread(
        svc.bus_cfg.channel,
        seconds,
        start,
        extra_ids=a.extra_ids,
        backlog=lambda: max(svc.queue.qsize(), sender.sent - svc.intake.received) / 4096,
    )
    w0 = time.monotonic()
    samples = [(0.0, 0.0, c.rss_mb(), 0)]
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
    commits = svc.store.commits if svc.store else 0
    svc.stop()
    shutil.rmtree(tmp, ignore_errors=True)

    report(
        samples,
        seconds,
        f"in process, {a.extra_ids} filler IDs, {commits} store commits: dropped "
        f"{counts['dropped']}, raw log files "
        f"closed {raw['closed_files']} (deleted {raw['deleted_files']}), stage {counts['stage']}",
    )
    if a.json:
        a.json.write_text(json.dumps({"samples": samples, **counts}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
