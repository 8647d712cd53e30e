"""FrameDecoder: profile validation, SI conversion, bad-frame accounting."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import struct
from pathlib import Path

import can
import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import REAL
from helpers.bus import EXTRA, EXTRA_DB, PAPER, VDP_DB, frame
from vdp import channels
from vdp.errors import ProfileError
from vdp.io.decoder import FrameDecoder, compile_extractor
from vdp.profile import ChannelMap, MessageCheck

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(__file__).resolve().parent / "data"
TOYOTA_DBC = REAL / "toyota_new_mc_pt_generated.dbc"
DEG = math.pi / 180.0
I = channels.INDEX


def as_dict(pairs):
    return {channels.NAMES[i]: v for i, v in pairs}


def errors(dec, kind=None):
    e = dec.stats.errors
    return {k: n for k, n in e.items() if kind is None or k[1] == kind}


# -- validation ---------------------------------------------------------------


def with_channel(profile, name, **changes):
    cm = dataclasses.replace(profile.channels[name], **changes)
    return dataclasses.replace(profile, channels={**profile.channels, name: cm})


def test_missing_message_names_table_and_suggests():
    prof = with_channel(PAPER, "yaw_rate", message="IMU_RATE")
    with pytest.raises(ProfileError) as exc:
        FrameDecoder(prof)
    msg = str(exc.value)
    assert "[channels.yaw_rate]" in msg and "'IMU_RATE'" in msg and "vdp.dbc" in msg
    assert "similar names" in msg and "IMU_RATES" in msg


def test_missing_signal_lists_candidates():
    prof = with_channel(PAPER, "yaw_rate", signal="YAWRATE")
    with pytest.raises(
        ProfileError,
        match=r"\[channels.yaw_rate\]: signal 'YAWRATE' is not in message "
        r"'IMU_RATES' of vdp.dbc; similar: YAW_RATE",
    ):
        FrameDecoder(prof)


def test_missing_sign_signal():
    prof = with_channel(PAPER, "speed", sign_signal="REVERSE")
    with pytest.raises(ProfileError, match=r"\[channels.speed\]: sign_signal 'REVERSE'"):
        FrameDecoder(prof)


def test_missing_alt_message():
    alt = dataclasses.replace(
        EXTRA.channels["wheel_speed_fl"].alt, message="NOPE", where="x.toml [channels.wheel_speed_fl.alt]"
    )
    prof = with_channel(EXTRA, "wheel_speed_fl", alt=alt)
    with pytest.raises(ProfileError, match=r"\[channels.wheel_speed_fl.alt\]: message 'NOPE' is not in extra.dbc"):
        FrameDecoder(prof)


def test_missing_check_signals():
    for chk, pattern in (
        (MessageCheck("IMU_RATES", counter="CNT", checksum="CHECKSUM"), "counter signal 'CNT'"),
        (MessageCheck("IMU_RATES", counter="COUNTER", checksum="CRC"), "checksum signal 'CRC'"),
        (MessageCheck("IMU_RATE", counter="COUNTER"), "message 'IMU_RATE'"),
    ):
        prof = dataclasses.replace(PAPER, checks={**PAPER.checks, chk.message: chk})
        with pytest.raises(ProfileError, match=rf"\[checks.{chk.message}\]: {pattern}"):
            FrameDecoder(prof)


def test_bad_dbc_is_profile_error(tmp_path):
    bad = tmp_path / "bad.dbc"
    bad.write_text("BO_ this is not a dbc\n")
    with pytest.raises(ProfileError, match="cannot load DBC"):
        FrameDecoder(dataclasses.replace(PAPER, dbc=bad))


def test_unit_mismatch_warns(caplog):
    with caplog.at_level(logging.WARNING, logger="vdp.io.decoder"):
        FrameDecoder(EXTRA)
    assert "ACCEL_Y in 'm/s^2' but the profile says 'g'" in caplog.text


# -- signal extraction against cantools ---------------------------------------


def _dbs():
    out = [VDP_DB, EXTRA_DB]
    if TOYOTA_DBC.is_file():
        out.append(cantools.database.load_file(str(TOYOTA_DBC), strict=False))
    return out


@pytest.mark.parametrize("db", _dbs(), ids=lambda db: f"{len(db.messages)}msgs")
@pytest.mark.filterwarnings("ignore::hypothesis.errors.HypothesisWarning")  # the DBC in the repr is big
@settings(max_examples=30, deadline=None)
@given(seed=st.binary(min_size=64, max_size=64))
def test_compiled_extractor_matches_cantools(db, seed):
    """Shifts and masks give what cantools gives, for every plain message and any payload."""
    compiled = 0
    for msg in db.messages:
        need = [(s.name, False, False) for s in msg.signals]
        raw_need = [(s.name, True, False) for s in msg.signals]
        f, f_raw = compile_extractor(msg, need), compile_extractor(msg, raw_need)
        if f is None:
            assert msg.is_multiplexed() or any(s.is_float for s in msg.signals)
            continue
        compiled += 1
        data = (seed * 2)[: msg.length]
        try:
            want = msg.decode(data, decode_choices=False, scaling=True)
            want_raw = msg.decode(data, decode_choices=False, scaling=False)
        except cantools.database.DecodeError:
            continue  # cantools cannot split overlapping signals (Toyota PCS_HUD); nothing to compare
        got, got_raw = f(data), f_raw(bytearray(data))
        assert got[0] is None and got_raw[0] is None
        for i, s in enumerate(msg.signals, 1):
            assert got[i] == pytest.approx(want[s.name], rel=1e-12, abs=1e-9), (msg.name, s.name)
            assert got_raw[i] == want_raw[s.name], (msg.name, s.name)
    assert (
        compiled == sum(1 for m in db.messages if not m.is_multiplexed() and not any(s.is_float for s in m.signals)) > 0
    )


# -- round trip through the paper profile -------------------------------------


def _physical(sig):
    return st.floats(min_value=sig.minimum, max_value=sig.maximum, allow_nan=False)


MAPPED = {}
for _cm in PAPER.channels.values():
    MAPPED.setdefault(_cm.message, []).append(_cm)


@st.composite
def paper_frames(draw):
    """A random frame of each mapped message: (msg, {channel: expected SI, tolerance})."""
    out = []
    for t, (name, maps) in enumerate(sorted(MAPPED.items())):
        msg = VDP_DB.get_message_by_name(name)
        vals = {s.name: draw(_physical(s)) for s in msg.signals if s.name not in ("COUNTER", "CHECKSUM")}
        counter = draw(st.integers(0, 15))
        f = (
            frame(VDP_DB, name, t=0.01 * t, counter=counter, **vals)
            if "COUNTER" in msg.signal_tree
            else frame(VDP_DB, name, t=0.01 * t, **vals)
        )
        expect = {}
        for cm in maps:
            sig = msg.get_signal_by_name(cm.signal)
            factor = cm.factor(PAPER.vehicle)
            si = factor * (vals[cm.signal] * cm.scale + cm.offset)
            expect[cm.channel] = (si, abs(factor * cm.scale) * sig.scale / 2 * (1 + 1e-9) + 1e-12)
        out.append((f, expect))
    return out


@settings(max_examples=200, deadline=None)
@given(frames=paper_frames())
def test_round_trip_paper_profile(frames):
    dec = FrameDecoder(PAPER, VDP_DB)
    for msg, expect in frames:
        got = as_dict(dec.decode(msg))
        assert set(got) == set(expect)
        for name, (si, tol) in expect.items():
            assert abs(got[name] - si) <= tol, (name, got[name], si, tol)
    assert dec.stats.decoded == len(frames) and not dec.stats.errors


def test_paper_values_exact():
    dec = FrameDecoder(PAPER, VDP_DB)
    got = as_dict(dec.decode(frame(VDP_DB, "IMU_RATES", counter=0, YAW_RATE=1.0, ROLL_RATE=-2.0)))
    assert got == {"yaw_rate": pytest.approx(DEG), "roll_rate": pytest.approx(-2 * DEG)}
    got = as_dict(dec.decode(frame(VDP_DB, "STEERING", counter=0, STEER_WHEEL_ANGLE=15.0)))
    assert got == {"steering_angle": pytest.approx(DEG)}  # 15 deg at the wheel / ratio 15


# -- extra profile: sign signal, scale/offset, extended ids, floats, mux, alt ---


def test_extended_big_endian_sign_signal_scale_offset():
    dec = FrameDecoder(EXTRA, EXTRA_DB)
    got = as_dict(dec.decode(frame(EXTRA_DB, "EXT_SPEED", SPEED=36.0, REVERSE=1, TORQUE_F=100)))
    assert got["speed"] == pytest.approx(-10.0)  # 36 km/h backwards
    assert got["wheel_torque_front"] == pytest.approx(0.5 * 100 + 10.0)
    got = as_dict(dec.decode(frame(EXTRA_DB, "EXT_SPEED", SPEED=36.0, REVERSE=0)))
    assert got["speed"] == pytest.approx(10.0)
    # The same number as a standard id is another message.
    std = frame(EXTRA_DB, "EXT_SPEED", SPEED=36.0)
    std.is_extended_id = False
    assert dec.decode(std) == []
    assert dec.stats.unknown == {0x18FEF100: 1}


def test_floats_and_nonfinite():
    dec = FrameDecoder(EXTRA, EXTRA_DB)
    got = as_dict(dec.decode(frame(EXTRA_DB, "FLOATS", ACCEL_X=1.25, ACCEL_Y=0.5)))
    assert got == {"accel_x": 1.25, "accel_y": pytest.approx(0.5 * 9.80665)}
    nan = can.Message(arbitration_id=301, is_extended_id=False, data=struct.pack("<ff", float("nan"), 1.0))
    inf = can.Message(arbitration_id=301, is_extended_id=False, data=struct.pack("<ff", 1.0, float("inf")))
    assert dec.decode(nan) == [] and dec.decode(inf) == []
    assert errors(dec) == {(301, "nonfinite"): 2}
    big = can.Message(arbitration_id=301, is_extended_id=False, data=struct.pack("<ff", 51.0, 1.0))
    assert dec.decode(big) == [] and errors(dec, "range") == {(301, "range"): 1}


def test_mux_pages_and_unknown_page():
    dec = FrameDecoder(EXTRA, EXTRA_DB)
    assert as_dict(dec.decode(frame(EXTRA_DB, "MUXED", PAGE=1, YAW=10.0))) == {"yaw_rate": pytest.approx(10 * DEG)}
    assert as_dict(dec.decode(frame(EXTRA_DB, "MUXED", PAGE=2, ROLL=10.0))) == {"roll_rate": pytest.approx(-10 * DEG)}
    bad = frame(EXTRA_DB, "MUXED", PAGE=1, YAW=10.0)
    bad.data[0] = 7
    assert dec.decode(bad) == []
    assert errors(dec) == {(300, "mux"): 1}


def test_alt_source_when_primary_silent_or_invalid():
    dec = FrameDecoder(EXTRA, EXTRA_DB)
    fl = I["wheel_speed_fl"]
    # Primary never seen: the alternative is used.
    assert dec.decode(frame(EXTRA_DB, "WHEELS_SLOW", t=0.0, WS_FL_ALT=5.0)) == [(fl, pytest.approx(5.0))]
    # Primary current (cycle 10 ms): alternative frames decode but give no sample.
    for k in range(5):
        assert dec.decode(frame(EXTRA_DB, "WHEELS", t=1.0 + 0.01 * k, counter=k, WS_FL=4.0)) == [
            (fl, pytest.approx(4.0))
        ]
    assert dec.decode(frame(EXTRA_DB, "WHEELS_SLOW", t=1.045, WS_FL_ALT=5.0)) == []
    # Primary silent for more than 5 cycles (last at 1.04): alternative again.
    assert dec.decode(frame(EXTRA_DB, "WHEELS_SLOW", t=1.10, WS_FL_ALT=5.5)) == [(fl, pytest.approx(5.5))]
    # Primary back.
    assert dec.decode(frame(EXTRA_DB, "WHEELS", t=1.11, counter=5, WS_FL=4.0)) == [(fl, pytest.approx(4.0))]
    assert dec.decode(frame(EXTRA_DB, "WHEELS_SLOW", t=1.12, WS_FL_ALT=5.0)) == []
    # Primary flagged invalid by its counter: the alternative takes over at once.
    for t in (1.12, 1.13, 1.14):
        assert dec.decode(frame(EXTRA_DB, "WHEELS", t=t, counter=9)) == []
    assert "wheel_speed_fl" not in dec.invalid_channels  # the alternative is current
    assert dec.invalid_messages == {"WHEELS"}
    assert dec.decode(frame(EXTRA_DB, "WHEELS_SLOW", t=1.145, WS_FL_ALT=6.0)) == [(fl, pytest.approx(6.0))]
    assert dec.stats.as_dict()["samples"]["wheel_speed_fl"] == 9


# -- a channel split into a coarse and a fine signal (data/fine.dbc) -------------

FINE_DB = cantools.database.load_file(str(DATA / "fine.dbc"), strict=True)


def split(message="STEER_ANGLE_SENSOR", signal="STEER_ANGLE", fine="STEER_FRACTION", **keys):
    """The paper's vehicle with only the steering-wheel angle, read from fine.dbc."""
    cm = ChannelMap(
        "steering_angle",
        message,
        signal,
        "deg",
        steering_wheel=True,
        fine=fine,
        where="fine.toml [channels.steering_angle]",
        **keys,
    )
    return dataclasses.replace(PAPER, dbc=DATA / "fine.dbc", channels={"steering_angle": cm}, checks={})


def test_fine_signal_is_added_to_the_coarse_one():
    dec = FrameDecoder(split(), FINE_DB)
    flipped = FrameDecoder(split(sign=-1.0, scale=2.0), FINE_DB)
    ratio = PAPER.vehicle.steering_ratio
    for coarse, frac in ((0.0, 0.0), (-1.5, 0.7), (3.0, -0.7), (-4.5, 0.3), (498.0, 0.7)):
        msg = frame(FINE_DB, "STEER_ANGLE_SENSOR", STEER_ANGLE=coarse, STEER_FRACTION=frac, STEER_RATE=-7)
        assert as_dict(dec.decode(msg)) == {"steering_angle": pytest.approx((coarse + frac) * DEG / ratio)}
        # the profile's scale and sign apply to the sum
        assert as_dict(flipped.decode(msg)) == {"steering_angle": pytest.approx(-2 * (coarse + frac) * DEG / ratio)}
    # raw 0x8 (-0.8) is outside the DBC's [-0.7|0.7] (Toyota never sends it): a bad frame, no sample
    assert dec.decode(frame(FINE_DB, "STEER_ANGLE_SENSOR", STEER_ANGLE=1.5, STEER_FRACTION=-0.8)) == []
    assert errors(dec) == {(37, "range"): 1}
    assert dec.stats.as_dict()["samples"] == {"steering_angle": 5}


def test_fine_signal_on_an_offset_grid():
    dec = FrameDecoder(split("FLOOR_SPLIT", "ANGLE", "REST"), FINE_DB)
    got = as_dict(dec.decode(frame(FINE_DB, "FLOOR_SPLIT", ANGLE=-0.75, REST=1.4)))
    assert got == {"steering_angle": pytest.approx(0.65 * DEG / PAPER.vehicle.steering_ratio)}


@pytest.mark.parametrize(
    "profile,pattern",
    [
        (
            split(fine="STEER_FRACTIN"),
            "fine signal 'STEER_FRACTIN' is not in message 'STEER_ANGLE_SENSOR' of fine.dbc; similar: STEER_FRACTION",
        ),
        (
            split(signal="STEER_FRACTION", fine="STEER_ANGLE"),
            r"fine signal 'STEER_ANGLE' \(steps of 1.5\) is not finer than 'STEER_FRACTION' \(steps of 0.1\)",
        ),
        (
            split("FLOOR_SPLIT", "ANGLE", "SHORT_REST"),
            r"fine signal 'SHORT_REST' carries \[0, 0.7\] in steps of 0.1, less than one step of 'ANGLE' \(1.5\): "
            r"their sum would have gaps",
        ),
        (
            split("FLOOR_SPLIT", "ANGLE", "REST_RAD"),
            "fine signal 'REST_RAD' is in 'rad' but 'ANGLE' is in 'deg'; the two are added, so they must share a unit",
        ),
    ],
    ids=["missing", "not-finer", "gaps", "other-unit"],
)
def test_fine_signal_errors(profile, pattern):
    with pytest.raises(ProfileError, match=rf"^fine.toml \[channels.steering_angle\]: {pattern}"):
        FrameDecoder(profile, FINE_DB)


def test_fine_signal_in_an_unknown_unit_warns(caplog):
    with caplog.at_level(logging.WARNING, logger="vdp.io.decoder"):
        dec = FrameDecoder(split("FLOOR_SPLIT", "ANGLE", "REST_DEGREE"), FINE_DB)
    assert "FLOOR_SPLIT.ANGLE in 'deg' and its fine signal REST_DEGREE in 'degree'" in caplog.text
    got = as_dict(dec.decode(frame(FINE_DB, "FLOOR_SPLIT", ANGLE=2.25, REST_DEGREE=0.3)))
    assert got == {"steering_angle": pytest.approx(2.55 * DEG / PAPER.vehicle.steering_ratio)}


def test_fine_signal_must_be_an_integer():
    cm = dataclasses.replace(EXTRA.channels["accel_x"], fine="ACCEL_Y")
    with pytest.raises(
        ProfileError,
        match=r"\[channels.accel_x\]: 'fine' needs integer signals, "
        r"but FLOATS.ACCEL_X is a float",
    ):
        FrameDecoder(dataclasses.replace(EXTRA, channels={**EXTRA.channels, "accel_x": cm}), EXTRA_DB)


# -- bad frames ------------------------------------------------------------------


def test_each_bad_kind_counted_and_no_sample():
    dec = FrameDecoder(PAPER, VDP_DB)
    good = frame(VDP_DB, "IMU_RATES", counter=0, YAW_RATE=1.0)
    assert dec.decode(good)
    cases = {
        "dlc": can.Message(arbitration_id=0xE1, is_extended_id=False, data=good.data[:7]),
        "remote": can.Message(arbitration_id=0xE1, is_extended_id=False, is_remote_frame=True, dlc=8),
        "range": frame(VDP_DB, "IMU_RATES", counter=1, YAW_RATE=1.0, ROLL_RATE=160.0),  # ROLL limit 150
        "checksum": frame(VDP_DB, "IMU_RATES", counter=2, fix_checksum=False, YAW_RATE=1.0),
        "counter": frame(VDP_DB, "IMU_RATES", counter=9, YAW_RATE=1.0),
    }
    long = can.Message(arbitration_id=0xE1, is_extended_id=False, data=bytes(good.data) + b"\0")
    for kind, msg in cases.items():
        assert dec.decode(msg) == [], kind  # the good YAW_RATE of the range frame is not sampled either
    assert dec.decode(long) == []
    assert dec.decode(can.Message(arbitration_id=0x7DF, is_extended_id=False, data=b"\x02\x01")) == []
    err = can.Message(arbitration_id=0xE1, is_extended_id=False, is_error_frame=True, data=good.data)
    assert dec.decode(err) == []
    assert errors(dec) == {
        (0xE1, "dlc"): 2,
        (0xE1, "remote"): 1,
        (0xE1, "range"): 1,
        (0xE1, "checksum"): 1,
        (0xE1, "counter"): 1,
    }
    d = dec.stats.as_dict()
    assert d["frames"] == 9 and d["decoded"] == 1 and d["error_frames"] == 1
    assert d["unknown_ids"] == [{"id": "0x7DF", "count": 1}]
    assert d["errors"]["0x0E1"] == {"checksum": 1, "counter": 1, "dlc": 2, "range": 1, "remote": 1}
    assert d["errors_by_kind"]["unknown_id"] == 1 and d["errors_by_kind"]["error_frame"] == 1
    assert d["messages"] == {"0x0E1": "IMU_RATES"}
    assert d["samples"] == {"yaw_rate": 1, "roll_rate": 1}


def test_gnss_range_limit():
    dec = FrameDecoder(PAPER, VDP_DB)
    ok = frame(VDP_DB, "GNSS_VELOCITY", GNSS_SPEED=65.0)
    assert as_dict(dec.decode(ok)) == {"speed": pytest.approx(65.0)}
    over = frame(VDP_DB, "GNSS_VELOCITY", GNSS_SPEED=65.0)
    over.data[0:2] = b"\xff\xff"  # 65.535 m/s > 65
    assert dec.decode(over) == [] and errors(dec) == {(0x1F0, "range"): 1}


@pytest.mark.parametrize("kind", ["counter", "checksum"])
def test_invalid_after_three_bad_and_recovery(kind):
    dec = FrameDecoder(PAPER, VDP_DB)
    ws = ("wheel_speed_fl", "wheel_speed_fr")

    def good(c):
        return frame(VDP_DB, "WHEEL_SPEEDS_FRONT", counter=c, WHEEL_SPEED_FL=10.0, WHEEL_SPEED_FR=10.0)

    def bad(c):
        if kind == "counter":  # a frozen counter
            return frame(VDP_DB, "WHEEL_SPEEDS_FRONT", counter=2, WHEEL_SPEED_FL=1.0)
        return frame(VDP_DB, "WHEEL_SPEEDS_FRONT", counter=c, fix_checksum=False, WHEEL_SPEED_FL=1.0)

    for c in range(3):
        assert dec.decode(good(c))
    for n, c in enumerate((3, 4, 5), 1):
        assert dec.decode(bad(c)) == []
        assert (set(ws) <= dec.invalid_channels) == (n == 3), n
        assert dec.is_valid("wheel_speed_fl") == (n < 3)
    assert dec.stats.as_dict()["invalid_channels"] == list(ws)
    assert dec.decode(bad(6)) == [] and not dec.is_valid("wheel_speed_fr")
    # A counter jump after a counter run needs one frame to resync; a checksum run keeps the count.
    c = 7
    if kind == "counter":
        assert dec.decode(good(c)) == []
        c += 1
    assert as_dict(dec.decode(good(c))) == {
        "wheel_speed_fl": pytest.approx(10.0),
        "wheel_speed_fr": pytest.approx(10.0),
    }
    assert dec.invalid_channels == frozenset() and dec.stats.as_dict()["invalid_channels"] == []
    assert errors(dec, kind)[(0xB1, kind)] >= 4


def test_one_bad_checksum_does_not_break_counter():
    dec = FrameDecoder(PAPER, VDP_DB)
    assert dec.decode(frame(VDP_DB, "STEERING", counter=0, STEER_WHEEL_ANGLE=3.0))
    assert dec.decode(frame(VDP_DB, "STEERING", counter=1, fix_checksum=False, STEER_WHEEL_ANGLE=3.0)) == []
    assert dec.decode(frame(VDP_DB, "STEERING", counter=2, STEER_WHEEL_ANGLE=3.0))
    assert errors(dec) == {(0xD0, "checksum"): 1}


def test_bus_channel_filter():
    prof = dataclasses.replace(PAPER, bus_channel="can1")
    dec = FrameDecoder(prof, VDP_DB)
    assert dec.decode(frame(VDP_DB, "GNSS_VELOCITY", GNSS_SPEED=5.0, channel="can0")) == []
    assert dec.decode(frame(VDP_DB, "GNSS_VELOCITY", GNSS_SPEED=5.0, channel="can1"))
    assert dec.decode(frame(VDP_DB, "GNSS_VELOCITY", GNSS_SPEED=5.0, channel=1))  # ASC/BLF numbering
    assert dec.decode(frame(VDP_DB, "GNSS_VELOCITY", GNSS_SPEED=5.0, channel=None))
    assert dec.decode(frame(VDP_DB, "GNSS_VELOCITY", GNSS_SPEED=5.0, channel=0)) == []
    assert dec.stats.skipped_channel == 2 and dec.stats.as_dict()["skipped_channel"] == 2


def test_checks_can_be_disabled():
    chk = dataclasses.replace(PAPER.checks["IMU_RATES"], check=False)
    dec = FrameDecoder(dataclasses.replace(PAPER, checks={**PAPER.checks, "IMU_RATES": chk}), VDP_DB)
    for _ in range(5):
        assert dec.decode(frame(VDP_DB, "IMU_RATES", counter=3, fix_checksum=False, YAW_RATE=2.0))
    assert not dec.stats.errors


def test_stats_as_dict_is_json():
    dec = FrameDecoder(PAPER, VDP_DB)
    dec.decode(frame(VDP_DB, "GNSS_VELOCITY", GNSS_SPEED=3.0))
    for k in range(12):
        dec.decode(can.Message(arbitration_id=0x700 + k % 4, is_extended_id=False, data=b"\0"))
    dec.decode(can.Message(arbitration_id=0x18DAF110, is_extended_id=True, data=b"\0"))
    d = json.loads(json.dumps(dec.stats.as_dict(top=2)))
    assert d["unknown_ids"] == [{"id": "0x700", "count": 3}, {"id": "0x701", "count": 3}]
    assert d["unknown_distinct"] == 5 and d["errors_by_kind"] == {"unknown_id": 13}
    assert d["samples"] == {"speed": 1} and d["decoded"] == 1 and d["frames"] == 14
