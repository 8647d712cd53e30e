"""The live service against careless and hostile neighbours (issue 13): a second service on
the same files, a flood of idle API clients, requests under a foreign Host name.

Servers listen on 127.0.0.1 only.
"""

from __future__ import annotations

import os
import re
import resource
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from starlette.applications import Starlette
from starlette.responses import PlainTextResponse
from starlette.routing import Route
from starlette.testclient import TestClient

from vdp.cli.serve import _guard_hosts

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


def test_on_localhost_any_host_header_is_answered():
    app = _app()
    assert _guard_hosts(app, "127.0.0.1") is app
