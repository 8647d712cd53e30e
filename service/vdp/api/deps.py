"""FastAPI dependencies: the running service, the settings the app was built with, the reset token."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from ..live import Service
from ..settings import Settings
from .guard import token_problem


async def get_service(request: Request) -> Service:
    # async: a plain def dependency is run in a worker thread (see routes)
    svc = getattr(request.app.state, "service", None)
    if svc is None:
        raise HTTPException(503, "the service is starting")
    return svc


async def get_settings(request: Request) -> Settings:
    return request.app.state.settings


Svc = Annotated[Service, Depends(get_service)]
Config = Annotated[Settings, Depends(get_settings)]

_bearer = HTTPBearer(auto_error=False, description="the [api] reset_token of the config")
Bearer = Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]


def authorize(settings: Config, cred: Bearer) -> None:
    """POST /reset needs the configured bearer token; without one configured it is disabled.

    The gate (:mod:`.guard`) has checked the same before the body was read; this keeps the route
    safe on its own and names the scheme in the API docs."""
    header = None if cred is None else f"{cred.scheme} {cred.credentials}"
    problem = token_problem(settings.api.reset_token, header)
    if problem is not None:
        code, why = problem
        raise HTTPException(code, why, headers={"WWW-Authenticate": "Bearer"} if code == 401 else None)
