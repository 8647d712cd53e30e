"""Response models: what the OpenAPI schema promises.

Unknown numbers are ``null``, never NaN: every ``value``/``std`` is nullable,
and a null value always comes with ``valid: false``.
"""

from __future__ import annotations

import dataclasses
from typing import Annotated, Any, Literal, get_type_hints

from pydantic import BaseModel, ConfigDict, Field, create_model, field_validator

from ..core import result


class _Model(BaseModel):
    # Extra keys from newer estimator versions pass through instead of failing the response.
    model_config = ConfigDict(extra="allow", ser_json_inf_nan="null")


def from_dataclass(dc: type, exclude: tuple[str, ...] = ()) -> type[BaseModel]:
    """A response model with the dataclass's fields, types, defaults and (``doc`` metadata)
    descriptions: the dataclass stays the one definition."""
    hints = get_type_hints(dc)
    spec: dict[str, Any] = {}
    for f in dataclasses.fields(dc):
        if f.name in exclude:
            continue
        if f.default is not dataclasses.MISSING:
            info = Field(f.default, description=f.metadata.get("doc"))
        elif f.default_factory is not dataclasses.MISSING:
            info = Field(default_factory=f.default_factory, description=f.metadata.get("doc"))
        else:
            info = Field(description=f.metadata.get("doc"))
        spec[f.name] = (hints[f.name], info)
    return create_model(dc.__name__, __base__=_Model, __module__=__name__, **spec)


# filed under its name, so the name is not repeated inside
Estimate = from_dataclass(result.Estimate, exclude=("name",))


class Supervisor(_Model):
    active_stage: int | None = Field(None, description="the stage whose gating window is open, or null")
    reasons: dict[str, str] = Field(default_factory=dict, description="per stage: 'open' or why it is closed")
    windows: int = 0
    gated: dict[str, Any] | None = Field(
        None,
        description="the share of the drive gated out, in all and per gate (reverse, ABS, ESC, TCS, kerb strike, "
        "wheel spin, standstill, creep): fraction, seconds, of, by_gate, and a sentence (text)",
    )


class Estimates(_Model):
    parameters: dict[str, Estimate] = Field(description="UKF estimates, the shape of `vdp replay --json`")
    baseline_ekf: dict[str, Estimate] | None = Field(None, description="the EKF baseline, same shape")
    stage: str = Field(description="stage1, stage2 or done")
    supervisor: Supervisor
    capabilities: dict[str, str | None] = Field(
        default_factory=dict,
        description="per stage ('1', '2') and for 'I_x' (no roll-rate gyro): null if it can run, else why not",
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


class DriveHistory(_Model):
    """GET /history: each parameter across drives, the drives and the changes named between them."""

    parameters: dict[str, list[dict[str, Any]]] = Field(
        description="per parameter, oldest first: the value, std, valid, status and samples each drive ended "
        "with (drive: its id; t0, t1: when it began and last looked at, unix time [s])"
    )
    drives: list[dict[str, Any]] = Field(
        description="oldest first: id, t0, t1, bus_t0, bus_t1, state (driving, ended), start and last (the "
        "estimates it started from and ended with), mass and scale (its own mass [kg] and wheel-speed scale, "
        "value and std, or null), print (its periodic CAN ids and their periods [s])"
    )
    changes: list[dict[str, Any]] = Field(
        description="oldest first: id, t, bus_t, drive, kind (mass, tyres), what (a sentence: which, how large), "
        "size (the relative step), params (those reset), old (their values before, and the numbers behind it)"
    )


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
    profile_check: dict[str, Any] | None = Field(
        None,
        description="the profile self-check: when it ran (bus time), its findings, the profile's messages "
        "seen (coverage) and `error` if the bus carries none or few of them",
    )
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
