"""Compiled (numba) UKF steps on vdp's two models: the numpy filters' numbers, without numpy's per-call cost.

By concern: ``base`` (status codes, the models' constants, the bounded transforms),
``linalg`` (the UKF's linear algebra), ``lat`` (stage 2's model, steps and runs), ``lon``
(stage 1's), ``lm`` (stage 1's batch check, Levenberg-Marquardt), ``ukf`` (the UKF classes
with compiled steps), ``scan`` (stage 2's output-error pass).  core.warm compiles them all.

Also stage 2's output-error pass (``oe_states``: core.output_error.Problem's prefix scan as
one loop over the rows, the same products associated left to right).

The UKF's arrays are tiny (stage 2: 19 sigma points of 9 states, 21 of 10 with the road's
bank; stage 1: 15 of 7), so the numpy path (core.filters with core.lateral /
core.longitudinal) spends its time in the per-call overhead of ~100 array operations per
step, not in arithmetic.  Here one
compiled call does a whole predict or update: the sigma points, the bounded transform
(core.bounds), the model on each point, the unscented transform and the gain.

The physics is not copied where numba can compile it as written: lateral's ``_rates``
(eqs 5, 7, 10-12), ``_roll_map`` (eq 9) and ``_geometry`` are compiled from their own
source.  What is written out again here is the glue numba cannot take as it is (numpy's
broadcasting over sigma points, ``tolist``): lateral.fx's sub-step loop, the floors of
``_unpack``, the input grid of ``_inputs``, longitudinal.slips and hx, and the filter
steps of core.filters.UKF, in the same operations and order.  tests/test_kernels.py
holds both paths to the same numbers (models, filter steps, and the estimates of whole
drives); a change to the models there must be followed here, and that test says so.

Every function is cached on disk by core.jit (the next process loads it instead of compiling);
core.warm compiles every signature the learners use at once, the first time one is wanted
(core.compiled.kernel).  The learners import this module only when they build their first
filter (numba's import costs ~0.5 s), and take the numpy path when numba cannot be imported
or ``LearnerConfig.compiled`` is off.  Small matrix products are loops here, not BLAS, so
nothing pulls in scipy's BLAS wrappers.
"""

# ruff: noqa: F401 (the package is the names its modules define, as callers import them: kernels.X)
from __future__ import annotations

from .base import (
    F0,
    F1,
    F2,
    F3,
    FREE,
    LOG,
    LOGIT,
    LOGIT_MAX,
    LOST_PD,
    MESSAGES,
    MIN_LOAD,
    NON_FINITE,
    NOT_PD,
    OK,
    SINGULAR,
    V_MIN,
    Lat,
    Lon,
    _geometry,
    _jit,
    _max,
    _pre,
    _rates,
    _roll_map,
    _to_si,
    lat_known,
    lon_known,
    transforms,
)
from .lat import (
    C_DIVERGED,
    C_EVERY,
    C_MAX_GAP,
    C_ROLL_BY_AY,
    C_ROLL_DEN,
    C_SAVE_EVERY,
    E_C,
    E_CHI,
    E_CHI_D,
    E_I,
    E_KP,
    E_MH,
    E_PHI,
    E_T,
    E_U,
    E_W,
    K_COUNT,
    K_E,
    K_E2,
    K_EE,
    K_HAS_E,
    K_N,
    K_NE,
    K_NIS,
    K_POS,
    K_ROWS,
    L_INFO_WINDOW,
    L_N_US,
    L_ROLL_INFO,
    L_ROLL_UPDATES,
    L_SAMPLES,
    L_T_LAST,
    L_UPDATES,
    ROLL_TOTAL,
    ROLL_WINDOW,
    TOTAL,
    WINDOW,
    _cons_add,
    _lat_ay,
    _lat_fx,
    _lat_grid,
    _lat_params,
    _nis,
    _recent,
    _roll_step,
    _row,
    lat_predict,
    lat_run,
    lat_update,
)
from .linalg import _checked, _cholesky, _gain_step, _inv, _mm, _mmt, _mv, _points, _transform
from .lm import _lon_cost, _lon_forces, _lon_h, _lon_normal, _lon_rows, _solve, lon_hx_rows, lon_lm, lon_solve
from .lon import (
    A_BLOCKS,
    A_GATED,
    A_N_ACC,
    A_SAMPLES,
    A_SINCE_BATCH,
    A_SINCE_FAR,
    A_T_LAST,
    B_CORR,
    B_H_HI,
    B_H_LO,
    B_SMALL_SLIP,
    B_SPIN_RATE,
    B_SPIN_SLIP,
    D_BLOCK,
    D_BLOCKS_CAP,
    D_EVERY,
    D_EVERY_MAX,
    D_MAX_GAP,
    D_SAVE_EVERY,
    GATED,
    PREDICT_FAILED,
    TAKEN,
    UPDATE_FAILED,
    _lon_hx,
    _lon_slips,
    lon_block,
    lon_predict,
    lon_run,
    lon_update,
)
from .scan import _oe_system, oe_states
from .ukf import LateralUKF, LongitudinalUKF, _CompiledUKF, _raise
