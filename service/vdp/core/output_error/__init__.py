"""Stage 2's batch check: an output-error fit of the single track over the windows' samples.

Stage 2's filter is a joint state-parameter filter: its dynamic states walk, its roll row
(eq 9) pulls on C_alpha and I_z through a_y, and its one-step predictions weigh a model
error otherwise than a simulation does.  Where the model describes the car (vdp's own
simulator) that lands on the truth; on a car it does not describe, the filter ended
-29 % ... +25 % off while the best fit of its own model class stayed within -10 % ... +24 %
(docs/decisions/0008).

So the learner keeps the windows' samples (at the filter's step, bounded: :class:`Record`)
and fits the single track without roll, eqs (5), (7), (10)-(12) with NOTES 8's front drive
force, by output error: simulated from each window's first sample with the recorded
road-wheel angle, speed and front wheel speed, and compared with the measured yaw rate
and a_y, weighted by the sensors' noise.  The fit's parameters are the front and rear
cornering stiffness (always per axle: a richer class than the filter's one C_alpha, so a
car whose axles differ shows up), I_z, a constant a_y offset (accelerometer bias, road
bank) and each window's initial v_y and yaw rate.  Gauss-Newton (Levenberg-Marquardt) on
the logs of the stiffnesses and I_z, with the profile's priors.

The model is linear in the state (v_y, yaw rate) for given parameters: the front drive
force's dependence on the slip angle is linearised at zero (its second-order term is
below 1e-4 of the lateral force), so each step is x' = F x + g with F and g computed for
all steps at once, and the simulation is a prefix scan of these maps (:class:`Problem`):
numpy throughout, no Python loop over the samples; or, where the learners' steps are
compiled (a replay, ``vdp batch``), one compiled pass over the rows (core.kernels.oe_states,
six to seven times less CPU per fit; the live service keeps numpy).

:func:`compare` is the verdict: when the filter's value and the fit's differ by more
than their uncertainties, the model cannot explain the data one way, and the filter's
std widens to cover the difference (not valid, with the reason).

Two terms beyond the filter's model make the fit's class richer (docs/decisions/0013, "A tyre shape
the data must earn"): the roll swing a_y += s phi'' (SWING), fitted wherever there is a
roll-rate gyro, and the tyre's shape (SHAPE_B, SHAPE_C), freed only where it takes most of the
linear law's structured misfit away (Check.solve).  Where the shape is freed, the values
reported for C_alpha, each axle and I_z are the fit's.

The package: ``problem`` (the record, the problem, the fit), ``solve``, ``verdict`` (compare,
against, cover_bend), ``check`` (the learner's side).
"""

from __future__ import annotations

from .check import REFIT_ROWS, Check
from .problem import MAX_ROWS, MIN_ROWS, N_GLOBAL, N_THETA, Fit, Problem, Record
from .solve import departs, mismatched, solve, spread, structured, whiteness
from .verdict import CHECKED, Z_MAX, against, compare, cover_axles, cover_bend

__all__ = [
    "CHECKED",
    "MAX_ROWS",
    "MIN_ROWS",
    "N_GLOBAL",
    "N_THETA",
    "REFIT_ROWS",
    "Z_MAX",
    "Check",
    "Fit",
    "Problem",
    "Record",
    "against",
    "compare",
    "cover_axles",
    "cover_bend",
    "departs",
    "mismatched",
    "solve",
    "spread",
    "structured",
    "whiteness",
]
