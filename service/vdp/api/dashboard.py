"""The live dashboard at ``/``, the API docs at ``/docs`` and ``/redoc``, and ``/export``: all offline.

A car has no internet: every asset is served by vdp itself.  The dashboard is plain
HTML, JS and SVG from ``api/static``; swagger-ui and redoc come from the
``fastapi-offline`` package's files, installed from the package index with vdp.  The
page polls the public JSON endpoints (``/estimates``, ``/status``, ``/health``), so a
client that goes away leaves nothing behind on the server.
"""

from __future__ import annotations

import logging
import unicodedata
from importlib.resources import files
from pathlib import Path
from typing import Annotated, Any, Literal
from urllib.parse import quote

from fastapi import APIRouter, FastAPI, Query, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, PlainTextResponse
from fastapi.staticfiles import StaticFiles

from ..core import mass
from ..core.params import SPECS
from ..export import FORMATS, Constants, render
from ..text import clean
from .deps import Svc

log = logging.getLogger(__name__)

STATIC = Path(str(files("vdp.api") / "static"))
DOCS_ASSETS = "/docs-assets"
# Only this service: redoc's bundle fetches its vendor's logo from the internet, and the
# browser must not even try (a car has no internet; an engineer's laptop should not leak).
LOCAL_ONLY = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data: blob:; "
    "style-src 'self' 'unsafe-inline'; script-src 'self' 'unsafe-inline' blob:; "
    "worker-src 'self' blob:; font-src 'self' data:; connect-src 'self'"
}


def docs_assets() -> Path | None:
    """swagger-ui and redoc as installed by the fastapi-offline package (None if it is missing)."""
    try:
        return Path(str(files("fastapi_offline") / "static"))
    except ModuleNotFoundError:
        return None


def install(app: FastAPI) -> None:
    """Add the dashboard, the offline docs and /export to ``app`` (made with docs_url=None, redoc_url=None)."""
    app.mount("/static", StaticFiles(directory=STATIC), name="static")
    assets = docs_assets()
    if assets is not None and assets.is_dir():
        app.mount(DOCS_ASSETS, StaticFiles(directory=assets), name="docs-assets")
    else:
        log.warning("fastapi-offline is not installed: /docs and /redoc have no assets (pip install fastapi-offline)")
    app.include_router(router)


router = APIRouter()
Format = Literal[tuple(FORMATS)]  # type: ignore[valid-type]  # an unknown one is a 422 naming the known


@router.get("/", include_in_schema=False)
def dashboard() -> FileResponse:
    return FileResponse(STATIC / "index.html", media_type="text/html", headers=LOCAL_ONLY)


@router.get("/docs", include_in_schema=False)
def swagger(request: Request) -> HTMLResponse:
    return _local(
        get_swagger_ui_html(
            openapi_url=request.app.openapi_url,
            title=f"{request.app.title} - API docs",
            swagger_js_url=f"{DOCS_ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{DOCS_ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{DOCS_ASSETS}/favicon.png",
        )
    )


@router.get("/redoc", include_in_schema=False)
def redoc(request: Request) -> HTMLResponse:
    return _local(
        get_redoc_html(
            openapi_url=request.app.openapi_url,
            title=f"{request.app.title} - API reference",
            redoc_js_url=f"{DOCS_ASSETS}/redoc.standalone.js",
            redoc_favicon_url=f"{DOCS_ASSETS}/favicon.png",
            with_google_fonts=False,  # a font from the internet would stall the page in the car
        )
    )


def _local(page: HTMLResponse) -> HTMLResponse:
    page.headers.update(LOCAL_ONLY)
    return page


@router.get("/dashboard/meta", summary="what the dashboard needs once: vehicle, parameters, priors")
def meta(svc: Svc) -> dict[str, Any]:
    prof = svc.profile
    return {
        "vehicle": prof.vehicle.name,
        "parameters": {
            s.name: {
                "unit": s.unit,
                "stage": s.stage,
                "description": s.description,
                "prior": {"value": prof.priors[s.name].value, "std": prof.priors[s.name].std},
            }
            for s in SPECS
        }
        | {
            # the mass as driven (core.mass): a card like the six's; /estimates says whether it is learnt
            mass.NAME: {
                "unit": mass.UNIT,
                "stage": mass.STAGE,
                "description": "vehicle mass as driven (kerb weight, occupants, load)",
                "prior": {"value": prof.vehicle.mass, "std": mass.PRIOR_REL * prof.vehicle.mass},
            }
        },
    }


@router.get(
    "/export",
    response_class=PlainTextResponse,
    summary="the current estimates as a CommonRoad, CARLA, JSON or TOML parameter file",
    responses={200: {"content": {m: {} for _, m in FORMATS.values()}}},
)
def export(svc: Svc, format: Annotated[Format, Query(description="the file layout")]) -> PlainTextResponse:
    params = svc.estimates()["parameters"]
    text = render(format, params, Constants.of(svc.profile.vehicle), source="vdp serve")
    suffix, media = FORMATS[format]
    name = f"{svc.profile.vehicle.name}.{format}.{suffix}"
    return PlainTextResponse(text, media_type=media, headers={"Content-Disposition": disposition(name)})


def disposition(name: str) -> str:
    """``inline`` with ``name`` as RFC 6266 says: the UTF-8 name percent-encoded (``filename*``) and
    an ASCII one beside it for old clients.  The name is the profile's vehicle: put in as it was,
    a letter beyond Latin-1 ("Škoda") was a 500, a newline cut the connection and a quote added
    parameters of its own."""
    utf8 = quote(clean(name), safe="")  # every byte but letters, digits and -._~ percent-encoded
    ascii_ = "".join(
        c if c.isascii() and (c.isalnum() or c in " -._()+,") else "_"
        for c in unicodedata.normalize("NFKD", clean(name))
        if not unicodedata.combining(c)  # (Škoda -> Skoda)
    )
    return f"inline; filename=\"{ascii_}\"; filename*=UTF-8''{utf8}"
