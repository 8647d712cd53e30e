"""The one candump parser (vdp.io.scan): compiled, against its own source run as Python, and
against the per-frame reader's tolerant rules (CandumpReader.slow), the reference for a line.

A line the scan accepts must be read exactly as the tolerant rules read it (same time, id,
data, channel, direction); a line it refuses goes to those rules (the per-frame reader) or
sends the whole log there (the bulk reader).  The scan may refuse more than it must, never
read a line differently.
"""

import gzip
import os
import tempfile

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from vdp.io import scan
from vdp.io.formats import candump
from vdp.io.logs import EXT_KEY, open_log
from vdp.sim.run import simulate, write_log

pytestmark = pytest.mark.skipif(not scan.available(), reason="the compiled parse needs numba")


def test_the_ext_key_is_the_readers():
    assert scan._EXT_KEY == EXT_KEY


def same_scan(buf: bytes, stop: bool) -> int:
    """The compiled scan and its Python source agree on ``buf``; the rows compared."""
    got, want = scan.lines(buf, stop), scan.reference(buf, stop)
    assert got[:3] == want[:3]
    assert np.array_equal(got[3], want[3])
    ok = got[3] == scan.OK
    for g, w in zip(got[4:], want[4:]):
        assert g.dtype == w.dtype and np.array_equal(g[ok], w[ok])
    return int(ok.sum())


def cut(raw: bytes, size: int) -> list[bytes]:
    out, lo = [], 0
    while lo < len(raw):  # blocks cut at a line's end, as the readers cut them
        hi = raw.rfind(b"\n", 0, lo + size) + 1
        out.append(raw[lo:hi])
        lo = hi
    return out


@pytest.fixture(scope="module")
def sim_log(repo_root, tmp_path_factory):
    from vdp.profile import load_profile

    prof = load_profile(repo_root / "profiles" / "paper.toml")
    frames, _ = simulate(prof, "paper", seed=2, noise="realistic", duration=8.0, extra_ids=4, extra_rate=100.0)
    path = tmp_path_factory.mktemp("scan") / "a.log"
    write_log(frames, path)
    return path


def test_the_compiled_scan_is_its_source_on_a_simulated_log(sim_log):
    blocks = cut(sim_log.read_bytes(), 20_000)
    rows = sum(same_scan(b, stop) for b in blocks[:3] for stop in (True, False))
    assert rows > 500  # (the Python source is slow: three blocks, both modes)


def test_the_compiled_scan_is_its_source_on_a_real_cars_bus(repo_root):
    """The RAV4's 15 s: four bus channels, short frames, extended ids of the recording device."""
    raw = gzip.decompress((repo_root / "tests" / "data" / "rav4-2018-highway-15s.log.gz").read_bytes())
    blocks = cut(raw, 20_000)
    assert sum(same_scan(b, stop) for b in blocks[:2] for stop in (True, False)) > 300
    got = scan.lines(raw, True)
    assert got[0] == scan.OK and len({int(c) for c in got[12]}) > 1  # every line read; several channels


def frames(path, fast: bool, monkeypatch) -> tuple:
    """What the per-frame reader gives: with the scan, or every line by the tolerant rules."""
    monkeypatch.setattr(candump, "_use_scan", lambda size: fast)
    src = open_log(path)
    src.keep_ids({0x123, 0x7FF})
    try:
        got = [
            (m.timestamp, m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.is_error_frame, m.channel)
            + (m.dlc, bytes(m.data), m.is_fd, m.is_rx, m.bitrate_switch, m.error_state_indicator)
            for m in src
        ]
    except Exception as exc:  # the same error both ways is the same reading
        got = [repr(exc)]
    s = src.stats
    return got, s.lines, s.frames, s.skipped, s.bad, dict(s.reasons), dict(s.passed_over), s.error_frames


@pytest.mark.parametrize("which", ["sim", "rav4"])
def test_the_per_frame_reader_reads_alike_with_and_without_the_scan(which, sim_log, repo_root, monkeypatch):
    path = sim_log if which == "sim" else repo_root / "tests" / "data" / "rav4-2018-highway-15s.log.gz"
    fast, slow = frames(path, True, monkeypatch), frames(path, False, monkeypatch)
    # lines read, frames handed out, frames of ids nobody decodes counted
    assert fast == slow and fast[1] > 4000 and fast[2] > 5 and sum(fast[6].values()) > 4000


LINES = [
    b"(1.000000) can0 123#00",
    b"(1711.250000) vcan1 1ABCDEF0#0102030405060708 R",
    b"(0.5) x 7FF#",
    b"(12.) can0 000#DEADBEEF t",
    b"(1.000000) can0 123#00\r",
]
BAD = [
    b"\r",
    b"(1.0)\tcan0 123#00",
    b"(1.0) can0 123#00 R T",
    b"(1.0) can0 123#00 X",
    b"(1.0) can0 123#00 RR",
    b"1.0 can0 123#00",
    b"(10) can0 123#00",
    b"(1.0x) can0 123#00",
    b"(.5) can0 123#00",
    b"(12345678901234567.89) can0 123#00",
    b"(9999999999.999999) can0 123#00",
    b"(1.0) can0 123#R",
    b"(1.0) can0 123##0011",
    b"(1.0) can0 12#00",
    b"(1.0) can0 1234#00",
    b"(1.0) can0 123#0",
    b"(1.0) can0 123#001122334455667788",
    b"(1.0) can0 12G#00",
    b"(1.0) can0 800#00",
    b"(1.0) can0 2FFFFFFF#00",
    b"(1.0) can0 123#0G",
    b"(1.0) can012345 123#00",
    b"(1.0)  can0 123#00",
    b"(1.0) can0 123#00 ",
    b"(1.0) ca\rn0 123#00",
    b"(1.0) ca\x00n0 123#00",
]


@pytest.mark.parametrize("line", LINES)
def test_good_lines_are_accepted(line):
    buf = b"\n".join([line, b"", line]) + b"\n"
    r = scan.lines(buf, True)
    assert r[0] == scan.OK and list(r[6]) == [1, 3]
    assert list(scan.lines(buf, False)[3]) == [scan.OK, scan.EMPTY, scan.OK]
    same_scan(buf, True)


@pytest.mark.parametrize("line", BAD)
def test_bad_lines_are_refused(line):
    buf = b"(0.5) can0 100#00\n" + line + b"\n"
    got = scan.lines(buf, True)
    assert got[0] != scan.OK and got[1] == 2 and not len(got[3])
    assert scan.lines(buf, False)[3][1] != scan.OK
    same_scan(buf, True)
    same_scan(buf, False)


PIECES = st.sampled_from(
    [b"(", b")", b" ", b".", b"#", b"0", b"7", b"9", b"A", b"f", b"G", b"R", b"T", b"can0", b"\r", b"\t", b"-", b"x"]
)
_DIR = tempfile.mkdtemp(prefix="vdp-scan-")


@settings(max_examples=300, deadline=None)
@given(
    base=st.sampled_from(LINES),
    cut=st.integers(0, 60),
    insert=st.lists(PIECES, max_size=3),
    drop=st.integers(0, 3),
)
@example(base=LINES[0], cut=1, insert=[b"0"], drop=0)
@example(base=LINES[0], cut=12, insert=[b"\r"], drop=0)
def test_a_mutated_line_is_never_read_differently(base, cut, insert, drop):
    """Whatever the tolerant rules make of a line, the scan makes the same, or refuses it."""
    cut = min(cut, len(base))
    line = base[:cut] + b"".join(insert) + base[cut + drop :]
    path = os.path.join(_DIR, "m.log")
    with open(path, "wb") as f:
        f.write(b"(0.5) can0 100#00\n" + line + b"\n(9.0) can0 7FF#01\n")
    with pytest.MonkeyPatch.context() as mp:
        fast, slow = frames(path, True, mp), frames(path, False, mp)
    assert fast == slow, line
    same_scan(b"(0.5) can0 100#00\n" + line + b"\n", False)
