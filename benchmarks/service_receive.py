"""The receive path alone: read queued udp_multicast datagrams, write them to the raw log, queue them.

    python benchmarks/service_receive.py [--frames 3000] [--rounds 10]

Inside ``unshare -n`` (re-executed there): ``--frames`` datagrams are sent onto the group, then the
direct socket reader (:mod:`vdp.live.reader`) reads them in blocks, the raw log writes each block
and the intake queues it, as the receive thread does; CPU time per frame of each step is printed.
No sleeping, no other threads: the cost of receive + raw logging without a GIL to share.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time

import service_common as c


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=3000, help="datagrams a round (the 4 MiB buffer holds ~4,000)")
    ap.add_argument("--rounds", type=int, default=10)
    a = ap.parse_args()
    if not c.in_netns():
        return c.reexec_in_netns()
    import can

    from vdp.live.bus import enlarge_receive_buffer
    from vdp.live.intake import FrameQueue, Intake
    from vdp.live.rawlog import RawLog
    from vdp.live.reader import socket_reader

    rx = can.Bus(interface="udp_multicast", channel=c.GROUP)
    enlarge_receive_buffer(rx)
    tx = can.Bus(interface="udp_multicast", channel=c.GROUP)
    _sock, read = socket_reader(rx, "can0", lambda e: None)
    raw = RawLog(tempfile.mkdtemp(prefix="vdp-bench-"), 64 << 20, 8)
    raw.open()
    intake = Intake(FrameQueue(maxsize=1 << 22))
    cost = {"read": 0.0, "raw log": 0.0, "queue": 0.0}
    n = 0
    for r in range(a.rounds + 1):
        for k in range(a.frames):
            tx.send(can.Message(timestamp=1.0 + k, arbitration_id=0x100 + k % 80, data=bytes(8), is_extended_id=False))
        time.sleep(0.05)
        while True:
            block: list = []
            t0 = time.thread_time()
            read(block, 1024)
            t1 = time.thread_time()
            if not block:
                break
            raw.on_block(block)
            t2 = time.thread_time()
            intake.on_block(block)
            t3 = time.thread_time()
            if r:  # the first round warms up
                cost["read"] += t1 - t0
                cost["raw log"] += t2 - t1
                cost["queue"] += t3 - t2
                n += len(block)
        raw.flush()
    raw.close()
    rx.shutdown()
    tx.shutdown()
    total = sum(cost.values())
    print(
        f"{n:,} frames: "
        + ", ".join(f"{k} {1e6 * v / n:.1f} us" for k, v in cost.items())
        + f"; receive + raw log {1e6 * total / n:.1f} us a frame = {100 * total / n * 8010:.1f} % of one core "
        "at 8,010 frames/s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
