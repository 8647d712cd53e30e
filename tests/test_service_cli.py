"""`vdp serve` on the command line: clear one-line errors, never a half-started service."""

from __future__ import annotations

import socket
from pathlib import Path

from vdp.cli import main as vdp_main

ROOT = Path(__file__).resolve().parents[1]


def test_config_or_simulate_is_required(capsys):
    assert vdp_main(["serve"]) == 2
    assert "give either --config FILE" in capsys.readouterr().err
    assert vdp_main(["serve", "--simulate", "--config", str(ROOT / "deploy" / "vdp.toml")]) == 2


def test_a_bad_config_is_one_line(tmp_path, capsys):
    cfg = tmp_path / "vdp.toml"
    cfg.write_text('profile = "p.toml"\n[bus]\nbitrat = 1\n')
    assert vdp_main(["serve", "--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert "unknown key(s) ['bitrat']" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_a_busy_port_is_refused_before_anything_starts(tmp_path, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        code = vdp_main(
            [
                "serve",
                "--simulate",
                "--port",
                str(port),
                "--db",
                str(tmp_path / "db.sqlite"),
                "--raw-dir",
                str(tmp_path / "raw"),
            ]
        )
    assert code == 2
    assert f"cannot listen on 127.0.0.1:{port}" in capsys.readouterr().err
    assert not (tmp_path / "db.sqlite").exists() and not (tmp_path / "raw").exists()


def test_python_m_vdp_is_the_vdp_command():
    """`python -m vdp` where the venv's scripts are not on PATH: the same CLI, its exit code kept."""
    import subprocess
    import sys

    ok = subprocess.run([sys.executable, "-m", "vdp", "--version"], capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0 and ok.stdout.startswith("vdp "), ok
    bad = subprocess.run([sys.executable, "-m", "vdp", "no-such-command"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "no-such-command" in bad.stderr
