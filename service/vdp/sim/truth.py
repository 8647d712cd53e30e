"""True values of the six unknown parameters (Li et al. 2021, Table 6).

Only the unknowns live here; the known constants (m, L, r, J, k_phi, c_phi, g)
come from the profile's :class:`vdp.profile.Vehicle`, so the simulator and the
estimator share one source for them.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping

from ..errors import ConfigError

log = logging.getLogger(__name__)

# Table 6.  C_alpha is per axle (single track), C_K is dimensionless (eq 14).
TRUTH: dict[str, float] = {
    "l_f": 1.4,  # m
    "h": 0.637,  # m
    "C_K": 10.0,  # -
    "C_alpha": 66900.0,  # N/rad
    "I_z": 2000.0,  # kg m^2
    "I_x": 4175.0,  # kg m^2
}


def truth_parameters(overrides: Mapping[str, float] | None = None) -> dict[str, float]:
    """Table 6 values with ``overrides`` applied; every value must be finite and positive."""
    out = dict(TRUTH)
    for key, value in (overrides or {}).items():
        if key not in TRUTH:
            raise ConfigError(f"unknown parameter '{key}'; known: {', '.join(TRUTH)}")
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"parameter '{key}' must be a number, got {value!r}") from None
        if not math.isfinite(v) or v <= 0:
            raise ConfigError(f"parameter '{key}' must be finite and positive, got {value!r}")
        out[key] = v
    if overrides:
        log.debug("truth parameters overridden: %s", dict(overrides))
    return out
