"""The simulator encodes every composite form a profile can declare (a sum, a weighted sum,
a product, pieces chosen by an enum, several channels sharing signals, and [drivetrain]
sources that are composites themselves): profile -> encode -> decode gives the channels'
values back within the signals' quantisation (property-based, over random profiles)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import can
import cantools
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vdp import channels
from vdp.errors import ProfileError
from vdp.io.decoder import FrameDecoder
from vdp.profile import ChannelMap, Composite, Drivetrain, Term, load_profile
from vdp.sim.encode import Encoder
from vdp.units import TERM

ROOT = Path(__file__).resolve().parents[1]
PAPER = load_profile(ROOT / "profiles" / "paper.toml")
DB = cantools.database.load_file(str(ROOT / "dbc" / "vdp.dbc"))
# numeric signals of vdp.dbc (no counters or checksums), and an enum for the pieces
NUMERIC = [
    ("WHEEL_TORQUE", "TORQUE_FRONT"),
    ("WHEEL_TORQUE", "TORQUE_REAR"),
    ("STEERING", "STEER_WHEEL_ANGLE"),
    ("STEERING", "STEER_WHEEL_RATE"),
    ("IMU_ACCEL", "ACCEL_X"),
    ("IMU_ACCEL", "ACCEL_Y"),
    ("IMU_RATES", "YAW_RATE"),
    ("IMU_RATES", "ROLL_RATE"),
    ("GNSS_VELOCITY", "GNSS_SPEED"),
    ("GNSS_VELOCITY", "GNSS_COURSE"),
]
ENUM = ("GNSS_VELOCITY", "FIX_TYPE")  # 0..5
TARGETS = ("wheel_torque_front", "wheel_torque_rear", "yaw_rate")


def sig(key):
    return DB.get_message_by_name(key[0]).get_signal_by_name(key[1])


def term_map(key, label: str) -> ChannelMap:
    return ChannelMap(TERM, key[0], key[1], "1", where=f"test {label}")


def profile(comps: dict[str, Composite], **kw):
    return dataclasses.replace(PAPER, channels={}, checks={}, composites=comps, sources={}, drivetrain=None, **kw)


def frames(enc: Encoder, values: dict, t: float = 1.0) -> list[can.Message]:
    return [
        can.Message(timestamp=t, arbitration_id=p.frame_id, data=enc.encode(p, values), is_extended_id=False)
        for p in enc.plans
    ]


def decode(prof, msgs) -> dict[str, float]:
    dec = FrameDecoder(prof)
    out = {}
    for m in msgs:
        for i, v in dec.decode(m):
            out[channels.NAMES[i]] = v
    assert dec.stats.errors == {}, dec.stats.as_dict()["errors"]
    return out


def physical(msgs) -> dict[tuple[str, str], float]:
    out = {}
    for m in msgs:
        d = DB.get_message_by_frame_id(m.arbitration_id)
        for name, v in d.decode(m.data, decode_choices=False).items():
            out[(d.name, name)] = v
    return out


def tolerance(comp: Composite, phys: dict) -> float:
    """Half a step of each term's (first) signal, times what multiplies it."""
    if comp.op == "product":
        f = abs(comp.terms[0].weight) * math.prod(abs(phys[(t.map.message, t.map.signal)]) for t in comp.terms[1:])
        return f * abs(sig((comp.terms[0].map.message, comp.terms[0].map.signal)).scale) / 2
    tol = 0.0
    for t in comp.terms:
        if t.when is not None:
            c = comp.conditions[t.when[0]]
            if int(phys[(c.message, c.signal)]) not in t.when[1]:
                continue
        f = abs(t.weight) * math.prod(abs(phys[(m.message, m.signal)]) for m in t.factors)
        tol += f * abs(sig((t.map.message, t.map.signal)).scale) / 2
    return tol


@st.composite
def composites(draw):
    """Up to three composite channels over vdp.dbc's signals: sums that may share signals and
    pieces by an enum, and products over signals of their own."""
    n = draw(st.integers(1, len(TARGETS)))
    pool = list(NUMERIC)
    used_in_products: set = set()
    used_in_sums: set = set()
    comps = {}
    weights = st.sampled_from([-2.5, -1.0, -0.4, 0.3, 0.5, 1.0, 1.7, 3.0])
    for name in TARGETS[:n]:
        op = draw(st.sampled_from(["sum", "product"]))
        if op == "product":
            free = [k for k in pool if k not in used_in_products and k not in used_in_sums]
            if len(free) < 2:
                op = "sum"
            else:
                keys = draw(st.lists(st.sampled_from(free), min_size=2, max_size=3, unique=True))
                used_in_products |= set(keys)
                terms = tuple(
                    Term(term_map(k, f"{name}.terms[{i}]"), draw(weights) if i == 0 else 1.0)
                    for i, k in enumerate(keys)
                )
                comps[name] = Composite(name, "product", terms, where=f"test {name}")
                continue
        free = [k for k in pool if k not in used_in_products]
        keys = draw(st.lists(st.sampled_from(free), min_size=1, max_size=3, unique=True))
        used_in_sums |= set(keys)
        pieces = draw(st.booleans())
        terms = []
        for i, k in enumerate(keys):
            when = None
            if pieces and draw(st.booleans()):
                when = (0, frozenset(draw(st.lists(st.integers(0, 5), min_size=1, max_size=3, unique=True))))
            terms.append(Term(term_map(k, f"{name}.terms[{i}]"), draw(weights), when))
        conds = (term_map(ENUM, f"{name}.conditions[0]"),) if pieces else ()
        comps[name] = Composite(name, "sum", tuple(terms), conds, where=f"test {name}")
    return comps


@settings(max_examples=60, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
@given(comps=composites(), data=st.data())
def test_every_composite_form_round_trips(comps, data):
    prof = profile(comps)
    enc = Encoder(prof, DB)
    # what a bus can carry: random signal values, as the decoder reads them
    keys = {(m.message, m.signal) for c in comps.values() for m in c.maps}
    vals = {}
    for key in sorted(keys):
        s = sig(key)
        raw_lo, raw_hi = sorted(round((b - s.offset) / s.scale) for b in (s.minimum, s.maximum))
        if key == ENUM:
            raw_lo, raw_hi = 0, 5
        vals[key] = data.draw(st.integers(raw_lo, raw_hi)) * s.scale + s.offset
    bus = []
    for name in {k[0] for k in keys}:
        m = DB.get_message_by_name(name)
        payload = {s.name: 0 for s in m.signals} | {k[1]: v for k, v in vals.items() if k[0] == name}
        bus.append(can.Message(timestamp=1.0, arbitration_id=m.frame_id, data=m.encode(payload), is_extended_id=False))
    truth = decode(prof, bus)
    for name in comps:
        if name not in truth:  # every piece off and nothing else: the channel is 0
            truth[name] = 0.0
    # ... encoded from those channel values, and decoded again
    msgs = frames(enc, {name: truth[name] for name in comps})
    got, phys = decode(prof, msgs), physical(msgs)
    for name, comp in comps.items():
        tol = tolerance(comp, phys) * (1 + 1e-6) + 1e-9 * (1 + abs(truth[name]))
        assert got.get(name, 0.0) == pytest.approx(truth[name], abs=tol), (name, comp, truth, got, phys)


def test_gear_pieces_and_a_ratio_product_take_a_lower_gear_for_more_torque():
    """A drive torque that is an engine torque times the gear ratio: the simulator picks the
    ratio (on its signal's grid) that keeps the engine torque in range."""
    eng, ratio = ("IMU_ACCEL", "ACCEL_X"), ("GNSS_VELOCITY", "GNSS_COURSE")  # +-30, 0..360 (0.01)
    comp = Composite(
        "wheel_torque_front", "product", (Term(term_map(eng, "e"), 0.9), Term(term_map(ratio, "r"))), where="t"
    )
    prof = profile({"wheel_torque_front": comp})
    enc = Encoder(prof, DB)
    for torque in (5.0, 20.0, 300.0, -2500.0):
        msgs = frames(enc, {"wheel_torque_front": torque})
        phys = physical(msgs)
        assert abs(phys[eng]) <= 30.0 and phys[ratio] >= 1.0
        assert decode(prof, msgs)["wheel_torque_front"] == pytest.approx(torque, abs=tolerance(comp, phys) + 1e-9)
    assert physical(frames(enc, {"wheel_torque_front": 5.0}))[ratio] == 1.0  # no more than needed


def test_a_composite_drive_torque_source_round_trips_through_the_drivetrain():
    """[drivetrain] with drive_torque = engine torque x ratio and a brake pressure: the
    simulator's drive and brake torques come back as the axle torques."""
    eng, ratio, press = ("IMU_ACCEL", "ACCEL_X"), ("GNSS_VELOCITY", "GNSS_COURSE"), ("WHEEL_TORQUE", "TORQUE_REAR")
    drive = Composite("drive_torque", "product", (Term(term_map(eng, "e"), 0.92), Term(term_map(ratio, "r"))))
    pressure = ChannelMap("brake_pressure", press[0], press[1], "bar", where="test brake_pressure")
    from vdp.profile import _axle_torques

    dt = Drivetrain("front", brake_balance=0.7, brake_gain=50.0)
    sources = {"drive_torque": drive, "brake_pressure": pressure}
    comps = _axle_torques("test", dt, sources, {}, {})
    prof = profile(comps)
    prof = dataclasses.replace(prof, sources=sources, drivetrain=dt)
    enc = Encoder(prof, DB)
    for drive_t, brake_t in ((0.0, 0.0), (800.0, 0.0), (0.0, 1500.0), (2400.0, 0.0)):
        msgs = frames(enc, {"drive_torque": drive_t, "brake_torque": brake_t})
        got = decode(prof, msgs)
        step = abs(physical(msgs)[ratio]) * 0.92 * 0.001 / 2 + 50.0 * 0.5 / 2  # engine and pressure steps
        assert got["wheel_torque_front"] == pytest.approx(drive_t - 0.7 * brake_t, abs=step)
        assert got["wheel_torque_rear"] == pytest.approx(-0.3 * brake_t, abs=step)


def test_a_signal_both_factor_and_term_is_refused():
    a, b = ("IMU_ACCEL", "ACCEL_X"), ("IMU_ACCEL", "ACCEL_Y")
    comps = {
        "wheel_torque_front": Composite(
            "wheel_torque_front", "product", (Term(term_map(a, "a")), Term(term_map(b, "b")))
        ),
        "wheel_torque_rear": Composite("wheel_torque_rear", "sum", (Term(term_map(b, "b")),)),
    }
    with pytest.raises(ProfileError, match="further factor of a product in one place and a term of a sum"):
        Encoder(profile(comps), DB)


def test_a_signal_both_channel_and_term_is_refused():
    a = ("IMU_ACCEL", "ACCEL_X")
    comps = {"wheel_torque_front": Composite("wheel_torque_front", "sum", (Term(term_map(a, "a"), 2.0),))}
    prof = dataclasses.replace(profile(comps), channels={"accel_x": PAPER.channels["accel_x"]})
    with pytest.raises(ProfileError, match="ACCEL_X: it is also accel_x's signal"):
        Encoder(prof, DB)
