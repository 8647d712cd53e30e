"""The REST API: a FastAPI app factory over a :class:`vdp.live.Service`.

``create_app(settings)`` builds nothing at import time: the service is made and
started in the app's lifespan (or passed in, already running, by a test).  HTTP
status codes are decided here and only here; the service raises vdp errors.
"""

from __future__ import annotations

import hmac
import logging
from contextlib import asynccontextmanager
from typing import Annotated, Any, Literal

from fastapi import Body, Depends, FastAPI, HTTPException, Query, Request
from fastapi.responses import JSONResponse, PlainTextResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

from .. import __version__
from ..core.params import NAMES
from ..errors import StoreError, VdpError
from ..settings import Settings
from . import dashboard, models

log = logging.getLogger(__name__)

LOOPBACK = ("127.0.0.1", "::1", "localhost")

Parameter = Literal[NAMES]  # type: ignore[valid-type]


def check_host(host: str) -> None:
    """Serving beyond this machine is allowed, but only on purpose."""
    if host not in LOOPBACK:
        log.warning(
            "the API listens on %s, not only on this machine: anyone who can reach it can read "
            "the estimates. Keep [api] reset_token secret, and firewall the port.",
            host,
        )


def _service(request: Request):
    svc = getattr(request.app.state, "service", None)
    if svc is None:
        raise HTTPException(503, "the service is starting")
    return svc


_bearer = HTTPBearer(auto_error=False, description="the [api] reset_token of the config")


def _authorize(request: Request, cred: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]) -> None:
    token = request.app.state.settings.api.reset_token
    if not token:
        raise HTTPException(403, "POST /reset is disabled: no [api] reset_token is configured")
    if cred is None or cred.scheme.lower() != "bearer":
        raise HTTPException(401, "a bearer token is required", headers={"WWW-Authenticate": "Bearer"})
    # Constant time, on bytes: compare_digest refuses non-ASCII str.
    if not hmac.compare_digest(cred.credentials.encode("utf-8"), token.encode("utf-8")):
        raise HTTPException(403, "wrong token")


class _Metrics:
    """A prometheus collector reading the service when scraped (no second set of counters)."""

    def __init__(self, app: FastAPI):
        self.app = app

    def collect(self):
        svc = getattr(self.app.state, "service", None)
        if svc is None:
            return
        m = svc.metrics()

        def gauge(name, doc, value, labels=None, **lv):
            g = GaugeMetricFamily(f"vdp_{name}", doc, labels=list(lv) if lv else None)
            if lv:
                g.add_metric(list(lv.values()), value)
            else:
                g.add_metric([], value)
            return g

        def counter(name, doc, value):
            c = CounterMetricFamily(f"vdp_{name}", doc)
            c.add_metric([], value)
            return c

        yield counter("frames_received", "CAN frames received from the bus", m["frames"])
        yield counter("frames_dropped", "frames dropped because estimation fell behind", m["dropped"])
        yield counter("frames_estimated", "frames fed to the estimation pipeline", m["fed"])
        yield counter("samples", "aligned samples the estimator saw", m["samples"])
        yield counter("bus_reconnects", "bus reconnects", m["reconnects"])
        yield counter("bus_errors", "bus errors (open failures, receive errors)", m["bus_errors"])
        yield counter("estimation_errors", "frames on which estimation raised", m["errors"])
        yield counter("raw_log_frames", "frames written to the raw log", m["raw_frames"])
        yield counter("raw_log_lost", "frames not written while raw logging was stopped", m["raw_lost"])
        yield counter("store_commits", "batches committed to the estimate store", m["store_commits"])
        yield gauge("queue_depth", "frames waiting for the estimator", m["queue_depth"])
        yield gauge("queue_capacity", "size of the estimation queue", m["queue_capacity"])
        yield gauge("frames_per_second", "receive rate over the last seconds", m["frames_per_s"])
        yield gauge("bus_up", "1 if the bus is open and receiving", 1.0 if m["bus_up"] else 0.0)
        yield gauge("healthy", "1 if /health says ok", 1.0 if m["healthy"] else 0.0)
        yield gauge("raw_log_ok", "1 if raw logging is running", 1.0 if m["raw_ok"] else 0.0)
        yield gauge("raw_log_bytes", "disk use of the raw log files", m["raw_bytes"])
        yield gauge("store_ok", "1 if estimates are being saved", 1.0 if m["store_ok"] else 0.0)
        yield gauge("uptime_seconds", "seconds since the service started", m["uptime"])
        yield gauge("channels_stale", "mapped channels currently stale", m["channels_stale"])
        yield gauge("active_stage", "stage whose gating window is open (0: none)", m["active_stage"] or 0)
        dec = m["decode"] or {}
        c = CounterMetricFamily("vdp_decode_errors", "decode errors by kind", labels=["kind"])
        for kind, n in (dec.get("errors_by_kind") or {}).items():
            c.add_metric([kind], n)
        yield c
        resets = CounterMetricFamily("vdp_filter_resets", "divergence resets by filter kind", labels=["filter"])
        for kind, n in m["resets"].items():
            resets.add_metric([kind], n)
        yield resets
        value = GaugeMetricFamily("vdp_estimate", "current estimate (SI units)", labels=["parameter"])
        std = GaugeMetricFamily("vdp_estimate_std", "1-sigma of the current estimate", labels=["parameter"])
        valid = GaugeMetricFamily("vdp_estimate_valid", "1 if the estimate is valid", labels=["parameter"])
        for name, p in m["parameters"].items():
            # an unknown number is left out, never exported as NaN (Estimate holds None then)
            if p.value is not None:
                value.add_metric([name], p.value)
            if p.std is not None:
                std.add_metric([name], p.std)
            valid.add_metric([name], 1.0 if p.valid else 0.0)
        yield value
        yield std
        yield valid


Svc = Annotated[Any, Depends(_service)]


def create_app(settings: Settings, service=None) -> FastAPI:
    """The API.  Without ``service`` the app makes one from ``settings`` and runs it in its lifespan."""
    owned = service is None

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if owned:
            from ..live import Service

            svc = Service(settings)
            svc.start()
            app.state.service = svc
        try:
            yield
        finally:
            if owned:
                app.state.service.stop()
                app.state.service = None

    app = FastAPI(
        title="vdp",
        version=__version__,
        lifespan=lifespan,
        docs_url=None,  # /docs and /redoc come from api.dashboard, with their assets served locally
        redoc_url=None,
        description="Vehicle dynamic parameters estimated live from the CAN bus "
        "(two-stage UKF, Li et al. 2021). Unknown numbers are null with valid false.",
    )
    app.state.settings = settings
    app.state.service = service
    dashboard.install(app)
    registry = CollectorRegistry(auto_describe=False)  # per app: two apps in one process never clash
    registry.register(_Metrics(app))
    app.state.registry = registry
    err = {"model": models.Problem}

    @app.exception_handler(VdpError)
    async def _vdp_error(request: Request, exc: VdpError):
        from ..live import Unavailable

        # Unavailable / store refused: try later or elsewhere.  Anything else: the request was wrong.
        code = 503 if isinstance(exc, (Unavailable, StoreError)) else 400
        return JSONResponse({"detail": str(exc)}, status_code=code)

    @app.get("/health", response_model=models.Health, summary="ok, or degraded with the reasons")
    def health(svc: Svc) -> Any:
        return svc.health()

    @app.get("/estimates", response_model=models.Estimates, summary="current estimates (UKF and EKF baseline)")
    def estimates(svc: Svc) -> Any:
        return svc.estimates()

    @app.get(
        "/estimates/history",
        response_model=models.History,
        responses={400: err, 503: err},
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

    @app.get("/status", response_model=models.Status, summary="bus, decoding, channels, gating, logs, store")
    def status(svc: Svc) -> Any:
        return svc.status()

    @app.post(
        "/reset",
        response_model=models.ResetResult,
        dependencies=[Depends(_authorize)],
        responses={400: err, 401: err, 403: err, 503: err},
        summary="clear stage 1, 2 or all (bearer token; disabled without one)",
    )
    def reset(
        svc: Svc,
        stage: Annotated[Literal["1", "2", "all"] | None, Query(description="1, 2 or all")] = None,
        body: Annotated[models.ResetBody | None, Body()] = None,
    ) -> Any:
        which = stage if stage is not None else (str(body.stage) if body is not None else "all")
        return svc.reset(None if which == "all" else int(which))

    @app.get(
        "/metrics",
        response_class=PlainTextResponse,
        summary="Prometheus text format",
        responses={200: {"content": {CONTENT_TYPE_LATEST: {}}}},
    )
    def metrics() -> PlainTextResponse:
        return PlainTextResponse(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)

    return app
