"""Ingest: bus -> (raw log, estimation queue), and the simulated bus feed.

Owns the bounded frame queue, the listeners python-can's Notifier calls (they
only append to the raw log and put frames in the queue), the bus link that
reconnects with backoff, and, with ``--simulate``, the simulator sending onto a
virtual bus of its own.  Nothing here decodes or estimates: the estimation
worker (:mod:`vdp.live.estimation`) takes frames from :attr:`Ingest.queue`.
"""

from __future__ import annotations

import itertools
import logging
import os
import queue
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from ..settings import Settings
from .bus import BusLink, frame_channel, open_bus
from .intake import FrameQueue, Intake
from .rawlog import RawLog

log = logging.getLogger(__name__)

_sim_ids = itertools.count(1)
RATE_WINDOW = 5.0  # s over which frames/s is measured
SIM_QUEUE = 8192  # frames: the simulator waits while half of this is queued (simfeed.PAUSE_ABOVE)


class Ingest:
    def __init__(self, settings: Settings, profile, opener: Callable | None = None):
        sv = settings.service
        # blocks of frames for estimation, bounded in frames: a block that finds it full is thinned
        self.queue: queue.Queue = FrameQueue(maxsize=sv.queue_size)
        self.intake = Intake(self.queue)
        raw = settings.raw_log
        floor = None if raw.min_free_mb is None else raw.min_free_mb << 20
        self.rawlog = (
            RawLog(raw.dir, raw.max_bytes, raw.max_files, raw.prefix, min_free=floor, drops=self.drops)
            if raw.enabled
            else None
        )
        bus_cfg = settings.bus
        listeners: list = []
        if settings.simulate.enabled:
            # A virtual channel of our own: two services in one process never share frames.
            channel = f"vdp-sim-{os.getpid()}-{next(_sim_ids)}"
            bus_cfg = replace(bus_cfg, interface="virtual", channel=channel, kwargs={})
        if self.rawlog is not None:  # the raw log first: it is what must never fall behind
            listeners.append(self.rawlog)
        listeners.append(self.intake)
        self.bus_cfg = bus_cfg
        # every frame gets the configured channel before anything sees it (guard_recv)
        chan = frame_channel(bus_cfg, profile.bus_channel)
        self.channel = chan
        if self.rawlog is not None:
            self.rawlog.channel = chan
        self.link = BusLink(bus_cfg, listeners, sv.reconnect_min, sv.reconnect_max, opener or open_bus, chan)
        self.sim = None
        if settings.simulate.enabled:
            from .simfeed import SimFeed

            self.sim = SimFeed(profile, settings.simulate, bus_cfg.channel, self.sim_backlog)
        self._rates: deque = deque()
        self.frames_per_s = 0.0
        self._dropped_seen = 0
        self.dropped_at: float | None = None  # monotonic time frames were last found dropped

    def drops(self) -> dict:
        """Frames lost before vdp read them, by cause, so far (the raw log's index, /status)."""
        i = self.link.info
        return {"kernel": i.kernel_drops, "controller_overruns": i.overruns}

    def open_rawlog(self) -> None:
        if self.rawlog is not None:
            self.rawlog.open()

    def start(self) -> None:
        """Start receiving (and simulating); the raw log is opened first (:meth:`open_rawlog`)."""
        self.link.start()
        if self.sim is not None:
            self.sim.start(ready=lambda: self.link.up)

    def stop(self) -> None:
        """Stop the simulator and the bus; the raw log stays open until :meth:`close`."""
        if self.sim is not None:
            self.sim.stop()
        self.link.stop()

    def close(self) -> None:
        if self.rawlog is not None:
            self.rawlog.close()

    def tick(self) -> None:
        """Housekeeping: flush the raw log (or retry it), measure the receive rate, note drops."""
        if self.rawlog is not None:
            self.rawlog.flush()
            self.rawlog.maybe_resume()
        now = time.monotonic()
        received = self.intake.received
        self._rates.append((now, received))
        while self._rates and now - self._rates[0][0] > RATE_WINDOW:
            self._rates.popleft()
        t0, n0 = self._rates[0]
        self.frames_per_s = (received - n0) / (now - t0) if now > t0 else 0.0
        if self.intake.dropped > self._dropped_seen:
            self._dropped_seen, self.dropped_at = self.intake.dropped, now
        self.link.poll_drops()

    # -- read side (any thread) ----------------------------------------------------------------
    def backlog(self) -> float:
        """Fill fraction of the estimation queue, counting the simulator's frames still on its
        virtual bus: that queue has no bound, so a lagging receive thread would grow it."""
        flight = self.sim.sent - self.intake.received if self.sim is not None else 0
        return (self.queue.qsize() + max(flight, 0)) / self.queue.maxsize

    def sim_backlog(self) -> float:
        """The simulator's view of the backlog: against at most SIM_QUEUE frames, so a simulation that
        runs ahead of estimation holds a few thousand frames in memory, not half of a car-sized queue."""
        flight = self.sim.sent - self.intake.received if self.sim is not None else 0
        return (self.queue.qsize() + max(flight, 0)) / min(self.queue.maxsize, SIM_QUEUE)

    def silent_for(self) -> float | None:
        last = self.intake.last_rx
        return None if last is None else time.monotonic() - last

    def status(self) -> dict[str, Any]:
        """The bus, queue, raw log and simulation parts of /status."""
        if self.rawlog is not None:
            # a frame counts as written once a flush finds it in a file in place: flushed now, /status says
            # what is on disk as it answers (one write and two stats, under the raw log's lock)
            self.rawlog.flush()
        return {
            "bus": {
                **self.link.status(),
                "frames": self.intake.received,
                "blocks": getattr(self.link.notifier, "blocks", None),
                "frames_per_s": self.frames_per_s,
                "last_frame_age_s": self.silent_for(),
            },
            # dropped: frames estimation skipped (thinned) because it was behind; the raw log has them
            "queue": {
                "depth": self.queue.qsize(),
                "capacity": self.queue.maxsize,
                "dropped": self.intake.dropped,
                "thinned": self.intake.dropped,
            },
            "raw_log": self.rawlog.stats() if self.rawlog is not None else {"enabled": False},
            "simulation": self.sim.status() if self.sim is not None else None,
        }
