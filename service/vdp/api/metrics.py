"""``/metrics``: a Prometheus collector reading the service when scraped (no second set of counters)."""

from __future__ import annotations

from fastapi import APIRouter, FastAPI, Request
from fastapi.responses import PlainTextResponse
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily


def install(app: FastAPI) -> None:
    """A registry per app (two apps in one process never clash) and the route that reads it."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(Collector(app))
    app.state.registry = registry
    app.include_router(router)


router = APIRouter()


@router.get(
    "/metrics",
    response_class=PlainTextResponse,
    summary="Prometheus text format",
    responses={200: {"content": {CONTENT_TYPE_LATEST: {}}}},
)
def metrics(request: Request) -> PlainTextResponse:
    return PlainTextResponse(generate_latest(request.app.state.registry), media_type=CONTENT_TYPE_LATEST)


class Collector:
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
        yield counter("frames_dropped", "frames not estimated because estimation fell behind (thinned)", m["dropped"])
        lost = CounterMetricFamily(
            "vdp_frames_lost", "frames lost before vdp read them (not in the raw log), by cause", labels=["cause"]
        )
        if m.get("kernel_drops") is not None:
            lost.add_metric(["kernel_receive_buffer"], m["kernel_drops"])
        lost.add_metric(["controller_overrun"], m.get("controller_overruns", 0))
        yield lost
        if m.get("receive_buffer") is not None:
            yield gauge("receive_buffer_bytes", "kernel receive buffer of the bus socket", m["receive_buffer"])
        yield counter("frames_estimated", "frames fed to the estimation pipeline", m["fed"])
        yield counter("samples", "aligned samples the estimator saw", m["samples"])
        yield counter("bus_reconnects", "bus reconnects", m["reconnects"])
        yield counter("bus_errors", "bus errors (open failures, receive errors)", m["bus_errors"])
        yield counter("bus_garbage", "datagrams on the bus interface that held no CAN frame", m.get("bus_garbage", 0))
        yield counter("estimation_errors", "frames on which estimation raised", m["errors"])
        yield counter("raw_log_accepted", "frames handed to the raw log", m.get("raw_accepted", 0))
        yield counter("raw_log_frames", "frames written to the raw log (in a file found in place)", m["raw_frames"])
        yield counter("raw_log_lost", "frames the raw log could not write (stopped, write failed)", m["raw_lost"])
        yield counter(
            "raw_log_reopened",
            "times the raw log's file or directory vanished and was made again",
            m.get("raw_reopened", 0),
        )
        yield counter("store_commits", "batches committed to the estimate store", m["store_commits"])
        yield counter(
            "store_recoveries", "damaged estimate stores moved aside for a fresh one", m.get("store_recoveries", 0)
        )
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
