"""vdp batch: many logs on a Dask cluster, results as Parquet, drives combined per vehicle.

vdp batch LOGS... [--manifest FILE] --out DIR [--workers N | --scheduler ADDRESS] [--mass]

Each log is one task.  A finished log is written at once to DIR/parts/, so an
interrupted batch loses nothing and a rerun skips what is done (a log that
failed, or changed since, is run again).  At the end DIR/runs.parquet (one row
per log x parameter) and DIR/vehicles.parquet (one row per vehicle x
parameter) are written from every part in DIR, and DIR/changes.parquet: the
changes named between each vehicle's drives in time order (a mass step, new
tyres, another car's bus; vdp.core.change, as the running service names them).
"""

from __future__ import annotations

import csv
import difflib
import glob
import logging
import os
import sys
import time
from pathlib import Path

from ..errors import ConfigError

log = logging.getLogger(__name__)

_GLOB_CHARS = set("*?[")


def add_parser(sub):
    p = sub.add_parser(
        "batch",
        help="estimate the parameters of many logs on a Dask cluster; Parquet out",
        description="Replay many CAN logs, each an independent task on Dask (a local cluster "
        "by default), into DIR/runs.parquet and DIR/vehicles.parquet. Needs the 'fleet' extra: "
        "pip install 'vdp[fleet]'.",
    )
    p.add_argument("logs", nargs="*", help="log files, globs ('logs/**/*.log') or directories")
    p.add_argument(
        "--manifest",
        metavar="FILE",
        help="CSV with the columns log,vehicle,profile (relative paths: from the manifest's folder)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="where the Parquet files go")
    p.add_argument(
        "--profile", default=None, help="vehicle profile for logs given without one (default: profiles/paper.toml)"
    )
    p.add_argument(
        "--vehicle",
        default=None,
        help="vehicle name for logs given without one (default: the profile's [vehicle] name)",
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--workers", type=int, default=None, help="local cluster of N worker processes (default: one per core)"
    )
    g.add_argument("--scheduler", metavar="ADDRESS", help="run on an existing Dask cluster, e.g. tcp://10.0.0.5:8786")
    p.add_argument("--redo", action="store_true", help="run every log again, even those already done")
    p.add_argument(
        "--mass",
        action="store_true",
        help="learn each drive's mass and use it in the six, as vdp replay --mass (the mass row then holds "
        "the learnt mass; logs run without it are run again)",
    )
    p.add_argument(
        "--plot",
        metavar="FILE",
        help="also draw each vehicle's drives against their combination (PNG, PDF or SVG by suffix)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


# -- inputs -------------------------------------------------------------------


def expand(inputs: list[str], unmatched: list[str] | None = None) -> list[str]:
    """Log paths from paths, globs and directories (a plain path is kept even if missing); a glob or
    folder that gives no log is appended to ``unmatched``."""
    from ..io.logs import FORMATS

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
    from ..fleet import Task
    from ..profile import load_profile
    from .replay import default_profile

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
        t = Task(str(Path(logp).resolve()), vehicle, prof, mass=bool(getattr(args, "mass", False)))
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


# -- parquet ------------------------------------------------------------------


def _schema():
    import pyarrow as pa

    from ..fleet import RUN_COLUMNS

    types = {str: pa.string(), float: pa.float64(), int: pa.int64(), bool: pa.bool_()}
    return pa.schema([(name, types[t]) for name, t in RUN_COLUMNS.items()])


def write_part(out: Path, key: str, rows: list[dict]) -> None:
    """One log's rows, written atomically (a crash leaves the old part or none)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from ..outfile import replacing

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
    from .. import __version__
    from ..fleet import content_hash, file_stamp

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
    if bool(first.get("mass_learnt")) != task.mass:
        return "--mass now" if task.mass else "without --mass now"
    # size and mtime first: a log that changed is told without reading it
    stamp = (first.get("log_size"), first.get("log_mtime_ns"))
    if stamp != file_stamp(task.log) or first["log_hash"] != content_hash(task.log):
        return "the log changed"
    return None


def profile_keys(todo: list) -> dict[str, str | None]:
    """profile path -> fleet.profile_hash of its files now (None if it does not load: its logs
    run, and their error rows say why)."""
    from ..errors import VdpError
    from ..fleet import profile_hash
    from ..profile import load_profile

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

    from ..fleet import changes, combine, since_changes

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
    from ..fleet import Z_FLAG

    return Z_FLAG


def _atomic(pq, table, path: Path) -> None:
    from ..outfile import replacing

    with replacing(path) as tmp:
        pq.write_table(table, tmp)


# -- dask -----------------------------------------------------------------------


def client(args):
    """A Dask client: on ``--scheduler``, or on a local cluster bound to 127.0.0.1 with no dashboard."""
    try:
        from distributed import Client, LocalCluster
    except ModuleNotFoundError:
        raise ConfigError("vdp batch needs Dask: pip install 'vdp[fleet]'") from None
    if not getattr(args, "verbose", 0):  # Dask's INFO lines (scheduler, nannies) are noise here
        for name in list(logging.root.manager.loggerDict):
            if name.startswith("distributed"):
                logging.getLogger(name).setLevel(logging.ERROR)
    if args.scheduler:
        try:
            return Client(args.scheduler, timeout="20s"), None
        except OSError as exc:
            raise ConfigError(f"--scheduler {args.scheduler}: cannot reach the scheduler: {exc}") from None
    n = args.workers if args.workers is not None else (os.cpu_count() or 1)
    if n < 1:
        raise ConfigError(f"--workers {n}: give at least 1")
    # host: scheduler, nannies and workers listen on loopback only (nothing on the host
    # network).  No dashboard; the scheduler still serves its health routes over HTTP,
    # and without an address it would take port 8787 on every interface of its host:
    # loopback and a free port instead.  One thread per worker: a replay is pure Python
    # under the GIL, processes are what run in parallel.
    cluster = LocalCluster(
        n_workers=n,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        worker_dashboard_address=None,
        scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"},
        silence_logs=logging.ERROR,
    )
    return Client(cluster), cluster


class Progress:
    """Logs done of all, on one line of stderr (a terminal only)."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.done, self.failed = total, 0, 0
        self.enabled = enabled and sys.stderr.isatty()
        self.t0 = time.monotonic()

    def step(self, failed: bool) -> None:
        self.done += 1
        self.failed += failed
        if not self.enabled:
            return
        el = time.monotonic() - self.t0
        frac = self.done / max(self.total, 1)
        eta = el * (1 - frac) / frac if frac else 0.0
        bar = "#" * int(30 * frac)
        sys.stderr.write(
            f"\r[{bar:<30}] {self.done}/{self.total} logs  {self.failed} failed  {el:5.0f} s  ETA {eta:4.0f} s "
        )
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")


def run(args) -> int:
    from ..fleet import run_task

    try:
        import pyarrow  # noqa: F401
    except ModuleNotFoundError:
        raise ConfigError("vdp batch needs pyarrow: pip install 'vdp[fleet]'") from None
    if args.workers is not None and args.workers < 1:
        raise ConfigError(f"--workers {args.workers}: give at least 1")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: exists and is not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"--out {out}: cannot create it: {exc.strerror or exc}") from None
    from .paths import check_apart, check_dir, check_output

    # a folder that takes no file is said now, not as a traceback after the first log
    check_dir(out, "--out")
    if (out / "parts").exists():
        check_dir(out / "parts", "--out")
    if args.plot:  # a wrong suffix or folder said before an hour of logs, not after (--out made first)
        check_output(args.plot, "--plot", (".png", ".pdf", ".svg"))
    unmatched: list[str] = []
    todo = tasks(args, unmatched)
    keys = profile_keys(todo)
    inputs = [("the log", t.log) for t in todo] + [("the profile", p) for p in keys]
    if args.manifest:
        inputs.append(("--manifest", args.manifest))
    check_apart({"--plot": args.plot}, inputs)  # (the tables are .parquet, never a log, profile or manifest)
    parts = read_parts(out)
    why = {t.key: "--redo" if args.redo else rerun_reason(parts.get(t.key, []), t, keys[t.profile]) for t in todo}
    pending = [t for t in todo if why[t.key] is not None]
    skipped = len(todo) - len(pending)
    counts: dict[str, int] = {}
    for t in pending:
        counts[why[t.key]] = counts.get(why[t.key], 0) + 1
    said = ", ".join(
        f"{n} {w}" if w == "new" else f"{n}: {w}" for w, n in sorted(counts.items(), key=lambda kv: -kv[1])
    )
    print(f"{len(todo)} logs: {skipped} already done, {len(pending)} to run" + (f" ({said})" if said else ""))
    failed: list[tuple[str, str]] = []
    if pending:
        from distributed import as_completed

        from .replay import compile_note

        if args.scheduler is None:  # local workers then load them from the cache (a cluster's compile their own)
            compile_note(warm=True)

        cl, cluster = client(args)
        try:
            print(f"dask: {len(cl.scheduler_info()['workers'])} workers at {cl.scheduler.address}")
            t_run = time.monotonic()
            futures = {cl.submit(run_task, t, key=f"vdp-{t.key}", pure=False): t for t in pending}
            bar = Progress(len(pending), enabled=not args.no_progress)
            for fut in as_completed(futures):
                t = futures[fut]
                try:
                    rows = fut.result()
                except Exception as exc:  # the worker died (KilledWorker), or Dask itself failed
                    from ..fleet import error_row, run_key

                    msg = f"task failed on the cluster: {type(exc).__name__}: {exc}"
                    rows = [error_row(t, msg, run_key(t.log, keys[t.profile]))]
                fut.release()
                write_part(out, t.key, rows)
                parts[t.key] = rows
                err = rows[0]["error"]
                if err:
                    failed.append((t.log, err))
                bar.step(bool(err))
            bar.close()
            print(f"ran {len(pending)} log{'s' if len(pending) != 1 else ''} in {time.monotonic() - t_run:.1f} s")
        finally:
            cl.close()
            if cluster is not None:
                cluster.close()
    # a log this run replayed under another profile or vehicle before: its earlier part stays on
    # disk but not in the results, or each such drive would count twice in vehicles.parquet
    keys: dict[str, set[str]] = {}
    for t in todo:
        keys.setdefault(t.log, set()).add(t.key)
    stale = [k for k, rows in parts.items() if rows and rows[0]["log"] in keys and k not in keys[rows[0]["log"]]]
    for k in stale:
        del parts[k]
        _supersede(out, k)
    if stale:
        print(
            f"left out {len(stale)} earlier result(s) of these logs under another profile or vehicle "
            f"(kept in {out / 'parts' / 'superseded'})"
        )
    rows, vehicles = write_results(out, parts)
    print(f"wrote {out / 'runs.parquet'} ({len(rows)} rows) and {out / 'vehicles.parquet'} ({len(vehicles)} rows)")
    for line in combination_notes(vehicles):
        print(line)
    if args.plot:
        from ..report import fleet_plot

        fleet_plot(rows, vehicles, args.plot)
        print(f"wrote {args.plot}")
    for path, err in failed:
        # the error names the log itself where the reader wrote it ("PATH: no such file")
        print(f"failed: {err}" if err.startswith(f"{path}:") else f"failed: {path}: {err}")
    for what in unmatched:
        print(f"failed: {what}")
    if failed:
        print(f"{len(failed)} of {len(pending)} logs failed (recorded in runs.parquet; a rerun tries them again)")
    if unmatched:
        print(f"{len(unmatched)} of the inputs gave no log (a typo in a path or glob?)")
    return 1 if failed or unmatched else 0


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
