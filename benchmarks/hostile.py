"""Hostile and damaged inputs through `vdp replay`: outcome, frames kept, peak RSS, time.

    nice -n 10 .venv/bin/python benchmarks/hostile.py [--seconds 60] [--only NAME] [--outputs]

Then the output side (issue 26; --outputs: only these): an output given as an input, names
that break a format, a hand-edited result, an unwritable --out, each through the CLI.

Every input is made on the fly in a temporary directory from one simulated drive
(`--seconds` of the paper's stage-1 scenario).  Each replay runs in its own process;
its peak RSS is that process's VmHWM.  "kept" is frames replayed / frames of the clean
drive the input holds (a damaged input cannot hold all of them).  The figures are in
RELIABILITY.md.
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

import can

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))

from vdp.sim.run import Simulation  # noqa: E402

PROFILE = ROOT / "profiles" / "paper.toml"
RUN = (
    "import json, sys, time\n"
    "from vdp.cli import main\n"
    "t = time.monotonic()\n"
    "try:\n"
    "    rc = main(sys.argv[2:])\n"
    "except BaseException as exc:\n"
    "    rc = f'{type(exc).__name__}'\n"
    "hwm = next(int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM:'))\n"
    "json.dump({'rc': rc, 'wall': time.monotonic() - t, 'rss_mb': hwm / 1024}, open(sys.argv[1], 'w'))\n"
)


def candump(msgs) -> str:
    out = []
    for m in msgs:
        aid = f"{m.arbitration_id:08X}" if m.is_extended_id else f"{m.arbitration_id:03X}"
        out.append(f"({m.timestamp:.6f}) can0 {aid}#{bytes(m.data).hex().upper()}\n")
    return "".join(out)


def at(m: can.Message, t: float) -> can.Message:
    return can.Message(
        timestamp=t, arbitration_id=m.arbitration_id, is_extended_id=m.is_extended_id, data=m.data, channel=m.channel
    )


def write(path: Path, msgs, start: float | None = None) -> Path:
    if path.suffix == ".log":
        path.write_text(candump(msgs))
        return path
    with can.Logger(str(path)) as w:
        if start is not None and hasattr(w, "start_timestamp"):
            w.start_timestamp = start
        for m in msgs:
            w.on_message_received(m)
    return path


def blf_damage(path: Path, msgs, how: str) -> Path:
    write(path, msgs)
    data = bytearray(path.read_bytes())
    pos, conts = 144, []
    while pos + 16 <= len(data):
        size = struct.unpack_from("<L", data, pos + 8)[0]
        conts.append((pos, size))
        pos += size + size % 4
    off, size = conts[len(conts) // 4]
    if how == "halved":
        struct.pack_into("<L", data, off + 8, size // 2)
    elif how == "doubled":
        struct.pack_into("<L", data, off + 8, size * 2)
    elif how == "zeroed":
        struct.pack_into("<L", data, off + 8, 0)
    elif how == "garbage":
        data[off : off + 64] = b"\xa5" * 64
    else:
        data[off + 200 : off + 264] = b"\xa5" * 64
    path.write_bytes(bytes(data))
    return path


def inputs(d: Path, msgs) -> dict:
    """name -> (path, frames of the drive it holds, what a user should get)."""
    n = len(msgs)
    q = n // 4
    step = [m if k < q else at(m, m.timestamp - 3600.0) for k, m in enumerate(msgs)]
    out: dict = {}
    out["clean .log"] = (write(d / "clean.log", msgs), n, "replayed")
    for suffix in (".log", ".csv", ".trc", ".blf", ".asc"):
        p = write(d / f"step{suffix}", step, start=msgs[0].timestamp - 7200.0)
        out[f"1 h clock step back, {suffix}"] = (p, n, "frames kept, bus time sane")
    k = n // 3
    glitch = [*msgs[:k], at(msgs[k], msgs[k].timestamp + 5 * 365 * 86400.0), *msgs[k + 1 :]]
    out["one frame 5 years ahead, .csv"] = (write(d / "future.csv", glitch), n, "frames kept")
    for stamp, name in ((1e21, "1e21"), (float("nan"), "NaN"), (-5.0, "negative")):
        bad = [*msgs[:k], at(msgs[k], stamp), at(msgs[k + 1], stamp), *msgs[k + 2 :]]
        out[f"two frames stamped {name}"] = (write(d / f"ts-{name}.log", bad), n - 2, "2 refused, counted")
    lines = (d / "clean.log").read_text().splitlines(True)
    for suffix in (".asc", ".trc"):
        clean = write(d / f"c{suffix}", msgs).read_text().splitlines(True)
        j = len(clean) // 2
        clean.insert(j, clean[j][:30] + " ZZ QQ\n")
        p = d / f"badline{suffix}"
        p.write_text("".join(clean))
        out[f"one bad line, {suffix}"] = (p, n, "1 skipped, counted")
    for how in ("halved", "doubled", "zeroed", "garbage", "corrupt zlib"):
        many = [at(m, m.timestamp + r * 100.0) for r in range(6) for m in msgs]
        out[f"BLF container {how}"] = (
            blf_damage(d / f"blf-{how.replace(' ', '-')}.blf", many, how),
            len(many),
            "rest replayed",
        )
    gz = gzip.compress("".join(lines).encode())
    p = d / "cut.log.gz"
    p.write_bytes(gz[: len(gz) * 3 // 4])
    out["truncated .log.gz (3/4 kept)"] = (p, n, "readable part replayed")
    p = d / "bomb.log.gz"
    z = zlib.compressobj(1, zlib.DEFLATED, 31)
    with open(p, "wb") as f:
        f.write(z.compress("".join(lines[: n // 2]).encode()))
        chunk = b"0" * (1 << 20)
        for _ in range(2048):  # one 2 GiB line
            f.write(z.compress(chunk))
        f.write(z.compress(("\n" + "".join(lines[n // 2 :])).encode()))
        f.write(z.flush())
    out["gzip line bomb (one 2 GiB line)"] = (p, n, "1 line skipped")
    p = d / "endless.log"
    with open(p, "wb") as f:
        f.write("".join(lines[:200]).encode())
        f.truncate(1 << 30)  # then 1 GiB of NUL bytes without a newline (sparse)
    out["endless line (1 GiB, no newline)"] = (p, 200, "1 line skipped")
    p = d / "chans.log"
    with open(p, "w") as f:
        for k2 in range(1_000_000):
            f.write(f"({1.7e9 + k2 * 1e-4:.6f}) x{k2} 0B1#0000000000000000\n")
    out["1 M distinct channel names"] = (p, 0, "table capped, rest counted")
    p = d / "ids.log"
    import random

    rng = random.Random(1)
    with open(p, "w") as f:
        f.write("".join(lines))
        t = msgs[-1].timestamp
        for k2 in range(1_000_000):
            f.write(f"({t + 0.001 + k2 * 1e-5:.6f}) can0 {rng.getrandbits(28) | 0x10000000:08X}#00\n")
    out["1 M random unknown ids after the drive"] = (p, n, "counted, table capped")
    fifo = d / "fifo.log"
    os.mkfifo(fifo)
    out["a FIFO as the log"] = (fifo, 0, "refused at once")
    dev = d / "zero.log"
    dev.symlink_to("/dev/zero")
    out["/dev/zero as the log"] = (dev, 0, "refused at once")
    return out


def replay(path: Path, d: Path) -> dict:
    res = d / "res.json"
    out = d / "out.json"
    for f in (res, out):
        if f.exists():
            f.unlink()
    args = ["replay", str(path), "--profile", str(PROFILE), "--no-progress", "--no-ekf", "--json", str(out)]
    env = {**os.environ, "PYTHONPATH": str(ROOT / "service")}
    t = time.monotonic()
    try:
        r = subprocess.run(
            [sys.executable, "-c", RUN, str(res), *args], capture_output=True, text=True, timeout=600, env=env
        )
        info = json.loads(res.read_text()) if res.exists() else {"rc": r.returncode, "rss_mb": float("nan")}
        info["stderr"] = r.stderr.strip().splitlines()[-1:] if r.stderr.strip() else []
    except subprocess.TimeoutExpired:
        info = {"rc": "timeout", "rss_mb": float("nan")}
    info["wall"] = time.monotonic() - t
    if out.exists():
        log = json.loads(out.read_text())["log"]
        info["frames"] = log["frames"]
        info["bad"] = log.get("bad_lines", 0)
        info["bus_time"] = log.get("duration_s")
        info["damage"] = (log.get("damage") or {}).get("places", 0)
    return info


def outputs(d: Path, log: Path) -> dict:
    """Output-side cases (issue 26): name -> (vdp arguments, check of what was left, what a user
    should get).  A check returns "" when the case held, else what broke."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib

    text = PROFILE.read_text().replace('"../dbc/vdp.dbc"', f'"{ROOT / "dbc" / "vdp.dbc"}"')
    own = d / "own.log"
    own.write_bytes(log.read_bytes())
    kept = own.read_bytes()
    math_name = d / "math.toml"
    math_name.write_text(text.replace('name = "paper"', 'name = "$^$"', 1))
    cond = d / "cond.toml"
    torque = 'wheel_torque_front = { message = "WHEEL_TORQUE", signal = "TORQUE_FRONT", unit = "Nm" }'
    cond.write_text(
        text.replace(
            torque,
            "wheel_torque_front = { conditions = [{ message = 5, signal = [] }], "
            'terms = [{ message = "WHEEL_TORQUE", signal = "TORQUE_FRONT", unit = "Nm" }] }',
        )
    )
    good = {"value": 1.2, "std": 0.02, "unit": "m", "status": "converged", "valid": True}
    car = {"name": "car", "mass": 1600.0, "wheelbase": 2.5, "wheel_radius": 0.3, "wheel_inertia": 2.0, "track": 1.5}

    def result(file: str, l_f=None, **vehicle) -> Path:
        p = d / f"{file}.json"
        p.write_text(json.dumps({"parameters": {"l_f": {**good, **(l_f or {})}}, "vehicle": {**car, **vehicle}}))
        return p

    def unchanged(path: Path, before: bytes):
        return lambda: "" if path.read_bytes() == before else f"{path.name} was overwritten"

    def loads(path: Path, key, want):
        def check() -> str:
            if not path.exists():
                return "nothing written"
            try:
                got = tomllib.loads(path.read_text())
            except tomllib.TOMLDecodeError as exc:
                return f"not valid TOML ({exc})"
            for k in key:
                got = got[k]
            return "" if got == want else f"read back {got!r}"

        return check

    def exists(path: Path):
        return lambda: "" if path.exists() else "nothing written"

    def absent(path: Path):
        return lambda: "" if not path.exists() else f"{path.name} written"

    nan = result("nan", {"value": float("nan")})
    text_num = result("text", {"value": "1.2"})
    zero = result("zero", wheelbase=0.0)
    newline = result("newline", name='Golf "R"\nm: 1')
    replay = ["replay", "--no-progress", "--no-ekf"]
    out: dict = {
        "replay drive.log --json drive.log": (
            [*replay, str(own), "--profile", str(PROFILE), "--json", str(own)],
            unchanged(own, kept),
            "refused, log kept",
        ),
        "replay --plot, vehicle named $^$": (
            [*replay, str(log), "--profile", str(math_name), "--plot", str(d / "math.png")],
            exists(d / "math.png"),
            "plotted",
        ),
        "composite conditions [{message = 5, signal = []}]": (
            [*replay, str(log), "--profile", str(cond)],
            lambda: "",
            "one line naming the key",
        ),
        "export commonroad, l_f NaN": (
            ["export", str(nan), "--format", "commonroad", "--out", str(d / "nan.yaml")],
            absent(d / "nan.yaml"),
            "refused, field named",
        ),
        'export carla, l_f "1.2"': (
            ["export", str(text_num), "--format", "carla", "--out", str(d / "text.carla.json")],
            absent(d / "text.carla.json"),
            "refused, field named",
        ),
        "export carla, wheelbase 0": (
            ["export", str(zero), "--format", "carla", "--out", str(d / "zero.carla.json")],
            absent(d / "zero.carla.json"),
            "refused, field named",
        ),
        "export toml, newline and quote in the name": (
            ["export", str(newline), "--format", "toml", "--out", str(d / "newline.toml")],
            loads(d / "newline.toml", ("vehicle", "name"), 'Golf "R"\nm: 1'),
            "name read back",
        ),
        "export json over its own result": (
            ["export", str(nan), "--format", "json", "--out", str(nan)],
            unchanged(nan, nan.read_bytes()),
            "refused, result kept",
        ),
        "profile new --name 'Golf \"R\"'": (
            [
                "profile",
                "new",
                "--dbc",
                str(ROOT / "dbc" / "vdp.dbc"),
                "--name",
                'Golf "R"',
                "--out",
                str(d / "g.toml"),
            ],
            loads(d / "g.toml", ("vehicle", "name"), 'Golf "R"'),
            "name read back",
        ),
        "batch --out /proc (no file can be made)": (
            ["batch", str(log), "--out", "/proc", "--workers", "1", "--no-progress"],
            lambda: "",
            "refused before the batch",
        ),
    }
    return out


def run_outputs(d: Path, log: Path, only: str | None) -> None:
    print(f"\n{'output case':50} {'rc':>17} {'held':>5} {'wall s':>7}  [what vdp said]")
    env = {**os.environ, "PYTHONPATH": str(ROOT / "service")}
    for name, (argv, check, want) in outputs(d, log).items():
        if only and only not in name:
            continue
        res = d / "res.json"
        res.unlink(missing_ok=True)
        t = time.monotonic()
        r = subprocess.run(
            [sys.executable, "-c", RUN, str(res), *argv], capture_output=True, text=True, timeout=600, env=env
        )
        rc = json.loads(res.read_text())["rc"] if res.exists() else r.returncode
        broke = check()
        said = (r.stderr.strip().splitlines() or [""])[-1]
        # held: the outcome wanted (0, or a one-line refusal, exit 2) and nothing overwritten or wrong
        held = not broke and rc in (0, 2) and (rc == 0 or len(r.stderr.strip().splitlines()) == 1)
        print(f"{name:50} {str(rc)[:17]:>17} {'yes' if held else 'NO':>5} {time.monotonic() - t:7.1f}  {want}"
              + (f"  [{said[:110]}]" if said else "") + (f"  BROKEN: {broke}" if broke else ""))  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--only", help="run the inputs whose name contains this")
    ap.add_argument("--outputs", action="store_true", help="run only the output-side cases (issue 26)")
    args = ap.parse_args()
    msgs = list(Simulation(PROFILE, "stage1", 1, "realistic", duration=args.seconds).frames())
    with tempfile.TemporaryDirectory(prefix="vdp-hostile-") as tmp:
        d = Path(tmp)
        if args.outputs:
            run_outputs(d, write(d / "clean.log", msgs), args.only)
            return 0
        cases = inputs(d, msgs)
        print(f"{len(msgs)} frames in the clean drive ({args.seconds:g} s)")
        head = ("input", "rc", "frames", "of", "bad", "dmg", "bus s", "RSS MB", "wall s")
        print(f"{head[0]:40} " + " ".join(f"{h:>7}" for h in head[1:]))
        for name, (path, holds, want) in cases.items():
            if args.only and args.only not in name:
                continue
            r = replay(path, d)
            bus = r.get("bus_time")
            print(
                f"{name:40} {r['rc']!s:>7} {r.get('frames', '-')!s:>7} {holds:>7} {r.get('bad', '-')!s:>7} "
                f"{r.get('damage', '-')!s:>7} {'-' if bus is None else f'{bus:.1f}':>7} {r['rss_mb']:7.0f} "
                f"{r['wall']:7.1f}  {want}"
                + (f"  [{r['stderr'][0][:90]}]" if r.get("rc") not in (0,) and r.get("stderr") else "")
            )
        for mult in (1, 2, 4):
            p = d / f"lin{mult}.log"
            base = (d / "clean.log").read_text()
            span = msgs[-1].timestamp - msgs[0].timestamp + 0.01
            with open(p, "w") as f:
                for r2 in range(mult * 4):
                    f.write(candump(at(m, m.timestamp + r2 * span) for m in msgs) if r2 else base)
            r = replay(p, d)
            mb = p.stat().st_size / 1e6
            rate = r["wall"] / mb
            print(f"linear: {mb:7.1f} MB clean candump: {r['wall']:6.1f} s, {rate:.3f} s/MB, {r['rss_mb']:.0f} MB RSS")
        run_outputs(d, d / "clean.log", args.only)
    return 0


if __name__ == "__main__":
    sys.exit(main())
