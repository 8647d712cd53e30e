"""The learners' tuning constants, each with why it has its value (and where it was measured).

The one place they are set: the learners read them as ``tuning.NAME`` at the time of use, so a
benchmark or a test that tries another value sets it here (``monkeypatch.setattr(tuning, ...)``).
"""

from __future__ import annotations

import math
from typing import Final

# Stage 2's dynamic states walk by model error only (std per sqrt(s), eqs (5), (8), (9)).
# v_y has no sensor: the filter sees it through a_y alone, so its walk decides how much
# of the accelerometer's noise it takes for v_y, and a noisy v_y is a noisy slip angle,
# which pulls C_alpha and I_z low (errors in variables).  0.05 m/s per sqrt(s) let v_y
# move in one 40 ms filter step as if pushed by 0.25 m/s^2 of unmodelled lateral
# acceleration, five times the accelerometer's noise, and took 3 % off C_alpha and I_z
# on the RAV4's drive (8 % with 0.1 m/s^2 of noise); 0.005 allows 0.025 m/s^2.
V_Y_WALK: Final[float] = 0.005  # m/s per sqrt(s)
YAW_WALK: Final[float] = 0.02  # rad/s per sqrt(s)
PHI_WALK: Final[float] = 1e-4  # rad per sqrt(s)
PHI_D_WALK: Final[float] = 0.005  # rad/s per sqrt(s)
L_F_STD_MIN: Final[float] = 1e-4  # m: stage 1's l_f is never taken as exact (keeps the covariance positive definite)

# A stage-2 window opens on a settled state: over the last SETTLE_TIME the yaw rate and the
# road-wheel angle changed by less than these rates (a window opening just after a steering
# step drove C_alpha and I_x the wrong way, measured on the independent models)
SETTLE_TIME: Final[float] = 0.2  # s
SETTLED_YAW_ACC: Final[float] = 0.15  # rad/s^2
SETTLED_STEER_RATE: Final[float] = math.radians(3.0)  # rad/s of road-wheel angle
# m/s: the steady-state start's own error (transients, slopes), beside C_alpha's share
V_Y_START_STD: Final[float] = 0.05
# The road's bank as stage 2's tenth state (lateral.BANK, g sin(bank), only with the road modelled:
# LearnerConfig.bank), a random walk from 0 at each window's start.  The prior's std covers a
# bank of 3 deg (0.51 m/s^2).  The walk: 0.0018 (m/s^2)^2/s (0.3 m/s^2 in 50 s) tracked the
# hills' and bank's 450-m sine to 0.02-0.04 m/s^2 and cost nothing on a flat road; ten times
# that cost C_alpha 1-3 % on the flat (docs/decisions/0023, 0025).
BANK_STD: Final[float] = 0.5  # m/s^2
BANK_Q: Final[float] = 0.0018  # (m/s^2)^2 per s
# Model mismatch (docs/decisions/0006): on vdp's own simulator, whose model
# is the estimator's, stage 2's NIS per row is about 0.18 and both lag-1 autocorrelations
# about 0; on the independent models they reached 1.2 and 0.65.  Beyond these the model
# does not explain the data: the stds widen by sqrt((1 + rho) / (1 - rho)) (the evidence
# of correlated residuals is overstated by that much) and by sqrt(NIS / NIS_MATCHED), and
# the parameters the mismatch bears on are not valid, with the reason.
NIS_MATCHED: Final[float] = 0.2
NIS_MISMATCH: Final[float] = 0.6
# stage 1's front-minus-rear batch residuals with the bending tyre and the slip offsets
# (core.longitudinal): -0.05 to 0.08 on vdp's own simulator with realistic noise, 0.15-0.39
# on the independent models (docs/decisions/0005)
RHO_MISMATCH: Final[float] = 0.12
# A tyre whose stiffness per unit load falls with load (by q per unit of relative load) shows
# only (1 - q) of the load transfer in its slips, and nothing in the slips tells q from h.
# When the data say the tyre law does not explain them, h's std takes q's typical size
# (0.1 on the brush cars, 0-0.3 for road tyres) as a consider term.
LOAD_SENSITIVITY: Final[float] = 0.1
# Below this reduced chi-square the batch residuals are far under the noise R assumes (a
# noise-free drive) and their colour is numerical: 0.003 and 0.011 on vdp's own noise-free
# drives, where the lag-1 correlation reached 0.27; 0.06-0.22 on the independent models'.
CHI2_QUIET: Final[float] = 0.03
# The reduced chi-square of stage 1's batch residuals that a matching model leaves with realistic
# noise (R is the sensors' noise inflated by Noise.inflate): 0.22 and 0.32 on vdp/paper seed 1 and
# vdp/small seed 2 (the tuning cases, docs/decisions/0001-honest-std.md).  The size in _widen.
CHI2_MATCHED: Final[float] = 0.3
# stage 2's a_y innovations (0.31 on one vdp seed with its a_y bias, 0.65 on brush tyres)
RHO_MISMATCH_2: Final[float] = 0.45
# I_x's model error when the roll-rate innovations show a mismatch (relative, 1 sigma): eq (9)
# puts the whole mass at the CG height h, rolling about the ground.  A car rolls its sprung
# mass (85-90 % of m) about a roll axis 0.05-0.15 m above the ground, so the true roll moment
# is about 0.6-0.85 of the model's, and the sprung mass's sideways motion as it rolls (a
# term eq 7 leaves out) moved I_x by +45 % on one independent model
# (notes/estimation-findings.md).  The I_x that fits the data is then an effective value,
# off the inertia by as much as these: 0.3 of it as one sigma.
ROLL_MODEL_ERROR: Final[float] = 0.3
DIVERGED_NIS: Final[float] = 25.0  # mean NIS per row over Consistency.RECENT updates beyond which a window has diverged

# Stage 1's batch check (core.batch): the blocks kept, how often the batch optimum is
# solved, and how far (squared Mahalanobis distance, 3 parameters) the filter may sit
# from it before it is re-seeded there (chi-square, 3 dof, 0.999: 16.3)
BATCH_BLOCKS: Final[int] = 3000  # 5 min of stage-1 windows in 0.1 s blocks
# blocks between checks: 20 (2 s of window), or a quarter of the blocks kept once that is more,
# at most BATCH_EVERY_MAX (Stage1.check_due).  A check costs about in proportion to the blocks
# kept, so at every 20 it grew with the square of the drive until the record was full: 27 % of
# an hour's replay, 2.1 s of CPU (docs/decisions/0004).  The early checks, which re-seed a
# filter started far off, come as often as before; the cap keeps what a live service commits
# and hands to stage 2 at most 20 s of window behind the check; the log's end solves once more
# on every block (TwoStageEstimator.finish).  The far check (the prior's mean as a start, the
# tyre-shape test, the model's error) comes every BATCH_FAR_EVERY x BATCH_EVERY blocks, as before.
BATCH_EVERY: Final[int] = 20
BATCH_EVERY_MAX: Final[int] = 200
BATCH_FAR_EVERY: Final[int] = 4  # every this many dense checks' blocks, a far one (the far start costs the most)
RESEED_M2: Final[float] = 16.3

# Stage 2's cornering stiffness per axle (Stage2): the profile's C_alpha prior is the mean's;
# the half-difference (C_f - C_r) / 2 gets this share of its std, independently (a real
# car's axles differ by up to about a third; a tight C_alpha prior means a known car)
AXLE_SPLIT: Final[float] = 0.5
AXLE_CORR_MAX: Final[float] = 0.95  # |correlation| of the two beyond this: the data know one combination of them
# The split is held (one C_alpha in effect: its half-difference's std SPLIT_HELD of C_alpha's prior
# std) until the data know the axles' mean to SPLIT_FREE_REL, then freed to AXLE_SPLIT.  In a steady
# corner the data fix each axle's force, F = C alpha, not C and the slip angle (v_y, no sensor)
# apart; one C_alpha closes that, two leave a curve (C_f, C_r, v_y) along which a filter started
# far off (priors x0.6 on vdp's `suv`) slid to C_alpha 0.1x with a std of 1 % and never came back.
SPLIT_HELD: Final[float] = 0.1
SPLIT_FREE_REL: Final[float] = 0.05

# Stage 1's tyre shape (core.longitudinal), estimated beside l_f, h, C_K and not reported:
# priors (mean, std).  The bend b = 1 / (3 mu) of a brush tyre is 0.28-0.42 for mu 0.8-1.2;
# the prior is centred on the paper's linear tyre (b = 0) and wide enough for any of them.
# The slip offsets: rolling resistance f_r / C_K (about 0.001) and a rolling radius a few
# tenths of a per cent off, mostly common to both axles (the same tyres, one radius in the
# profile); their front-minus-rear half-difference is smaller (0.00014 on the multi-body
# car).  A free difference costs l_f its information where one axle only brakes (a
# front-driven car: l_f's std 0.8 % instead of 0.5 %).
BEND_PRIOR: Final[tuple[float, ...]] = (0.0, 0.5)
# c = 5 / (27 mu^2) of a brush tyre, 0.13-0.29; a Magic-Formula tyre's 0.3-0.6
CUBIC_PRIOR: Final[tuple[float, ...]] = (0.0, 1.0)
OFFSET_STD: Final[float] = 0.002  # their common part
OFFSET_SPLIT_STD: Final[float] = 0.0005  # (s_0f - s_0r) / 2
# Three more parameters cost l_f, h and C_K precision (a front-driven car on vdp's own tyre:
# l_f's std 0.8 % instead of 0.5 %), so stage 1 starts on the paper's straight line (the
# shape held at 0 by a prior this tight) and frees the shape once the data demand it: the
# batch cost falls by more than SHAPE_LR times the residuals' noise level (reduced chi-square,
# times (1 + rho) / (1 - rho) for their correlation) when the shape is free.  On vdp's own
# simulator that drop stayed at 0.3-25, on the independent models 119-1,001 (docs/decisions/0008;
# "A stage 1 that holds with a real tyre").
SHAPE_OFF_STD: Final[tuple[float, ...]] = (1e-4, 1e-4, 1e-6)  # b, c, each offset
SHAPE_LR: Final[float] = 60.0
