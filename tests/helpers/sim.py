"""A simulated drive as a replay source, for tests that replay without writing a log."""

from __future__ import annotations

from vdp.sim.run import Simulation


class Frames:
    """What open_log returns, minus the file: frames, a position, a path and empty stats."""

    def __init__(self, sim: Simulation):
        self.sim, self.position, self.path = sim, 0, f"simulated {sim.scenario.name}"

    def __iter__(self):
        return self.sim.frames()

    class stats:
        @staticmethod
        def as_dict() -> dict:
            return {}
