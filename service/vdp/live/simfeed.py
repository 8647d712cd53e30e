"""``vdp serve --simulate``: the simulator drives an in-process python-can virtual bus.

The frames go through the same Notifier, raw log, queue and pipeline as on a
car; only the bus is virtual.  Timestamps are the simulator's own (the bus
keeps them: ``preserve_timestamps``), starting at the wall-clock time the feed
starts, so ``--sim-speed 20`` shows twenty seconds of driving per second
without changing what the filters see.  Unlike a real bus, a simulation can
wait: when the estimation queue is half full (or holds SIM_QUEUE / 2 frames) the feed
pauses, so no frame is ever dropped however fast it runs.  And it does not keep
pausing: a feed that had to wait in a window of ADAPT_EVERY seconds runs on at
the speed the machine sustained in it (less a tenth, for headroom), says so once,
and tries a little faster after each window without a wait, up to --sim-speed.
On a 2-core machine shared with other work the README's 20x is out of reach for
one Python process (the GIL puts simulator, receive and estimation on one
core); left alone, the feed ran at 12-14x with the queue half full, and all of a
core.
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
ADAPT_EVERY = 5.0  # s of wall time between speed adjustments
HEADROOM = 0.9  # run at this fraction of the speed the machine sustained
PROBE = 1.2  # after a window without waiting, try this much faster (up to --sim-speed)
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
        self.running_speed = cfg.speed  # the speed the feed runs at now (see ADAPT_EVERY)
        self._said_speed = False
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
            "running_speed": self.running_speed,
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
        stop, backlog = self._stop, self.backlog
        t0 = w0 = None
        last = None
        speed = self.running_speed
        win_w = win_t = win_p = None  # the adaptation window's start: wall, sim time, paused_s
        for n, msg in enumerate(sim.frames()):
            ts = msg.timestamp
            if t0 is None:
                first = t0 = ts
                w0 = time.monotonic()
                win_w, win_t, win_p = w0, ts, self.paused_s
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
                            self.cfg.speed,
                        )
                now = time.monotonic()
                if speed > 0 and now - win_w >= ADAPT_EVERY:
                    new = self._adapt(speed, (ts - win_t) / (now - win_w), self.paused_s > win_p)
                    if new != speed:
                        speed = self.running_speed = new
                        t0, w0 = ts, now  # paced from here at the new speed
                    win_w, win_t, win_p = now, ts, self.paused_s
            bus.send(msg)
            self.sent += 1
            last = ts
            self.sim_time = ts - first
        return last

    def _adapt(self, speed: float, achieved: float, waited: bool) -> float:
        """The next window's speed: what the machine sustained (less HEADROOM) after a wait, a little
        faster (PROBE, up to --sim-speed) after a window without one."""
        asked = self.cfg.speed
        if waited:
            new = max(round(HEADROOM * achieved, 1), 0.1)
            if new < speed and not self._said_speed:
                self._said_speed = True
                log.warning(
                    "simulation: this machine sustains about %.1fx real time (simulator, bus and estimation "
                    "share one Python process); running at %.1fx instead of --sim-speed %g, and trying faster "
                    "now and then (/status simulation.running_speed)",
                    achieved,
                    new,
                    asked,
                )
            return min(new, speed)
        return min(round(speed * PROBE, 1), asked) if speed < asked else speed
