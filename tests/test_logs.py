"""open_log: the tolerant candump parser, other formats, broken files, progress."""

from __future__ import annotations

import gzip
import importlib.util
import json
import math
import shutil
from pathlib import Path

import can
import pytest

from conftest import REAL
from vdp import channels
from vdp.errors import LogFormatError
from vdp.io.decoder import FrameDecoder
from vdp.io.logs import channel_keys, open_log
from vdp.profile import load_profile

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data"
RAV4_LOG = REAL / "rav4-2018-highway-60s.log.gz"
RAV4_DBC = REAL / "toyota_new_mc_pt_generated.dbc"
DEG = math.pi / 180.0
T0 = 1700000000.0


def read(path, **kw):
    with open_log(path, **kw) as src:
        return list(src), src


def write(tmp_path, text, name="x.log"):
    p = tmp_path / name
    p.write_text(text)
    return p


# -- golden file ----------------------------------------------------------------

# tests/data/golden.log, paper profile (dbc/vdp.dbc, all Intel byte order).  Values by hand:
#  1 0B1 E803 D007: FL 0x03E8=1000*0.004 = 4 rad/s, FR 0x07D0=2000 -> 8;  counter 0,
#        checksum 0xFF-((E8+03+D0+07 + B1) & 0xFF) = 0xFF-(627&0xFF=0x73) = 0x8C
#  2 0B2 E204 DC05: RL 1250*0.004 = 5, RR 1500 -> 6; checksum 0x86
#  3 0C0 9001 38FF: front 400*0.5 = 200 N*m, rear 0xFF38=-200 -> -100; checksum 0x77
#  4 0D0 9600: steering wheel 150*0.1 = 15 deg, / ratio 15 = 1 deg road wheel; checksum 0x99
#  5 0E0 DC05 30F8: ax 1500*0.001 = 1.5, ay 0xF830=-2000 -> -2.0 m/s^2; checksum 0x16
#  6 0E1 C800 70FE: yaw 200*0.005 = 1 deg/s, roll 0xFE70=-400 -> -2 deg/s; checksum 0xE8
#  7 1F0 3930: GNSS speed 0x3039=12345*0.001 = 12.345 m/s (no checks on GNSS)
#  8-13 bad lines: garbage, odd hex, non-hex, 9 bytes, backwards time, nan time
# 14 0E1 9CFF 0000, counter 1: yaw 0xFF9C=-100 -> -0.5 deg/s, roll 0; checksum 0x82
# 15 7DF: unknown id;  16: error frame;  17 0B1#R: remote frame
# 18 0E1 counter 2 with checksum 00 (should be 0x81): rejected
# 19 0E1 2C01 1400, counter 3 (counting on past the bad checksum): yaw 300 -> 1.5, roll 20 -> 0.1 deg/s
# 20 0B1 with 7 bytes: wrong length;  21 1F0 FFFF: 65.535 m/s > DBC max 65: range
# 22 0D0 D4FE counter 1, ' R' suffix: -300*0.1 = -30 deg wheel -> -2 deg road
# 23 can1: another bus channel
GOLDEN_SAMPLES = [
    (T0 + 0.000, "wheel_speed_fl", 4.0),
    (T0 + 0.000, "wheel_speed_fr", 8.0),
    (T0 + 0.001, "wheel_speed_rl", 5.0),
    (T0 + 0.001, "wheel_speed_rr", 6.0),
    (T0 + 0.002, "wheel_torque_front", 200.0),
    (T0 + 0.002, "wheel_torque_rear", -100.0),
    (T0 + 0.003, "steering_angle", 1.0 * DEG),
    (T0 + 0.004, "accel_x", 1.5),
    (T0 + 0.004, "accel_y", -2.0),
    (T0 + 0.005, "yaw_rate", 1.0 * DEG),
    (T0 + 0.005, "roll_rate", -2.0 * DEG),
    (T0 + 0.006, "speed", 12.345),
    (T0 + 0.020, "yaw_rate", -0.5 * DEG),
    (T0 + 0.020, "roll_rate", 0.0),
    (T0 + 0.040, "yaw_rate", 1.5 * DEG),
    (T0 + 0.040, "roll_rate", 0.1 * DEG),
    (T0 + 0.060, "steering_angle", -2.0 * DEG),
]


def test_golden_log_reading():
    frames, src = read(DATA / "golden.log", channel="can0")
    st = src.stats
    assert (st.lines, st.frames, st.skipped, st.error_frames, st.bad) == (23, 16, 1, 1, 6)
    assert [(b.line, b.reason) for b in st.examples] == [
        (8, "not '(time) channel id#data'"),
        (9, "odd number of data hex digits"),
        (10, "data is not hex"),
        (11, "9 data bytes in a classic frame (max 8)"),
        (12, "timestamp goes backwards"),
        (13, "non-finite timestamp"),
    ]
    assert st.examples[2].text == "(1700000000.011000) can0 0E1#C80070FE0000ZZE8"
    assert st.as_dict()["bad_reasons"]["timestamp goes backwards"] == 1
    assert st.channels == {"can0", "can1"}
    assert [f.arbitration_id for f in frames[:7]] == [0xB1, 0xB2, 0xC0, 0xD0, 0xE0, 0xE1, 0x1F0]
    assert frames[8].arbitration_id == 0x7DF and frames[9].is_error_frame and frames[10].is_remote_frame
    assert frames[-1].is_rx is True and frames[-1].data == bytearray.fromhex("D4FE00000000015C")


def test_golden_log_decoding():
    frames, _ = read(DATA / "golden.log", channel="can0")
    dec = FrameDecoder(load_profile(ROOT / "profiles" / "paper.toml"))
    got = [(f.timestamp, channels.NAMES[i], v) for f in frames for i, v in dec.decode(f)]
    assert len(got) == len(GOLDEN_SAMPLES)
    for (t, name, v), (t_want, name_want, v_want) in zip(got, GOLDEN_SAMPLES):
        assert name == name_want and t == pytest.approx(t_want, abs=1e-7)
        assert v == pytest.approx(v_want, rel=1e-12, abs=1e-15), name
    d = dec.stats.as_dict()
    assert d["errors"] == {"0x0B1": {"dlc": 1, "remote": 1}, "0x0E1": {"checksum": 1}, "0x1F0": {"range": 1}}
    assert d["unknown_ids"] == [{"id": "0x7DF", "count": 1}] and d["error_frames"] == 1
    assert d["frames"] == 16 and d["decoded"] == 10


def test_channel_filter():
    frames, src = read(DATA / "golden.log", channel="can1")
    assert [(f.channel, f.arbitration_id) for f in frames] == [("can1", 0xB1)]
    assert src.stats.skipped == 21 and src.stats.bad == 1  # the garbage line is not a frame of any channel
    assert channel_keys("can1") == {"can1", "1", 1} and channel_keys("vcan") == {"vcan"}


# -- candump parsing -----------------------------------------------------------------


def test_candump_frame_kinds(tmp_path):
    p = write(
        tmp_path,
        "\n".join(
            [
                "(1.000000) can0 123#DEADBEEF",
                "(1.000001) vcan1 18FEF100#0102 T",
                "(1.000002) can0 1FFFFFFF#",
                "(1.000003) can0 123##1" + "AA" * 12,
                "(1.000004) can0 123##3",
                "(1.000005) can0 123#R",
                "(1.000006) can0 00000123#R5",
                "(1.000007) can0 20000004#0000040000000000",
                "(1.000008) can0 321#1122334455667788_C",
                "",
                "   ",
                "(1.000009) 0 7FF#00",
                "(1.000010) can0 20000004#0000040000000000",  # a known error id is still an error frame
            ]
        )
        + "\n",
    )
    frames, src = read(p)
    assert src.stats.bad == 0 and src.stats.frames == 11 and src.stats.error_frames == 2
    f = frames
    assert (f[0].arbitration_id, f[0].is_extended_id, f[0].data, f[0].dlc, f[0].channel, f[0].is_rx) == (
        0x123,
        False,
        bytearray.fromhex("DEADBEEF"),
        4,
        "can0",
        True,
    )
    assert (f[1].arbitration_id, f[1].is_extended_id, f[1].channel, f[1].is_rx) == (0x18FEF100, True, "vcan1", False)
    assert (f[2].arbitration_id, f[2].dlc, f[2].data) == (0x1FFFFFFF, 0, bytearray())
    assert f[3].is_fd and f[3].bitrate_switch and not f[3].error_state_indicator and len(f[3].data) == 12
    assert f[4].is_fd and f[4].bitrate_switch and f[4].error_state_indicator and f[4].dlc == 0
    assert f[5].is_remote_frame and f[5].dlc == 0 and not f[5].is_extended_id
    assert f[6].is_remote_frame and f[6].dlc == 5 and f[6].is_extended_id
    assert f[7].is_error_frame and f[7].arbitration_id == 0x4 and f[7].data[2] == 0x04
    assert f[8].data == bytearray.fromhex("1122334455667788") and not f[8].is_error_frame
    assert f[9].channel == 0 and f[9].arbitration_id == 0x7FF
    assert f[10].is_error_frame and f[10].arbitration_id == 0x4
    assert [x.timestamp for x in f] == [pytest.approx(1.0 + k * 1e-6, abs=1e-9) for k in range(11)]
    assert all(not x.is_fd for x in f if x not in (f[3], f[4]))


def test_same_messages_as_python_can(tmp_path):
    """On valid files our parser and python-can's agree field by field."""
    p = tmp_path / "pc.log"
    msgs = [
        can.Message(
            timestamp=T0 + 0.001 * k,
            arbitration_id=(0x18DA00F1 + k) if k % 3 == 0 else 0x100 + k,
            is_extended_id=k % 3 == 0,
            data=bytes(range(k % 9)),
            is_rx=k % 2 == 0,
            channel="can0" if k % 4 else "can1",
        )
        for k in range(40)
    ]
    msgs.append(can.Message(timestamp=T0 + 1, arbitration_id=0x7A0, is_extended_id=False, is_remote_frame=True))
    msgs.append(
        can.Message(
            timestamp=T0 + 2,
            arbitration_id=0x7A1,
            is_extended_id=False,
            is_fd=True,
            bitrate_switch=True,
            data=bytes(range(16)),
        )
    )
    with can.Logger(p) as w:
        for m in msgs:
            w.on_message_received(m)
    ours, _ = read(p)
    theirs = list(can.LogReader(p))
    fields = (
        "timestamp",
        "arbitration_id",
        "is_extended_id",
        "is_remote_frame",
        "is_error_frame",
        "channel",
        "dlc",
        "data",
        "is_fd",
        "is_rx",
        "bitrate_switch",
        "error_state_indicator",
    )
    assert len(ours) == len(theirs) == len(msgs)
    for a, b in zip(ours, theirs):
        assert {k: getattr(a, k) for k in fields} == {k: getattr(b, k) for k in fields}


GOOD_A = "(1700000000.000000) can0 0B1#0011223344556677"
GOOD_B = "(1700000000.002000) can0 18FEF100#AABB"
BAD_LINES = {
    "garbage": ("hello world", "not '(time) channel id#data'"),
    "five fields": ("(1700000000.001000) can0 123#00 R extra", "not '(time) channel id#data'"),
    "bad direction": ("(1700000000.001000) can0 123#00 X", "not '(time) channel id#data'"),
    "no parentheses": ("1700000000.001000 can0 123#00", "bad timestamp"),
    "timestamp text": ("(soon) can0 123#00", "bad timestamp"),
    "negative time": ("(-1.000000) can0 123#00", "negative timestamp"),
    "nan time": ("(nan) can0 123#00", "non-finite timestamp"),
    "inf time": ("(inf) can0 123#00", "non-finite timestamp"),
    "backwards": ("(1699999999.999000) can0 123#00", "timestamp goes backwards"),
    "no hash": ("(1700000000.001000) can0 12300", "no '#' between id and data"),
    "id length": ("(1700000000.001000) can0 1234#00", "id is not 3 or 8 hex digits"),
    "id not hex": ("(1700000000.001000) can0 12G#00", "id is not hex"),
    "id sign": ("(1700000000.001000) can0 +12#00", "id is not hex"),
    "std id too big": ("(1700000000.001000) can0 800#00", "standard id above 0x7FF"),
    "ext id flags": ("(1700000000.001000) can0 40000000#00", "extended id above 0x1FFFFFFF"),
    "odd payload": ("(1700000000.001000) can0 123#ABC", "odd number of data hex digits"),
    "non-hex payload": ("(1700000000.001000) can0 123#ABCX", "data is not hex"),
    "dlc > 8": ("(1700000000.001000) can0 123#" + "00" * 9, "9 data bytes in a classic frame (max 8)"),
    "fd length": ("(1700000000.001000) can0 123##0" + "00" * 9, "CAN FD length 9 is not a valid FD length"),
    "fd flags": ("(1700000000.001000) can0 123##Z00", "CAN FD flags are not one hex digit"),
    "remote length": ("(1700000000.001000) can0 123#R9", "bad remote frame length"),
    "raw dlc suffix": ("(1700000000.001000) can0 123#0011_C", "bad raw DLC suffix"),
    "binary junk": ("\x7f\x01\x02 \x03", "not '(time) channel id#data'"),
}


@pytest.mark.parametrize("case", sorted(BAD_LINES))
def test_bad_line_skipped_counted_strict(tmp_path, case):
    line, reason = BAD_LINES[case]
    p = write(tmp_path, f"{GOOD_A}\n{line}\n{GOOD_B}\n")
    frames, src = read(p)
    assert [f.arbitration_id for f in frames] == [0xB1, 0x18FEF100]
    assert frames[1].data == bytearray(b"\xaa\xbb")
    st = src.stats
    assert (st.lines, st.frames, st.bad) == (3, 2, 1)
    assert [(b.line, b.reason) for b in st.examples] == [(2, reason)]
    assert st.reasons == {reason: 1}
    with pytest.raises(LogFormatError, match=rf"x\.log: line 2: {__import__('re').escape(reason)}"):
        read(p, strict=True)


def test_the_skipped_lines_warning_names_the_first_ones_line(tmp_path, caplog):
    p = write(tmp_path, f"{GOOD_A}\n(1700000000.001000) can0 123#ABC\n{GOOD_B}\n")
    with caplog.at_level("WARNING", logger="vdp.io.logs"):
        read(p)
    assert "skipped 1 bad line (odd number of data hex digits: 1; first at line 2)" in caplog.text


def test_examples_capped_counts_exact(tmp_path):
    lines = [GOOD_A] + ["(1700000000.001000) can0 123#XYZW"] * 150 + [GOOD_B]
    frames, src = read(write(tmp_path, "\n".join(lines) + "\n"))
    assert len(frames) == 2 and src.stats.bad == 150 and len(src.stats.examples) == 100
    assert src.stats.examples[-1].line == 101


def test_clock_jump_back_is_followed(tmp_path):
    lines = [f"({T0 + 100 + k:.6f}) can0 100#00" for k in range(3)]
    lines += [f"({T0 + k * 0.01:.6f}) can0 200#01" for k in range(15)]
    frames, src = read(write(tmp_path, "\n".join(lines) + "\n"))
    # 9 lines behind the clock are dropped; the 10th in a row says the clock really jumped.
    assert [f.arbitration_id for f in frames] == [0x100] * 3 + [0x200] * 6
    assert src.stats.bad == 9 and src.stats.resyncs == 1
    assert frames[3].timestamp == pytest.approx(T0 + 0.09)


def test_single_future_glitch_costs_few_lines(tmp_path):
    lines = [f"({T0 + k * 0.01:.6f}) can0 100#00" for k in range(5)]
    lines.append(f"({T0 + 1e6:.6f}) can0 100#00")
    lines += [f"({T0 + 0.05 + k * 0.01:.6f}) can0 100#00" for k in range(30)]
    frames, src = read(write(tmp_path, "\n".join(lines) + "\n"))
    assert len(frames) == 36 - 9 and src.stats.resyncs == 1


# -- broken files -------------------------------------------------------------------


def test_missing_directory_unknown_suffix(tmp_path):
    with pytest.raises(LogFormatError, match="no such file"):
        open_log(tmp_path / "nope.log")
    (tmp_path / "d.log").mkdir()
    with pytest.raises(LogFormatError, match="is a directory"):
        open_log(tmp_path / "d.log")
    with pytest.raises(LogFormatError, match=r"unknown log format '\.txt'; supported: \.log"):
        open_log(write(tmp_path, GOOD_A, "x.txt"))
    with pytest.raises(LogFormatError, match="unknown log format"):
        open_log(write(tmp_path, GOOD_A, "noext"))


@pytest.mark.parametrize("name", ["e.log", "e.asc", "e.blf", "e.trc", "e.csv", "e.mf4"])
def test_empty_file(tmp_path, name):
    (tmp_path / name).write_bytes(b"")
    with pytest.raises(LogFormatError, match="is empty"):
        open_log(tmp_path / name)


@pytest.mark.parametrize("name", ["e.log.gz", "e.blf.gz"])
def test_empty_gzip(tmp_path, name):
    with gzip.open(tmp_path / name, "wb"):
        pass
    with pytest.raises(LogFormatError, match="is empty"):
        open_log(tmp_path / name)


def test_only_blank_lines(tmp_path):
    with pytest.raises(LogFormatError, match="no CAN frames in 3 lines"):
        read(write(tmp_path, "\n\n\n"))


def _big_log(path: Path, n: int = 20000) -> list[str]:
    lines = [f"({T0 + k * 0.001:.6f}) can0 {0x100 + k % 50:03X}#{k % 256:02X}{k % 199:02X}00112233" for k in range(n)]
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "wt") as f:
        f.write("\n".join(lines) + "\n")
    return lines


def test_truncated_gzip_replays_what_is_there_and_says_what_was_lost(tmp_path):
    p = tmp_path / "t.log.gz"
    lines = _big_log(p)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    got, src = read(p)
    st = src.stats
    assert 1000 < len(got) < 20000 and st.truncated and st.damaged == 1
    assert [f"({m.timestamp:.6f}) can0 {m.arbitration_id:03X}#{m.data.hex().upper()}" for m in got] == lines[: len(got)]
    assert "gzip stream ends early" in st.damage[0].reason and f"{len(got):,} frames read" in st.damage_summary()


def test_corrupt_gzip_body_replays_what_is_before_it(tmp_path):
    p = tmp_path / "c.log.gz"
    _big_log(p)
    data = bytearray(p.read_bytes())
    data[len(data) // 2 : len(data) // 2 + 64] = b"\xff" * 64
    p.write_bytes(bytes(data))
    got, src = read(p)
    assert 1000 < len(got) < 20000 and src.stats.damaged == 1
    assert "corrupt gzip data" in src.stats.damage[0].reason
    # the reader cannot tell what the damage cost: never "nothing skipped"
    summary = src.stats.damage_summary()
    assert "how much was lost is unknown" in summary and "nothing skipped" not in summary, summary
    assert "found at byte" in summary
    with pytest.raises(LogFormatError, match="damaged at byte"):
        read(p, strict=True)


def test_damage_summary_counts_the_garbage_a_broken_stream_let_through():
    """A gzip stream broken early can hand out garbage lines before its end fails the CRC check:
    the summary counts them beside the damage, whose cost the reader cannot know."""
    from vdp.io.logs import LogStats

    st = LogStats()
    for n in range(215):
        st.add_bad(100 + n, "not a candump line", "\x8f\x02garbage")
    st.add_damage(297_329, -1, "corrupt gzip data (CRC check failed) after line 10977; nothing after it is readable")
    st.frames = 10_762
    assert st.damage_summary() == (
        "damaged in 1 place(s), how much was lost is unknown; 10,762 frames read; 215 bad lines rejected in all; "
        "first: corrupt gzip data (CRC check failed) after line 10977; nothing after it is readable "
        "(found at byte 297,329 of the file)"
    )


def test_truncated_plain_log_is_tolerated(tmp_path):
    p = tmp_path / "cut.log"
    _big_log(p, 100)
    data = p.read_bytes()
    p.write_bytes(data[:-20])  # cut inside the last line
    frames, src = read(p)
    assert len(frames) == 99 and src.stats.bad == 1 and src.stats.examples[0].line == 100


def _frames_for_formats() -> list[can.Message]:
    msgs = [
        can.Message(
            timestamp=T0 + 0.123456 + k * 0.0105,
            arbitration_id=0x100 + k,
            is_extended_id=False,
            data=bytes((k * 7 + j) % 256 for j in range(k % 9)),
            channel=0,
        )
        for k in range(30)
    ]
    msgs.append(
        can.Message(timestamp=T0 + 1.0, arbitration_id=0x18FEF100, is_extended_id=True, data=b"\x01\x02\x03", channel=0)
    )
    msgs.append(
        can.Message(
            timestamp=T0 + 1.5, arbitration_id=0x123, is_extended_id=False, is_remote_frame=True, dlc=0, channel=0
        )
    )
    return msgs


def test_truncated_blf_replays_what_is_there(tmp_path):
    p = tmp_path / "t.blf"
    with can.Logger(p) as w:
        for k in range(3000):
            w.on_message_received(
                can.Message(timestamp=T0 + k * 0.001, arbitration_id=k % 2000, is_extended_id=False, data=bytes(8))
            )
    data = p.read_bytes()
    p.write_bytes(data[: len(data) * 2 // 3])
    got, src = read(p)
    assert 1000 < len(got) < 3000 and src.stats.truncated
    assert [m.arbitration_id for m in got] == [k % 2000 for k in range(len(got))]
    assert "the file ends early" in src.stats.damage_summary()


@pytest.mark.parametrize(
    "name,content,pattern",
    [
        ("w.blf", "(1.0) can0 123#00\n", "not a BLF file"),
        ("w.mf4", "(1.0) can0 123#00\n", "not an MF4 file"),
        ("w.log", b"LOGG\x00\x00\x01\x02" * 100, "binary data in a .log text log"),
        ("w.asc", "(1.0) can0 123#00\n" * 5, "no CAN frames"),
        ("w.trc", "(1.0) can0 123#00\n" * 5, r"not a valid \.trc file: no CAN frames.*ValueError"),
        ("w.log", "date Sat Nov 21 2026\nbase hex timestamps absolute\n" * 60, "not a candump -L log: the first 100"),
        ("w.log.gz", "(1.0) can0 123#00\n", "named .gz but is not gzip-compressed"),
        (
            "w.csv",
            "timestamp,arbitration_id,extended,remote,error,dlc,data\n1.0,0x123,0,0\n",
            r"not a valid \.csv file",
        ),
    ],
)
def test_wrong_format(tmp_path, name, content, pattern):
    p = tmp_path / name
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(LogFormatError, match=pattern):
        read(p)


def test_gzip_without_gz_name_is_read(tmp_path):
    p = tmp_path / "z.log"
    with gzip.open(p, "wt") as f:
        f.write(GOOD_A + "\n" + GOOD_B + "\n")
    frames, src = read(p)
    assert len(frames) == 2 and src.compressed


def test_mf4_needs_asammdf(tmp_path):
    if importlib.util.find_spec("asammdf") is not None:
        pytest.skip("asammdf is installed; the format round trip covers .mf4")
    p = tmp_path / "m.mf4"
    p.write_bytes(b"MDF     4.10    " + bytes(200))
    with pytest.raises(LogFormatError, match="needs asammdf"):
        open_log(p)


# -- the same frames in every format ---------------------------------------------------

FORMATS = [".log", ".asc", ".blf", ".trc", ".csv", ".log.gz", ".asc.gz", ".blf.gz", ".trc.gz", ".csv.gz"]
if importlib.util.find_spec("asammdf") is not None:
    FORMATS.append(".mf4")


@pytest.mark.parametrize("suffix", FORMATS)
def test_formats_read_back_identically(tmp_path, suffix):
    msgs = _frames_for_formats()
    if ".trc" in suffix:
        msgs = [m for m in msgs if not m.is_remote_frame]  # python-can's TRC writer cannot write them
    p = tmp_path / f"f{suffix}"
    if suffix == ".blf.gz":  # python-can cannot write it; a gzipped .blf is still a fair input
        plain = tmp_path / "f.blf"
        with can.Logger(plain) as w:
            for m in msgs:
                w.on_message_received(m)
        with open(plain, "rb") as fi, gzip.open(p, "wb") as fo:
            shutil.copyfileobj(fi, fo)
    else:
        with can.Logger(p) as w:
            for m in msgs:
                w.on_message_received(m)
    got, src = read(p)
    assert src.stats.bad == 0
    assert len(got) == len(msgs)
    for a, b in zip(msgs, got):
        assert (b.arbitration_id, b.is_extended_id, b.is_remote_frame, bytes(b.data)) == (
            a.arbitration_id,
            a.is_extended_id,
            a.is_remote_frame,
            bytes(a.data),
        )
        if not a.is_remote_frame:
            assert b.dlc == a.dlc
    rel = [b.timestamp - got[0].timestamp - (a.timestamp - msgs[0].timestamp) for a, b in zip(msgs, got)]
    assert max(abs(x) for x in rel) < 2e-6  # every format keeps microseconds between frames
    if not suffix.startswith(".asc"):  # python-can's ASC reader starts the clock at 0
        assert got[0].timestamp == pytest.approx(msgs[0].timestamp, abs=1e-6)
    # candump keeps names, CSV has no channel, the others number channels from 0 (see vdp.io.logs).
    want_channel = {"log": "can0", "csv": None}.get(suffix.split(".")[1], 0)
    assert {b.channel for b in got} == {want_channel}


# -- progress -----------------------------------------------------------------------


@pytest.mark.parametrize("name", ["p.log", "p.log.gz", "p.asc"])
def test_progress(tmp_path, name):
    p = tmp_path / name
    if name == "p.asc":
        with can.Logger(p) as w:
            for k in range(20000):
                w.on_message_received(
                    can.Message(timestamp=T0 + k * 0.001, arbitration_id=k % 2000, is_extended_id=False, data=bytes(8))
                )
    else:
        _big_log(p)
    src = open_log(p)
    assert src.size == p.stat().st_size and src.position == 0
    seen = []
    for k, _ in enumerate(src):
        if k % 1000 == 0:
            seen.append(src.position)
    assert seen == sorted(seen) and 0 < seen[len(seen) // 2] < src.size
    assert src.position == src.size and src.fraction == 1.0
    with pytest.raises(RuntimeError, match="only once"):
        iter(src)


# -- the real RAV4 log ----------------------------------------------------------------


@pytest.mark.skipif(not RAV4_LOG.is_file(), reason=f"real RAV4 log not present at {RAV4_LOG}")
def test_real_rav4_log_frames_per_channel():
    counts: dict[str, int] = {}
    with open_log(RAV4_LOG) as src:
        for m in src:
            counts[m.channel] = counts.get(m.channel, 0) + 1
    assert counts == {"can0": 53800, "can1": 45000, "can2": 12434, "can3": 24234}  # README: 135,468
    assert src.stats.bad == 0 and src.position == src.size


@pytest.mark.skipif(
    not (RAV4_LOG.is_file() and RAV4_DBC.is_file()), reason=f"real RAV4 log or DBC not present in {RAV4_LOG.parent}"
)
def test_real_rav4_log_decodes():
    dec = FrameDecoder(load_profile(DATA / "rav4.toml"))
    speeds = []
    with open_log(RAV4_LOG) as src:
        for m in src:
            for i, v in dec.decode(m):
                if i == channels.SPEED:
                    speeds.append(v)
    d = dec.stats.as_dict()
    # Counts of 8-byte frames per id on can0; the 100 shorter frames in the log are rejected.
    assert d["samples"] == {
        "wheel_speed_fl": 4946,
        "wheel_speed_fr": 4946,
        "wheel_speed_rl": 4946,
        "wheel_speed_rr": 4946,
        "steering_angle": 4969,
        "accel_x": 4914,
        "accel_y": 4914,
        "yaw_rate": 4914,
        "speed": 2480,
    }
    assert d["errors_by_kind"]["dlc"] == 100 and d["skipped_channel"] == 135468 - 53800
    assert min(speeds) > 7.5 and max(speeds) < 21.0  # README: 8 to 20 m/s


def test_dotted_name_gzip(tmp_path):
    """python-can's LogReader refuses 'a.b.log.gz' (it wants exactly two suffixes); we do not."""
    p = tmp_path / "drive.2024-01-01.log.gz"
    with gzip.open(p, "wt") as f:
        f.write(GOOD_A + "\n")
    frames, src = read(p)
    assert len(frames) == 1 and src.format == ".log" and src.compressed


def test_stats_as_dict_is_json(tmp_path):
    _, src = read(DATA / "golden.log")
    d = json.loads(json.dumps(src.stats.as_dict()))
    assert d["bad_lines"] == 6 and d["bad_examples"][0] == {
        "line": 8,
        "reason": "not '(time) channel id#data'",
        "text": "this is not a candump line",
    }


# -- ids nobody decodes ----------------------------------------------------------------


def test_keep_ids_passes_over_other_ids(tmp_path):
    p = write(
        tmp_path,
        "\n".join(
            [
                "(1.000000) can0 0B1#E803D007",
                "(1.001000) can0 7DF#0102",  # first line of an id: handed out (it fills the id cache)
                "(1.002000) can0 7DF#0304",
                "(x) can0 7DF#0506",  # passed over before its timestamp is read: not a bad line
                "(1.003000) can0 12345678#AA",
                "(1.004000) can0 12345678#BB",
                "(1.005000) can0 0B1#E803D008",
                "(1.006000) can0 7DF#R",  # a remote frame of such an id too
                "(1.007000) can0 20000080#0000000000000000",  # error frames are always handed out
            ]
        )
        + "\n",
    )
    with open_log(p) as src:
        src.keep_ids({0xB1})
        frames = list(src)
    assert [(f.arbitration_id, f.is_remote_frame) for f in frames] == [
        (0xB1, False),
        (0x7DF, False),
        (0x12345678, False),
        (0xB1, False),
        (0x80, False),
    ]
    assert frames[-1].is_error_frame
    assert src.stats.passed_over == {0x7DF: 3, 0x12345678 | 1 << 31: 1}
    d = src.stats.as_dict()
    assert (d["frames"], d["passed_over"], d["bad_lines"], d["error_frames"]) == (9, 4, 0, 1)
    with pytest.raises(RuntimeError, match="before iterating"):
        src.keep_ids({0xB1})


def test_replay_passing_over_ids_gives_the_same_result(tmp_path):
    """The reader's id filter changes cost, not results: same estimates and counts as
    feeding every frame of the drive to the pipeline."""
    from vdp.pipeline import Pipeline
    from vdp.replay import replay
    from vdp.sim.run import Simulation, write_log

    prof = load_profile(ROOT / "profiles" / "paper.toml")
    frames = list(
        Simulation(prof, "stage1", seed=5, noise="realistic", duration=8.0, extra_ids=6, extra_rate=100.0).frames()
    )
    path = tmp_path / "d.log"
    write_log(iter(frames), path)
    res = replay(open_log(path), Pipeline(prof))
    ref = Pipeline(prof)
    for f in frames:
        ref.feed(f)
    ref.flush()  # (the samples held for the gates' look-ahead, as run() takes them at the log's end)
    want = ref.result()
    assert res.log.source["passed_over"] > 0.4 * len(frames)  # half of this bus is filler
    assert res.log.frames == len(frames) == ref.frames
    for key in ("frames", "decoded", "unknown_ids", "unknown_distinct", "errors_by_kind"):
        assert res.decode[key] == want.decode[key], key
    assert res.parameters == want.parameters and res.parameters["C_K"].samples > 200
