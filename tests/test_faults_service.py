"""Faults of the live service (issue 6): bus, receive thread, silent channels, diverging filters.

The bus and backoff tests use fakes and a virtual bus; the channel and filter tests run
the real pipeline on simulated drives (stage 1 restored as converged, so the short
`stage2` drive runs stage 2).
"""

from __future__ import annotations

import math
import socket
import threading

import can
import numpy as np
import pytest
from fastapi.testclient import TestClient

from helpers.bus import PAPER
from helpers.live import make_settings, wait_for, wait_frames, wait_up
from vdp.api import create_app
from vdp.core import filters
from vdp.core.result import Estimate
from vdp.errors import BusError
from vdp.live import Service
from vdp.live.bus import RECEIVE_BUFFER, BusLink
from vdp.pipeline import Pipeline
from vdp.settings import BusSettings
from vdp.sim.run import Simulation

STAGE1 = {"l_f": 1.4, "h": 0.637, "C_K": 10.0}  # the simulator's truth


def restore_stage1(pipe) -> None:
    pipe.restore({n: Estimate.from_dict(n, {"value": v, "std": 0.002 * v, "samples": 2000}) for n, v in STAGE1.items()})


def drive(scenario: str, seconds: float, seed: int = 4) -> list[can.Message]:
    return list(Simulation(PAPER, scenario, seed, "realistic", duration=seconds).frames())


# -- the bus ------------------------------------------------------------------------------------
class _Clock(threading.Event):
    """A stop event whose waits return at once and are recorded: the backoff without the waiting."""

    def __init__(self):
        super().__init__()
        self.waits: list[float] = []

    def wait(self, timeout=None):
        self.waits.append(timeout)
        return self.is_set()


def test_reconnect_backoff_doubles_up_to_its_bound_and_never_spins():
    cfg = BusSettings(interface="virtual", channel="backoff", bitrate=None, listen_only=False)
    opens = []

    def opener(c):
        opens.append(c)
        if len(opens) == 10:
            link._stop.set()
        raise BusError("cannot open socketcan bus 'can0': No such device")

    link = BusLink(cfg, [], reconnect_min=0.5, reconnect_max=4.0, opener=opener)
    link._stop = _Clock()
    link._keep()  # the keeper loop, run here: it returns once stopped
    assert link._stop.waits == [0.5, 1.0, 2.0, 4.0, 4.0, 4.0, 4.0, 4.0, 4.0, 4.0]
    assert link.info.state == "down" and link.info.errors == 10 and "No such device" in link.info.last_error


def test_a_listener_raising_in_the_receive_thread_is_noticed_and_receiving_resumes():
    seen = []

    class Brittle(can.Listener):
        def on_message_received(self, msg):
            seen.append(msg.data[0])
            if msg.data[0] == 3:
                raise RuntimeError("listener bug")

    cfg = BusSettings(interface="virtual", channel=f"brittle-{id(seen)}", bitrate=None, listen_only=False)
    link = BusLink(cfg, [Brittle()], reconnect_min=0.05, reconnect_max=0.2)
    link.start()
    tx = can.Bus(interface="virtual", channel=cfg.channel)
    try:
        wait_for(lambda: link.up, "the bus to open")
        first = link.notifier
        for k in range(5):
            tx.send(can.Message(arbitration_id=0x100, data=bytes([k])))
        wait_for(lambda: link.info.reconnects >= 1 and link.up and link.notifier is not first, "a new notifier")
        assert "listener bug" in link.info.last_error and link.info.errors >= 1
        tx.send(can.Message(arbitration_id=0x100, data=bytes([42])))
        wait_for(lambda: 42 in seen, "frames after the reconnect")
    finally:
        tx.shutdown()
        link.stop()


class _SocketBus(can.BusABC):
    """A bus over an OS socket, like socketcan's (a UDP socket here: nothing is sent)."""

    def __init__(self, **kw):
        super().__init__(channel="sock", **kw)
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def _recv_internal(self, timeout):
        threading.Event().wait(timeout or 0.01)
        return None, False

    def send(self, msg, timeout=None):
        raise AssertionError("vdp never transmits")

    def shutdown(self):
        self.socket.close()
        super().shutdown()


def _allowed_receive_buffer() -> tuple[int, int]:
    """(the kernel's default, the most it grants this process) for a socket's receive buffer."""
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        default = probe.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) // 2
        try:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUFFORCE, RECEIVE_BUFFER)  # CAP_NET_ADMIN
            return default, RECEIVE_BUFFER
        except (OSError, AttributeError):
            with open("/proc/sys/net/core/rmem_max") as f:
                return default, min(int(f.read()), RECEIVE_BUFFER)
    finally:
        probe.close()


def test_the_bus_socket_gets_a_large_receive_buffer():
    # The kernel queues frames while the receive thread waits for the GIL (an API burst):
    # its default buffer holds ~30 ms of a saturated bus, then frames are lost uncounted.
    default, allowed = _allowed_receive_buffer()
    if allowed <= default:
        pytest.skip(
            f"the kernel grants no receive buffer above its default ({default} bytes) here: "
            "net.core.rmem_max is at the default and there is no CAP_NET_ADMIN"
        )
    cfg = BusSettings(interface="socketcan", channel="can0", bitrate=None)
    link = BusLink(cfg, [], opener=lambda c: _SocketBus())
    link.start()
    try:
        wait_for(lambda: link.up, "the bus to open")
        got = link.bus.socket.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) // 2
        assert got >= allowed and link.status()["receive_buffer"] == got
    finally:
        link.stop()


# -- a channel goes silent ---------------------------------------------------------------------
def test_a_silent_channel_is_stale_pauses_gating_and_no_filter_predicts_across_the_gap(monkeypatch):
    predicts = {"n": 0}
    for cls in (filters.UKF, filters.EKF):

        def predict(self, dt, u, _orig=cls.predict):
            predicts["n"] += 1
            return _orig(self, dt, u)

        monkeypatch.setattr(cls, "predict", predict)

    frames = drive("stage2", 14.0)
    t0 = frames[0].timestamp
    gap = (t0 + 7.0, t0 + 8.5)  # IMU_RATES (yaw and roll rate) silent inside stage 2's window
    pipe = Pipeline(PAPER)
    restore_stage1(pipe)
    est, learner = pipe.estimator, pipe.estimator.s2["ukf"]
    before = [m for m in frames if m.timestamp < gap[0]]
    during = [m for m in frames if gap[0] <= m.timestamp < gap[1] and m.arbitration_id != 0x0E1]
    after = [m for m in frames if m.timestamp >= gap[1]]
    for m in before:
        pipe.feed(m)
    assert est.supervisor.active == 2 and learner.filter is not None
    old_filter, samples = learner.filter, learner.samples
    # (the pipeline takes each sample look_ahead ticks after it came: the gates' look-ahead)
    settle = [m for m in during if m.timestamp < gap[0] + 0.1 + pipe.look_ahead() * est.cfg.tick]
    for m in settle:
        pipe.feed(m)
    n0 = predicts["n"]
    for m in during[len(settle) :]:
        pipe.feed(m)
    fresh = pipe.result().channels
    assert fresh["yaw_rate"].stale and fresh["roll_rate"].stale and not fresh["accel_y"].stale
    assert est.supervisor.active is None and learner.filter is None
    # the yaw rate closes the window (stage 2 can do without a roll rate, not without a yaw rate)
    assert est.supervisor.reason[2] == "channels missing or stale: yaw_rate"
    assert predicts["n"] == n0  # no filter stepped while the channel was silent
    assert learner.samples - samples <= 10  # only the ticks before it was found stale
    closed = est.supervisor.windows[-1]
    assert closed.stage == 2 and gap[0] <= closed.end <= gap[0] + 0.1
    for m in after:
        pipe.feed(m)
    reopened = est.supervisor.windows[-1]
    assert est.supervisor.active == 2 and reopened.start >= gap[1] and reopened is not closed
    # a new filter after the gap: the old one's dynamic states never crossed it
    assert learner.filter is not None and learner.filter is not old_filter
    assert learner.samples > samples + 200


def test_a_silent_channel_shows_in_health_and_status(tmp_path):
    frames = drive("stage1", 5.0)
    t_end = frames[-1].timestamp
    sent = [m for m in frames if not (m.arbitration_id == 0x0E1 and m.timestamp > t_end - 1.0)]
    svc = Service(make_settings(tmp_path))
    svc.start()
    wait_up(svc)
    tx = can.Bus(interface="virtual", channel=svc.bus_cfg.channel, preserve_timestamps=True)
    client = TestClient(create_app(svc.settings, svc))
    try:
        for m in sent:
            tx.send(m)
        wait_frames(svc, len(sent))
        h = client.get("/health").json()
        assert h["status"] == "degraded" and "stale channels: roll_rate, yaw_rate" in h["reasons"]
        ch = client.get("/status").json()["channels"]
        assert ch["yaw_rate"]["stale"] and ch["yaw_rate"]["age"] == pytest.approx(1.0, abs=0.02)
        assert not ch["accel_x"]["stale"]
        # the whole bus silent beyond [service] silence: every channel stale, its age counted to now
        # (the ages at the newest frame stay small while nothing comes: /status said "not stale")
        quiet = svc.settings.service.silence + 7.0
        svc.ingest.silent_for = lambda: quiet
        ch = client.get("/status").json()["channels"]
        assert all(c["stale"] for c in ch.values())
        assert ch["accel_x"]["age"] == pytest.approx(quiet, abs=0.05)
    finally:
        tx.shutdown()
        svc.stop()


# -- a filter diverges ----------------------------------------------------------------------------
def _indefinite(P: np.ndarray) -> np.ndarray:
    """Same positive diagonal, correlations of 1.5: not positive definite."""
    d = np.sqrt(np.diag(P))
    C = 1.5 * np.outer(d, d)
    np.fill_diagonal(C, np.diag(P))
    assert np.linalg.eigvalsh(C).min() < 0
    return C


@pytest.mark.parametrize("kind", ["ukf", "ekf"])
def test_a_covariance_no_longer_positive_definite_resets_stage_1_to_its_last_good(kind):
    frames = drive("stage1", 16.0, seed=2)
    pipe = Pipeline(PAPER)
    half = len(frames) // 2
    for m in frames[:half]:
        pipe.feed(m)
    learner = pipe.estimator.s1[kind]
    assert learner.filter is not None and learner.samples > 100 and learner.resets == 0
    good = learner._good[0].copy()
    f = learner.filter._f
    f.P = _indefinite(f.P)
    for m in frames[half:]:
        pipe.feed(m)
        if learner.resets:
            break
    assert learner.resets == 1, "the broken covariance went unnoticed"
    assert "positive definite" in learner.last_error
    np.testing.assert_allclose(learner.theta, good)  # back to the last good estimate
    for e in pipe.result().parameters.values():
        assert e.value is None or math.isfinite(e.value)


def test_a_diverging_stage_2_resets_is_flagged_and_no_response_carries_nan(tmp_path):
    frames = drive("stage2", 12.0)
    svc = Service(make_settings(tmp_path))
    svc.start()
    wait_up(svc)
    svc._call(restore_stage1)  # on the worker thread, like everything touching the pipeline
    tx = can.Bus(interface="virtual", channel=svc.bus_cfg.channel, preserve_timestamps=True)
    client = TestClient(create_app(svc.settings, svc))
    half = len(frames) // 2
    try:
        for m in frames[:half]:
            tx.send(m)
        wait_frames(svc, half)
        assert svc.estimates()["supervisor"]["active_stage"] == 2

        def poison(pipe):
            s2 = pipe.estimator.s2
            assert s2["ukf"].filter is not None and s2["ekf"].filter is not None
            s2["ukf"].filter._f.x[4] = math.nan  # C_alpha of the UKF
            s2["ekf"].filter._f.P = _indefinite(s2["ekf"].filter._f.P)
            return {k: l._good[0].copy() for k, l in s2.items()}

        good = svc._call(poison)
        # what the API serves right now, before the next step notices: never NaN
        for path in ("/estimates", "/status", "/metrics"):
            r = client.get(path)
            assert r.status_code == 200 and "NaN" not in r.text and "Infinity" not in r.text, path
        for m in frames[half:]:
            tx.send(m)
        wait_frames(svc, len(frames))
        resets = svc._call(lambda p: {k: (l.resets, l.last_error) for k, l in p.estimator.s2.items()})
        assert resets["ukf"][0] == 1 and "non-finite" in resets["ukf"][1]
        assert resets["ekf"][0] == 1 and "positive definite" in resets["ekf"][1]
        h = client.get("/health").json()
        for kind in ("UKF", "EKF"):  # both said, one not hiding the other
            assert any(f"{kind} filter diverged and was reset to its last good estimate" in r for r in h["reasons"]), h[
                "reasons"
            ]
        r = client.get("/estimates")
        assert "NaN" not in r.text and r.json()["resets"] == {"ukf": 1, "ekf": 1}
        p = r.json()["parameters"]["C_alpha"]
        assert p["value"] is not None and math.isfinite(p["value"])
        assert abs(p["value"] - good["ukf"][0]) < 0.5 * good["ukf"][0]  # carried on from the last good one
        assert client.get("/metrics").text.count("NaN") == 0
    finally:
        tx.shutdown()
        svc.stop()
