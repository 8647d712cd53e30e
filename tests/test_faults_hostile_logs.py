"""Hostile and damaged logs (issue 13): every format skips bad records, damage replays what is
readable and says what was lost, absurd clocks are refused, and memory stays bounded.

Each test is one break the red-team run found; the clean drive is short and simulated.
"""

from __future__ import annotations

import gzip
import json
import math
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import can
import pytest

from vdp.buffer import Aligner
from vdp.cli import main
from vdp.errors import LogFormatError
from vdp.io.logs import open_log
from vdp.sim.run import Simulation

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "profiles" / "paper.toml"
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "service")}


@pytest.fixture(scope="module")
def msgs():
    return list(Simulation(PROFILE, "stage1", 3, "realistic", duration=6.0).frames())


def write(path: Path, frames, start: float | None = None) -> Path:
    """``frames`` as a log; ``start``: the BLF header's start time (frames are stored relative to it)."""
    if path.suffix == ".log":  # python-can's candump writer holds a clock step back at the last time
        path.write_text("".join(_candump(m) for m in frames))
        return path
    with can.Logger(str(path)) as w:
        if start is not None and hasattr(w, "start_timestamp"):
            w.start_timestamp = start
        for m in frames:
            w.on_message_received(m)
    return path


def read(path: Path, **kw):
    with open_log(path, **kw) as src:
        return list(src), src.stats


def replay_cli(path: Path, out: Path, *extra: str) -> int:
    return main(
        ["replay", str(path), "--profile", str(PROFILE), "--json", str(out), "--no-progress", "--no-ekf", *extra]
    )


# -- one bad line in a text format: skipped, counted, named with --strict -------------------

BAD_LINE = {
    ".asc": lambda line: line.replace(" d 8 ", " d 8 ZZ ", 1),
    ".trc": lambda line: line[: line.rindex("Tx") + 2] + "  8  ZZ 00 11 22 33 44 55 66",
    ".csv": lambda line: line.replace(",8,", ",8,@@not base64@@", 1),
}


@pytest.mark.parametrize("suffix", sorted(BAD_LINE))
def test_one_bad_line_in_asc_trc_csv_is_skipped_not_fatal(tmp_path, msgs, suffix):
    clean = write(tmp_path / f"clean{suffix}", msgs)
    lines = clean.read_text().splitlines()
    k = len(lines) // 2
    while not any(c in lines[k] for c in (" d 8 ", "Tx", ",8,")):
        k += 1
    lines.insert(k, BAD_LINE[suffix](lines[k]))
    dirty = tmp_path / f"dirty{suffix}"
    dirty.write_text("\n".join(lines) + "\n")
    good, _ = read(clean)
    got, st = read(dirty)
    assert len(got) == len(good) == len(msgs) and st.bad == 1
    assert st.examples[0].line == k + 1 and "unreadable" in st.examples[0].reason
    with pytest.raises(LogFormatError, match=rf"line {k + 1}: unreadable"):
        read(dirty, strict=True)


# -- a clock step back a quarter in: the frames are kept, bus time stays sane ------------------


@pytest.mark.parametrize("suffix", [".log", ".csv", ".trc", ".blf", ".asc"])
def test_a_clock_step_back_keeps_the_frames(tmp_path, msgs, suffix):
    q = len(msgs) // 4
    stepped = [m if k < q else _at(m, m.timestamp - 3600.0) for k, m in enumerate(msgs)]
    p = write(tmp_path / f"s{suffix}", stepped, start=msgs[0].timestamp - 7200.0)
    got, st = read(p)
    if suffix == ".asc":
        # python-can's ASC writer stamps the frames before the step relative to the first one, and
        # the rest absolute: the reader sees one jump of years forward, and keeps every frame
        assert len(got) == len(msgs) and st.jumps == 1 and st.bad == 0
    else:
        # the clock is followed after a few frames behind it; those few are counted, never silent
        assert len(got) >= len(msgs) - 10 and len(got) + st.bad == len(msgs) and st.resyncs == 1
    span = msgs[-1].timestamp - msgs[0].timestamp
    assert 0.95 * span <= st.bus_time <= span


@pytest.mark.parametrize("suffix", [".log", ".csv", ".blf"])
def test_one_far_future_frame_costs_a_few_frames_not_the_rest(tmp_path, msgs, suffix):
    k = len(msgs) // 3
    glitch = [*msgs[:k], _at(msgs[k], msgs[k].timestamp + 5 * 365 * 86400.0), *msgs[k + 1 :]]
    got, st = read(write(tmp_path / f"f{suffix}", glitch))
    assert len(got) >= len(msgs) - 10 and st.jumps == 1
    span = msgs[-1].timestamp - msgs[0].timestamp
    assert 0.95 * span <= st.bus_time <= span


@pytest.mark.parametrize("stamp,reason", [(1e21, "out of range"), (math.nan, "non-finite"), (-5.0, "negative")])
def test_absurd_timestamps_are_refused_and_counted(tmp_path, msgs, stamp, reason):
    k = len(msgs) // 2
    bad = [*msgs[:k], _at(msgs[k], stamp), _at(msgs[k + 1], stamp), *msgs[k + 2 :]]
    p = tmp_path / "a.log"
    p.write_text("".join(_candump(m) for m in bad))
    got, st = read(p)
    assert len(got) == len(msgs) - 2 and st.bad == 2 and all(reason in r for r in st.reasons)


def test_the_aligner_refuses_a_time_where_its_tick_cannot_advance():
    a = Aligner()
    calls = 0
    sample = a._sample

    def counted(t):
        nonlocal calls
        calls += 1
        if calls > 1000:
            raise RuntimeError("the tick does not advance: samples pile up")
        return sample(t)

    a._sample = counted
    for t in (1.7e9, 1.7e9 + 0.02, 1e21, 1e21, 1e21 * (1 + 1e-15)):
        a.push(t, [(0, 1.0)])
    assert calls <= 3 and a.clock_backwards == 3


def test_the_replay_summary_never_shows_a_negative_or_absurd_bus_time(tmp_path, msgs, capsys):
    q = len(msgs) // 4
    stepped = [m if k < q else _at(m, m.timestamp - 3600.0) for k, m in enumerate(msgs)]
    p = write(tmp_path / "s.trc", stepped)
    assert replay_cli(p, tmp_path / "o.json") == 0
    first = capsys.readouterr().out.splitlines()[0]
    secs = float(first.split(" frames, ")[1].split(" s of bus time")[0])
    assert 5.5 <= secs <= 6.0, first


# -- BLF container damage: read what can be read, say what was lost ----------------------------


def _containers(data: bytes) -> list[tuple[int, int]]:
    """(offset, size field) of each top-level LOBJ container after the 144-byte header."""
    out, pos = [], 144
    while pos + 16 <= len(data):
        sig, _, _, size, typ = struct.unpack_from("<4sHHLL", data, pos)
        assert sig == b"LOBJ"
        out.append((pos, size))
        pos += size + size % 4
    return out


@pytest.mark.parametrize("damage", ["halved", "doubled", "zeroed", "type", "garbage", "corrupt zlib"])
def test_blf_container_damage_replays_the_rest(tmp_path, msgs, damage, capsys):
    span = msgs[-1].timestamp - msgs[0].timestamp + 0.01
    frames = [_at(m, m.timestamp + r * span) for r in range(8) for m in msgs]  # the drive 8 times over
    p = write(tmp_path / "c.blf", frames)
    data = bytearray(p.read_bytes())
    conts = _containers(bytes(data))
    assert len(conts) >= 4
    off, size = conts[len(conts) // 4]
    if damage == "halved":
        struct.pack_into("<L", data, off + 8, size // 2)
    elif damage == "doubled":
        struct.pack_into("<L", data, off + 8, size * 2)
    elif damage == "zeroed":
        struct.pack_into("<L", data, off + 8, 0)
    elif damage == "type":
        struct.pack_into("<L", data, off + 12, 77)
    elif damage == "garbage":
        data[off : off + 64] = b"\xa5" * 64
    else:
        data[off + 200 : off + 264] = b"\xa5" * 64
    p.write_bytes(bytes(data))
    got, st = read(p)
    # what a container holds is ~2,000 frames here: at most about one is lost
    lost = len(frames) - len(got)
    per_container = len(frames) / len(conts)
    assert lost <= 1.5 * per_container and st.damaged >= 1
    assert len({m.timestamp for m in got}) == len(got)  # nothing handed out twice
    if damage in ("halved", "doubled", "zeroed"):
        assert lost <= 2  # the zlib stream knows its own end: only the objects at its edges can go
    assert replay_cli(p, tmp_path / "o.json") == 0
    out = capsys.readouterr().out
    assert "damaged in" in out and f"{len(got):,} frames read" in out
    d = json.loads((tmp_path / "o.json").read_text())["log"]["damage"]
    assert d["places"] == st.damaged and d["bytes_skipped"] == st.lost_bytes


# -- gzip bomb, endless lines, FIFOs, devices: bounded, refused ------------------------------


# Peak RSS [MB] of this process's own memory: VmHWM.  (ru_maxrss would also count the pytest
# process the child was forked from: Linux carries the high-water mark across exec.)
_HWM = (
    "def hwm():\n"
    "    for line in open('/proc/self/status'):\n"
    "        if line.startswith('VmHWM:'):\n"
    "            return int(line.split()[1]) // 1024\n"
)


def _peak_rss_reading(path: Path) -> tuple[int, str]:
    """(growth of peak RSS in MB while reading, stats) of a fresh process reading ``path`` with
    open_log.  Growth over the peak once the compiled scan is loaded (numba and LLVM: about
    120 MB of their own), so the bound judges the reader, not the compiler."""
    code = (
        "import sys\n"
        f"{_HWM}"
        "from vdp.io import scan\n"
        "from vdp.io.logs import open_log\n"
        "scan.lines(b'(1.0) can0 123#00\\n', False)\n"
        "src = open_log(sys.argv[1])\n"
        "base = hwm()\n"
        "n = sum(1 for _ in src)\n"
        "print(hwm() - base, n, src.stats.bad, src.stats.reasons)\n"
    )
    r = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120, env=ENV)
    assert r.returncode == 0, r.stderr
    rss, rest = r.stdout.split(" ", 1)
    return int(rss), rest


def test_a_gzip_line_bomb_is_skipped_in_bounded_memory(tmp_path, msgs):
    p = tmp_path / "bomb.log.gz"
    z = zlib.compressobj(1, zlib.DEFLATED, 31)
    with open(p, "wb") as f:
        f.write(z.compress("".join(_candump(m) for m in msgs[:50]).encode()))
        chunk = b"0" * (1 << 20)
        for _ in range(400):  # one 400 MB line, 0.4 MB of gzip
            f.write(z.compress(chunk))
        f.write(z.compress(("\n" + "".join(_candump(m) for m in msgs[50:100])).encode()))
        f.write(z.flush())
    grew, rest = _peak_rss_reading(p)
    assert grew < 64, rest  # the line is 400 MB: reading it whole would grow by that much
    n, bad = (int(x) for x in rest.split()[:2])
    assert n == 100 and bad == 1 and "line longer than" in rest
    # and through vdp replay, whose bulk reader hands such a log to the bounded per-frame one
    code = f"import sys\n{_HWM}from vdp.cli import main\nrc = main(sys.argv[1:])\nprint('peak', hwm(), 'rc', rc)\n"
    args = ["replay", str(p), "--profile", str(PROFILE), "--no-progress", "--no-ekf"]
    r = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=120, env=ENV)
    peak = r.stdout.split("peak ")[1].split()
    assert int(peak[0]) < 300 and peak[2] == "0" and "1 malformed log line(s) skipped" in r.stdout, r.stdout


def test_an_endless_plain_line_is_skipped_in_bounded_memory(tmp_path, msgs):
    p = tmp_path / "endless.log"
    with open(p, "wb") as f:
        f.write("".join(_candump(m) for m in msgs[:200]).encode())
        f.truncate(200 << 20)  # then 200 MB of NUL bytes and no newline: sparse, cheap to make
    grew, rest = _peak_rss_reading(p)
    assert grew < 64 and rest.split()[:2] == ["200", "1"], rest  # 200 MB line, read whole: +200


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_a_fifo_or_device_given_as_a_log_is_refused_at_once(tmp_path, kind):
    p = tmp_path / "drive.log"
    if kind == "fifo":
        os.mkfifo(p)
    else:
        p.symlink_to("/dev/zero")
    r = subprocess.run(
        [sys.executable, "-c", "import sys; from vdp.cli import main; sys.exit(main())", "replay", str(p)],
        capture_output=True,
        text=True,
        timeout=60,
        env=ENV,
    )
    want = "a FIFO (named pipe)" if kind == "fifo" else "a character device"
    assert r.returncode == 2 and r.stderr.strip() == f"vdp replay: error: {p}: is {want}, not a log file; " + (
        "copy the log to a regular file first"
    )


def test_garbage_channel_names_do_not_grow_a_table(tmp_path):
    p = tmp_path / "chans.log"
    p.write_text("".join(f"({1e9 + k * 0.001:.6f}) x{k} 0B1#00\n" for k in range(3000)))
    got, st = read(p)
    assert len(st.channels) == 1024 and len(got) == 1024 and st.bad == 3000 - 1024


def test_truncated_log_gz_replays_the_readable_part_through_the_cli(tmp_path, msgs, capsys):
    p = tmp_path / "t.log.gz"
    p.write_bytes(gzip.compress("".join(_candump(m) for m in msgs).encode())[:-3000])
    assert replay_cli(p, tmp_path / "o.json") == 0
    out = capsys.readouterr().out
    assert "gzip stream ends early" in out
    log = json.loads((tmp_path / "o.json").read_text())["log"]
    assert 0.5 * len(msgs) < log["frames"] < len(msgs) and log["damage"]["truncated"]


# -- helpers ---------------------------------------------------------------------------------


def _at(m: can.Message, t: float) -> can.Message:
    return can.Message(
        timestamp=t,
        arbitration_id=m.arbitration_id,
        is_extended_id=m.is_extended_id,
        data=m.data,
        channel=m.channel,
        dlc=m.dlc,
    )


def _candump(m: can.Message) -> str:
    aid = f"{m.arbitration_id:08X}" if m.is_extended_id else f"{m.arbitration_id:03X}"
    return f"({m.timestamp:.6f}) can0 {aid}#{bytes(m.data).hex().upper()}\n"
