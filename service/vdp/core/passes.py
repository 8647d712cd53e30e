"""The steps the estimator takes before its learners, written once on a state array (issue 29).

The speed filter (core.speed.SpeedFilter), the gyro offsets (estimator.GyroBias) and the
gating supervisor (core.supervisor.Supervisor) keep their state in one array laid out by the
named indices below (NaN stands for None); the speed measured at a sample is chosen here too
(TwoStageEstimator._speed).  Each step is a plain function of that array: the classes call it
per sample on a list (Python floats: a list is the fast container for them), and core.prepass
compiles the same function, inlined into its pass over a block, on a numpy array.  So each
algorithm has one implementation, and the two paths agree to the last bit (tests/test_passes.py
holds each compiled step to the Python one).  No numba here: the per-sample path (a live
service, a short log) must never import it (core.compiled).

numba cannot call a Python function: where a step calls another (speed_step, speed_reset),
core.prepass compiles the callee too and gives the caller's compiled copy the compiled one.
numba freezes this module's constants into its cached code: this file is one of core.jit's
SOURCES, so a change here compiles anew.
"""

from __future__ import annotations

import math

from .. import channels as ch

# the state array: the speed filter, the gyro offsets, the supervisor (NaN stands for None)
(V, P_VV, P_VB, P_BB, BIAS, S_T, A_PREV, G_YAW, G_ROLL, G_N, G_T, U_T, OBSERVED, EXC1, EXC2, AX_M, AX_SQ, D_M, D_SQ,
 YAW_SQ, OPEN1, SINCE1, OPEN2, SINCE2, K_DT, K_AX, K_STEER) = range(27)  # fmt: skip
N_STATE = 27
# the parameters array
(ACCEL_NOISE, BIAS_WALK, GNSS_NOISE, MAX_GAP, WHEEL_REF, WHEEL_NOISE, BRAKE_MAX, RADIUS, GYRO_TAU, V_MIN,
 DELTA_MAX_1, YAW_MAX_1, AX_STD_MIN, AX_MEAN_MAX_2, DELTA_STD_MIN_2, YAW_RMS_MIN_2, TAU_AX, TAU_STEER, T_ON,
 T_OFF, WHEELBASE) = range(21)  # fmt: skip
N_PARAMS = 21
# the channels the steps read, passed in as ``c`` (numba would freeze module globals into its cache), and
# their positions in it
CHANNELS = (ch.WS_FL, ch.WS_FR, ch.WS_RL, ch.WS_RR, ch.T_F, ch.T_R, ch.DELTA, ch.AX, ch.YAW, ch.ROLL, ch.SPEED)
WS_FL, WS_FR, WS_RL, WS_RR, T_F, T_R, DELTA, AX, YAW, ROLL, SPEED = range(11)
# the supervisor's reason codes, as copies: numba freezes a global into the cached code and invalidates
# that cache only when this file changes (tests/test_batched.py holds them equal)
_SPEED_LOW, _STEERING, _YAWING, _LITTLE_AX, _LITTLE_STEER, _NOT_CONSTANT, _MISSING, _WAITING = range(1, 9)
_GATED, _SHUTS = _WAITING, 6  # supervisor.GATED, gates.SHUTS: gate k's reason code is _GATED + k
_REVERSE = 1  # gates.REVERSE


def new_state() -> list[float]:
    """A state list (each part's owner sets its own entries)."""
    return [math.nan] * N_STATE


class Entry:
    """An entry of its owner's state list (``self.st``) as an attribute; ``none``: NaN reads as None."""

    def __init__(self, i: int, none: bool = False):
        self.i, self.none = i, none

    def __get__(self, obj, cls=None):
        if obj is None:
            return self
        x = obj.st[self.i]
        return None if self.none and math.isnan(x) else x

    def __set__(self, obj, x) -> None:
        obj.st[self.i] = math.nan if x is None else x


def gate_params(p, g) -> None:
    """Set the entries of a parameters array (or list) a GateConfig gives (the supervisor's and the gyro offsets')."""
    p[V_MIN], p[DELTA_MAX_1], p[YAW_MAX_1], p[AX_STD_MIN] = g.v_min, g.delta_max_1, g.yaw_max_1, g.ax_std_min
    p[AX_MEAN_MAX_2], p[DELTA_STD_MIN_2], p[YAW_RMS_MIN_2] = g.ax_mean_max_2, g.delta_std_min_2, g.yaw_rms_min_2
    p[TAU_AX], p[TAU_STEER], p[T_ON], p[T_OFF] = g.tau_ax, g.tau_steer, g.t_on, g.t_off


# -- the speed filter (core.speed.SpeedFilter) ------------------------------------


def speed_params(p, cfg) -> None:
    """Set the speed filter's entries of a parameters array (or list) from its SpeedConfig."""
    p[ACCEL_NOISE], p[BIAS_WALK], p[GNSS_NOISE] = cfg.accel_noise, cfg.bias_walk, cfg.gnss_noise
    p[MAX_GAP] = cfg.max_gap


def speed_measured(p, c, y, fresh, age):
    """The speed measured at a sample (channel values ``y``, their ``fresh`` flags and ``age``):
    the GNSS speed where it is fresh; else the free-rolling axle's (WHEEL_REF: 1 front, 2 rear,
    0 none) while it is not braked.  Returns (speed, whether there is one, its std: NaN for
    GNSS_NOISE), as :func:`speed_step` takes them."""
    ax = y[c[AX]]
    if fresh[c[SPEED]] and math.isfinite(y[c[SPEED]]):
        # the GNSS speed belongs to its own time: carried to the tick with a_x
        return y[c[SPEED]] + (ax * age[c[SPEED]] if math.isfinite(ax) else 0.0), True, math.nan
    if p[WHEEL_REF] == 0.0:
        return 0.0, False, math.nan
    front = p[WHEEL_REF] == 1.0
    left = y[c[WS_FL]] if front else y[c[WS_RL]]
    right = y[c[WS_FR]] if front else y[c[WS_RR]]
    tq = y[c[T_F]] if front else y[c[T_R]]
    # braked (its torque below -BRAKE_MAX), the axle's wheels slip: no reference then
    if math.isfinite(left) and math.isfinite(right) and not (math.isfinite(tq) and tq < -p[BRAKE_MAX]):
        return 0.5 * (left + right) * p[RADIUS], True, p[WHEEL_NOISE]
    return 0.0, False, p[WHEEL_NOISE]


def speed_reset(st):
    """Forget the speed (not the bias, which outlives gaps)."""
    st[V] = math.nan
    st[P_VV] = 0.0
    st[P_VB] = 0.0
    st[S_T] = math.nan
    st[A_PREV] = math.nan


def turning(p, yaw):
    """The speed filter's ``turn`` (core.speed, "Turning") at a yaw rate: 0 while it is within
    stage 1's straight-line limit YAW_MAX_1 (Table 2; or unknown), else a bound on the ``r v_y``
    the filter's model leaves out, ``r^2 L`` (WHEELBASE: the CG's lateral speed is the kinematic
    ``r l_r`` in a slow turn, ``l_r < L``)."""
    if not abs(yaw) >= p[YAW_MAX_1]:  # (NaN: no gyro, nothing known of a turn)
        return 0.0
    return yaw * yaw * p[WHEELBASE]


def reversing(a_x, gate):
    """The speed filter's ``turn`` while the gates see the car reverse (``gate``, core.gates' code):
    the GNSS and wheel speeds are magnitudes, so the model's dv/dt = a_x has the wrong sign and leaves
    out up to 2 |a_x|; the bias is held (at least 1 mm/s^2, so that it is held at a standstill too).
    Without this a reverse out of a parking space taught the bias -0.24 m/s^2 (truth -0.01), which
    took a minute to leave, and stage 1's C_K after it read 1.8 std low (benchmarks/gates.py)."""
    if gate != _REVERSE:
        return 0.0
    return max(2.0 * abs(a_x), 1e-3) if math.isfinite(a_x) else 1e-3


def speed_step(st, p, t, a_x, gnss, has_gnss, noise, turn):
    """Advance to ``t`` with the measured a_x; correct with a speed measured at ``t`` (GNSS, or
    the free-rolling axle; ``has_gnss`` False: none), of std ``noise`` (NaN: ``GNSS_NOISE``).
    ``turn`` > 0 (m/s^2, a bound on the ``r v_y`` the model leaves out, :func:`turning`): the car
    turns, the bias is held (a consider state: no gain, its variance kept) and the speed's
    process noise is widened by it (core.speed, "Turning")."""
    r = p[GNSS_NOISE] if math.isnan(noise) else noise
    no_t = math.isnan(st[S_T])
    dt = 0.0 if no_t else t - st[S_T]
    if not math.isfinite(a_x) or no_t or dt <= 0 or dt > p[MAX_GAP]:
        speed_reset(st)
        st[S_T] = t if math.isfinite(a_x) else math.nan
    elif math.isfinite(st[V]):
        # trapezoidal: exact for a_x linear in time, so a smooth a_x leaves no drift to mistake for bias
        a_mean = 0.5 * (a_x + st[A_PREV]) if math.isfinite(st[A_PREV]) else a_x
        st[V] += dt * (a_mean - st[BIAS])
        # P = F P F^T + Q with F = [[1, -dt], [0, 1]] (squares as products, not **: Python's pow can
        # differ from x * x in the last bit, and numba may compile ** as a product)
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


# -- the gyro offsets (estimator.GyroBias) ------------------------------------------


def gyro_update(st, p, t, d, yaw, roll):
    """Take a sample's steering angle ``d`` and yaw and roll rates at ``t``: while the car drives
    straight (within stage 1's limits), their means are the gyros' offsets."""
    if math.isfinite(d) and math.isfinite(yaw) and abs(d) < p[DELTA_MAX_1] and abs(yaw) < p[YAW_MAX_1]:
        # plain mean for the first samples, then an exponential one
        dt = 0.01 if math.isnan(st[G_T]) else min(max(t - st[G_T], 0.0), 0.1)
        k = max(dt / p[GYRO_TAU], 1.0 / (st[G_N] + 1))
        st[G_YAW] += k * (yaw - st[G_YAW])
        if math.isfinite(roll):  # a car without a roll-rate gyro still has its yaw offset learnt
            st[G_ROLL] += k * (roll - st[G_ROLL])
        st[G_N] += 1
    st[G_T] = t


# -- the gating supervisor (core.supervisor.Supervisor) --------------------------------


def is_hard(code):
    """Whether a reason code shuts an open window at once (not a little excitation, which the
    hysteresis waits out)."""
    return code != 0 and code != _LITTLE_AX and code != _LITTLE_STEER  # noqa: PLR1714 (numba: no set)


def hyst(st, i_open, i_since, t, ok, hard, p):
    """A stage's window with hysteresis (its entries ``i_open``, 0 or 1, and ``i_since``, when the
    condition last changed): it opens once ``ok`` has held for T_ON and closes once it has
    failed for T_OFF, or at once where ``hard``.  Returns whether it is open."""
    is_open = st[i_open] != 0.0
    if ok == is_open:
        st[i_since] = math.nan
        return is_open
    if not ok and hard:
        st[i_open] = 0.0
        st[i_since] = math.nan
        return False
    if math.isnan(st[i_since]) or t < st[i_since]:  # (t < since: the bus clock stepped back)
        st[i_since] = t
    if t - st[i_since] >= (p[T_ON] if ok else p[T_OFF]):
        st[i_open] = 1.0 if ok else 0.0
        st[i_since] = math.nan
    return st[i_open] != 0.0


def supervise(st, p, t, gap, gate, ax, d, yaw, v_x, gnss, ws_rl, ws_rr):
    """A sample's excitation, at ``t`` (``gap``: the first after a gap; ``gate``: its gate code,
    core.gates): the moving statistics, the seconds observed and excited, and the reason codes
    (0: none) that keep each stage's window shut, the channels and the hand-over aside.
    Returns (the step's seconds, stage 1's code, stage 2's code)."""
    dt = 0.01 if math.isnan(st[U_T]) or gap else min(max(t - st[U_T], 0.0), 0.1)
    st[U_T] = t
    if dt != st[K_DT]:  # nearly every step is one tick: its gains kept (two exp per sample were a tenth of the cost)
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
    speed = v_x if math.isfinite(v_x) else gnss
    if not math.isfinite(speed):
        speed = 0.5 * (ws_rl + ws_rr) * p[RADIUS]
    # stage 1 (a missing channel is not judged here)
    if not speed > p[V_MIN]:
        d1 = _SPEED_LOW
    elif abs(d) >= p[DELTA_MAX_1]:
        d1 = _STEERING
    elif abs(yaw) >= p[YAW_MAX_1]:
        d1 = _YAWING
    elif math.sqrt(max(st[AX_SQ] - st[AX_M] * st[AX_M], 0.0)) < p[AX_STD_MIN]:
        d1 = _LITTLE_AX  # the spread of a_x, not its RMS: a constant offset (grade, bias) excites nothing
    else:
        d1 = 0
    # stage 2: steering first, it is what defines this stage, so it is the blocker worth naming
    d_std = math.sqrt(max(st[D_SQ] - st[D_M] * st[D_M], 0.0))
    if d_std < p[DELTA_STD_MIN_2] and math.sqrt(max(st[YAW_SQ], 0.0)) < p[YAW_RMS_MIN_2]:
        d2 = _LITTLE_STEER
    elif not speed > p[V_MIN]:
        d2 = _SPEED_LOW
    elif abs(st[AX_M]) > p[AX_MEAN_MAX_2]:
        d2 = _NOT_CONSTANT
    else:
        d2 = 0
    if 0 < gate <= _SHUTS:  # a gate shuts both windows, unless the driving already does
        if d1 == 0 or d1 == _LITTLE_AX:  # noqa: PLR1714 (numba: no set)
            d1 = _GATED + gate
        if d2 == 0 or d2 == _LITTLE_STEER:  # noqa: PLR1714
            d2 = _GATED + gate
    st[OBSERVED] += dt
    if d1 == 0:
        st[EXC1] += dt
    if d2 == 0:
        st[EXC2] += dt
    return dt, d1, d2
