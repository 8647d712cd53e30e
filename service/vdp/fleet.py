"""Fleet runs: one task per log, rows per log x parameter, drives combined per vehicle.

``run_task`` is what a Dask worker runs (``vdp batch``): it replays one log
exactly as ``vdp replay`` does and returns plain rows, or one error row if the
log is missing, damaged or truncated.  ``combine`` merges a vehicle's valid
drives by inverse-variance weighting and tests them for consistency (chi^2),
flagging a drive that disagrees with the rest.  Everything here is plain
Python and numpy: the CLI owns Dask and Parquet.
"""

from __future__ import annotations

import contextvars
import hashlib
import logging
import math
import os
import stat
import time
import traceback
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from . import __version__
from .across import changes, drive_measures, measures_of, since_changes, usable  # noqa: F401 (batch's, scripts')
from .core.params import PUBLISHED
from .core.result import CONVERGED, INVALID, NOT_IDENTIFIABLE, NOT_RUN, UNCERTAIN
from .errors import VdpError

log = logging.getLogger(__name__)

PARAMETERS = PUBLISHED  # the six and the mass (its row says not_run where its estimation is off)
Z_FLAG = 3.0  # |z| of a drive against the others' combination that flags it as disagreeing
# The share of each drive's std that is common to all drives of a car, and so does not average
# out: the model's error, the profile's constants and the priors are the same in every drive.
# On vdp's own simulator, 12 paper drives of one car scattered by ~0.6 of their stds around a
# value ~0.6 of a std off the truth; independent drives would scatter by 1 (docs/decisions/0010;
# "Combining a car's drives").  Without it 12 drives' combination was 2.1-2.6 of its std off.
COMMON = 0.7
P_CONSISTENT = 0.01  # chi^2 p-value below which a vehicle's drives are called inconsistent

# what a status means when the parameter has no number worth using (the README's table)
REASONS = {
    NOT_RUN: "its stage had no window in this log (window_s is 0)",
    UNCERTAIN: "std still above the convergence threshold",
    NOT_IDENTIFIABLE: "the data did not halve the prior std: the value is mostly the prior's",
    INVALID: "non-finite or outside a sane range",
}

# runs.parquet, one row per log x parameter (an error: one row, parameter null)
RUN_COLUMNS = {
    "log": str,
    "vehicle": str,
    "profile": str,
    "parameter": str,
    "value": float,
    "std": float,
    "unit": str,
    "status": str,
    "reason": str,
    "error": str,
    "valid": bool,
    "stage": int,
    "window_s": float,  # bus time the parameter's stage spent learning (its windows)
    "duration_s": float,  # bus time of the log
    "frames": int,
    "decode_errors": int,  # frames the decoder rejected (dlc, range, counter, checksum, ...)
    "bad_lines": int,  # unreadable log lines skipped
    "damage": str,  # what the reader could not read (a cut gzip, a bad BLF container), or null
    "wall_s": float,
    "cpu_s": float,  # CPU time of the thread that replayed this log (Dask's own threads left out)
    "log_size": int,  # of the file when it was run
    "log_mtime_ns": int,
    # what the result was made of (run_key): a rerun redoes a log whose bytes, profile (or its
    # DBCs) or vdp changed since; size and mtime alone kept a result of a corrected profile
    "log_hash": str,
    "profile_hash": str,
    "vdp_version": str,
    # C_alpha's row: each axle (its Estimate's extra; C_alpha is their mean), else null
    "C_alpha_front": float,
    "C_alpha_front_std": float,
    "C_alpha_rear": float,
    "C_alpha_rear_std": float,
    # the drive's own measures for the changes between a vehicle's drives (drive_measures)
    "start_time": float,  # bus time of the log's first frame [s]: the drives' order
    "mass": float,  # from the longitudinal dynamics of its first minutes [kg] (vdp.core.change.fit_mass)
    "mass_std": float,
    "wheel_scale": float,  # wheel speeds against the ground speed (vdp.core.change.fit_scale)
    "wheel_scale_std": float,
    "bus_print": str,  # JSON {id: period [s]} of its periodic CAN ids (vdp.core.change.bus_print)
    # the share of the log gated out (core.gates: reverse, ABS, ESC, TCS, kerbs, wheel spin, standstill,
    # creep) and the sentence that splits it by gate; null for a result made before the gates
    "gated": float,
    "gated_by": str,
    # whether the run put the learnt mass into C_K, C_alpha, I_z and I_x (vdp batch --mass auto or on,
    # as vdp replay), and the mode it ran with (core.mass.MassConfig); null for a result made before
    "mass_learnt": bool,
    "mass_mode": str,
}
AXLE_COLUMNS = ("C_alpha_front", "C_alpha_front_std", "C_alpha_rear", "C_alpha_rear_std")


@dataclass(frozen=True)
class Task:
    log: str
    vehicle: str
    profile: str
    mass: str = "auto"  # the mass mode (vdp batch --mass, core.mass.MassConfig); another mode runs again

    @property
    def key(self) -> str:
        """Stable name of this log x vehicle x profile (part file name, Dask key)."""
        text = "\0".join((self.log, self.vehicle, self.profile))
        return hashlib.sha1(text.encode()).hexdigest()[:16]


def file_stamp(path: str) -> tuple[int, int] | None:
    """(size, mtime in ns) of a file, None if it is not there."""
    try:
        st = Path(path).stat()
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns


def content_hash(path: str | Path) -> str | None:
    """BLAKE2b-128 of a regular file's bytes (hex), None if it is not one or cannot be read (a
    FIFO would never end).  About 2 ms per MB (1.75 measured, from the page cache): nothing
    beside a replay's ~2.5 s per MB."""
    h = hashlib.blake2b(digest_size=16)
    try:
        with open(path, "rb") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                return None
            while chunk := f.read(1 << 20):
                h.update(chunk)
    except OSError:
        return None
    return h.hexdigest()


def profile_hash(profile: Any) -> str | None:
    """Of a loaded profile's TOML and its DBCs: what decides a log's result beside the log."""
    h = hashlib.blake2b(digest_size=16)
    for p in (profile.path, *profile.dbcs):
        one = content_hash(p)
        if one is None:
            return None
        h.update(one.encode())
    return h.hexdigest()


def run_key(log: str, profile_key: str | None) -> dict[str, Any]:
    """The columns a rerun compares to tell a result still good: the log's bytes, the profile's
    and vdp's version (size and mtime kept as facts of the file)."""
    size, mtime = file_stamp(log) or (None, None)
    return {
        "log_size": size,
        "log_mtime_ns": mtime,
        "log_hash": content_hash(log),
        "profile_hash": profile_key,
        "vdp_version": __version__,
    }


# per worker process: a profile is loaded (and its DBC parsed) once while its files stay the same;
# a worker of a long-lived cluster (--scheduler) loads an edited profile again
_PROFILES: dict[str, tuple[Any, str | None]] = {}


def _profile(path: str) -> tuple[Any, str | None]:
    """(the profile at ``path``, profile_hash of it)."""
    from .profile import load_profile

    got = _PROFILES.get(path)
    if got is None or got[1] is None or profile_hash(got[0]) != got[1]:
        prof = load_profile(path)
        got = _PROFILES[path] = (prof, profile_hash(prof))
    return got


def replay_log(path: str, profile_path: str, mass: str = "auto") -> Any:
    """The RunResult of ``vdp replay PATH --profile PROFILE --no-ekf --mass MASS`` (vdp.replay's use
    case: the same check, the same marks, the same numbers), and the log's own measures from the
    minutes the check read (across.measures_of): (result, measures)."""
    from .pipeline import run_config
    from .replay import check, compiled_pays, replay_file

    profile, _ = _profile(profile_path)
    checked = check(path, profile)
    # as vdp replay, without the EKF baseline (the UKF's numbers do not depend on it)
    cfg = run_config("batch", compiled=compiled_pays(path), mass=mass)
    result = replay_file(path, profile, cfg, checked)
    try:
        measures = measures_of(checked.head, profile)
    except Exception as exc:  # the replay read it: a failure here only leaves the measures out
        log.warning("%s: no drive measures: %s: %s", path, type(exc).__name__, exc)
        measures = {}
    return result, measures


_TASK_LOG: contextvars.ContextVar[str | None] = contextvars.ContextVar("vdp_task_log", default=None)


def _name_the_log() -> None:
    """Make vdp's log records name the log a task replays (``PATH: message``).

    Many logs run at once in a worker's threads, and a warning deep in the pipeline (the profile
    check's mass, a message's counter failures) does not know which file it came from.  The record
    factory is the one place every record passes through, whatever handlers the worker has."""
    old = logging.getLogRecordFactory()
    if getattr(old, "names_the_log", False):
        return

    def factory(*args, **kwargs):
        rec = old(*args, **kwargs)
        path = _TASK_LOG.get()
        if path is not None and rec.name.startswith("vdp"):
            # formatted here, then prefixed: many records put the path in through their arguments
            # ("%s: %s", path, ...), and a '%' in the path must not meet the formatting
            text = rec.getMessage()
            if not text.startswith(path):
                rec.msg, rec.args = f"{path}: {text}", ()
        return rec

    factory.names_the_log = True
    logging.setLogRecordFactory(factory)


def run_task(task: Task) -> list[dict]:
    """Replay one log; its rows, or one error row.  Never raises for a bad log."""
    _name_the_log()
    token = _TASK_LOG.set(task.log)
    try:
        return _run(task)
    finally:
        _TASK_LOG.reset(token)


def _run(task: Task) -> list[dict]:
    # the key before the replay: a log or profile changed meanwhile makes the next batch run it again
    key = run_key(task.log, None)
    t0, c0 = time.monotonic(), time.thread_time()
    try:
        res, measures = replay_log(task.log, task.profile, task.mass)
    except VdpError as exc:
        return [error_row(task, str(exc), key)]
    except Exception as exc:  # a bug, not the log: keep the rest of the fleet going, say where
        log.error("%s: replay failed:\n%s", task.log, traceback.format_exc())
        return [error_row(task, f"internal error: {type(exc).__name__}: {exc}", key)]
    # the hash of the profile's files as this replay loaded them (the cache is refreshed on a change)
    key["profile_hash"] = _PROFILES[task.profile][1] if task.profile in _PROFILES else None
    rows = rows_from_result(res, task, key)
    measures["start_time"] = res.log.start_time if res.log is not None else None
    for r in rows:
        r.update(measures)
    wall, cpu = time.monotonic() - t0, time.thread_time() - c0
    for r in rows:
        r["wall_s"], r["cpu_s"] = wall, cpu
    return rows


def _puts(mode: str) -> bool:
    """Whether a run in mass mode ``mode`` puts the learnt mass into the six (core.mass.MassConfig.put)."""
    from .core.mass import MassConfig

    return MassConfig(mode).put


def error_row(task: Task, error: str, key: dict[str, Any] | None) -> dict:
    row: dict[str, Any] = dict.fromkeys(RUN_COLUMNS)
    row.update(log=task.log, vehicle=task.vehicle, profile=task.profile, status="error", error=error, valid=False)
    row.update(mass_learnt=_puts(task.mass), mass_mode=task.mass)
    row.update(key or {})
    return row


def rows_from_result(res: Any, task: Task, key: dict[str, Any] | None = None) -> list[dict]:
    """One row per parameter from a replay's :class:`vdp.result.RunResult`."""
    lg = res.log
    src = lg.source if lg is not None else {}
    duration = lg.duration_s if lg is not None else 0.0
    by_kind = res.decode.get("errors_by_kind") or {}
    decode_errors = sum(n for k, n in by_kind.items() if k not in {"unknown_id", "error_frame"})
    # bus time each stage spent in windows (an open window runs to the newest frame)
    window = {1: 0.0, 2: 0.0}
    for w in res.windows:
        end = w.end if w.end is not None else res.bus_time
        if end is not None:
            window[w.stage] = window.get(w.stage, 0.0) + max(end - w.start, 0.0)
    rows = []
    for name in PARAMETERS:
        e = res.parameters.get(name)
        if e is None:
            continue
        reason = e.reason
        if reason is None:
            # the car cannot estimate it (I_x without a roll-rate gyro) or cannot run its stage
            caps = res.capabilities if e.status == NOT_RUN else {}
            reason = caps.get(name) or caps.get(str(e.stage)) or REASONS.get(e.status)
        row: dict[str, Any] = dict.fromkeys(RUN_COLUMNS)
        row.update(
            log=task.log,
            vehicle=task.vehicle,
            profile=task.profile,
            parameter=name,
            value=_num(e.value),
            std=_num(e.std),
            unit=e.unit,
            status=e.status,
            reason=reason,
            valid=bool(e.valid),
            stage=e.stage,
            window_s=window.get(e.stage, 0.0),
            duration_s=float(duration),
            frames=int(lg.frames if lg is not None else res.frames),
            decode_errors=int(decode_errors),
            bad_lines=int(src.get("bad_lines") or 0),
            damage=(src.get("damage") or {}).get("summary") or None,
            wall_s=float(lg.wall_s if lg is not None else 0.0),
            mass_learnt=_puts(task.mass),
            mass_mode=task.mass,
        )
        g = (getattr(res, "supervisor", None) or {}).get("gated") or {}
        if g.get("of"):
            row.update(gated=float(g["fraction"]), gated_by=g["text"])
        x = e.extra or {}
        for k in AXLE_COLUMNS:
            if x.get(k) is not None:
                row[k] = _num(x[k])
        row.update(key or {})
        rows.append(row)
    return rows


def _num(v: Any) -> float:
    return math.nan if v is None else float(v)


def weighted(values: list[float], stds: list[float]) -> tuple[float, float]:
    """Inverse-variance weighted mean and its std (the drives taken as independent)."""
    w = [1.0 / (s * s) for s in stds]
    sw = sum(w)
    return sum(wi * x for wi, x in zip(w, values)) / sw, math.sqrt(1.0 / sw)


def combined(values: list[float], stds: list[float], common: float = COMMON) -> tuple[float, float]:
    """The drives' inverse-variance weighted mean, and its std with an error shared by all of
    them (it does not shrink with more drives) of ``common`` times the best drive's std:
    var = (1 - c^2) / sum(w) + c^2 min(s)^2, w = 1 / s^2.  One drive keeps its std, n equal
    drives give s sqrt((1 - c^2) / n + c^2), and a drive added never widens it (a shared part
    c s_i per drive would have: a noisy drive's share outweighed the information it adds)."""
    mean, sd = weighted(values, stds)
    best = min(stds)
    return mean, math.sqrt((1.0 - common * common) * sd * sd + (common * best) ** 2)


def combine(rows: Iterable[Mapping[str, Any]]) -> tuple[list[dict], dict[tuple[str, str, str], float]]:
    """Per vehicle x parameter: the combination of its converged and valid drives (a copy of a
    log counted once), and each drive's z.

    The value is their inverse-variance weighted mean; its std keeps an error all drives
    share (:func:`combined`).  The consistency test takes the drives' full stds, as if their
    errors were independent: chi^2 = sum((x_i - mean)^2 / s_i^2) over all of them against
    chi^2 with n-1 degrees of freedom, a small p-value saying they do not agree within their
    stds.  A shared error cancels from these differences, so the test is conservative (on
    drives whose errors share 0.7 of their std it would call inconsistent, or flag, about
    half as often as its nominal rate): it names a drive only when even independent errors
    cannot explain it.  Which drive disagrees: each is compared with the combination of the
    others, z_i = (x_i - mean_-i) / sqrt(s_i^2 + s_-i^2); the worst one beyond
    Z_FLAG is flagged and left out, and the rest are tested again (one bad drive
    pulls the others' means, so all are not judged at once).  With two drives left
    their z are equal: both are flagged, neither is known to be the wrong one.

    ``value``/``std`` combine the drives not flagged (both of an inconsistent pair);
    ``chi2``/``p_value`` test all converged drives, ``chi2_kept``/``p_value_kept`` the drives
    ``value`` combines (the retest after flagging; the same where none was flagged).  Returns the vehicle rows and
    {(log, vehicle, parameter): z of that drive against the unflagged others}.
    """
    from scipy.stats import chi2 as chi2_dist

    groups: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for r in rows:
        if r.get("parameter") is None:
            continue
        groups.setdefault((r["vehicle"], r["parameter"]), []).append(r)
    out: list[dict] = []
    zs: dict[tuple[str, str, str], float] = {}
    order = {p: i for i, p in enumerate(PARAMETERS)}
    for (vehicle, param), rs in sorted(groups.items(), key=lambda kv: (kv[0][0], order.get(kv[0][1], 99))):
        # copies first, over every converged drive: a not-valid log and its .gz are one drive too
        once, copies = _distinct([r for r in rs if r.get("status") == CONVERGED])
        good = [r for r in once if usable(r)]
        row: dict[str, Any] = {
            "vehicle": vehicle,
            "parameter": param,
            "unit": next((r.get("unit") for r in rs if r.get("unit")), None),
            "value": math.nan,
            "std": math.nan,
            "drives": len(good),
            "runs": len(rs),
            "chi2": math.nan,
            "dof": max(len(good) - 1, 0),
            "p_value": math.nan,
            "consistent": None,
            "scale": math.nan,
            "flagged": [],
            "chi2_kept": math.nan,
            "dof_kept": max(len(good) - 1, 0),
            "p_value_kept": math.nan,
            # converged, but vdp said not valid (its reason in runs.parquet): left out
            "not_valid": sum(1 for r in once if not r.get("valid")),
            "copies": copies,  # logs that are another log's very drive (the same result): counted once
        }
        xs = [float(r["value"]) for r in good]
        ss = [float(r["std"]) for r in good]
        kept = list(range(len(good)))
        if len(good) >= 2:
            mean, _ = weighted(xs, ss)
            chi2 = sum(((x - mean) / s) ** 2 for x, s in zip(xs, ss))
            dof = len(good) - 1
            p = float(chi2_dist.sf(chi2, dof))
            row.update(chi2=chi2, p_value=p, consistent=p >= P_CONSISTENT, scale=max(1.0, math.sqrt(chi2 / dof)))
            while len(kept) >= 2:
                z = {i: _loo_z(xs, ss, kept, i) for i in kept}
                worst = max(kept, key=lambda i: abs(z[i]))
                if abs(z[worst]) <= Z_FLAG:
                    break
                if len(kept) == 2:  # a pair that disagrees: flag both, keep both
                    row["flagged"] += [good[i]["log"] for i in kept]
                    break
                row["flagged"].append(good[worst]["log"])
                kept.remove(worst)
            for i, r in enumerate(good):
                zs[(r["log"], vehicle, param)] = _loo_z(xs, ss, kept, i)
        if good:
            kx, ks = [xs[i] for i in kept], [ss[i] for i in kept]
            row["value"], row["std"] = combined(kx, ks)
            row["drives"] = len(kept)
            if len(kept) >= 2:  # the retest, of the drives the value combines
                chi2_k = sum(((x - row["value"]) / s) ** 2 for x, s in zip(kx, ks))
                p_k = float(chi2_dist.sf(chi2_k, len(kept) - 1))
                row.update(chi2_kept=chi2_k, dof_kept=len(kept) - 1, p_value_kept=p_k)
        out.append(row)
    return out, zs


def _distinct(rows: list[Mapping[str, Any]]) -> tuple[list[Mapping[str, Any]], list[str]]:
    """The drives once each, and the logs left out as copies of one before them.  A replay is
    exact, so a copy of a log (a backup, its .gz) gives the very same value, std, frames and bus
    time; counted twice it would shrink the combination's std as if it were a second drive."""
    seen: set[tuple] = set()
    out, copies = [], []
    for r in rows:
        key = (r.get("value"), r.get("std"), r.get("frames"), r.get("duration_s"))
        if not r.get("frames"):  # (a row without its log's facts: nothing to tell a copy by)
            out.append(r)
        elif key in seen:
            copies.append(r["log"])
        else:
            seen.add(key)
            out.append(r)
    return out, copies


def _loo_z(xs: list[float], ss: list[float], kept: list[int], i: int) -> float:
    """Drive i against the combination of the kept drives other than i."""
    others = [j for j in kept if j != i]
    m, s = weighted([xs[j] for j in others], [ss[j] for j in others])
    return (xs[i] - m) / math.sqrt(ss[i] ** 2 + s**2)
