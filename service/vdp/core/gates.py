"""Gates for what the two-stage model does not cover: reverse, ABS/ESC/TCS, kerbs, wheel spin,
standstill and creep.

The paper's models (eqs 1-14) describe a car rolling forwards on four tyres in their linear
range on a smooth road.  A real drive leaves that range now and then:

- **reverse** (the gear's status flag, or a signed GNSS or wheel speed below -REV_SPEED): the
  slip and the load transfer change sign with the direction, which an unsigned speed hides;
- **ABS, ESC, TCS** (the status flags a profile maps, channels.STATUS): the brakes or the
  engine regulate a wheel at its grip, beyond the linear tyre (eq 14's C_K, eq 11's C_alpha);
- **wheel spin** (one wheel far from the others, or from the ground speed): the same on a bus
  without status flags;
- **kerb strikes** (a short spike of a_y that the yaw rate does not explain, |a_y - v r|):
  a road input, not the tyres' response.  The test fires at the spike's peak, but the samples of
  its rise (and the roll-rate and wheel-speed pulses that come with it) are as far from the
  model: the gate shuts from ``kerb_pre`` seconds before the first sample that fires.  It can,
  because a pipeline shows the test each sample that far ahead of its turn (:func:`kerb`,
  ``Gates.ahead``; vdp.pipeline's look-ahead); a caller that shows none gates from the sample
  that fires, as before;
- **standstill and creep** (below STAND and CREEP m/s): the slip is singular near standstill
  (NOTES 11).  Both lie below the supervisor's v_min, whose speed gate already shuts the
  windows there: they are counted, so a drive's report says where its time went, but never
  change a window.

Each gate but standstill and creep shuts both stages' windows while it holds and for ``hold``
seconds after (the tyres and the filters settle).  Each is counted per drive: the seconds
under each gate (a sample under several counts under the first of :data:`NAMES`) and under
any, for "4 % of the drive gated out: reverse 1 %, ABS 3 %".

Pure: one sample's channel values in, a gate code out.  :func:`step` is written for both paths:
the supervisor calls it per sample on a list, a replay's block pass (core.batched) over the
block's arrays, compiled by numba where it is installed (:func:`kernel`).  The thresholds are
far from what a drive without these events reaches (BENCHMARKS.md, "Reverse, ABS, kerbs"), so such a drive's
estimates are the same, to the bit, as without the gates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import channels as ch

# gate codes (0: none), in the order a sample under several is counted
REVERSE, ABS, ESC, TCS, KERB, SPIN, STANDSTILL, CREEP = range(1, 9)
NAMES = {
    REVERSE: "reverse",
    ABS: "ABS",
    ESC: "ESC",
    TCS: "TCS",
    KERB: "kerb strike",
    SPIN: "wheel spin",
    STANDSTILL: "standstill",
    CREEP: "creep",
}
SHUTS = SPIN  # codes up to this one shut the windows (standstill and creep only count)
N_GATES = len(NAMES)


@dataclass(frozen=True)
class GatesConfig:
    rev_speed: float = 0.5  # m/s: a signed speed below minus this is reversing (noise at rest stays within)
    spin_rel: float = 0.25  # a wheel this share of the speed away from the median wheel or the ground
    spin_abs: float = 1.5  # m/s: ... and at least this far (the driver's ABS/TCS keep slip near 0.1)
    # m/s^2: |a_y - v r| beyond this is no tyre's response to the yaw.  3.0 fired on the light stiff-tyre
    # car's brisk steering (benchmarks/robust.py --cars light: C_alpha +-3 % where ungated +-0.6 %); chosen
    # on that car and the simulator's 6 m/s^2 kerb pulses, both tuning cases (no held-out case yet)
    kerb_ay: float = 5.0
    kerb_speed: float = 2.0  # m/s: the kerb test's lowest speed (v r means little below)
    # s before the first sample over kerb_ay that the gate shuts (the strike's rise: the test fires near
    # its peak).  The simulator's 80-ms half-sine passes kerb_ay = 5 of its 6 m/s^2 from 25 ms in, so the
    # first sample that fires is up to 25 + 20 (a tick) ms after the rise began; 0.06 s adds a tick of
    # margin for a real IMU's filter.  Chosen on city seeds 1-3 with kerb=4 (benchmarks/gates.py), checked
    # on seeds 4-6 and the ordinary scenario (BENCHMARKS.md, "Reverse, ABS, kerbs")
    kerb_pre: float = 0.06
    hold: float = 0.5  # s a gate stays shut after its cause ends
    standstill: float = 0.3  # m/s
    creep: float = 2.0  # m/s
    shut: bool = True  # False: count only, shut no window (what the gates are worth: benchmarks/gates.py)


# the state: per gate that holds, the time it holds until; the last time; the seconds counted; the
# kerb gate's start (kerb_pre before the strike's first sample over the test)
(H_REV, H_ABS, H_ESC, H_TCS, H_KERB, H_SPIN, T_LAST, OBSERVED, ANY) = range(9)
SECONDS = 9  # seconds under gate k at SECONDS + k - 1
K_FROM = SECONDS + N_GATES
N_STATE = K_FROM + 1
# the parameters array
(REV_SPEED, SPIN_REL, SPIN_ABS, KERB_AY, KERB_SPEED, HOLD, STAND, CREEP_V, RADIUS, KERB_PRE) = range(10)
# channel indices, passed in (numba would freeze module globals into its cache)
CHANNELS = np.array([ch.WS_FL, ch.WS_FR, ch.WS_RL, ch.WS_RR, ch.AY, ch.YAW, ch.SPEED, ch.REVERSE, ch.ABS, ch.ESC,
                     ch.TCS])  # fmt: skip
_FL, _FR, _RL, _RR, _AY, _YAW, _SPEED, _REV, _ABS, _ESC, _TCS = range(11)
_FAR = -1e300  # "never": a hold that has not started


def params(cfg: GatesConfig, wheel_radius: float) -> np.ndarray:
    p = np.empty(10)
    p[:] = (cfg.rev_speed, cfg.spin_rel, cfg.spin_abs, cfg.kerb_ay, cfg.kerb_speed, cfg.hold, cfg.standstill,
            cfg.creep, wheel_radius, cfg.kerb_pre)  # fmt: skip
    return p


def new_state() -> list[float]:
    st = [0.0] * N_STATE
    for i in range(H_SPIN + 1):
        st[i] = _FAR
    st[T_LAST] = math.nan
    st[K_FROM] = _FAR
    return st


def kerb(st, p, c, t, y):
    """The kerb test on the sample ``y`` at ``t``: a lateral spike the yaw rate does not explain
    (a_y = v r + dv_y/dt, dv_y/dt small).  Where it fires, the kerb gate holds from kerb_pre before
    (from the first sample that fires of a strike) to ``hold`` after.  Called on each sample before
    :func:`step`, as early as the caller has it (a look-ahead), and again at its step: a second call
    on a sample changes nothing."""
    ay, yaw = y[c[_AY]], y[c[_YAW]]
    if not (math.isfinite(ay) and math.isfinite(yaw)):
        return
    v = y[c[_SPEED]]
    if math.isfinite(v):
        v = abs(v)
    else:  # the wheels' mean ground speed, of those there
        s = 0.0
        n = 0
        for k in range(4):
            w = y[c[k]] * p[RADIUS]
            if math.isfinite(w):
                s += w
                n += 1
        if n == 0:
            return
        v = abs(s / n)
    if v > p[KERB_SPEED] and abs(ay - v * yaw) > p[KERB_AY]:
        if t - p[KERB_PRE] > st[H_KERB]:  # a new strike (not one whose hold still runs): its rise before
            st[K_FROM] = t - p[KERB_PRE] - 1e-6  # (a tick kerb_pre before, whatever the float's rounding)
        st[H_KERB] = max(st[H_KERB], t + p[HOLD])


def step(st, p, c, t, gap, y):
    """One sample ``y`` (channel values) at ``t`` (``gap``: the first after a gap): count it and
    return its gate code (0: none).  ``st`` is changed in place."""
    dt = 0.01 if math.isnan(st[T_LAST]) or gap else min(max(t - st[T_LAST], 0.0), 0.1)
    st[T_LAST] = t
    hold = p[HOLD]
    r = p[RADIUS]
    gnss = y[c[_SPEED]]
    # the wheels' ground speeds (signed where the bus signs them): those there, first, and their sum
    w0, w1, w2, w3 = y[c[_FL]] * r, y[c[_FR]] * r, y[c[_RL]] * r, y[c[_RR]] * r
    s = w0 + w1 + w2 + w3
    n = 4
    if not math.isfinite(s):  # (a wheel missing or stale: the rare case)
        n = 0
        s = 0.0
        for k in range(4):
            w = y[c[k]] * r
            if math.isfinite(w):
                if n == 0:
                    w0 = w
                elif n == 1:
                    w1 = w
                elif n == 2:
                    w2 = w
                s += w
                n += 1
    v = abs(gnss) if math.isfinite(gnss) else (abs(s / n) if n else math.nan)
    # reverse: the gear, or a signed speed (GNSS, wheels) clearly below zero
    # (a flag is on above 0.5; NaN, not mapped or stale, gates nothing)
    if y[c[_REV]] > 0.5 or gnss < -p[REV_SPEED] or (n >= 2 and s / n < -p[REV_SPEED]):
        st[H_REV] = t + hold
    for k in range(3):  # ABS, ESC, TCS: their flags and holds in the same order
        if y[c[_ABS + k]] > 0.5:
            st[H_ABS + k] = t + hold
    # kerb: :func:`kerb`, called before (the kerb gate holds from K_FROM, not before)
    # wheel spin: one wheel far from the median of the others (three or four wheels), or from the ground
    if n >= 3:
        lo = hi = 0.0
        if n == 3:
            med = max(min(w0, w1), min(max(w0, w1), w2))
            far = max(abs(w0 - med), abs(w1 - med), abs(w2 - med))
            lo, hi = min(w0, w1, w2), max(w0, w1, w2)
        else:
            lo, hi = min(w0, w1, w2, w3), max(w0, w1, w2, w3)
            med = 0.5 * (w0 + w1 + w2 + w3 - lo - hi)
            far = max(hi - med, med - lo)
        if math.isfinite(gnss):
            far = max(far, abs(hi) - v, v - abs(lo))
        ref = max(v, abs(med)) if math.isfinite(v) else abs(med)
        if far > max(p[SPIN_REL] * ref, p[SPIN_ABS]):
            st[H_SPIN] = t + hold
    code = 0
    for k in range(H_SPIN + 1):  # REVERSE .. SPIN: the holds' order is the codes'
        if t <= st[k] and (k != H_KERB or t >= st[K_FROM]):
            code = k + 1
            break
    if code == 0 and math.isfinite(v):
        if v < p[STAND]:
            code = STANDSTILL
        elif v < p[CREEP_V]:
            code = CREEP
    st[OBSERVED] += dt
    if code != 0:
        st[ANY] += dt
        st[SECONDS + code - 1] += dt
    return code


def run(st, p, c, T, Y, gaps, out, ahead):
    """:func:`step` over a block's first ``len(out)`` samples (T ticks, Y values, gaps flags), ``out``
    their codes; :func:`kerb` on each sample ``ahead`` samples before its turn (the rows past
    ``len(out)`` are only looked at)."""
    j = 0
    for i in range(out.shape[0]):
        while j < T.shape[0] and j <= i + ahead:
            kerb(st, p, c, T[j], Y[j])
            j += 1
        out[i] = step(st, p, c, T[i], gaps[i], Y[i])


_compiled: list = []


def kernel():
    """:func:`run` compiled (numba, cached beside this file), or the Python one without numba."""
    if not _compiled:
        try:
            from numba import njit
        except ImportError:
            _compiled.append(run)
        else:
            # step and kerb compiled in place for the compiled run; the per-sample path keeps _step_py, _kerb_py
            globals()["kerb"] = njit(cache=True, nogil=True, inline="always")(_kerb_py)
            globals()["step"] = njit(cache=True, nogil=True, inline="always")(_step_py)
            _compiled.append(njit(cache=True, nogil=True)(run))
    return _compiled[0]


class Gates:
    """The gates' state for the per-sample path (the supervisor's), and their counts."""

    def __init__(self, cfg: GatesConfig | None = None, wheel_radius: float = 0.3):
        self.cfg = cfg or GatesConfig()
        self.p = params(self.cfg, wheel_radius)
        self._p = self.p.tolist()
        self._c = CHANNELS.tolist()
        self.reset()

    def reset(self) -> None:
        self.st = new_state()

    def ahead(self, t: float, y) -> None:
        """Show the kerb test a sample before its turn (vdp.pipeline's look-ahead): a strike it
        finds gates the samples from kerb_pre before it as they come."""
        _kerb_py(self.st, self._p, self._c, t, y)

    def update(self, t: float, gap: bool, y) -> int:
        _kerb_py(self.st, self._p, self._c, t, y)  # (nothing new where it was seen ahead)
        code = _step_py(self.st, self._p, self._c, t, gap, y)
        return code if self.cfg.shut or code > SHUTS else 0

    def block(self, T: np.ndarray, Y: np.ndarray, gaps: np.ndarray, n: int | None = None, ahead: int = 0) -> np.ndarray:
        """The codes of a block's first ``n`` samples (all by default), the state carried on (a
        replay's block pass); the kerb test sees each sample ``ahead`` samples before its turn,
        the rows past ``n`` only so."""
        st = np.array(self.st)
        out = np.zeros(len(T) if n is None else n, dtype=np.int64)
        kernel()(st, self.p, CHANNELS, T, Y, gaps, out, ahead)
        self.st = st.tolist()
        return out if self.cfg.shut else np.where(out > SHUTS, out, 0)

    def summary(self) -> dict:
        return summary({NAMES[k]: self.st[SECONDS + k - 1] for k in NAMES}, self.st[ANY], self.st[OBSERVED])


_step_py = step  # the Python functions, kept when kernel() compiles them in place
_kerb_py = kerb


def _pct(x: float) -> str:
    p = 100.0 * x
    return f"{p:.0f} %" if p >= 9.5 or p == 0 else f"{p:.1f} %".replace(".0 %", " %")


def summary(seconds: dict[str, float], gated: float, observed: float) -> dict:
    """The drive's gated share, in all and per gate: seconds, fractions and a sentence."""
    of = observed if observed > 0 else math.nan
    frac = {k: v / of for k, v in seconds.items() if v > 0} if observed > 0 else {}
    total = gated / of if observed > 0 else 0.0
    if not frac:
        text = "nothing of the drive gated out" if observed > 0 else "no data yet"
    else:
        parts = ", ".join(f"{k} {_pct(v)}" for k, v in frac.items())
        text = f"{_pct(total)} of the drive gated out: {parts}"
    return {
        "fraction": round(total, 4),
        "seconds": round(gated, 2),
        "of": round(observed, 2),
        "by_gate": {k: {"seconds": round(seconds[k], 2), "fraction": round(v, 4)} for k, v in frac.items()},
        "text": text,
    }
