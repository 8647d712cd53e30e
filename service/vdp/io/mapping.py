"""Channel mapping: what turns decoded signal values into a canonical channel's samples,
beyond one signal's scale and sign (which :mod:`vdp.io.decoder` applies as it decodes).

- :class:`Composite`: the live state of a composite channel (vdp.profile.Composite): each
  term's newest value, combined once per frame that carries a term;
- :func:`invalid`: why a value is invalid by its status signal or plausible range.
"""

from __future__ import annotations

import math
from typing import Any

from .. import channels


class Composite:
    """Live state of a composite channel: each term's newest value and time."""

    def __init__(self, comp: Any):
        self.comp = comp
        self.index = channels.INDEX[comp.channel]
        self.maps = comp.maps  # slot j reads maps[j]: terms, their further factors, conditions
        n = len(self.maps)
        self.values: list[float | None] = [None] * n
        self.times = [-math.inf] * n
        self.slopes = [0.0] * n  # each term's rate of change between its last two frames
        self.n_terms = len(comp.terms)
        self.cond = comp.cond_start  # slot of condition 0
        self.weights = [t.weight for t in comp.terms]
        self.when = [t.when for t in comp.terms]
        self.factors: list[tuple[int, ...]] = []  # per term: the slots of its further factors
        j = self.n_terms
        for t in comp.terms:
            self.factors.append(tuple(range(j, j + len(t.factors))))
            j += len(t.factors)
        self.product = comp.op == "product"

    def label(self, j: int) -> str:
        m = self.maps[j]
        return f"{m.message}.{m.signal}"

    def put(self, j: int, v: float | None, t: float) -> None:
        """Term ``j``'s new value at ``t`` (None: invalid; the composite waits for a valid one)."""
        old, t_old = self.values[j], self.times[j]
        dt = t - t_old
        self.slopes[j] = (v - old) / dt if v is not None and old is not None and 0.0 < dt <= self.comp.max_age else 0.0
        self.values[j], self.times[j] = v, t

    def value(self, t: float) -> float | None:
        """The channel's value at ``t`` if every term (and condition) is current, else None."""
        oldest = t - self.comp.max_age
        vals = self.values
        for i, ti in enumerate(self.times):
            if ti < oldest or vals[i] is None:
                return None
        if self.product:
            out = self.weights[0]
            for i in range(self.cond):
                out *= vals[i]
            return out
        out = 0.0
        for i in range(self.n_terms):
            w = self.when[i]
            if w is not None and int(vals[self.cond + w[0]]) not in w[1]:
                continue  # this piece does not apply in the current gear or direction
            # a term from another message was sent up to a period ago: carried to t along its
            # last slope, or the sum lags the fastest term (a torque that lags the wheel
            # speeds by a few ms biases stage 1's C_K by per cents on a front-driven car).
            # Further factors are not: a gear ratio steps, and a slope across a shift is no rate.
            term = self.weights[i] * (vals[i] + self.slopes[i] * (t - self.times[i]))
            for k in self.factors[i]:
                term *= vals[k]
            out += term
        return out


def invalid(valid: tuple, vals: tuple, v: float) -> str | None:
    """Why a value is invalid by its status signal or plausible range (None: it is valid)."""
    status_pos, values, ok_if_in, lo, hi, name = valid
    if status_pos >= 0:
        s = vals[status_pos]
        if s is not None and (s in values) != ok_if_in:
            return f"status {name}={s}"
    if not lo <= v <= hi:
        return "implausible"
    return None
