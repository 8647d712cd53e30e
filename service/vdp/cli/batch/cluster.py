"""vdp batch's Dask cluster (one of its own on this host, or one named) and its progress line."""

from __future__ import annotations

import logging
import os
import sys
import time

from ...errors import ConfigError


def client(args):
    """A Dask client: on ``--scheduler``, or on a local cluster bound to 127.0.0.1 with no dashboard."""
    try:
        from distributed import Client, LocalCluster
    except ModuleNotFoundError:
        raise ConfigError("vdp batch needs Dask: pip install 'vdp[fleet]'") from None
    if not getattr(args, "verbose", 0):  # Dask's INFO lines (scheduler, nannies) are noise here
        for name in list(logging.root.manager.loggerDict):
            if name.startswith("distributed"):
                logging.getLogger(name).setLevel(logging.ERROR)
    if args.scheduler:
        try:
            return Client(args.scheduler, timeout="20s"), None
        except OSError as exc:
            raise ConfigError(f"--scheduler {args.scheduler}: cannot reach the scheduler: {exc}") from None
    n = args.workers if args.workers is not None else (os.cpu_count() or 1)
    if n < 1:
        raise ConfigError(f"--workers {n}: give at least 1")
    # host: scheduler, nannies and workers listen on loopback only (nothing on the host
    # network).  No dashboard; the scheduler still serves its health routes over HTTP,
    # and without an address it would take port 8787 on every interface of its host:
    # loopback and a free port instead.  One thread per worker: a replay is pure Python
    # under the GIL, processes are what run in parallel.
    cluster = LocalCluster(
        n_workers=n,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        worker_dashboard_address=None,
        scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"},
        silence_logs=logging.ERROR,
    )
    return Client(cluster), cluster


class Progress:
    """Logs done of all, on one line of stderr (a terminal only)."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.done, self.failed = total, 0, 0
        self.enabled = enabled and sys.stderr.isatty()
        self.t0 = time.monotonic()

    def step(self, failed: bool) -> None:
        self.done += 1
        self.failed += failed
        if not self.enabled:
            return
        el = time.monotonic() - self.t0
        frac = self.done / max(self.total, 1)
        eta = el * (1 - frac) / frac if frac else 0.0
        bar = "#" * int(30 * frac)
        sys.stderr.write(
            f"\r[{bar:<30}] {self.done}/{self.total} logs  {self.failed} failed  {el:5.0f} s  ETA {eta:4.0f} s "
        )
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")
