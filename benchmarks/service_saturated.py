"""The live logger on a saturated 1 Mbit/s bus, in real time: frames/s, CPU per thread, drops by cause,
API latency and RSS over time.  Rerun it on your logger.

    python benchmarks/service_saturated.py --netns [--seconds 60] [--runs 10]     # sender process, udp_multicast
    python benchmarks/service_saturated.py [--seconds 60]                          # sender thread, virtual bus
    python benchmarks/service_saturated.py --netns --api-rate 50                   # plus /estimates at 50 req/s
    python benchmarks/service_saturated.py --netns --api-rate 50 --api-paths mix   # the five JSON routes in turn
    python benchmarks/service_saturated.py --bus socketcan:can0 --seconds 60       # your own bus, as it is

About 8000 frames/s (simulated `paper` drives with realistic noise, vdp's ~610 frames/s, plus 74
unrelated IDs at 100 Hz) go onto the bus at their own pace for ``--seconds`` of bus time into a live
:class:`vdp.live.Service` (real pipeline, rotating raw log, SQLite store); with ``--bus IFACE:CHANNEL``
nothing is sent and the service reads that bus as it is.  Each run prints:

- frames sent and the rate they really went out at (a loaded machine's sender lags), received,
  estimated, decoded, raw-logged;
- drops by cause: the kernel's (the socket's ``sk_drops``, what vdp counts), the controller's overrun
  reports, estimation's thinning (the raw log keeps those), the raw log's own losses, and, with
  ``--netns``, the namespace's UDP ``RcvbufErrors`` as a cross-check of the kernel count;
- CPU from /proc/self/task/*/stat per thread, over wall time and per frame, and the share of one core
  that CPU would be at the nominal ~8,010 frames/s (a loaded machine stretches wall time; CPU time per
  frame it stretches much less); receive + raw logging is the receive thread;
- with ``--api-rate``, a client process's GET latency percentiles (127.0.0.1, uvicorn in this process);
- RSS every ``--rss-every`` s; the machine's load average and CPU steal over the run.

The service's CPU excludes the sender (another process with ``--netns``; its thread's own CPU
otherwise) and this benchmark's watcher thread.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import threading
import time
from pathlib import Path

import service_common as c

NOMINAL = 8010.0  # frames/s of the saturated bus sent here


def task_cpu() -> dict[str, float]:
    """CPU seconds per thread of this process, from /proc/self/task/*/stat, by Python thread name."""
    tick = os.sysconf("SC_CLK_TCK")
    names = {t.native_id: t.name for t in threading.enumerate()}
    out: dict[str, float] = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()
        cpu = (int(fields[11]) + int(fields[12])) / tick  # utime, stime
        name = names.get(int(tid), f"native-{tid}")
        if name.startswith(("BlockNotifier", "Notifier for")):
            name = "receive+raw log"
        out[name] = out.get(name, 0.0) + cpu
    return out


def steal() -> tuple[int, int]:
    """(steal, total) jiffies of all CPUs so far (/proc/stat)."""
    with open("/proc/stat") as f:
        cols = [int(x) for x in f.readline().split()[1:]]
    return (cols[7] if len(cols) > 7 else 0), sum(cols)


def one_run(a, k: int) -> dict:
    bus = a.bus.split(":", 1) if a.bus else None
    if bus:
        svc, tmp = c.start_service(False, interface=bus[0], channel=bus[1] if len(bus) > 1 else "")
    else:
        svc, tmp = c.start_service(a.netns)
    api = c.ApiServer(svc.settings, svc).start() if a.api_rate else None
    kw = {"extra_ids": a.extra_ids, "extra_rate": a.extra_rate}
    start = float(int(time.time()) + 2)  # the first frame's wall-clock time
    sender = None
    if bus:
        pass
    elif a.netns:
        sender = c.sender_process(a.seconds, start, **kw)
    else:
        sender = c.SenderThread(svc.bus_cfg.channel, a.seconds, start, **kw)
        sender.start()
    paths = "" if a.api_paths == "mix" else a.api_paths
    client = (
        c.client_process(
            "rate", api.port, rate=a.api_rate, count=int(a.api_rate * a.seconds), seconds=a.seconds, paths=paths
        )
        if api
        else None
    )
    while time.time() < start:
        time.sleep(0.001)
    udp0 = c.udp_rcvbuf_errors() if a.netns else None
    cpu0, th0, w0 = time.process_time(), task_cpu(), time.monotonic()
    st0, load0 = steal(), os.getloadavg()
    depth, rss = [0], [(0.0, c.rss_mb())]

    def watch(stop: threading.Event) -> None:
        next_rss = a.rss_every
        while not stop.wait(0.05):
            depth[0] = max(depth[0], svc.queue.qsize())
            t = time.monotonic() - w0
            if t >= next_rss:
                rss.append((round(t, 1), c.rss_mb()))
                next_rss += a.rss_every

    stop = threading.Event()
    watcher = threading.Thread(target=watch, args=(stop,), name="bench-watch", daemon=True)
    watcher.start()
    sender_cpu = None
    if bus:
        time.sleep(a.seconds)
        sent, sender_where, send_wall = None, f"none: {a.bus} as it is", a.seconds
    elif a.netns:
        out, _ = sender.communicate(timeout=a.seconds * 4 + 120)
        info = json.loads(out.strip().splitlines()[-1])
        sent, sender_where = info["sent"], "a separate process (udp_multicast, unshare -n)"
        send_wall = time.monotonic() - w0
    else:
        sender.done.wait(a.seconds * 4 + 120)
        sent, sender_where = sender.sent, "a thread of this process (virtual bus)"
        send_wall = time.monotonic() - w0
    if sent is not None:
        c.drain(svc, sent)
    else:
        svc.sync()
    svc.housekeeping()  # reads the socket's drop counter once more
    wall = time.monotonic() - w0
    cpu, th1 = time.process_time() - cpu0, task_cpu()
    st1, load1 = steal(), os.getloadavg()
    stop.set()
    watcher.join()
    rss.append((round(wall, 1), c.rss_mb()))
    per_thread = {n: v - th0.get(n, 0.0) for n, v in th1.items()}
    if sender is not None and not a.netns:
        sender_cpu = sender.cpu
    api_out = (
        json.loads(client.communicate(timeout=a.seconds * 4 + 120)[0].strip().splitlines()[-1]) if client else None
    )
    udp1 = c.udp_rcvbuf_errors() if a.netns else None
    counts = c.service_counts(svc)
    link = svc.link.info
    svc.stop()
    if api:
        api.stop()
    shutil.rmtree(tmp, ignore_errors=True)

    service_cpu = cpu - (sender_cpu or 0.0) - per_thread.pop("bench-watch", 0.0)
    per_thread.pop("bench-sender", None)
    frames = counts["received"]
    rx = per_thread.get("receive+raw log", 0.0)
    missing = None if sent is None else sent - counts["raw_logged"]
    fig = {
        "run": k,
        "seconds": a.seconds,
        "sent": sent,
        "sender": sender_where,
        "send_rate": None if sent is None else sent / send_wall,
        "nominal_rate": NOMINAL if sent is not None else None,
        "wall_s": wall,
        "service_cpu_s": service_cpu,
        "core_fraction_wall": service_cpu / wall,
        "cpu_us_per_frame": 1e6 * service_cpu / max(frames, 1),
        "core_fraction_at_nominal": (service_cpu / max(frames, 1)) * NOMINAL if sent is not None else None,
        "receive_log_us_per_frame": 1e6 * rx / max(frames, 1),
        "receive_log_fraction_at_nominal": (rx / max(frames, 1)) * NOMINAL if sent is not None else None,
        "threads_cpu_s": {n: round(v, 2) for n, v in sorted(per_thread.items(), key=lambda kv: -kv[1]) if v > 0.005},
        "drops": {
            "kernel": link.kernel_drops,
            "controller_overruns": link.overruns,
            "estimation_thinned": counts["dropped"],
            "raw_log_lost": counts["raw_lost"],
            "udp_rcvbuf_errors": None if udp0 is None or udp1 is None else udp1 - udp0,
            "missing_from_raw_log": missing,
        },
        "max_queue_depth": depth[0],
        "rss_mb": rss,
        "load_avg": [load0[0], load1[0]],
        "steal_pct": 100.0 * (st1[0] - st0[0]) / max(st1[1] - st0[1], 1),
        **counts,
        "api": api_out,
    }
    report(a, fig)
    return fig


def report(a, f: dict) -> None:
    d = f["drops"]
    print(f"-- run {f['run'] + 1}: {a.seconds:.0f} s of bus; sender: {f['sender']}")
    if f["sent"] is not None:
        print(
            f"frames: sent {f['sent']:,} at {f['send_rate']:,.0f}/s (nominal {NOMINAL:,.0f}/s), received "
            f"{f['received']:,}, estimated {f['estimated']:,}, raw-logged {f['raw_logged']:,}"
        )
    else:
        print(
            f"frames: received {f['received']:,} ({f['received'] / a.seconds:,.0f}/s), raw-logged {f['raw_logged']:,}"
        )
    print(
        f"drops: kernel {d['kernel']}, controller overruns {d['controller_overruns']}, estimation thinned "
        f"{d['estimation_thinned']}, raw log lost {d['raw_log_lost']}"
        + (
            f"; namespace-wide UDP RcvbufErrors {d['udp_rcvbuf_errors']} (every socket: the sender's own, "
            "never read, too)"
            if d["udp_rcvbuf_errors"] is not None
            else ""
        )
        + (f"; missing from the raw log {d['missing_from_raw_log']}" if d["missing_from_raw_log"] is not None else "")
    )
    nominal = (
        f"; at {NOMINAL:,.0f} frames/s: {100 * f['core_fraction_at_nominal']:.1f} % of one core, receive + raw "
        f"log {100 * f['receive_log_fraction_at_nominal']:.1f} %"
        if f["core_fraction_at_nominal"] is not None
        else ""
    )
    print(
        f"CPU: service {f['service_cpu_s']:.1f} s over {f['wall_s']:.1f} s wall = {100 * f['core_fraction_wall']:.1f} "
        f"% of one core; {f['cpu_us_per_frame']:.1f} us a frame (receive + raw log "
        f"{f['receive_log_us_per_frame']:.1f} us){nominal}"
    )
    print("  per thread (CPU s): " + ", ".join(f"{n} {v:.2f}" for n, v in f["threads_cpu_s"].items()))
    print(
        f"machine: load average {f['load_avg'][0]:.1f} -> {f['load_avg'][1]:.1f} on {os.cpu_count()} CPUs, "
        f"steal {f['steal_pct']:.0f} %; max queue depth {f['max_queue_depth']:,}"
    )
    print("RSS (s, MB): " + ", ".join(f"{t:.0f}: {m:.0f}" for t, m in f["rss_mb"]))
    api = f["api"]
    if api:
        lat = api["latency_ms"]
        print(
            f"API at {a.api_rate:g} req/s: {api['requests']} requests, {api['failed_count']} failed; latency "
            f"p50 {lat['p50']:.1f} ms, p90 {lat['p90']:.1f} ms, p99 {lat['p99']:.1f} ms, max {lat['max']:.1f} ms"
        )
        if len(api["per_path"]) > 1:
            for p, v in api["per_path"].items():
                print(f"  {p}: p50 {v['p50']:.1f} ms, p99 {v['p99']:.1f} ms, max {v['max']:.1f} ms")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="bus time per run (default 60)")
    ap.add_argument("--runs", type=int, default=1, help="runs, each with a fresh service (default 1)")
    ap.add_argument(
        "--netns", action="store_true", help="sender in another process on udp_multicast, inside unshare -n"
    )
    ap.add_argument("--bus", help="IFACE:CHANNEL: read this bus as it is, send nothing (e.g. socketcan:can0)")
    ap.add_argument("--api-rate", type=float, default=0.0, help="GET requests per second during ingest")
    ap.add_argument("--api-paths", default="/estimates", help="comma-separated paths, or 'mix' (default /estimates)")
    ap.add_argument("--rss-every", type=float, default=10.0, help="s between RSS samples (default 10)")
    ap.add_argument("--extra-ids", type=int, default=c.FILLER_IDS)
    ap.add_argument("--extra-rate", type=float, default=c.FILLER_RATE)
    ap.add_argument("--json", type=Path, help="also write the figures here")
    a = ap.parse_args()
    if a.netns and a.bus:
        ap.error("--bus reads your own bus; --netns makes a private one: give one of them")
    if a.netns and not c.in_netns():
        return c.reexec_in_netns()
    print(f"python {sys.version.split()[0]}; python-can {__import__('can').__version__}; {os.cpu_count()} CPUs")
    figs = [one_run(a, k) for k in range(a.runs)]
    bad = [f["run"] + 1 for f in figs if sum(v or 0 for k, v in f["drops"].items() if k != "udp_rcvbuf_errors")]
    if a.runs > 1:
        cores = [100 * f["core_fraction_at_nominal"] for f in figs if f["core_fraction_at_nominal"] is not None]
        p99 = [f["api"]["latency_ms"]["p99"] for f in figs if f["api"]]
        print(
            f"== {a.runs} runs: runs with any frame lost or thinned: {bad or 'none'}"
            + (f"; service at nominal rate {min(cores):.1f}-{max(cores):.1f} % of a core" if cores else "")
            + (f"; API p99 {min(p99):.1f}-{max(p99):.1f} ms" if p99 else "")
        )
    if a.json:
        a.json.write_text(json.dumps(figs if a.runs > 1 else figs[0], indent=1))
    exact = all(
        f["drops"]["missing_from_raw_log"] in (None, (f["drops"]["kernel"] or 0)) and f["drops"]["raw_log_lost"] == 0
        for f in figs
    )
    return 0 if not bad and exact else 1


if __name__ == "__main__":
    sys.exit(main())
