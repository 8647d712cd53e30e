"""vdp batch's results on disk: each log's part, which logs are done, and the Parquet tables of all."""

from __future__ import annotations

import logging
import os
from pathlib import Path

log = logging.getLogger("vdp.cli.batch")  # speaks as the subcommand, the name users filter on


def _schema():
    import pyarrow as pa

    from ...fleet import RUN_COLUMNS

    types = {str: pa.string(), float: pa.float64(), int: pa.int64(), bool: pa.bool_()}
    return pa.schema([(name, types[t]) for name, t in RUN_COLUMNS.items()])


def write_part(out: Path, key: str, rows: list[dict]) -> None:
    """One log's rows, written atomically (a crash leaves the old part or none)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from ...outfile import replacing

    parts = out / "parts"
    parts.mkdir(parents=True, exist_ok=True)
    with replacing(parts / f"{key}.parquet") as tmp:
        pq.write_table(pa.Table.from_pylist(rows, schema=_schema()), tmp)


def read_parts(out: Path) -> dict[str, list[dict]]:
    import pyarrow.parquet as pq

    got = {}
    for f in sorted((out / "parts").glob("*.parquet")):
        if f.name.startswith("."):  # a part being written (outfile.replacing), or one a kill left half-done
            continue
        try:
            got[f.stem] = pq.read_table(f).to_pylist()
        except Exception as exc:  # a damaged part is redone, not fatal
            log.warning("%s: unreadable (%s); its log will be run again", f, exc)
    return got


def rerun_reason(rows: list[dict], task, profile_key: str | None) -> str | None:
    """Why ``task`` must run (again), or None: its part is a result of this very log, profile
    (``profile_key``: fleet.profile_hash now) and vdp version, without an error.  A part of an
    earlier vdp that has no such key is run again."""
    from ... import __version__
    from ...fleet import content_hash, file_stamp

    if not rows:
        return "new"
    first = rows[0]
    if any(r["error"] for r in rows):
        return "failed before"
    if not first.get("log_hash"):
        return "an earlier vdp's result"
    if first.get("vdp_version") != __version__:
        return "another vdp version"
    if profile_key is None or first.get("profile_hash") != profile_key:
        return "its profile changed"
    if (first.get("mass_mode") or ("on" if first.get("mass_learnt") else "off")) != task.mass:
        return f"--mass {task.mass} now"
    # size and mtime first: a log that changed is told without reading it
    stamp = (first.get("log_size"), first.get("log_mtime_ns"))
    if stamp != file_stamp(task.log) or first["log_hash"] != content_hash(task.log):
        return "the log changed"
    return None


def profile_keys(todo: list) -> dict[str, str | None]:
    """profile path -> fleet.profile_hash of its files now (None if it does not load: its logs
    run, and their error rows say why)."""
    from ...errors import VdpError
    from ...fleet import profile_hash
    from ...profile import load_profile

    keys: dict[str, str | None] = {}
    for t in todo:
        if t.profile not in keys:
            try:
                keys[t.profile] = profile_hash(load_profile(t.profile))
            except VdpError:
                keys[t.profile] = None
    return keys


def write_results(out: Path, parts: dict[str, list[dict]]) -> tuple[list[dict], list[dict]]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    from ...fleet import changes, combine, since_changes

    def order(key: str) -> tuple[str, str]:  # by log, then vehicle; each log's rows in NAMES order
        first = parts[key][0] if parts[key] else {}
        return str(first.get("log", "")), str(first.get("vehicle", ""))

    rows = [r for key in sorted(parts, key=order) for r in parts[key]]
    found = changes(rows)
    # each vehicle's combination is of its drives since the last change of each parameter
    vehicles, zs = combine(since_changes(rows, found))
    for r in rows:
        z = zs.get((r["log"], r["vehicle"], r["parameter"]))
        r["z"] = z
        r["disagrees"] = None if z is None else abs(z) > _z_flag()
    schema = _schema().append(pa.field("z", pa.float64())).append(pa.field("disagrees", pa.bool_()))
    _atomic(pq, pa.Table.from_pylist(rows, schema=schema), out / "runs.parquet")
    vschema = pa.schema(
        [
            ("vehicle", pa.string()),
            ("parameter", pa.string()),
            ("unit", pa.string()),
            ("value", pa.float64()),
            ("std", pa.float64()),
            ("drives", pa.int64()),
            ("runs", pa.int64()),
            ("chi2", pa.float64()),
            ("dof", pa.int64()),
            ("p_value", pa.float64()),
            ("consistent", pa.bool_()),
            ("scale", pa.float64()),
            ("flagged", pa.list_(pa.string())),
            ("chi2_kept", pa.float64()),
            ("dof_kept", pa.int64()),
            ("p_value_kept", pa.float64()),
            ("not_valid", pa.int64()),
            ("copies", pa.list_(pa.string())),
        ]
    )
    _atomic(pq, pa.Table.from_pylist(vehicles, schema=vschema), out / "vehicles.parquet")
    cschema = pa.schema(
        [
            ("vehicle", pa.string()),
            ("log", pa.string()),
            ("start_time", pa.float64()),
            ("kind", pa.string()),
            ("what", pa.string()),
            ("size", pa.float64()),
            ("params", pa.list_(pa.string())),
        ]
    )
    found = [{k: c.get(k) for k in cschema.names} for c in found]
    _atomic(pq, pa.Table.from_pylist(found, schema=cschema), out / "changes.parquet")
    for c in found:
        log.warning("%s: %s (from %s on)", c["vehicle"], c["what"], c["log"])
    return rows, vehicles


def _z_flag() -> float:
    from ...fleet import Z_FLAG

    return Z_FLAG


def _atomic(pq, table, path: Path) -> None:
    from ...outfile import replacing

    with replacing(path) as tmp:
        pq.write_table(table, tmp)


def combination_notes(vehicles: list[dict]) -> list[str]:
    """What a reader of vehicles.parquet should know of a vehicle's combination: copies of a log
    counted once, and converged drives left out as not valid."""
    out = []
    copies: dict[str, set[str]] = {}
    for v in vehicles:
        copies.setdefault(v["vehicle"], set()).update(v.get("copies") or [])
    for car, logs in sorted(copies.items()):
        if logs:
            names = ", ".join(sorted(logs)[:3]) + (", ..." if len(logs) > 3 else "")
            out.append(f"{car}: {len(logs)} log(s) gave the very result of another and were counted once ({names})")
    for v in vehicles:
        if v.get("not_valid"):
            out.append(
                f"{v['vehicle']} {v['parameter']}: {v['not_valid']} converged drive(s) left out as not valid "
                f"(their reason is in runs.parquet){'; no valid drive to combine' if not v['drives'] else ''}"
            )
    return out


def _supersede(out: Path, key: str) -> None:
    """Move a part no longer in the results aside (nothing is deleted; the notice is given once)."""
    src = out / "parts" / f"{key}.parquet"
    dst = out / "parts" / "superseded" / src.name
    try:
        dst.parent.mkdir(exist_ok=True)
        os.replace(src, dst)
    except OSError as exc:
        log.warning("%s: could not move it aside (%s); it stays where it is", src, exc)
