"""The estimator's work before the learners, compiled over a block of samples: a replay's fast path.

Per aligned sample, :meth:`TwoStageEstimator.handle` runs the speed filter (core.speed), the
gyro offsets (estimator.GyroBias) and the gating supervisor (core.supervisor) in Python:
~7 us a sample, a fifth of a replay's CPU once the reader is fast.  None of them depends on
the learners, only on the samples and on whether l_f is known (the hand-over), so a replay
can run them over a whole block in one compiled loop (core.prepass) and visit in Python
only the samples a learner takes.  The loop repeats those classes' operations in their order,
so it gives their numbers to the last bit; this module holds the loop's state layout and
moves the state between it and the objects, without numba.  ``tests/test_batched.py`` holds
the two paths to the same estimates, supervisor state and windows, and the speed filter's and
the supervisor's own tests run on the classes, the reference.  A change to either must be followed here.

The learners' own steps over an open window's run of samples are compiled as well
(``core.kernels.lat_run`` and ``lon_run``, called by ``learner.Stage2.steps`` and
``Stage1.steps``): each stops before the first sample that needs the learner's Python step
(a window that ends, restarts or diverges, a failed step, a batch check or a last-good copy
due), so the rare paths are written once.  With both, an hour of a busy bus replays in ~2.8 s
of CPU where it took ~5.8 s sample by sample (docs/decisions/0003).

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
N_CODES = max(sup.REASONS) + 1  # reason codes 0 (none) to supervisor.WAITING, then the gates' (GATED + k)
# the parameters array
(ACCEL_NOISE, BIAS_WALK, GNSS_NOISE, MAX_GAP, WHEEL_REF, WHEEL_NOISE, BRAKE_MAX, RADIUS, GYRO_TAU, V_MIN,
 DELTA_MAX_1, YAW_MAX_1, AX_STD_MIN, AX_MEAN_MAX_2, DELTA_STD_MIN_2, YAW_RMS_MIN_2, TAU_AX, TAU_STEER, T_ON,
 T_OFF, WHEELBASE) = range(21)  # fmt: skip
# the supervisor's reason codes, as copies: numba freezes a global into the cached code and invalidates
# that cache only when this file changes (tests/test_batched.py holds them equal)
_SPEED_LOW, _STEERING, _YAWING, _LITTLE_AX, _LITTLE_STEER, _NOT_CONSTANT, _MISSING, _WAITING = range(1, 9)
_GATED, _SHUTS = _WAITING, 6  # supervisor.GATED, gates.SHUTS: gate k's reason code is _GATED + k
# channel indices, passed in (numba would freeze module globals into its cache)
CHANNELS = np.array(
    [ch.WS_FL, ch.WS_FR, ch.WS_RL, ch.WS_RR, ch.T_F, ch.T_R, ch.DELTA, ch.AX, ch.YAW, ch.ROLL, ch.SPEED]
)
WS_FL, WS_FR, WS_RL, WS_RR, T_F, T_R, DELTA, AX, YAW, ROLL, SPEED = range(11)


# -- the state and parameters, from and to the estimator's objects ------------------


def batchable(speed) -> bool:
    """Whether this speed filter is the one the pass repeats (a coarse GNSS's is not)."""
    return type(speed) is SpeedFilter


def params(cfg, vehicle, gyro_tau: float) -> np.ndarray:
    """The parameters array of an EstimatorConfig (its speed and gate configs) for ``vehicle``."""
    s, g = cfg.speed, cfg.gate
    ref = {None: 0.0, "front": 1.0}.get(s.wheel_ref, 2.0)
    p = np.zeros(21)
    p[[ACCEL_NOISE, BIAS_WALK, GNSS_NOISE, MAX_GAP, WHEEL_REF, WHEEL_NOISE, BRAKE_MAX, RADIUS, GYRO_TAU]] = (
        s.accel_noise, s.bias_walk, s.gnss_noise, s.max_gap, ref, s.wheel_noise, s.brake_torque_max,
        vehicle.wheel_radius, gyro_tau,
    )  # fmt: skip
    p[[V_MIN, DELTA_MAX_1, YAW_MAX_1, AX_STD_MIN, AX_MEAN_MAX_2, DELTA_STD_MIN_2, YAW_RMS_MIN_2]] = (
        g.v_min, g.delta_max_1, g.yaw_max_1, g.ax_std_min, g.ax_mean_max_2, g.delta_std_min_2, g.yaw_rms_min_2,
    )  # fmt: skip
    p[[TAU_AX, TAU_STEER, T_ON, T_OFF]] = (g.tau_ax, g.tau_steer, g.t_on, g.t_off)
    p[WHEELBASE] = vehicle.wheelbase  # estimator.turning's bound on r v_y
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
            code = _code(why)
            blk[stage - 1, code], first[stage - 1, code] = sec, -2
    return blk, first


def _code(why: sup.Reason) -> int:
    """The code of a driving reason (the supervisor's blockers are keyed by their reasons)."""
    if why.code not in sup.REASONS:
        raise ValueError(f"not a driving reason: {why!r}")
    return int(why.code)


def set_blockers(su, blk: np.ndarray, first: np.ndarray) -> None:
    """Write the pass's blocker seconds back, new reasons in the order they first blocked."""
    for stage in (1, 2):
        b = su.blockers[stage]
        new = [(int(first[stage - 1, code]), code) for code in range(1, N_CODES) if first[stage - 1, code] >= 0]
        for _, code in sorted(new):
            b[su.why(code)] = 0.0  # inserted where the per-sample path would have first
        for why in b:
            b[why] = float(blk[stage - 1, _code(why)])


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


def reason(su, code: int, y, needs) -> sup.Reason | None:
    """The supervisor's reason for a code at the sample ``y`` (a missing channel's list named)."""
    if code == 0:
        return None
    if code == sup.MISSING:
        return su._missing(y, needs)
    return su.why(code)
