"""vdp batch: many logs on a Dask cluster, results as Parquet, drives combined per vehicle.

vdp batch LOGS... [--manifest FILE] --out DIR [--workers N | --scheduler ADDRESS] [--mass MODE]

Each log is one task.  A finished log is written at once to DIR/parts/, so an
interrupted batch loses nothing and a rerun skips what is done (a log that
failed, or changed since, is run again).  At the end DIR/runs.parquet (one row
per log x parameter) and DIR/vehicles.parquet (one row per vehicle x
parameter) are written from every part in DIR, and DIR/changes.parquet: the
changes named between each vehicle's drives in time order (a mass step, new
tyres, another car's bus; vdp.core.change, as the running service names them).

The subcommand's pieces: :mod:`.inputs` (logs, manifest, tasks), :mod:`.results`
(parts, what is done, the Parquet tables) and :mod:`.cluster` (Dask, the progress
line); their names are importable from here as before.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from ...errors import ConfigError
from ..options import mass_option
from .cluster import Progress, client
from .inputs import MANIFEST_COLUMNS, expand, read_manifest, tasks  # noqa: F401 (importable from here, as before)
from .results import (
    _supersede,
    combination_notes,
    profile_keys,
    read_parts,
    rerun_reason,
    write_part,
    write_results,
)

log = logging.getLogger(__name__)


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
        **mass_option(),
        help="the mass as vdp replay --mass takes it (default auto: learnt, and put into C_K, C_alpha and "
        "I_z where it reads off the profile's; logs run with another mode are run again)",
    )
    p.add_argument(
        "--plot",
        metavar="FILE",
        help="also draw each vehicle's drives against their combination (PNG, PDF or SVG by suffix)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def run(args) -> int:
    from ...fleet import run_task

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
    from ..paths import check_apart, check_dir, check_output

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

        from ..replay import compile_note

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
                    from ...fleet import error_row, run_key

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
        from ...report import fleet_plot

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
