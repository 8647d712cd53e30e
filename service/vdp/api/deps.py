"""FastAPI dependencies: the running service, the settings the app was built with, the reset token."""

from __future__ import annotations

import hmac
from typing import Annotated

from fastapi import Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from ..live import Service
from ..settings import Settings


def get_service(request: Request) -> Service:
    svc = getattr(request.app.state, "service", None)
    if svc is None:
        raise HTTPException(503, "the service is starting")
    return svc


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


Svc = Annotated[Service, Depends(get_service)]
Config = Annotated[Settings, Depends(get_settings)]

_bearer = HTTPBearer(auto_error=False, description="the [api] reset_token of the config")
Bearer = Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]


def authorize(settings: Config, cred: Bearer) -> None:
    """POST /reset needs the configured bearer token; without one configured it is disabled."""
    token = settings.api.reset_token
    if not token:
        raise HTTPException(403, "POST /reset is disabled: no [api] reset_token is configured")
    if cred is None or cred.scheme.lower() != "bearer":
        raise HTTPException(401, "a bearer token is required", headers={"WWW-Authenticate": "Bearer"})
    # Constant time, on bytes: compare_digest refuses non-ASCII str.
    if not hmac.compare_digest(cred.credentials.encode("utf-8"), token.encode("utf-8")):
        raise HTTPException(403, "wrong token")
