"""200 concurrent API clients while the service ingests a saturated bus (issue 6, Load).

    python benchmarks/service_load.py [--netns] [--clients 200] [--requests 5] [--rounds 3] [--seconds 60]

The saturated bus of service_saturated.py (about 8000 frames/s in real time) feeds a
live :class:`vdp.live.Service` for ``--seconds`` of bus time; uvicorn serves its API on
127.0.0.1 in the same process.  Every ``--seconds / (rounds + 1)`` a client process
opens ``--clients`` connections at once and sends ``--requests`` GET requests on each,
one after another (/health, /estimates, /status, /metrics, /estimates/history in
turn).  It prints, per round, failed requests and latency percentiles, and at the
end the frame counts: none may be dropped and no request may fail.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import service_common as c


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="bus time")
    ap.add_argument(
        "--netns", action="store_true", help="sender in another process on udp_multicast, inside unshare -n"
    )
    ap.add_argument("--clients", type=int, default=200)
    ap.add_argument("--requests", type=int, default=5, help="per client")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--json", type=Path, help="also write the figures here")
    a = ap.parse_args()
    if a.netns and not c.in_netns():
        return c.reexec_in_netns()

    svc, tmp = c.start_service(a.netns)
    api = c.ApiServer(svc.settings, svc).start()
    start = float(int(time.time()) + 2)
    if a.netns:
        sender = c.sender_process(a.seconds, start)
    else:
        sender = c.SenderThread(svc.bus_cfg.channel, a.seconds, start)
        sender.start()
    rounds = []
    every = a.seconds / (a.rounds + 1)
    for k in range(a.rounds):
        while time.time() < start + every * (k + 1):
            time.sleep(0.05)
        before = (svc.intake.received, svc.intake.dropped, time.time() - start)
        p = c.client_process("burst", api.port, clients=a.clients, requests=a.requests)
        out = json.loads(p.communicate(timeout=300)[0].strip().splitlines()[-1])
        out["bus_time_s"] = before[2]
        out["frames_during"] = svc.intake.received - before[0]
        out["dropped_during"] = svc.intake.dropped - before[1]
        rounds.append(out)
    if a.netns:
        sent = json.loads(sender.communicate(timeout=a.seconds + 120)[0].strip().splitlines()[-1])["sent"]
    else:
        sender.done.wait(a.seconds + 120)
        sent = sender.sent
    c.drain(svc, sent)
    counts = c.service_counts(svc)
    svc.stop()
    api.stop()
    shutil.rmtree(tmp, ignore_errors=True)

    where = "a separate process (udp_multicast, unshare -n)" if a.netns else "a thread (virtual bus)"
    print(
        f"bus: {a.seconds:.0f} s at {sent / a.seconds:,.0f} frames/s, sender in {where}; "
        f"{a.rounds} rounds of {a.clients} concurrent clients x {a.requests} requests"
    )
    failed = 0
    for k, r in enumerate(rounds, 1):
        lat = r["latency_ms"]
        failed += r["failed_count"]
        print(
            f"round {k} at {r['bus_time_s']:.0f} s: {r['requests']} requests in {r['wall_s']:.2f} s "
            f"({r['requests'] / r['wall_s']:,.0f}/s), {r['failed_count']} failed"
            + (f" {r['failed'][:3]}" if r["failed_count"] else "")
            + f"; latency p50 {lat['p50']:.0f} ms, p90 {lat['p90']:.0f} ms, p99 {lat['p99']:.0f} ms, "
            f"max {lat['max']:.0f} ms; frames meanwhile {r['frames_during']:,}, dropped {r['dropped_during']}"
        )
    lost = {k: counts[k] for k in ("received", "estimated", "decode_frames", "raw_logged") if counts[k] != sent}
    print(
        f"frames: sent {sent:,}, received {counts['received']:,}, dropped {counts['dropped']}, "
        f"estimated {counts['estimated']:,}, raw-logged {counts['raw_logged']:,}"
        + ("" if not lost else f"  MISMATCH vs sent: {lost}")
    )
    if a.json:
        a.json.write_text(json.dumps({"sent": sent, "rounds": rounds, **counts}, indent=1))
    return 0 if not failed and not lost and counts["dropped"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
