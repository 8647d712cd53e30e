"""CAN frames -> canonical SI samples, per a vehicle profile and its DBC.

:class:`FrameDecoder` checks the profile's mapping against the DBC once, then
turns each frame into ``[(channel index, SI value), ...]``.  Bad frames never
raise: they are counted in :class:`DecodeStats` by arbitration ID and kind,
and a frame with any bad mapped signal yields nothing (no partial samples).

Hot path: one dict lookup finds a frame's plan (unknown IDs stop there), and the
plan's extractor (:mod:`vdp.io.signals`: the bit-level half, frames -> signal values,
generated code for plain integer signals, cantools for multiplexed messages and float
signals) yields the values this package maps to channels.  A channel with a
``fine`` signal (coarse + fine layouts) sums the two in the output loop.  What goes
beyond one signal per channel (composite channels, status and plausibility) lives in
:mod:`vdp.io.mapping`; the decoder hands it the decoded values.

The package: ``plan`` (the profile's mapping checked against the DBC and compiled, one plan
per arbitration id), ``frames`` (:class:`FrameDecoder`: a frame through its plan, and the
counters of :class:`DecodeStats`), ``dbc`` (:func:`load_dbc`: the profile's DBCs as one).
``MAX_UNKNOWN`` is read in ``frames``: a test sets it there.
"""

from __future__ import annotations

from ..signals import check_fine, compile_extractor, limits  # (limits: the decoder's API)
from .dbc import load_dbc
from .frames import BAD_RUN_INVALID, KINDS, MAX_UNKNOWN, DecodeStats, FrameDecoder, _hex
from .plan import ACTIVE, ALT_AFTER_CYCLES, DEFAULT_CYCLE

__all__ = [
    "ACTIVE",
    "ALT_AFTER_CYCLES",
    "BAD_RUN_INVALID",
    "DEFAULT_CYCLE",
    "KINDS",
    "MAX_UNKNOWN",
    "DecodeStats",
    "FrameDecoder",
    "_hex",
    "check_fine",
    "compile_extractor",
    "limits",
    "load_dbc",
]
