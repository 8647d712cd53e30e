"""Security (issue 6): `vdp serve` listens on 127.0.0.1 unless told otherwise.

The rest of the security list has its tests elsewhere: POST /reset refused (401/403)
with the state unchanged in test_api.py, config and profile validation in
test_service_settings.py, test_service_cli.py and test_profiles_errors.py, and
schemathesis in test_api_schema.py.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vdp.cli import build_parser
from vdp.cli.serve import _bind, _settings

ROOT = Path(__file__).resolve().parents[1]


def listeners(port: int) -> set[str]:
    """Local addresses of the sockets listening on ``port`` (from /proc/net/tcp and tcp6)."""
    out = set()
    for name in ("tcp", "tcp6"):
        try:
            rows = Path(f"/proc/net/{name}").read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            local, state = row.split()[1], row.split()[3]
            addr, p = local.split(":")
            if state == "0A" and int(p, 16) == port:  # 0A: LISTEN
                out.add(addr)
    return out


def test_every_way_to_start_the_service_defaults_to_loopback(tmp_path):
    cfg = tmp_path / "vdp.toml"
    cfg.write_text(f'profile = "{ROOT}/profiles/paper.toml"\n')
    for argv in (
        ["serve", "--simulate"],
        ["serve", "--config", str(cfg)],
        ["serve", "--config", str(ROOT / "deploy" / "vdp.toml")],
    ):
        s = _settings(build_parser().parse_args(argv))
        assert s.api.host == "127.0.0.1", argv
    sock = _bind("127.0.0.1", 0)
    try:
        assert sock.getsockname()[0] == "127.0.0.1"
        assert listeners(sock.getsockname()[1]) == {"0100007F"}
    finally:
        sock.close()
    s = _settings(build_parser().parse_args(["serve", "--simulate", "--host", "0.0.0.0"]))
    assert s.api.host == "0.0.0.0"  # another address is an explicit choice (and is logged: test_api.py)


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_running_vdp_serve_listens_on_127_0_0_1_only(tmp_path):
    err = tmp_path / "serve.err"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys; from vdp.cli import main; sys.exit(main())",
            "serve",
            "--simulate",
            "--port",
            "0",
            "--sim-speed",
            "1",
            "--db",
            str(tmp_path / "db.sqlite"),
            "--raw-dir",
            str(tmp_path / "raw"),
        ],
        stdout=subprocess.DEVNULL,
        stderr=open(err, "w"),
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT / "service")},
    )
    try:
        end = time.monotonic() + 120
        while not (m := re.search(r"http://([^/]+):(\d+)/estimates", err.read_text())):
            assert proc.poll() is None and time.monotonic() < end, err.read_text()[-3000:]
            time.sleep(0.05)
        assert m.group(1) == "127.0.0.1"
        assert listeners(int(m.group(2))) == {"0100007F"}  # 127.0.0.1, nothing on 0.0.0.0 or ::
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0, err.read_text()[-3000:]
