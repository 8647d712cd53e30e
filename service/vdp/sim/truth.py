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


# Optional per-axle cornering stiffness (N/rad): a real car's front and rear differ (their ratio
# sets its understeer).  Given both, C_alpha is their mean (what the estimator publishes);
# not given, both axles have C_alpha.
AXLES: tuple[str, ...] = ("C_alpha_front", "C_alpha_rear")


def _checked(overrides: Mapping[str, float] | None) -> dict[str, float]:
    out = {}
    for key, value in (overrides or {}).items():
        if key not in TRUTH and key not in AXLES:
            raise ConfigError(f"unknown parameter '{key}'; known: {', '.join(TRUTH)}, {', '.join(AXLES)}")
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"parameter '{key}' must be a number, got {value!r}") from None
        if not math.isfinite(v) or v <= 0:
            raise ConfigError(f"parameter '{key}' must be finite and positive, got {value!r}")
        out[key] = v
    axles = [k for k in AXLES if k in out]
    if axles and len(axles) != len(AXLES):
        raise ConfigError(f"give both {' and '.join(AXLES)} (per-axle cornering stiffness), not only {axles[0]}")
    if axles and "C_alpha" in out:
        raise ConfigError(f"give C_alpha or {' and '.join(AXLES)} (their mean is C_alpha), not both")
    return out


def truth_parameters(overrides: Mapping[str, float] | None = None) -> dict[str, float]:
    """Table 6 values with ``overrides`` applied; every value must be finite and positive.

    ``overrides`` may give the per-axle cornering stiffness (:data:`AXLES`, both); then
    C_alpha is their mean.
    """
    given = _checked(overrides)
    out = dict(TRUTH)
    out.update({k: v for k, v in given.items() if k in TRUTH})
    if AXLES[0] in given:
        out["C_alpha"] = 0.5 * (given[AXLES[0]] + given[AXLES[1]])
    if overrides:
        log.debug("truth parameters overridden: %s", dict(overrides))
    return out


def axle_parameters(overrides: Mapping[str, float] | None = None) -> dict[str, float]:
    """Per-axle cornering stiffness: the overrides' (both), else C_alpha on each axle."""
    given = _checked(overrides)
    if AXLES[0] in given:
        return {k: given[k] for k in AXLES}
    c = truth_parameters(overrides)["C_alpha"]
    return dict.fromkeys(AXLES, c)
