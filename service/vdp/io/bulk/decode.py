"""A block's frames decoded one message at a time, as the frame decoder would (:mod:`vdp.io.bulk`).

Every signal of every frame of a message in one numpy expression (same shifts, masks, scale
and offset as the decoder's generated extractors, so the same floats); the decoder's plan
state and counters left as ``FrameDecoder.decode`` leaves them; the good frames' values
handed to the aligner a block at a time (:mod:`vdp.io.bulk.aligner`).  A block the vectorised
decoder does not cover goes through ``FrameDecoder.decode`` frame by frame.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import can
import numpy as np

from ... import channels
from ..decoder import ACTIVE, MAX_UNKNOWN, compile_extractor
from ..formats.base import EXT_KEY
from ..signals import range_limits as limits  # with the profile's range overrides
from .aligner import align

log = logging.getLogger(__name__)


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


class BlockDecoding:
    """:class:`vdp.io.bulk.BulkSource`'s decoding of the frames it keeps (it reads ``path``
    and keeps ``_off``, the plans whose block decoding disagreed with the frame decoder)."""

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
