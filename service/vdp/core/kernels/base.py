"""What every compiled step shares: status codes, a model's constants as numba takes them,
the bounded transforms (core.bounds), the physics compiled from core.lateral's own source.
"""

from __future__ import annotations

import collections

import numpy as np

from .. import lateral, longitudinal
from ..jit import jit

# status codes of a step (the learner's FilterError messages, as the numpy path words them)
OK, NOT_PD, SINGULAR, NON_FINITE, LOST_PD = 0, 1, 2, 3, 4
MESSAGES = {
    NOT_PD: "Matrix is not positive definite",
    SINGULAR: "Singular matrix",
    NON_FINITE: "non-finite state or covariance",
    LOST_PD: "covariance lost positive definiteness",
}

# a model's constants as numba takes them (attribute access on a named tuple)
Lat = collections.namedtuple("Lat", "m L r k_phi c_phi l_f h C_K g per_axle ck_slope roll_by_ay")
Lon = collections.namedtuple("Lon", "m L r J g")

# bounded transforms per state (core.bounds): 0 free, 1 log, 2 logit
FREE, LOG, LOGIT = 0, 1, 2


def lat_known(k: lateral.Known) -> Lat:
    """As floats and a bool whatever the profile wrote (an integer mass would be another
    signature: another compile for another profile)."""
    f = float
    return Lat(f(k.m), f(k.L), f(k.r), f(k.k_phi), f(k.c_phi), f(k.l_f), f(k.h), f(k.C_K), f(k.g),
               bool(k.per_axle), f(k.ck_slope), bool(k.roll_by_ay))  # fmt: skip


def lon_known(k: longitudinal.Known) -> Lon:
    """As floats (see lat_known)."""
    return Lon(float(k.m), float(k.L), float(k.r), float(k.J), float(k.g))


def transforms(bounds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(kind per state, lo, span) of a core.bounds.Bounds, as the kernels take them."""
    kind = np.zeros(bounds.n, dtype=np.int64)
    lo = np.zeros(bounds.n)
    span = np.ones(bounds.n)
    kind[bounds.log] = LOG
    kind[bounds.logit] = LOGIT
    lo[bounds.logit] = bounds.lo
    span[bounds.logit] = bounds.span
    return kind, lo, span


_jit = jit()

# the physics, compiled from core.lateral's own source
_rates = _jit(lateral._rates)
_roll_map = _jit(lateral._roll_map)
_geometry = _jit(lateral._geometry)
_pre = _jit(lateral._pre)

V_MIN = lateral.V_MIN
F0, F1, F2, F3 = (float(v) for v in lateral.PARAM_FLOOR)
LOGIT_MAX = 30.0
MIN_LOAD = longitudinal.MIN_LOAD_FRACTION


@_jit
def _max(a, b):
    """The builtin max of two floats (the second only when it is larger)."""
    return b if b > a else a


@_jit
def _to_si(t, kind, lo, span, out):
    """core.bounds.Bounds.to_si of one state."""
    for i in range(t.shape[0]):
        if kind[i] == LOG:
            out[i] = np.exp(t[i])
        elif kind[i] == LOGIT:
            q = min(max(t[i], -LOGIT_MAX), LOGIT_MAX)
            out[i] = lo[i] + span[i] / (1.0 + np.exp(-q))
        else:
            out[i] = t[i]
