"""Every kind of bad profile is one clear ProfileError naming the file and the table.

Each case starts from profiles/paper.toml (pointed at dbc/vdp.dbc by absolute path),
breaks one thing, and checks the message.  Errors the TOML alone shows come from
load_profile; errors that need the DBC come from FrameDecoder, which every pipeline,
replay and service builds first.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from vdp.cli import main
from vdp.errors import ProfileError
from vdp.io.decoder import FrameDecoder
from vdp.profile import load_profile

ROOT = Path(__file__).resolve().parents[1]
VDP_DBC = ROOT / "dbc" / "vdp.dbc"
BASE = (ROOT / "profiles" / "paper.toml").read_text().replace('dbc = "../dbc/vdp.dbc"', f'dbc = "{VDP_DBC}"')


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "car.toml"
    p.write_text(text)
    return p


def edit(old: str, new: str):
    def f(text: str) -> str:
        assert old in text, f"test setup: {old!r} is not in paper.toml"
        return text.replace(old, new, 1)

    return f


def drop_table(name: str):
    """Remove [name] and its lines up to the next table."""
    return lambda text: re.sub(rf"(?ms)^\[{re.escape(name)}\]\n.*?(?=^\[|\Z)", "", text)


def add(line: str, after: str):
    return edit(after, f"{after}\n{line}")


YAW = 'yaw_rate           = { message = "IMU_RATES", signal = "YAW_RATE", unit = "deg/s" }'


def yaw(**keys) -> str:
    inner = ", ".join(f"{k} = {v}" for k, v in keys.items())
    return f"yaw_rate           = {{ {inner} }}"


def base_yaw(**extra) -> dict:
    d = {"message": '"IMU_RATES"', "signal": '"YAW_RATE"', "unit": '"deg/s"'}
    d.update(extra)
    return d


# (id, change to paper.toml, table named in the message, rest of the message as a regex)
LOAD_CASES = [
    ("unknown-section", add("[vehicles]\nmass = 1.0", "g = 9.8\n"), None, r"unknown section\(s\) \['vehicles'\]"),
    ("no-vehicle", drop_table("vehicle"), "[vehicle]", "missing table"),
    ("no-priors", drop_table("priors"), "[priors]", "missing table"),
    ("no-can", drop_table("can"), "[can]", "missing 'dbc'"),
    ("no-channels", drop_table("channels"), "[channels]", "missing; map at least one of"),
    ("missing-key", edit("mass = 1600.0 ", "# mass"), "[vehicle]", "missing 'mass'"),
    ("unknown-vehicle-key", add("masss = 1.0", "g = 9.8"), "[vehicle]", r"unknown key\(s\) \['masss'\]"),
    (
        "text-for-number",
        edit("mass = 1600.0", 'mass = "heavy"'),
        "[vehicle]",
        "'mass' must be a finite number, got 'heavy'",
    ),
    ("bool-for-number", edit("mass = 1600.0", "mass = true"), "[vehicle]", "'mass' must be a finite number"),
    ("nan", edit("mass = 1600.0", "mass = nan"), "[vehicle]", "'mass' must be a finite number"),
    ("negative", edit("wheelbase = 2.5", "wheelbase = -2.5"), "[vehicle]", "'wheelbase' must be positive"),
    ("zero", edit("wheel_radius = 0.3", "wheel_radius = 0"), "[vehicle]", "'wheel_radius' must be positive"),
    (
        "both-roll-forms",
        add("roll_stiffness = 1.0", "g = 9.8"),
        "[vehicle]",
        "give 'roll_stiffness' or 'roll_stiffness_per_deg', not both",
    ),
    ("empty-name", edit('name = "paper"', 'name = ""'), "[vehicle]", "'name' must be a non-empty string"),
    ("prior-missing", edit("I_x     = { value = 3000.0,  std = 1500.0 }", ""), "[priors.I_x]", "missing"),
    ("prior-unknown", add("m = { value = 1.0, std = 1.0 }", "[priors]"), "[priors]", r"unknown parameter\(s\) \['m'\]"),
    (
        "prior-one-axle",
        add("C_alpha_f = { value = 6.0e4, std = 3.0e4 }", "[priors]"),
        "[priors]",
        "C_alpha_f needs C_alpha_r too",
    ),
    ("prior-negative-std", edit("std = 0.2 }", "std = -0.2 }"), "[priors.h]", "value and std must be positive"),
    ("prior-text", edit("value = 0.55", 'value = "half a metre"'), "[priors.h]", "'value' must be a finite number"),
    ("prior-unknown-key", edit("std = 0.2 }", "std = 0.2, mean = 1.0 }"), "[priors.h]", r"unknown key\(s\) \['mean'\]"),
    ("can-unknown-key", add('dbcs = ["a.dbc"]', "[can]"), "[can]", r"unknown key\(s\) \['dbcs'\]"),
    (
        "can-dbc-missing-file",
        edit(f'dbc = "{VDP_DBC}"', 'dbc = "no/such.dbc"'),
        "[can]",
        "dbc file '.*no/such.dbc' does not exist",
    ),
    ("can-dbc-not-text", edit(f'dbc = "{VDP_DBC}"', "dbc = 3"), "[can]", "missing 'dbc'"),
    ("can-channel-number", add("channel = 0", "[can]"), "[can]", "'channel' must be a string"),
    (
        "unknown-channel",
        edit(YAW, YAW.replace("yaw_rate  ", "yaw       ")),
        "[channels]",
        r"unknown channel\(s\) \['yaw'\]; known: wheel_speed_fl",
    ),
    (
        "channel-not-table",
        edit(YAW, 'yaw_rate = "IMU_RATES.YAW_RATE"'),
        "[channels.yaw_rate]",
        "must be a table with message, signal and unit",
    ),
    (
        "channel-missing-signal",
        edit(YAW, yaw(message='"IMU_RATES"', unit='"deg/s"')),
        "[channels.yaw_rate]",
        "missing 'signal'",
    ),
    (
        "channel-unknown-key",
        edit(YAW, yaw(**base_yaw(scal="2"))),
        "[channels.yaw_rate]",
        r"unknown key\(s\) \['scal'\]",
    ),
    (
        "unknown-unit",
        edit(YAW, yaw(**base_yaw(unit='"deg/h"'))),
        "[channels.yaw_rate]",
        "unit 'deg/h' is not known; use one of rad/s, deg/s",
    ),
    (
        "unit-wrong-kind",
        edit(YAW, yaw(**base_yaw(unit='"km/h"'))),
        "[channels.yaw_rate]",
        r"unit 'km/h' \(speed\) cannot be converted to yaw_rate's rad/s",
    ),
    ("bad-sign", edit(YAW, yaw(**base_yaw(sign="2"))), "[channels.yaw_rate]", "'sign' must be 1 or -1"),
    ("zero-scale", edit(YAW, yaw(**base_yaw(scale="0"))), "[channels.yaw_rate]", "'scale' must not be 0"),
    (
        "text-offset",
        edit(YAW, yaw(**base_yaw(offset='"1"'))),
        "[channels.yaw_rate]",
        "'offset' must be a finite number",
    ),
    (
        "sign-signal-number",
        edit(YAW, yaw(**base_yaw(sign_signal="1"))),
        "[channels.yaw_rate]",
        "'sign_signal' must be a signal name",
    ),
    (
        "steering-wheel-elsewhere",
        edit(YAW, yaw(**base_yaw(steering_wheel="true"))),
        "[channels.yaw_rate]",
        "'steering_wheel' applies to steering_angle only",
    ),
    (
        "fine-number",
        edit(YAW, yaw(**base_yaw(fine="0.1"))),
        "[channels.yaw_rate]",
        "'fine' must be a signal name, got 0.1",
    ),
    ("fine-empty", edit(YAW, yaw(**base_yaw(fine='""'))), "[channels.yaw_rate]", "'fine' must be a signal name"),
    (
        "fine-is-signal",
        edit(YAW, yaw(**base_yaw(fine='"YAW_RATE"'))),
        "[channels.yaw_rate]",
        "'fine' must be another signal than signal 'YAW_RATE'",
    ),
    (
        "fine-is-sign-signal",
        edit(YAW, yaw(**base_yaw(fine='"ROLL_RATE"', sign_signal='"ROLL_RATE"'))),
        "[channels.yaw_rate]",
        "'fine' must be another signal than sign_signal 'ROLL_RATE'",
    ),
    (
        "alt-fine-is-signal",
        edit(YAW, yaw(**base_yaw(alt='{ message = "A", signal = "B", unit = "deg/s", fine = "B" }'))),
        "[channels.yaw_rate.alt]",
        "'fine' must be another signal than signal 'B'",
    ),
    (
        "alt-of-alt",
        edit(
            YAW,
            yaw(
                **base_yaw(
                    alt='{ message = "A", signal = "B", unit = "deg/s", '
                    'alt = { message = "C", signal = "D", unit = "deg/s" } }'
                )
            ),
        ),
        "[channels.yaw_rate.alt]",
        "cannot have its own 'alt'",
    ),
    (
        "alt-bad-unit",
        edit(YAW, yaw(**base_yaw(alt='{ message = "A", signal = "B", unit = "m/s" }'))),
        "[channels.yaw_rate.alt]",
        "cannot be converted",
    ),
    (
        "composite-condition-not-names",
        edit(
            'wheel_torque_front = { message = "WHEEL_TORQUE", signal = "TORQUE_FRONT", unit = "Nm" }',
            "wheel_torque_front = { conditions = [{ message = 5, signal = [] }], "
            'terms = [{ message = "WHEEL_TORQUE", signal = "TORQUE_FRONT", unit = "Nm" }] }',
        ),
        "[channels.wheel_torque_front]",
        r"conditions\[0\]: 'message' must be a message name \(a string\), got 5",
    ),
    (
        "composite-condition-signal-list",
        edit(
            'wheel_torque_front = { message = "WHEEL_TORQUE", signal = "TORQUE_FRONT", unit = "Nm" }',
            'wheel_torque_front = { conditions = [{ message = "STEERING", signal = [] }], '
            'terms = [{ message = "WHEEL_TORQUE", signal = "TORQUE_FRONT", unit = "Nm" }] }',
        ),
        "[channels.wheel_torque_front]",
        r"conditions\[0\]: 'signal' must be a signal name \(a string\), got \[\]",
    ),
    (
        "checks-not-table",
        edit('IMU_RATES          = { counter = "COUNTER", checksum = "CHECKSUM" }', 'IMU_RATES = "COUNTER"'),
        "[checks.IMU_RATES]",
        "must be a table",
    ),
    (
        "checks-unknown-key",
        edit(
            'IMU_RATES          = { counter = "COUNTER", checksum = "CHECKSUM" }',
            'IMU_RATES = { counter = "COUNTER", crc = "CHECKSUM" }',
        ),
        "[checks.IMU_RATES]",
        r"unknown key\(s\) \['crc'\]",
    ),
    (
        "checks-unknown-kind",
        edit(
            'IMU_RATES          = { counter = "COUNTER", checksum = "CHECKSUM" }',
            'IMU_RATES = { checksum = "CHECKSUM", checksum_kind = "crc8" }',
        ),
        "[checks.IMU_RATES]",
        "checksum_kind must be 'vdp' or 'none', got 'crc8'",
    ),
    (
        "checks-check-text",
        edit(
            'IMU_RATES          = { counter = "COUNTER", checksum = "CHECKSUM" }',
            'IMU_RATES = { counter = "COUNTER", check = "yes" }',
        ),
        "[checks.IMU_RATES]",
        "'check' must be true or false",
    ),
    (
        "checks-counter-number",
        edit('IMU_RATES          = { counter = "COUNTER", checksum = "CHECKSUM" }', "IMU_RATES = { counter = 4 }"),
        "[checks.IMU_RATES]",
        "'counter' must be a signal name, got 4",
    ),
]


@pytest.mark.parametrize("change,table,pattern", [c[1:] for c in LOAD_CASES], ids=[c[0] for c in LOAD_CASES])
def test_load_errors_name_file_and_table(tmp_path, change, table, pattern):
    path = write(tmp_path, change(BASE))
    with pytest.raises(ProfileError) as exc:
        load_profile(path)
    msg = str(exc.value)
    where = f"{path} {table}: " if table else f"{path}: "
    assert msg.startswith(where), msg
    assert re.search(pattern, msg[len(where) :]), msg
    assert "\n" not in msg


def test_base_profile_is_valid(tmp_path):
    """The cases above break a profile that is fine as it is."""
    FrameDecoder(load_profile(write(tmp_path, BASE)))


def test_missing_file():
    with pytest.raises(ProfileError, match=r"^nope/car.toml: no such profile file"):
        load_profile("nope/car.toml")


def test_bad_toml_names_the_line(tmp_path):
    path = write(tmp_path, BASE.replace("mass = 1600.0", "mass = = 1600.0"))
    with pytest.raises(ProfileError, match=rf"^{re.escape(str(path))}: not valid TOML: .*line 7"):
        load_profile(path)


def test_not_utf8(tmp_path):
    path = tmp_path / "car.toml"
    path.write_bytes(b'[vehicle]\nname = "\xff"\n')
    with pytest.raises(ProfileError, match=rf"^{re.escape(str(path))}: not valid TOML"):
        load_profile(path)


# -- errors that need the DBC ----------------------------------------------------------

DBC_CASES = [
    (
        "missing-message",
        edit('message = "IMU_RATES", signal = "YAW_RATE"', 'message = "IMU_RATE", signal = "YAW_RATE"'),
        "[channels.yaw_rate]",
        "message 'IMU_RATE' is not in vdp.dbc; messages with similar names: IMU_RATES",
    ),
    (
        "missing-signal",
        edit('signal = "YAW_RATE"', 'signal = "YAWRATE"'),
        "[channels.yaw_rate]",
        "signal 'YAWRATE' is not in message 'IMU_RATES' of vdp.dbc; similar: YAW_RATE",
    ),
    (
        "missing-sign-signal",
        edit(YAW, yaw(**base_yaw(sign_signal='"YAW_SIGN"'))),
        "[channels.yaw_rate]",
        "sign_signal 'YAW_SIGN' is not in message 'IMU_RATES'",
    ),
    (
        "missing-alt-message",
        edit(YAW, yaw(**base_yaw(alt='{ message = "GYRO2", signal = "Z", unit = "deg/s" }'))),
        "[channels.yaw_rate.alt]",
        "message 'GYRO2' is not in vdp.dbc",
    ),
    (
        "alt-same-message",
        edit(YAW, yaw(**base_yaw(alt='{ message = "IMU_RATES", signal = "ROLL_RATE", unit = "deg/s" }'))),
        "[channels.yaw_rate.alt]",
        "the alternative source must be another message than the primary 'IMU_RATES'",
    ),
    (
        "missing-fine-signal",
        edit(YAW, yaw(**base_yaw(fine='"YAW_RATE_FINE"'))),
        "[channels.yaw_rate]",
        "fine signal 'YAW_RATE_FINE' is not in message 'IMU_RATES' of vdp.dbc; similar: YAW_RATE",
    ),
    (
        "fine-not-finer",
        edit(YAW, yaw(**base_yaw(fine='"ROLL_RATE"'))),
        "[channels.yaw_rate]",
        r"fine signal 'ROLL_RATE' \(steps of 0.005\) is not finer than 'YAW_RATE' \(steps of 0.005\)",
    ),
    (
        "fine-other-unit",
        edit('signal = "STEER_WHEEL_ANGLE",', 'signal = "STEER_WHEEL_ANGLE", fine = "STEER_WHEEL_RATE",'),
        "[channels.steering_angle]",
        "fine signal 'STEER_WHEEL_RATE' is in 'deg/s' but 'STEER_WHEEL_ANGLE' is in "
        "'deg'; the two are added, so they must share a unit",
    ),
    (
        "checks-missing-message",
        add('IMU_RATE = { counter = "COUNTER" }', "[checks]"),
        "[checks.IMU_RATE]",
        "message 'IMU_RATE' is not in vdp.dbc",
    ),
    (
        "checks-missing-counter",
        edit('IMU_RATES          = { counter = "COUNTER"', 'IMU_RATES = { counter = "CNT"'),
        "[checks.IMU_RATES]",
        "counter signal 'CNT' is not in message 'IMU_RATES'",
    ),
    (
        "checks-missing-checksum",
        edit(
            'IMU_RATES          = { counter = "COUNTER", checksum = "CHECKSUM" }',
            'IMU_RATES = { counter = "COUNTER", checksum = "CRC" }',
        ),
        "[checks.IMU_RATES]",
        "checksum signal 'CRC' is not in message 'IMU_RATES'",
    ),
]


@pytest.mark.parametrize("change,table,pattern", [c[1:] for c in DBC_CASES], ids=[c[0] for c in DBC_CASES])
def test_dbc_errors_name_file_and_table(tmp_path, change, table, pattern):
    path = write(tmp_path, change(BASE))
    prof = load_profile(path)  # the TOML itself is fine
    with pytest.raises(ProfileError) as exc:
        FrameDecoder(prof)
    msg = str(exc.value)
    assert msg.startswith(f"{path} {table}: ") and re.search(pattern, msg), msg


def test_unparsable_dbc(tmp_path):
    bad = tmp_path / "bad.dbc"
    bad.write_text("BO_ this is not a dbc\n")
    path = write(tmp_path, BASE.replace(f'dbc = "{VDP_DBC}"', 'dbc = "bad.dbc"'))
    with pytest.raises(ProfileError, match=rf"^{re.escape(str(path))} \[can\]: cannot load DBC .*bad.dbc"):
        FrameDecoder(load_profile(path))


# -- opendbc references ----------------------------------------------------------------


def test_unknown_opendbc_name_suggests(tmp_path):
    pytest.importorskip("opendbc")
    path = write(tmp_path, BASE.replace(f'dbc = "{VDP_DBC}"', 'dbc = "opendbc:vw_mqbb"'))
    with pytest.raises(
        ProfileError,
        match=rf"^{re.escape(str(path))} \[can\]: opendbc has no DBC named "
        r"'vw_mqbb' .*; similar: vw_mqb",
    ):
        load_profile(path)


def test_unknown_generated_name_suggests(tmp_path):
    pytest.importorskip("opendbc")
    path = write(tmp_path, BASE.replace(f'dbc = "{VDP_DBC}"', 'dbc = "opendbc:toyota_new_mc_pt_generatd"'))
    with pytest.raises(ProfileError, match=r"similar: toyota_new_mc_pt_generated"):
        load_profile(path)


def test_opendbc_not_installed(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "opendbc", None)  # import opendbc now raises ImportError
    path = write(tmp_path, BASE.replace(f'dbc = "{VDP_DBC}"', 'dbc = "opendbc:vw_mqb"'))
    with pytest.raises(
        ProfileError,
        match=rf"^{re.escape(str(path))} \[can\]: dbc 'opendbc:vw_mqb' needs the "
        r"opendbc package; install it with: pip install 'vdp\[opendbc\]'",
    ):
        load_profile(path)


# -- through the CLI: one line on stderr, exit status 2 ---------------------------------


@pytest.mark.parametrize("command", ["replay", "simulate"])
def test_cli_prints_one_line(tmp_path, capsys, command):
    path = write(tmp_path, BASE.replace('signal = "YAW_RATE"', 'signal = "YAWRATE"'))
    log = tmp_path / "drive.log"
    log.write_text("(1.0) can0 0E1#0000000000000000\n")
    args = (
        [command, str(log), "--profile", str(path)]
        if command == "replay"
        else [command, "--profile", str(path), "--out", str(tmp_path / "x.log"), "--duration", "1"]
    )
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"vdp {command}: error: {path} [channels.yaw_rate]: ")
    assert "YAWRATE" in err[0]


@pytest.mark.parametrize("name", ['Golf "R"', "Golf\nR = 1", "back\\slash\t$^$", "\u0160koda \U0001f697"])
def test_profile_new_writes_any_name_as_a_toml_string(tmp_path, capsys, name):
    """The draft's name is the given one read back, whatever it holds (a quote made the draft
    invalid TOML; a newline added a key)."""
    out = tmp_path / "d.toml"
    assert main(["profile", "new", "--dbc", str(VDP_DBC), "--name", name, "--out", str(out)]) == 0
    assert load_profile(out).vehicle.name == name
    assert out.read_text().splitlines()[0].startswith("# Draft profile for ")
