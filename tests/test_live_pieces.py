"""Each piece of the live service on its own: ingest, the estimation loop, the store writer."""

from __future__ import annotations

import dataclasses
import queue
import time

import can
import pytest

from helpers.live import FakePipeline, make_settings, send, wait_for
from vdp.errors import StoreError
from vdp.live.estimation import Estimation, Published, Unavailable
from vdp.live.ingest import Ingest
from vdp.live.writer import StoreWriter
from vdp.profile import load_profile
from vdp.store import Store, profile_fingerprint


@pytest.fixture(scope="module")
def paper(repo_root):
    return load_profile(repo_root / "profiles" / "paper.toml")


def test_ingest_puts_every_frame_in_the_queue_and_the_raw_log(tmp_path, paper):
    settings = make_settings(tmp_path)
    ing = Ingest(settings, paper)
    ing.open_rawlog()
    ing.start()
    tx = can.Bus(interface="virtual", channel=ing.bus_cfg.channel, preserve_timestamps=True)
    try:
        wait_for(lambda: ing.link.up, "the bus to open")
        send(tx, 30)
        wait_for(lambda: ing.intake.received == 30, "30 frames")
        ing.tick()
        got: list = []
        while len(got) < 30:  # blocks of frame records (timestamp first), in order
            got += ing.queue.get_nowait()
        assert [f[0] for f in got] == pytest.approx([1000.0 + 0.01 * k for k in range(30)])
        assert ing.rawlog.frames == 30 and ing.silent_for() is not None
        st = ing.status()
        assert st["bus"]["frames"] == 30 and st["queue"]["depth"] == 0 and st["simulation"] is None
        assert ing.backlog() == 0.0
    finally:
        tx.shutdown()
        ing.stop()
        ing.close()
    assert ing.rawlog.stats()["bytes"] > 0


def frame(k: int, first: int = 40) -> can.Message:
    return can.Message(timestamp=1000.0 + 0.01 * k, arbitration_id=0x123, data=bytes([first + k % 10] * 8))


def test_estimation_feeds_in_order_publishes_and_survives_bad_frames():
    class Picky(FakePipeline):
        def feed(self, msg):
            super().feed(msg)
            if msg.data[0] == 45:
                raise ValueError("a frame the pipeline chokes on")

    frames: queue.Queue = queue.Queue()
    est = Estimation(Picky(), frames, publish_interval=0.05)
    assert est.latest.seq == 0 and not est.alive
    with pytest.raises(Unavailable):
        est.call(lambda p: None)  # not started
    est.start()
    try:
        for k in range(20):
            frames.put(frame(k))
        seen = est.call(lambda p: p.frames)  # runs after the frames queued before it
        assert seen == 20 and est.fed == 20 and est.errors == 2  # data[0] == 45 twice
        pub = est.latest
        assert isinstance(pub, Published) and pub.fed == 20 and pub.result.frames == 20
        assert pub.result.parameters["l_f"].value == pytest.approx(1.0 + 49 / 100)  # the last frame's byte
    finally:
        est.stop()
    assert not est.alive and est.latest.fed == 20


def test_a_dead_estimation_worker_is_started_again():
    frames: queue.Queue = queue.Queue()
    est = Estimation(FakePipeline(), frames, publish_interval=0.05)
    est.start()
    est.stop()  # the thread ends as if it had died
    assert not est.alive
    est.ensure_running()
    try:
        assert est.alive and est.restarts == 1
        frames.put(frame(1))
        assert est.call(lambda p: p.frames) == 1
    finally:
        est.stop()


def test_a_stop_estimates_the_queued_frames_for_its_budget_then_drops_and_counts_the_rest():
    """Ctrl-C on `vdp serve --simulate` drained ~32,000 queued frames (7-10 s) in silence. The worker
    is held on the first frame until the stop has been asked for, with no time left: the 999 frames
    queued behind it are dropped and counted, and a command among them is refused, not left waiting."""
    import threading

    go = threading.Event()

    class Held(FakePipeline):
        def feed(self, msg):
            go.wait(10)
            super().feed(msg)

    frames: queue.Queue = queue.Queue()
    est = Estimation(Held(), frames, publish_interval=0.05)
    est.start()
    for k in range(1000):
        frames.put(frame(k))
    wait_for(lambda: frames.qsize() == 999, "the worker to take the first frame")
    from vdp.live.estimation import _Command

    cmd = _Command(lambda p: p.frames)
    frames.put(cmd)
    stopper = threading.Thread(target=est.stop, kwargs={"budget": 0.0})
    stopper.start()
    wait_for(lambda: est._stop_by is not None, "the stop to be asked for")
    go.set()
    stopper.join(10)
    assert not est.alive
    assert est.fed == 1 and est.dropped == 999 and isinstance(cmd.future.exception(), Unavailable)
    # without a budget every queued frame is estimated, as before
    frames2: queue.Queue = queue.Queue()
    est2 = Estimation(FakePipeline(), frames2, publish_interval=0.05)
    for k in range(50):
        frames2.put(frame(k))
    est2.start()
    est2.stop()
    assert est2.fed == 50 and est2.dropped == 0


def test_restoring_checks_the_estimator_took_the_values():
    class Deaf(FakePipeline):
        def restore(self, params):
            self.restored = params  # ... and ignores them

    stored = {"l_f": dataclasses.replace(FakePipeline().result().parameters["l_f"], value=1.77)}
    ok = Estimation(FakePipeline(), queue.Queue(), 0.05)
    assert ok.restore(stored) is None and ok.restored
    deaf = Estimation(Deaf(), queue.Queue(), 0.05)
    assert "l_f" in deaf.restore(stored) and not deaf.restored


def test_store_writer_commits_each_snapshot_once_and_reads_history(tmp_path, paper):
    settings = make_settings(tmp_path)
    fp = profile_fingerprint(paper)
    w = StoreWriter(settings.store, fp, "paper")
    assert w.open() == {} and w.ok and w.state == "ok"
    pipe = FakePipeline()
    pipe.feed(frame(1))  # one sample: estimates worth keeping
    pub = Published(1, 100.0, pipe.result(), 0)
    w.commit(pub)
    w.commit(pub)  # the same snapshot again: nothing new to write
    assert w.commits == 1 and w.last_commit is not None
    page = w.history("l_f", None, None, 10, 0)
    assert page["total"] == 1 and page["items"][0]["value"] == pipe.lf and page["next_offset"] is None
    w.close()
    assert w.state == "closed" and w.commits == 0
    again = StoreWriter(settings.store, fp, "paper")
    stored = again.open()
    assert set(stored) == set(pipe.result().parameters) - {"I_x"}  # I_x had no value: not worth restoring
    again.close()


def test_store_writer_refuses_another_profiles_store_and_keeps_going(tmp_path):
    settings = make_settings(tmp_path)
    Store(settings.store.path, "0" * 64, "another car").close()
    w = StoreWriter(settings.store, "1" * 64, "paper")
    assert w.open() == {} and w.state == "refused" and "another vehicle profile" in w.error
    w.commit(Published(1, time.time(), FakePipeline().result(), 0))  # no store: nothing, no error
    with pytest.raises(Unavailable, match="refused"):
        w.history(None, None, None, 10, 0)
    assert w.status()["state"] == "refused"
    with pytest.raises(StoreError):
        Store(settings.store.path, "1" * 64, "paper")  # the file is still the other car's


def test_a_raw_log_disk_below_its_free_space_floor_is_said_at_start(tmp_path, caplog):
    """A logger started on a disk that is already nearly full said nothing until frames came;
    now the start says how much is free, the floor, and what happens."""
    import logging

    from vdp.live.rawlog import RawLog

    raw = RawLog(tmp_path / "raw", max_bytes=4096, max_files=3, min_free=1 << 60)  # more than any disk
    with caplog.at_level(logging.WARNING, logger="vdp.live.rawlog"):
        raw.open()
    raw.close()
    assert "less than the" in caplog.text and "min_free_mb" in caplog.text
    caplog.clear()
    ok = RawLog(tmp_path / "raw2", max_bytes=4096, max_files=3, min_free=0)
    with caplog.at_level(logging.WARNING, logger="vdp.live.rawlog"):
        ok.open()
    ok.close()
    assert "min_free_mb" not in caplog.text


def test_a_raw_log_whose_last_flush_fails_is_still_closed_and_named(tmp_path, monkeypatch):
    """A full disk at shutdown: the last flush fails mid-line. The file is not left as the open
    one with half a line (it was, until the next start salvaged it): the unfinished line is cut
    and the file named as the closed ones."""
    import errno

    import can

    from vdp.live.rawlog import RawLog

    raw = RawLog(tmp_path / "raw", max_bytes=1 << 20, max_files=3, min_free=0)
    raw.open()
    for i in range(50):
        raw.on_message_received(can.Message(timestamp=1.0 + i, arbitration_id=0x123, data=b"\x01\x02"))
    raw.flush()
    with open(raw.current, "ab") as f:
        f.write(b"(1700000000.5) can0 123#01")  # what a flush cut short by a full disk leaves

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(raw._logger, "stop", full)
    raw.close()
    assert not raw.current.exists() and raw.disk_full
    (closed,) = raw.closed_files()
    text = closed.read_bytes()
    assert text.endswith(b"\n") and text.count(b"\n") == 50  # the 50 whole lines, the cut one dropped


def test_a_check_still_solving_does_not_hold_the_process_exit(tmp_path):
    """The stage-2 checks ran on a ThreadPoolExecutor, whose worker the interpreter joins at exit:
    a fit still solving held Ctrl-C's exit after "service stopped".  Here the check never ends;
    the process must end anyway (the limit only guards against a hang)."""
    import subprocess
    import sys

    script = (
        "import threading\n"
        "from vdp.live.service import CheckThread\n"
        "c = CheckThread()\n"
        "c.submit(threading.Event().wait)\n"
        "later = c.submit(print, 'never')\n"
        "c.shutdown(wait=False, cancel_futures=True)\n"
        "assert later.cancelled()\n"
        "print('exiting')\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout == "exiting\n", out.stderr


NO_NUMBA_SCRIPT = """
import sys
from vdp.core.estimator import EstimatorConfig
from vdp.live.service import Service
from vdp.pipeline import Pipeline
from vdp.profile import load_profile
from vdp.sim.run import Simulation

profile = load_profile(sys.argv[1])
cfg = Service.estimator_config(per_axle=False, checks=None)
pipe = Pipeline(profile, cfg)
for msg in Simulation(profile, "paper", 1, "realistic").frames():
    pipe.feed(msg)
    if pipe.samples >= 2000:  # 40 s: both stages' filters are open by then
        break
est = pipe.estimator
opened = sum(x.filter is not None for x in [*est.s1.values(), *est.s2.values()])
print(cfg.learner.compiled, pipe.samples, opened, "numba" in sys.modules)
"""


def test_the_live_pipeline_never_loads_numba(repo_root):
    """The service estimates with numpy's steps; numba's import (its LLVM: ~120 MB of RSS, docs/decisions/
    0020) must not come in by asking whether a filter is the compiled one."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": str(repo_root / "service")}
    out = subprocess.run(
        [sys.executable, "-c", NO_NUMBA_SCRIPT, str(repo_root / "profiles" / "paper.toml")],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    compiled, samples, opened, numba = out.stdout.split()
    assert (compiled, int(samples) >= 2000, int(opened) > 0) == ("False", True, True), out.stdout
    assert numba == "False", "numba was imported by the live pipeline"


def test_every_listener_of_the_bus_takes_blocks(tmp_path, paper):
    """BlockNotifier makes a python-can Message of every frame for a listener without ``on_block``: one
    such listener (it was the link's error hook) doubled the receive thread's CPU on a saturated bus."""
    ing = Ingest(make_settings(tmp_path), paper)
    per_frame = [type(x).__name__ for x in ing.link.listeners if not hasattr(x, "on_block")]
    assert per_frame == []


def test_a_silence_of_the_bus_runs_the_gap_hook_before_the_first_frame_after_it():
    """The drive look must see a drive before the next one's frames come, whenever the keeper
    thread runs (a simulated pair of drives an hour apart passed in a second, before its first
    look, and became one drive): the worker runs the hook at the silence itself, in a block of
    frame records (the gap inside one block, or between two) and frame by frame alike."""
    seen: list = []
    frames: queue.Queue = queue.Queue()
    est = Estimation(FakePipeline(), frames, publish_interval=0.05)
    est.gap_hook, est.gap_s = (lambda p, end, start: seen.append((p.frames, end, start))), 60.0

    def rec(t: float):
        return (t, 0x123, 0, bytes(8), None)

    est.start()
    try:
        frames.put([rec(1000.0 + 0.01 * k) for k in range(10)] + [rec(4600.0 + 0.01 * k) for k in range(5)])
        frames.put([rec(4600.1), rec(4600.2)])  # no silence: no look
        frames.put([rec(9000.0)])  # a silence between two blocks
        frames.put(can.Message(timestamp=9001.0, arbitration_id=0x123, data=bytes(8)))
        frames.put(can.Message(timestamp=20000.0, arbitration_id=0x123, data=bytes(8)))  # one by one
        assert est.call(lambda p: p.frames) == 20
    finally:
        est.stop()
    # each look saw every frame before its silence, none after, and was told the silence's bounds
    # (the first: before the run's first frame, the bus silent before it)
    assert [n for n, _, _ in seen] == [0, 10, 17, 19]
    assert [(e, t) for _, e, t in seen] == [
        (None, 1000.0),
        (pytest.approx(1000.09), 4600.0),
        (4600.2, 9000.0),
        (9001.0, 20000.0),
    ]


def test_a_block_is_fed_and_counted_as_frame_by_frame(paper):
    """Estimation._feed_block decodes and counts what Pipeline.feed of each frame does: decoded, unknown ids
    and their order, for a block of plain frames and one with an extended id and an error frame."""
    import itertools

    from vdp.live.reader import ERR, EXT, TX, frame_of
    from vdp.pipeline import Pipeline
    from vdp.sim.run import Simulation

    sim = Simulation(paper, "paper", 1, "realistic", extra_ids=12, extra_rate=100.0, start_time=1000.0)
    msgs = list(itertools.islice(sim.frames(), 600))
    msgs.append(
        can.Message(timestamp=msgs[-1].timestamp + 0.001, arbitration_id=0x18DAF110, data=bytes(8), is_extended_id=True)
    )
    msgs.append(
        can.Message(
            timestamp=msgs[-1].timestamp + 0.001,
            arbitration_id=0x4,
            data=bytes(8),
            is_extended_id=False,
            is_error_frame=True,
        )
    )
    one = Pipeline(paper)
    for m in msgs:
        one.feed(m)
    blocks = Pipeline(paper)
    est = Estimation(blocks, queue.Queue(), 1.0, channel="can0")
    recs = [(f[0], f[1], f[2] & ~TX, f[3], None) for f in map(frame_of, msgs)]  # as read from a socket
    plain, mixed = recs[:300], recs[300:]  # a block of plain frames, and one with an extended id and an error frame
    assert not any(f[2] for f in plain) and {f[2] & (EXT | ERR) for f in mixed} == {0, EXT, ERR}
    est._feed_block(plain)
    est._feed_block(mixed)
    a, b = one.decoder.stats.as_dict(top=100), blocks.decoder.stats.as_dict(top=100)
    assert a == b and a["decoded"] > 0 and a["unknown_distinct"] == 13
    assert list(one.decoder.stats.unknown) == list(blocks.decoder.stats.unknown)
    assert est.fed == len(msgs) and blocks.samples == one.samples
