"""Time alignment: decoded channel values in, fixed-rate samples out.

Frames of different messages arrive at their own times and periods.  The
:class:`Aligner` turns them into :class:`Sample` rows on a fixed tick grid
(the estimator's tick, 20 ms): each channel is linearly interpolated to the tick from the
values around it, or held if no later value has come yet.  A tick is emitted
once bus time has passed it by ``delay``, so the value after the tick is
usually known.  A channel silent for longer than its ``stale_after`` is NaN in
the sample, so no filter ever predicts across the gap.

Bus time that goes backwards is rejected; a jump forward larger than
``max_gap`` restarts the grid (a gap marker, never one huge step).  When
``RESYNC_AFTER`` frames in a row are behind the clock, it was the clock that
moved (a clock step back, or one frame stamped far in the future): the grid
restarts at the new time, so one bad timestamp never stops estimation.

:class:`SampleRing` keeps the most recent samples in a fixed-size array, so
memory stays flat however long the car drives.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from . import channels
from .core.sample import Sample

log = logging.getLogger(__name__)

_DEPTH = 4  # values kept per channel for interpolation
_EPS = 1e-6  # s: time comparisons tolerate float rounding of absolute Unix times (~2e-7 s)
RESYNC_AFTER = 10  # frames in a row behind the clock before the grid follows them back
_MAX_T = 1e10  # s (year 2286): bus times beyond are refused; near 1e21 floats are 131,072 s apart


class Aligner:
    def __init__(
        self,
        stale_after: np.ndarray | None = None,
        tick: float = 0.01,
        delay: float = 0.012,
        max_gap: float = 1.0,
        limits: tuple[list[float], list[float]] | None = None,
    ):
        self.tick = tick
        self.delay = delay
        self.max_gap = max_gap
        self.stale_after = np.full(channels.N, 0.1) if stale_after is None else np.asarray(stale_after, dtype=float)
        self._stale = [float(x) for x in self.stale_after]
        # per channel, the lowest and highest value taken (channels.limits): beyond is dropped
        lo, hi = limits if limits is not None else ([-math.inf] * channels.N, [math.inf] * channels.N)
        self._lo, self._hi = [float(x) for x in lo], [float(x) for x in hi]
        self.refused: dict[int, list[float]] = {}  # channel -> [values dropped, lowest, highest]
        self.reset()

    def _refuse(self, ch: int, lo: float, hi: float, n: int = 1) -> None:
        r = self.refused.get(ch)
        if r is None:
            self.refused[ch] = [n, lo, hi]
        else:
            r[0] += n
            r[1], r[2] = min(r[1], lo), max(r[2], hi)

    def keep_block(self, per_channel: dict) -> dict:
        """``per_channel`` (channel -> (frame indices, values), vdp.io.bulk's) without the values
        beyond the channel's limits, which are counted as :meth:`push` counts them."""
        out = {}
        for c, (fi, fv) in per_channel.items():
            bad = (fv < self._lo[c]) | (fv > self._hi[c])  # NaN goes on, as in push
            if bad.any():
                self._refuse(c, float(fv[bad].min()), float(fv[bad].max()), int(bad.sum()))
                fi, fv = fi[~bad], fv[~bad]
            out[c] = (fi, fv)
        return out

    def refused_dict(self) -> dict[str, dict]:
        """Values dropped per channel name: how many, the range they spanned, the channel's limits."""
        return {
            channels.NAMES[c]: {"values": int(n), "min": lo, "max": hi, "limits": [self._lo[c], self._hi[c]]}
            for c, (n, lo, hi) in sorted(self.refused.items())
        }

    def reset(self) -> None:
        # per channel: the last _DEPTH (time, value) pairs, oldest first (plain
        # lists: this runs for every decoded frame, where numpy's overhead dominates)
        self._t = [[-math.inf] * _DEPTH for _ in range(channels.N)]
        self._v = [[math.nan] * _DEPTH for _ in range(channels.N)]
        self._emitted = [-math.inf] * channels.N  # newest time already reported fresh
        self.next_tick: float | None = None
        self.last_time = -math.inf
        self.gap = True
        self.clock_backwards = 0
        self.clock_jumps = 0
        self._behind = 0  # frames in a row behind the clock

    def newest(self, ch: int) -> float:
        """Bus time of the newest value of channel ``ch`` (-inf if none)."""
        return self._t[ch][-1]

    def push(self, t: float, pairs) -> list[Sample]:
        """Add one frame's (channel, value) pairs at bus time ``t``; return due ticks."""
        if not -_MAX_T < t < _MAX_T:  # NaN, inf, or so large a tick no longer advances (1e21 + 0.01 == 1e21)
            self.clock_backwards += 1
            return []
        out: list[Sample] = []
        back = t < self.last_time - 1e-3
        if back:
            self.clock_backwards += 1
            self._behind += 1
            if self._behind < RESYNC_AFTER:
                return out
            # Not a stray frame: the clock stepped back, or the newest time was one frame's
            # glitch.  Waiting for the clock to catch up would stop estimation until then.
            log.info(
                "bus time went %.3f s back for %d frames in a row; restarting the sample grid",
                self.last_time - t,
                self._behind,
            )
            self.last_time = t
        self._behind = 0
        if back or self.next_tick is None or t - self.last_time > self.max_gap:
            if self.next_tick is not None:
                self.clock_jumps += 1
                if not back:
                    log.info("bus time jumped %.3f s forward; restarting the sample grid", t - self.last_time)
            # after a step back, values older than those already reported are new again
            keep_emitted = self._emitted if not back else [-math.inf] * channels.N
            self.reset_history()
            self._emitted = keep_emitted
            # ticks are whole multiples of the tick (n * tick, never a running sum), so
            # a log with absolute times and one restarted at 0 put them at the same places
            self._n = math.ceil(t / self.tick - _EPS)
            self.next_tick = self._n * self.tick
            self.gap = True
        else:
            while self.next_tick + self.delay <= t:
                out.append(self._sample(self.next_tick))
                self._n += 1
                self.next_tick = self._n * self.tick
        self.last_time = max(self.last_time, t)
        lo, hi = self._lo, self._hi
        for ch, value in pairs:
            if value < lo[ch] or value > hi[ch]:  # beyond what a car can read (NaN goes on)
                self._refuse(ch, value, value)
                continue
            th, vh = self._t[ch], self._v[ch]
            del th[0], vh[0]
            th.append(t)
            vh.append(value)
        return out

    def reset_history(self) -> None:
        self._t = [[-math.inf] * _DEPTH for _ in range(channels.N)]
        self._v = [[math.nan] * _DEPTH for _ in range(channels.N)]

    def _sample(self, T: float) -> Sample:
        n = channels.N
        values = [math.nan] * n
        ages = [math.inf] * n
        fresh = [False] * n
        emitted = self._emitted
        for ch in range(n):
            th = self._t[ch]
            if th[-1] == -math.inf:
                continue
            vh = self._v[ch]
            k = 0  # index of the first value after T
            while k < _DEPTH and th[k] <= T + _EPS:  # a frame on the tick belongs to it
                k += 1
            if k == _DEPTH:
                v, age, before = vh[-1], T - th[-1], th[-1]  # hold
            elif k == 0 or th[k - 1] == -math.inf:
                v, age, before = vh[k], 0.0, -math.inf  # only later values: use the earliest
            else:
                t0, t1 = th[k - 1], th[k]
                v = vh[k - 1] + (T - t0) / (t1 - t0) * (vh[k] - vh[k - 1]) if t1 > t0 else vh[k]
                age, before = T - t0, t0
            if age > self._stale[ch]:
                v = math.nan
            values[ch], ages[ch] = v, age
            # fresh: a value at or before T that has not been reported yet
            if before > emitted[ch]:
                fresh[ch] = True
                emitted[ch] = before
        s = Sample(T, tuple(values), tuple(fresh), tuple(ages), self.gap)
        self.gap = False
        return s


class SampleRing:
    """The last ``capacity`` samples in a preallocated array (flat memory)."""

    def __init__(self, capacity: int = 3000):
        self.capacity = capacity
        self.t = np.full(capacity, math.nan)
        self.values = np.full((capacity, channels.N), math.nan)
        self.count = 0

    def append(self, s: Sample) -> None:
        i = self.count % self.capacity
        self.t[i] = s.t
        self.values[i] = s.values
        self.count += 1

    def extend(self, T: np.ndarray, Y: np.ndarray) -> None:
        """Append a block of samples' ticks and values (rows), as append on each would."""
        n = len(T)
        if n > self.capacity:  # only the newest fit; they land where append would put them
            T, Y, skip = T[-self.capacity :], Y[-self.capacity :], n - self.capacity
        else:
            skip = 0
        idx = (np.arange(len(T)) + self.count + skip) % self.capacity
        self.t[idx] = T
        self.values[idx] = Y
        self.count += n

    def latest(self, n: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The newest ``n`` samples in time order."""
        m = min(self.count, self.capacity if n is None else min(n, self.capacity))
        idx = (np.arange(self.count - m, self.count)) % self.capacity
        return self.t[idx], self.values[idx]
