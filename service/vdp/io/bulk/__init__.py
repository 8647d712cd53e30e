"""Bulk replay of candump -L logs: whole blocks parsed (vdp.io.scan) and decoded with numpy.

The per-frame path (``open_log`` -> ``can.Message`` -> ``FrameDecoder.decode``)
costs a few microseconds of Python per line.  Here a block of lines (2 MB) is
parsed at once by the compiled scan, the one candump parser; lines of ids the profile does
not decode are counted by id and dropped before anything else; the rest are
decoded one message at a time, every signal of every frame in one numpy
expression (same shifts, masks, scale and offset as the decoder's generated
extractors, so the same floats).  Only the aligner and the estimator see the
frames one by one.

The result is the per-frame path's, to the last bit: same frames, same decoder
counters (plans' counters, checksums, good-frame counts, error kinds), same
samples.  Whatever this path does not reproduce exactly goes the per-frame way:

- a block with a frame the vectorised decoder does not cover (multiplexed or
  float signals, an alternative source, a counter or checksum failure, a message
  flagged invalid) is decoded frame by frame through ``FrameDecoder.decode``;
- a log with anything but plain, in-order data frames (a bad line, a remote, FD
  or error frame, time going backwards, odd spacing) is replayed again from the
  start by the per-frame reader (vdp.replay.replay_log), whose rules for damaged logs
  are the reference.  Clean logs, the usual case, never pay for that.

The package: ``run`` (:func:`pays`, :func:`usable`: when it pays; vdp.replay.replay_log uses it), ``source``
(:class:`BulkSource`: the log read a block at a time, each block parsed and its frames sorted
by channel and id), ``decode`` (a block's frames decoded per message, as the frame decoder
would) and ``aligner`` (the aligner's ticks over a block).  The module-level settings are read
where they are used, so a test sets them there: ``BLOCK`` in ``source`` (re-exported here to
read), ``_ID_CACHE_MAX`` in ``source``, ``MAX_UNKNOWN`` (the decoder's cap) in ``decode``.
"""

from __future__ import annotations

from .aligner import align
from .decode import _Plan
from .run import pays, usable
from .source import BLOCK, BulkSource, Irregular

__all__ = [
    "BLOCK",
    "BulkSource",
    "Irregular",
    "_Plan",
    "align",
    "pays",
    "usable",
]
