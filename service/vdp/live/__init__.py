"""The live service behind ``vdp serve``: bus, raw log, estimation worker, store."""

from .service import Published, Service, Unavailable

__all__ = ["Published", "Service", "Unavailable"]
