"""The live service on a saturated 1 Mbit/s bus, in real time: dropped frames and CPU.

    python benchmarks/service_saturated.py [--seconds 112]                 # sender thread, virtual bus
    python benchmarks/service_saturated.py --netns [--seconds 112]         # sender process, udp_multicast
    python benchmarks/service_saturated.py --api-rate 50 [--netns]         # plus API latency at 50 req/s

About 8000 frames/s (simulated `paper` drives with realistic noise, vdp's ~610
frames/s, plus 74 unrelated IDs at 100 Hz) go onto the bus at their own pace for
``--seconds`` of bus time into a live :class:`vdp.live.Service` (real pipeline,
raw rotating log, SQLite store).  It prints:

- frames sent, received, dropped (the service's own queue counter), estimated,
  decoded and raw-logged: every count must equal what was sent;
- CPU time over wall time of the service.  With the in-process sender (default)
  the sender thread's own CPU is read per thread and taken off the process's; with
  ``--netns`` the sender is another process (udp_multicast inside ``unshare -n``),
  so the process's CPU is the service's alone (including the udp_multicast
  receive: a socket read and a msgpack unpack per frame);
- with ``--api-rate``, a client process sends GET requests at that rate over
  127.0.0.1 to uvicorn in the service process, and the latency percentiles.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import threading
import time
from pathlib import Path

import service_common as c


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=112.0, help="bus time (default: one paper drive, 112 s)")
    ap.add_argument(
        "--netns", action="store_true", help="sender in another process on udp_multicast, inside unshare -n"
    )
    ap.add_argument("--api-rate", type=float, default=0.0, help="GET requests per second during ingest")
    ap.add_argument("--extra-ids", type=int, default=c.FILLER_IDS)
    ap.add_argument("--extra-rate", type=float, default=c.FILLER_RATE)
    ap.add_argument("--json", type=Path, help="also write the figures here")
    a = ap.parse_args()
    if a.netns and not c.in_netns():
        return c.reexec_in_netns()

    svc, tmp = c.start_service(a.netns)
    api = c.ApiServer(svc.settings, svc).start() if a.api_rate else None
    kw = {"extra_ids": a.extra_ids, "extra_rate": a.extra_rate}
    start = float(int(time.time()) + 2)  # the first frame's wall-clock time
    if a.netns:
        sender = c.sender_process(a.seconds, start, **kw)
    else:
        sender = c.SenderThread(svc.bus_cfg.channel, a.seconds, start, **kw)
        sender.start()
    client = (
        c.client_process("rate", api.port, rate=a.api_rate, count=int(a.api_rate * a.seconds), seconds=a.seconds)
        if api
        else None
    )

    # Measure from the first frame on; the queue depth is sampled as it goes.
    while time.time() < start:
        time.sleep(0.001)
    cpu0, th0, w0, rss0 = time.process_time(), c.threads_cpu(), time.monotonic(), c.rss_mb()
    depth = [0]

    def watch(stop: threading.Event) -> None:
        while not stop.wait(0.05):
            depth[0] = max(depth[0], svc.queue.qsize())

    stop = threading.Event()
    watcher = threading.Thread(target=watch, args=(stop,), name="bench-watch", daemon=True)
    watcher.start()
    if a.netns:
        out, _ = sender.communicate(timeout=a.seconds + 120)
        info = json.loads(out.strip().splitlines()[-1])
        sent, sender_cpu, sender_where = info["sent"], None, "a separate process (udp_multicast, unshare -n)"
    else:
        sender.done.wait(a.seconds + 120)
        sent, sender_where = sender.sent, "a thread of this process (virtual bus)"
    c.drain(svc, sent)
    wall = time.monotonic() - w0
    cpu, th1 = time.process_time() - cpu0, c.threads_cpu()
    stop.set()
    watcher.join()
    per_thread = {k: v - th0.get(k, 0.0) for k, v in th1.items()}
    if not a.netns:
        # the sender thread has ended; it read its own CPU clock just before
        sender_cpu = sender.cpu
    api_out = json.loads(client.communicate(timeout=120)[0].strip().splitlines()[-1]) if client else None
    counts = c.service_counts(svc)
    rss1 = c.rss_mb()
    svc.stop()
    if api:
        api.stop()
    shutil.rmtree(tmp, ignore_errors=True)

    service_cpu = cpu - (sender_cpu or 0.0) - per_thread.get("bench-watch", 0.0)
    fig = {
        "seconds": a.seconds,
        "sent": sent,
        "frames_per_s": sent / a.seconds,
        "sender": sender_where,
        "wall_s": wall,
        "process_cpu_s": cpu,
        "sender_cpu_s": sender_cpu,
        "service_cpu_s": service_cpu,
        "service_core_fraction": service_cpu / wall,
        "max_queue_depth": depth[0],
        "threads_cpu_s": {k: round(v, 2) for k, v in sorted(per_thread.items()) if v > 0.005},
        "rss_mb": [rss0, rss1],
        **counts,
        "api": api_out,
    }
    lost = {k: counts[k] for k in ("received", "estimated", "decode_frames", "raw_logged") if counts[k] != sent}
    print(
        f"bus: {a.seconds:.0f} s at {sent / a.seconds:,.0f} frames/s ({sent:,} frames: vdp's paper drive "
        f"+ {a.extra_ids} filler IDs at {a.extra_rate:g} Hz); sender: {sender_where}"
    )
    print(
        f"frames: sent {sent:,}, received {counts['received']:,}, dropped {counts['dropped']}, "
        f"estimated {counts['estimated']:,}, decoder saw {counts['decode_frames']:,}, "
        f"raw-logged {counts['raw_logged']:,} (lost {counts['raw_lost']}), estimation errors "
        f"{counts['estimation_errors']}, bus errors {counts['bus_errors']}"
        + ("" if not lost else f"  MISMATCH vs sent: {lost}")
    )
    print(
        f"CPU: process {cpu:.1f} s over {wall:.1f} s wall"
        + (f"; sender thread {sender_cpu:.1f} s" if sender_cpu is not None else "")
        + f"; service {service_cpu:.1f} s = {100 * service_cpu / wall:.1f} % of one core"
    )
    print(
        "  per thread: "
        + ", ".join(
            f"{k} {100 * v / wall:.1f} %"
            for k, v in sorted(per_thread.items(), key=lambda kv: -kv[1])
            if v > 0.005 and k not in ("bench-watch",)
        )
    )
    print(
        f"max queue depth {depth[0]:,} of {counts['queue_capacity']:,}; RSS {rss0:.0f} -> {rss1:.0f} MB; "
        f"stage at the end: {counts['stage']}"
    )
    if api_out:
        lat = api_out["latency_ms"]
        print(
            f"API at {a.api_rate:g} req/s: {api_out['requests']} requests, {api_out['failed_count']} failed; "
            f"latency p50 {lat['p50']:.1f} ms, p90 {lat['p90']:.1f} ms, p99 {lat['p99']:.1f} ms, "
            f"max {lat['max']:.1f} ms"
        )
        for p, v in api_out["per_path"].items():
            print(f"  {p}: p50 {v['p50']:.1f} ms, p99 {v['p99']:.1f} ms, max {v['max']:.1f} ms")
    if a.json:
        a.json.write_text(json.dumps(fig, indent=1))
    return 0 if not lost and counts["dropped"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
