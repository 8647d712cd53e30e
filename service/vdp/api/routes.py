"""The JSON routes: health, estimates and their history, status, reset.

/health and /estimates read the snapshot the estimation thread published (and counters): nothing
in them waits, so they run on the event loop itself (``async def``).  A plain ``def`` route is run
in a worker thread, and each hand-over between threads waits for the GIL, up to
``sys.getswitchinterval()`` behind a busy estimator: that was most of the API's latency on a
saturated bus.  /status (it flushes the raw log and lists its files), /metrics (the same),
/estimates/history (SQLite) and /reset (waits for the worker) stay in threads: on the loop, 200
clients at once held it long enough for connections to be dropped."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body, Depends, Query
from fastapi.responses import JSONResponse, Response

from ..core.params import PUBLISHED
from . import models
from .deps import Svc, authorize

Parameter = Literal[PUBLISHED]  # type: ignore[valid-type]
_ERR = {"model": models.Problem}

router = APIRouter()


@router.get("/health", response_model=models.Health, summary="ok, or degraded with the reasons")
async def health(svc: Svc) -> Any:
    return svc.health()


@router.get("/estimates", response_model=models.Estimates, summary="current estimates (UKF and EKF baseline)")
async def estimates(svc: Svc) -> Any:
    return Response(_estimates_body(svc), media_type="application/json")


_cached: dict = {"pub": None, "body": b""}


def _estimates_body(svc) -> bytes:
    """/estimates as FastAPI would render it (the model's JSON), made once per published snapshot: a
    dashboard polling at 50 req/s costs two renderings a second, not fifty."""
    pub = svc.latest  # Service.estimates() reads this snapshot and nothing else
    if _cached["pub"] is not pub:
        doc = models.Estimates.model_validate(svc.estimates()).model_dump(mode="json", by_alias=True)
        _cached["body"], _cached["pub"] = JSONResponse(doc).body, pub
    return _cached["body"]


_HEAD = [(b"content-type", b"application/json")]
_BODY = (b"content-length", b"transfer-encoding")


async def answer_estimates(app, scope, send) -> bool:
    """``GET /estimates`` (without a body) answered with :func:`_estimates_body`, the very bytes and headers
    the route answers; False (nothing sent) for anything else, and for a service not there yet.  Like
    ``GET /health`` it is never refused as busy: it is answered at once, from memory.  Called by the
    app itself before Starlette's middleware stack, FastAPI's routing and dependency solving, which cost
    far more CPU than handing over the cached body (a client polling at 50 req/s: docs/decisions/0020)."""
    if scope["type"] != "http" or scope["path"] != "/estimates" or scope["method"] != "GET":
        return False
    if any(k in _BODY for k, _v in scope["headers"]):
        return False  # a request with a body goes through the gate, which reads or refuses it
    svc = getattr(app.state, "service", None)
    if svc is None:
        return False
    body = _estimates_body(svc)
    head = [(b"content-length", str(len(body)).encode()), *_HEAD]
    await send({"type": "http.response.start", "status": 200, "headers": head})
    await send({"type": "http.response.body", "body": body})
    return True


@router.get(
    "/estimates/history",
    response_model=models.History,
    responses={400: _ERR, 503: _ERR},
    summary="committed estimates over time, oldest first, paged",
)
def history(
    svc: Svc,
    parameter: Annotated[Parameter | None, Query(description="one parameter, or all")] = None,
    since: Annotated[float | None, Query(description="unix time [s], inclusive", allow_inf_nan=False)] = None,
    until: Annotated[float | None, Query(description="unix time [s], exclusive", allow_inf_nan=False)] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0, le=2**53)] = 0,
) -> Any:
    return svc.history(parameter, since, until, limit, offset)


@router.get(
    "/history",
    response_model=models.DriveHistory,
    responses={503: _ERR},
    summary="each parameter across drives, and the changes named between them (a mass step, new tyres)",
)
def drive_history(svc: Svc, limit: Annotated[int, Query(ge=1, le=1000)] = 1000) -> Any:
    return svc.drive_history(limit)


@router.get("/status", response_model=models.Status, summary="bus, decoding, channels, gating, logs, store")
def status(svc: Svc) -> Any:
    return svc.status()


@router.post(
    "/reset",
    response_model=models.ResetResult,
    dependencies=[Depends(authorize)],
    responses={400: _ERR, 401: _ERR, 403: _ERR, 503: _ERR},
    summary="clear stage 1, 2 or all (bearer token; disabled without one)",
)
def reset(
    svc: Svc,
    stage: Annotated[Literal["1", "2", "all"] | None, Query(description="1, 2 or all")] = None,
    body: Annotated[models.ResetBody | None, Body()] = None,
) -> Any:
    which = stage if stage is not None else (str(body.stage) if body is not None else "all")
    return svc.reset(None if which == "all" else int(which))
