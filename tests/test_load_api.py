"""Load (issue 6): the API answers 200 concurrent clients while the service ingests a saturated bus.

No request may fail and no frame may be dropped.  Two forms:

- in process: a sender thread puts a saturated bus (~8000 frames/s: a simulated drive
  plus 74 unrelated IDs at 100 Hz) in real time on a virtual bus; uvicorn serves the
  app on 127.0.0.1 from the socket `vdp serve` would listen on;
- across processes (private network namespace): benchmarks/service_load.py with the
  sender in its own process on udp_multicast.  There the kernel queues the frames, and
  frames it drops while the receive thread waits would be lost without a count: the
  test compares frames sent with frames received.

The figures (latencies, rates) go to BENCHMARKS.md, not into these assertions.
"""

from __future__ import annotations

import asyncio
import json
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest

from helpers.bus import PAPER
from helpers.live import make_settings, wait_for, wait_up
from helpers.netns import netns_reason
from vdp.api import create_app
from vdp.cli.serve import _bind
from vdp.live import Service
from vdp.sim.run import Simulation

ROOT = Path(__file__).resolve().parents[1]
PATHS = ["/health", "/estimates", "/status", "/metrics", "/estimates/history?limit=50"]


def test_the_api_socket_is_tcp_so_answers_are_not_held_back():
    # asyncio sets TCP_NODELAY only on sockets whose proto is TCP; without it every answer
    # (headers and body are two writes) waits ~40 ms for the client's delayed ACK.
    sock = _bind("127.0.0.1", 0)
    seen = []

    async def main():
        class Probe(asyncio.Protocol):
            def connection_made(self, transport):
                s = transport.get_extra_info("socket")
                seen.append(s.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY))
                transport.close()

        server = await asyncio.get_running_loop().create_server(Probe, sock=sock)
        _, w = await asyncio.open_connection(*sock.getsockname()[:2])
        for _ in range(100):
            if seen:
                break
            await asyncio.sleep(0.01)
        w.close()
        server.close()

    asyncio.run(main())
    assert seen and seen[0] != 0


class _Server:
    """uvicorn on 127.0.0.1, as `vdp serve` runs it, in a thread."""

    def __init__(self, settings, svc):
        import uvicorn

        self.sock = _bind("127.0.0.1", 0)
        self.port = self.sock.getsockname()[1]
        self.server = uvicorn.Server(uvicorn.Config(create_app(settings, svc), log_level="warning", access_log=False))
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)

    def __enter__(self):
        self.thread.start()
        wait_for(lambda: self.server.started, "uvicorn to start")
        return self

    def __exit__(self, *exc):
        self.server.should_exit = True
        self.thread.join(timeout=10)
        self.sock.close()


async def _get(reader, writer, path: str) -> tuple[int, bytes]:
    """One HTTP/1.1 GET on a kept-alive connection (a bare client: the test measures the server)."""
    writer.write(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
    await writer.drain()
    head = await reader.readuntil(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    length = next(int(v) for k, _, v in (ln.partition(":") for ln in lines[1:]) if k.lower() == "content-length")
    return status, await reader.readexactly(length)


async def _clients(port: int, clients: int, requests: int) -> list[tuple[str, int | str]]:
    """``clients`` connections opened at once, each sending ``requests`` GETs one after another."""
    results: list[tuple[str, int | str]] = []
    go = asyncio.Event()

    async def one(i):
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        try:
            await go.wait()
            for k in range(requests):
                path = PATHS[(i + k) % len(PATHS)]
                try:
                    status, body = await asyncio.wait_for(_get(reader, writer, path), 60)
                    if path != "/metrics":
                        json.loads(body)
                    results.append((path, status))
                except (OSError, asyncio.IncompleteReadError, asyncio.TimeoutError, ValueError) as exc:
                    results.append((path, f"{type(exc).__name__}: {exc}"))
                    return
        finally:
            writer.close()

    tasks = [asyncio.create_task(one(i)) for i in range(clients)]
    await asyncio.sleep(0.1)
    go.set()
    await asyncio.gather(*tasks)
    return results


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_200_concurrent_clients_while_the_bus_is_saturated(tmp_path):
    svc = Service(make_settings(tmp_path))
    svc.start()
    wait_up(svc)
    period = 4.0
    start = time.time() + 0.5
    frames = list(
        Simulation(
            PAPER, "stage1", 1, "realistic", extra_ids=74, extra_rate=100.0, duration=period, start_time=start
        ).frames()
    )
    assert len(frames) / period > 7500  # a saturated 1 Mbit/s bus
    stop, done, sent = threading.Event(), threading.Event(), [0]

    def send():
        # the drive again and again, at its own pace, until the clients are done
        tx = can.Bus(interface="virtual", channel=svc.bus_cfg.channel, preserve_timestamps=True)
        try:
            shift = 0.0
            while not stop.is_set():
                for m in frames:
                    t = m.timestamp + shift
                    ahead = t - time.time()
                    if ahead > 0.002:
                        time.sleep(ahead)
                    tx.send(
                        can.Message(
                            timestamp=t, arbitration_id=m.arbitration_id, data=m.data, is_extended_id=m.is_extended_id
                        )
                    )
                    sent[0] += 1
                shift += period + 0.01
        finally:
            tx.shutdown()
            done.set()

    try:
        with _Server(svc.settings, svc) as server:
            threading.Thread(target=send, daemon=True).start()
            wait_for(lambda: svc.intake.received > 8000, "the bus to be busy")
            before = svc.intake.received
            results = asyncio.run(_clients(server.port, 200, 5))
            during = svc.intake.received - before
            stop.set()
            assert done.wait(60)
            wait_for(lambda: svc.intake.received >= sent[0], "every frame", limit=60)
            svc.sync()
        assert len(results) == 1000
        failed = [r for r in results if r[1] != 200]
        assert not failed, failed[:5]
        assert during > 4000  # the clients ran while frames were coming in
        st = svc.status()
        assert st["queue"]["dropped"] == 0 and st["bus"]["frames"] == sent[0]
        assert st["estimation"]["frames"] == sent[0] and st["raw_log"]["frames"] == sent[0]
        assert st["estimation"]["errors"] == 0
    finally:
        svc.stop()


@pytest.mark.slow
@pytest.mark.netns
@pytest.mark.timeout(600)
def test_200_concurrent_clients_with_the_sender_in_another_process(tmp_path):
    why = netns_reason()
    if why:
        pytest.skip(why)
    out = tmp_path / "load.json"
    r = subprocess.run(
        [
            sys.executable,
            str(ROOT / "benchmarks" / "service_load.py"),
            "--netns",
            "--seconds",
            "6",
            "--rounds",
            "1",
            "--json",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=500,
    )
    assert out.exists(), r.stdout + r.stderr[-3000:]
    res = json.loads(out.read_text())
    rnd = res["rounds"][0]
    assert rnd["requests"] == 1000 and rnd["failed_count"] == 0, rnd["failed"]
    assert rnd["frames_during"] > 8000  # the clients ran while the bus was busy
    # counted by the service, and compared with what the other process sent
    assert res["dropped"] == 0 and res["received"] == res["sent"] > 40000, (res, r.stdout)
    assert res["estimated"] == res["sent"] and res["raw_logged"] == res["sent"]
    assert r.returncode == 0, r.stdout + r.stderr[-3000:]
