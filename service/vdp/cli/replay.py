"""vdp replay: a drive's CAN log in, the six parameters with their uncertainty out.

vdp replay drive.log --profile profiles/paper.toml --json out.json --plot out.png [--truth drive.truth.json]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from ..core.result import CONVERGED
from ..errors import ConfigError, ProfileError
from .options import mass_option
from .paths import check_apart, check_output, profile_inputs


def add_parser(sub):
    p = sub.add_parser(
        "replay",
        help="estimate the parameters from a recorded CAN log",
        description="Replay a CAN log (.log candump, .asc, .blf, .trc, .csv, .mf4; "
        "gzipped or not) through the estimation pipeline.",
    )
    p.add_argument("log", help="the CAN log file")
    p.add_argument("--profile", default=None, help="vehicle profile TOML (default: profiles/paper.toml)")
    p.add_argument("--json", dest="json_out", metavar="PATH", help="write the full result as JSON")
    p.add_argument("--plot", metavar="PATH", help="write a PNG of each parameter over time")
    p.add_argument(
        "--series",
        metavar="FILE",
        help="write the estimates over time (.csv or .parquet): t, then value, std, status per parameter",
    )
    p.add_argument(
        "--channels",
        metavar="FILE",
        help="write the aligned, validated channel samples the estimator saw (.csv or .parquet)",
    )
    p.add_argument("--truth", metavar="PATH", help="a .truth.json from vdp simulate, to compare against")
    p.add_argument("--strict", action="store_true", help="stop at the first malformed log line")
    p.add_argument(
        "--baseline",
        choices=("none", "ekf"),
        default="none",
        help="run a baseline filter beside the UKF and report it (JSON 'baseline_ekf', the table's EKF "
        "column): ekf, the paper's EKF (Table 5), about 4x the replay's CPU (docs/decisions/0009); default none",
    )
    p.add_argument("--no-ekf", action="store_true", help="no EKF baseline (the default; kept for scripts)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    axles = p.add_mutually_exclusive_group()
    axles.add_argument(
        "--per-axle",
        action="store_true",
        help="stage 2 estimates the front and the rear cornering stiffness separately (the default; C_alpha "
        "is their mean, each axle in C_alpha's extra)",
    )
    axles.add_argument(
        "--one-c",
        action="store_true",
        help="one cornering stiffness for both axles, as the paper (worse on a car whose axles differ: "
        "docs/decisions/0008)",
    )
    p.add_argument(
        "--mass",
        **mass_option(),
        help="the mass (issue 28): auto (the default) learns it from the drive and, where it reads off the "
        "profile's beyond 2 of its stds, puts it into C_K, C_alpha and I_z once known to 5 %% (widening their "
        "stds before that); on (--mass alone) puts it in from the start; report learns it only; off takes "
        "the profile's vehicle.mass as weighed as driven",
    )
    p.add_argument(
        "--road",
        action="store_true",
        help="model the road's grade, its bank (a state of stage 2) and the IMU's tilt with the body "
        "(a body-fixed IMU; issue 28)",
    )
    p.add_argument(
        "--after",
        action="append",
        metavar="JSON",
        help="an earlier drive of the same car, as `vdp replay --json` wrote it: the changes between the "
        "drives (a mass step, new tyres, another car on the bus) are named by the rules of vdp serve and "
        "vdp batch, over all the drives in the time order of their logs (repeatable)",
    )
    p.add_argument(
        "--per-frame",
        action="store_true",
        help="read a candump log frame by frame instead of in blocks (slower, same result)",
    )
    return p


def compile_note(warm: bool = False) -> None:
    """Compile this checkout's filter steps now if they are not cached yet, and say so on stdout
    (core.jit.FIRST_COMPILE, once), which would otherwise look like a hang.  ``warm``: the bulk
    reader's parse too (vdp batch, before its workers would each compile it)."""
    try:
        from ..core import jit
    except ImportError:  # no numba: the numpy steps run, nothing to compile
        return
    if jit.cached():
        return
    from ..core import warm as core_warm

    core_warm.ensure(say=lambda note: print(note, flush=True))
    if warm:
        from ..io import scan

        scan.warm()  # (a second or two)


def default_profile() -> Path:
    """profiles/paper.toml from the working directory, else from the source checkout."""
    for base in (Path.cwd(), Path(__file__).resolve().parents[3]):
        p = base / "profiles" / "paper.toml"
        if p.is_file():
            return p
    raise ConfigError("no --profile given and profiles/paper.toml not found; pass --profile PATH")


def profile_path(given: str) -> Path:
    """A --profile as given, else (relative and not in the working directory) from the source
    checkout, as `vdp simulate` reads it: the README's `--profile profiles/paper.toml` then works
    from any directory."""
    p = Path(given)
    if p.is_file() or p.is_absolute():
        return p
    q = Path(__file__).resolve().parents[3] / p
    return q if q.is_file() else p


class Progress:
    """A one-line progress bar on stderr, only on a terminal."""

    def __init__(self, total: int, enabled: bool):
        self.total = max(total, 1)
        self.enabled = enabled and sys.stderr.isatty()
        self.t0 = time.monotonic()
        self._last = 0.0

    def update(self, done: int, frames: int) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last < 0.2:
            return
        self._last = now
        frac = min(done / self.total, 1.0)
        rate = frames / max(now - self.t0, 1e-9)
        bar = "#" * int(30 * frac)
        eta = (now - self.t0) * (1 - frac) / frac if frac > 0 else 0
        sys.stderr.write(f"\r[{bar:<30}] {100 * frac:5.1f}%  {frames} frames  {rate:,.0f}/s  ETA {eta:4.0f} s ")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")


def run(args) -> int:
    from .. import profilecheck, report
    from ..pipeline import run_config
    from ..profile import load_profile
    from ..replay import check, compiled_pays, replay_file
    from ..series import SUFFIXES, ChannelTap, SeriesRecorder, write_table

    if args.no_ekf and args.baseline == "ekf":
        raise ConfigError("--baseline ekf and --no-ekf contradict each other; give one of them")
    # every output is checked before the replay: a bad path never costs a long run
    for flag, path, suffixes in (
        ("--json", args.json_out, None),
        ("--plot", args.plot, (".png", ".pdf", ".svg")),
        ("--series", args.series, SUFFIXES),
        ("--channels", args.channels, SUFFIXES),
    ):
        if path:
            check_output(path, flag, suffixes)
    path = profile_path(args.profile) if args.profile else default_profile()
    profile = load_profile(path)
    outputs = {"--json": args.json_out, "--plot": args.plot, "--series": args.series, "--channels": args.channels}
    after = list(args.after or ())
    earlier = [(f"--after {i + 1}", a) for i, a in enumerate(after)]
    check_apart(outputs, [("the log", args.log), *profile_inputs(profile).items(), ("--truth", args.truth), *earlier])
    before = [_earlier(a) for a in after]  # an unreadable one is refused before the replay
    # the profile self-check reads the log's first minutes; a log of another car stops here
    try:
        checked = check(args.log, profile)
    except ProfileError as exc:
        if args.profile:
            raise
        # the user chose no profile: say that this one was only the default
        raise ProfileError(
            f"{exc} (no --profile was given, so {path} was taken by default: it is vdp's simulated car; "
            f"pass --profile with your car's profile, or draft one with vdp profile new)"
        ) from None
    head, check_rep, cov = checked.head, checked.report, checked.coverage
    if cov.missing:  # fewer than half seen stopped check_log; a few missing still cost their channels
        print(f"profile check: {args.log}: {cov.message()}")
        for msg in cov.missing:  # what each missing message would have carried: the user sees what is lost
            lost = sorted(n for n, c in profile.channels.items() if c.message == msg)
            if lost:
                print(f"  {msg} carries {', '.join(lost)}: the run has none of them")
    for line in profilecheck.lines(check_rep, mass_on=args.mass in ("auto", "on")):
        print(line)
    truth = report.load_truth(args.truth) if args.truth else None
    compiled = compiled_pays(args.log)  # a short log never loads numba (vdp.replay.COMPILED_FROM)
    cfg = run_config(
        "replay",
        compiled=compiled,
        per_axle=not args.one_c,
        mass=args.mass,
        road=args.road,
        ekf=args.baseline == "ekf",
        plot=bool(args.plot),
    )
    if compiled:
        compile_note()
    try:
        size = Path(args.log).stat().st_size
    except OSError:
        size = 0  # replay_log says what is wrong with it
    progress = Progress(size, enabled=not args.no_progress)
    made: dict = {}

    def prepare(pipe):
        # recorders on each attempt's fresh pipeline: a candump log that the block reader hands
        # back is replayed again frame by frame
        made["recorder"] = SeriesRecorder(pipe) if args.series else None
        made["tap"] = ChannelTap(pipe) if args.channels else None

    result = replay_file(
        args.log,
        profile,
        cfg,
        checked,
        prepare,
        strict=args.strict,
        progress=progress.update,
        # the series samples the estimates frame by frame; else blocks where they pay (bulk.pays)
        bulk=False if args.per_frame or args.series else None,
        wrap=lambda src: made["recorder"].wrap(src) if made["recorder"] else src,
    )
    recorder, tap = made["recorder"], made["tap"]
    progress.close()

    # this drive's own measures (its mass, wheel-speed scale, bus print: what a later --after reads)
    # from the minutes the check read, and the changes against the earlier drives
    drive = _measures(head, profile, result)
    found = _changes(before, args.log, drive, result) if before else None

    # the files first: a table piped into head (a closed pipe) must not cost the user them
    wrote: list[str] = []
    if args.json_out:
        doc = report.document(result, truth)
        doc["vehicle"] = _constants(profile)
        doc["profile_check"] = {**check_rep.as_dict(), "coverage": cov.as_dict()}
        doc["drive"] = drive
        if found is not None:
            doc["changes"] = found
        report.write_json(doc, args.json_out)
        wrote.append(f"wrote {args.json_out}")
    t0 = result.log.start_time
    if recorder is not None:
        recorder.finish(result)
        cols, rows = recorder.table(t0)
        write_table(args.series, cols, rows)
        wrote.append(f"wrote {args.series} ({len(rows)} rows)")
    if tap is not None:
        a = tap.array(t0)
        write_table(args.channels, tap.columns(), a)
        wrote.append(f"wrote {args.channels} ({len(a)} samples)")
    if args.plot:
        doc = result.estimates_dict()  # windows on the trace's time axis (since the log's start)
        report.plot(
            result.trace_since_start(),
            doc["windows"],
            args.plot,
            truth,
            title=f"{Path(args.log).name}: {profile.vehicle.name}",
            params=doc["parameters"],
            priors=profile.priors,
            capabilities=doc.get("capabilities"),
        )
        wrote.append(f"wrote {args.plot}")

    lg = result.log
    print(
        f"{args.log}: {lg.frames} frames, {lg.duration_s:.1f} s of bus time, "
        f"replayed in {lg.wall_s:.1f} s ({lg.realtime_factor:.0f}x real time)"
    )
    for line in report.stage_lines(result):
        print(line)
    for line in report.gate_lines(result):
        print(line)
    print(report.table(result, truth))
    answer = profilecheck.mass_answer(result.parameters, check_rep)
    if answer is not None:
        print(answer)
    for line in _coaching(result):
        print(line)
    kept, total = len(result.windows), result.supervisor.get("windows", 0)
    if total > kept:
        print(f"{total} gating windows in all; the JSON and the plot keep the newest {kept}")
    if found is not None:
        for line in _change_lines(found, args.log, len(before)):
            print(line)
    for line in report.decode_lines(result):
        print(line)
    bad = lg.source.get("bad_lines", 0)
    if bad:
        print(f"{bad} malformed log line(s) skipped; see the JSON 'log' section for line numbers")
    damage = lg.source.get("damage") or {}
    if damage.get("places"):
        print(f"{args.log}: {damage['summary']}; see the JSON 'log' section")
    for line in wrote:
        print(line)
    return 0


def _constants(profile) -> dict:
    """The profile's known constants, so that `vdp export` needs no profile to hand the result on."""
    from dataclasses import asdict

    from ..export import Constants

    return {**asdict(Constants.of(profile.vehicle)), "profile": str(profile.path)}


def _coaching(result) -> list[str]:
    """Progress per stage, and what to drive for what is not yet learnt."""
    coach = result.coaching
    if not coach:
        return []
    stages = coach["stages"]
    # a stage this car cannot run (core.progress: can_run) has no progress to show: its
    # percentage read as "on its way"
    lines = [
        "progress: "
        + ", ".join(
            f"stage {k} {100 * v['progress']:.0f} %" if v.get("can_run", True) else f"stage {k} cannot run"
            for k, v in stages.items()
        )
        + f"; next: {coach['next']}"
    ]
    for name, p in result.parameters.items():
        if p.status != CONVERGED and p.hint:
            hint = p.hint
            # the table's "!" lines gave the reason already: the hint adds only what to do about it
            if p.reason and p.reason in hint:
                hint = hint.replace(f"not valid: {p.reason}", "not valid (reason above)")
                hint = hint.replace(p.reason, "(reason above)")
            lines.append(f"  {name}: {hint}")
    return lines


def _earlier(path: str) -> tuple[str, dict]:
    """(its log, the document) of an earlier drive's `vdp replay --json`; a ConfigError that says
    what is wrong with it."""
    import json

    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"--after {path}: no such file") from None
    except (OSError, ValueError) as exc:
        raise ConfigError(f"--after {path}: not a vdp replay --json document: {exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("parameters"), dict):
        raise ConfigError(f"--after {path}: not a vdp replay --json document (no 'parameters')")
    if not isinstance(doc.get("drive"), dict):
        raise ConfigError(
            f"--after {path}: has no 'drive' section (its mass, wheel-speed scale and bus print): it was "
            "written by an older vdp; replay that log again with --json"
        )
    log = (doc.get("log") or {}).get("path") or path
    return str(log), doc


def _measures(head, profile, result) -> dict:
    """The drive's own measures (vdp.across.measures_of) in the JSON's shape: the bus print as an object."""
    import json

    from ..across import measures_of

    m = measures_of(head, profile)
    m["bus_print"] = json.loads(m["bus_print"]) if m.get("bus_print") else None
    m["start_time"] = result.log.start_time if result.log is not None else None
    return m


def _changes(before: list[tuple[str, dict]], log: str, drive: dict, result) -> list[dict]:
    """The changes across the earlier drives and this one, in the time order of their logs
    (vdp.across.changes: the rules vdp batch and vdp serve apply)."""
    from ..across import changes, document_rows
    from ..result import jsonable

    rows = [r for lg, doc in before for r in document_rows(doc, lg)]
    rows += document_rows({"drive": drive, "parameters": jsonable(result.estimates_dict())["parameters"]}, log)
    return [{k: v for k, v in c.items() if k != "vehicle"} for c in changes(rows)]


def _change_lines(found: list[dict], log: str, n: int) -> list[str]:
    if not found:
        return [f"changes: none against {n} earlier drive{'s' if n > 1 else ''} (--after)"]
    out = []
    for c in found:
        where = "this drive" if c["log"] == log else c["log"]
        out.append(f"change at {where}: {c['what']}; resets {', '.join(c['params'])}")
    return out
