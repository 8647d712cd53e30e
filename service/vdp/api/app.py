"""The REST API: a FastAPI app factory over a :class:`vdp.live.Service`.

``create_app(settings)`` builds nothing at import time: the settings (a
:class:`~vdp.settings.Settings`, or the path of a config file to load) are
made here, and the service is made and started in the app's lifespan (or
passed in, already running, by a test).  The routes live in
:mod:`~vdp.api.routes`, :mod:`~vdp.api.metrics` and :mod:`~vdp.api.dashboard`
and get the service and settings through :mod:`~vdp.api.deps`.  HTTP status
codes are decided in this package and only here; the service raises vdp errors.
"""

from __future__ import annotations

import logging
import sqlite3
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from .. import __version__, live
from ..errors import StoreError, VdpError
from ..settings import Settings, load_settings
from ..store import is_damage
from . import dashboard, metrics, routes
from .guard import Gate

log = logging.getLogger(__name__)

LOOPBACK = ("127.0.0.1", "::1", "localhost")


def check_host(host: str) -> None:
    """Serving beyond this machine is allowed, but only on purpose."""
    if host not in LOOPBACK:
        log.warning(
            "the API listens on %s, not only on this machine: anyone who can reach it can read "
            "the estimates. Keep [api] reset_token secret, and firewall the port.",
            host,
        )


async def _vdp_error(request: Request, exc: Exception) -> JSONResponse:
    # Unavailable / store refused: try later or elsewhere.  Anything else: the request was wrong.
    code = 503 if isinstance(exc, (live.Unavailable, StoreError)) else 400
    return JSONResponse({"detail": str(exc)}, status_code=code)


async def _sqlite_error(request: Request, exc: Exception) -> JSONResponse:
    # The store wraps its own queries; this catches any other route's: a damaged file is moved aside
    # for a fresh one (as at start), and the answer is "try again", never a 500 with /health saying ok.
    svc = getattr(request.app.state, "service", None)
    if svc is not None and is_damage(exc):
        svc.writer.damaged(exc)
    log.error("estimate store error on %s: %s", request.url.path, exc)
    return JSONResponse({"detail": f"the estimate store failed ({exc}); see /health"}, status_code=503)


class _App(FastAPI):
    """FastAPI, but ``GET /estimates`` is answered from the published snapshot before the middleware
    stack (routes.answer_estimates); a server's HostGuard still comes first (vdp serve)."""

    async def __call__(self, scope, receive, send) -> None:
        if not await routes.answer_estimates(self, scope, send):
            await super().__call__(scope, receive, send)


def create_app(
    settings: Settings | str | Path, service: live.Service | None = None, max_requests: int = 1024
) -> FastAPI:
    """The API.  Without ``service`` the app makes one from ``settings`` and runs it in its lifespan.

    ``max_requests``: requests in flight at most (GET /health is never refused), see :mod:`.guard`."""
    if not isinstance(settings, Settings):
        settings = load_settings(settings)
    owned = service is None

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if owned:
            app.state.service = live.Service(settings)  # looked up now: a test may stand in its own
            app.state.service.start()
        try:
            yield
        finally:
            if owned:
                app.state.service.stop()
                app.state.service = None

    app = _App(
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
    app.add_exception_handler(VdpError, _vdp_error)
    app.add_exception_handler(sqlite3.Error, _sqlite_error)
    # outermost: token and size are checked before anything reads the body
    app.add_middleware(Gate, settings=settings, max_requests=max(1, max_requests))
    dashboard.install(app)
    app.include_router(routes.router)
    metrics.install(app)
    return app
