"""One aligned sample: what the aligner hands the estimator at each tick.

A :class:`Sample` is immutable (a named tuple: built once per tick, cheaply).
Channel values are read one way only, ``s.values[channels.X]`` (Python floats:
cheaper than numpy one by one).  The aligner fills the channel fields; the
estimator derives the rest (speed filter, gyro offsets) and passes on a copy
with them set (:meth:`derived`).
"""

from __future__ import annotations

import math
from typing import NamedTuple


class Sample(NamedTuple):
    t: float  # bus time of the tick [s]
    values: tuple[float, ...]  # per channel index; NaN if unknown or stale
    fresh: tuple[bool, ...]  # a value newer than the last tick's came in
    age: tuple[float, ...]  # s since the value before the tick (inf: never seen)
    gap: bool = False  # the first tick after a gap or a clock jump
    # derived by the estimator: the speed filter (GNSS + IMU) ...
    v_x: float = math.nan
    v_std: float = math.nan
    ax_bias: float = 0.0
    # ... and the gyro offsets learnt while driving straight
    yaw_bias: float = 0.0
    roll_bias: float = 0.0

    def derived(self, v_x: float, v_std: float, ax_bias: float, yaw_bias: float, roll_bias: float) -> Sample:
        """A copy with the derived fields set."""
        return Sample(self.t, self.values, self.fresh, self.age, self.gap, v_x, v_std, ax_bias, yaw_bias, roll_bias)


def block(T, Y, F, A, gap: bool) -> list[Sample]:
    """The samples of a block given as arrays (ticks, values, fresh, ages by channel; ``gap``:
    the first follows a gap), as the aligner builds them one by one."""
    rows = zip(T.tolist(), Y.tolist(), F.tolist(), A.tolist())
    return [Sample(t, tuple(y), tuple(f), tuple(a), gap and i == 0) for i, (t, y, f, a) in enumerate(rows)]
