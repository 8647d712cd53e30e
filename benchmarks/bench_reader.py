"""Log reading and frame decoding speed: vdp vs python-can / cantools.

    .venv/bin/python benchmarks/bench_reader.py [--lines 500000] [--log FILE]

Writes a candump -L file of paper-profile traffic (7 mapped ids with valid
counters and checksums, plus unmapped ids, 10 % of lines) unless --log is
given, then prints frames/s for ``can.LogReader`` and ``vdp.io.logs.open_log``
(plain and gzipped), and µs/frame for ``FrameDecoder.decode`` against
``cantools`` ``decode_message`` alone.  Best of --repeat runs.
"""

from __future__ import annotations

import argparse
import gzip
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path

import can
import cantools

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))

from vdp.io.checks import vdp_checksum  # noqa: E402
from vdp.io.decoder import FrameDecoder  # noqa: E402
from vdp.io.logs import open_log  # noqa: E402
from vdp.profile import load_profile  # noqa: E402


def make_log(path: Path, lines: int, db: cantools.database.Database) -> None:
    rng = random.Random(1)
    msgs = db.messages
    counters = {m.frame_id: 0 for m in msgs}
    t = 1700000000.0
    with open(path, "w") as f:
        for _ in range(lines):
            t += 0.0002
            if rng.random() < 0.1:
                f.write(f"({t:.6f}) can0 {rng.choice((0x123, 0x7DF, 0x3A0)):03X}#{rng.getrandbits(64):016X}\n")
                continue
            m = rng.choice(msgs)
            vals = {s.name: rng.uniform(s.minimum, s.maximum) * 0.9 for s in m.signals}
            if "COUNTER" in vals:
                vals["COUNTER"] = counters[m.frame_id]
                counters[m.frame_id] = (counters[m.frame_id] + 1) % 16
                vals["CHECKSUM"] = 0
            data = bytearray(m.encode(vals, strict=False))
            if "CHECKSUM" in vals:
                data[7] = vdp_checksum(m.frame_id, data)
            f.write(f"({t:.6f}) can0 {m.frame_id:03X}#{data.hex().upper()}\n")


def best(fn, repeat: int) -> tuple[float, int]:
    times, n = [], 0
    for _ in range(repeat):
        t = time.perf_counter()
        n = fn()
        times.append(time.perf_counter() - t)
    return min(times), n


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=500_000)
    ap.add_argument("--log", type=Path, help="an existing candump -L file to use instead")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    profile = load_profile(ROOT / "profiles" / "paper.toml")
    db = cantools.database.load_file(str(profile.dbc))
    tmp = Path(tempfile.mkdtemp(prefix="vdp-bench-"))
    try:
        log = args.log or tmp / "bench.log"
        if not args.log:
            make_log(log, args.lines, db)
        gz = tmp / (log.name + ".gz")
        with open(log, "rb") as fi, gzip.open(gz, "wb", compresslevel=6) as fo:
            shutil.copyfileobj(fi, fo)

        def python_can(path):
            return lambda: sum(1 for _ in can.LogReader(path))

        def ours(path):
            def run():
                with open_log(path) as src:
                    return sum(1 for _ in src)

            return run

        print(f"file: {log} ({log.stat().st_size / 1e6:.1f} MB)")
        rates = {}
        for label, fn in (
            ("can.LogReader      .log", python_can(log)),
            ("vdp open_log       .log", ours(log)),
            ("can.LogReader   .log.gz", python_can(gz)),
            ("vdp open_log    .log.gz", ours(gz)),
        ):
            dt, n = best(fn, args.repeat)
            rates[label] = n / dt
            print(f"{label}: {n / dt:10,.0f} frames/s  ({n} frames, {dt:.2f} s)")
        print(
            f"open_log / LogReader: {rates['vdp open_log       .log'] / rates['can.LogReader      .log']:.2f}x plain, "
            f"{rates['vdp open_log    .log.gz'] / rates['can.LogReader   .log.gz']:.2f}x gzip"
        )

        with open_log(log) as src:
            frames = list(src)

        def decode_all():
            d = FrameDecoder(profile, db).decode
            for m in frames:
                d(m)
            return len(frames)

        def cantools_all():
            dm = db.decode_message
            for m in frames:
                try:
                    dm(m.arbitration_id, m.data, decode_choices=False)
                except KeyError:
                    pass
            return len(frames)

        def replay():
            d = FrameDecoder(profile, db).decode
            n = 0
            with open_log(log) as src:
                for m in src:
                    d(m)
                    n += 1
            return n

        dt, n = best(decode_all, args.repeat)
        print(f"FrameDecoder.decode:         {dt / n * 1e6:.2f} us/frame (all frames, 10 % unmapped)")
        dt, n = best(cantools_all, args.repeat)
        print(f"cantools decode_message:     {dt / n * 1e6:.2f} us/frame (no checks, no conversion)")
        dt, n = best(replay, args.repeat)
        print(
            f"open_log + decode:           {n / dt:10,.0f} frames/s "
            f"({n / dt / rates['can.LogReader      .log']:.2f}x bare can.LogReader)"
        )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
