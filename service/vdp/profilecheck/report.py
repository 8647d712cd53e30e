"""The profile check's findings and report, and what they make of the estimates (mark_invalid)."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field

from ..core.params import MASS, STAGE2
from ..core.result import NOT_RUN, Estimate, learnt_in
from ..profile import PARAMETERS

log = logging.getLogger(__name__)


# Stage 2 takes stage 1's l_f, h and C_K as known: a fault under stage 1 spoils both.
DEPENDS: dict[str, tuple[str, ...]] = {
    "wheel_speed": PARAMETERS,
    "wheel_torque": PARAMETERS,
    "accel_x": PARAMETERS,
    "speed": PARAMETERS,
    "mass": PARAMETERS,
    "l_f": PARAMETERS,
    "steering_angle": STAGE2,
    "accel_y": STAGE2,
    "yaw_rate": STAGE2,
}


@dataclass(frozen=True)
class Finding:
    check: str  # e.g. "accel_x_sign"
    subject: str  # the channel or profile key at fault: "accel_x", "vehicle.mass", "priors.l_f"
    message: str  # one line, with the likely fix
    params: tuple[str, ...]  # parameters that rest on it: not reported valid

    def as_dict(self) -> dict:
        return {"check": self.check, "subject": self.subject, "message": self.message, "params": list(self.params)}


@dataclass
class Report:
    findings: list[Finding] = field(default_factory=list)
    measured: dict[str, float] = field(default_factory=dict)  # the figures each check found
    skipped: dict[str, str] = field(default_factory=dict)  # check -> why it could not be judged
    seconds: float = 0.0  # bus time looked at

    def add(self, check: str, subject: str, message: str, params: tuple[str, ...]) -> None:
        self.findings.append(Finding(check, subject, message, params))

    @property
    def invalid(self) -> dict[str, str]:
        """Parameter -> why it is not valid (the first finding that concerns it)."""
        out: dict[str, str] = {}
        for f in self.findings:
            for p in f.params:
                out.setdefault(p, f"profile check: {f.message}")
        return out

    def as_dict(self) -> dict:
        return {
            "findings": [f.as_dict() for f in self.findings],
            "measured": {k: round(v, 4) for k, v in self.measured.items()},
            "skipped": dict(self.skipped),
            "seconds": round(self.seconds, 1),
        }


def mark_invalid(params: Mapping[str, Estimate], report: Report) -> dict[str, Estimate]:
    """The estimates with ``valid = False`` and the ``reason`` on every parameter a finding concerns;
    a learnt mass (core.mass) where a finding concerns the channels it rests on.  A valid learnt mass
    that the six are scaled with answers the finding on the profile's mass: that one marks nothing."""
    out = dict(params)
    m = out.get(MASS)
    if m is not None and m.status != NOT_RUN:
        why = next((f.message for f in report.findings if _under_mass(f)), None)
        if why is not None:
            out[MASS] = dataclasses.replace(m, valid=False, reason=f"profile check: {why}")
    findings = report.findings
    if _mass_learnt(out):
        findings = [f for f in findings if f.subject != "vehicle.mass"]
    for name, why in Report(findings).invalid.items():
        e = out.get(name)
        if e is not None:
            out[name] = dataclasses.replace(e, valid=False, reason=why)
    return out


def _mass_learnt(params: Mapping[str, Estimate]) -> bool:
    """A learnt mass that the six are scaled with (core.mass.scaled marks them ``mass_source`` "learnt";
    a result from before the mark: ``mass_used`` with the mass valid)."""
    m = params.get(MASS)
    if m is None or m.status == NOT_RUN:
        return False
    extras = [e.extra or {} for n, e in params.items() if n != MASS]
    put = learnt_in(extras)
    return put if put is not None else m.valid and any("mass_used" in x for x in extras)


def _under_mass(f: Finding) -> bool:
    """A finding on a channel the learnt mass rests on: the torques, a_x and the speeds, which
    stage 1 rests on too (C_K among its parameters).  Not the profile's mass (the learnt one
    replaces it) nor a prior (the mass takes none from the geometry)."""
    return "C_K" in f.params and not f.subject.startswith(("vehicle.", "priors."))


def lines(rep: Report, mass_on: bool = False) -> list[str]:
    """What the CLI prints: one warning line per finding.  ``mass_on``: the mass is learnt as driven
    (core.mass), so the finding on the profile's mass marks the six only if that is not learnt."""
    return lines_of(rep.findings, mass_on)


def lines_of(findings: list[Finding], mass_on: bool = False) -> list[str]:
    out = []
    for f in findings:
        line = f"profile check: {f.message}"
        if f.params and mass_on and f.subject == "vehicle.mass":
            line += f" (not valid unless the mass learnt as driven is: {', '.join(f.params)})"
        elif f.params:
            line += f" (not valid: {', '.join(f.params)})"
        out.append(line)
    return out


def mass_answer(params: Mapping[str, Estimate], rep: Report) -> str | None:
    """The line that says a valid learnt mass answered the finding on the profile's mass (None
    where there is no such finding or the mass was not learnt valid)."""
    if not _mass_learnt(params) or not any(f.subject == "vehicle.mass" for f in rep.findings):
        return None
    m = params[MASS]
    return (
        f"profile check: the mass learnt as driven, {m.value:.0f} ± {m.std:.0f} kg, answers the finding on "
        f"vehicle.mass: the parameters are scaled with it and keep their own verdicts"
    )
