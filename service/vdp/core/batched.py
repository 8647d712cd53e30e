"""The estimator's work before the learners, compiled over a block of samples: a replay's fast path.

Per aligned sample, :meth:`TwoStageEstimator.handle` runs the speed filter (core.speed), the
gyro offsets (estimator.GyroBias) and the gating supervisor (core.supervisor) in Python:
~7 us a sample, a fifth of a replay's CPU once the reader is fast.  None of them depends on
the learners, only on the samples and on whether l_f is known (the hand-over), so a replay
can run them over a whole block in one compiled loop (:func:`prepass`) and visit in Python
only the samples a learner takes.  The loop repeats those classes' operations in their order,
so it gives their numbers to the last bit; ``tests/test_batched.py`` holds the two paths to
the same estimates, supervisor state and windows, and the speed filter's and the supervisor's
own tests run on the classes, the reference.  A change to either must be followed here.

The learners' own steps over an open window's run of samples are compiled as well
(``core.kernels.lat_run`` and ``lon_run``, called by ``learner.Stage2.steps`` and
``Stage1.steps``): each stops before the first sample that needs the learner's Python step
(a window that ends, restarts or diverges, a failed step, a batch check or a last-good copy
due), so the rare paths are written once.  With both, an hour of a busy bus replays in ~2.8 s
of CPU where it took ~5.8 s sample by sample (BENCHMARKS.md, "A replay a block at a time").

The state crosses over as one float array (:func:`pack`, :func:`unpack`): the Python objects
stay the state's owners, so a live service and a replay can hand a drive to each other.
Without numba, with the compiled steps off (LearnerConfig.compiled) or with a coarse GNSS's
rounding-error filter, the estimator runs per sample.
"""

from __future__ import annotations

import math

import numpy as np

from .. import channels as ch
from . import supervisor as sup
from .speed import SpeedFilter

# the state array: the speed filter, the gyro offsets, the supervisor (NaN stands for None)
(V, P_VV, P_VB, P_BB, BIAS, S_T, A_PREV, G_YAW, G_ROLL, G_N, G_T, U_T, OBSERVED, EXC1, EXC2, AX_M, AX_SQ, D_M, D_SQ,
 YAW_SQ, OPEN1, SINCE1, OPEN2, SINCE2, K_DT, K_AX, K_STEER) = range(27)  # fmt: skip
N_STATE = 27
N_CODES = len(sup.REASONS) + 1  # reason codes 0 (none) to supervisor.WAITING, then the gates' (GATED + k)
# the parameters array
(ACCEL_NOISE, BIAS_WALK, GNSS_NOISE, MAX_GAP, WHEEL_REF, WHEEL_NOISE, BRAKE_MAX, RADIUS, GYRO_TAU, V_MIN,
 DELTA_MAX_1, YAW_MAX_1, AX_STD_MIN, AX_MEAN_MAX_2, DELTA_STD_MIN_2, YAW_RMS_MIN_2, TAU_AX, TAU_STEER, T_ON,
 T_OFF) = range(20)  # fmt: skip
# the supervisor's reason codes, as copies: numba freezes a global into the cached code and invalidates
# that cache only when this file changes (tests/test_batched.py holds them equal)
_SPEED_LOW, _STEERING, _YAWING, _LITTLE_AX, _LITTLE_STEER, _NOT_CONSTANT, _MISSING, _WAITING = range(1, 9)
_GATED, _SHUTS = _WAITING, 6  # supervisor.GATED, gates.SHUTS: gate k's reason code is _GATED + k
# channel indices, passed in (numba would freeze module globals into its cache)
CHANNELS = np.array(
    [ch.WS_FL, ch.WS_FR, ch.WS_RL, ch.WS_RR, ch.T_F, ch.T_R, ch.DELTA, ch.AX, ch.YAW, ch.ROLL, ch.SPEED]
)
WS_FL, WS_FR, WS_RL, WS_RR, T_F, T_R, DELTA, AX, YAW, ROLL, SPEED = range(11)


def _speed_reset(st):
    st[V] = math.nan
    st[P_VV] = 0.0
    st[P_VB] = 0.0
    st[S_T] = math.nan
    st[A_PREV] = math.nan


def _speed_step(st, p, t, a_x, gnss, has_gnss, noise):
    """SpeedFilter.step; ``has_gnss`` False for None, ``noise`` NaN for the default."""
    r = p[GNSS_NOISE] if math.isnan(noise) else noise
    no_t = math.isnan(st[S_T])
    dt = 0.0 if no_t else t - st[S_T]
    if not math.isfinite(a_x) or no_t or dt <= 0 or dt > p[MAX_GAP]:
        _speed_reset(st)
        st[S_T] = t if math.isfinite(a_x) else math.nan
    elif math.isfinite(st[V]):
        a_mean = 0.5 * (a_x + st[A_PREV]) if math.isfinite(st[A_PREV]) else a_x
        st[V] += dt * (a_mean - st[BIAS])
        an = p[ACCEL_NOISE] * dt
        p_vv = st[P_VV] - 2 * dt * st[P_VB] + dt * dt * st[P_BB] + an * an
        p_vb = st[P_VB] - dt * st[P_BB]
        st[P_VV] = p_vv
        st[P_VB] = p_vb
        st[P_BB] += p[BIAS_WALK] * p[BIAS_WALK] * dt
        st[S_T] = t
    st[A_PREV] = a_x
    if not has_gnss or not math.isfinite(gnss):
        return
    if not math.isfinite(st[V]):
        st[V] = gnss
        st[P_VV] = r * r
        st[P_VB] = 0.0
        st[S_T] = t
        return
    s = st[P_VV] + r * r
    k_v = st[P_VV] / s
    k_b = st[P_VB] / s
    e = gnss - st[V]
    st[V] += k_v * e
    st[BIAS] += k_b * e
    p_vv, p_vb, p_bb = st[P_VV], st[P_VB], st[P_BB]
    st[P_VV] = p_vv - k_v * p_vv
    st[P_VB] = p_vb - k_v * p_vb
    st[P_BB] = p_bb - k_b * p_vb


def _hyst(st, i_open, i_since, t, ok, hard, p):
    """Supervisor._hyst on the state array's gate (open: 0/1, since: NaN for None)."""
    is_open = st[i_open] != 0.0
    if ok == is_open:
        st[i_since] = math.nan
        return is_open
    if not ok and hard:
        st[i_open] = 0.0
        st[i_since] = math.nan
        return False
    if math.isnan(st[i_since]) or t < st[i_since]:
        st[i_since] = t
    if t - st[i_since] >= (p[T_ON] if ok else p[T_OFF]):
        st[i_open] = 1.0 if ok else 0.0
        st[i_since] = math.nan
    return st[i_open] != 0.0


def _missing(y, needs):
    for i in needs:  # noqa: SIM110 (numba compiles no generator inside any())
        if not math.isfinite(y[i]):
            return True
    return False


def _hard(code):
    """A reason that shuts a window at once (not a little excitation, which the hysteresis waits out)."""
    return code != 0 and code != _LITTLE_AX and code != _LITTLE_STEER  # noqa: PLR1714 (numba: no set)


def _blocked(blk, first, stage, code, dt, i):
    if first[stage, code] == -1:  # (-2: the reason was in the dict before the block)
        first[stage, code] = i
    blk[stage, code] += dt


def _prepass(T, Y, F, A, gap, gate, st, p, c, needs1, needs2, done_from, blk, first, out, stage):
    """Speed filter, gyro offsets and supervisor over the block's samples, in place on ``st``
    and ``blk`` (the supervisor's blockers, seconds per stage and code; ``first``: the sample
    where a code absent before first blocked); ``out`` gets v_x, its std, the a_x bias and
    the two gyro offsets per sample, ``stage`` the open window's (0: none).  Samples from
    ``done_from`` on see l_f known; ``gate`` holds each sample's gate code (core.gates).  Returns
    the reason codes of the last sample."""
    n = T.shape[0]
    r1 = r2 = 0
    for i in range(n):
        t = T[i]
        y = Y[i]
        # -- TwoStageEstimator._speed
        ax = y[c[AX]]
        has = False
        gnss = 0.0
        if F[i, c[SPEED]] and math.isfinite(y[c[SPEED]]):
            has = True
            gnss = y[c[SPEED]] + (ax * A[i, c[SPEED]] if math.isfinite(ax) else 0.0)
        noise = math.nan
        if not has and p[WHEEL_REF] != 0.0:
            front = p[WHEEL_REF] == 1.0
            left = y[c[WS_FL]] if front else y[c[WS_RL]]
            right = y[c[WS_FR]] if front else y[c[WS_RR]]
            tq = y[c[T_F]] if front else y[c[T_R]]
            if math.isfinite(left) and math.isfinite(right) and not (math.isfinite(tq) and tq < -p[BRAKE_MAX]):
                has = True
                gnss = 0.5 * (left + right) * p[RADIUS]
            noise = p[WHEEL_NOISE]
        if gap[i]:
            _speed_reset(st)
        _speed_step(st, p, t, ax, gnss, has, noise)
        v = st[V]
        out[i, 0] = v
        out[i, 1] = math.sqrt(st[P_VV]) if math.isfinite(v) else math.nan
        out[i, 2] = st[BIAS]
        # -- GyroBias.update
        d, yaw, roll = y[c[DELTA]], y[c[YAW]], y[c[ROLL]]
        if math.isfinite(d) and math.isfinite(yaw) and abs(d) < p[DELTA_MAX_1] and abs(yaw) < p[YAW_MAX_1]:
            dt = 0.01 if math.isnan(st[G_T]) else min(max(t - st[G_T], 0.0), 0.1)
            k = max(dt / p[GYRO_TAU], 1.0 / (st[G_N] + 1))
            st[G_YAW] += k * (yaw - st[G_YAW])
            if math.isfinite(roll):
                st[G_ROLL] += k * (roll - st[G_ROLL])
            st[G_N] += 1
        st[G_T] = t
        out[i, 3] = st[G_YAW]
        out[i, 4] = st[G_ROLL]
        # -- Supervisor.update
        dt = 0.01 if math.isnan(st[U_T]) or gap[i] else min(max(t - st[U_T], 0.0), 0.1)
        st[U_T] = t
        if dt != st[K_DT]:
            st[K_DT] = dt
            st[K_AX] = 1.0 - math.exp(-dt / p[TAU_AX])
            st[K_STEER] = 1.0 - math.exp(-dt / p[TAU_STEER])
        k_ax, k_steer = st[K_AX], st[K_STEER]
        if math.isfinite(ax):
            st[AX_M] += k_ax * (ax - st[AX_M])
            st[AX_SQ] += k_ax * (ax * ax - st[AX_SQ])
        if math.isfinite(d) and math.isfinite(yaw):
            st[D_M] += k_steer * (d - st[D_M])
            st[D_SQ] += k_steer * (d * d - st[D_SQ])
            st[YAW_SQ] += k_steer * (yaw * yaw - st[YAW_SQ])
        speed = v if math.isfinite(v) else y[c[SPEED]]
        if not math.isfinite(speed):
            speed = 0.5 * (y[c[WS_RL]] + y[c[WS_RR]]) * p[RADIUS]
        # Supervisor._drive1, _drive2
        if not speed > p[V_MIN]:
            d1 = _SPEED_LOW
        elif abs(d) >= p[DELTA_MAX_1]:
            d1 = _STEERING
        elif abs(yaw) >= p[YAW_MAX_1]:
            d1 = _YAWING
        elif math.sqrt(max(st[AX_SQ] - st[AX_M] * st[AX_M], 0.0)) < p[AX_STD_MIN]:
            d1 = _LITTLE_AX
        else:
            d1 = 0
        d_std = math.sqrt(max(st[D_SQ] - st[D_M] * st[D_M], 0.0))
        if d_std < p[DELTA_STD_MIN_2] and math.sqrt(max(st[YAW_SQ], 0.0)) < p[YAW_RMS_MIN_2]:
            d2 = _LITTLE_STEER
        elif not speed > p[V_MIN]:
            d2 = _SPEED_LOW
        elif abs(st[AX_M]) > p[AX_MEAN_MAX_2]:
            d2 = _NOT_CONSTANT
        else:
            d2 = 0
        g = gate[i]
        if 0 < g <= _SHUTS:  # Supervisor.update: a gate shuts both windows, unless the driving already does
            if d1 == 0 or d1 == _LITTLE_AX:  # noqa: PLR1714 (numba: no set)
                d1 = _GATED + g
            if d2 == 0 or d2 == _LITTLE_STEER:  # noqa: PLR1714
                d2 = _GATED + g
        st[OBSERVED] += dt
        if d1 == 0:
            st[EXC1] += dt
        else:
            _blocked(blk, first, 0, d1, dt, i)
        if d2 == 0:
            st[EXC2] += dt
        else:
            _blocked(blk, first, 1, d2, dt, i)
        r1 = _MISSING if _missing(y, needs1) else d1
        if i < done_from:
            r2 = _WAITING
        else:
            r2 = _MISSING if _missing(y, needs2) else d2
        o1 = _hyst(st, OPEN1, SINCE1, t, r1 == 0, _hard(r1), p)
        o2 = _hyst(st, OPEN2, SINCE2, t, r2 == 0, _hard(r2), p)
        stage[i] = 2 if o2 else 1 if o1 else 0
    return r1, r2


_compiled: list = []  # [the compiled _prepass], or [None] without numba


def kernel():
    """The compiled pass (core.batched_compiled, made at first use or loaded from numba's cache
    beside this file); None without numba."""
    if not _compiled:
        try:
            from .batched_compiled import prepass
        except ImportError:
            prepass = None
        if not _compiled:  # (another thread may have set it meanwhile: the same function)
            _compiled.append(prepass)
    return _compiled[0]


def warm() -> None:
    """Compile (or load from the cache) the pass once, before a replay needs it."""
    if kernel() is None:
        return
    from .estimator import EstimatorConfig
    from .supervisor import Supervisor

    n = 3
    T = np.arange(n) * 0.02
    Y = np.zeros((n, ch.N))
    F, A = np.ones((n, ch.N), dtype=bool), np.zeros((n, ch.N))
    blk, first = blockers(Supervisor())
    need = np.arange(2, dtype=np.int64)
    p = params(EstimatorConfig(), type("V", (), {"wheel_radius": 0.3}), 30.0)
    kernel()(T, Y, F, A, np.zeros(n, dtype=bool), np.zeros(n, dtype=np.int64), np.zeros(N_STATE), p, CHANNELS,
             need, need, 0, blk, first, np.empty((n, 5)), np.empty(n, dtype=np.int64))  # fmt: skip
    Supervisor().gates.block(T, Y, np.zeros(n, dtype=bool))  # (compiles core.gates' pass too)


# -- the state and parameters, from and to the estimator's objects ------------------


def batchable(speed) -> bool:
    """Whether this speed filter is the one the pass repeats (a coarse GNSS's is not)."""
    return type(speed) is SpeedFilter and kernel() is not None


def params(cfg, vehicle, gyro_tau: float) -> np.ndarray:
    """The parameters array of an EstimatorConfig (its speed and gate configs) for ``vehicle``."""
    s, g = cfg.speed, cfg.gate
    ref = {None: 0.0, "front": 1.0}.get(s.wheel_ref, 2.0)
    p = np.zeros(20)
    p[[ACCEL_NOISE, BIAS_WALK, GNSS_NOISE, MAX_GAP, WHEEL_REF, WHEEL_NOISE, BRAKE_MAX, RADIUS, GYRO_TAU]] = (
        s.accel_noise, s.bias_walk, s.gnss_noise, s.max_gap, ref, s.wheel_noise, s.brake_torque_max,
        vehicle.wheel_radius, gyro_tau,
    )  # fmt: skip
    p[[V_MIN, DELTA_MAX_1, YAW_MAX_1, AX_STD_MIN, AX_MEAN_MAX_2, DELTA_STD_MIN_2, YAW_RMS_MIN_2]] = (
        g.v_min, g.delta_max_1, g.yaw_max_1, g.ax_std_min, g.ax_mean_max_2, g.delta_std_min_2, g.yaw_rms_min_2,
    )  # fmt: skip
    p[[TAU_AX, TAU_STEER, T_ON, T_OFF]] = (g.tau_ax, g.tau_steer, g.t_on, g.t_off)
    return p


def _none(x: float | None) -> float:
    return math.nan if x is None else x


def _back(x: float) -> float | None:
    return None if math.isnan(x) else x


def pack(speed, gyro, su) -> np.ndarray:
    """The state array of a SpeedFilter, a GyroBias and a Supervisor."""
    st = np.empty(N_STATE)
    g1, g2 = su._gates[1], su._gates[2]
    st[:] = (
        speed.v, speed.p_vv, speed.p_vb, speed.p_bb, speed.bias, _none(speed.t), speed.a_prev,
        gyro.yaw, gyro.roll, gyro.n, _none(gyro.t),
        _none(su._t), su.observed, su.excited[1], su.excited[2], su._ax_m, su._ax_sq, su._d_m, su._d_sq, su._yaw_sq,
        float(g1.open), _none(g1.since), float(g2.open), _none(g2.since), su._dt, su._k[0], su._k[1],
    )  # fmt: skip
    return st


def unpack(st: np.ndarray, speed, gyro, su) -> None:
    """Set the three objects' state from the array (pack's inverse)."""
    x = st.tolist()
    speed.v, speed.p_vv, speed.p_vb, speed.p_bb, speed.bias = x[V], x[P_VV], x[P_VB], x[P_BB], x[BIAS]
    speed.t, speed.a_prev = _back(x[S_T]), x[A_PREV]
    gyro.yaw, gyro.roll, gyro.n, gyro.t = x[G_YAW], x[G_ROLL], int(x[G_N]), _back(x[G_T])
    su._t, su.observed, su.excited[1], su.excited[2] = _back(x[U_T]), x[OBSERVED], x[EXC1], x[EXC2]
    su._ax_m, su._ax_sq, su._d_m, su._d_sq, su._yaw_sq = x[AX_M], x[AX_SQ], x[D_M], x[D_SQ], x[YAW_SQ]
    g1, g2 = su._gates[1], su._gates[2]
    g1.open, g1.since, g2.open, g2.since = x[OPEN1] != 0.0, _back(x[SINCE1]), x[OPEN2] != 0.0, _back(x[SINCE2])
    su._dt, su._k = x[K_DT], (x[K_AX], x[K_STEER])


def blockers(su) -> tuple[np.ndarray, np.ndarray]:
    """(seconds, first) arrays of the supervisor's blockers: per stage and reason code."""
    blk = np.zeros((2, N_CODES))
    first = np.full((2, N_CODES), -1, np.int64)
    for stage in (1, 2):
        for why, sec in su.blockers[stage].items():
            code = _code(su, why)
            blk[stage - 1, code], first[stage - 1, code] = sec, -2
    return blk, first


def _code(su, why: str) -> int:
    for code in sup.REASONS:
        if su.why(code) == why:
            return code
    raise ValueError(f"not a driving reason: {why!r}")


def set_blockers(su, blk: np.ndarray, first: np.ndarray) -> None:
    """Write the pass's blocker seconds back, new reasons in the order they first blocked."""
    for stage in (1, 2):
        b = su.blockers[stage]
        new = [(int(first[stage - 1, code]), code) for code in range(1, N_CODES) if first[stage - 1, code] >= 0]
        for _, code in sorted(new):
            b[su.why(code)] = 0.0  # inserted where the per-sample path would have first
        for why in b:
            b[why] = float(blk[stage - 1, _code(su, why)])


def windows(su, T: np.ndarray, stage: np.ndarray) -> None:
    """The supervisor's windows after the block: opened, closed and counted as its update does."""
    cut = np.flatnonzero(np.diff(stage)) + 1
    starts = [0, *cut.tolist()]
    ends = [*cut.tolist(), len(stage)]
    for a, b, sg in zip(starts, ends, stage[starts].tolist()):
        new = sg or None
        if new != su.active:
            t = float(T[a])
            if su.active is not None:
                su.windows[-1].end = t
            if new is not None:
                su.windows.append(sup.Window(new, t))
                su.window_count += 1
            su.active = new
        if new is not None:
            su.windows[-1].samples += b - a


def reason(su, code: int, y, needs) -> str | None:
    """The supervisor's reason for a code at the sample ``y`` (a missing channel's list named)."""
    if code == 0:
        return None
    if code == sup.MISSING:
        return su._missing(y, needs)
    return su.why(code)
