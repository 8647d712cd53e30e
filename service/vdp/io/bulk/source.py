"""A candump log for ``replay()``, read a block at a time (:mod:`vdp.io.bulk`).

Each block is parsed at once by the compiled scan (:mod:`vdp.io.scan`); frames of other bus
channels are skipped, ids nobody decodes are counted and dropped, time order is checked, and
the rest go to the block decoder (:mod:`vdp.io.bulk.decode`).
"""

from __future__ import annotations

import gzip
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .. import scan  # (no numba: the compiled parse is made at its first use)
from ..formats.base import _ID_CACHE_MAX, _MAX_CHANNELS, LogStats, channel_keys
from ..logs import open_log
from .decode import BlockDecoding

BLOCK = 1 << 21  # bytes read and parsed at once: memory stays flat whatever the log's length
_MAX_TS = 1e10  # later stamps are the per-frame reader's to judge
_JUMP = 3600.0  # s: a forward jump this large is the per-frame reader's to judge
_TX = {b"T", b"t"}


class Irregular(Exception):
    """The log has something only the per-frame reader handles exactly."""


class BulkSource(BlockDecoding):
    """A candump log for ``replay()``: it feeds the pipeline itself, a block at a time.

    Same attributes as :class:`vdp.io.logs.LogSource` that ``replay()`` reads
    (``path``, ``size``, ``position``, ``stats``, ``keep_ids``), plus
    ``feed_into(pipeline, progress)``.  Raises :class:`Irregular` when the log
    needs the per-frame reader (see the package's doc, :mod:`vdp.io.bulk`).
    """

    def __init__(
        self,
        path: str | Path,
        strict: bool = False,
        channel: str | None = None,
        until: float | None = None,
        keep_all: bool = False,
    ):
        """``until``: read only up to the first frame more than ``until`` seconds of bus time
        after the first, as a loop over ``open_log`` that breaks there (the profile check's
        first minutes); ``keep_all``: hand every frame to the decoder, none passed over by id
        (its counts of ids it does not decode are then the per-frame decoder's, in its order)."""
        self.path = Path(path)
        self._until = until
        self._keep_all = keep_all
        # the per-frame reader's checks of the file itself: missing, empty, binary, bad gzip
        probe = open_log(self.path, strict=strict, channel=channel)
        self.size, self.compressed = probe.size, probe.compressed
        probe.close()
        self._raw = open(self.path, "rb")
        self._stream: Any = gzip.GzipFile(fileobj=self._raw, mode="rb") if self.compressed else self._raw
        self._want = channel_keys(channel) if channel is not None else None
        self.stats = LogStats(unit="line")
        self._keep: frozenset[int] | None = None
        self._off: set[int] = set()  # plans whose block decoding disagreed with the frame decoder
        # whether vdp.io.scan's compiled parse runs here; asked at the first block, so that opening
        # a log does not import numba
        self._scan: bool | None = None

    @property
    def position(self) -> int:
        try:
            return self._raw.tell()
        except (ValueError, OSError):
            return self.size

    def keep_ids(self, keys) -> None:
        self._keep = frozenset(keys)

    def close(self) -> None:
        for f in (self._stream, self._raw):
            try:
                f.close()
            except Exception:  # a half-read gzip stream may complain on close; nothing to save
                pass

    def __iter__(self):
        raise TypeError("BulkSource feeds a pipeline (feed_into); open_log() gives frames one by one")

    # -- the work ----------------------------------------------------------------
    def feed_into(self, pipe: Any, progress: Callable[[int, int], None] | None = None) -> tuple[int, float | None]:
        """Feed the whole log to ``pipe``; (frames handed to it, first frame's time)."""
        dec = pipe.decoder
        keep = frozenset(dec.ids) if self._keep is None else self._keep
        plans = self._plans(dec)
        st = self.stats
        state = {
            "last": 0.0,
            "seen": set(),  # id keys already handed out once (as the per-frame reader's id cache)
            "chans": {},  # channel token -> (channel value, wanted)
            "first": None,
            "n": 0,
        }
        keep_arr = None if self._keep_all else np.array(sorted(keep), dtype=np.int64)
        tail = b""
        lineno = 0
        while True:
            try:
                block = self._stream.read(BLOCK)
            except (OSError, EOFError, zlib.error) as exc:
                raise Irregular(f"unreadable after line {lineno}: {type(exc).__name__}") from None
            if not block:
                if tail:
                    lineno = self._block(tail + b"\n", lineno, pipe, plans, keep_arr, state)
                break
            block = tail + block
            cut = block.rfind(b"\n") + 1
            tail = block[cut:]
            if len(tail) > BLOCK:  # a line longer than a block (a gzip line bomb): bounded per-frame reading
                raise Irregular(f"a line longer than {BLOCK} bytes after line {lineno}")
            if cut:
                lineno = self._block(block[:cut], lineno, pipe, plans, keep_arr, state)
            if progress is not None:
                progress(self.position, state["n"])
            if state.get("done"):
                break
        st.lines = lineno
        # in order and without jumps (else Irregular): the per-frame reader's bus time is the span
        st.bus_time = state["last"] - state["first"] if state["first"] is not None else 0.0
        if st.frames == 0:  # the per-frame reader's words for that (an error, or a warning)
            raise Irregular("no frames")
        return state["n"], state["first"]

    def _block(self, buf: bytes, lineno: int, pipe: Any, plans: dict, keep_arr: Any, state: dict) -> int:
        st = self.stats
        if self._scan is None:
            self._scan = scan.available()
            if not self._scan:  # numba is a dependency; without it the tolerant reader parses every line
                raise Irregular("no compiled parse (numba does not import)")
        code, bad, n_lines, _, _, _, lines_no, ts, key, _, data, dlc, ch_code, ch_lo, ch_hi, _ = scan.lines(buf)
        if code:
            where = f"line {lineno + bad}" if bad else f"a block after line {lineno}"
            raise Irregular(f"{scan.MESSAGES[code]} ({where})")
        lines_no = lines_no + lineno
        if self._until is not None:
            j = self._cut(buf, ts, ch_code, ch_lo, ch_hi, state)
            if j is not None:  # the rows before the first frame past ``until``; the reading stops
                state["done"] = True
                n_lines = int(lines_no[j]) - lineno - 1
                ts, key, data, dlc, ch_code, ch_lo, ch_hi, lines_no = (
                    a[:j] for a in (ts, key, data, dlc, ch_code, ch_lo, ch_hi, lines_no)
                )
        if not len(ts):
            return lineno + n_lines
        uniq, inv = np.unique(ch_code, return_inverse=True)
        chans = state["chans"]
        wanted_u, value_u = [], []
        for code, first in zip(uniq.tolist(), [int(np.argmax(inv == i)) for i in range(len(uniq))]):
            if code not in chans:
                if len(chans) >= _MAX_CHANNELS:  # garbage: the per-frame reader makes them bad lines
                    raise Irregular(f"more than {_MAX_CHANNELS} distinct channels")
                name = bytes(buf[ch_lo[first] : ch_hi[first]]).decode("ascii", "replace")
                self.stats.channels.add(name)
                value: Any = int(name) if name.isdigit() else name
                chans[code] = (value, self._want is None or value in self._want)
            value_u.append(chans[code][0])
            wanted_u.append(chans[code][1])
        wanted = np.array(wanted_u)[inv]
        st.skipped += int((~wanted).sum())
        # ids nobody decodes: the first of each is handed out (as the per-frame reader does), the rest
        # counted by id; beyond _ID_CACHE_MAX distinct ids, counted in one number and not stored (a
        # log of random ids must not grow the tables: 359 MB for a million ids before this cap)
        kept = wanted if keep_arr is None else np.isin(key, keep_arr) & wanted
        other = wanted & ~kept
        seen = state["seen"]
        hand = kept.copy()
        if other.any():
            ok, first_at = np.unique(key[other], return_index=True)
            idx_other = np.flatnonzero(other)
            for k, j in zip(ok.tolist(), first_at.tolist()):
                if k not in seen and len(seen) < _ID_CACHE_MAX:
                    seen.add(k)
                    hand[idx_other[j]] = True
            passed = other & ~hand
            if passed.any():
                pk, pc = np.unique(key[passed], return_counts=True)
                over = st.passed_over
                for k, c in zip(pk.tolist(), pc.tolist()):
                    if k in seen:
                        over[k] = over.get(k, 0) + c
                    else:
                        st.passed_over_other += c
        sel = np.flatnonzero(hand)
        if not len(sel):
            return lineno + n_lines
        t = ts[sel]
        if t[0] < state["last"] or (len(t) > 1 and (np.diff(t) < 0).any()):
            raise Irregular("time goes backwards")
        jumped = len(t) > 1 and np.diff(t).max() > _JUMP
        if t[-1] > _MAX_TS or jumped or (state["n"] and t[0] - state["last"] > _JUMP):
            raise Irregular("a clock jump")
        state["last"] = float(t[-1])
        if state["first"] is None:
            state["first"] = float(t[0])
        st.frames += len(sel)
        state["n"] += len(sel)
        self._decode(pipe, plans, sel, t, key[sel], data[sel], dlc[sel], inv[sel], value_u, lines_no[sel])
        return lineno + n_lines

    def _cut(self, buf: bytes, ts: np.ndarray, ch_code: np.ndarray, ch_lo, ch_hi, state: dict) -> int | None:
        """The row of the first frame (of a channel asked for) more than ``until`` seconds after
        the log's first, or None.  (The channel table is left to _block: names seen after the
        cut are not the log's first minutes'.)"""
        chans = state["chans"]
        uniq, first, inv = np.unique(ch_code, return_index=True, return_inverse=True)
        want = []
        for code, i in zip(uniq.tolist(), first.tolist()):
            if code in chans:
                want.append(chans[code][1])
            else:
                name = bytes(buf[ch_lo[i] : ch_hi[i]]).decode("ascii", "replace")
                want.append(self._want is None or (int(name) if name.isdigit() else name) in self._want)
        wanted = np.array(want)[inv]
        t0 = state.get("t0")
        if t0 is None:
            w = np.flatnonzero(wanted)
            if not len(w):
                return None
            t0 = state["t0"] = float(ts[w[0]])
        past = np.flatnonzero(wanted & (ts - t0 > self._until))
        return int(past[0]) if len(past) else None
