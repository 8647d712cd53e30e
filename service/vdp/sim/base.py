"""What a drive and a trace share: the sampling clock, the profile lookup, the wheel slips.

:mod:`.run` (the drive) and :mod:`.trace` (the physics alone) both build on these;
each name is importable from :mod:`vdp.sim.run` as before.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..errors import ProfileError
from ..profile import Profile, load_profile
from .vehicle import V_FLOOR

START_TIME = 1700000000.0
STEP_MS = 1  # integration step and sampling grid [ms]; DBC cycle times are whole ms
DT = STEP_MS / 1000.0
TRUTH_FORMAT = "vdp-truth/1"
REPO_ROOT = Path(__file__).resolve().parents[3]
DEFAULT_PROFILE = Path("profiles/paper.toml")


def resolve_profile(path: str | Path | None = None) -> Path:
    """A profile path as given, else relative to the CWD, else relative to the repository."""
    p = Path(path) if path else DEFAULT_PROFILE
    if p.is_file():
        return p
    if not p.is_absolute():
        for base in (Path.cwd(), REPO_ROOT):
            q = base / p
            if q.is_file():
                return q
    raise ProfileError(f"{p}: no such profile file (looked in {Path.cwd()} and {REPO_ROOT})")


def _profile(profile: Profile | str | Path | None, dbc: str | Path | None) -> Profile:
    prof = profile if isinstance(profile, Profile) else load_profile(resolve_profile(profile))
    if dbc is not None:
        d = Path(dbc)
        if not d.is_file():
            raise ProfileError(f"{d}: DBC file does not exist")
        prof = dataclasses.replace(prof, dbc=d.resolve())
    return prof


def wheel_slips(x, r: float) -> tuple[float, float]:
    """(s_f, s_r): each axle's wheel slip as its traction control sees it (eq 13, steering left out)."""
    v = x[0]
    d = v if v > V_FLOOR else V_FLOOR
    return (x[5] * r - v) / d, (x[6] * r - v) / d
