"""The REST API of ``vdp serve``; see :func:`vdp.api.app.create_app`."""

from .app import check_host, create_app

__all__ = ["check_host", "create_app"]
