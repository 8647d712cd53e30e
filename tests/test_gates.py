"""Gates for what the model does not cover (core.gates): each gate from its own evidence, its hold,
its count, the drive's sentence; the supervisor shutting its windows by them; a profile's status
flags (active_when) decoded and encoded; and a seeded simulated drive with reverse manoeuvres,
ABS stops, kerb strikes and wheel spin against the same drive without them."""

import math

import pytest

from vdp import channels as ch
from vdp.core import gates as gt
from vdp.core.sample import Sample
from vdp.core.supervisor import REASONS, Supervisor
from vdp.errors import ProfileError
from vdp.profile import load_profile

R = 0.3  # m, the wheel radius the gates are made with


def values(speed=20.0, ay=0.0, yaw=0.0, wheels=None, gnss=None, **flags):
    y = [0.0] * ch.N
    for i, w in zip((ch.WS_FL, ch.WS_FR, ch.WS_RL, ch.WS_RR), wheels or (speed,) * 4):
        y[i] = w / R
    y[ch.AY], y[ch.YAW] = ay, yaw
    y[ch.SPEED] = speed if gnss is None else gnss
    for name in ch.STATUS:
        y[ch.INDEX[name]] = flags.get(name, math.nan)  # not mapped: NaN
    return y


def feed(g, rows, t0=0.0, dt=0.02):
    return [g.update(t0 + k * dt, False, y) for k, y in enumerate(rows)]


def test_ordinary_driving_passes_every_gate():
    g = gt.Gates(wheel_radius=R)
    # cornering at 3 m/s^2 (a_y = v r), the inner and outer wheels 4 % apart, braking slip on one axle
    rows = [values(15.0, ay=3.0, yaw=0.2, wheels=(14.7, 15.3, 14.7, 15.3))] * 50
    rows += [values(15.0, wheels=(13.8, 13.8, 15.0, 15.0), reverse=0.0, abs_active=0.0)] * 50
    assert set(feed(g, rows)) == {0}
    assert g.summary()["text"] == "nothing of the drive gated out"


@pytest.mark.parametrize(
    "row, code",
    [
        (values(2.0, reverse=1.0), gt.REVERSE),  # the gear
        (values(gnss=-1.2, speed=1.2), gt.REVERSE),  # a signed GNSS speed
        (values(-1.2), gt.REVERSE),  # signed wheel speeds (and GNSS)
        (values(12.0, abs_active=1.0), gt.ABS),
        (values(12.0, esc_active=1.0), gt.ESC),
        (values(12.0, tcs_active=1.0), gt.TCS),
        (values(12.0, ay=6.5, yaw=0.05), gt.KERB),  # 6.5 m/s^2 where the yaw explains 0.6
        (values(8.0, wheels=(13.0, 8.0, 8.0, 8.0)), gt.SPIN),  # one wheel 5 m/s ahead of the others
        (values(8.0, wheels=(11.0, 11.0, 11.0, 11.0), gnss=8.0), gt.SPIN),  # all four ahead of the ground
        (values(0.1), gt.STANDSTILL),
        (values(1.0), gt.CREEP),
    ],
)
def test_each_gate_from_its_evidence(row, code):
    g = gt.Gates(wheel_radius=R)
    assert g.update(0.0, False, row) == code


def test_a_gate_holds_after_its_cause_and_the_first_of_several_counts():
    g = gt.Gates(wheel_radius=R)
    codes = feed(g, [values(12.0, abs_active=1.0, esc_active=1.0)] * 10 + [values(12.0)] * 40)
    # ABS before ESC; 0.5 s after the flag goes (the sample at 0.18 s was its last) the gate opens
    assert codes[:10] == [gt.ABS] * 10
    assert set(codes[10:34]) == {gt.ABS} and set(codes[35:]) == {0}  # (0.68 s itself: at the float's whim)
    s = g.summary()
    n = codes.count(gt.ABS)
    assert s["by_gate"]["ABS"]["seconds"] == pytest.approx(0.01 + (n - 1) * 0.02)  # (the first sample counts 10 ms)
    assert "ESC" not in s["by_gate"]
    assert s["text"] == f"{100 * s['fraction']:.0f} % of the drive gated out: ABS {100 * s['fraction']:.0f} %"
    assert 0.65 < s["fraction"] < 0.72


def test_a_missing_or_stale_flag_gates_nothing():
    g = gt.Gates(wheel_radius=R)
    y = values(12.0)
    y[ch.AY] = y[ch.YAW] = math.nan
    y[ch.WS_FL] = y[ch.WS_FR] = math.nan  # two wheels: no spin test
    assert feed(g, [y] * 5) == [0] * 5


def test_the_sentence_names_each_gate_with_its_share():
    s = gt.summary({"reverse": 6.0, "ABS": 30.0, "kerb strike": 0.0}, 36.0, 600.0)
    assert s["text"] == "6 % of the drive gated out: reverse 1 %, ABS 5 %"
    assert s["fraction"] == 0.06 and s["by_gate"]["ABS"] == {"seconds": 30.0, "fraction": 0.05}
    assert gt.summary({}, 0.0, 0.0)["text"] == "no data yet"


def sample(t, speed=20.0, ax=0.0, **flags):
    y = values(speed, **flags)
    y[ch.AX], y[ch.T_F], y[ch.T_R], y[ch.DELTA], y[ch.AY] = ax, 100.0, 100.0, 0.0, 0.0
    return Sample(t, tuple(y), (True,) * ch.N, (0.0,) * ch.N, v_x=speed)


def test_a_gate_shuts_the_supervisors_open_window_at_once_and_says_why():
    sup = Supervisor(wheel_radius=R)
    stages = [sup.update(k * 0.01, sample(k * 0.01, ax=3.0 * math.sin(k * 0.05)), False) for k in range(600)]
    assert stages[-1] == 1  # straight acceleration and braking: stage 1's window open
    t = 6.0
    assert sup.update(t, sample(t, ax=-4.0, abs_active=1.0), False) is None  # shut at once, no t_off
    assert sup.reason[1] == REASONS[gt.ABS + 8] == "gated out: ABS"
    assert sup.state()["gated"]["by_gate"]["ABS"]["seconds"] > 0
    # the driving's own reasons come first: at standstill the gate counts but the reason stays the speed
    sup.update(t + 0.01, sample(t + 0.01, speed=0.0), False)
    assert sup.reason[1].startswith("speed below")


def test_a_profile_maps_a_gear_enum_and_status_bits(repo_root, tmp_path):
    prof = load_profile(repo_root / "profiles" / "paper_status.toml")
    assert prof.channels["reverse"].active == frozenset({1}) and prof.channels["abs_active"].active is None
    text = (repo_root / "profiles" / "paper.toml").read_text()
    text = text.replace('dbc = "../dbc/vdp.dbc"', f'dbc = "{repo_root / "dbc" / "vdp.dbc"}"')
    for extra, words in (
        ('speed = { message = "GNSS_VELOCITY", signal = "GNSS_SPEED", unit = "m/s", active_when = [1] }',
         "applies to the status flags only"),
        ('reverse = { message = "VEHICLE_STATUS", signal = "GEAR", unit = "1", active_when = 1 }',
         "must be a list of the signal's raw integer values"),
        ('reverse = { message = "VEHICLE_STATUS", signal = "GEAR", unit = "m/s" }', "cannot be converted"),
    ):  # fmt: skip
        lines = [ln for ln in text.splitlines() if not ln.startswith(extra.split(" ")[0] + " ")]
        at = lines.index("[checks]")
        p = tmp_path / "p.toml"
        p.write_text("\n".join(lines[:at] + [extra, ""] + lines[at:]) + "\n")
        with pytest.raises(ProfileError, match=words):
            load_profile(p)


def test_the_status_flags_go_on_the_bus_and_come_back(repo_root):
    from vdp.io.decoder import FrameDecoder
    from vdp.sim.encode import Encoder

    prof = load_profile(repo_root / "profiles" / "paper_status.toml")
    enc, dec = Encoder(prof), FrameDecoder(prof)
    plan = next(p for p in enc.plans if p.name == "VEHICLE_STATUS")
    assert sorted(plan.channels) == sorted(ch.STATUS)
    import can

    for flags in ((1.0, 0.0, 1.0, 0.0), (0.0, 1.0, 0.0, 1.0)):
        data = enc.encode(plan, dict(zip(ch.STATUS, flags)))
        got = dict(
            dec.decode(can.Message(timestamp=1.0, arbitration_id=plan.frame_id, data=data, is_extended_id=False))
        )
        assert [got[ch.INDEX[n]] for n in ch.STATUS] == list(flags)
    gear = plan.message.decode(enc.encode(plan, dict(zip(ch.STATUS, (1.0, 0.0, 0.0, 0.0)))), decode_choices=False)
    assert gear["GEAR"] == 1  # REVERSE in vdp.dbc's table


# -- a seeded drive with the events against the same drive without them ---------------------------
EVENTS = "reverse=2,abs=2,kerb=4,spin=2"


@pytest.fixture(scope="module")
def drives(repo_root, tmp_path_factory):
    """The city drive (seed 11) with the events and without them, replayed with the status profile."""
    from vdp.pipeline import Pipeline
    from vdp.replay import replay_log
    from vdp.sim.events import Events
    from vdp.sim.run import Simulation, write_log

    prof = load_profile(repo_root / "profiles" / "paper_status.toml")
    d = tmp_path_factory.mktemp("gates")
    out = {}
    for effects in (True, False):
        sim = Simulation(prof, "city", seed=11, events=Events.parse(EVENTS, effects=effects))
        path = d / f"city_{effects}.log"
        write_log(sim.frames(), path)
        out[effects] = (replay_log(path, lambda: Pipeline(prof))[0], sim.truth)
    return out


@pytest.mark.slow
def test_the_gate_counts_match_the_events(drives):
    (res, truth), (plain, _) = drives[True], drives[False]
    g, g0 = res.supervisor["gated"]["by_gate"], plain.supervisor["gated"]["by_gate"]
    plan = truth["events"]["plan"]
    hold = gt.GatesConfig().hold
    end = truth["duration"]
    span = {
        k: sum(min(e["end"] + hold, end) - e["start"] for e in plan if e["kind"] == k)
        for k in ("reverse", "kerb", "spin")
    }
    # reverse: the gear's span, plus the hold (up to the drive's end); the sensors are sampled every 20 ms
    # (tolerance 0.1 s an event)
    assert g["reverse"]["seconds"] == pytest.approx(span["reverse"], abs=0.2)
    # a kerb strike: the part of its 80-ms pulse above the gate's threshold, and the hold, each
    # (tolerance: the pulse's 80 ms an event)
    assert g["kerb strike"]["seconds"] == pytest.approx(span["kerb"], abs=4 * 0.08)
    assert g["kerb strike"]["seconds"] >= 4 * hold  # every kerb seen
    # the spin: traction control's flag on meanwhile (TCS counts before the wheel's own test)
    assert g["TCS"]["seconds"] == pytest.approx(span["spin"], abs=0.2)
    assert g["ABS"]["seconds"] > 2.0  # the driver's ABS regulated on both slippery patches
    for k in ("reverse", "kerb strike", "TCS", "ABS", "wheel spin", "ESC"):
        assert k not in g0, k  # the same drive without the events: none of these gates fired
    assert set(g0) <= {"standstill", "creep"}


@pytest.mark.slow
def test_the_estimates_agree_with_the_drive_without_the_events(drives):
    (res, _), (plain, _) = drives[True], drives[False]
    for name in ("l_f", "h", "C_K", "C_alpha", "I_z"):
        a, b = res.parameters[name], plain.parameters[name]
        sd = math.hypot(a.std, b.std)
        assert abs(a.value - b.value) <= 2.0 * sd, (name, a.value, b.value, sd)  # within 2 sigma of the difference


@pytest.mark.slow
def test_the_fleet_rows_carry_the_gated_share(drives):
    from vdp.core.params import PUBLISHED
    from vdp.fleet import Task, rows_from_result

    res = drives[True][0]
    rows = rows_from_result(res, Task("city.log", "paper", "paper_status.toml"))
    g = res.supervisor["gated"]
    assert len(rows) == len(PUBLISHED) and {r["gated"] for r in rows} == {g["fraction"]} and g["fraction"] > 0.1
    assert rows[0]["gated_by"] == g["text"] and "reverse" in g["text"]


# -- a kerb strike's rise: the look-ahead -----------------------------------------------------------
# the simulator's 80-ms half-sine of 6 m/s^2 on a_y as 20-ms ticks read it (sim.events): the test
# (kerb_ay 5) fires at its peak; the two ticks of its rise carry 0.5 and 4 m/s^2, and 0.04 and 0.28 rad/s
# of roll rate, far beyond the model too (benchmarks/gates.py: let into stage 2, I_x read 2.5e12)
PULSE = (0.5, 4.0, 5.7, 4.0, 0.5)


def strike(before=20, after=40, v=15.0, yaw=0.2):
    cruise = values(v, ay=v * yaw, yaw=yaw)
    rows = [cruise] * before
    for a in PULSE:
        rows.append(values(v, ay=v * yaw + a, yaw=yaw))
    return rows + [cruise] * after


def feed_ahead(g, rows, look, dt=0.02):
    """What vdp.pipeline does: each sample shown to the kerb test ``look`` samples before its turn."""
    out = []
    for k, y in enumerate(rows):
        if k == 0:
            for j in range(min(look, len(rows))):
                g.ahead(j * dt, rows[j])
        if k + look < len(rows):
            g.ahead((k + look) * dt, rows[k + look])
        out.append(g.update(k * dt, False, y))
    return out


def test_a_kerb_strike_is_gated_from_its_rise_when_the_samples_come_ahead():
    cfg = gt.GatesConfig()
    look = math.ceil(cfg.kerb_pre / 0.02 - 1e-9)
    fire = 20 + PULSE.index(5.7)  # the first sample over kerb_ay
    codes = feed_ahead(gt.Gates(cfg, wheel_radius=R), strike(), look)
    first = codes.index(gt.KERB)
    assert first <= 20  # the rise's every sample gated ...
    assert fire - first == look  # ... from kerb_pre before the sample that fires, no earlier
    assert set(codes[first : fire + int(cfg.hold / 0.02)]) == {gt.KERB} and set(codes[:first]) == {0}
    # shown no sample ahead (a caller that calls update alone): from the sample that fires, as before
    plain = feed(gt.Gates(cfg, wheel_radius=R), strike())
    assert plain.index(gt.KERB) == fire
    # the hold after is the same either way; the look-ahead adds kerb_pre to the count
    assert codes[fire:] == plain[fire:]


def test_brisk_steering_gates_nothing_with_the_look_ahead():
    # the light stiff-tyre car's brisk steering: |a_y - v r| up to 3.2 m/s^2 (benchmarks/robust.py's
    # light car on the paper drive), in a burst of the same shape as a strike
    rows = [values(15.0, ay=3.0 + a * 3.2 / 5.7, yaw=0.2) for a in (0.0,) * 20 + PULSE + (0.0,) * 40]
    g = gt.Gates(wheel_radius=R)
    assert set(feed_ahead(g, rows, 3)) == {0}
    assert g.summary()["text"] == "nothing of the drive gated out"


def test_a_second_strike_within_the_hold_extends_it_and_a_later_one_starts_its_own_rise():
    cfg = gt.GatesConfig()
    hold = int(cfg.hold / 0.02)
    near = strike(after=10) + strike(before=0)  # the second fires 0.3 s after the first: one gated span
    codes = feed_ahead(gt.Gates(cfg, wheel_radius=R), near, 3)
    assert set(codes[:19]) == {0} and set(codes[19 : 37 + hold]) == {gt.KERB}
    far = strike(after=60) + strike(before=0)  # 1.3 s after: its own rise, from kerb_pre before it fires
    codes = feed_ahead(gt.Gates(cfg, wheel_radius=R), far, 3)
    assert set(codes[22 + hold + 1 : 84]) == {0} and set(codes[84 : 87 + hold]) == {gt.KERB}


def test_the_pipeline_takes_each_sample_after_the_gates_saw_the_next_ones(repo_root, monkeypatch):
    """vdp.pipeline's look-ahead: every sample reaches the estimator once, in order, look_ahead samples
    after it came (the gates saw it at once); a gap, and the log's end (run), take the samples held."""
    from vdp.core.estimator import TwoStageEstimator
    from vdp.pipeline import Pipeline

    pipe = Pipeline(load_profile(repo_root / "profiles" / "paper.toml"))
    look = pipe.look_ahead()
    assert look == math.ceil(gt.GatesConfig().kerb_pre / pipe.estimator.cfg.tick - 1e-9) >= 2
    taken, seen = [], []
    monkeypatch.setattr(TwoStageEstimator, "handle", lambda self, t, s: taken.append(t) or s)
    monkeypatch.setattr(TwoStageEstimator, "ahead", lambda self, s: seen.append(s.t))
    rows = [sample(0.02 * k) for k in range(10)]
    rows[0] = rows[0]._replace(gap=True)
    pipe.take(rows[:1])  # (one at a time, the first after a gap: as the aligner hands them)
    pipe.take(rows[1:6])
    assert seen == [s.t for s in rows[:6]] and taken == [s.t for s in rows[: 6 - look]]
    gap = rows[6]._replace(gap=True)
    pipe.take([gap, *rows[7:]])
    assert taken == [s.t for s in rows[: 10 - look]]  # the gap took the samples held before it
    pipe.flush()
    assert taken == [s.t for s in rows] and pipe.samples == 10
