"""Typed service settings: the example config loads, every mistake names its key."""

from __future__ import annotations

from pathlib import Path

import pytest

from vdp.errors import ConfigError
from vdp.live.bus import bus_kwargs
from vdp.settings import BusSettings, load_settings, simulate_settings

ROOT = Path(__file__).resolve().parents[1]


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "vdp.toml"
    p.write_text(text)
    return p


def test_the_example_config_loads():
    s = load_settings(ROOT / "deploy" / "vdp.toml")
    assert s.bus.interface == "socketcan" and s.bus.channel == "can0" and s.bus.receive_own_messages is False
    assert s.api.host == "127.0.0.1" and s.api.port == 8000 and s.api.reset_token is None
    assert s.raw_log.max_files >= 2 and s.store.path.is_absolute()


def test_defaults_and_relative_paths(tmp_path):
    s = load_settings(write(tmp_path, 'profile = "p.toml"\n[store]\npath = "db/x.sqlite"\n'))
    assert s.profile == (tmp_path / "p.toml").resolve()
    assert s.store.path == (tmp_path / "db" / "x.sqlite").resolve()
    assert s.api.host == "127.0.0.1" and s.bus.listen_only is True
    assert s.service.per_axle is True  # each axle's C_alpha, as vdp replay (LearnerConfig.per_axle)


def test_per_axle_reaches_the_live_estimator(tmp_path):
    from vdp.live.service import Service

    s = load_settings(write(tmp_path, f'profile = "{ROOT / "profiles" / "paper.toml"}"\n[service]\nper_axle = true\n'))
    assert s.service.per_axle is True
    svc = Service(s)  # built, not started
    assert all(l2.cfg.per_axle for l2 in svc.estimation.pipeline.estimator.s2.values())


def test_road_reaches_the_live_estimator(tmp_path):
    """``[service] road = true`` models the road as ``vdp replay --road`` does: the grade and the IMU's
    tilt (core.road.Tilt) and the bank as stage 2's tenth state; off by default, nine states."""
    from vdp.core import lateral
    from vdp.live.service import Service

    prof = f'profile = "{ROOT / "profiles" / "paper.toml"}"\n'
    off = Service(load_settings(write(tmp_path, prof))).estimation.pipeline.estimator
    assert off.tilt is None and not off.s2["ukf"].cfg.bank
    s = load_settings(write(tmp_path, prof + "[service]\nroad = true\n"))
    assert s.service.road is True
    est = Service(s).estimation.pipeline.estimator  # built, not started
    assert est.tilt is not None and est.cfg.road.on and est.s2["ukf"].cfg.bank
    assert est.s2["ukf"]._n == lateral.BANK + 1 and off.s2["ukf"]._n == lateral.N_X  # ten states, or nine


@pytest.mark.parametrize(
    "text, match",
    [
        ('[bus]\ninterface = "socketcan"\n', "'profile' is missing"),
        ('profile = "p.toml"\n[bus]\nbitrat = 5\n', r"\[bus\]: unknown key\(s\) \['bitrat'\]"),
        ('profile = "p.toml"\n[bus]\nbitrate = "fast"\n', r"\[bus\] 'bitrate': must be an integer"),
        ('profile = "p.toml"\n[bus]\nreceive_own_messages = true\n', "'receive_own_messages': must be false"),
        ('profile = "p.toml"\n[api]\nport = 70000\n', r"\[api\] 'port': must be within"),
        ('profile = "p.toml"\n[api]\nreset_token = "short"\n', "'reset_token': must be at least 16"),
        ('profile = "p.toml"\n[raw_log]\nmax_files = 1\n', "'max_files': must be at least 2"),
        ('profile = "p.toml"\n[store]\nsynchronous = "off"\n', "'synchronous'"),
        ('profile = "p.toml"\n[service]\nreconnect_max = 0.1\n', "'reconnect_max'"),
        ('profile = "p.toml"\n[service]\nper_axle = "yes"\n', "'per_axle'"),
        ('profile = "p.toml"\n[service]\nroad = 1\n', "'road'"),
        ('profile = "p.toml"\n[bus.kwargs]\nchannel = "x"\n', r"\[bus.kwargs\]"),
        ('profile = "p.toml"\n[mystery]\n', "unknown section"),
        ('profile = "p.toml"\nbus = 3\n', r"\[bus\]: must be a table"),
        ("profile = \n", "not valid TOML"),
        # a typo'd interface is refused at start (it was retried for ever, as if the car were off)
        ('profile = "p.toml"\n[bus]\ninterface = "socketcn"\n', "no interface 'socketcn'.*did you mean 'socketcan'"),
        ('profile = "p.toml"\n[raw_log]\ndir = "afile"\n', r"\[raw_log\] 'dir' \(--raw-dir\): .*afile is a file"),
        ('profile = "p.toml"\n[store]\npath = "."\n', r"\[store\] 'path' \(--db\): .* is a folder"),
    ],
)
def test_mistakes_name_the_key(tmp_path, text, match):
    (tmp_path / "afile").write_text("not a folder")
    with pytest.raises(ConfigError, match=match):
        load_settings(write(tmp_path, text))


def test_missing_config_file(tmp_path):
    with pytest.raises(ConfigError, match="no such config file"):
        load_settings(tmp_path / "nope.toml")


def test_listen_only_where_python_can_offers_it():
    assert bus_kwargs(BusSettings(interface="slcan", channel="/dev/ttyACM0"))["listen_only"] is True
    assert bus_kwargs(BusSettings(interface="kvaser", channel="0"))["driver_mode"] is False
    kw = bus_kwargs(BusSettings(interface="socketcan", channel="can0"))
    assert kw["receive_own_messages"] is False and "listen_only" not in kw  # no such flag: set on the netdev
    assert "listen_only" not in bus_kwargs(BusSettings(interface="slcan", channel="x", listen_only=False))


def test_simulate_settings_are_valid_and_local(tmp_path):
    s = simulate_settings(ROOT / "profiles" / "paper.toml", tmp_path)
    assert s.simulate.enabled and s.bus.interface == "virtual" and s.api.host == "127.0.0.1"
    assert s.store.path.parent == tmp_path and s.raw_log.dir.parent == tmp_path


def test_the_raw_logs_lock_is_in_its_folder_and_a_file_in_the_way_is_named(tmp_path):
    """A logger writing straight to a USB stick's mount point may not write the mount point's
    parent: the raw log's lock goes in its own folder; a file where a folder must be is named."""
    from vdp.live.lock import service_lock

    base = load_settings(write(tmp_path, 'profile = "p.toml"\n[raw_log]\ndir = "stick"\n[store]\npath = "s.sqlite"\n'))
    with service_lock(base) as lock:
        assert (tmp_path / "stick" / ".vdp.lock").is_file() and len(lock._fds) == 2
    (tmp_path / "afile").write_text("")
    bad = load_settings(write(tmp_path, 'profile = "p.toml"\n[store]\npath = "afile/state.sqlite"\n'))
    with pytest.raises(ConfigError, match=r"the estimate store needs the folder .*afile, but .*afile is a file"):
        service_lock(bad).acquire()


def test_the_mass_modes_are_one_vocabulary_and_a_wrong_one_is_refused(tmp_path):
    """[service] mass, vdp replay/batch --mass and core.mass.MassConfig take the same words; the
    switch of before ("true"/"false") still reads as on/off; another word is refused by name."""
    from vdp.core.mass import MODES
    from vdp.settings import MASS_MODES, load_settings

    assert MASS_MODES == MODES
    prof = Path(__file__).resolve().parents[1] / "profiles" / "paper.toml"
    for value, mode in (("true", "on"), ("false", "off"), ('"report"', "report")):
        cfg = tmp_path / "vdp.toml"
        cfg.write_text(f'profile = "{prof}"\n[service]\nmass = {value}\n')
        assert load_settings(cfg).service.mass == mode
    cfg.write_text(f'profile = "{prof}"\n[service]\nmass = "yes"\n')
    with pytest.raises(ConfigError, match="'mass': must be one of auto, on, report, off"):
        load_settings(cfg)
