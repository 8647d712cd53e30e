"""Drives of the running service: where one begins and ends, and the changes between them.

A drive begins when the service starts (the logger powered with the ignition) and after a
silence of the bus of GAP seconds of bus time (an ignition cycle of a logger that stays on);
it ends there and at a stop.  At each drive's start its bus print (the periodic CAN ids and
their periods, vdp.core.change.bus_print) is judged against the car the store has learnt:

- the same car: the estimates carried from earlier drives go on learning, and the store
  keeps them (until judged, PRINT_AFTER seconds of bus time, nothing is committed: a
  different car's first seconds never land in the known car's store);
- another car: its estimates start again from the priors, the store is refused with the
  reason and left as it is (the known car's estimates and history kept), and the raw log
  keeps every frame as always.

During a drive, every EVERY seconds of bus time, the drive's own measures (its mass from the
longitudinal dynamics, its wheel-speed scale, C_K and C_alpha against the values it started
from) go through vdp.core.change.detect; a change named resets only the parameters it
affects, and the store keeps it with the values before.

Everything here runs on the estimation worker (Service calls :meth:`Drives.check` through its
command queue), so the pipeline is never touched from two threads.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time

import numpy as np

from .. import channels as ch
from ..core.change import Measure, bus_print, combine, compare_prints, detect, fit_mass, fit_scale, id_counts
from ..core.mass import STAGE as MASS_STAGE
from ..core.params import MASS, STAGE1, STAGE2
from ..core.result import CONVERGED, UNCERTAIN
from ..errors import StoreError

log = logging.getLogger(__name__)

GAP = 60.0  # s of bus time without a sample: the car was switched off in between
LONG_STOP = 120.0  # s standing still with the bus on: a stop long enough to load the car
STILL = 0.3  # m/s: below it the car stands
PRINT_AFTER = 10.0  # s of bus time before a drive's bus print is judged
EVERY = 5.0  # s of bus time between looks at the drive's measures
TYRE_MIN_SAMPLES = (
    1000  # samples (10 s in windows) a stage must learn in this drive before its C_K or C_alpha is compared
)
LEARNT = (CONVERGED, UNCERTAIN)


class Stops:
    """Finds the long stops in a stream of (bus time, speed): standing still (below STILL) for
    LONG_STOP or longer and then moving again, where a load may have changed with the bus on."""

    def __init__(self, long_stop: float = LONG_STOP, still: float = STILL):
        self.long_stop, self.still = long_stop, still
        self.since: float | None = None  # bus time the car has stood still since
        self.seen = -math.inf

    def feed(self, t, v) -> tuple[float, float] | None:
        """The newest (stopped at, moving again at) among samples newer than those fed before."""
        out = None
        for ti, vi in zip(t, v):
            if ti <= self.seen or not math.isfinite(vi):
                continue
            self.seen = ti
            if abs(vi) < self.still:
                if self.since is None:
                    self.since = ti
            else:
                if self.since is not None and ti - self.since >= self.long_stop:
                    out = (self.since, ti)
                self.since = None
        return out


def summary(params) -> dict:
    """What a drive row keeps of the estimates: value, std, valid, status, samples per parameter."""
    return {
        n: {"value": e.value, "std": e.std, "valid": e.valid, "status": e.status, "samples": e.samples}
        for n, e in params.items()
    }


def _measure(doc) -> Measure | None:
    if not doc or doc.get("value") is None or doc.get("std") is None:
        return None
    return Measure(float(doc["value"]), float(doc["std"]))


class Drives:
    def __init__(self, profile, writer, gap: float = GAP, print_after: float = PRINT_AFTER, every: float = EVERY):
        self.profile = profile
        self.writer = writer
        self.gap, self.print_after, self.every = gap, print_after, every
        self.drive: int | None = None  # the store's row of the drive going on
        self.number = 0  # drives begun in this run
        self.t0: float | None = None  # bus time the drive began
        self.count_t0: float | None = None
        self.counts0: dict[int, int] = {}
        self.start: dict = {}  # name -> Estimate the drive started from
        self.ref_print: dict[int, float] | None = None  # the store's car
        self.print: dict[int, float] | None = None  # this drive's, once judged
        self.confirmed = False
        self.refused: str | None = None
        self.mass_ref: Measure | None = None
        self.scale_ref: Measure | None = None
        self.mass: Measure | None = None
        self.scale: Measure | None = None
        self.named: set[str] = set()  # kinds named in this drive
        self.changes: list[dict] = []  # named in this run, for /status
        self._next = -math.inf
        self._seen = -math.inf  # newest self-check sample looked at for gaps
        self.stops = Stops()

    # -- the store's side ----------------------------------------------------------------------
    def open(self) -> None:
        """Read the known car (its bus print) and the references earlier drives left."""
        store = self.writer.store
        if store is None:
            return
        try:
            text = store.meta("bus_print")
            drives, changes = store.drives(), store.changes()
        except StoreError as exc:
            log.error("cannot read the drives of %s: %s", store.path, exc)
            return
        self.ref_print = {int(k): float(v) for k, v in json.loads(text).items()} if text else None
        if self.ref_print is not None:  # nothing committed before the bus is known to be this car's
            self.writer.hold = "judging whether the bus is the known car's"

        def since(kinds) -> int:
            return max((c["drive"] or 0 for c in changes if c["kind"] in kinds), default=0)

        cut = since(("mass", "car"))
        self.mass_ref = combine([m for d in drives if d["id"] >= cut and (m := _measure(d["mass"])) is not None])
        cut = since(("tyres", "car"))
        self.scale_ref = combine([m for d in drives if d["id"] >= cut and (m := _measure(d["scale"])) is not None])

    def _store(self):
        return None if self.refused else self.writer.store

    def _write(self, what: str, fn) -> None:
        store = self._store()
        if store is None:
            return
        try:
            fn(store)
        except StoreError as exc:
            log.error("could not keep the %s in %s: %s", what, store.path, exc)

    # -- the worker's side ---------------------------------------------------------------------
    def check(self, pipe) -> None:
        """Look at the drive so far (on the estimation worker)."""
        now = pipe.last_bus_time
        mon = getattr(pipe, "monitor", None)
        if now is None or mon is None:
            return
        gap = self._gap(mon) or self._stop(mon)
        if gap is not None and self.t0 is not None:
            self.end(pipe, gap[0])
            self.begin(pipe, gap[1])
        if self.t0 is None:
            self.begin(pipe, mon.t[0] if mon.t else now)
        if now < self._next:
            return
        self._next = now + self.every
        if not self.confirmed and not self.refused and now - self.count_t0 >= self.print_after:
            self._judge(pipe, now)
        if self.confirmed:
            self._look(pipe, now)

    def silence(self, pipe, end: float | None, start: float) -> None:
        """The bus was silent from ``end`` to ``start`` [bus time] and the frame at ``start`` is not
        yet fed (the worker's hook); ``end`` None: it is the run's first frame.  The drive so far
        is looked at and ends at ``end``, and the next begins at ``start``, from the parameters as
        they are before its first frame and with its frame counts from here.  Begun at the
        keeper's next look instead, a drive fed faster than the keeper runs (a replayed drive, a
        second of wall time) began with some of its own learning already in its start, so a tyre
        change could not show, and a drive that ended before that look was never stored."""
        if end is not None:
            self.check(pipe)
            if self.t0 is not None:
                self.end(pipe, end)
        self.begin(pipe, start)
        self.count_t0 = start
        self._seen = max(self._seen, start)  # the silence is handled: the next look does not end this drive

    @staticmethod
    def monitor_ok(pipe) -> bool:
        return pipe.last_bus_time is not None and getattr(pipe, "monitor", None) is not None

    def _gap(self, mon) -> tuple[float, float] | None:
        """(end, start) of the newest silence longer than ``gap`` among the samples not yet seen (the
        self-check keeps only its last minutes: the samples before a long silence are gone from it,
        so the newest one seen before is remembered)."""
        t = mon.t
        out = None
        i = len(t) - 1
        while i >= 0 and t[i] > self._seen:
            before = t[i - 1] if i > 0 and t[i - 1] > self._seen else self._seen
            if math.isfinite(before) and t[i] - before > self.gap:
                out = (before, t[i])
                break
            i -= 1
        if t:
            self._seen = max(self._seen, t[-1])
        return out

    def _stop(self, mon) -> tuple[float, float] | None:
        """A long stop with the bus on among the self-check's new samples (Stops)."""
        n = 0
        while n < len(mon.t) and mon.t[-1 - n] > self.stops.seen:
            n += 1
        if not n:
            return None
        y = np.vstack(mon.y[-n:])
        p, veh = self.profile, self.profile.vehicle
        wheels = [ch.INDEX[c] for c in ch.NAMES[:4] if p.has(c)]
        if p.has("speed"):
            v = y[:, ch.SPEED]
        elif wheels:
            v = np.nanmean(y[:, wheels], axis=1) * veh.wheel_radius
        else:
            return None
        return self.stops.feed(mon.t[-n:], v)

    def begin(self, pipe, t: float) -> None:
        self.number += 1
        self.t0 = t
        self.count_t0 = pipe.last_bus_time if pipe.last_bus_time is not None else t
        self.counts0 = id_counts(pipe.decoder)
        self.start = dict(pipe.result().parameters)
        self.print, self.confirmed, self.drive = None, False, None
        self.mass = self.scale = None
        self.named = set()
        self._next = -math.inf
        if self.ref_print is not None and not self.refused:
            # another car's first seconds must not land in the known car's store
            self.writer.hold = "judging whether the bus is the known car's"
        log.info("drive %d began (bus time %.1f)", self.number, t)

    def _judge(self, pipe, now: float) -> None:
        counts = id_counts(pipe.decoder)
        delta = {k: n - self.counts0.get(k, 0) for k, n in counts.items()}
        self.print = bus_print(delta, now - self.count_t0)
        why = compare_prints(self.ref_print, self.print) if self.ref_print is not None else None
        if why is not None:
            self._another_car(pipe, why)
            return
        self.confirmed = True
        self.writer.hold = None
        if self.ref_print is None and self.print:
            self.ref_print = self.print
            doc = json.dumps({str(k): v for k, v in self.print.items()})
            self._write("bus print", lambda s: s.set_meta("bus_print", doc))
        start = summary(self.start)
        prn = {f"0x{k:X}": v for k, v in self.print.items()}
        store = self._store()
        if store is not None:
            try:
                self.drive = store.begin_drive(time.time(), self.t0, start, prn)
            except StoreError as exc:
                log.error("could not keep the drive in %s: %s", store.path, exc)

    def _another_car(self, pipe, why: str) -> None:
        path = self.writer.cfg.path
        self.refused = (
            f"another car on this logger: {why}. The store {path} holds the estimates of "
            f"'{self.writer.profile_name}' as learnt on the known car and is kept as it is; this car's "
            "estimates start from the priors and are not saved (give it its own [store] path, or "
            "vdp serve --db FILE)"
        )
        log.error("%s", self.refused)
        pipe.reset(None)
        self.writer.refuse(self.refused)
        change = {"kind": "car", "what": f"a different car: {why}", "size": None, "params": list(STAGE1 + STAGE2)}
        self.changes.append({**change, "t": time.time(), "bus_t": pipe.last_bus_time, "drive": None, "saved": False})

    def _look(self, pipe, now: float) -> None:
        params = pipe.result().parameters
        self.mass, self.scale = self._fits(pipe.monitor)
        ref = {"mass": None if "mass" in self.named else self.mass_ref, "radius": self.scale_ref}
        cur = {"mass": self.mass, "radius": self.scale}
        if "tyres" not in self.named:
            for name in ("C_K", "C_alpha"):
                a, b = self.start.get(name), params.get(name)
                if (
                    a is not None
                    and b is not None
                    and a.status in LEARNT
                    and b.status in LEARNT
                    and b.samples - a.samples >= TYRE_MIN_SAMPLES
                ):
                    ref[name], cur[name] = Measure(a.value, a.std), Measure(b.value, b.std)
        else:
            ref["radius"] = None
        for change in detect(ref, cur, mass_estimated=_mass_used(pipe)):
            if change.kind in self.named:
                continue
            self._apply(pipe, change, params)
            params = pipe.result().parameters
        self._write(
            "drive",
            lambda s: (
                self.drive is not None
                and s.update_drive(self.drive, time.time(), now, summary(params), _doc(self.mass), _doc(self.scale))
            ),
        )

    def _fits(self, mon) -> tuple[Measure | None, Measure | None]:
        """This drive's mass and wheel-speed scale, from the self-check's samples (10 Hz, its last 10 min)."""
        if not mon.t:
            return None, None
        t = np.asarray(mon.t)
        keep = t >= self.t0
        if keep.sum() < 20:
            return None, None
        y = np.vstack([mon.y[i] for i in np.flatnonzero(keep)])
        veh, p = self.profile.vehicle, self.profile
        wheels = [c for c in ch.NAMES[:4] if p.has(c)]
        v_wheel = np.nanmean(y[:, [ch.INDEX[c] for c in wheels]], axis=1) * veh.wheel_radius if wheels else None
        v_ref = y[:, ch.SPEED] if p.has("speed") else None
        v = v_ref if v_ref is not None else v_wheel
        mass = scale = None
        if v is not None and all(p.has(c) for c in ("wheel_torque_front", "wheel_torque_rear", "accel_x")):
            force = (y[:, ch.T_F] + y[:, ch.T_R]) / veh.wheel_radius
            mass = fit_mass(force, y[:, ch.AX], v, veh.wheel_inertia, veh.wheel_radius)
        if v_wheel is not None and v_ref is not None:
            scale = fit_scale(v_wheel, v_ref)
        return mass, scale

    def _apply(self, pipe, change, params) -> None:
        """Reset the parameters ``change`` affects to their priors; keep it and the values before.
        The mass (a mass step, where it is learnt) goes back to its learner's prior: a learner
        resumed from the drives before would otherwise take the new load's rows as outliers."""
        priors = self.profile.priors
        learns = getattr(getattr(pipe, "estimator", None), "mass", None) is not None  # (off: the profile's, kept)
        hit = [n for n in change.params if n in params and (n in priors or (n == MASS and learns))]
        old = {n: {"value": params[n].value, "std": params[n].std, "status": params[n].status} for n in hit}
        seed = {}
        for names in (STAGE1, STAGE2):
            if not any(n in hit for n in names):
                continue  # a stage the change leaves alone keeps its filter as it is
            for n in names:
                e = params.get(n)
                if e is None:
                    continue
                if n in hit:
                    seed[n] = dataclasses.replace(e, value=priors[n].value, std=priors[n].std)
                elif e.value is not None and e.std is not None:
                    seed[n] = e
        if seed:
            pipe.restore(seed)  # (published values: taken out of the mass they were published with, then)
        if MASS in hit:
            pipe.reset(MASS_STAGE)
        now = pipe.result().parameters
        for n in hit:
            self.start[n] = now[n]  # the tyres are judged from here on against the new values
        self.named.add(change.kind)
        if change.kind == "mass":
            self.mass_ref = None  # the drives from this one on are the reference now
        if change.kind == "tyres":
            self.scale_ref = None
        doc = change.as_dict()
        log.warning("change named: %s; reset %s", change.what, ", ".join(hit) or "nothing")
        self.changes.append({**doc, "t": time.time(), "bus_t": pipe.last_bus_time, "drive": self.drive, "old": old})
        self._write("change", lambda s: s.add_change(time.time(), pipe.last_bus_time, self.drive, doc, old))

    def end(self, pipe, t: float | None = None) -> None:
        """The drive has ended (a silence, or the service stopping): keep its last values."""
        if self.t0 is None:
            return
        if self.confirmed and self.monitor_ok(pipe) and (t is None or t >= pipe.last_bus_time):
            # the drive's last measures: a change its last seconds show is named too (the looks come
            # every EVERY s of bus time, and a drive fed faster than the keeper runs gets few)
            self._look(pipe, pipe.last_bus_time)
        params = pipe.result().parameters
        if self.confirmed and self.drive is not None:
            self._write(
                "drive",
                lambda s: s.update_drive(
                    self.drive, time.time(), t if t is not None else pipe.last_bus_time, summary(params),
                    _doc(self.mass), _doc(self.scale), state="ended",
                ),
            )  # fmt: skip
        # what this drive measured is the reference for the next (within this run)
        if self.mass is not None:
            self.mass_ref = (
                self.mass if "mass" in self.named or self.mass_ref is None else combine([self.mass_ref, self.mass])
            )
        if self.scale is not None:
            self.scale_ref = self.scale if self.scale_ref is None else combine([self.scale_ref, self.scale])
        log.info("drive %d ended", self.number)
        self.t0 = None

    def status(self) -> dict:
        return {
            "drive": self.drive,
            "drives_this_run": self.number,
            "bus_print": "another car" if self.refused else ("same car" if self.confirmed else "judging"),
            "refused": self.refused,
            "mass": _doc(self.mass),
            "wheel_speed_scale": _doc(self.scale),
            "changes": self.changes,
        }


def _mass_used(pipe) -> bool:
    """Whether the estimator puts a learnt mass into C_K and C_alpha (core.mass.scaled): then a
    mass step leaves them alone (core.change.affected)."""
    est = getattr(pipe, "estimator", None)
    return bool(est is not None and est.cfg.mass.put)


def _doc(m: Measure | None) -> dict | None:
    return None if m is None else {"value": m.value, "std": m.std}
