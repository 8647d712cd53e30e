"""1,100 idle TCP clients against `vdp serve --simulate` at a soft limit of 1,024 open files.

    nice -n 10 .venv/bin/python benchmarks/idle_clients.py [--clients 1100] [--hard 1024]

The service runs in its own process with RLIMIT_NOFILE soft 1,024 and the given hard
limit (the machine's by default; 1,024 is the worst case: vdp cannot raise it).  Prints
/health's answer time once a second while the clients hang on, the raw log's growth
during and after, the size of the service's stderr (an accept() traceback flood shows
there) and, from /metrics, frames received vs written to the raw log and lost.
The figures are in RELIABILITY.md.
"""

from __future__ import annotations

import argparse
import re
import resource
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHILD = (
    "import resource, sys\n"
    "resource.setrlimit(resource.RLIMIT_NOFILE, (1024, int(sys.argv[1])))\n"
    "sys.argv = ['vdp', *sys.argv[2:]]\n"
    "from vdp.cli import main\n"
    "sys.exit(main())\n"
)


def get(url: str, timeout: float = 10.0) -> tuple[str, float, str]:
    t = time.monotonic()
    try:
        with urllib.request.urlopen(url, timeout=timeout) as r:
            body, code = r.read().decode(), str(r.status)
    except urllib.error.HTTPError as exc:
        body, code = "", str(exc.code)
    except Exception as exc:  # timeouts, refused: the point of the measurement
        body, code = "", type(exc).__name__
    return code, time.monotonic() - t, body


def metric(text: str, name: str) -> float | None:
    m = re.search(rf"^vdp_{name}(?:_total)? ([0-9.e+]+)$", text, re.M)
    return float(m.group(1)) if m else None


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--clients", type=int, default=1100)
    ap.add_argument("--hard", type=int, default=resource.getrlimit(resource.RLIMIT_NOFILE)[1])
    ap.add_argument("--seconds", type=int, default=10)
    args = ap.parse_args()
    d = Path(tempfile.mkdtemp(prefix="vdp-idle-"))
    err = open(d / "err.txt", "wb")
    cmd = ["serve", "--simulate", "--loop", "--sim-speed", "5", "--port", "0"]
    cmd += ["--db", str(d / "s.sqlite"), "--raw-dir", str(d / "raw")]
    env = {"PYTHONPATH": str(ROOT / "service"), "PATH": "/usr/bin:/bin"}
    p = subprocess.Popen([sys.executable, "-c", CHILD, str(args.hard), *cmd], stderr=err, stdout=err, env=env)
    try:
        while not (m := re.search(r"127\.0\.0\.1:(\d+)/health", (d / "err.txt").read_text())):
            if p.poll() is not None:
                print((d / "err.txt").read_text())
                return 1
            time.sleep(0.1)
        url = f"http://127.0.0.1:{m.group(1)}"
        time.sleep(2)
        raw = d / "raw"

        def raw_bytes() -> int:
            return sum(f.stat().st_size for f in raw.glob("*.log"))

        soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
        resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, args.clients + 512), hard))
        socks = []
        for _ in range(args.clients):
            s = socket.socket()
            s.settimeout(5)
            try:
                s.connect(("127.0.0.1", int(m.group(1))))
            except OSError as exc:
                print(f"connect {len(socks)}: {exc}")
                break
            socks.append(s)
        print(f"{len(socks)} idle clients connected (service: soft 1024, hard {args.hard})")
        b0, worst = raw_bytes(), 0.0
        for k in range(args.seconds):
            time.sleep(1)
            code, dt, _ = get(url + "/health")
            worst = max(worst, dt)
            print(f"  {k + 1:2d} s: /health {code} in {dt:.3f} s")
        b1 = raw_bytes()
        for s in socks:
            s.close()
        time.sleep(3)
        b2 = raw_bytes()
        _, _, text = get(url + "/metrics")
        print(
            f"worst /health {worst:.3f} s; raw log +{b1 - b0:,} bytes while they hung on, "
            f"+{b2 - b1:,} in the 3 s after; service stderr {(d / 'err.txt').stat().st_size:,} bytes"
        )
        print(
            f"frames received {metric(text, 'frames_received')}, written to the raw log "
            f"{metric(text, 'raw_log_frames')}, not written {metric(text, 'raw_log_lost')}"
        )
    finally:
        p.terminate()
        p.wait(30)
    return 0


if __name__ == "__main__":
    sys.exit(main())
