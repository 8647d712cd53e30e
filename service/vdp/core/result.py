"""What the estimator publishes: one typed estimate per parameter, and the estimator's snapshot.

These types are the contract from the learners to the store, the report and the
API (which derives its response models from them).  They are frozen: a
snapshot taken on the estimation thread can be handed to any other thread.

Status names are defined here and only here (``Status`` and its constants);
parameter names live in :mod:`vdp.core.params`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal, get_args

Status = Literal["not_run", "uncertain", "converged", "not_identifiable", "invalid"]
STATUSES: tuple[str, ...] = get_args(Status)
NOT_RUN, UNCERTAIN, CONVERGED, NOT_IDENTIFIABLE, INVALID = STATUSES
# a stage is done when each of its parameters has converged or is known not to be identifiable
SETTLED: tuple[str, ...] = (CONVERGED, NOT_IDENTIFIABLE)

Stage = Literal["stage1", "stage2", "done"]


def _doc(text: str) -> dict:
    return {"doc": text}


@dataclass(frozen=True)
class Estimate:
    """One parameter's estimate.  ``value``/``std`` are None when not finite, and then
    ``valid`` is False (enforced here, so no reader has to check it again)."""

    name: str = field(metadata=_doc("parameter name (vdp.core.params.NAMES)"))
    value: float | None = field(metadata=_doc("estimate in SI units; null when not known, and then valid is false"))
    std: float | None = field(metadata=_doc("1-sigma uncertainty; null when not known, and then valid is false"))
    unit: str = field(metadata=_doc("SI unit of value and std"))
    status: Status = field(metadata=_doc(f"one of {', '.join(STATUSES)}"))
    valid: bool = field(
        metadata=_doc(
            "true for a finite estimate inside its sane range, learnt from the data, whose std is within the "
            "parameter's usefulness threshold (l_f 2 %, h, C_K, C_alpha, I_z 5 %, I_x 10 %); the std carries "
            "the model's error where a mismatch shows (reason then says which term and how large) and a floor "
            "no drive length averages out"
        )
    )
    stage: int = field(metadata=_doc("1 (l_f, h, C_K) or 2 (C_alpha, I_z, I_x)"))
    samples: int = field(metadata=_doc("samples the filter has used for this parameter"))
    reason: str | None = field(default=None, metadata=_doc("why the status is what it is, when not plain"))
    progress: float | None = field(
        default=None,
        metadata=_doc("0-1: how far the std has come from the prior's to the convergence threshold (log scale)"),
    )
    hint: str | None = field(default=None, metadata=_doc("what to drive for this parameter, in a driver's words"))
    extra: Mapping[str, float | bool | str | None] = field(
        default_factory=dict,
        metadata=_doc(
            "further named numbers of this estimate; C_alpha's: C_alpha_front, C_alpha_rear and their _std "
            "(N/rad, per axle; value is their mean), C_alpha_axle_corr, C_alpha_front_minus_rear_std, "
            "per_axle_valid and per_axle_reason (why the per-axle values are not valid, e.g. the drive "
            "does not separate the axles)"
        ),
    )

    def __post_init__(self):
        if self.valid and (self.value is None or self.std is None):
            object.__setattr__(self, "valid", False)

    def as_dict(self) -> dict[str, Any]:
        """The JSON shape (without the name, which is the key it is filed under).  Optional
        fields appear only when set, so older readers see the keys they know."""
        out: dict[str, Any] = {
            "value": self.value,
            "std": self.std,
            "unit": self.unit,
            "valid": self.valid,
            "stage": self.stage,
            "samples": self.samples,
            "status": self.status,
        }
        for key in ("reason", "progress", "hint"):
            v = getattr(self, key)
            if v is not None:
                out[key] = v
        if self.extra:
            out["extra"] = dict(self.extra)
        return out

    @classmethod
    def from_dict(cls, name: str, d: Mapping[str, Any]) -> Estimate:
        """The inverse of :meth:`as_dict` (a stored or received estimate)."""
        return cls(
            name=name,
            value=finite(d.get("value")),
            std=finite(d.get("std")),
            unit=str(d.get("unit", "")),
            status=d.get("status", NOT_RUN),
            valid=bool(d.get("valid")),
            stage=int(d.get("stage") or 0),
            samples=int(d.get("samples") or 0),
            reason=d.get("reason"),
            progress=d.get("progress"),
            hint=d.get("hint"),
            extra=dict(d.get("extra") or {}),
        )


def finite(v: Any) -> float | None:
    """A finite float, or None (NaN, inf and None all mean "not known")."""
    if v is None:
        return None
    f = float(v)
    return f if math.isfinite(f) else None


@dataclass(frozen=True)
class WindowSpan:
    """One gating window of a stage: bus times [s] (end None while it is open)."""

    stage: int
    start: float
    end: float | None
    samples: int

    def as_dict(self, t0: float = 0.0) -> dict[str, Any]:
        return {
            "stage": self.stage,
            "start": self.start - t0,
            "end": None if self.end is None else self.end - t0,
            "samples": self.samples,
        }


# a trace row: (t, stage, per filter kind ((value, std) per parameter, in NAMES order))
TraceRow = tuple


@dataclass(frozen=True)
class Snapshot:
    """The estimator's state at one moment: UKF parameters, the EKF baseline, gating."""

    parameters: Mapping[str, Estimate]
    baseline_ekf: Mapping[str, Estimate] | None
    stage: Stage
    supervisor: Mapping[str, Any]  # active_stage, reasons, windows (count), excitation
    windows: tuple[WindowSpan, ...]
    resets: Mapping[str, int]  # divergence resets per filter kind


def learnt_in(extras) -> bool | None:
    """Whether the six whose ``extra`` dicts these are were published with the learnt mass put in
    (core.mass.scaled marks them ``mass_source``); None where no mark says (a result made before it)."""
    extras = list(extras)
    if not any("mass_source" in x for x in extras):
        return None
    return any(x.get("mass_source") == "learnt" for x in extras)
