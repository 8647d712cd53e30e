"""Numbers read from a profile's TOML: finite, in size, and named in the error where they are not."""

from __future__ import annotations

import math
from typing import Any

from ..errors import ProfileError

_MAX_NUM = 1e12  # no constant of a car comes near; beyond, products in the filters overflow


def _num(where: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProfileError(f"{where}: '{key}' must be a finite number, got {value!r}")
    try:
        v = float(value)  # an integer of 400 digits does not fit a float
    except OverflowError:
        v = math.inf
    if not math.isfinite(v):
        raise ProfileError(f"{where}: '{key}' must be a finite number, got {_short(value)}")
    if abs(v) > _MAX_NUM:
        raise ProfileError(f"{where}: '{key}' = {v:g} is out of range (at most {_MAX_NUM:g} in size)")
    return v


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:20]}...({len(text)} characters)"
