"""Stage 2's cornering stiffness per axle: the split of the C_alpha prior into the axles'
mean and half-difference, holding and freeing it, and publishing their mean.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from .. import lateral, output_error
from ..params import BY_NAME, STAGE2
from ..result import finite
from . import tuning
from .verdict import honest_std

log = logging.getLogger(__name__)


class AxleSplit:
    """Stage2's per-axle C_alpha (a mixin of :class:`vdp.core.learn.stage2.Stage2`)."""

    keys = ("C_alpha_f", "C_alpha_r", "I_z", "I_x")  # the filter's parameters (lateral.PARAM_SLICE)
    # published = _MEAN @ filter's: C_alpha = (C_alpha_f + C_alpha_r) / 2, I_z, I_x
    _MEAN = np.array([[0.5, 0.5, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    # one C_alpha for both axles (LearnerConfig.per_axle off): C_alpha_f is it, C_alpha_r inert
    _ONE = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    # filter's = _SPLIT @ published + the half-difference (a restore from published values)
    _SPLIT = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])

    @property
    def _M(self) -> np.ndarray:
        return self._MEAN if self.cfg.per_axle else self._ONE

    def _prior(self) -> tuple[np.ndarray, np.ndarray]:
        """Per axle from the profile's ``C_alpha_f``/``C_alpha_r`` priors when it gives both
        (independent), else from its C_alpha prior: that is the mean's, and the half-difference
        (C_f - C_r) / 2 is independent of it with AXLE_SPLIT of its std (zero mean).  With one
        C_alpha for both axles, C_alpha_f starts from the C_alpha prior (C_alpha_r is inert)."""
        p = self.priors
        iz, ix = p["I_z"], p["I_x"]
        f, r = p.get("C_alpha_f"), p.get("C_alpha_r")
        if not self.cfg.per_axle:
            c = p["C_alpha"]
            return np.array([c.value, c.value, iz.value, ix.value]), np.diag(np.square([c.std, c.std, iz.std, ix.std]))
        if f is not None and r is not None:
            return np.array([f.value, r.value, iz.value, ix.value]), np.diag(np.square([f.std, r.std, iz.std, ix.std]))
        c = p["C_alpha"]
        return np.array([c.value, c.value, iz.value, ix.value]), self._SPLIT @ np.diag(
            np.square([c.std, iz.std, ix.std])
        ) @ self._SPLIT.T + self._difference_cov(c.std)

    @staticmethod
    def _difference_cov(c_std: float, share: float = tuning.AXLE_SPLIT) -> np.ndarray:
        """Covariance of (+D, -D, 0, 0), D the axles' half-difference, std ``share`` c_std."""
        d = np.zeros((4, 4))
        d[:2, :2] = (share * c_std) ** 2 * np.array([[1.0, -1.0], [-1.0, 1.0]])
        return d

    def _free_split(self) -> None:
        """Free the held half-difference (SPLIT_HELD) to AXLE_SPLIT once the data know the
        axles' mean to SPLIT_FREE_REL: its variance goes into the open filter's covariance."""
        if not self.split_held or self.filter is None:
            return
        x, P = self.filter_state()
        f, r = x[lateral.C_F], x[lateral.C_R]
        mean_sd = 0.5 * math.sqrt(
            max(P[lateral.C_F, lateral.C_F] + P[lateral.C_R, lateral.C_R] + 2.0 * P[lateral.C_F, lateral.C_R], 0.0)
        )
        if not mean_sd < tuning.SPLIT_FREE_REL * 0.5 * (f + r):
            return
        c_std = self.priors["C_alpha"].std
        var = (tuning.AXLE_SPLIT**2 - tuning.SPLIT_HELD**2) * c_std**2
        # (C_f, C_r) = (M + D, M - D): D's variance along (+1, -1), in the filter's coordinates
        # (log C: d log C = dC / C)
        v = np.zeros(self._n)
        v[lateral.C_F], v[lateral.C_R] = 1.0 / f, -1.0 / r
        self.filter.set_state(self.filter.x, self.filter.P + var * np.outer(v, v))
        self.split_held = False
        log.info(
            "stage 2 %s: axles' mean known to %.1f %%; their split freed", self.kind, 100 * mean_sd / (0.5 * (f + r))
        )

    def _publish(self, theta, cov):
        M = self._M
        return M @ theta, M @ cov @ M.T

    def _unpublish(self, theta, cov):
        """Both axles at the stored mean, their difference as uncertain as the prior says."""
        S, c_std = self._SPLIT, self.priors["C_alpha"].std
        if not self.cfg.per_axle:  # C_alpha_r inert: uncorrelated, at the prior's std
            P = S @ cov @ S.T
            P[1, :] = P[:, 1] = 0.0
            P[1, 1] = c_std**2
            return S @ theta, P
        share = tuning.SPLIT_HELD if self.split_held else tuning.AXLE_SPLIT
        return S @ theta, S @ cov @ S.T + self._difference_cov(c_std, share)

    def _in_range(self, theta) -> bool:
        return all(BY_NAME[n].lo <= v <= BY_NAME[n].hi for n, v in zip(("C_alpha",) * 2 + STAGE2[1:], theta))

    def _extra(self, name, theta, cov, factor, valid, reason) -> dict:
        """C_alpha's per-axle values and stds, their correlation, and whether the drive separates them.

        The axles are separated when the data have at least halved the prior std of their
        difference (the rule ``not_identifiable`` uses) and the two are not nearly perfectly
        correlated (then the data know one combination of them, usually their mean, and the
        per-axle values are the prior's split of it).
        """
        if name != "C_alpha" or not self.cfg.per_axle:
            return {}
        var_f, var_r, cov_fr = cov[0, 0], cov[1, 1], cov[0, 1]
        sf, sr = factor * math.sqrt(max(var_f, 0.0)), factor * math.sqrt(max(var_r, 0.0))
        corr = cov_fr / math.sqrt(var_f * var_r) if var_f > 0 and var_r > 0 else math.nan
        diff = factor * math.sqrt(max(var_f + var_r - 2.0 * cov_fr, 0.0))
        f, r = float(theta[0]), float(theta[1])
        axle_why = None  # the batch check (core.output_error) per axle, as adjust() does for the mean
        if self.cfg.batch_check and self.known is not None and (fit := self.batch_fit()) is not None:
            f, sf, why_f = output_error.compare("C_alpha_front", f, sf, fit, output_error.Z_MAX)
            r, sr, why_r = output_error.compare("C_alpha_rear", r, sr, fit, output_error.Z_MAX)
            # whether the drive separates the axles stays the filter's verdict (its covariance: what the
            # drive excited), also where the values are the fit's: the fit's common-mode model error
            # correlates its axles (0.99 on brush/small) without saying the drive could not tell them apart
            axle_why = why_f or why_r
        spec = BY_NAME["C_alpha"]
        if self.samples > 0:
            sf, sr = honest_std(spec, f, sf), honest_std(spec, r, sr)
        why = None
        if self.samples == 0:
            why = "stage 2 has not run"
        elif not (diff <= 0.5 * self.prior_diff_std and abs(corr) <= tuning.AXLE_CORR_MAX):
            why = (
                f"the drive does not separate the axles: front minus rear is known to +-{diff:,.0f} N/rad "
                f"(prior +-{self.prior_diff_std:,.0f}), correlation {corr:+.2f}; only their mean is"
            )
        elif not valid:
            why = reason or "the mean C_alpha is not valid yet (each axle waits for it)"
        elif not (sf <= spec.useful_rel * abs(f) and sr <= spec.useful_rel * abs(r)):
            why = f"a per-axle std is above the {100 * spec.useful_rel:g} % a model can use"
        # a valid pair keeps the batch check's finding beside it, as the mean does
        note = why if why is not None else axle_why
        return {
            "C_alpha_front": finite(f),
            "C_alpha_front_std": finite(sf),
            "C_alpha_rear": finite(r),
            "C_alpha_rear_std": finite(sr),
            "C_alpha_axle_corr": finite(corr),
            "C_alpha_front_minus_rear_std": finite(diff),
            "per_axle_valid": why is None,
            "per_axle_reason": note,
        }
