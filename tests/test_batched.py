"""The estimator a block at a time (TwoStageEstimator.handle_block, core.batched) against the
estimator a sample at a time (handle), the reference: the same result to the last bit."""

import dataclasses
import gzip
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vdp.buffer import SampleRing
from vdp.core import batched, learner
from vdp.core.estimator import EstimatorConfig, TwoStageEstimator
from vdp.core.learner import Stage1, Stage2
from vdp.core.sample import Sample
from vdp.io import bulk
from vdp.io.bulk import replay_log
from vdp.pipeline import Pipeline
from vdp.profile import load_profile
from vdp.sim.run import simulate, write_log

pytestmark = pytest.mark.skipif(batched.kernel() is None, reason="numba is not installed: no compiled pass")


@pytest.fixture(scope="module")
def paper(repo_root):
    return load_profile(repo_root / "profiles" / "paper.toml")


@pytest.fixture(scope="module")
def drive(tmp_path_factory, paper):
    """The city drive with unrelated ids: windows of both stages open and close, the hand-over between."""
    d = tmp_path_factory.mktemp("batched")
    frames, _ = simulate(paper, "city", seed=5, noise="realistic", extra_ids=3, extra_rate=50.0)
    write_log(frames, d / "drive.log")
    return d / "drive.log"


def supervisor_state(pipe):
    su = pipe.estimator.supervisor
    return (
        repr(su.blockers), [w.as_dict() for w in su.windows], su.window_count, su.active, su.reason,
        su.observed, su.excited, su._ax_m, su._ax_sq, su._d_m, su._d_sq, su._yaw_sq,
        [(g.open, g.since) for g in su._gates.values()],
    )  # fmt: skip


def stage1_state(l1):
    f = l1.filter
    return (
        l1.samples, l1.gated, l1.reseeds, l1._since_batch, l1._since_far, l1.t_last, l1._acc,
        [a.tolist() for a in l1._blocks.arrays()], repr(l1.fit), repr(l1._good), l1.theta.tolist(),
        None if f is None else (f._f.x.tolist(), f._f.P.tolist(), None if f._f.y is None else f._f.y.tolist()),
    )  # fmt: skip


def stage2_state(l2):
    f = l2.filter
    cons = [(c.n, c.nis, c.rows, c.e2, c.ee, c.ne, c._e, list(c._recent))
            for c in (l2.window, l2.total, l2.roll_window, l2.roll_total)]  # fmt: skip
    ex = l2._excite
    return (
        l2.samples, l2.updates, l2.roll_updates, l2.roll_info, l2._info_window, l2.restarts, l2.t_last, l2._us, cons,
        None if ex is None else (ex.phi, ex.w, ex.chi, ex.chi_d, ex.t, ex.u),
        [[tuple(float(v) for v in row) for row in w] for w in l2.check.record.windows], l2.check.record.added,
        None if f is None else (f._f.x.tolist(), f._f.P.tolist(), f._f.y.tolist(), f._f.S.tolist()),
        l2.theta.tolist(), l2.theta_P.tolist(), repr(l2._good),
    )  # fmt: skip


def state(pipe):
    """What a replay leaves that a reader or a live service could see."""
    e = pipe.estimator
    sp, gy = e.speed, e.gyro_bias
    return {
        "stage2": stage2_state(e.s2["ukf"]),
        "supervisor": supervisor_state(pipe),
        "stage1": stage1_state(e.s1["ukf"]),
        "speed": (sp.v, sp.p_vv, sp.p_vb, sp.p_bb, sp.bias, sp.t, sp.a_prev),
        "gyro": (gy.yaw, gy.roll, gy.n, gy.t),
        "handover_t": e.handover_t,
        "clock": (e.t, e._stage),
        "samples": pipe.samples,
        "ring": (pipe.ring.count, pipe.ring.t.tolist(), pipe.ring.values.tolist()),
    }


def replay_both(path, profile, monkeypatch):
    """(per sample, a block at a time): (document, state) of each, and how many blocks went by
    the compiled pass with the hand-over inside one."""
    cfg = EstimatorConfig(baseline=False, trace_len=0)
    handed, calls, stepped = [], [], {1: [], 2: []}
    visit, steps1, steps2 = TwoStageEstimator._visit, Stage1.steps, Stage2.steps

    def spy(steps, stage):
        def spy_steps(self, T, Y, D, G, a, b):
            r = steps(self, T, Y, D, G, a, b)
            stepped[stage].append(r - a)
            return r

        return spy_steps

    def spy_visit(self, *a):
        i = visit(self, *a)
        handed.append(i)
        return i

    def spy_handle(self, t, s):
        calls.append(t)
        return handle(self, t, s)

    handle = TwoStageEstimator.handle
    monkeypatch.setattr(TwoStageEstimator, "_visit", spy_visit)
    monkeypatch.setattr(TwoStageEstimator, "handle", spy_handle)
    monkeypatch.setattr(Stage1, "steps", spy(steps1, 1))
    monkeypatch.setattr(Stage2, "steps", spy(steps2, 2))
    out = []
    for is_bulk in (False, True):
        calls.clear()
        doc, pipe = replay_log(path, lambda: Pipeline(profile, cfg), bulk=is_bulk, channel=profile.bus_channel)
        doc = json.loads(json.dumps(doc.to_dict()))
        for k in ("wall_s", "realtime_factor"):
            doc["log"].pop(k)
        out.append((doc, state(pipe), len(calls)))
    (a, sa, na), (b, sb, nb) = out
    assert na == sa["samples"] and nb == 0  # the reference took every sample one by one, the block path none
    if sa["stage2"][1]:  # stage 2 stepped: most of its samples by the compiled steps
        assert sum(stepped[2]) > 0.8 * sa["stage2"][0]
    s1 = pipe.estimator.s1["ukf"]
    if s1.samples > 500 and sa["handover_t"] is not None:  # stage 1 after the hand-over: by the compiled steps too
        assert sum(stepped[1]) > 0.5 * s1.samples
    return (a, sa), (b, sb), [i for i in handed if i is not None]


def test_block_pass_gives_the_per_sample_result(drive, paper, monkeypatch):
    monkeypatch.setattr(bulk, "BLOCK", 1 << 16)  # many blocks: windows and the hand-over cross their ends
    (a, sa), (b, sb), handed = replay_both(drive, paper, monkeypatch)
    assert b == a and sb == sa
    assert a["parameters"]["l_f"]["status"] == "converged"
    assert a["parameters"]["C_alpha"]["value"] is not None  # stage 2 ran
    assert len(handed) == 1 and handed[0] > 0  # l_f became known inside a block: the pass ran again
    assert len(sa["supervisor"][1]) > 4  # windows of both stages


def test_windows_that_diverge_and_last_good_copies_inside_the_compiled_steps(drive, paper, monkeypatch):
    """A window diverging, and the last-good copies, are the learner's own step: the compiled steps
    stop before such a sample and leave nothing of it taken.  Made frequent here."""
    monkeypatch.setattr(learner, "DIVERGED_NIS", 0.1)
    (a, sa), (b, sb), _ = replay_both(drive, paper, monkeypatch)
    assert sa["stage2"][5] > 3  # windows restarted
    assert b == a and sb == sa


def test_a_gap_a_wheel_reference_and_a_profile_l_f(drive, paper, repo_root, tmp_path, monkeypatch):
    lines = drive.read_bytes().splitlines(keepends=True)
    half = len(lines) // 2
    shifted = []
    for ln in lines[half:]:  # 5 s of silence: the grid restarts, the speed filter resets
        ts, rest = ln.split(b" ", 1)
        shifted.append(b"(%.6f) " % (float(ts[1:-1]) + 5.0) + rest)
    gap = tmp_path / "gap.log.gz"
    gap.write_bytes(gzip.compress(b"".join(lines[:half] + shifted)))
    (a, sa), (b, sb), _ = replay_both(gap, paper, monkeypatch)
    assert b == a and sb == sa and a["log"]["clock"]["jumps"] == 1

    # l_f measured: the hand-over at the first sample, stage 2 from the start
    known = dataclasses.replace(paper, vehicle=dataclasses.replace(paper.vehicle, l_f=1.4, l_f_std=0.01))
    (a, sa), (b, sb), _ = replay_both(drive, known, monkeypatch)
    assert b == a and sb == sa and sa["handover_t"] is not None

    # no GNSS: the free-rolling axle is the speed reference (a wheel_ref speed filter).  The golf's
    # log goes through the per-frame decoder, so its samples are handed to the estimator directly
    golf = load_profile(repo_root / "profiles" / "vw_golf_mk7.toml")
    assert golf.speed_reference == "wheels"
    frames, _ = simulate(golf, "paper", seed=2, noise="realistic", duration=60.0)
    write_log(frames, tmp_path / "golf.log")
    cfg = EstimatorConfig(baseline=False, trace_len=0)
    samples = []
    pipe = Pipeline(golf, cfg)
    pipe.tap(samples.append)
    replay_log(tmp_path / "golf.log", lambda: pipe, bulk=False)
    one, blocks = Pipeline(golf, cfg).estimator, Pipeline(golf, cfg).estimator
    assert one.cfg.speed.wheel_ref == "rear" and blocks.batchable()
    for s in samples:
        one.handle(s.t, s)
    for k in range(0, len(samples), 777):  # blocks of any length: the aligner's split is not special
        part = samples[k : k + 777]
        T = np.array([s.t for s in part])
        Y, F, A = (np.array([getattr(s, f) for s in part]) for f in ("values", "fresh", "age"))
        blocks.handle_block(T, Y, F, A, part[0].gap)
    assert repr(blocks.snapshot()) == repr(one.snapshot())
    assert (blocks.speed.v, blocks.speed.bias, blocks.gyro_bias.yaw) == (one.speed.v, one.speed.bias, one.gyro_bias.yaw)
    assert blocks.handover_t == one.handover_t is not None


def test_the_pass_words_reasons_as_the_supervisor():
    from vdp.core import supervisor as sup

    copies = (batched._SPEED_LOW, batched._STEERING, batched._YAWING, batched._LITTLE_AX, batched._LITTLE_STEER,
              batched._NOT_CONSTANT, batched._MISSING, batched._WAITING)  # fmt: skip
    assert copies == (sup.SPEED_LOW, sup.STEERING, sup.YAWING, sup.LITTLE_AX, sup.LITTLE_STEER, sup.NOT_CONSTANT,
                      sup.MISSING, sup.WAITING)  # fmt: skip
    little = [c for c in range(1, batched.N_CODES) if c != sup.MISSING and sup.REASONS[c].startswith("little")]
    assert little == [sup.LITTLE_AX, sup.LITTLE_STEER]  # the ones Supervisor.update does not shut at once


def test_a_kept_trace_or_a_coarse_gnss_goes_sample_by_sample(paper, repo_root):
    assert Pipeline(paper, EstimatorConfig(trace_len=0)).estimator.batchable()
    assert not Pipeline(paper, EstimatorConfig()).estimator.batchable()  # trace rows come from every sample
    ford = load_profile(repo_root / "profiles" / "ford_escape_2020.toml")  # whole mph: the rounding state
    assert not Pipeline(ford, EstimatorConfig(trace_len=0)).estimator.batchable()


@settings(max_examples=60, deadline=None)
@given(
    cap=st.integers(1, 12),
    sizes=st.lists(st.integers(0, 30), min_size=1, max_size=6),
)
def test_ring_extend_is_append_on_each(cap, sizes):
    one, many = SampleRing(cap), SampleRing(cap)
    k = 0
    for n in sizes:
        T = np.arange(k, k + n, dtype=float)
        Y = np.outer(T, np.ones(one.values.shape[1])) + np.arange(one.values.shape[1])
        for i in range(n):
            one.append(Sample(T[i], tuple(Y[i]), (), ()))
        many.extend(T, Y)
        k += n
    assert many.count == one.count
    np.testing.assert_array_equal(many.t, one.t)
    np.testing.assert_array_equal(many.values, one.values)
