"""core.passes' steps, each written once: compiled (core.prepass, numba) on an array against the
plain Python function on a list (the per-sample path's), on the same inputs, to the bit."""

import math

import numpy as np
import pytest

from vdp import channels as ch
from vdp.core import passes
from vdp.core.estimator import GyroBias
from vdp.core.sample import Sample
from vdp.core.speed import SpeedConfig, SpeedFilter
from vdp.core.supervisor import GateConfig

prepass = pytest.importorskip("vdp.core.prepass", reason="numba is not installed: nothing compiled")


def same(a, b) -> bool:
    """The same floats to the bit (a NaN matches a NaN: numba's and Python's may differ in payload)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    nan = np.isnan(a)
    return bool(np.array_equal(nan, np.isnan(b)) and np.array_equal(a[~nan].view(np.int64), b[~nan].view(np.int64)))


def params() -> list[float]:
    p = [math.nan] * passes.N_PARAMS
    passes.speed_params(p, SpeedConfig())
    passes.gate_params(p, GateConfig())
    p[passes.GYRO_TAU] = 30.0
    p[passes.WHEELBASE] = 2.5
    return p


def speed_inputs(n: int = 3000, seed: int = 0):
    """(t, a_x, gnss, has, noise, yaw) per step: every branch of the step (a_x missing, time going
    back or leaping past max_gap, a GNSS speed missing or NaN, the wheels' noise, a turn: the yaw
    rate beyond stage 1's limit, or missing) now and then."""
    rng = np.random.default_rng(seed)
    turns = np.random.default_rng(seed + 100)  # (its own draws: the other inputs as they were before turns)
    t, v = 0.0, 10.0
    for k in range(n):
        u = rng.random()
        t += -0.05 if u < 0.01 else 0.5 if u < 0.02 else 0.02
        a = 0.3 * math.sin(0.01 * k) + 0.05 * rng.standard_normal()
        v += 0.02 * a
        ax = math.nan if rng.random() < 0.01 else a + 0.1
        has = k % 5 == 0 or rng.random() < 0.01
        gnss = (math.nan if rng.random() < 0.05 else v + 0.05 * rng.standard_normal()) if has else 0.0
        noise = 0.08 if rng.random() < 0.2 else math.nan
        yaw = (0.3 if math.sin(0.013 * k) > 0.7 else 0.0) + 0.01 * turns.standard_normal()
        yield t, ax, gnss, has, noise, math.nan if turns.random() < 0.01 else yaw


def test_the_turn_compiled_is_the_python_one():
    assert prepass._turning.py_func is passes.turning
    p = params()
    pa = np.array(p)
    ys = [-0.4, -0.1, -0.05, 0.0, 0.05, 0.1, 0.3, math.nan, math.inf, p[passes.YAW_MAX_1], -p[passes.YAW_MAX_1]]
    for yaw in ys:
        assert same(passes.turning(p, yaw), prepass._turning(pa, yaw)), yaw
    assert passes.turning(p, 0.3) == 0.3 * 0.3 * 2.5 and passes.turning(p, math.nan) == 0.0


def test_the_speed_step_compiled_is_the_python_one():
    assert prepass._speed_step.py_func.__code__ is passes.speed_step.__code__  # one source, compiled
    p = params()
    py, jit = passes.new_state(), np.array(passes.new_state())
    py[passes.BIAS] = jit[passes.BIAS] = 0.0
    py[passes.P_BB] = jit[passes.P_BB] = 0.05**2
    passes.speed_reset(py)
    prepass._speed_reset(jit)
    assert same(py, jit)
    pa = np.array(p)
    ready = resets = 0
    held = 0
    for k, (t, ax, gnss, has, noise, yaw) in enumerate(speed_inputs()):
        if k % 700 == 699:  # a gap in the grid: the estimator resets the filter
            passes.speed_reset(py)
            prepass._speed_reset(jit)
        turn = passes.turning(p, yaw)
        bias = py[passes.BIAS]
        passes.speed_step(py, p, t, ax, gnss, has, noise, turn)
        prepass._speed_step(jit, pa, t, ax, gnss, has, noise, prepass._turning(pa, yaw))
        assert same(py, jit), k
        ready += math.isfinite(py[passes.V])
        resets += math.isnan(py[passes.V])
        held += turn > 0.0 and has and math.isfinite(gnss) and py[passes.BIAS] == bias
    assert ready > 2000 and resets > 20  # (the inputs met both: a filter running, and restarting)
    assert held > 50  # (and turns: a GNSS speed that left the bias as it was)
    assert py[passes.BIAS] != 0.0 and py[passes.P_BB] != 0.05**2  # the bias learnt


def test_the_speed_filter_steps_on_its_state_list():
    """SpeedFilter is core.passes' step on its list: None for no GNSS or the default noise, and
    the attributes read the list."""
    f, st, p = SpeedFilter(), passes.new_state(), params()
    st[passes.BIAS], st[passes.P_BB] = 0.0, 0.05**2
    passes.speed_reset(st)
    assert same(f.st, st) and f.t is None and not f.ready
    for t, ax, gnss, has, noise, yaw in speed_inputs(500, seed=1):
        turn = passes.turning(p, yaw)
        f.step(t, ax, gnss if has else None, None if math.isnan(noise) else noise, turn)
        passes.speed_step(st, p, t, ax, gnss, has, noise, turn)
        assert same(f.st, st)
    assert f.ready and (f.v, f.bias, f.p_vv, f.t) == (st[passes.V], st[passes.BIAS], st[passes.P_VV], st[passes.S_T])


def gyro_inputs(n: int = 3000, seed: int = 0):
    """(t, delta, yaw, roll) per step: straight driving mostly, now and then a turn beyond
    stage 1's limits, a channel missing, the clock going back or leaping."""
    rng = np.random.default_rng(seed)
    t = 0.0
    for _ in range(n):
        u = rng.random()
        t += -0.05 if u < 0.01 else 0.5 if u < 0.02 else 0.02
        d, yaw, roll = 0.005 * rng.standard_normal(), 0.003 + 0.01 * rng.standard_normal(), -0.002 + 0.01 * rng.random()
        if rng.random() < 0.03:
            d, yaw, roll = (math.nan, yaw, roll) if rng.random() < 0.5 else (d, yaw, math.nan)
        yield t, d, yaw, roll


def test_the_gyro_offsets_compiled_are_the_python_ones():
    assert prepass._gyro_update.py_func is passes.gyro_update
    p, py = params(), GyroBias().st  # (the class's initial state)
    jit, pa = np.array(py), np.array(p)
    taken = 0
    for k, (t, d, yaw, roll) in enumerate(gyro_inputs()):
        n = py[passes.G_N]
        passes.gyro_update(py, p, t, d, yaw, roll)
        prepass._gyro_update(jit, pa, t, d, yaw, roll)
        assert same(py, jit), k
        taken += py[passes.G_N] > n
    assert 1000 < taken < 3000 and py[passes.G_YAW] != 0.0 and py[passes.G_ROLL] != 0.0  # straight samples only


def test_the_gyro_offsets_step_on_their_state_list():
    g, st, p = GyroBias(), passes.new_state(), params()
    st[passes.G_YAW] = st[passes.G_ROLL] = st[passes.G_N] = 0.0
    assert same(g.st, st) and g.t is None and g.n == 0
    cfg = GateConfig()
    for t, d, yaw, roll in gyro_inputs(500, seed=1):
        y = [math.nan] * (max(ch.DELTA, ch.YAW, ch.ROLL) + 1)
        y[ch.DELTA], y[ch.YAW], y[ch.ROLL] = d, yaw, roll
        out = g.update(Sample(t, tuple(y), (), ()), cfg)
        passes.gyro_update(st, p, t, d, yaw, roll)
        assert same(g.st, st) and out == (st[passes.G_YAW], st[passes.G_ROLL])
    assert g.n == int(st[passes.G_N]) > 400 and g.t == t


def test_the_windows_hysteresis_compiled_is_the_python_one():
    """Both windows through conditions that flicker, hold, fail hard or softly, and a clock that steps back."""
    assert prepass._hyst.py_func is passes.hyst
    rng = np.random.default_rng(2)
    p, py = params(), passes.new_state()
    py[passes.OPEN1] = py[passes.OPEN2] = 0.0
    jit, pa = np.array(py), np.array(p)
    t, opened, closed = 0.0, 0, 0
    ok = [False, False]
    for k in range(4000):
        t += -0.3 if rng.random() < 0.005 else 0.02
        for w, (i_open, i_since) in enumerate(((passes.OPEN1, passes.SINCE1), (passes.OPEN2, passes.SINCE2))):
            if rng.random() < 0.05:  # the condition changes, now and then for a while
                ok[w] = not ok[w]
            hard = rng.random() < 0.3
            was = py[i_open]
            a = passes.hyst(py, i_open, i_since, t, ok[w], hard, p)
            b = prepass._hyst(jit, i_open, i_since, t, ok[w], hard, pa)
            assert a == b and same(py, jit), k
            opened += was == 0.0 and a
            closed += was == 1.0 and not a
    assert opened > 20 and closed > 20


def test_the_supervisors_excitation_compiled_is_the_python_one():
    """A drive through every reason code: slow and fast, straight and turning, a_x still and busy,
    a gate now and then, channels missing, steps of uneven length and gaps."""
    assert prepass._supervise.py_func is passes.supervise
    rng = np.random.default_rng(3)
    p = params()
    p[passes.RADIUS] = 0.3
    py = passes.new_state()
    py[passes.U_T : passes.K_STEER + 1] = [0.0] * (passes.K_STEER + 1 - passes.U_T)
    py[passes.U_T] = py[passes.K_DT] = math.nan
    jit, pa = np.array(py), np.array(p)
    t, seen = 0.0, set()
    for k in range(6000):
        t += 0.02 if k % 11 else float(rng.uniform(-0.01, 0.2))
        phase = (k // 400) % 5  # every 8 s: slow, accelerating, weaving, cruising, braking
        v = 3.0 if phase == 0 else 20.0
        ax = {1: 2.0 * math.sin(0.05 * k), 4: -3.0}.get(phase, 0.05 * rng.standard_normal())
        if phase == 2 and k % 400 >= 200:  # weaving while speeding up
            ax += 1.0
        d = 0.05 * math.sin(0.03 * k) if phase == 2 else 0.002 * rng.standard_normal()
        yaw = 0.3 * math.sin(0.03 * k) if phase == 2 else 0.004 * rng.standard_normal()
        gap, gate = bool(rng.random() < 0.002), int(rng.integers(1, 9)) if rng.random() < 0.02 else 0
        v_x = math.nan if rng.random() < 0.05 else v
        gnss = math.nan if rng.random() < 0.5 else v
        ax, d = (math.nan if rng.random() < 0.01 else x for x in (ax, d))
        args = (t, gap, gate, ax, d, yaw, v_x, gnss, v / 0.3, v / 0.3)
        a = passes.supervise(py, p, *args)
        b = prepass._supervise(jit, pa, *args)
        assert a == b and same(py, jit), k
        seen.update(a[1:])
    assert seen == {0, *range(1, 7), *range(passes._GATED + 1, passes._GATED + passes._SHUTS + 1)}


def test_the_speed_measured_compiled_is_the_python_one():
    """GNSS fresh or stale or missing, a_x missing, each wheel reference, an axle braked or a wheel missing."""
    assert prepass._speed_measured.py_func is passes.speed_measured
    rng = np.random.default_rng(4)
    c = np.array(passes.CHANNELS)
    n = max(passes.CHANNELS) + 1
    seen = set()
    for k in range(3000):
        p = params()
        p[passes.WHEEL_REF], p[passes.BRAKE_MAX] = float(k % 3), 20.0
        p[passes.RADIUS], p[passes.WHEEL_NOISE] = 0.31, 0.07
        y = 20.0 + rng.standard_normal(n)
        y[c[passes.T_F]], y[c[passes.T_R]] = rng.uniform(-40.0, 40.0, 2)
        y[rng.random(n) < 0.1] = math.nan
        fresh, age = rng.random(n) < 0.3, rng.uniform(0.0, 0.1, n)
        a = passes.speed_measured(p, passes.CHANNELS, tuple(y.tolist()), tuple(fresh.tolist()), tuple(age.tolist()))
        b = prepass._speed_measured(np.array(p), c, y, fresh, age)
        assert a[1] == b[1] and same(a[0::2], b[0::2]), k
        seen.add((k % 3, a[1], a[2] == 0.07))
    # GNSS (no noise given), the wheels (theirs), nothing: for each reference
    assert seen >= {(0, True, False), (0, False, False), (1, True, True), (1, False, True), (2, True, True)}


def test_which_reasons_shut_a_window_at_once():
    from vdp.core.supervisor import REASONS, Supervisor

    assert prepass._hard.py_func is passes.is_hard
    codes = range(max(REASONS) + 2)
    assert [prepass._hard(k) for k in codes] == [passes.is_hard(k) for k in codes]
    why = Supervisor().why
    little = [k for k in REASONS if not why(k).hard]
    assert little == [passes._LITTLE_AX, passes._LITTLE_STEER] and not passes.is_hard(0)
