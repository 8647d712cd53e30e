"""Bad input in logs, through `vdp replay` (issue 6): nothing valid is lost, nothing crashes.

A short simulated drive is written as a candump log; bad lines of every kind and
error-class frames are mixed in.  Replay must use every valid line before and after
them (the estimates equal those of the clean log), count and report the bad ones with
their line numbers, and with --strict stop at the first one.  Broken files give one
line on stderr and exit status 2, never a traceback.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from vdp.cli import main
from vdp.sim.run import Simulation, write_log

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "profiles" / "paper.toml"

# truncated .gz and .blf files replay their readable part: tests/test_faults_hostile_logs.py
# (line, reason the reader gives); {t} is a time inside the drive
BAD = [
    ("this is not a candump line", "not '(time) channel id#data'"),
    ("({t}) can0 0E1#ABC", "odd number of data hex digits"),
    ("({t}) can0 0E1#00112233445566ZZ", "data is not hex"),
    ("(-1.000000) can0 0E1#0011223344556677", "negative timestamp"),
    ("(nan) can0 0E1#0011223344556677", "non-finite timestamp"),
    ("({back}) can0 0E1#0011223344556677", "timestamp goes backwards"),
]


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("badlogs")
    clean = d / "clean.log"
    write_log(Simulation(PROFILE, "stage1", 3, "realistic", duration=8.0).frames(), clean)
    lines = clean.read_text().splitlines()
    out, bad_at, errors = [], [], 0
    step = len(lines) // (len(BAD) + 3)
    for k, line in enumerate(lines):
        out.append(line)
        slot = k // step
        if k % step == step // 2 and 1 <= slot <= len(BAD):
            t = float(line[1 : line.index(")")])
            text, reason = BAD[slot - 1]
            out.append(text.format(t=f"{t:.6f}", back=f"{t - 100:.6f}"))
            bad_at.append((len(out), reason))
        if k % step == 7:  # an error-class frame whose id bits equal a mapped message's id
            out.append(f"({float(line[1 : line.index(')')]):.6f}) can0 200000B1#0000040000000000")
            errors += 1
    dirty = d / "dirty.log"
    dirty.write_text("\n".join(out) + "\n")
    return {"dir": d, "clean": clean, "dirty": dirty, "good": len(lines), "bad_at": bad_at, "errors": errors}


def replay(path: Path, out: Path, *extra: str) -> int:
    return main(
        ["replay", str(path), "--profile", str(PROFILE), "--json", str(out), "--no-progress", "--no-ekf", *extra]
    )


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vdp replay: error: "), err
    assert "Traceback" not in err
    return lines[0]


def test_bad_lines_are_skipped_counted_and_every_valid_line_is_used(logs, capsys):
    d = logs["dir"]
    assert replay(logs["clean"], d / "clean.json") == 0
    capsys.readouterr()
    assert replay(logs["dirty"], d / "dirty.json") == 0
    assert f"{len(BAD)} malformed log line(s) skipped" in capsys.readouterr().out
    clean, dirty = (json.loads((d / f"{n}.json").read_text()) for n in ("clean", "dirty"))
    log = dirty["log"]
    assert log["bad_lines"] == len(BAD)
    assert [(b["line"], b["reason"]) for b in log["bad_examples"]] == logs["bad_at"]
    # error-class frames are frames: counted as such, never decoded as data
    assert log["frames"] == logs["good"] + logs["errors"] and log["decode"]["error_frames"] == logs["errors"]
    assert log["decode"]["decoded"] == clean["log"]["decode"]["decoded"]
    assert log["decode"]["errors"] == clean["log"]["decode"]["errors"] == {}
    # every valid line before and after the bad ones was used: the very same estimates
    assert clean["parameters"]["l_f"]["samples"] > 250  # 20 ms samples
    for name, e in clean["parameters"].items():
        got = dirty["parameters"][name]
        assert (got["value"], got["std"], got["samples"], got["status"]) == (
            e["value"],
            e["std"],
            e["samples"],
            e["status"],
        ), name


def test_strict_stops_at_the_first_bad_line_with_its_number(logs, capsys):
    assert replay(logs["dirty"], logs["dir"] / "strict.json", "--strict") == 2
    first, reason = logs["bad_at"][0]
    assert f"line {first}: {reason}" in one_line_error(capsys)
    assert not (logs["dir"] / "strict.json").exists()


def test_a_plain_log_cut_mid_line_keeps_every_full_line(logs, capsys):
    # what a power cut leaves: the last line is half written
    cut = logs["dir"] / "cut.log"
    data = logs["clean"].read_bytes()
    cut.write_bytes(data[:-10])  # mid-payload: an odd number of hex digits left
    assert replay(cut, logs["dir"] / "cut.json") == 0
    log = json.loads((logs["dir"] / "cut.json").read_text())["log"]
    assert log["frames"] == logs["good"] - 1 and log["bad_lines"] == 1
    assert log["bad_examples"][0]["line"] == logs["good"]


BROKEN = {
    "missing.log": (None, "no such file"),
    "a-directory.log": ("dir", "is a directory"),
    "empty.log": (b"", "is empty"),
    "empty.blf": (b"", "is empty"),
    "drive.txt": (b"(1.0) can0 0B1#00\n", "unknown log format"),
    "text.blf": (b"(1.0) can0 0B1#00\n" * 50, "not a BLF file"),
    "binary.log": (bytes(range(256)) * 40, "binary data"),
    "candump.asc": (b"(1.0) can0 0B1#00\n" * 50, "no CAN frames"),
    "notgzip.log.gz": (b"(1.0) can0 0B1#00\n", "not gzip-compressed"),
    "header-only.log": (b"date Sat Nov 21 2026\nbase hex timestamps absolute\n" * 60, "not a candump -L log"),
}


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_broken_files_are_one_line_errors(logs, capsys, tmp_path, name):
    content, needle = BROKEN[name]
    p = tmp_path / name
    if content == "dir":
        p.mkdir()
    elif callable(content):
        content(p, logs["clean"])
    elif content is not None:
        p.write_bytes(content)
    assert replay(p, tmp_path / "out.json") == 2
    assert needle in one_line_error(capsys)
    assert not (tmp_path / "out.json").exists()


def test_the_real_command_exits_non_zero_without_a_traceback(tmp_path):
    p = tmp_path / "empty.log"
    p.write_bytes(b"")
    r = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from vdp.cli import main; sys.exit(main())",
            "replay",
            str(p),
            "--profile",
            str(PROFILE),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": str(ROOT / "service")},
    )
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.strip().splitlines() == [f"vdp replay: error: {p}: file is empty"], r.stderr


def test_a_damaged_frame_line_in_an_asc_log_is_counted_and_strict_stops_at_it(logs, capsys):
    """A Vector ASC frame line python-can cannot read is a bad line (counted, its number given,
    --strict stops at it), not one of the events ASC holds besides frames, which are passed over
    as before (statistics, error frames, comments).  It had been passed over without a word."""
    import can

    d = logs["dir"]
    asc = d / "drive.asc"
    with can.ASCWriter(str(asc)) as w:
        for m in Simulation(PROFILE, "stage1", 3, "realistic", duration=4.0).frames():
            w.on_message_received(m)
    lines = asc.read_text().splitlines()
    frames = [i for i, ln in enumerate(lines) if " Rx " in ln or " Tx " in ln]
    k = frames[len(frames) // 2]
    lines[k] = lines[k][: lines[k].index("x ") + 2] + " garbage!!"  # the id and direction kept
    lines.insert(frames[10], "   0.010000 1  Statistic: D 0 R 0 XD 0 XR 0 E 0 O 0 B 0.00%")
    lines.insert(frames[11], "// a comment")
    bad = d / "bad.asc"
    bad.write_text("\n".join(lines) + "\n")
    assert replay(bad, d / "asc.json") == 0
    log = json.loads((d / "asc.json").read_text())["log"]
    assert log["bad_lines"] == 1 and log["bad_examples"][0]["line"] == k + 3  # (two lines inserted before it)
    capsys.readouterr()
    assert replay(bad, d / "asc-strict.json", "--strict") == 2
    assert f"line {k + 3}: unreadable .asc line" in one_line_error(capsys)
