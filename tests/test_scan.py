"""The compiled candump parse (vdp.io.scan) against numpy's (bulk.BulkSource._parse), the reference.

The scan may be stricter than numpy's parse, never laxer: a line it accepts must be a line
numpy's accepts, parsed to the same numbers; a line numpy's refuses it must refuse too
(both send the log to the per-frame reader, whose rules are the reference for damage).
"""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from vdp.io import scan
from vdp.io.bulk import BulkSource, Irregular
from vdp.io.logs import EXT_KEY
from vdp.sim.run import simulate, write_log

pytestmark = pytest.mark.skipif(not scan.available(), reason="the compiled parse needs numba")


def numpy_parse(buf: bytes, lineno: int = 0):
    try:
        return BulkSource._parse(buf, lineno)
    except Irregular as exc:
        return str(exc)


def scanned(buf: bytes, lineno: int = 0):
    code, bad, n_lines, *arrays = scan.lines(buf)
    if code:
        return scan.MESSAGES[code]
    arrays[0] = arrays[0] + lineno
    return (n_lines, *arrays)


def same(a, b) -> bool:
    if isinstance(a, str) or isinstance(b, str):
        return isinstance(a, str) and isinstance(b, str)
    return a[0] == b[0] and all(np.array_equal(x, y) for x, y in zip(a[1:], b[1:]))


def test_the_ext_key_is_the_readers():
    assert scan._EXT_KEY == EXT_KEY


def test_a_simulated_log_parses_to_numpys_arrays_block_by_block(repo_root, tmp_path):
    from vdp.profile import load_profile

    prof = load_profile(repo_root / "profiles" / "paper.toml")
    frames, _ = simulate(prof, "paper", seed=2, noise="realistic", duration=8.0, extra_ids=4, extra_rate=100.0)
    path = tmp_path / "a.log"
    write_log(frames, path)
    raw = path.read_bytes()
    lineno = lo = 0
    while lo < len(raw):  # blocks cut at a line's end, as the reader cuts them
        hi = raw.rfind(b"\n", 0, lo + 60_000) + 1
        block, lo = raw[lo:hi], hi
        want, got = numpy_parse(block, lineno), scanned(block, lineno)
        assert not isinstance(want, str) and same(want, got)
        lineno += want[0]
    assert lineno > 5000 and len(got[1]) > 100  # every block of a 8-s drive compared


def test_a_real_cars_bus_parses_to_numpys_arrays(repo_root):
    """The RAV4's 15 s (four bus channels, short frames, extended ids of the recording device):
    the scan's arrays are numpy's, block by block, on a bus vdp did not write."""
    import gzip

    raw = gzip.decompress((repo_root / "tests" / "data" / "rav4-2018-highway-15s.log.gz").read_bytes())
    lineno = lo = blocks = 0
    while lo < len(raw):
        hi = raw.rfind(b"\n", 0, lo + 200_000) + 1
        block, lo = raw[lo:hi], hi
        want, got = numpy_parse(block, lineno), scanned(block, lineno)
        assert not isinstance(want, str) and same(want, got)
        lineno += want[0]
        blocks += 1
    assert lineno > 30_000 and blocks > 3 and len({int(c) for c in got[6]}) > 1  # several channels


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
]


@pytest.mark.parametrize("line", LINES)
def test_good_lines_parse_alike(line):
    buf = b"\n".join([line, b"", line]) + b"\n"
    want, got = numpy_parse(buf, 7), scanned(buf, 7)
    assert not isinstance(want, str), want
    assert same(want, got) and list(got[1]) == [8, 10]


@pytest.mark.parametrize("line", BAD)
def test_bad_lines_are_refused_alike(line):
    buf = b"(0.5) can0 100#00\n" + line + b"\n"
    want, got = numpy_parse(buf), scanned(buf)
    assert isinstance(want, str) and isinstance(got, str), (want, got)


PIECES = st.sampled_from(
    [b"(", b")", b" ", b".", b"#", b"0", b"7", b"9", b"A", b"f", b"G", b"R", b"T", b"can0", b"\r", b"\t", b"-", b"x"]
)


@settings(max_examples=400, deadline=None)
@given(
    base=st.sampled_from(LINES),
    cut=st.integers(0, 60),
    insert=st.lists(PIECES, max_size=3),
    drop=st.integers(0, 3),
)
@example(base=LINES[0], cut=1, insert=[b"0"], drop=0)
def test_a_mutated_line_is_never_read_differently(base, cut, insert, drop):
    """Whatever numpy's parse makes of a line, the scan makes the same, or refuses it."""
    cut = min(cut, len(base))
    line = base[:cut] + b"".join(insert) + base[cut + drop :]
    buf = b"(0.5) can0 100#00\n" + line + b"\n"
    want, got = numpy_parse(buf), scanned(buf)
    if isinstance(got, str):
        return  # refused: the per-frame reader decides (stricter is allowed)
    assert not isinstance(want, str), f"the scan accepted {line!r}, numpy's parse refused it: {want}"
    assert same(want, got), line
