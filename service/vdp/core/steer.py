"""The front wheels' steer that the steering-wheel angle does not show: compliance and roll steer.

A real front axle steers out of the turn as its tyres' aligning torque twists a compliant
steering, and both axles steer with the body's roll (K&C: "lateral-force compliance steer",
"roll steer").  Eq (12)'s slip angles take the road-wheel angle from the steering-wheel angle
over a fixed ratio, so a single track fed that angle reads the axle as softer than its tyres:
brush/compact (about 1 deg per g of compliance, roll steer 0.08 front, 0.04 rear) reads a front
axle 0.80 as stiff as its tyres, and no yaw-rate, a_y or roll-rate signal tells the two apart
(docs/decisions/0019).  A profile that declares its K&C figures (Vehicle.compliance_steer,
roll_steer_f, roll_steer_r) has the angle corrected here, before any learner sees it.

Both are taken quasi-static, in proportion to the measured a_y:

- the front axle's lateral force is m a_y l_r / L (its steady share);
- the roll is eq (9)'s, m h a_y / (k_phi - m g h);
- a rear steer delta_r is a front steer -delta_r with the sideslip shifted by v_x delta_r
  (eq 12: alpha_f = delta - delta_r - (v_y' + l_f r) / v_x, alpha_r = -(v_y' - l_r r) / v_x),
  which is the same car in a steady state.

So delta_eff = delta - k a_y, k [rad per m/s^2] from :func:`gain`.  Undeclared (all 0), k is 0
and nothing is touched.
"""

from __future__ import annotations

import math

import numpy as np

from .. import channels as ch


def gain(vehicle, l_f: float, h: float) -> float:
    """k [rad of road-wheel angle per m/s^2 of a_y]: the compliance and roll steer, out of the
    turn, that a profile declares (0 where it declares none)."""
    v = vehicle
    c = getattr(v, "compliance_steer", 0.0)
    rs = getattr(v, "roll_steer_f", 0.0) + getattr(v, "roll_steer_r", 0.0)
    if not (c or rs):
        return 0.0
    l_r = v.wheelbase - l_f
    mh = v.mass * h
    roll_gain = mh / max(v.roll_stiffness - mh * v.g, 1e-9 * v.roll_stiffness)  # eq (9), phi / a_y
    return c * v.mass * l_r / v.wheelbase + rs * roll_gain


def sample(s, k: float):
    """The sample with its road-wheel angle corrected (where a_y is known; else as it was)."""
    y = s.values
    d, ay = y[ch.DELTA], y[ch.AY]
    if not math.isfinite(ay):
        return s
    out = list(y)
    out[ch.DELTA] = d - k * ay
    return s._replace(values=tuple(out))


def block(Y: np.ndarray, k: float) -> np.ndarray:
    """:func:`sample` over a block's values (a copy)."""
    Y = Y.copy()
    ay = Y[:, ch.AY]
    ok = np.isfinite(ay)
    Y[ok, ch.DELTA] -= k * ay[ok]
    return Y
