"""vdp profile: check a vehicle profile against a log of the car, or draft one from a DBC.

vdp profile check drive.log --profile profiles/mycar.toml [--json out.json] [--seconds 300]
vdp profile new --dbc car.dbc [--log drive.log] [--out mycar.toml]

Exit status 0 when the profile fits the log, 1 when a check found a mismatch (each
printed with the channel and the likely fix), 2 on an error (a log that holds too few of
the profile's messages is one).
"""

from __future__ import annotations

import json
from pathlib import Path

from ..outfile import write_text
from .paths import check_apart, check_output, profile_inputs


def add_parser(sub):
    p = sub.add_parser(
        "profile",
        help="draft a vehicle profile from a DBC (new), or check one against a log (check)",
        description="Check that a profile reads the car's bus the way the physics says it must: "
        "signs, units, steering flag, mass, priors against geometry.",
    )
    s = p.add_subparsers(dest="action", metavar="ACTION")
    s.required = True
    c = s.add_parser("check", help="check a profile against a CAN log of the car")
    c.add_argument("log", help="a CAN log of the car, driven with some acceleration, braking and turns")
    c.add_argument("--profile", required=True, help="the vehicle profile TOML")
    c.add_argument("--seconds", type=float, default=300.0, help="bus time read from the log's start (default 300)")
    c.add_argument("--json", dest="json_out", metavar="PATH", help="write the findings as JSON")
    n = s.add_parser("new", help="draft a profile from a DBC (and a log): candidate signals per channel")
    n.add_argument("--dbc", required=True, help="the car's DBC file, or opendbc:NAME for one of the opendbc package")
    n.add_argument("--log", help="a CAN log of the car: rank the candidates by how their values behave")
    n.add_argument("--out", default="draft.toml", help="where to write the TOML draft (default draft.toml)")
    n.add_argument("--name", default="my-car", help="the vehicle's name in the draft")
    return p


def run_new(args) -> int:
    from ..errors import ConfigError
    from ..io import dbcfix
    from ..scaffold import draft, propose

    check_output(args.out, "--out", (".toml",))
    if args.dbc.startswith("opendbc:"):  # as a profile names it: the draft says it the same way
        from ..opendbc import opendbc_path

        dbc, ref = opendbc_path(f"--dbc {args.dbc}", args.dbc[len("opendbc:") :]), args.dbc
    else:
        dbc = ref = Path(args.dbc).resolve()
        if not dbc.is_file():
            raise ConfigError(
                f"--dbc {args.dbc}: no such file (for a DBC of the opendbc package, say opendbc:NAME, "
                f"e.g. opendbc:hyundai_kia_generic)"
            )
    dbc_input = {} if args.dbc.startswith("opendbc:") else {"--dbc": args.dbc}
    check_apart({"--out": args.out}, {"--log": args.log, **dbc_input})
    db = dbcfix.load(dbc)
    cands, facts = propose(db, args.log)
    for ch, cs in cands.items():
        best = ", ".join(f"{c.message}.{c.signal} [{c.dbc_unit or '-'}]" for c in cs[:3]) or "none"
        print(f"{ch:20} {best}")
    write_text(args.out, draft(dbc, cands, args.name, facts, ref=str(ref)))
    print(f"wrote {args.out}: edit the values marked EDIT, then run vdp profile check LOG --profile {args.out}")
    return 0


def run(args) -> int:
    if args.action == "new":
        return run_new(args)
    from ..errors import ConfigError
    from ..profile import load_profile
    from ..profilecheck import check_log, lines

    if not args.seconds > 0:
        raise ConfigError(f"--seconds must be positive, got {args.seconds}")
    if args.json_out:
        check_output(args.json_out, "--json", (".json",))
    profile = load_profile(args.profile)
    check_apart({"--json": args.json_out}, {"the log": args.log, **profile_inputs(profile)})
    rep, cov = check_log(args.log, profile, seconds=args.seconds)
    print(f"{args.log}: {cov.message()}; checked {rep.seconds:.1f} s of bus time")
    for name, v in rep.measured.items():
        print(f"  {name} = {v:.4g}")
    for name, why in rep.skipped.items():
        print(f"  not checked: {name}: {why}")
    out = lines(rep)
    for line in out:
        print(line)
    if not out:
        print("profile check: no mismatch found")
    if args.json_out:
        doc = rep.as_dict()
        doc["coverage"] = dict(cov.as_dict(), messages=cov.wanted, other_ids=cov.other[:20])
        write_text(args.json_out, json.dumps(doc, indent=2))
        print(f"wrote {args.json_out}")
    return 1 if out else 0
