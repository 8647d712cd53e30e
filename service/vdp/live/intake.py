"""The receive-thread side of estimation: hand blocks of frames to a bounded queue, never block.

One estimation worker drains the queue (the pipeline is not thread-safe), so a
slow filter step can never stall the receive thread.  The queue holds blocks
(lists of :data:`~vdp.live.reader.Frame` records) and is bounded in frames: a
block that finds it full is not queued, and its frames are counted as thinned
(``dropped``): estimation skips them, the raw log has every one, memory stays
bounded, and /status and /health say so.
"""

from __future__ import annotations

import logging
import queue
import time

import can

from .reader import frame_of

log = logging.getLogger(__name__)


class FrameQueue(queue.Queue):
    """A queue.Queue of blocks and commands, sized and counted in frames (a command counts one).

    ``maxsize`` is in frames (:class:`Intake` puts no more than the room left); ``qsize()`` is the
    frames (and commands) queued."""

    def _init(self, maxsize: int) -> None:
        super()._init(maxsize)
        self._n = 0

    def _qsize(self) -> int:
        return self._n

    def _put(self, item) -> None:
        self.queue.append(item)
        self._n += len(item) if type(item) is list else 1

    def _get(self):
        item = self.queue.popleft()
        self._n -= len(item) if type(item) is list else 1
        return item


class Intake(can.Listener):
    def __init__(self, q: queue.Queue):
        self.q = q
        self.received = 0
        self.dropped = 0  # frames estimation skipped because it was behind (the raw log has them)
        self.thinnings = 0  # blocks (or their tails) thinned
        self.failures = 0
        self.last_rx: float | None = None  # time.monotonic() of the newest frame

    def on_block(self, block: list) -> None:
        """One block from the receive thread: queued, or, past the queue's room, thinned and counted."""
        n = len(block)
        self.received += n
        self.last_rx = time.monotonic()
        q = self.q
        try:
            room = q.maxsize - q.qsize() if q.maxsize > 0 else n
            if room < n:  # estimation is behind: what does not fit is skipped, the oldest kept
                self._thin(n - max(room, 0))
                if room <= 0:
                    return
                block = block[:room]
            q.put_nowait(block)
        except queue.Full:  # a command took the room meanwhile
            self._thin(len(block))
        except Exception:  # the receive thread must survive anything
            self.failures += 1
            if self.failures == 1:
                log.exception("queueing a block failed")

    def _thin(self, n: int) -> None:
        self.dropped += n
        self.thinnings += 1
        if self.thinnings == 1 or self.thinnings % 1000 == 0:
            log.warning(
                "estimation is behind the bus: %d frame(s) not estimated so far (queue of %d frames full); "
                "the raw log keeps every frame",
                self.dropped,
                self.q.maxsize,
            )

    def on_message_received(self, msg: can.Message) -> None:
        """One frame (a plain Notifier, tests): a block of one."""
        try:
            block = [frame_of(msg)]
        except Exception:
            self.failures += 1
            if self.failures == 1:
                log.exception("queueing a frame failed")
            return
        self.on_block(block)

    def on_error(self, exc: Exception) -> None:
        """Bus errors are the BusLink's business; defined so python-can sees them handled."""

    def stop(self) -> None:
        """The Notifier calls this on each reconnect; the queue stays."""
