"""Bad frames on the bus and bad bus time (issue 6): counted per ID, never half used, never a bad step.

- the live service (real pipeline, virtual bus) gets a drive with bad frames mixed in:
  each is counted under its ID and kind, and the estimates are exactly those of the
  good frames alone, so no partial sample entered the buffer;
- any frame at all (hypothesis) is counted exactly once and yields all or nothing;
- bad counters make a channel invalid in /health, and good frames bring it back;
- clock faults (one frame stamped far in the future, a step back, a jump forward,
  NaN, jitter) never give a filter a non-positive or huge step, and estimation
  carries on after each.
"""

from __future__ import annotations

import math

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from helpers.bus import EXTRA, EXTRA_DB, PAPER, VDP_DB, frame
from helpers.live import make_settings, wait_frames, wait_up
from vdp.core import compiled, filters
from vdp.core.estimator import EstimatorConfig
from vdp.core.result import Estimate
from vdp.live import Service
from vdp.pipeline import Pipeline
from vdp.sim.run import Simulation

TRUTH_S1 = ("l_f", "h", "C_K")


def drive(scenario: str, seconds: float, seed: int = 3) -> list[can.Message]:
    return list(Simulation(PAPER, scenario, seed, "realistic", duration=seconds).frames())


def msg(t: float, arb: int, data: bytes = bytes(8), **kw) -> can.Message:
    return can.Message(timestamp=t, arbitration_id=arb, is_extended_id=arb > 0x7FF, data=data, **kw)


@pytest.fixture
def service(tmp_path):
    made = []

    def make():
        svc = Service(make_settings(tmp_path))
        svc.start()
        wait_up(svc)
        tx = can.Bus(interface="virtual", channel=svc.bus_cfg.channel, preserve_timestamps=True)
        made.append((svc, tx))
        return svc, tx

    yield make
    for svc, tx in made:
        tx.shutdown()
        svc.stop()


def test_bad_frames_on_the_live_bus_are_counted_and_never_half_used(service):
    good = drive("stage1", 6.0)
    sent, kept = [], []
    steering = [k for k, m in enumerate(good) if m.arbitration_id == 0x0D0]
    corrupt = steering[len(steering) // 2]
    for k, m in enumerate(good):
        if k == corrupt:
            bad = can.Message(
                timestamp=m.timestamp, arbitration_id=m.arbitration_id, is_extended_id=False, data=bytearray(m.data)
            )
            bad.data[7] ^= 0xFF  # checksum wrong: the whole frame goes, not just its steering angle
            sent.append(bad)
            continue
        sent.append(m)
        kept.append(m)
        if k == len(good) // 3:
            t = m.timestamp
            gnss = frame(VDP_DB, "GNSS_VELOCITY", t=t, GNSS_SPEED=10.0)
            gnss.data[0:2] = b"\xff\xff"  # 65.535 m/s: above the DBC's 65
            sent += [
                msg(t, 0x0E1, bytes(7)),  # wrong DLC
                can.Message(timestamp=t, arbitration_id=0x0B1, is_extended_id=False, is_remote_frame=True, dlc=8),
                msg(t, 0x7DF, b"\x02\x01\x0d"),  # unknown ids
                msg(t, 0x18DAF110),
                msg(t, 0x0E1, is_error_frame=True),  # bus error; its id bits equal IMU_RATES
                gnss,
            ]
    svc, tx = service()
    for m in sent:
        tx.send(m)
    wait_frames(svc, len(sent))
    st = svc.status()
    dec = st["decode"]
    assert dec["errors"] == {
        "0x0E1": {"dlc": 1},
        "0x0B1": {"remote": 1},
        "0x0D0": {"checksum": 1},
        "0x1F0": {"range": 1},
    }
    assert {u["id"] for u in dec["unknown_ids"]} == {"0x7DF", "0x18DAF110"} and dec["error_frames"] == 1
    assert st["estimation"]["errors"] == 0 and st["estimation"]["frames"] == len(sent)
    assert st["bus"]["errors"] == 0 and st["bus"]["reconnects"] == 0 and svc.link.up

    # the service's own learners (numpy's filter steps, not the compiled ones, which agree to ~1e-10)
    ref = Pipeline(PAPER, EstimatorConfig(trace_len=600, learner=svc.estimation.pipeline.estimator.cfg.learner))
    for m in kept:
        ref.feed(m)
    ref.flush()  # (the samples held for the gates' look-ahead: the service's sync takes them too)
    want = {k: e.as_dict() for k, e in ref.result().parameters.items()}
    live = svc.estimates()["parameters"]
    assert svc.latest.result.samples == ref.samples and want["l_f"]["samples"] > 150  # 20 ms samples
    for name in want:
        assert (live[name]["value"], live[name]["std"], live[name]["samples"]) == (
            want[name]["value"],
            want[name]["std"],
            want[name]["samples"],
        ), name


# -- any frame ----------------------------------------------------------------------------------
IDS = sorted({m.frame_id for m in VDP_DB.messages} | {m.frame_id for m in EXTRA_DB.messages})
FRAMES = st.lists(
    st.tuples(
        st.one_of(st.sampled_from(IDS), st.integers(0, 0x7FF), st.integers(0, 0x1FFFFFFF)),
        st.booleans(),
        st.one_of(st.binary(max_size=8), st.binary(min_size=9, max_size=64)),
        st.sampled_from(["data", "data", "data", "remote", "error", "fd"]),
        st.floats(0.0, 0.02),
    ),
    min_size=1,
    max_size=80,
)


def _build(items) -> list[can.Message]:
    out, t = [], 1000.0
    for arb, ext, data, kind, dt in items:
        t += dt
        ext = (ext and arb in IDS and arb > 0x7FF) or arb > 0x7FF
        if kind == "remote":
            out.append(
                can.Message(
                    timestamp=t, arbitration_id=arb, is_extended_id=ext, is_remote_frame=True, dlc=min(len(data), 8)
                )
            )
        else:
            out.append(
                can.Message(
                    timestamp=t,
                    arbitration_id=arb,
                    is_extended_id=ext,
                    data=data,
                    is_error_frame=kind == "error",
                    is_fd=kind == "fd" or len(data) > 8,
                )
            )
    return out


def _tally(stats) -> tuple:
    return (
        stats.decoded,
        stats.error_frames,
        stats.skipped_channel,
        sum(stats.unknown.values()),
        sum(stats.errors.values()),
    )


@pytest.mark.parametrize("profile", [PAPER, EXTRA], ids=["paper", "extra-mux-float-ext"])
@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True, database=None)
@given(items=FRAMES)
def test_any_frame_is_counted_once_and_gives_all_or_nothing(profile, items):
    pipe = Pipeline(profile, EstimatorConfig(baseline=False))
    dec = pipe.decoder
    for m in _build(items):
        before = _tally(dec.stats)
        pairs = dec.decode(m)  # the decoder alone, as pipe.feed calls it
        after = _tally(dec.stats)
        moved = [a - b for a, b in zip(after, before)]
        assert sorted(moved) == [0, 0, 0, 0, 1], (m, moved)  # exactly one counter per frame
        if pairs:
            assert moved[0] == 1  # samples only from a frame accepted whole
        assert all(math.isfinite(v) for _, v in pairs), pairs
        pipe.feed(m)  # and the whole pipeline takes it without raising
    assert dec.stats.frames == 2 * len(items)


def test_bad_counters_make_a_channel_invalid_and_good_frames_bring_it_back(service):
    svc, tx = service()

    def wheels(t, c):
        return frame(VDP_DB, "WHEEL_SPEEDS_FRONT", t=t, counter=c, WHEEL_SPEED_FL=10.0, WHEEL_SPEED_FR=10.0)

    t, n = 1000.0, 0
    for c in range(5):
        tx.send(wheels(t, c))
        t, n = t + 0.01, n + 1
    for _ in range(3):  # a frozen counter: the sender is stuck, its data is stale
        tx.send(wheels(t, 4))
        t, n = t + 0.01, n + 1
    wait_frames(svc, n)
    reason = "invalid channels (bad counter or checksum): wheel_speed_fl, wheel_speed_fr"
    assert reason in svc.health()["reasons"]
    assert svc.status()["decode"]["invalid_channels"] == ["wheel_speed_fl", "wheel_speed_fr"]
    for c in (9, 10, 11):  # counting again (the first one resyncs the counter)
        tx.send(wheels(t, c))
        t, n = t + 0.01, n + 1
    wait_frames(svc, n)
    assert reason not in svc.health()["reasons"]
    st = svc.status()["decode"]
    assert st["invalid_channels"] == [] and st["errors"]["0x0B1"]["counter"] == 4


# -- clock faults -------------------------------------------------------------------------------
@pytest.fixture
def steps(monkeypatch):
    """Every dt given to a UKF or EKF predict, by filter kind."""
    got: dict[str, list[float]] = {"ukf": [], "ekf": []}
    # the compiled UKFs (core.kernels) replace _predict, not predict: counted here too
    for cls in (filters.UKF, filters.EKF):

        def predict(self, dt, u, _orig=cls.predict):
            got[self.kind].append(dt)
            return _orig(self, dt, u)

        monkeypatch.setattr(cls, "predict", predict)
    # stage 1's compiled UKF steps a block in one call (core.kernels.lon_block), its dt an argument
    block = compiled.kernel("lon_block")
    if block is not None:

        def lon_block(*a):
            got["ukf"].append(a[14])
            return block(*a)

        from vdp.core import kernels

        monkeypatch.setattr(kernels, "lon_block", lon_block)
    return got


def _with_clock_faults(frames: list[can.Message]) -> tuple[list[can.Message], list[int]]:
    """The drive with, at fifths of it: one frame stamped 11 days ahead, the clock stepping 5 s
    back, jumping 1000 s forward, then a NaN stamp and 0.5 ms of jitter back."""
    n = len(frames)
    out, marks, shift = [], [], 0.0

    def copy(m, t):
        return can.Message(
            timestamp=t,
            arbitration_id=m.arbitration_id,
            is_extended_id=m.is_extended_id,
            data=m.data,
            channel=m.channel,
        )

    for k, m in enumerate(frames):
        fifth = 5 * k // n
        if k and 5 * (k - 1) // n != fifth:
            marks.append(len(out))
            if fifth == 1:
                out.append(copy(m, m.timestamp + 1e6))  # one glitch
            elif fifth == 2:
                shift -= 5.0
            elif fifth == 3:
                shift += 1000.0
            elif fifth == 4:
                out.append(copy(m, math.nan))
                out.append(copy(m, m.timestamp + shift - 0.0005))
        out.append(copy(m, m.timestamp + shift))
    return out, marks


@pytest.mark.parametrize("scenario", ["stage1", "stage2"])
def test_clock_faults_never_give_a_filter_a_bad_step(steps, scenario):
    frames = drive(scenario, 16.0, seed=4)
    faulty, marks = _with_clock_faults(frames)

    def run(seq, at):
        pipe = Pipeline(PAPER)
        if scenario == "stage2":  # stage 1 known and converged: the drive runs stage 2
            pipe.restore(
                {
                    n: Estimate.from_dict(n, {"value": v, "std": 0.002 * v, "samples": 2000})
                    for n, v in zip(TRUTH_S1, (1.4, 0.637, 10.0))
                }
            )
        counts = []
        for k, m in enumerate(seq):
            if k in at:
                counts.append(len(steps["ukf"]))
            pipe.feed(m)
        return pipe, counts + [len(steps["ukf"])]

    clean_marks = [i * len(frames) // 5 for i in range(1, 5)]  # the same fifths of the clean drive
    clean, clean_counts = run(frames, clean_marks)
    n_clean = {k: len(v) for k, v in steps.items()}
    for v in steps.values():
        v.clear()
    pipe, counts = run(faulty, marks)
    for kind, dts in steps.items():
        assert len(dts) > 0.8 * n_clean[kind] > 30, (kind, len(dts), n_clean[kind])
        bad = [dt for dt in dts if not 0.0 < dt <= 0.25]
        assert not bad, (kind, bad[:5])
    # estimation went on after every fault: each fifth of the drive stepped the filters about as
    # often as the clean drive's (stage 1 leaves out blocks beyond the small-slip range, so a
    # fifth of hard acceleration steps it less in both)
    per = [b - a for a, b in zip(counts, counts[1:])]
    per_clean = [b - a for a, b in zip(clean_counts, clean_counts[1:])]
    assert all(p >= 0.5 * c > 0 for p, c in zip(per, per_clean)), (per, per_clean)
    res = pipe.result()
    assert res.clock.jumps >= 3
    assert all(e.value is None or math.isfinite(e.value) for e in res.parameters.values())
    assert pipe.samples > 0.95 * clean.samples
