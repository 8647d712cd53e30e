"""The live service against careless and hostile neighbours (issues 13 and 26): a second service
on the same files, a flood of idle API clients, requests under a foreign Host name (loopback
included), request bodies too large to read, slow-loris clients.

Servers listen on 127.0.0.1 only.
"""

from __future__ import annotations

import os
import re
import resource
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from dataclasses import replace
from pathlib import Path

import pytest
from starlette.applications import Starlette
from starlette.responses import PlainTextResponse
from starlette.routing import Route
from starlette.testclient import TestClient

from helpers.live import FakePipeline, make_settings
from vdp.cli.serve import _bind, _guard_hosts, build_server
from vdp.live import Service

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "service")}
SERVE = [sys.executable, "-c", "import sys; from vdp.cli import main; sys.exit(main())", "serve", "--simulate"]
# the same, with the usual default soft limit of open files (the hard limit as the machine has it)
SERVE_1024 = [
    sys.executable,
    "-c",
    "import resource, sys; from vdp.cli import main\n"
    "resource.setrlimit(resource.RLIMIT_NOFILE, (1024, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))\n"
    "sys.exit(main())",
    "serve",
    "--simulate",
]


def start(tmp_path: Path, name: str, *extra: str, soft_1024: bool = False) -> tuple[subprocess.Popen, Path]:
    err = tmp_path / f"{name}.err"
    cmd = SERVE_1024 if soft_1024 else SERVE
    args = [*cmd, "--port", "0", "--db", str(tmp_path / "s.sqlite"), "--raw-dir", str(tmp_path / "raw"), *extra]
    p = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=open(err, "wb"), env=ENV)
    return p, err


def wait_port(p: subprocess.Popen, err: Path) -> int:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        m = re.search(r"http://127\.0\.0\.1:(\d+)/health", err.read_text())
        if m:
            return int(m.group(1))
        assert p.poll() is None, err.read_text()
        time.sleep(0.1)
    raise AssertionError("the service did not come up: " + err.read_text())


def get(port: int, path: str = "/health", timeout: float = 10.0) -> tuple[int, float]:
    t = time.monotonic()
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=timeout) as r:
            r.read()
            code = r.status
    except urllib.error.HTTPError as exc:
        code = exc.code
    return code, time.monotonic() - t


def raw_bytes(d: Path) -> int:
    return sum(f.stat().st_size for f in d.glob("*.log"))


def stop(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.terminate()
        try:
            p.wait(30)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(10)


def test_a_second_service_on_the_same_store_and_raw_dir_is_refused(tmp_path):
    first, err1 = start(tmp_path, "first", "--loop")
    try:
        port = wait_port(first, err1)
        time.sleep(1.0)
        second = subprocess.run(
            [*SERVE, "--port", "0", "--db", str(tmp_path / "s.sqlite"), "--raw-dir", str(tmp_path / "raw")],
            capture_output=True,
            text=True,
            timeout=60,
            env=ENV,
        )
        lines = second.stderr.strip().splitlines()
        assert second.returncode == 2 and len(lines) == 1, second.stderr
        assert f"in use by another vdp serve (pid {first.pid})" in lines[0]
        # the first goes on: it answers, and its open raw file keeps growing under its own name
        current = tmp_path / "raw" / "vdp-current.log"
        size = current.stat().st_size
        time.sleep(1.5)
        assert get(port)[0] == 200 and first.poll() is None
        assert current.stat().st_size > size
    finally:
        stop(first)
    # the lock goes with the process: a new service starts on the same files
    again, err = start(tmp_path, "again")
    try:
        wait_port(again, err)
    finally:
        stop(again)


@pytest.mark.slow
def test_1100_idle_clients_neither_starve_health_nor_the_raw_log(tmp_path):
    hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    svc, err = start(tmp_path, "svc", "--loop", "--sim-speed", "5", soft_1024=True)
    socks = []
    try:
        port = wait_port(svc, err)
        raw = tmp_path / "raw"
        soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
        resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, max(soft, 4096)), hard))
        for _ in range(1100):
            s = socket.create_connection(("127.0.0.1", port), timeout=5)
            socks.append(s)
        before = raw_bytes(raw)
        worst = max(get(port)[1] for _ in range(5))
        time.sleep(1.0)
        during = raw_bytes(raw)
        code, _ = get(port)
        # with a hard limit above the service's bound, health never waits for the idle sockets; at
        # a hard limit of 1,024 the first answer waits for them to be closed (5 s). 3 s tells the
        # two apart on a busy machine (1.5 s seen with the other test worker's load beside it)
        assert code == 200 and worst < (3.0 if hard >= 4096 else 6.0), worst
        assert during > before
        for s in socks:
            s.close()
        socks = []
        time.sleep(1.5)
        assert raw_bytes(raw) > during and svc.poll() is None
        assert err.stat().st_size < 100_000, err.read_text()[-2000:]  # no accept() traceback flood
    finally:
        for s in socks:
            s.close()
        stop(svc)


def _app():
    return Starlette(routes=[Route("/health", lambda request: PlainTextResponse("ok"))])


@pytest.mark.parametrize(
    "host,code",
    [
        ("evil.example", 400),
        ("evil.example:8000", 400),
        ("localhost:8000", 200),
        ("192.168.7.2:8000", 200),
        ("[fe80::1]:8000", 200),
        (socket.gethostname(), 200),
    ],
)
def test_beyond_localhost_the_host_header_is_checked(host, code):
    client = TestClient(_guard_hosts(_app(), "0.0.0.0"))
    assert client.get("/health", headers={"host": host}).status_code == code


@pytest.mark.parametrize(
    "host,code",
    [
        ("evil.example", 400),  # a rebound DNS name pointing at 127.0.0.1
        ("evil.example:8000", 400),
        ("192.168.7.2:8000", 400),  # not this machine's loopback
        ("localhost:8000", 200),
        ("127.0.0.1:8000", 200),
        ("[::1]:8000", 200),
        ("logger.example", 200),  # named in [api] allowed_hosts
    ],
)
def test_on_loopback_the_host_header_is_checked_too(host, code):
    client = TestClient(_guard_hosts(_app(), "127.0.0.1", "logger.example"))
    assert client.get("/health", headers={"host": host}).status_code == code


# -- vdp serve's HTTP server in a thread (127.0.0.1): limits before work -------------------------

TOKEN = "s3cret-token-for-tests-0123456789"


@pytest.fixture
def served(tmp_path):
    """(port, service) of `vdp serve`'s uvicorn server over a service with a fake pipeline."""
    made = []

    def make(**api):
        s = make_settings(tmp_path, TOKEN)
        s = replace(s, api=replace(s.api, **api))
        svc = Service(s, pipeline=FakePipeline())
        svc.start()
        server = build_server(s, svc)
        sock = _bind("127.0.0.1", 0)
        t = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
        t.start()
        made.append((svc, server, t, sock))
        end = time.monotonic() + 30
        while not server.started:
            assert time.monotonic() < end and t.is_alive(), "the server did not start"
            time.sleep(0.02)
        return sock.getsockname()[1], svc

    yield make
    for svc, server, t, sock in made:
        server.should_exit = True
        t.join(15)
        sock.close()
        svc.stop()


def ask(port: int, head: bytes, body: bytes = b"", timeout: float = 10.0) -> bytes:
    """Send a request head (and maybe a body), return what the server answers before closing."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        s.sendall(head + body)
        out = b""
        while not _complete(out):
            chunk = s.recv(65536)
            if not chunk:
                break
            out += chunk
        return out


def _complete(answer: bytes) -> bool:
    head, sep, body = answer.partition(b"\r\n\r\n")
    m = re.search(rb"content-length: (\d+)", head, re.I)
    return bool(sep) and m is not None and len(body) >= int(m.group(1))


def status_of(answer: bytes) -> int:
    return int(answer.split(b" ", 2)[1])


def test_a_foreign_host_name_is_refused_by_vdp_serve_on_loopback(served):
    port, _ = served()
    assert status_of(ask(port, b"GET /status HTTP/1.1\r\nHost: evil.example\r\n\r\n")) == 400
    assert status_of(ask(port, b"GET /status HTTP/1.1\r\nHost: 127.0.0.1:%d\r\n\r\n" % port)) == 200


def test_a_request_head_beyond_16_kb_is_refused_with_431(served):
    """httptools' parser (vdp serve's, for its CPU a request) has no head limit of its own: the
    guard counts the head as it is parsed, as h11's limit did."""
    from vdp.cli.serve import HEAD_LIMIT, _guarded_protocol

    assert _guarded_protocol(10, 1.0).__mro__[1].__name__ == "HttpToolsProtocol"  # installed with vdp
    port, _ = served()
    head = b"GET /status HTTP/1.1\r\nHost: localhost\r\nX-Pad: %s\r\n\r\n"
    assert status_of(ask(port, head % (b"x" * (HEAD_LIMIT + 100)))) == 431
    assert status_of(ask(port, head % (b"x" * 1000))) == 200  # a head of a few KB is answered


def test_a_huge_reset_body_is_refused_before_it_is_read(served):
    port, svc = served(max_body=4096)
    big = 30 << 20
    # The body is never sent: every answer below comes from the head alone.  Today's code waits for
    # the 30 MB (and would then parse them) before it looks at the token.
    for auth, code in ((b"", 401), (b"Authorization: Bearer wrong-token-0123456789\r\n", 403)):
        head = b"POST /reset HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
        head += auth + b"Content-Length: %d\r\n\r\n" % big
        assert status_of(ask(port, head, timeout=10.0)) == code
    head = b"POST /reset HTTP/1.1\r\nHost: localhost\r\nAuthorization: Bearer %s\r\n" % TOKEN.encode()
    answer = ask(port, head + b"Content-Type: text/plain\r\nContent-Length: %d\r\n\r\n" % big)
    assert status_of(answer) == 413 and b"max_body" in answer
    # chunked: no length to check, the body is cut off past the cap as it is read
    chunk = b"x" * 1000
    body = b"".join(b"%x\r\n%s\r\n" % (len(chunk), chunk) for _ in range(10)) + b"0\r\n\r\n"
    answer = ask(port, head + b"Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n", body)
    assert status_of(answer) == 413
    assert svc.pipeline.resets == []
    # a small body with the token still works
    ok = b'{"stage": 1}'
    answer = ask(port, head + b"Content-Type: application/json\r\nContent-Length: %d\r\n\r\n" % len(ok), ok)
    assert status_of(answer) == 200 and svc.pipeline.resets == [1]


def test_slow_loris_clients_are_closed_and_health_is_still_answered(served):
    port, _ = served(max_connections=20, header_timeout=1.0)
    slow = []
    try:
        for _ in range(30):  # more than max_connections, each sending half a request head
            s = socket.create_connection(("127.0.0.1", port), timeout=10)
            s.sendall(b"GET /health HTTP/1.1\r\nHost: loc")
            slow.append(s)
        answer = ask(port, b"GET /health HTTP/1.1\r\nHost: localhost\r\n\r\n")
        assert status_of(answer) == 200
        # a byte now and then does not keep a connection: every slow one is closed by the server
        for s in slow:
            try:
                s.sendall(b"a")
            except OSError:
                pass  # closed already (the oldest, for the newcomers)
        closed = 0
        for s in slow:
            try:
                closed += s.recv(1024) == b""  # the server's close; the 10 s socket timeout only guards a hang
            except ConnectionResetError:
                closed += 1
        assert closed == len(slow)
    finally:
        for s in slow:
            s.close()


def test_a_body_that_trickles_in_is_given_up_after_the_header_timeout(served):
    port, svc = served(header_timeout=1.0)
    head = b"POST /reset HTTP/1.1\r\nHost: localhost\r\nAuthorization: Bearer %s\r\n" % TOKEN.encode()
    head += b"Content-Type: application/json\r\nContent-Length: 100\r\n\r\n"
    # 14 of the 100 bytes, then nothing: the server answers 408 and closes, the request never runs
    answer = ask(port, head, b'{"stage": 1,  ')
    assert status_of(answer) == 408 and b"did not arrive within 1 s" in answer and svc.pipeline.resets == []


def test_health_is_answered_when_every_other_request_slot_is_taken(tmp_path):
    import asyncio

    import httpx

    from vdp.api.guard import Gate

    release = asyncio.Event()

    async def slow(request):
        await release.wait()
        return PlainTextResponse("done")

    app = Starlette(
        routes=[Route("/slow", slow), Route("/health", lambda request: PlainTextResponse("ok"))],
    )
    gated = Gate(app, make_settings(tmp_path), max_requests=1)

    async def scene():
        transport = httpx.ASGITransport(app=gated)
        async with httpx.AsyncClient(transport=transport, base_url="http://localhost") as client:
            busy = asyncio.create_task(client.get("/slow"))
            while gated.in_flight < 1:
                await asyncio.sleep(0.01)
            other = await client.get("/slow")
            health = await client.get("/health")
            release.set()
            return other.status_code, health.status_code, (await busy).status_code

    assert asyncio.run(scene()) == (503, 200, 200)


def test_every_route_that_takes_a_body_is_checked_for_its_token_before_the_body_is_read(tmp_path):
    from vdp.api import create_app
    from vdp.api.guard import TOKEN_ROUTES

    paths = create_app(make_settings(tmp_path, TOKEN)).openapi()["paths"]
    writes = {(m.upper(), p) for p, ops in paths.items() for m in ops if m in ("post", "put", "patch", "delete")}
    assert writes and writes <= TOKEN_ROUTES, writes - TOKEN_ROUTES
