"""Changes between drives: per-drive measurements in, named changes out (issue 28, part 4).

A car is learnt over many drives (the service carries its estimates from one to the next).
Between two drives, or at a long stop, it may change:

- a **mass step**: passengers, luggage, a roof box.  Measured per drive from the longitudinal
  dynamics (:func:`fit_mass`, the profile check's fit with a std), or from a ``mass`` estimate
  where the estimator has one;
- a **tyre change**: a step in C_alpha or C_K beyond their combined std, or in the rolling
  radius (the wheel speeds against the ground speed);
- a **different car**: its bus carries other CAN ids, or the same ones at other periods
  (:func:`bus_print`, :func:`compare_prints`).  A profile's fingerprint alone cannot tell: two
  cars may share a profile.

Each detector takes a value and its std per drive and knows nothing of where they came from,
so ``vdp serve`` and ``vdp batch`` (a fleet's drives in time order) apply the same rules.
A change names the parameters it makes stale (:data:`AFFECTS`); only those are reset.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

K_STEP = 3.0  # a step beyond this many combined stds is a change (a false alarm ~0.3 % a test)
# The smallest step worth naming, relative: below it the change is within what a drive's
# conditions move (fuel, a passenger's weight against the model's floor; tyre wear and
# temperature move C_alpha by a few per cent within a drive).
MIN_STEP = {"mass": 0.05, "C_K": 0.08, "C_alpha": 0.08, "radius": 0.01}

# What each change makes stale.  A load moves the CG and adds inertia: l_f, h, I_z, I_x are the
# loaded car's afterwards.  While the mass is the profile's constant (no ``mass`` estimate), C_K
# (per unit load) and C_alpha absorb a wrong mass too, so they go with it.
AFFECTS = {
    "mass": ("mass", "l_f", "h", "I_z", "I_x"),
    "tyres": ("C_K", "C_alpha"),
    "car": ("mass", "l_f", "h", "C_K", "C_alpha", "I_z", "I_x"),
}
MASS_COUPLED = ("C_K", "C_alpha")  # reset with a mass step while the mass is not estimated

# a different car's bus: ids with at least this rate count (a periodic message; event frames,
# diagnostics and a door's status come and go and do not identify the car)
PRINT_MIN_RATE = 2.0  # Hz
PRINT_MIN_IDS = 3  # this many ids, each way, make a mismatch ...
PRINT_SHARE = 0.15  # ... or this share of the reference's ids, whichever is larger
PERIOD_TOL = 0.3  # a shared id's period differing by more than this share is another car's


@dataclass(frozen=True)
class Measure:
    """One drive's value of a quantity and its 1-sigma std."""

    value: float
    std: float

    @property
    def ok(self) -> bool:
        return math.isfinite(self.value) and math.isfinite(self.std) and self.std > 0 and self.value != 0


@dataclass(frozen=True)
class Change:
    """A named change: ``kind`` (mass, tyres, car), a sentence saying which and how large,
    the relative ``size`` of the step (None for a car), the parameters it resets, and the
    numbers behind it (old, new, their stds)."""

    kind: str
    what: str
    size: float | None
    params: tuple[str, ...]
    numbers: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"kind": self.kind, "what": self.what, "size": self.size, "params": list(self.params), **self.numbers}


def step(old: Measure, new: Measure, min_rel: float = 0.0, k: float = K_STEP) -> float | None:
    """``new / old - 1`` when the step is beyond ``k`` combined stds and ``min_rel``, else None.

    The combined std sqrt(s_old^2 + s_new^2) is that of two independent values.  Where ``old`` is
    a filter's value at a drive's start and ``new`` the same filter's later, the difference's
    std is smaller (sqrt(s_old^2 - s_new^2) for a Kalman filter): the test is conservative.
    """
    if not (old.ok and new.ok):
        return None
    d = new.value - old.value
    if abs(d) <= k * math.hypot(old.std, new.std) or abs(d) <= min_rel * abs(old.value):
        return None
    return d / old.value


def combine(measures: Sequence[Measure]) -> Measure | None:
    """Inverse-variance mean of several drives' measures (the reference a new drive is tested against)."""
    good = [m for m in measures if m.ok]
    if not good:
        return None
    w = [1.0 / m.std**2 for m in good]
    return Measure(sum(wi * m.value for wi, m in zip(w, good)) / sum(w), 1.0 / math.sqrt(sum(w)))


def affected(kind: str, mass_estimated: bool = False) -> tuple[str, ...]:
    """The parameters a change of ``kind`` resets."""
    out = AFFECTS[kind]
    if kind == "mass" and not mass_estimated:
        out = out + MASS_COUPLED
    return out


def _pct(x: float) -> str:
    return f"{100 * x:+.0f} %"


def detect(
    ref: Mapping[str, Measure | None], now: Mapping[str, Measure | None], mass_estimated: bool = False
) -> list[Change]:
    """Changes between a reference (``mass``, ``C_K``, ``C_alpha``, ``radius``: earlier drives'
    or the value a drive started from) and a drive's measures.  A mass step comes first and,
    while the mass is not estimated, explains a step in C_K and C_alpha: no tyre change is
    named beside it (those two are reset with the mass anyway)."""
    out: list[Change] = []
    m0, m1 = ref.get("mass"), now.get("mass")
    if m0 is not None and m1 is not None:
        s = step(m0, m1, MIN_STEP["mass"])
        if s is not None:
            out.append(
                Change(
                    "mass",
                    f"mass step of {m1.value - m0.value:+.0f} kg ({_pct(s)}): {m0.value:.0f} ± {m0.std:.0f} kg "
                    f"before, {m1.value:.0f} ± {m1.std:.0f} kg now",
                    s,
                    affected("mass", mass_estimated),
                    {"old": m0.value, "old_std": m0.std, "new": m1.value, "new_std": m1.std},
                )
            )
    if out and not mass_estimated:
        return out
    steps = []
    for name in ("C_K", "C_alpha", "radius"):
        a, b = ref.get(name), now.get(name)
        if a is None or b is None:
            continue
        s = step(a, b, MIN_STEP[name])
        if s is not None:
            steps.append((name, s, a, b))
    if steps:
        what = ", ".join(
            f"{n} {_pct(s)} ({a.value:.4g} ± {a.std:.2g} to {b.value:.4g} ± {b.std:.2g})" for n, s, a, b in steps
        )
        big = max(steps, key=lambda x: abs(x[1]))
        out.append(
            Change(
                "tyres",
                f"tyre change: {what}",
                big[1],
                affected("tyres"),
                {n: {"old": a.value, "old_std": a.std, "new": b.value, "new_std": b.std} for n, _, a, b in steps},
            )
        )
    return out


# -- the car on the bus -------------------------------------------------------------------------
def bus_print(counts: Mapping[int, int], duration: float, min_rate: float = PRINT_MIN_RATE) -> dict[int, float]:
    """The periodic CAN ids of ``duration`` seconds of bus and their mean periods [s]: what
    identifies a car on its bus (which ECUs talk, and how often)."""
    if not duration > 0:
        return {}
    return {int(i): duration / n for i, n in counts.items() if n >= max(min_rate * duration, 2)}


def id_counts(dec) -> dict[int, int]:
    """Frames per CAN id (the decoder's key: the id, with its extended flag) a FrameDecoder has
    been offered: those it decodes, those it refused, and the ids it does not know."""
    out = dict(dec.stats.unknown.copy())
    for p in list(dec._plans.values()):
        if p.good:
            out[p.key] = out.get(p.key, 0) + p.good
    for (key, _kind), n in dec.stats.errors.copy().items():
        out[key] = out.get(key, 0) + n
    return out


def _ids(keys) -> str:
    keys = sorted(keys)
    text = ", ".join(f"0x{k & 0x1FFFFFFF:X}" for k in keys[:6])
    return text + (f" and {len(keys) - 6} more" if len(keys) > 6 else "")


def compare_prints(ref: Mapping[int, float], new: Mapping[int, float]) -> str | None:
    """Why the bus of ``new`` is not the car of ``ref`` (two :func:`bus_print` results), or None.

    Some ids of a car come and go (a GNSS that starts late, an ECU that sleeps), so a few
    missing or extra ids are tolerated: a mismatch needs PRINT_MIN_IDS ids or PRINT_SHARE of the
    reference's, whichever is more, new, missing or at another period.
    """
    if not ref or not new:
        return None
    need = max(PRINT_MIN_IDS, math.ceil(PRINT_SHARE * len(ref)))
    extra = set(new) - set(ref)
    gone = set(ref) - set(new)
    moved = {i for i in set(ref) & set(new) if abs(new[i] / ref[i] - 1.0) > PERIOD_TOL}
    why = []
    if len(extra) >= need:
        why.append(f"{len(extra)} periodic CAN ids never on the known car's bus ({_ids(extra)})")
    if len(gone) >= need:
        why.append(f"{len(gone)} of its {len(ref)} periodic ids absent ({_ids(gone)})")
    if len(moved) >= need:
        why.append(f"{len(moved)} ids at other periods ({_ids(moved)})")
    return "; ".join(why) or None


# -- a drive's mass ---------------------------------------------------------------------------------
MASS_MIN_SAMPLES = 50  # strong samples (|a_x| > 0.5 m/s^2) a fit needs
MASS_CHUNKS = 6  # contiguous pieces of the drive for the jackknife std
MASS_FLOOR = 0.01  # relative: grade and drag the fit's road-load terms do not follow


def _smooth(x: np.ndarray, win: int) -> np.ndarray:
    if win <= 1:
        return x
    k = np.ones(win) / win
    return np.convolve(x, k, mode="same")


def fit_mass(
    force: np.ndarray, ax: np.ndarray, v: np.ndarray, wheel_inertia: float, wheel_radius: float, win: int = 5
) -> Measure | None:
    """The mass from the wheel torques' force and a_x (eqs 1-2 summed over both axles), as the
    profile check fits it (profilecheck.check_samples, "mass_fit"): force = m_eff a_x + c + k v^2
    (rolling resistance and grade, drag), m = m_eff - 2 J / r^2.  The std is a delete-one-piece
    jackknife over MASS_CHUNKS contiguous pieces of the drive (the residuals are coloured: the
    lstsq formula's std would be several times too small), with MASS_FLOOR.  None when the drive
    has too little acceleration or braking (|a_x| > 0.5 m/s^2) to tell."""
    force, ax, v = (_smooth(np.asarray(a, dtype=float), win) for a in (force, ax, v))
    ok = np.isfinite(force) & np.isfinite(ax) & np.isfinite(v) & (v > 1.0)
    if win > 1:
        ok[:win] = ok[-win:] = False
    strong = ok & (np.abs(ax) > 0.5)
    if strong.sum() < MASS_MIN_SAMPLES:
        return None
    idx = np.flatnonzero(ok)
    inertia = 2.0 * wheel_inertia / wheel_radius**2

    def fit(sel: np.ndarray) -> float:
        A = np.column_stack([ax[sel], np.ones(len(sel)), v[sel] ** 2])
        coef, *_ = np.linalg.lstsq(A, force[sel], rcond=None)
        return float(coef[0]) - inertia

    m = fit(idx)
    pieces = np.array_split(idx, MASS_CHUNKS)
    loo = []
    for i in range(MASS_CHUNKS):
        rest = np.concatenate([p for j, p in enumerate(pieces) if j != i])
        if (np.abs(ax[rest]) > 0.5).sum() >= MASS_MIN_SAMPLES // 2:
            loo.append(fit(rest))
    if len(loo) < 3:
        return None
    k = len(loo)
    jack = math.sqrt((k - 1) / k * float(np.sum((np.array(loo) - np.mean(loo)) ** 2)))
    return Measure(m, math.hypot(jack, MASS_FLOOR * abs(m)))


def fit_scale(v_wheel: np.ndarray, v_ref: np.ndarray) -> Measure | None:
    """The wheel speeds' scale against the ground speed (a rolling radius relative to the
    profile's): the median ratio above 3 m/s, as the profile check measures "wheel_speed_scale",
    with a jackknife std over contiguous pieces.  A new tyre of another size steps it."""
    ok = np.isfinite(v_wheel) & np.isfinite(v_ref) & (v_ref > 3.0)
    idx = np.flatnonzero(ok)
    if len(idx) < MASS_MIN_SAMPLES:
        return None
    r = v_wheel[idx] / v_ref[idx]
    med = float(np.median(r))
    pieces = np.array_split(np.arange(len(idx)), MASS_CHUNKS)
    loo = [float(np.median(np.delete(r, p))) for p in pieces]
    k = len(loo)
    jack = math.sqrt((k - 1) / k * float(np.sum((np.array(loo) - np.mean(loo)) ** 2)))
    return Measure(med, math.hypot(jack, 1e-3 * med))  # 0.1 %: the speeds' own resolution and slip
