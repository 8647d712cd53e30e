"""The estimator's work before the learners, compiled over a block of samples: a replay's fast path.

Per aligned sample, :meth:`TwoStageEstimator.handle` runs the speed filter (core.speed), the
gyro offsets (estimator.GyroBias) and the gating supervisor (core.supervisor) in Python:
~7 us a sample, a fifth of a replay's CPU once the reader is fast.  None of them depends on
the learners, only on the samples and on whether l_f is known (the hand-over), so a replay
can run them over a whole block in one compiled loop (core.prepass) and visit in Python
only the samples a learner takes.  Their steps are written once (core.passes): the classes
call them per sample on the estimator's state list, the loop compiles them, so both paths give
the same numbers to the last bit.  The loop adds only what the classes hold in Python form (the
supervisor's blockers and missing channels); ``tests/test_batched.py``
holds the two paths to the same estimates, supervisor state and windows.  This module makes
the loop's parameters and turns what it counts back into the supervisor's, without numba.

The learners' own steps over an open window's run of samples are compiled as well
(``core.kernels.lat_run`` and ``lon_run``, called by ``learner.Stage2.steps`` and
``Stage1.steps``): each stops before the first sample that needs the learner's Python step
(a window that ends, restarts or diverges, a failed step, a batch check or a last-good copy
due), so the rare paths are written once.  With both, an hour of a busy bus replays in ~2.8 s
of CPU where it took ~5.8 s sample by sample (docs/decisions/0003).

The state crosses over as the estimator's state list, copied into an array and back: the
Python objects stay the state's owners, so a live service and a replay can hand a drive to
each other.  Without numba, with the compiled steps off (LearnerConfig.compiled) or with a
coarse GNSS's rounding-error filter, the estimator runs per sample.
"""

from __future__ import annotations

import numpy as np

from . import passes as ps
from . import supervisor as sup
from .speed import SpeedFilter

N_CODES = max(sup.REASONS) + 1  # reason codes 0 (none) to supervisor.WAITING, then the gates' (GATED + k)
CHANNELS = np.array(ps.CHANNELS)  # the channels the pass reads (core.passes)


# -- the parameters, and what the pass counts back into the supervisor ------------------


def batchable(speed) -> bool:
    """Whether this speed filter is the one the pass repeats (a coarse GNSS's is not)."""
    return type(speed) is SpeedFilter


def params(cfg, vehicle, gyro_tau: float) -> np.ndarray:
    """The parameters array of an EstimatorConfig (its speed and gate configs) for ``vehicle``."""
    s, g = cfg.speed, cfg.gate
    ref = {None: 0.0, "front": 1.0}.get(s.wheel_ref, 2.0)
    p = np.zeros(ps.N_PARAMS)
    ps.speed_params(p, s)
    p[[ps.WHEEL_REF, ps.WHEEL_NOISE, ps.BRAKE_MAX]] = ref, s.wheel_noise, s.brake_torque_max
    p[ps.RADIUS], p[ps.GYRO_TAU] = vehicle.wheel_radius, gyro_tau
    ps.gate_params(p, g)
    p[ps.WHEELBASE] = vehicle.wheelbase  # passes.turning's bound on r v_y
    return p


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
