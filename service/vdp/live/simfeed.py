"""``vdp serve --simulate``: the simulator drives an in-process python-can virtual bus.

The frames go through the same Notifier, raw log, queue and pipeline as on a
car; only the bus is virtual.  Timestamps are the simulator's own (the bus
keeps them: ``preserve_timestamps``), starting at the wall-clock time the feed
starts, so ``--sim-speed 20`` shows twenty seconds of driving per second
without changing what the filters see.  Unlike a real bus, a simulation can
wait: when the estimation queue is half full the feed pauses, so no frame is
ever dropped however fast it runs.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import can

from ..errors import VdpError
from ..settings import SimulateSettings

log = logging.getLogger(__name__)

PAUSE_ABOVE = 0.5  # queue fill fraction at which the feed waits for the estimator
RETRY_MIN, RETRY_MAX = 1.0, 30.0  # s between attempts to start a loop's simulation again


class SimFeed:
    def __init__(self, profile, cfg: SimulateSettings, channel: str, backlog: Callable[[], float]):
        from ..sim.run import Simulation  # imported here: only --simulate needs the simulator

        self.profile = profile
        self.cfg = cfg
        self.channel = channel
        self.backlog = backlog
        kw = {} if cfg.noise is None else {"noise": cfg.noise}
        # each loop drives with the next seed (SEED, SEED + 1, ...): the live demo's noise and
        # driving differ from loop to loop, as a car's drives do, instead of repeating one drive
        self.seed = cfg.seed
        self._make = lambda start: Simulation(profile, cfg.scenario, self.seed, start_time=start, **kw)
        # Start on a whole second: the estimator's sample grid then sits at the same phase
        # of the frames every run, so a simulated drive gives the same numbers each time.
        self._sim = self._make(float(int(time.time())))  # validates scenario and noise now
        self.truth = self._sim.truth
        self.sent = 0
        self.loops = 0
        self.sim_time = 0.0
        self.done = False
        self.error: str | None = None
        self.retries = 0  # failed attempts to start the scenario again
        # --sim-speed is a cap, not a promise: the feed waits when estimation falls behind,
        # and says so (once in the log, and in status() as the speed it really ran at)
        self.paused_s = 0.0
        self._said_slow = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def duration(self) -> float:
        return self._sim.duration

    def start(self, ready: Callable[[], bool]) -> None:
        self._thread = threading.Thread(target=self._run, args=(ready,), name="vdp-sim", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the scenario has been sent (or the feed failed); True if it ended."""
        if self._thread is None:
            return True
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def status(self) -> dict:
        return {
            "scenario": self.cfg.scenario,
            "speed": self.cfg.speed,
            "seed": self.seed,  # the current loop's (--seed, plus one per loop)
            "noise": self.truth.get("noise", {}).get("model", self.cfg.noise),
            "sim_time": self.sim_time,
            "duration": self.duration,
            "loops": self.loops,
            "frames_sent": self.sent,
            "paused_s": self.paused_s,
            "done": self.done,
            "error": self.error,
            "retries": self.retries,
            "truth": self.truth.get("parameters"),
        }

    def _run(self, ready: Callable[[], bool]) -> None:
        # Frames sent before the service's receiving bus exists would be lost.
        while not ready():
            if self._stop.wait(0.05):
                return
        try:
            bus = can.Bus(
                interface="virtual", channel=self.channel, preserve_timestamps=True, receive_own_messages=False
            )
        except Exception as exc:
            self.error = f"cannot open the virtual bus: {exc}"
            log.error("simulation: %s", self.error)
            return
        try:
            sim = self._sim
            while not self._stop.is_set():
                last = self._send(sim, bus)
                if self._stop.is_set() or not self.cfg.loop or last is None:
                    break
                self.loops += 1
                self.seed = self.cfg.seed + self.loops
                log.info("simulation: scenario %s done; starting it again (seed %d)", self.cfg.scenario, self.seed)
                sim = self._remake(float(int(last) + 2))
                if sim is None:
                    break
            self.done = not self._stop.is_set()
            if self.done:
                log.info(
                    "simulation: scenario %s done (%d frames); the service keeps serving", self.cfg.scenario, self.sent
                )
        except VdpError as exc:
            self.error = str(exc)
            log.error("simulation stopped: %s", exc)
        except Exception as exc:  # keep the service up; say what happened
            self.error = f"{type(exc).__name__}: {exc}"
            log.exception("simulation stopped")
        finally:
            bus.shutdown()

    def _remake(self, start: float):
        """The next loop's simulation; if it cannot be made (its DBC gone or unreadable for a
        moment), say why and retry with backoff instead of ending the feed.  None once stopped."""
        wait = RETRY_MIN
        while not self._stop.is_set():
            try:
                sim = self._make(start)
            except Exception as exc:
                self.error = f"cannot start the scenario again: {exc}"
                self.retries += 1
                log.error("simulation: %s; retrying in %.0f s", self.error, wait)
                if self._stop.wait(wait):
                    return None
                wait = min(2 * wait, RETRY_MAX)
                continue
            if self.error is not None:
                log.warning("simulation: running again after: %s", self.error)
                self.error = None
            return sim
        return None

    def _send(self, sim, bus: can.BusABC) -> float | None:
        speed = self.cfg.speed
        stop, backlog = self._stop, self.backlog
        t0 = w0 = None
        last = None
        for n, msg in enumerate(sim.frames()):
            ts = msg.timestamp
            if t0 is None:
                t0, w0 = ts, time.monotonic()
            if speed > 0:
                ahead = w0 + (ts - t0) / speed - time.monotonic()
                if ahead > 0.002 and stop.wait(ahead):
                    return None
            if not n & 0xFF:
                if stop.is_set():
                    return None
                if backlog() > PAUSE_ABOVE:
                    p0 = time.monotonic()
                    while backlog() > PAUSE_ABOVE:
                        if stop.wait(0.002):
                            return None
                    waited = time.monotonic() - p0
                    w0 += waited  # a pause is not lost time to catch up on
                    self.paused_s += waited
                    if speed > 0 and not self._said_slow:  # (speed 0 asks for exactly this)
                        self._said_slow = True
                        log.warning(
                            "simulation: estimation cannot keep up with --sim-speed %g; the simulator "
                            "waits for it (/status simulation.paused_s counts the waiting)",
                            speed,
                        )
            bus.send(msg)
            self.sent += 1
            last = ts
            self.sim_time = ts - t0
        return last
