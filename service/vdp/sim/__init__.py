"""The simulator: the paper's manoeuvres, truth physics, sensors and CAN encoding.

Modules: :mod:`.truth` (Table 6 unknowns), :mod:`.vehicle` (pure physics),
:mod:`.driver`, :mod:`.scenario`, :mod:`.sensors`, :mod:`.encode` (profile -> DBC),
:mod:`.run` (streaming frames; its clock and profile lookup in :mod:`.base`, drops
and filler frames in :mod:`.filler`), :mod:`.trace` (physics only), :mod:`.logfile`
(log and truth files), :mod:`.bus` (live bus).

``simulate``, ``Simulation``, ``trace``, ``write_log`` and friends are importable from
here; they load lazily so that ``vdp.sim.vehicle`` stays free of python-can.
"""

from __future__ import annotations

_RUN = (
    "Simulation",
    "simulate",
    "trace",
    "write_log",
    "write_truth",
    "truth_path",
    "send_live",
    "tee_bus",
    "open_bus",
    "paced",
    "resolve_profile",
    "START_TIME",
    "DT",
)


def __getattr__(name: str):
    if name in _RUN:
        from . import run

        return getattr(run, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = list(_RUN)
