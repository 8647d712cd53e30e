"""Response models: what the OpenAPI schema promises.

Unknown numbers are ``null``, never NaN: every ``value``/``std`` is nullable,
and a null value always comes with ``valid: false``.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

STATUSES = ("not_run", "uncertain", "converged", "not_identifiable", "invalid")


class _Model(BaseModel):
    # Extra keys from newer estimator versions pass through instead of failing the response.
    model_config = ConfigDict(extra="allow", ser_json_inf_nan="null")


class Estimate(_Model):
    value: float | None = Field(description="estimate in SI units; null when not known, and then valid is false")
    std: float | None = Field(description="1-sigma uncertainty; null when not known, and then valid is false")
    unit: str
    valid: bool = Field(description="true only for a converged, finite estimate inside its sane range")
    stage: int = Field(description="1 (l_f, h, C_K) or 2 (C_alpha, I_z, I_x)")
    samples: int = Field(description="samples the filter has used for this parameter")
    status: str = Field(description=f"one of {', '.join(STATUSES)}")
    progress: float | None = Field(
        None, description="0-1: how far the std has come from the prior's to the convergence threshold (log scale)"
    )
    hint: str | None = Field(None, description="what to drive for this parameter, in a driver's words")


class Supervisor(_Model):
    active_stage: int | None = Field(None, description="the stage whose gating window is open, or null")
    reasons: dict[str, str] = Field(default_factory=dict, description="per stage: 'open' or why it is closed")
    windows: int = 0


class Estimates(_Model):
    parameters: dict[str, Estimate] = Field(description="UKF estimates, the shape of `vdp replay --json`")
    baseline_ekf: dict[str, Estimate] | None = Field(None, description="the EKF baseline, same shape")
    stage: str = Field(description="stage1, stage2 or done")
    supervisor: Supervisor
    capabilities: dict[str, str | None] = Field(
        default_factory=dict, description="per stage: null if it can run, else why not"
    )
    coaching: dict[str, Any] | None = Field(
        None,
        description="per stage progress (0-1) and gate, per parameter information gained, window "
        "seconds and seconds to go, and `next`: the manoeuvre to drive next",
    )
    resets: dict[str, int] = Field(default_factory=dict, description="divergence resets per filter kind")
    restored: bool = Field(False, description="the estimator started from the stored estimates")
    bus_time: float | None = Field(None, description="timestamp of the newest frame estimated [s]")
    updated: float = Field(description="unix time of this snapshot [s]")


class HistoryItem(_Model):
    id: int
    t: float = Field(description="unix time of the committed batch [s]")
    bus_t: float | None = None
    parameter: str
    value: float | None
    std: float | None
    valid: bool
    stage: int
    status: str
    samples: int


class History(_Model):
    items: list[HistoryItem]
    total: int = Field(description="rows matching the query in all")
    limit: int
    offset: int
    next_offset: int | None = Field(None, description="offset of the next page, null on the last one")


class Health(_Model):
    status: Literal["ok", "degraded"]
    reasons: list[str] = Field(description="empty when ok")
    stage: str
    uptime_s: float


class Status(_Model):
    uptime_s: float
    started: float
    profile: dict[str, Any]
    bus: dict[str, Any] = Field(description="state (up, down, connecting), frames, frames_per_s, reconnects ...")
    queue: dict[str, Any]
    estimation: dict[str, Any]
    decode: dict[str, Any] = Field(description="decode errors by ID and kind, unknown IDs")
    channels: dict[str, Any] = Field(description="each mapped channel's age [s] and whether it is stale")
    gating: dict[str, Any] = Field(description="supervisor state and the current gating window")
    raw_log: dict[str, Any] = Field(description="raw CAN log files and their disk use")
    store: dict[str, Any]
    simulation: dict[str, Any] | None = None


class ResetBody(BaseModel):
    model_config = ConfigDict(extra="forbid")
    stage: Literal["1", "2", "all"] | Annotated[int, Field(ge=1, le=2)] = Field("all", description="1, 2 or all")

    @field_validator("stage", mode="before")
    @classmethod
    def _not_bool(cls, v: Any) -> Any:
        if isinstance(v, bool):  # JSON true is not stage 1 (pydantic would take it as 1)
            raise ValueError('stage must be 1, 2 or "all", not a boolean')
        return v


class ResetResult(Estimates):
    reset: Literal["1", "2", "all"]


class Problem(BaseModel):
    detail: str
