"""Learners: one per stage and filter kind, with openpilot's interface.

By concern: ``base`` (the configuration and the shared learner), ``stage1``, ``stage2``,
``axles`` (stage 2's per-axle C_alpha), ``verdict`` (the innovation tests and what they make
of an estimate), ``tuning`` (the constants, each with its why).

``handle(t, sample)`` feeds one aligned sample (only inside the stage's
window), ``snapshot()`` publishes value, std, validity and status per
parameter, ``reset()`` returns to the priors.  A non-finite state or a failed
Cholesky resets the stage to its last good estimate and says so; it never
raises.

Convergence and identifiability are judged on the filter's own uncertainty,
never on a truth value:

- ``converged``: std below the parameter's ``converged_rel`` share of its value;
- ``not_identifiable``: after ``min_samples`` in windows the data has not even
  halved the prior std (NOTES 12), so the number is the prior's, not the data's;
- ``uncertain``: in between.
"""
