"""core.learn's names where they were before it was split by concern (``vdp.core.learner``).

A tuning constant is read from its own module (vdp.core.learn.tuning): set it there, not here.
"""

# ruff: noqa: F401 (the names of core.learn's modules, as callers import them)
from __future__ import annotations

from .learn.axles import AxleSplit
from .learn.base import LearnerConfig, Noise, StageLearner
from .learn.stage1 import (
    _BLOCK_CHANNELS,
    _BOTH_AXLES,
    _GATED,
    _PREDICT_FAILED,
    _TAKEN,
    _UPDATE_FAILED,
    Stage1,
    _Blocks,
    _shape_prior,
)
from .learn.stage2 import _STEP_CHANNELS, Stage2
from .learn.tuning import (
    AXLE_CORR_MAX,
    AXLE_SPLIT,
    BATCH_BLOCKS,
    BATCH_EVERY,
    BATCH_EVERY_MAX,
    BATCH_FAR_EVERY,
    BEND_PRIOR,
    CHI2_MATCHED,
    CHI2_QUIET,
    CUBIC_PRIOR,
    DIVERGED_NIS,
    L_F_STD_MIN,
    LOAD_SENSITIVITY,
    NIS_MATCHED,
    NIS_MISMATCH,
    OFFSET_SPLIT_STD,
    OFFSET_STD,
    PHI_D_WALK,
    PHI_WALK,
    RESEED_M2,
    RHO_MISMATCH,
    RHO_MISMATCH_2,
    ROLL_MODEL_ERROR,
    SETTLE_TIME,
    SETTLED_STEER_RATE,
    SETTLED_YAW_ACC,
    SHAPE_LR,
    SHAPE_OFF_STD,
    SPLIT_FREE_REL,
    SPLIT_HELD,
    V_Y_START_STD,
    V_Y_WALK,
    YAW_WALK,
)
from .learn.verdict import Consistency, Hard, RollExcitation, _verdict, _widen, honest_std, quad_form, too_wide, useful
