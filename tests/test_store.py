"""The estimate store: round trip, WAL, refusal of another profile or schema, kill -9."""

from __future__ import annotations

import dataclasses
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from vdp.core.result import Estimate
from vdp.errors import StoreError
from vdp.profile import Prior, load_profile
from vdp.store import SCHEMA_VERSION, Store, profile_fingerprint

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "profiles" / "paper.toml"
NAMES = ("l_f", "h", "C_K", "C_alpha", "I_z", "I_x")


def params(v: float = 1.0, status: str = "converged") -> dict[str, Estimate]:
    return {
        n: Estimate(
            name=n,
            value=v * (i + 1),
            std=0.01 * v,
            unit="m",
            valid=status == "converged",
            stage=1 if i < 3 else 2,
            status=status,
            samples=int(100 * v),
        )
        for i, n in enumerate(NAMES)
    }


@pytest.fixture
def fp() -> str:
    return profile_fingerprint(load_profile(PROFILE))


def test_round_trip_and_history_only_on_change(tmp_path, fp):
    db = tmp_path / "s.sqlite"
    st = Store(db, fp, "paper")
    assert st.load() == {}
    assert st.save(params(1.0), t=100.0, bus_t=5.0) == 6
    assert st.save(params(1.0), t=101.0, bus_t=6.0) == 0  # nothing changed: no history rows
    p = params(2.0)
    p["h"] = dataclasses.replace(p["h"], value=float("nan"))  # never stored as NaN
    assert st.save(p, t=102.0) == 6
    st.close()

    st = Store(db, fp, "paper")
    stored = st.load()
    assert set(stored) == set(NAMES) and stored["l_f"].t == 102.0
    got = {k: v.estimate for k, v in stored.items()}
    assert got["l_f"].value == 2.0 and got["l_f"].std == pytest.approx(0.02)
    assert got["l_f"].valid is True and got["l_f"].status == "converged" and got["l_f"].samples == 200
    assert got["h"].value is None and got["h"].valid is False
    assert got["C_alpha"].stage == 2
    items, total = st.history()
    assert total == 12 and [i["t"] for i in items[:6]] == [100.0] * 6
    assert st.integrity() == "ok"
    st.close()


def test_history_paging_and_filters(tmp_path, fp):
    st = Store(tmp_path / "s.sqlite", fp, "paper", synchronous="normal")
    for k in range(10):
        st.save(params(1.0 + k), t=1000.0 + k)
    items, total = st.history("l_f")
    assert total == 10 and [i["value"] for i in items] == [1.0 + k for k in range(10)]
    page1, total = st.history("l_f", limit=4, offset=0)
    page3, _ = st.history("l_f", limit=4, offset=8)
    assert total == 10 and len(page1) == 4 and len(page3) == 2 and page3[-1]["value"] == 10.0
    since, total = st.history("I_x", since=1005.0)
    assert total == 5 and all(i["t"] >= 1005.0 for i in since)
    window, total = st.history(since=1002.0, until=1004.0)
    assert total == 12 and {i["parameter"] for i in window} == set(NAMES)
    st.close()


def test_wal_mode_and_readers_see_commits(tmp_path, fp):
    db = tmp_path / "s.sqlite"
    st = Store(db, fp, "paper")
    st.save(params(1.0), t=1.0)
    con = sqlite3.connect(db)
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert Path(f"{db}-wal").exists()
    # another connection reads the committed batch while the writer is still open
    assert con.execute("SELECT value FROM estimates WHERE name='l_f'").fetchone()[0] == 1.0
    con.close()
    st.close()


def test_history_is_pruned(tmp_path, fp):
    st = Store(tmp_path / "s.sqlite", fp, "paper", synchronous="normal", history_max_rows=50)
    for k in range(600):  # pruning runs every 600 batches
        st.save(params(1.0 + k), t=float(k))
    _, total = st.history()
    assert total <= 50
    items, _ = st.history(limit=1000)
    assert items[-1]["value"] == pytest.approx((1.0 + 599) * 6)  # the newest rows are the ones kept
    st.close()


def test_another_profile_is_refused_and_left_alone(tmp_path, fp):
    db = tmp_path / "s.sqlite"
    st = Store(db, fp, "paper")
    st.save(params(3.0), t=1.0)
    st.close()
    before = db.read_bytes()
    other = dataclasses.replace(load_profile(PROFILE))
    other = dataclasses.replace(other, priors={**other.priors, "h": Prior(0.6, 0.2)})
    fp2 = profile_fingerprint(other)
    assert fp2 != fp
    with pytest.raises(StoreError, match="another vehicle profile"):
        Store(db, fp2, "changed")
    assert db.read_bytes() == before  # nothing deleted, nothing rewritten
    again = Store(db, fp, "paper")  # the right profile still gets its data
    assert again.load()["l_f"].estimate.value == 3.0
    again.close()


def test_fingerprint_ignores_comments_but_not_values(tmp_path):
    text = PROFILE.read_text()
    a = tmp_path / "a.toml"
    a.write_text("# a comment\n" + text.replace("../dbc/vdp.dbc", str(ROOT / "dbc" / "vdp.dbc")))
    b = tmp_path / "b.toml"
    b.write_text(a.read_text().replace("mass = 1600.0", "mass = 1650.0"))
    fp0 = profile_fingerprint(load_profile(PROFILE))
    assert profile_fingerprint(load_profile(a)) == fp0
    assert profile_fingerprint(load_profile(b)) != fp0


def test_schema_change_and_foreign_files_are_refused(tmp_path, fp):
    db = tmp_path / "s.sqlite"
    Store(db, fp, "paper").close()
    con = sqlite3.connect(db)
    con.execute("UPDATE meta SET value='999' WHERE key='schema_version'")
    con.commit()
    con.close()
    with pytest.raises(StoreError, match=f"schema 999.*uses {SCHEMA_VERSION}"):
        Store(db, fp, "paper")

    other = tmp_path / "other.sqlite"
    con = sqlite3.connect(other)
    con.execute("CREATE TABLE t (x)")
    con.commit()
    con.close()
    with pytest.raises(StoreError, match="not a vdp estimate store"):
        Store(other, fp, "paper")

    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"this is not sqlite at all" * 100)
    with pytest.raises(StoreError, match="not a vdp store"):
        Store(junk, fp, "paper")
    assert junk.read_bytes() == b"this is not sqlite at all" * 100


WRITER = textwrap.dedent(
    f"""
    import sys
    from vdp.core.result import Estimate
    from vdp.store import Store
    db, fp = sys.argv[1], sys.argv[2]
    st = Store(db, fp, "paper")
    got = st.load()
    n = got["l_f"].estimate.samples if got else 0
    while True:
        n += 1
        st.save({{name: Estimate(name=name, value=n + i / 10, std=0.1, unit="m", valid=True, stage=1,
                                 status="converged", samples=n) for i, name in enumerate({NAMES!r})}}, t=float(n))
        print(n, flush=True)
"""
)


@pytest.mark.slow
def test_kill_9_while_writing_keeps_the_store_intact(tmp_path, fp):
    db = tmp_path / "s.sqlite"
    last = 0
    for round_ in range(5):
        proc = subprocess.Popen(
            [sys.executable, "-c", WRITER, str(db), fp],
            stdout=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONPATH": str(ROOT / "service")},
        )
        want = last + 20 + 7 * round_
        seen = last
        for line in proc.stdout:
            seen = int(line)
            if seen >= want:
                break
        os.kill(proc.pid, signal.SIGKILL)  # mid-stream: it is committing the next batches right now
        proc.wait()
        proc.stdout.close()
        assert seen >= want, "the writer stopped early"
        con = sqlite3.connect(db)
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        con.close()
        st = Store(db, fp, "paper")
        got = {k: v.estimate for k, v in st.load().items()}
        # every batch it reported committed is there (maybe a few more)
        assert got["l_f"].samples >= seen and got["I_x"].value == pytest.approx(got["l_f"].samples + 0.5)
        _, total = st.history("l_f")
        assert total == got["l_f"].samples
        last = got["l_f"].samples
        st.close()
