"""Profile self-check: does the profile read this car's bus the way the physics says it must?

A wrong sign, unit or steering flag gives "converged" estimates with tight stds that
are wrong (a_x flipped: l_f +65 %; the steering-wheel angle read as the road-wheel
angle: C_alpha -61 %; wheel speeds /3.6: l_f +90 %).  Each of these breaks a relation
that holds on any car, whatever its parameters:

- ``a_y = v * r`` in a steady turn (no sideslip change), and its sign;
- ``a_x = dv/dt`` (eq 1), and its sign;
- the wheel speeds times the wheel radius equal the ground speed (a few % of slip);
- the steering angle and the yaw rate have the same sign (ISO 8855: both positive left);
- ``delta = L * r / v`` within an understeer margin at moderate a_y (the kinematic
  bicycle): a road-wheel angle 15x too large or small is the steering-wheel flag;
- ``(T_f + T_r) / r = (m + 2 J / r^2) * a_x`` plus road loads (eq 1-2, both axles'
  wheel inertia), fitted for ``m``;
- the l_f prior lies inside the wheelbase.

:func:`check_samples` takes aligned samples (arrays); :func:`check_log` decodes the
first minutes of a log through the profile first.  Each mismatch is a :class:`Finding`
naming the channel (or profile key), the likely fix and the parameters that rest on it,
which :func:`mark_invalid` then reports as not valid.

The package, by concern: ``report`` (findings, and what they make of the estimates), ``samples``
(the physics on aligned samples), ``limits`` (values no car produces, the profile against
itself), ``coverage`` (which messages a log carries, refused frames), ``head`` (a log's first
minutes), ``monitor`` (a running service's self-check).
"""

from __future__ import annotations

from ..core.params import STAGE2
from ..profile import PARAMETERS
from .coverage import Coverage, check_refused, coverage, primary_messages
from .head import Head, check_head, check_log, first_seconds
from .limits import check_bounds, check_brake_pressure, check_profile
from .monitor import START_AFTER, START_CYCLES, Monitor, start_after
from .report import DEPENDS, Finding, Report, lines, lines_of, mark_invalid, mass_answer
from .samples import CHECK_SECONDS, CHECKS, KNOWN_FACTORS, MIN_SAMPLES, TICK, check_samples

__all__ = [
    "CHECKS",
    "CHECK_SECONDS",
    "DEPENDS",
    "KNOWN_FACTORS",
    "MIN_SAMPLES",
    "PARAMETERS",
    "STAGE2",
    "START_AFTER",
    "START_CYCLES",
    "TICK",
    "Coverage",
    "Finding",
    "Head",
    "Monitor",
    "Report",
    "check_bounds",
    "check_brake_pressure",
    "check_head",
    "check_log",
    "check_profile",
    "check_refused",
    "check_samples",
    "coverage",
    "first_seconds",
    "lines",
    "lines_of",
    "mark_invalid",
    "mass_answer",
    "primary_messages",
    "start_after",
]
