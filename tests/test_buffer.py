"""The aligner: interpolation to the tick grid, staleness, fresh flags and clock faults."""

import math

import numpy as np

from vdp import channels as ch
from vdp.buffer import Aligner, SampleRing


def feed(al, frames):
    out = []
    for t, pairs in frames:
        out += al.push(t, pairs)
    return out


def test_linear_signal_is_interpolated_exactly_to_the_ticks():
    al = Aligner(stale_after=np.full(ch.N, 0.05))
    # a ramp sampled 3 ms after each tick: value = 2 t
    frames = [(k * 0.01 + 0.003, [(ch.AX, 2 * (k * 0.01 + 0.003))]) for k in range(100)]
    samples = feed(al, frames)
    assert len(samples) > 90
    for s in samples[1:]:
        assert math.isclose(s.values[ch.AX], 2 * s.t, abs_tol=1e-9)


def test_silent_channel_becomes_nan_and_slow_channel_is_held():
    stale = np.full(ch.N, 0.05)
    stale[ch.SPEED] = 0.5
    al = Aligner(stale_after=stale)
    frames = []
    for k in range(300):
        t = k * 0.01
        pairs = [(ch.YAW, 0.1)] if t < 1.0 else []  # yaw stops at 1 s
        pairs.append((ch.AX, 1.0))
        if k % 10 == 0:
            pairs.append((ch.SPEED, 10.0))
        frames.append((t, pairs))
    samples = feed(al, frames)
    early = [s for s in samples if 0.2 < s.t < 0.9]
    late = [s for s in samples if s.t > 1.2]
    assert all(s.values[ch.YAW] == 0.1 for s in early)
    assert all(math.isnan(s.values[ch.YAW]) for s in late)
    assert all(s.values[ch.SPEED] == 10.0 for s in late)
    # GNSS is fresh once per 100 ms, never twice for the same value
    fresh = [s.t for s in samples if s.fresh[ch.SPEED]]
    assert len(fresh) in (len(samples) // 10, len(samples) // 10 + 1)


def test_backwards_time_is_rejected_and_forward_jump_restarts_the_grid():
    al = Aligner()
    feed(al, [(k * 0.01, [(ch.AX, 1.0)]) for k in range(50)])
    assert al.push(0.1, [(ch.AX, 5.0)]) == []
    assert al.clock_backwards == 1
    out = feed(al, [(100.0 + k * 0.01, [(ch.AX, 1.0)]) for k in range(10)])
    assert al.clock_jumps == 1
    assert out and out[0].gap
    steps = np.diff([s.t for s in out])
    assert np.all(steps > 0) and np.all(steps < 0.011)  # no huge step ever reaches a filter
    assert al.push(float("nan"), [(ch.AX, 1.0)]) == []


def test_ring_memory_is_flat():
    ring = SampleRing(capacity=10)
    al = Aligner()
    for s in feed(al, [(k * 0.01, [(ch.AX, float(k))]) for k in range(100)]):
        ring.append(s)
    t, v = ring.latest()
    assert len(t) == 10 and ring.values.shape == (10, ch.N)
    assert np.all(np.diff(t) > 0)
