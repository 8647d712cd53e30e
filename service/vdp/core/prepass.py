"""core.batched's pass over a block, compiled (numba): imported at its first use, not with the core.

The speed filter (core.speed.SpeedFilter), the gyro offsets (estimator.GyroBias) and the
gating supervisor (core.supervisor.Supervisor) over a block of samples in one loop, on the
state array core.passes lays out.  Their steps, and the speed measured at each sample
(TwoStageEstimator._speed), are core.passes', compiled here; the loop adds what the classes
hold in Python form: the supervisor's blockers (seconds per reason code, where the class keys
a dict by its reasons) and its test for missing channels.  The helpers are compiled
inlined into the pass (a call per sample cost too much).  Cached by core.jit;
``NUMBA_DISABLE_JIT=1`` runs this same source as Python.
"""

from __future__ import annotations

import math
import types

from . import passes as ps
from .jit import jit

_inline = jit(inline="always")


def _calling(fn, **helpers):
    """A copy of ``fn`` whose globals name the compiled ``helpers`` (numba calls no Python
    function); ``fn`` itself, the per-sample path's, keeps calling the Python ones."""
    return types.FunctionType(fn.__code__, {**fn.__globals__, **helpers}, fn.__name__, fn.__defaults__, fn.__closure__)


_speed_measured = _inline(ps.speed_measured)
_speed_reset = _inline(ps.speed_reset)
_turning = _inline(ps.turning)
_reversing = _inline(ps.reversing)
_speed_step = _inline(_calling(ps.speed_step, speed_reset=_speed_reset))
_gyro_update = _inline(ps.gyro_update)
_hyst = _inline(ps.hyst)
_hard = _inline(ps.is_hard)
_supervise = _inline(ps.supervise)


@_inline
def _missing(y, needs):
    for i in needs:  # noqa: SIM110 (numba compiles no generator inside any())
        if not math.isfinite(y[i]):
            return True
    return False


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
        ax = y[c[ps.AX]]
        gnss, has, noise = _speed_measured(p, c, y, F[i], A[i])
        if gap[i]:
            _speed_reset(st)
        _speed_step(st, p, t, ax, gnss, has, noise, max(_turning(p, y[c[ps.YAW]]), _reversing(ax, gate[i])))
        v = st[ps.V]
        out[i, 0] = v
        out[i, 1] = math.sqrt(st[ps.P_VV]) if math.isfinite(v) else math.nan
        out[i, 2] = st[ps.BIAS]
        # -- GyroBias.update
        _gyro_update(st, p, t, y[c[ps.DELTA]], y[c[ps.YAW]], y[c[ps.ROLL]])
        out[i, 3] = st[ps.G_YAW]
        out[i, 4] = st[ps.G_ROLL]
        # -- Supervisor.update
        dt, d1, d2 = _supervise(st, p, t, gap[i], gate[i], ax, y[c[ps.DELTA]], y[c[ps.YAW]], v, y[c[ps.SPEED]],
                                y[c[ps.WS_RL]], y[c[ps.WS_RR]])  # fmt: skip
        if d1 != 0:
            _blocked(blk, first, 0, d1, dt, i)
        if d2 != 0:
            _blocked(blk, first, 1, d2, dt, i)
        r1 = ps._MISSING if _missing(y, needs1) else d1
        if i < done_from:
            r2 = ps._WAITING
        else:
            r2 = ps._MISSING if _missing(y, needs2) else d2
        o1 = _hyst(st, ps.OPEN1, ps.SINCE1, t, r1 == 0, _hard(r1), p)
        o2 = _hyst(st, ps.OPEN2, ps.SINCE2, t, r2 == 0, _hard(r2), p)
        stage[i] = 2 if o2 else 1 if o1 else 0
    return r1, r2
