"""Scaffold: what `vdp profile new` proposes, against a profile written by hand (issue 25).

    nice -n 10 python benchmarks/scaffold.py [--busy] [--seed 1] [--duration 112] [--all]

Per car, a drive of the paper's scenario is simulated through the car's profile (the
reference) into its opendbc DBC; the scaffold (vdp.scaffold's ``candidates`` and
``behaviour``, as ``vdp profile new --dbc ... --log ...`` runs them) then ranks the DBC's
signals on that log, and its first choice per channel is compared with the reference's.
The cars: every shipped profile that names an opendbc DBC, and ``BUILT`` below, profiles
for other opendbc cars mapping what openpilot's carstate reads (wheel speeds, steering
angle), written here for the benchmark.  Then the real RAV4 drives (tests/data, 15 s, and
/work/shared/data/real, 60 s, if present) against profiles/toyota_rav4.toml: HELD OUT, the
scaffold's rules were never tuned on them.

How it counts:
- *right*: of the reference's channels and sources whose messages are in the log, those
  whose first candidate is the reference's message and signal.  A composite (the Golf's
  engine torque x ratio, the Elantra's per-cent torque by gear) counts right when the first
  candidate is one of its terms: the draft names that signal and says it needs a ratio or a
  weight.  A ``fine`` part or an ``alt`` of the reference is not asked for.
- *by name*: the same share from the DBC alone (``vdp profile new`` without ``--log``).
- *junk*: of all first candidates (the reference's channels and the others the scaffold
  proposes something for), those that are no measurement: by name a counter, checksum, CRC,
  alive or status, validity or quality signal; a short field with a value table; or a
  signal that never moves in the log.  The rule is this file's own, not the scaffold's.

A simulated log holds only the messages the reference maps (their other signals as the
simulator fills them): a candidate in another message is "not in the log" and ranks lower.
``--busy`` puts every other message of the DBC on the bus as well (``busy``), each signal a
slow wave across its range: then the log has to rank candidates that all move.  The by-name
column shows what the DBC alone gives; the real drives have every message.  The drive is the
paper's whole scenario (112 s) by default: its turns come after 52 s, and a yaw rate or a
lateral acceleration is ranked by how it follows steering x speed.
"""

from __future__ import annotations

import argparse
import logging
import re
import sys
import tempfile
import time
from pathlib import Path

import tomllib

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))

REAL = Path("/work/shared/data/real")
WHEELS = ("fl", "fr", "rl", "rr")
# Other opendbc cars: (DBC, [channels] lines) as openpilot's carstate reads the signals
BUILT = {
    "subaru_global_2017": (
        "subaru_global_2017_generated",
        {
            **{f"wheel_speed_{w}": ("Wheel_Speeds", w.upper(), "km/h") for w in WHEELS},
            "steering_angle": ("Steering_Torque", "Steering_Angle", "deg"),
        },
    ),
    "honda_civic_2016": (
        "honda_civic_touring_2016_can_generated",
        {
            **{f"wheel_speed_{w}": ("WHEEL_SPEEDS", f"WHEEL_SPEED_{w.upper()}", "km/h") for w in WHEELS},
            "steering_angle": ("STEERING_SENSORS", "STEER_ANGLE", "deg"),
        },
    ),
    "gm_global_a": (
        "gm_global_a_powertrain_generated",
        {
            "wheel_speed_fl": ("EBCMWheelSpdFront", "FLWheelSpd", "km/h"),
            "wheel_speed_fr": ("EBCMWheelSpdFront", "FRWheelSpd", "km/h"),
            "wheel_speed_rl": ("EBCMWheelSpdRear", "RLWheelSpd", "km/h"),
            "wheel_speed_rr": ("EBCMWheelSpdRear", "RRWheelSpd", "km/h"),
            "steering_angle": ("PSCMSteeringAngle", "SteeringWheelAngle", "deg"),
        },
    ),
    "nissan_x_trail_2017": (
        "nissan_x_trail_2017_generated",
        {
            "wheel_speed_fl": ("WHEEL_SPEEDS_FRONT", "WHEEL_SPEED_FL", "km/h"),
            "wheel_speed_fr": ("WHEEL_SPEEDS_FRONT", "WHEEL_SPEED_FR", "km/h"),
            "wheel_speed_rl": ("WHEEL_SPEEDS_REAR", "WHEEL_SPEED_RL", "km/h"),
            "wheel_speed_rr": ("WHEEL_SPEEDS_REAR", "WHEEL_SPEED_RR", "km/h"),
            "steering_angle": ("STEER_ANGLE_SENSOR", "STEER_ANGLE", "deg"),
        },
    ),
}
# no measurement, by name: the benchmark's own rule (tokens of the signal's name)
JUNK = re.compile(
    r"(^|_)(ctr|cnt|counter|count|msgcnt\d*|checksum|chksum|chks|cs|crc\d*|alive\w*|parity|qf|qbit\w*|"
    r"stat|status|sta|valid|vld|invalid|inv|quality|qual)($|_|\d)|counter|checksum|crc|alive|status|valid",
    re.I,
)


def built_profile(name: str, dbc: str, chans: dict, where: Path) -> Path:
    """A profile for a car vdp ships none for: the paper's constants, the car's DBC and signals."""
    text = (ROOT / "profiles" / "paper.toml").read_text()
    head = text[: text.index("[can]")]
    lines = [head, "[can]", f'dbc = "opendbc:{dbc}"', "", "[channels]"]
    for ch, (msg, sig, unit) in chans.items():
        extra = ", steering_wheel = true" if ch == "steering_angle" else ""
        lines.append(f'{ch} = {{ message = "{msg}", signal = "{sig}", unit = "{unit}"{extra} }}')
    path = where / f"{name}.toml"
    path.write_text("\n".join(lines).replace('name = "paper"', f'name = "{name}"') + "\n")
    return path


def reference(path: Path) -> dict[str, tuple[set[tuple[str, str]], bool]]:
    """channel -> (the (message, signal) pairs that count as right, whether a composite), as the
    profile's [channels] writes them (not the axle torques its [drivetrain] derives)."""
    out = {}
    for ch, cm in tomllib.loads(path.read_text())["channels"].items():
        if "terms" in cm:
            out[ch] = ({(t["message"], t["signal"]) for t in cm["terms"]}, True)
        else:
            out[ch] = ({(cm["message"], cm["signal"])}, False)
    return out


def in_log(log: Path, db, channel: str | None, seconds: float) -> dict[str, tuple[float, float]]:
    """'message.signal' -> (min, max) over the log's frames of the DBC's messages."""
    from vdp.io.logs import open_log

    by_id = {(m.frame_id, m.is_extended_frame): m for m in db.messages}
    span: dict[str, tuple[float, float]] = {}
    t0 = None
    with open_log(log) as src:
        for msg in src:
            t0 = msg.timestamp if t0 is None else t0
            if msg.timestamp - t0 > seconds:
                break
            if channel is not None and msg.channel is not None and str(msg.channel) != channel:
                continue
            m = by_id.get((msg.arbitration_id, msg.is_extended_id))
            if m is None or len(msg.data) != m.length:
                continue
            try:
                vals = m.decode(bytes(msg.data), decode_choices=False)
            except Exception:  # a frame of another layout
                continue
            for s, v in vals.items():
                k = f"{m.name}.{s}"
                lo, hi = span.get(k, (v, v))
                span[k] = (min(lo, v), max(hi, v))
    return span


def junk_why(db, c, span) -> str | None:
    sig = db.get_message_by_name(c.message).get_signal_by_name(c.signal)
    if JUNK.search(c.signal):
        return "name"
    lo, hi = sig.minimum, sig.maximum
    inside = [r for r in sig.choices or {} if lo is None or hi is None or lo <= r * sig.scale + sig.offset <= hi]
    if inside and sig.length <= 8:
        return "value table"  # named values within its range: a state (codes beyond it mark no value)
    moves = [span.get(f"{c.message}.{s}") for s in (c.signal, c.fine) if s]
    if moves[0] is not None and all(lohi is None or lohi[0] == lohi[1] for lohi in moves):
        return "constant"  # (with its fine part, if it has one: STEER_ANGLE in 1.5 deg steps)
    return None


def score(car: str, dbc: Path, path: Path, log: Path, channel: str | None, seconds: float) -> dict:
    from vdp.io import dbcfix
    from vdp.scaffold import propose

    db = dbcfix.load(dbc)
    by_name, _ = propose(db)
    first_name = {ch: (cs[0].message, cs[0].signal) for ch, cs in by_name.items() if cs}
    cands, _ = propose(db, log, seconds=seconds)  # as `vdp profile new --dbc DBC --log LOG` runs it
    first = {ch: (cs[0].message, cs[0].signal) for ch, cs in cands.items() if cs}
    span = in_log(log, db, channel, seconds)
    ref = reference(path)
    row = {"car": car, "n": 0, "right": 0, "name_right": 0, "composites": 0, "firsts": 0}
    row |= {"wrong": [], "junk": [], "extra": [], "name_wrong": []}
    for ch, (pairs, composite) in ref.items():
        if not all(f"{m}.{s}" in span for m, s in pairs):
            continue  # a channel the log does not carry: not counted
        row["n"] += 1
        row["composites"] += composite
        row["right"] += first.get(ch) in pairs
        row["name_right"] += first_name.get(ch) in pairs
        if first_name.get(ch) not in pairs:
            got = ".".join(first_name[ch]) if ch in first_name else "nothing"
            row["name_wrong"].append(f"{ch}: {got}")
        if first.get(ch) not in pairs:
            got = ".".join(first[ch]) if ch in first else "nothing"
            row["wrong"].append(f"{ch}: {got}")
    for ch, cs in cands.items():
        if not cs:
            continue
        row["firsts"] += 1
        if ch not in ref:
            row["extra"].append(f"{ch}: {cs[0].message}.{cs[0].signal} [{cs[0].dbc_unit or '-'}]")
        why = junk_why(db, cs[0], span)
        if why:
            row["junk"].append(f"{ch}: {cs[0].message}.{cs[0].signal} ({why})")
    return row


def busy(log: Path, path: Path, seed: int) -> None:
    """Add every other message of the DBC to a simulated log, 10 times a second, each signal a slow
    wave across its range with its own period and phase: a bus where the signals the reference
    does not map move too, unrelated to the drive (counters and checksums as well)."""
    import numpy as np

    from vdp.io import dbcfix
    from vdp.profile import load_profile

    rng = np.random.default_rng(seed)
    db = dbcfix.load(load_profile(path).dbc)
    mapped = {m for m, _ in (p for pairs, _ in reference(path).values() for p in pairs)}
    lines = log.read_text().splitlines()
    t0 = float(lines[0].split()[0][1:-1])
    t_end = float(lines[-1].split()[0][1:-1])
    extra = []
    for m in db.messages:
        if m.name in mapped:
            continue
        waves = {}
        for sg in m.signals:
            lo = sg.minimum if sg.minimum is not None else sg.offset
            hi = sg.maximum if sg.maximum is not None else sg.offset + sg.scale * (2 ** min(sg.length, 16) - 1)
            waves[sg.name] = (lo, hi, rng.uniform(4.0, 40.0), rng.uniform(0, 2 * np.pi))
        ident = f"{m.frame_id:08X}" if m.is_extended_frame else f"{m.frame_id:03X}"
        for t in np.arange(t0 + rng.uniform(0, 0.1), t_end, 0.1):
            phase = 2 * np.pi * (t - t0)
            vals = {n: lo + (hi - lo) * (0.5 + 0.5 * np.sin(phase / w + ph)) for n, (lo, hi, w, ph) in waves.items()}
            try:
                data = m.encode(vals, strict=False, scaling=True).hex().upper()
            except Exception:  # a multiplexed or odd layout: leave the message out
                break
            sep = "#" if m.length <= 8 else "##0"
            extra.append((t, f"({t:.6f}) can0 {ident}{sep}{data}"))
    both = [(float(ln.split()[0][1:-1]), ln) for ln in lines] + extra
    both.sort(key=lambda x: x[0])
    log.write_text("\n".join(ln for _, ln in both) + "\n")


def simulated(car: str, path: Path, tmp: Path, duration: float, seed: int, full_bus: bool) -> dict:
    from vdp.profile import load_profile
    from vdp.sim.run import Simulation, write_log

    prof = load_profile(path)
    log = tmp / f"{car}.log"
    write_log(Simulation(prof, "paper", seed=seed, duration=duration).frames(), log)
    if full_bus:
        busy(log, path, seed)
    return score(car, prof.dbc, path, log, None, duration + 1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=112.0, help="seconds of each simulated drive (default 112)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--busy", action="store_true", help="every other message of the DBC in the log too (busy)")
    ap.add_argument("--all", action="store_true", help="also list the first choices where the reference maps nothing")
    a = ap.parse_args()
    logging.getLogger("vdp").setLevel(logging.ERROR)
    from vdp.profile import load_profile

    t_start = time.perf_counter()
    rows, held = [], []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for path in sorted((ROOT / "profiles").glob("*.toml")):
            dbc = tomllib.loads(path.read_text())["can"]["dbc"]
            if isinstance(dbc, str) and dbc.startswith("opendbc:"):
                rows.append(simulated(path.stem, path, tmp, a.duration, a.seed, a.busy))
        for car, (dbc, chans) in BUILT.items():
            path = built_profile(car, dbc, chans, tmp)
            rows.append(simulated(f"{car} (built)", path, tmp, a.duration, a.seed, a.busy))
        rav4 = load_profile(ROOT / "profiles" / "toyota_rav4.toml")
        drives = [(ROOT / "tests/data/rav4-2018-highway-15s.log.gz", rav4.dbc, 15.0)]
        if (REAL / "rav4-2018-highway-60s.log.gz").exists():
            drives.append((REAL / "rav4-2018-highway-60s.log.gz", REAL / "toyota_new_mc_pt_generated.dbc", 60.0))
        for log, dbc, secs in drives:
            held.append(score(f"real RAV4, {secs:.0f} s (held out)", dbc, rav4.path, log, rav4.bus_channel, secs))
    head = ("car", "channels in the log", "right (with the log)", "right (DBC alone)", "composites", "first choices")
    print("| " + " | ".join([*head, "junk"]) + " |")
    print("|---|---|---|---|---|---|---|")

    def line(r):
        pct = 100 * r["right"] / r["n"] if r["n"] else 0.0
        return (
            f"| {r['car']} | {r['n']} | {r['right']} ({pct:.0f} %) | {r['name_right']} | {r['composites']} "
            f"| {r['firsts']} | {len(r['junk'])} |"
        )

    for r in [*rows, None, *held]:
        if r is None:
            tot = {k: sum(x[k] for x in rows) for k in ("n", "right", "name_right", "composites", "firsts")}
            tot.update(car=f"**total, {len(rows)} simulated cars**", junk=[j for x in rows for j in x["junk"]])
            print(line(tot))
            continue
        print(line(r))
    print()
    for r in [*rows, *held]:
        for w in r["wrong"]:
            print(f"- {r['car']}: wrong first choice, {w}")
        for j in r["junk"]:
            print(f"- {r['car']}: junk in first place, {j}")
        for x in r["name_wrong"] if a.all else []:
            print(f"- {r['car']}: from the DBC alone, wrong first choice, {x}")
        for x in r["extra"] if a.all else []:
            print(f"- {r['car']}: proposed where the reference maps nothing, {x}")
    print(f"\n({time.perf_counter() - t_start:.0f} s, {a.duration:.0f} s simulated drives, seed {a.seed})")
    return 0


if __name__ == "__main__":
    import benchenv

    benchenv.announce()
    sys.exit(main())
