"""vdp batch's inputs: the logs from paths, globs, folders and a manifest, as fleet tasks."""

from __future__ import annotations

import csv
import difflib
import glob
import sys
from pathlib import Path

from ...errors import ConfigError

_GLOB_CHARS = set("*?[")


def expand(inputs: list[str], unmatched: list[str] | None = None) -> list[str]:
    """Log paths from paths, globs and directories (a plain path is kept even if missing); a glob or
    folder that gives no log is appended to ``unmatched``."""
    from ...io.logs import FORMATS

    def is_log(p: Path) -> bool:
        suffixes = [s.lower() for s in p.suffixes]
        if suffixes and suffixes[-1] == ".gz":
            suffixes = suffixes[:-1]
        return p.is_file() and bool(suffixes) and suffixes[-1] in FORMATS

    out: list[str] = []
    for item in inputs:
        p = Path(item)
        if _GLOB_CHARS & set(item):
            hits = sorted(glob.glob(item, recursive=True))
            if not hits:
                print(f"vdp batch: warning: no file matches {item}", file=sys.stderr)
                if unmatched is not None:
                    unmatched.append(f"{item}: no file matches")
            out.extend(h for h in hits if Path(h).is_file())
        elif p.is_dir():
            hits = []
            for f in sorted(p.rglob("*"), key=str):
                if is_log(f) and _is_manifest(f):  # a CSV of logs, not a CSV log of frames
                    print(f"vdp batch: {f} is a manifest, not a log; left out (give it as --manifest)", file=sys.stderr)
                elif is_log(f):
                    hits.append(str(f))
            if not hits:
                print(f"vdp batch: warning: no log files ({', '.join(FORMATS)}) in {item}", file=sys.stderr)
                if unmatched is not None:
                    unmatched.append(f"{item}: no log files in it")
            out.extend(hits)
        else:
            out.append(item)
    return out


def _is_manifest(path: Path) -> bool:
    """Whether a .csv file is a manifest (its header names a 'log' column), not a CAN log."""
    if path.suffix.lower() != ".csv":
        return False
    try:
        with path.open(encoding="utf-8-sig", errors="replace") as f:
            head = next(csv.reader([f.readline()]), [])  # as read_manifest reads it: quotes allowed
    except OSError:
        return False
    return "log" in (c.strip().lower() for c in head)


MANIFEST_COLUMNS = ("log", "vehicle", "profile")


def read_manifest(path: str) -> list[tuple[str, str | None, str | None]]:
    """(log, vehicle or None, profile or None) per manifest line."""
    where = Path(path)
    try:
        text = where.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such manifest file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the manifest: {exc}") from None
    reader = csv.DictReader(text.splitlines())
    # header names as written (Log, VEHICLE, a trailing comma's empty one: a spreadsheet's export)
    reader.fieldnames = [(c or "").strip().lower() for c in reader.fieldnames or []]
    cols = [c for c in reader.fieldnames if c]
    if "log" not in cols:
        raise ConfigError(
            f"{path}: the manifest needs a header line with the columns log,vehicle,profile "
            f"(found: {','.join(cols) or 'nothing'})"
        )
    # another column beside all three is a note of the user's; in place of vehicle or profile it is
    # most likely that column misnamed (car, vehicle_name), which would be passed over in silence
    unknown = [c for c in cols if c not in MANIFEST_COLUMNS]
    if unknown and not all(c in cols for c in MANIFEST_COLUMNS):
        near = {c: difflib.get_close_matches(c.lower(), MANIFEST_COLUMNS, 1, 0.5) for c in unknown}
        said = ", ".join(f"'{c}'" + (f" (did you mean '{near[c][0]}'?)" if near[c] else "") for c in unknown)
        raise ConfigError(
            f"{path}: unknown manifest column(s) {said}: the columns are {','.join(MANIFEST_COLUMNS)} (vehicle and "
            f"profile may be left out: the profile's name is the vehicle, and profiles/paper.toml the profile; "
            f"other columns are allowed beside all three)"
        )
    base = where.resolve().parent
    out = []
    for n, rec in enumerate(reader, 2):
        rec = {(k or "").strip(): (v or "").strip() for k, v in rec.items()}
        if not rec.get("log"):
            if any(rec.values()):
                raise ConfigError(f"{path}: line {n}: no log path in the 'log' column")
            continue

        def rel(v: str) -> str:
            return str(base / v) if v and not Path(v).is_absolute() else v

        prof = rel(rec.get("profile", "")) or None
        if prof is not None and not Path(prof).is_file():
            raise ConfigError(
                f"{path}: line {n}: profile {rec['profile']}: no such file ({prof}; a relative path is "
                f"read from the manifest's folder)"
            )
        out.append((rel(rec["log"]), rec.get("vehicle") or None, prof))
    if not out:
        raise ConfigError(f"{path}: the manifest lists no logs")
    return out


def tasks(args, unmatched: list[str] | None = None) -> list:
    from ...fleet import Task
    from ...profile import load_profile
    from ..replay import default_profile

    entries: list[tuple[str, str | None, str | None]] = []
    if args.manifest:
        entries += read_manifest(args.manifest)
    entries += [(p, None, None) for p in expand(args.logs, unmatched)]
    if not entries:
        if unmatched:
            raise ConfigError(f"no logs to run: {'; '.join(unmatched)}")
        raise ConfigError("no logs given: name log files, globs or directories, or --manifest FILE")
    default = str(Path(args.profile).resolve()) if args.profile else None
    names: dict[str, str] = {}
    out, seen = [], set()
    for logp, vehicle, prof in entries:
        prof = str(Path(prof).resolve()) if prof else (default or str(default_profile().resolve()))
        if vehicle is None:
            vehicle = args.vehicle
        if vehicle is None:
            if prof not in names:
                names[prof] = load_profile(prof).vehicle.name  # bad profile: one clear error up front
            vehicle = names[prof]
        t = Task(str(Path(logp).resolve()), vehicle, prof, mass=getattr(args, "mass", "auto"))
        if t.key not in seen:
            seen.add(t.key)
            out.append(t)
    # a drive is one vehicle's: listed under two vehicles or profiles it would count for both
    twice: dict[str, list] = {}
    for t in out:
        twice.setdefault(t.log, []).append(t)
    clash = [ts for ts in twice.values() if len(ts) > 1]
    if clash:
        ts = clash[0]
        listed = "; ".join(f"vehicle {t.vehicle!r} with {t.profile}" for t in ts)
        more = f" (and {len(clash) - 1} more log(s) so)" if len(clash) > 1 else ""
        raise ConfigError(
            f"{ts[0].log} is listed {len(ts)} times, as {listed}{more}: a drive belongs to one vehicle "
            f"and one profile; list it once"
        )
    # one vehicle's drives under several profiles: its combination mixes them (a revised profile
    # of the same car, or two cars under one name: only the user knows)
    profiles: dict[str, dict[bytes, str]] = {}  # vehicle -> the profiles' texts (copies of one are one)
    for t in out:
        try:
            text = Path(t.profile).read_bytes()
        except OSError:
            text = t.profile.encode()
        profiles.setdefault(t.vehicle, {}).setdefault(text, t.profile)
    for vehicle, by_text in sorted(profiles.items()):
        ps = by_text.values()
        if len(ps) > 1:
            print(
                f"vdp batch: vehicle {vehicle!r} has drives under {len(ps)} profiles ({', '.join(sorted(ps))}); "
                f"they are combined as one car: name each car's vehicle apart if they are not",
                file=sys.stderr,
            )
    return out
