"""The bus's random extras of a drive: uniform draws for frame drops, and unrelated frames."""

from __future__ import annotations

import heapq
from collections.abc import Iterator

import can
import numpy as np


class _Uniforms:
    def __init__(self, rng: np.random.Generator, block: int = 4096):
        self.rng, self.block, self.buf, self.i = rng, block, [], 0

    def __call__(self) -> float:
        if self.i >= len(self.buf):
            self.buf, self.i = self.rng.random(self.block).tolist(), 0
        self.i += 1
        return self.buf[self.i - 1]


class _Filler:
    """Unrelated frames (IDs not in the DBC, random payloads), each ID at ``rate`` Hz."""

    def __init__(self, rng: np.random.Generator, n: int, rate: float, taken: set[int], start_us: int):
        free = np.array([i for i in range(0x800) if i not in taken])
        self.ids = [int(i) for i in rng.choice(free, size=n, replace=False)]
        self.period_us = max(1, int(round(1e6 / rate)))
        self.rng = rng
        self.heap = [(start_us + int(rng.integers(0, self.period_us)), i) for i in self.ids]
        heapq.heapify(self.heap)

    def until(self, end_us: int, chan: str) -> Iterator[can.Message]:
        heap = self.heap
        while heap[0][0] < end_us:
            ts, fid = heapq.heappop(heap)
            heapq.heappush(heap, (ts + self.period_us, fid))
            yield can.Message(
                timestamp=ts / 1e6,
                arbitration_id=fid,
                is_extended_id=False,
                data=self.rng.bytes(8),
                channel=chan,
                is_rx=False,
            )
