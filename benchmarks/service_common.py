"""Shared harness of the live-service benchmarks (benchmarks/service_*.py).

- a saturated 1 Mbit/s bus: simulated `paper` drives back to back (vdp's own
  ~610 frames/s) plus unrelated filler IDs, about 8000 frames/s in all, sent in
  real time (or as fast as the service keeps up, for the RSS run);
- the sender runs either as a thread of the benchmark process on a python-can
  ``virtual`` bus (its CPU is measured per thread and taken off the process's),
  or as a separate process on ``udp_multicast`` inside a private network
  namespace (``unshare -n``: nothing leaves the machine), so the service
  process's CPU is the service's alone;
- CPU per thread from ``time.pthread_getcpuclockid``, RSS from /proc/self/status;
- ``vdp serve``'s own uvicorn server (``vdp.cli.serve.build_server``) serving the app on
  127.0.0.1 in a thread of the service process, as ``vdp serve`` does.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))

PROFILE = ROOT / "profiles" / "paper.toml"
GROUP = "239.74.163.9"  # udp_multicast group: only ever used inside unshare -n
NETNS_SETUP = "ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo"
# A saturated 1 Mbit/s bus: ~8000 frames/s.  vdp's paper profile sends ~610/s; the
# rest are unrelated IDs as on a real car (74 IDs at 100 Hz = 7400/s).
FILLER_IDS = 74
FILLER_RATE = 100.0


# -- measuring ---------------------------------------------------------------------------------
def thread_cpu(t: threading.Thread) -> float:
    """CPU seconds used so far by a live thread (0 if it has ended)."""
    try:
        return time.clock_gettime(time.pthread_getcpuclockid(t.ident))
    except (OSError, TypeError, ProcessLookupError):
        return 0.0


def threads_cpu() -> dict[str, float]:
    """CPU seconds per live thread, by name (vdp's receive thread is 'BlockNotifier for bus ...')."""
    out: dict[str, float] = {}
    for t in threading.enumerate():
        name = "can-notifier (receive)" if t.name.startswith(("Notifier for", "BlockNotifier for")) else t.name
        out[name] = out.get(name, 0.0) + thread_cpu(t)
    return out


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def udp_rcvbuf_errors() -> int | None:
    """Datagrams the kernel dropped because a UDP socket's receive buffer was full (this netns)."""
    try:
        lines = [ln.split() for ln in open("/proc/net/snmp") if ln.startswith("Udp:")]
        return int(lines[1][lines[0].index("RcvbufErrors")])
    except (OSError, IndexError, ValueError):
        return None


def percentile(xs: list[float], q: float) -> float:
    if not xs:
        return float("nan")
    s = sorted(xs)
    k = min(len(s) - 1, max(0, int(round(q / 100.0 * (len(s) - 1)))))
    return s[k]


# -- the bus -----------------------------------------------------------------------------------
def drive_frames(
    seconds: float,
    start: float,
    extra_ids: int = FILLER_IDS,
    extra_rate: float = FILLER_RATE,
    scenario: str = "paper",
    noise: str = "realistic",
):
    """Simulated drives back to back (new seed each), ``seconds`` of bus time from ``start``."""
    from vdp.profile import load_profile
    from vdp.sim.run import Simulation

    profile = load_profile(PROFILE)
    end = start + seconds
    t, seed = start, 1
    while t < end:
        sim = Simulation(profile, scenario, seed, noise, extra_ids=extra_ids, extra_rate=extra_rate, start_time=t)
        last = t
        for msg in sim.frames():
            if msg.timestamp >= end:
                return
            last = msg.timestamp
            yield msg
        t, seed = last + 0.01, seed + 1


def send_paced(bus, frames, stop: threading.Event | None = None, backlog=None, counter=None) -> int:
    """Send ``frames`` at their own pace (their timestamps are wall-clock times), or, with
    ``backlog`` (a callable giving the receiver's queue fill), as fast as it keeps up."""
    n = 0
    for msg in frames:
        if backlog is None:
            ahead = msg.timestamp - time.time()
            if ahead > 0.002:
                time.sleep(ahead)
        elif not n & 0xFF:
            while backlog() > 0.5:
                time.sleep(0.002)
        if stop is not None and not n & 0xFF and stop.is_set():
            break
        bus.send(msg)
        n += 1
        if counter is not None:
            counter[0] = n
    return n


class SenderThread(threading.Thread):
    """In-process sender onto a python-can virtual bus (its CPU is read per thread)."""

    def __init__(self, channel: str, seconds: float, start: float, backlog=None, **kw):
        super().__init__(name="bench-sender", daemon=True)
        self.channel, self.seconds, self.start_t, self.backlog, self.kw = channel, seconds, start, backlog, kw
        self.count = [0]
        self.done = threading.Event()
        self.stop = threading.Event()
        self.error: str | None = None
        self.cpu = 0.0  # its own CPU seconds, read just before it ends

    @property
    def sent(self) -> int:
        return self.count[0]

    def run(self) -> None:
        import can

        bus = can.Bus(interface="virtual", channel=self.channel, preserve_timestamps=True, receive_own_messages=False)
        try:
            send_paced(bus, drive_frames(self.seconds, self.start_t, **self.kw), self.stop, self.backlog, self.count)
        except Exception as exc:  # reported by the benchmark
            self.error = f"{type(exc).__name__}: {exc}"
        finally:
            bus.shutdown()
            self.cpu = time.thread_time()
            self.done.set()


def sender_process(seconds: float, start: float, group: str = GROUP, **kw) -> subprocess.Popen:
    """A separate process sending onto udp_multicast; it prints {"sent": n, "cpu": s} at the end."""
    code = (
        "import json, sys, time, can; sys.path.insert(0, sys.argv[1]); import service_common as c; "
        "bus = can.Bus(interface='udp_multicast', channel=sys.argv[2]); "
        "t0 = time.process_time(); "
        "n = c.send_paced(bus, c.drive_frames(float(sys.argv[3]), float(sys.argv[4]), **json.loads(sys.argv[5]))); "
        "time.sleep(0.2); bus.shutdown(); "
        "print(json.dumps({'sent': n, 'cpu': time.process_time() - t0}), flush=True)"
    )
    return subprocess.Popen(
        [sys.executable, "-c", code, str(Path(__file__).parent), group, str(seconds), str(start), json.dumps(kw)],
        stdout=subprocess.PIPE,
        text=True,
    )


# -- private network namespace -------------------------------------------------------------------
def in_netns() -> bool:
    return os.environ.get("VDP_BENCH_NETNS") == "1"


def reexec_in_netns() -> int:
    """Run this very command again inside ``unshare -n`` with lo up and a multicast route."""
    if not shutil.which("unshare") or not shutil.which("ip"):
        sys.exit("--netns needs unshare (util-linux) and ip (iproute2)")
    cmd = ["unshare", "-n", "bash", "-c", f'{NETNS_SETUP} && exec "$0" "$@"', sys.executable, *sys.argv]
    return subprocess.call(cmd, env={**os.environ, "VDP_BENCH_NETNS": "1"})


# -- the service ---------------------------------------------------------------------------------
def settings(tmp: Path, interface: str = "virtual", channel: str | None = None, **service):
    from vdp.settings import ApiSettings, BusSettings, RawLogSettings, ServiceSettings, Settings, StoreSettings

    return Settings(
        profile=PROFILE,
        bus=BusSettings(
            interface=interface, channel=channel or f"bench-{os.getpid()}", bitrate=None, listen_only=False
        ),
        # the in-car defaults, except smaller files so a run rotates a few times
        raw_log=RawLogSettings(dir=tmp / "raw", max_bytes=16 * 1024 * 1024, max_files=8),
        store=StoreSettings(path=tmp / "state.sqlite"),
        api=ApiSettings(host="127.0.0.1", port=0),
        service=ServiceSettings(**service),
        source="benchmark",
    )


def start_service(netns: bool, interface: str | None = None, channel: str | None = None):
    """A started in-process service on a fresh temp dir: (service, dir), once its bus is up.

    udp_multicast inside the private namespace (``--netns``), else the virtual bus (or ``interface``)."""
    import tempfile

    from vdp.cli.serve import tune_interpreter
    from vdp.live import Service

    tune_interpreter()  # as vdp serve does
    tmp = Path(tempfile.mkdtemp(prefix="vdp-bench-"))
    if interface:
        cfg = settings(tmp, interface, channel)
    else:
        cfg = settings(tmp, "udp_multicast", GROUP) if netns else settings(tmp)
    svc = Service(cfg)
    svc.start()
    wait_up(svc)
    return svc, tmp


def wait_up(svc, limit: float = 30.0) -> None:
    end = time.monotonic() + limit
    while not svc.link.up:
        if time.monotonic() > end:
            raise SystemExit(f"the service's bus did not open: {svc.link.info.last_error}")
        time.sleep(0.01)


def drain(svc, sent: int, limit: float = 60.0) -> None:
    """Wait until every frame sent has been received (or the limit), then estimated."""
    end = time.monotonic() + limit
    while svc.intake.received < sent and time.monotonic() < end:
        time.sleep(0.02)
    svc.sync()


class ApiServer:
    """`vdp serve`'s own uvicorn server (its host guard and guarded HTTP protocol: ``build_server``)
    serving the app on 127.0.0.1 (a free port) in a thread, as `vdp serve` does."""

    def __init__(self, settings, service):
        from vdp.cli.serve import _bind, build_server

        self.sock = _bind("127.0.0.1", 0)  # the very socket `vdp serve` listens on
        self.port = self.sock.getsockname()[1]
        self.server = build_server(settings, service)
        self.thread = threading.Thread(
            target=self.server.run, kwargs={"sockets": [self.sock]}, name="uvicorn", daemon=True
        )

    def start(self) -> ApiServer:
        self.thread.start()
        end = time.monotonic() + 30
        while not self.server.started:
            if time.monotonic() > end:
                raise SystemExit("uvicorn did not start")
            time.sleep(0.01)
        return self

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=10)
        self.sock.close()


def client_process(mode: str, port: int, **kw) -> subprocess.Popen:
    """benchmarks/service_client.py in its own process (its CPU is not the service's)."""
    args = [sys.executable, str(Path(__file__).parent / "service_client.py"), mode, "--port", str(port)]
    for k, v in kw.items():
        args += [f"--{k.replace('_', '-')}", str(v)]
    return subprocess.Popen(args, stdout=subprocess.PIPE, text=True)


def service_counts(svc) -> dict:
    st = svc.status()
    return {
        "received": svc.intake.received,
        "dropped": svc.intake.dropped,
        "estimated": st["estimation"]["frames"],
        "estimation_errors": st["estimation"]["errors"],
        "decoded": st["decode"]["decoded"],
        "decode_frames": st["decode"]["frames"],
        "raw_logged": st["raw_log"]["frames"],
        "raw_lost": st["raw_log"]["lost"],
        "bus_errors": st["bus"]["errors"],
        "reconnects": st["bus"]["reconnects"],
        "stage": st["estimation"]["stage"],
        "queue_capacity": st["queue"]["capacity"],
    }
