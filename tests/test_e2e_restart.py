"""Power loss: `kill -9` the running service, start it again; the estimates are back at once.

`vdp serve --simulate` runs as a real process (HTTP on 127.0.0.1 only, a free port).
After each kill the store passes `PRAGMA integrity_check`, the restarted service
serves the committed estimates from its first answer, and every closed raw log
file is complete.
"""

from __future__ import annotations

import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from vdp.io.logs import open_log

ROOT = Path(__file__).resolve().parents[1]
STAGE1 = ("l_f", "h", "C_K")

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]


def start(tmp: Path, n: int, speed: str) -> tuple[subprocess.Popen, int, Path]:
    err = tmp / f"serve{n}.err"
    cmd = [
        sys.executable,
        "-c",
        "import sys; from vdp.cli import main; sys.exit(main())",
        "serve",
        "--simulate",
        "--sim-speed",
        speed,
        "--noise",
        "none",
        "--port",
        "0",
        "--host",
        "127.0.0.1",
        "--db",
        str(tmp / "state.sqlite"),
        "--raw-dir",
        str(tmp / "raw"),
    ]
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.DEVNULL,
        stderr=open(err, "w"),
        cwd=tmp,
        env={**os.environ, "PYTHONPATH": str(ROOT / "service")},
    )
    end = time.monotonic() + 120
    while time.monotonic() < end:
        m = re.search(r"http://127\.0\.0\.1:(\d+)/estimates", err.read_text())
        if m:
            return proc, int(m.group(1)), err
        if proc.poll() is not None:
            pytest.fail(f"vdp serve exited: {err.read_text()[-3000:]}")
        time.sleep(0.05)
    proc.kill()
    pytest.fail("vdp serve did not start")


def get(port: int, path: str) -> dict:
    end = time.monotonic() + 30
    while True:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=10) as r:
                return json.loads(r.read())
        except OSError:
            if time.monotonic() > end:
                raise
            time.sleep(0.05)


def stored(db: Path) -> dict:
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        return {
            r[0]: {"value": r[1], "std": r[2], "status": r[3], "t": r[4]}
            for r in con.execute("SELECT name, value, std, status, t FROM estimates")
        }
    except sqlite3.OperationalError:
        return {}  # not created yet
    finally:
        con.close()


def until(cond, what: str, proc: subprocess.Popen, err: Path, limit: float = 300.0):
    end = time.monotonic() + limit
    while not cond():
        if proc.poll() is not None:
            pytest.fail(f"vdp serve died while waiting for {what}: {err.read_text()[-3000:]}")
        if time.monotonic() > end:
            proc.kill()
            pytest.fail(f"gave up waiting for {what}")
        time.sleep(0.1)


def kill9(proc: subprocess.Popen) -> None:
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()


def check_after_crash(tmp: Path) -> dict:
    db = tmp / "state.sqlite"
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    con.close()
    for p in sorted((tmp / "raw").glob("vdp-0*.log")):  # closed files: complete
        assert p.read_bytes().endswith(b"\n"), p
        src = open_log(p)
        assert sum(1 for _ in src) > 0 and src.stats.bad == 0, p
    return stored(db)


def test_kill_9_and_restart_carries_on_from_the_stored_estimates(tmp_path):
    db = tmp_path / "state.sqlite"
    proc, port, err = start(tmp_path, 0, speed="0")  # as fast as it goes, to converge soon
    until(
        lambda: all(stored(db).get(n, {}).get("status") == "converged" for n in STAGE1),
        "stage 1 to converge and be committed",
        proc,
        err,
    )
    kill9(proc)
    last = check_after_crash(tmp_path)
    assert all(last[n]["status"] == "converged" for n in STAGE1)

    for n in (1, 2):
        # real time now: the drive starts with a straight cruise, so nothing moves the
        # estimates before the first answer, which must carry the committed ones exactly
        proc, port, err = start(tmp_path, n, speed="1")
        first = get(port, "/estimates")
        assert first["restored"] is True, get(port, "/health")["reasons"]
        for name in STAGE1:
            e = first["parameters"][name]
            assert e["status"] == "converged" and e["valid"], (name, e)
            assert e["value"] == pytest.approx(last[name]["value"], rel=1e-9), name
            assert e["std"] == pytest.approx(last[name]["std"], rel=1e-9), name
        st = get(port, "/status")
        assert set(STAGE1) <= set(st["store"]["restored"]) and st["store"]["state"] == "ok"
        # let it commit a few more batches, then cut the power again
        t0 = last["l_f"]["t"]
        until(lambda t0=t0: stored(db).get("l_f", {}).get("t", 0) > t0 + 1.5, "new commits", proc, err)
        kill9(proc)
        last = check_after_crash(tmp_path)
        assert all(last[n]["status"] == "converged" for n in STAGE1)

    # and a clean stop after all that
    proc, port, err = start(tmp_path, 3, speed="1")
    assert get(port, "/estimates")["restored"] is True
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(60) == 0, err.read_text()[-3000:]
    assert not (tmp_path / "raw" / "vdp-current.log").exists()
    check_after_crash(tmp_path)
