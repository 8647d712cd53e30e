"""A drive's own measures, and the changes named across a vehicle's drives in time order.

Each log's mass, wheel-speed scale and bus print come from its first minutes, read as the
profile check reads them (:func:`vdp.profilecheck.first_seconds`, the samples the running
service's self-check measures its drives on); :func:`changes` applies the running service's
rules (vdp.core.change: detect, compare_prints, combine) to a vehicle's drives in the time
order of their logs.  ``vdp batch`` runs it over runs.parquet's rows, ``vdp replay --after``
over earlier replays' JSON documents (:func:`document_rows`) and this one.  Plain Python and
numpy: no dataframe, no Dask.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from typing import Any

from .core.result import CONVERGED, UNCERTAIN, learnt_in

# -- a drive's own measures, and the changes between a vehicle's drives -----------------------
MEASURE_SECONDS = 300.0  # of bus time from a log's start (the profile check reads as much)


def drive_measures(path: str, profile: Any, seconds: float = MEASURE_SECONDS) -> dict[str, Any]:
    """The columns of a log's own mass, wheel-speed scale and bus print, from its first
    ``seconds``, decoded and aligned as the profile check reads them (profilecheck.first_seconds:
    the samples the running service's self-check gives its drives' measures)."""
    from .profilecheck import first_seconds

    return measures_of(first_seconds(path, profile, seconds, quiet=True), profile)


def measures_of(head: Any, profile: Any) -> dict[str, Any]:
    """:func:`drive_measures` of a log's first seconds already read (a profilecheck.Head), its
    samples kept at 10 Hz as the self-check keeps them (fit_mass smooths over 5)."""
    import numpy as np

    from . import channels as ch
    from .core.change import bus_print, fit_mass, fit_scale, id_counts

    out: dict[str, Any] = dict.fromkeys(("mass", "mass_std", "wheel_scale", "wheel_scale_std", "bus_print"))
    if head.span > 0:
        prn = bus_print(id_counts(head.decoder), head.span)
        out["bus_print"] = json.dumps({f"0x{k:X}": round(v, 6) for k, v in prn.items()})
    keep, last = [], -math.inf
    for i, t in enumerate(head.t):
        if t - last >= 0.1:
            keep.append(i)
            last = t
    if len(keep) < 20:
        return out
    y = head.y[keep]
    veh = profile.vehicle
    wheels = [c for c in ch.NAMES[:4] if profile.has(c)]
    v_wheel = np.nanmean(y[:, [ch.INDEX[c] for c in wheels]], axis=1) * veh.wheel_radius if wheels else None
    v_ref = y[:, ch.SPEED] if profile.has("speed") else None
    v = v_ref if v_ref is not None else v_wheel
    if v is not None and all(profile.has(c) for c in ("wheel_torque_front", "wheel_torque_rear", "accel_x")):
        m = fit_mass(
            (y[:, ch.T_F] + y[:, ch.T_R]) / veh.wheel_radius, y[:, ch.AX], v, veh.wheel_inertia, veh.wheel_radius
        )
        if m is not None:
            out["mass"], out["mass_std"] = m.value, m.std
    if v_wheel is not None and v_ref is not None:
        k = fit_scale(v_wheel, v_ref)
        if k is not None:
            out["wheel_scale"], out["wheel_scale_std"] = k.value, k.std
    return out


def changes(rows: Iterable[Mapping[str, Any]]) -> list[dict]:
    """The changes between each vehicle's drives, in the time order of their logs: the rules of
    the running service (vdp.core.change.detect, compare_prints) on each log's own estimates
    and measures.  A drive is tested against the drives since the last change of that kind
    (their inverse-variance combination); another car's bus is tested against the vehicle's
    first drive (or the first since another car).  One dict per change: vehicle, log, start_time,
    kind, what, size, params."""
    from .core.change import Measure, affected, combine, compare_prints, detect

    drives: dict[str, dict[str, dict]] = {}
    for r in rows:
        if r.get("parameter") is None:
            continue  # an error row
        d = drives.setdefault(r["vehicle"], {}).setdefault(r["log"], {"row": r, "params": {}})
        d["params"][r["parameter"]] = r
    out: list[dict] = []

    def measure(v, s) -> Measure | None:
        return Measure(v, s) if v is not None and s is not None and math.isfinite(v) and math.isfinite(s) else None

    for vehicle in sorted(drives):
        logs = sorted(drives[vehicle].values(), key=lambda d: (d["row"].get("start_time") or math.inf, d["row"]["log"]))
        since: dict[str, list[dict]] = {"mass": [], "tyres": []}
        ref_print = None
        for d in logs:
            r = d["row"]
            prn = {int(k, 16): v for k, v in json.loads(r["bus_print"]).items()} if r.get("bus_print") else None
            now = {
                "mass": measure(r.get("mass"), r.get("mass_std")),
                "radius": measure(r.get("wheel_scale"), r.get("wheel_scale_std")),
            }
            for n in ("C_K", "C_alpha"):
                p = d["params"].get(n)
                now[n] = measure(p.get("value"), p.get("std")) if p is not None and usable(p) else None
            found = []
            why = compare_prints(ref_print, prn) if ref_print and prn else None
            if why is not None:
                car = {"kind": "car", "what": f"a different car: {why}", "size": None, "params": list(affected("car"))}
                found.append(car)
                since = {"mass": [], "tyres": []}
                ref_print = prn
            else:
                ref_print = ref_print or prn
                ref = {
                    "mass": combine([x["mass"] for x in since["mass"] if x["mass"] is not None]),
                    "radius": combine([x["radius"] for x in since["tyres"] if x["radius"] is not None]),
                }
                for n in ("C_K", "C_alpha"):
                    ref[n] = combine([x[n] for x in since["tyres"] if x[n] is not None])
                # a drive whose mass was learnt (vdp batch --mass) has it put into C_K and C_alpha:
                # a mass step leaves them alone, as in the running service (core.change.affected)
                learnt = bool(r.get("mass_learnt"))
                for c in detect(ref, now, mass_estimated=learnt):
                    found.append(c.as_dict())
                    if c.kind == "mass" and learnt:
                        since["mass"] = []
                    elif c.kind == "mass":
                        since = {"mass": [], "tyres": []}  # C_K and C_alpha went with it
                    else:
                        since["tyres"] = []
            since["mass"].append(now)
            since["tyres"].append(now)
            for c in found:
                out.append({"vehicle": vehicle, "log": r["log"], "start_time": r.get("start_time"), **c})
    return out


def since_changes(rows: Iterable[Mapping[str, Any]], found: Iterable[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """``rows`` without the drives before the last change (of :func:`changes`) that affects their
    parameter: a vehicle's combination is of the car as it is now, not of the car before new tyres."""
    cut: dict[tuple[str, str], float] = {}
    for c in found:
        t = c.get("start_time")
        if t is None:
            continue
        for p in c.get("params") or ():
            key = (c["vehicle"], p)
            cut[key] = max(cut.get(key, -math.inf), t)
    out = []
    for r in rows:
        t0 = cut.get((r.get("vehicle"), r.get("parameter")))
        t = r.get("start_time")
        if t0 is None or (t is not None and t >= t0):
            out.append(r)
    return out


# -- combining a vehicle's drives -------------------------------------------


def usable(row: Mapping[str, Any]) -> bool:
    """A drive's parameter enters the combination only if vdp called it valid (its honest std
    within the usefulness threshold, no profile the self-check found wrong, ...)."""
    v, s = row.get("value"), row.get("std")
    return (
        bool(row.get("valid"))
        and row.get("status") in (CONVERGED, UNCERTAIN)  # learnt from the data (an older row may say more)
        and v is not None
        and s is not None
        and math.isfinite(v)
        and math.isfinite(s)
        and s > 0
    )


def document_rows(doc: Mapping[str, Any], log: str, vehicle: str = "") -> list[dict]:
    """The rows :func:`changes` reads of one `vdp replay --json` document: its parameters, and its
    drive's own measures (the document's ``drive``)."""
    d = doc.get("drive") or {}
    prn = d.get("bus_print")
    common = {k: d.get(k) for k in ("start_time", "mass", "mass_std", "wheel_scale", "wheel_scale_std")}
    common.update(vehicle=vehicle, log=log, bus_print=json.dumps(prn) if prn else None)
    params = doc.get("parameters") or {}
    # a replay with --mass: the six carry the mass they were scaled with (core.mass.scaled's mass_used)
    extras = [(p or {}).get("extra") or {} for p in params.values()]
    put = learnt_in(extras)  # (core.mass.scaled's mark; a JSON from before it: mass_used)
    common["mass_learnt"] = put if put is not None else any("mass_used" in x for x in extras)
    return [
        dict(common, parameter=n, value=p.get("value"), std=p.get("std"), status=p.get("status"), valid=p.get("valid"))
        for n, p in params.items()
    ]
