"""``vdp simulate``: drive a scenario and write a CAN log (plus its truth JSON) or feed a bus."""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

from ..errors import ConfigError

log = logging.getLogger(__name__)


def _param(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    try:
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: {value!r} is not a number") from None


def add_parser(sub) -> argparse.ArgumentParser:
    from ..sim.scenario import SCENARIOS
    from ..sim.sensors import NOISE_MODELS

    p = sub.add_parser(
        "simulate",
        help="simulate a drive and write a CAN log or feed a bus",
        description="Simulate the paper's vehicle (truth: Table 6) driving a scenario; "
        "write a CAN log and <name>.truth.json beside it, or send live onto a bus.",
    )
    p.add_argument("--scenario", choices=sorted(SCENARIOS), default="paper", help="manoeuvre (default: paper)")
    p.add_argument("--seed", type=int, default=0, help="random seed; the same seed gives the same bytes (default: 0)")
    p.add_argument("--noise", choices=NOISE_MODELS, default="realistic", help="sensor noise model (default: realistic)")
    p.add_argument(
        "--out",
        type=Path,
        help="log file; the suffix picks the format (.log candump, .log.gz, .asc, .blf, .trc, .csv, ...)",
    )
    p.add_argument("--truth", type=Path, help="truth JSON path (default: <out stem>.truth.json)")
    p.add_argument("--profile", help="vehicle profile TOML (default: profiles/paper.toml)")
    p.add_argument("--dbc", help="use this DBC instead of the profile's")
    p.add_argument(
        "--param",
        type=_param,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a true parameter (l_f, h, C_K, C_alpha, I_z, I_x; or C_alpha_front and "
        "C_alpha_rear, per axle, whose mean is C_alpha); repeatable",
    )
    p.add_argument(
        "--model",
        choices=("vdp", "brush", "mb"),
        default="vdp",
        help="vehicle physics: vdp's own (default), or an independent model (brush: first-principles "
        "brush-tyre car; mb: CommonRoad multi-body model, needs the bench extra); an independent model "
        "also writes <out stem>.profile.toml with the car's known constants and priors",
    )
    p.add_argument("--car", help="car set of an independent model (brush: saloon, small; mb: bmw_320i, ...)")
    # issue 28's world (vdp.sim.road): each off by default
    p.add_argument(
        "--load",
        type=float,
        default=0.0,
        metavar="KG",
        help="an undeclared load as passengers and luggage (the profile keeps its mass; default 0)",
    )
    p.add_argument(
        "--road",
        choices=("flat", "hills"),
        default=None,
        help="hills: grade to +-8 %% and bank to +-3 deg along the drive (default: flat, as before)",
    )
    p.add_argument(
        "--imu",
        choices=("road", "body"),
        default="road",
        help="body: the accelerometer tilts with the body's pitch and roll (default: road-aligned)",
    )
    p.add_argument(
        "--duration", type=float, help="stop after this many seconds (at most the scenario's length; said if capped)"
    )
    p.add_argument(
        "--repeat",
        type=int,
        default=1,
        metavar="N",
        help="N drives of the scenario back to back in one log, seeds SEED..SEED+N-1, 1 s apart: "
        "a long log of one car (default 1)",
    )
    p.add_argument("--drop-rate", type=float, default=0.0, help="drop each frame with this probability")
    p.add_argument("--extra-ids", type=int, default=0, help="number of unrelated filler IDs (benchmarks)")
    p.add_argument("--extra-rate", type=float, default=100.0, help="frames per second of each filler ID")
    p.add_argument("--bus-interface", help="send live with python-can: virtual, udp_multicast, socketcan, ...")
    p.add_argument("--bus-channel", help="bus channel (default depends on the interface)")
    p.add_argument(
        "--events",
        metavar="KIND=N,...",
        help="events the model does not cover (off by default): reverse manoeuvres in stops, ABS stops on a "
        "slippery patch, kerb strikes in turns, wheel spin pulling away, e.g. reverse=2,abs=2,kerb=4,spin=2; "
        "their flags go on the bus where the profile maps them (profiles/paper_status.toml)",
    )
    p.add_argument(
        "--events-plain",
        action="store_true",
        help="with --events: the same drive without them (a stop for each reverse manoeuvre, a dry road for "
        "each ABS stop, no kerbs, no spin), to compare estimates with",
    )
    p.add_argument(
        "--sim-speed",
        type=float,
        default=1.0,
        help="live speed as a multiple of real time; 0 = as fast as possible (default 1)",
    )
    return p


def _progress():
    if not sys.stderr.isatty():
        return None
    last = [0.0]

    def show(t: float, total: float) -> None:
        now = time.monotonic()
        if now - last[0] >= 0.5 or t >= total:
            last[0] = now
            end = "\n" if t >= total else ""
            print(f"\rsimulated {t:6.1f} / {total:.1f} s", end=end, file=sys.stderr, flush=True)

    return show


def run(args: argparse.Namespace) -> int:
    from ..sim import run as simrun

    if args.out is None and args.bus_interface is None:
        raise ConfigError("give --out FILE and/or --bus-interface NAME")
    if args.sim_speed < 0:
        raise ConfigError("--sim-speed must be >= 0")
    if args.out is not None:  # before anything is written: a format vdp cannot read back is refused
        from ..sim.run import check_writable

        check_writable(args.out)
    from .paths import check_apart

    truth = args.truth or (simrun.truth_path(args.out) if args.out is not None else None)
    check_apart({"--out": args.out, "--truth": truth}, {"--profile": args.profile, "--dbc": args.dbc})
    for path in (args.out, args.truth):  # a new folder for the log, as vdp batch --out makes its own
        if path is not None:
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise ConfigError(f"{path}: cannot create its folder {path.parent}: {exc.strerror or exc}") from None
    params = dict(args.param)
    if args.repeat < 1:
        raise ConfigError(f"--repeat must be at least 1, got {args.repeat}")
    if args.model != "vdp":
        if args.events:
            raise ConfigError("--events applies to --model vdp only")
        if args.repeat != 1:
            raise ConfigError("--repeat applies to --model vdp only")
        return _run_independent(args)
    if args.car:
        raise ConfigError("--car chooses a car of an independent model; give --model brush or --model mb too")

    events = None
    if args.events:
        from ..sim.events import Events

        events = Events.parse(args.events, effects=not args.events_plain)
    elif args.events_plain:
        raise ConfigError("--events-plain goes with --events KIND=N,...: the drive without those events")

    def make(k: int = 0, start: float = simrun.START_TIME) -> simrun.Simulation:
        return simrun.Simulation(
            args.profile,
            args.scenario,
            args.seed + k,
            args.noise,
            params=params or None,
            dbc=args.dbc,
            drop_rate=args.drop_rate,
            extra_ids=args.extra_ids,
            extra_rate=args.extra_rate,
            duration=args.duration,
            start_time=start,
            **_world(args),
            events=events,
        )

    sim = make() if args.repeat == 1 else simrun.Repeated(make, args.repeat)
    if args.duration is not None and args.duration > sim.scenario.duration:
        # the cap bites: say so rather than hand back a shorter drive than asked for
        print(
            f"vdp simulate: --duration {args.duration:g} s is longer than scenario '{sim.scenario.name}' "
            f"({sim.scenario.duration:g} s); simulating {sim.duration:g} s",
            file=sys.stderr,
        )
    t0 = time.perf_counter()
    count, files, sent = _drive(args, sim)
    wall = time.perf_counter() - t0
    where = f" -> {', '.join(files)}" if files else ""
    live = f" (sent on {args.bus_interface})" if sent else ""
    what = sim.scenario.name if args.repeat == 1 else f"{sim.scenario.name} x {args.repeat}"
    print(f"simulated {what}: {sim.duration:.1f} s, {count} frames in {wall:.1f} s{live}{where}")
    return 0


def _world(args: argparse.Namespace) -> dict:
    """--load, --road, --imu as the simulators take them (vdp.sim.road)."""
    from ..sim.road import Imu, get_road

    return {
        "load": args.load,
        "road": get_road(args.road) if args.road not in (None, "flat") else None,
        "imu": Imu(body=True) if args.imu == "body" else None,
    }


def _run_independent(args: argparse.Namespace) -> int:
    """An independent model's drive: the same encode path and outputs, plus the car's profile TOML."""
    from ..sim.independent import SCENARIOS
    from ..sim.independent.common import IndependentSimulation

    for flag, given in (
        ("--param", args.param),
        ("--profile", args.profile),
        ("--dbc", args.dbc),
        ("--drop-rate", args.drop_rate),
        ("--extra-ids", args.extra_ids),
    ):
        if given:
            raise ConfigError(f"{flag} applies to --model vdp only; an independent model's car is set by --car")
    if args.scenario not in SCENARIOS:
        raise ConfigError(
            f"--model {args.model} drives only {', '.join(SCENARIOS)} (it needs speed above 5 m/s); "
            f"got --scenario {args.scenario}"
        )
    t0 = time.perf_counter()
    from ..sim.independent import get_model

    model = get_model(args.model, args.car, **_world(args))
    sim = IndependentSimulation(model, None, args.scenario, args.seed, args.noise, duration=args.duration)
    count, files, _ = _drive(args, sim, profile=True)
    wall = time.perf_counter() - t0
    where = f" -> {', '.join(files)}" if files else ""
    print(
        f"simulated {sim.model.name}/{sim.model.car} {sim.scenario.name}: {sim.duration:.1f} s, "
        f"{count} frames in {wall:.1f} s{where}"
    )
    return 0


def _drive(args: argparse.Namespace, sim, profile: bool = False) -> tuple[int, list[str], bool]:
    """Run ``sim``'s frames to the bus, the log and its truth (and, with ``profile``, the car's
    profile TOML beside them); return the frame count, the files written and whether a bus was used."""
    from ..outfile import write_bytes, write_text
    from ..sim import run as simrun

    frames = sim.frames(progress=_progress())
    bus = None
    files = []
    count = 0
    try:
        if args.bus_interface:
            bus = simrun.open_bus(args.bus_interface, args.bus_channel)
            frames = simrun.tee_bus(frames, bus, args.sim_speed)
        if args.out is not None:
            truth = args.truth or simrun.truth_path(args.out)
            simrun.write_truth(sim.truth, truth)
            files = [str(args.out), str(truth)]
            if profile:
                stem = simrun.truth_path(args.out).name[: -len(".truth.json")]
                prof = args.out.with_name(stem + ".profile.toml")
                from ..sim.independent.common import DBC as dbc

                text = sim.profile_toml()
                # the DBC beside the profile: the log, truth, profile and DBC move together as one folder
                copy = prof.with_name(dbc.name)
                if not copy.exists() or copy.read_bytes() != dbc.read_bytes():
                    write_bytes(copy, dbc.read_bytes())
                write_text(prof, text.replace(f'dbc = "{dbc}"', f'dbc = "{dbc.name}"'))
                files += [str(prof), str(copy)]
            count = simrun.write_log(frames, args.out, sim.bus_channel)
        else:
            for _ in frames:
                count += 1
            if args.truth:
                simrun.write_truth(sim.truth, args.truth)
                files = [str(args.truth)]
    finally:
        if bus is not None:
            bus.shutdown()
    return count, files, bus is not None
