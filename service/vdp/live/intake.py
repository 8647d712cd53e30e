"""The receive-thread side of estimation: hand frames to a bounded queue, never block.

One estimation worker drains the queue (the pipeline is not thread-safe), so a
slow filter step can never stall python-can's receive thread.  If the queue is
ever full the frame is dropped and counted: /status and /health report it.
"""

from __future__ import annotations

import logging
import queue
import time

import can

log = logging.getLogger(__name__)


class Intake(can.Listener):
    def __init__(self, q: queue.Queue):
        self.q = q
        self.received = 0
        self.dropped = 0
        self.failures = 0
        self.last_rx: float | None = None  # time.monotonic() of the newest frame

    def on_message_received(self, msg: can.Message) -> None:
        self.received += 1
        self.last_rx = time.monotonic()
        try:
            self.q.put_nowait(msg)
        except queue.Full:
            self.dropped += 1
            if self.dropped == 1 or self.dropped % 10_000 == 0:
                log.error(
                    "estimation is behind: %d frame(s) dropped so far (queue of %d full)", self.dropped, self.q.maxsize
                )
        except Exception:  # the Notifier thread must survive anything
            self.failures += 1
            if self.failures == 1:
                log.exception("queueing a frame failed")

    def on_error(self, exc: Exception) -> None:
        """Bus errors are the BusLink's business; defined so python-can sees them handled."""

    def stop(self) -> None:
        """The Notifier calls this on each reconnect; the queue stays."""
