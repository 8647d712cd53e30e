"""core.batched's pass over a block, compiled (numba): imported at its first use, not with the core.

Speed filter (core.speed.SpeedFilter), gyro offsets (estimator.GyroBias) and gating
supervisor (core.supervisor.Supervisor) over a block of samples in one loop, their operations
in their order (see core.batched, which packs their state into the array this works on).
The helpers are compiled inlined into the pass (a call per sample cost too much).  Cached by
core.jit; ``NUMBA_DISABLE_JIT=1`` runs this same source as Python.
"""

from __future__ import annotations

import math

from .batched import (
    _GATED,
    _LITTLE_AX,
    _LITTLE_STEER,
    _MISSING,
    _NOT_CONSTANT,
    _SHUTS,
    _SPEED_LOW,
    _STEERING,
    _WAITING,
    _YAWING,
    A_PREV,
    ACCEL_NOISE,
    AX,
    AX_M,
    AX_MEAN_MAX_2,
    AX_SQ,
    AX_STD_MIN,
    BIAS,
    BIAS_WALK,
    BRAKE_MAX,
    D_M,
    D_SQ,
    DELTA,
    DELTA_MAX_1,
    DELTA_STD_MIN_2,
    EXC1,
    EXC2,
    G_N,
    G_ROLL,
    G_T,
    G_YAW,
    GNSS_NOISE,
    GYRO_TAU,
    K_AX,
    K_DT,
    K_STEER,
    MAX_GAP,
    OBSERVED,
    OPEN1,
    OPEN2,
    P_BB,
    P_VB,
    P_VV,
    RADIUS,
    ROLL,
    S_T,
    SINCE1,
    SINCE2,
    SPEED,
    T_F,
    T_OFF,
    T_ON,
    T_R,
    TAU_AX,
    TAU_STEER,
    U_T,
    V_MIN,
    WHEEL_NOISE,
    WHEEL_REF,
    WHEELBASE,
    WS_FL,
    WS_FR,
    WS_RL,
    WS_RR,
    YAW,
    YAW_MAX_1,
    YAW_RMS_MIN_2,
    YAW_SQ,
    V,
)
from .jit import jit

_inline = jit(inline="always")


@_inline
def _speed_reset(st):
    st[V] = math.nan
    st[P_VV] = 0.0
    st[P_VB] = 0.0
    st[S_T] = math.nan
    st[A_PREV] = math.nan


@_inline
def _speed_step(st, p, t, a_x, gnss, has_gnss, noise, turn):
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
        tn = turn * dt
        p_vv = st[P_VV] - 2 * dt * st[P_VB] + dt * dt * st[P_BB] + an * an + tn * tn
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
    p_vv, p_vb, p_bb = st[P_VV], st[P_VB], st[P_BB]
    st[P_VV] = p_vv - k_v * p_vv
    st[P_VB] = p_vb - k_v * p_vb
    if turn > 0.0:
        return  # turning: the bias is held
    st[BIAS] += k_b * e
    st[P_BB] = p_bb - k_b * p_vb


@_inline
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


@_inline
def _missing(y, needs):
    for i in needs:  # noqa: SIM110 (numba compiles no generator inside any())
        if not math.isfinite(y[i]):
            return True
    return False


@_inline
def _hard(code):
    """A reason that shuts a window at once (not a little excitation, which the hysteresis waits out)."""
    return code != 0 and code != _LITTLE_AX and code != _LITTLE_STEER  # noqa: PLR1714 (numba: no set)


@_inline
def _blocked(blk, first, stage, code, dt, i):
    if first[stage, code] == -1:  # (-2: the reason was in the dict before the block)
        first[stage, code] = i
    blk[stage, code] += dt


@jit()
def prepass(T, Y, F, A, gap, gate, st, p, c, needs1, needs2, done_from, blk, first, out, stage):
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
        # -- estimator.turning
        yr = y[c[YAW]]
        turn = yr * yr * p[WHEELBASE] if abs(yr) >= p[YAW_MAX_1] else 0.0
        _speed_step(st, p, t, ax, gnss, has, noise, turn)
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
