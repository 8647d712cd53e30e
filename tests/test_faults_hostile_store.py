"""A damaged or unwritable estimate store (issue 13): the service degrades, never ends, and the
raw log never stops.

A damaged file is moved aside (kept), a fresh store starts, /health says "degraded" with the
reason and /metrics counts it; a full disk is "unavailable" with the right advice, retried
until there is room.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import sqlite3
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from vdp.core.result import Estimate
from vdp.errors import StoreError
from vdp.store import Store

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "service")}
FP = "f" * 64


def est(value: float, samples: int) -> Estimate:
    return Estimate(
        name="l_f", value=value, std=0.1, unit="m", status="converging", valid=False, stage=1, samples=samples
    )


def filled_store(path: Path, saves: int = 300) -> None:
    s = Store(path, FP, "paper", synchronous="normal")
    for k in range(saves):
        s.save({"l_f": est(1.0 + k * 1e-3, k)}, t=1.7e9 + k)
    s.close()
    with sqlite3.connect(path) as con:
        con.execute("PRAGMA wal_checkpoint(TRUNCATE)")


def overwrite_page(path: Path, page: int) -> None:
    size = sqlite3.connect(path).execute("PRAGMA page_size").fetchone()[0]
    with open(path, "r+b") as f:
        f.seek((page - 1) * size)
        f.write(b"\xa5" * size)


def rootpage(path: Path, name: str) -> int:
    with sqlite3.connect(path) as con:
        return con.execute("SELECT rootpage FROM sqlite_master WHERE name=?", (name,)).fetchone()[0]


@pytest.mark.parametrize("where", ["a history page", "the meta index page"])
def test_a_damaged_store_is_moved_aside_and_a_fresh_one_starts(tmp_path, where):
    p = tmp_path / "s.sqlite"
    filled_store(p)
    page = rootpage(p, "history") if where == "a history page" else rootpage(p, "sqlite_autoindex_meta_1")
    overwrite_page(p, page)
    damaged = p.read_bytes()
    s = Store(p, FP, "paper")
    assert s.recovered and "damaged" in s.recovered and s.load() == {}
    kept = [q for q in tmp_path.iterdir() if re.fullmatch(r"s\.sqlite\.damaged-[0-9TZ]+", q.name)]
    assert len(kept) == 1 and kept[0].read_bytes() == damaged and kept[0].name in s.recovered
    s.save({"l_f": est(1.2, 5)})
    assert s.load()["l_f"].estimate.value == 1.2
    s.close()


def test_another_sqlite_file_is_still_refused_and_left_alone(tmp_path):
    p = tmp_path / "other.sqlite"
    with sqlite3.connect(p) as con:
        con.execute("CREATE TABLE t (x)")
    with pytest.raises(StoreError, match="not a vdp estimate store"):
        Store(p, FP)
    assert not [q for q in tmp_path.iterdir() if "damaged" in q.name]
    with sqlite3.connect(p) as con:
        assert con.execute("SELECT name FROM sqlite_master").fetchall() == [("t",)]


def _get(url: str) -> str:
    with urllib.request.urlopen(url, timeout=10) as r:
        return r.read().decode()


def test_vdp_serve_on_a_damaged_store_is_degraded_not_dead(tmp_path):
    db = tmp_path / "s.sqlite"
    filled_store(db)
    overwrite_page(db, rootpage(db, "history"))
    err = tmp_path / "err.txt"
    args = ["serve", "--simulate", "--loop", "--port", "0", "--db", str(db), "--raw-dir", str(tmp_path / "raw")]
    p = subprocess.Popen(
        [sys.executable, "-c", "import sys; from vdp.cli import main; sys.exit(main())", *args],
        stdout=subprocess.DEVNULL,
        stderr=open(err, "wb"),
        env=ENV,
    )
    try:
        deadline = time.monotonic() + 60
        while not (m := re.search(r"http://127\.0\.0\.1:(\d+)/health", err.read_text())):
            assert p.poll() is None and time.monotonic() < deadline, err.read_text()
            time.sleep(0.1)
        url = f"http://127.0.0.1:{m.group(1)}"
        time.sleep(2.0)
        health = json.loads(_get(url + "/health"))
        assert health["status"] == "degraded"
        assert any(r.startswith("estimate store recovered:") and "damaged-" in r for r in health["reasons"])
        metrics = _get(url + "/metrics")
        assert "vdp_store_recoveries_total 1.0" in metrics and "vdp_bus_garbage_total 0.0" in metrics
        raw = tmp_path / "raw"
        size = sum(f.stat().st_size for f in raw.glob("*.log"))
        time.sleep(1.0)
        assert sum(f.stat().st_size for f in raw.glob("*.log")) > size and p.poll() is None
        assert "Traceback" not in err.read_text()
    finally:
        p.terminate()
        p.wait(30)


# -- a full disk: the right advice, and a retry once there is room ------------------------------

FULL_DISK = r"""
import os, subprocess, sys, time
from pathlib import Path
from vdp.errors import StoreError
from vdp.live.writer import StoreWriter
from vdp.settings import StoreSettings
d = Path(sys.argv[1])
subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "none", str(d)], check=True)
with open(d / "fill", "wb") as f:
    try:
        f.write(b"x" * (2 << 20))
    except OSError:
        pass
w = StoreWriter(StoreSettings(path=d / "s.sqlite"), "f" * 64, "paper")
assert w.open() == {}
print("STATE", w.state)
print("ERROR", w.error)
(d / "fill").unlink()
w._retry_at = 0.0
print("FILES", sorted(os.listdir(d)))
ok = w._try_open()
print("REOPENED", ok, w.state)
print("ERROR2", w.error)
w.close()
"""


def _can_mount() -> str | None:
    if not shutil.which("unshare") or os.geteuid() != 0:
        return "needs root and unshare (util-linux) to mount a small tmpfs"
    r = subprocess.run(["unshare", "-m", "true"], capture_output=True, timeout=20)
    return None if r.returncode == 0 else f"unshare -m failed: {r.stderr.decode()[:200]}"


@pytest.mark.skipif(_can_mount() is not None, reason=str(_can_mount()))
def test_a_full_disk_under_a_new_store_gives_the_right_advice_and_is_retried(tmp_path):
    d = tmp_path / "small"
    d.mkdir()
    r = subprocess.run(
        ["unshare", "-m", sys.executable, "-c", FULL_DISK, str(d)],
        capture_output=True,
        text=True,
        timeout=60,
        env=ENV,
    )
    assert r.returncode == 0, r.stderr
    out = dict(line.split(" ", 1) for line in r.stdout.strip().splitlines())
    assert out["STATE"] == "unavailable"
    assert "the disk is full" in out["ERROR"] and "not a vdp store" not in out["ERROR"]
    assert out["REOPENED"] == "True ok"


# -- damage found while the service runs (issue 26) ---------------------------------------------


def test_a_store_damaged_while_the_service_runs_is_moved_aside_and_health_says_so(tmp_path):
    from fastapi.testclient import TestClient

    from helpers.live import FakePipeline, make_settings
    from vdp.api import create_app
    from vdp.live import Service
    from vdp.profile import load_profile
    from vdp.store import profile_fingerprint

    settings = make_settings(tmp_path)
    db = settings.store.path
    s = Store(db, profile_fingerprint(load_profile(settings.profile)), "paper", synchronous="normal")
    for k in range(300):
        s.save({"l_f": est(1.0 + k * 1e-3, k)}, t=1.7e9 + k)
    s.close()  # checkpointed: the history pages live in the file itself
    svc = Service(settings, pipeline=FakePipeline())
    svc.start()
    client = TestClient(create_app(settings, svc))
    try:
        # (the bus thread connects as the service starts: under load /health may say so first)
        deadline = time.monotonic() + 20
        while True:
            reasons = client.get("/health").json()["reasons"]
            if not any(r.startswith("bus connect") for r in reasons) or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        assert reasons == ["no frames received yet"]
        overwrite_page(db, rootpage(db, "history"))  # a disk fault, or a careless hand, under the service
        r = client.get("/estimates/history")
        assert r.status_code == 503 and "damaged" in r.json()["detail"], r.text  # was a 500
        h = client.get("/health").json()
        assert h["status"] == "degraded"
        assert any(x.startswith("estimate store recovered:") and "damaged-" in x for x in h["reasons"]), h
        kept = [q for q in tmp_path.iterdir() if re.fullmatch(r"state\.sqlite\.damaged-[0-9TZ]+", q.name)]
        assert len(kept) == 1
        r = client.get("/estimates/history", params={"limit": 1000})  # the fresh store answers: only new rows
        assert r.status_code == 200 and all(it["t"] > 1.7e9 + 300 for it in r.json()["items"])
        assert "vdp_store_recoveries_total 1.0" in client.get("/metrics").text
        svc.commit()
    finally:
        svc.stop()
    # what is left under the store's name after shutdown is a sound store, not the damaged file
    with sqlite3.connect(db) as con:
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert con.execute("SELECT count(*) FROM estimates").fetchone()[0] > 0
    assert b"\xa5" * 1024 in kept[0].read_bytes()  # the damaged file, kept for a look
