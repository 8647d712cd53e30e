"""The aligner, a block at a time: what ``Aligner.push`` would return over a block of decoded
frames, as arrays (:mod:`vdp.io.bulk`)."""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

log = logging.getLogger(__name__)


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
    from ... import buffer

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
