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
  start by the per-frame reader (``replay_log``), whose rules for damaged logs
  are the reference.  Clean logs, the usual case, never pay for that.
"""

from __future__ import annotations

import gzip
import logging
import math
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
import numpy as np

from .. import channels
from ..result import RunResult
from . import scan  # (no numba: the compiled parse is made at its first use)
from .decoder import ACTIVE, MAX_UNKNOWN, compile_extractor
from .formats.base import _ID_CACHE_MAX, _MAX_CHANNELS, EXT_KEY, LogStats, channel_keys
from .logs import open_log
from .signals import range_limits as limits  # with the profile's range overrides

log = logging.getLogger(__name__)

BLOCK = 1 << 21  # bytes read and parsed at once: memory stays flat whatever the log's length
_MAX_TS = 1e10  # later stamps are the per-frame reader's to judge
_JUMP = 3600.0  # s: a forward jump this large is the per-frame reader's to judge
_TX = {b"T", b"t"}


class Irregular(Exception):
    """The log has something only the per-frame reader handles exactly."""


def pays(path: str | Path) -> bool:
    """Whether reading ``path`` a block at a time pays (a candump log, and :func:`scan.pays`:
    numba loaded already, or a long log); the result is the same either way."""
    try:
        size = Path(path).stat().st_size
    except OSError:
        return False  # the per-frame reader says what is wrong with it
    return usable(path) and scan.pays(size)


def usable(path: str | Path) -> bool:
    """Bulk replay covers candump -L logs, plain or gzipped."""
    suffixes = [s.lower() for s in Path(path).suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes = suffixes[:-1]
    return bool(suffixes) and suffixes[-1] == ".log"


def replay_log(
    path: str | Path,
    make_pipeline: Callable[[], Any],
    strict: bool = False,
    channel: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    bulk: bool | None = None,
    wrap: Callable[[Any], Any] | None = None,
) -> tuple[RunResult, Any]:
    """``replay()``'s result for a log, and the pipeline it ran on.

    candump logs go the bulk way where it pays (``bulk`` None: :func:`pays`; True: always,
    False: never); if the log turns out to need the per-frame reader's rules, it is
    replayed again that way on a fresh pipeline.  ``wrap``: applied to a per-frame source
    (a recorder that needs every frame).
    """
    from ..replay import replay

    if bulk is None:
        bulk = pays(path)
    if bulk and usable(path):
        src = BulkSource(path, strict=strict, channel=channel)
        pipe = make_pipeline()
        try:
            return replay(src, pipe, progress=progress), pipe
        except Irregular as why:
            log.info("%s: %s; replaying it frame by frame", path, why)
        finally:
            src.close()
    source = open_log(path, strict=strict, channel=channel)
    pipe = make_pipeline()
    try:
        return replay(wrap(source) if wrap else source, pipe, progress=progress), pipe
    finally:
        source.close()


class _Plan:
    """Vectorised extraction of one decoder plan's signals (None where not covered)."""

    def __init__(self, dplan: Any, msg: Any, need: list[tuple[str, bool, bool]], ranges: dict | None = None):
        self.p = dplan
        self.length = msg.length
        self.pad = False  # [can] pad_short (set by the reader)
        self.n_pad = 0  # short frames padded in the block being decoded
        self.fid = dplan.frame_id
        self.checked = False  # compared with the decoder's own extractor on the first frames seen
        self.fields = []  # per needed signal: (little endian, shift, mask, half or 0, scale, offset, scaled, lo, hi)
        for name, raw, check in need:
            sig = msg.get_signal_by_name(name)
            if sig.byte_order == "little_endian":
                le, shift = True, sig.start
            else:
                le, shift = False, (msg.length - 1 - sig.start // 8) * 8 + sig.start % 8 - sig.length + 1
            scale, offset = sig.conversion.scale, sig.conversion.offset
            scaled = not raw and (scale != 1 or offset != 0)
            lo, hi = limits(msg, sig, ranges) if check and not raw else (-math.inf, math.inf)
            half = 1 << (sig.length - 1) if sig.is_signed else 0
            self.fields.append((le, shift, (1 << sig.length) - 1, half, float(scale), float(offset), scaled, lo, hi))

    def agrees(self, b: np.ndarray) -> bool:
        """The frame decoder's own extractor gives the same kinds and values for these frames."""
        vals, bad = self.extract(b)
        cols = [v.tolist() for v in vals]
        for i, row in enumerate(b.tolist()):
            mine = ("range" if bad[i] else None, *(c[i] for c in cols))
            if self.p.extract(bytes(row[: self.length])) != mine:
                return False
        return True

    def extract(self, b: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        """Values of the needed signals (slot i+1 of the decoder's tuple) and a range-error mask."""
        n = self.length
        w = b[:, :n].astype(np.uint64)
        le = be = None
        out, bad = [], np.zeros(len(b), bool)
        for little, shift, mask, half, scale, offset, scaled, lo, hi in self.fields:
            if little:
                if le is None:
                    le = np.zeros(len(b), np.uint64)
                    for i in range(n):
                        le |= w[:, i] << np.uint64(8 * i)
                src = le
            else:
                if be is None:
                    be = np.zeros(len(b), np.uint64)
                    for i in range(n):
                        be |= w[:, i] << np.uint64(8 * (n - 1 - i))
                src = be
            v = ((src >> np.uint64(shift)) & np.uint64(mask)).astype(np.int64)
            if half:
                v = (v ^ half) - half
            if scaled:
                v = v.astype(np.float64) * scale + offset
            if lo > -math.inf:
                bad |= ~(v >= lo)
            if hi < math.inf:
                bad |= ~(v <= hi)
            out.append(v)
        return out, bad


class BulkSource:
    """A candump log for ``replay()``: it feeds the pipeline itself, a block at a time.

    Same attributes as :class:`vdp.io.logs.LogSource` that ``replay()`` reads
    (``path``, ``size``, ``position``, ``stats``, ``keep_ids``), plus
    ``feed_into(pipeline, progress)``.  Raises :class:`Irregular` when the log
    needs the per-frame reader (see the module's doc).
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

    def _plans(self, dec: Any) -> dict[int, _Plan | None]:
        out: dict[int, _Plan | None] = {}
        for key, p in dec._plans.items():
            msg = dec.db.get_message_by_name(p.name)
            # the decoder's own slot order when it keeps it; rebuilt from the profile otherwise
            need = dec.needs.get(key) if hasattr(dec, "needs") else _needs(dec, p, msg)
            ok = (
                need is not None
                and compile_extractor(msg, need, getattr(dec, "ranges", None)) is not None
                and all(o[5] is None for o in p.outputs)  # an alternative source depends on another's state
                # status and plausibility: the per-frame path (a status flag read from an enum: here too)
                and all(o[7] is None or o[7][0] is ACTIVE for o in p.outputs)
                and all(o[0] < channels.N for o in p.outputs)  # composite channels' terms: the per-frame path
            )
            out[key] = _Plan(p, msg, need, getattr(dec, "ranges", None)) if ok else None
            if out[key] is not None:  # [can] pad_short: a short frame's missing bytes are zeros here too
                out[key].pad = bool(getattr(dec, "_pad", False))
        return out

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

    def _decode(self, pipe, plans, sel, t, key, data, dlc, ch_idx, ch_values, lines) -> None:
        dec = pipe.decoder
        dst = dec.stats
        ukeys, first_at = np.unique(key, return_index=True)
        work = []  # (plan, rows)
        per_frame = False
        for k in ukeys[np.argsort(first_at)].tolist():  # first seen first, as the per-frame decoder counts them
            rows = np.flatnonzero(key == k)
            vp = plans.get(k, "unknown")
            if vp == "unknown":
                unk = dst.unknown
                if k in unk or len(unk) < MAX_UNKNOWN:  # the decoder's own cap (FrameDecoder.decode)
                    unk[k] = unk.get(k, 0) + len(rows)
                else:
                    dst.unknown_other += len(rows)
                dst.frames += len(rows)
                continue
            if vp is None or vp.p.invalid:
                per_frame = True
            work.append((k, vp, rows))
        why = "a message the block decoder does not cover, or one flagged invalid" if per_frame else ""
        done = []
        for k, vp, rows in work:
            if why:
                break
            r = self._vector(vp, t[rows], data[rows], dlc[rows])
            if r is None:
                why = f"a counter or checksum failure in {vp.p.name} (or its layout read differently)"
            done.append((k, vp, rows, r))
        if why:
            log.debug("%s: block at line %d decoded frame by frame: %s", self.path, int(lines[0]), why)
            return self._per_frame(pipe, [(k, r) for k, _, r in work], t, key, data, dlc, ch_idx, ch_values)
        # commit: plan state and counters as FrameDecoder.decode leaves them, then the frames in order
        got = []  # (rows of good frames, channel indices, their values)
        for k, vp, rows, (good, n_dlc, n_range, last_count, out_idx, out_vals) in done:
            p = vp.p
            tr = t[rows]
            if not p.fixed_period:
                for ti in tr.tolist():
                    last = p.last_seen
                    if last is not None and ti > last:
                        p.period += 0.05 * (min(ti - last, 2.0 * p.period) - p.period)
                    p.last_seen = ti
            p.last_seen = float(tr[-1])
            n = len(rows)
            dst.frames += n
            if n_dlc:
                dst.errors[(k, "dlc")] = dst.errors.get((k, "dlc"), 0) + n_dlc
            dst.padded += vp.n_pad
            if n_range:
                dst.errors[(k, "range")] = dst.errors.get((k, "range"), 0) + n_range
            if last_count is not None:
                p.prev_count = last_count
            ng = int(good.sum())
            if ng:
                dst.decoded += ng
                p.good += ng
                p.bad_run = 0
                gi = np.flatnonzero(good)
                p.last_good = float(tr[gi[-1]])
                if p.plain is None:
                    counted = dst._counted
                    for idx in out_idx:
                        counted[idx] += ng
                got.append((rows[gi], out_idx, out_vals))
        if not got:
            return None
        rows_all = np.concatenate([g[0] for g in got])
        order = np.argsort(rows_all, kind="stable")
        frame_of = np.empty(len(rows_all), np.int64)
        frame_of[order] = np.arange(len(rows_all))  # position of each good frame in time order
        times = t[rows_all[order]]
        per_channel: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        at = 0
        for rows_g, out_idx, out_vals in got:
            fidx = frame_of[at : at + len(rows_g)]
            at += len(rows_g)
            for col, idx in enumerate(out_idx):
                if idx in per_channel:  # two messages feed one channel: merge in frame order
                    fi, fv = per_channel[idx]
                    fi, fv = np.concatenate((fi, fidx)), np.concatenate((fv, out_vals[:, col]))
                    o = np.argsort(fi, kind="stable")
                    per_channel[idx] = (fi[o], fv[o])
                else:
                    per_channel[idx] = (fidx, out_vals[:, col])
        for block in align(pipe.aligner, times, per_channel):
            pipe.take_block(*block)
        pipe.last_bus_time = float(times[-1])
        return None

    def _vector(self, vp: _Plan, t, data, dlc):
        """Decode one plan's frames of a block, or None if it needs the per-frame decoder."""
        p = vp.p
        ok_dlc = dlc == vp.length
        vp.n_pad = 0
        if vp.pad:  # bytes beyond a frame's length are zero in ``data`` already
            short = dlc < vp.length
            vp.n_pad = int(short.sum())
            ok_dlc |= short
        n_dlc = int((~ok_dlc).sum())
        b = data[ok_dlc]
        if not vp.checked and len(b):
            vp.checked = True
            if not vp.agrees(b[:64]):  # a layout read differently from the frame decoder: a bug here
                log.warning("%s: block and frame decoders disagree; decoding it frame by frame", p.name)
                self._off.add(p.key)
        if p.key in self._off:
            return None
        vals, bad_range = vp.extract(b) if len(b) else ([np.zeros(0, np.int64)] * len(vp.fields), np.zeros(0, bool))
        last_count = None
        if p.checked and len(b):
            if p.cs_pos >= 0:
                s = b[:, :7].astype(np.int64).sum(axis=1) + (vp.fid & 0xFF) + ((vp.fid >> 8) & 0xFF)
                if (vals[p.cs_pos - 1] != 0xFF - (s & 0xFF)).any():
                    return None  # a checksum failure: counters and validity need the frame-by-frame rules
            if p.cnt_pos >= 0:
                c = vals[p.cnt_pos - 1]
                prev = np.empty(len(c), np.int64)
                prev[1:] = c[:-1]
                expect = (prev + 1) % p.cnt_mod
                bad = c != expect
                if p.prev_count is None:
                    bad[0] = False
                else:
                    bad[0] = c[0] != (p.prev_count + 1) % p.cnt_mod
                if bad.any():
                    return None
                last_count = int(c[-1])
        good_sub = ~bad_range
        good = np.zeros(len(t), bool)
        good[np.flatnonzero(ok_dlc)[good_sub]] = True
        n_range = int(bad_range.sum())
        idxs, cols = [], []
        for idx, pos, mul, add, sign_pos, _primary, fine_pos, valid in p.outputs:
            v = vals[pos - 1][good_sub]
            if valid is not None:  # a status flag from an enum's raw values (FrameDecoder.decode)
                idxs.append(idx)
                cols.append(np.isin(v, list(valid[1])).astype(np.float64))
                continue
            if fine_pos >= 0:
                v = v + vals[fine_pos - 1][good_sub]
            v = v * mul + add
            if sign_pos >= 0:
                v = np.where(vals[sign_pos - 1][good_sub] != 0, -v, v)
            idxs.append(idx)
            cols.append(v.astype(np.float64))
        out_vals = np.column_stack(cols) if cols else np.zeros((int(good.sum()), 0))
        return good, n_dlc, n_range, last_count, idxs, out_vals

    def _per_frame(self, pipe, work, t, key, data, dlc, ch_idx, ch_values) -> None:
        """The block's decodable frames through FrameDecoder.decode, one by one (exact by construction)."""
        rows = np.sort(np.concatenate([r for _, r in work])) if work else np.zeros(0, np.int64)
        feed = pipe.feed
        msg_cls = can.Message
        tl, kl, dl, cl = t.tolist(), key.tolist(), dlc.tolist(), ch_idx.tolist()
        for i in rows.tolist():
            k = kl[i]
            ext = bool(k & EXT_KEY)
            aid = k & 0x1FFFFFFF if ext else k
            payload = bytes(data[i, : dl[i]])
            feed(msg_cls(tl[i], aid, ext, False, False, ch_values[cl[i]], dl[i], payload, False, True))


def _needs(dec: Any, p: Any, msg: Any) -> list[tuple[str, bool, bool]] | None:
    """The decoder's list of needed signals for a plan, rebuilt in its slot order."""
    names: dict[int, tuple[str, bool, bool]] = {}
    prof = dec.profile
    for cmap in prof.channels.values():
        for m in (cmap, cmap.alt):
            if m is None or m.message != p.name:
                continue
            for sig, raw, check in ((m.signal, False, True), (m.sign_signal, False, False), (m.fine, False, True)):
                if sig:
                    _add(names, sig, raw, check)
    chk = prof.checks.get(p.name)
    if chk is not None and chk.check:
        if chk.counter:
            _add(names, chk.counter, True, False)
        if chk.checksum and chk.checksum_kind == "vdp":
            _add(names, chk.checksum, True, False)
    return list(names.values()) if names else None


def _add(names: dict, sig: str, raw: bool, check: bool) -> None:
    old = names.get(sig)
    names[sig] = (sig, raw, check) if old is None else (sig, old[1] and raw, old[2] or check)


# -- the aligner, a block at a time -----------------------------------------------


def align(al: Any, t: np.ndarray, per_channel: dict[int, tuple[np.ndarray, np.ndarray]]) -> list:
    """What ``Aligner.push`` would return over these frames, as blocks of samples (ticks,
    values, fresh, ages, and whether the first follows a gap: Pipeline.take_block's
    arguments), and the state it would leave.

    ``t``: the decoded frames' bus times in order (never decreasing); ``per_channel``:
    channel -> (frame indices, values) in frame order.  The aligner's rules, as arrays:
    tick n (at n * tick) is emitted by the first frame at or after n * tick + delay,
    from the values of the frames before that one (the last _DEPTH per channel); a
    frame more than max_gap after the previous restarts the grid.
    """
    from .. import buffer

    depth, eps = buffer._DEPTH, buffer._EPS
    per_channel = al.keep_block(per_channel)  # values beyond a car's limits: dropped, as push() does
    n_ch = len(al._t)
    out: list = []
    m = len(t)
    if not m:
        return out
    # segments between grid restarts: a frame more than max_gap after the one before it
    prev = np.empty(m)
    prev[0] = al.last_time
    prev[1:] = t[:-1]
    restart = (t - prev) > al.max_gap
    if al.next_tick is None:
        restart[0] = True
    cuts = np.flatnonzero(restart).tolist()
    bounds = sorted({0, *cuts, m})
    stale = np.array(al._stale)
    for j0, j1 in zip(bounds[:-1], bounds[1:]):
        if restart[j0]:
            if al.next_tick is not None:
                al.clock_jumps += 1
                log.info("bus time jumped %.3f s forward; restarting the sample grid", t[j0] - al.last_time)
            al.reset_history()
            al._n = math.ceil(float(t[j0]) / al.tick - eps)
            al.next_tick = al._n * al.tick
            al.gap = True
            emit_from = j0 + 1  # the restarting frame emits nothing
        else:
            emit_from = j0
        seg_t = t[j0:j1]
        # ticks emitted in this segment and the frame that emits each
        n0 = al._n
        t_last = float(seg_t[-1])
        if emit_from < j1:
            # the largest n with n * tick + delay <= t_last, found as the aligner would step
            guess = math.floor((t_last - al.delay) / al.tick) + 2
            ns = np.arange(n0, max(guess, n0) + 1)
            due = ns.astype(np.float64) * al.tick + al.delay
            ns, due = ns[due <= t_last], due[due <= t_last]
            n_max = int(ns[-1]) + 1 if len(ns) else n0
        else:
            ns, due, n_max = np.zeros(0, np.int64), np.zeros(0), n0
        trig = np.searchsorted(t[emit_from:j1], due, "left") + emit_from  # global frame index
        T = ns.astype(np.float64) * al.tick
        k_ticks = len(ns)
        vals = np.full((k_ticks, n_ch), np.nan)
        ages = np.full((k_ticks, n_ch), np.inf)
        fresh = np.zeros((k_ticks, n_ch), bool)
        new_t, new_v, new_emitted = [], [], []
        for c in range(n_ch):
            ht = [x for x in al._t[c] if x != -math.inf]
            hv = al._v[c][depth - len(ht) :]
            fi, fv = per_channel.get(c, (None, None))
            if fi is not None:
                sel = (fi >= j0) & (fi < j1)
                fi_c, fv_c = fi[sel], fv[sel]
            else:
                fi_c, fv_c = np.zeros(0, np.int64), np.zeros(0)
            te = np.concatenate((np.array(ht, float), t[fi_c]))
            ve = np.concatenate((np.array(hv, float), fv_c))
            fe = np.concatenate((np.full(len(ht), -1, np.int64), fi_c))
            if k_ticks and len(te):
                mm = np.searchsorted(fe, trig, "left")  # entries pushed before the emitting frame
                lo = np.maximum(mm - depth, 0)
                has = mm > lo
                cnt = np.clip(np.searchsorted(te, T + eps, "right"), lo, mm) - lo
                pads = depth - (mm - lo)
                k = pads + cnt
                hold = has & (k == depth)
                early = has & ~hold & (cnt == 0)
                interp = has & ~hold & ~early
                v = np.full(k_ticks, np.nan)
                age = np.full(k_ticks, np.inf)
                before = np.full(k_ticks, -np.inf)
                ih = np.maximum(mm - 1, 0)
                v[hold] = ve[ih[hold]]
                age[hold] = T[hold] - te[ih[hold]]
                before[hold] = te[ih[hold]]
                v[early] = ve[lo[early]]
                age[early] = 0.0
                i1 = np.minimum(lo + cnt, len(te) - 1)
                i0 = np.maximum(i1 - 1, 0)
                t0, t1, v0, v1 = te[i0], te[i1], ve[i0], ve[i1]
                with np.errstate(divide="ignore", invalid="ignore"):
                    lin = np.where(t1 > t0, v0 + (T - t0) / (t1 - t0) * (v1 - v0), v1)
                v[interp] = lin[interp]
                age[interp] = T[interp] - t0[interp]
                before[interp] = t0[interp]
                v[age > stale[c]] = np.nan
                vals[:, c], ages[:, c] = v, age
                run = np.maximum.accumulate(np.concatenate(([al._emitted[c]], before)))
                fr = has & (before > run[:-1])
                fresh[:, c] = fr
                emitted = float(run[-1])
            else:
                emitted = al._emitted[c]
            new_emitted.append(emitted)
            # the history the aligner keeps: the last _DEPTH values of the segment
            keep_t = te[-depth:].tolist()
            keep_v = ve[-depth:].tolist()
            new_t.append([-math.inf] * (depth - len(keep_t)) + keep_t)
            new_v.append([math.nan] * (depth - len(keep_v)) + keep_v)
        if k_ticks:
            out.append((T, vals, fresh, ages, al.gap))
            al.gap = False
        al._t, al._v, al._emitted = new_t, new_v, new_emitted
        al._n = n_max
        al.next_tick = al._n * al.tick
        al.last_time = t_last
        al._behind = 0
    return out
