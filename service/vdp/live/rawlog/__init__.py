"""Field logging: every raw frame to rotating candump ``.log`` files.

python-can's :class:`can.SizedRotatingLogger` does the writing and the size
rotation; this listener adds what an unattended logger needs:

- file names that sort in recording order: ``{prefix}-{seq:06d}-{UTC start}.log``,
  with ``{prefix}-current.log`` as the one open file;
- at most ``max_files`` files: the oldest closed ones are deleted;
- closed files are complete: flushed and fsync'ed before the rename, so a power
  cut leaves no half file among them.  After a crash the open file is salvaged
  at the next start: cut back to its last full line and closed like the others;
- disk full (or any other OSError) stops logging and says why, and never
  reaches the receive thread: estimation and the API carry on.  Logging tries
  again after RETRY_MIN s, backing off to RETRY_MAX, and the frames it could
  not write are counted (``lost``);
- the newest data wins: when free space falls under ``min_free`` (at each
  rotation, and before resuming after a full disk) the oldest closed files are
  deleted, each with a warning, until it is back above the floor;
- it cannot be unlinked from under itself: at every flush (and before each
  rotation) the open file is checked to still be ``{prefix}-current.log`` in
  the directory (same inode, still linked).  A file deleted or moved away, or
  the whole directory, is noticed within one flush: the directory is made
  again, a new file opened, and the frames not yet known to be in a file there
  are written again into it.  Left alone, every frame went into the deleted
  file until the next rotation, and none after it;
- the counts are exact: ``accepted`` = ``written`` + ``lost`` + ``pending``.
  A frame is written once a flush has put it into a file found in place (or a
  rotation closed it); ``pending`` ones are held until then, so a file that
  vanishes loses none of them.  When a write fails, the complete lines that
  reached the file are counted written and the rest of the buffer lost (a full

The package: ``listener`` (:class:`RawLog`: the counts, opening and closing, the receive thread's
writes), ``recovery`` (a write that failed, a file gone from under the log: stopping, resuming,
writing again into a new file), ``files`` (the directory's files: names, rotation, the index,
salvage, and deleting the oldest for the file count and the free-space floor), ``rotating``
(python-can's rotating writer as the raw log uses it).
"""

from __future__ import annotations

from .listener import HEADS_MAX, HOLD_MAX, RawLog
from .recovery import RETRY_MAX, RETRY_MIN

__all__ = ["HEADS_MAX", "HOLD_MAX", "RETRY_MAX", "RETRY_MIN", "RawLog"]
