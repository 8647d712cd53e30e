"""Network-namespace test helpers: run a script inside ``unshare -n`` (its own lo, multicast on it)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


NETNS_SETUP = "ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo"


def netns_reason(setup: str = NETNS_SETUP, cannot: str = "unshare -n is not permitted here") -> str | None:
    """Why ``setup`` cannot run inside a private network namespace here (None: it can).

    ``cannot`` starts the reason when the setup itself fails (e.g. no vcan in this kernel).
    """
    if not shutil.which("unshare") or not shutil.which("ip"):
        return "needs unshare (util-linux) and ip (iproute2)"
    try:
        r = subprocess.run(["unshare", "-n", "bash", "-c", setup], capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"unshare -n failed: {exc}"
    if r.returncode != 0:
        return f"{cannot}: {(r.stderr or r.stdout).strip()[:200]}"
    return None


def run_in_netns(script: str, *args: str, setup: str = NETNS_SETUP, timeout: float = 300) -> dict:
    """Run a Python script inside a fresh network namespace; it prints one JSON line last."""
    code = f'{setup} && exec "$0" "$@"'
    r = subprocess.run(
        ["unshare", "-n", "bash", "-c", code, sys.executable, "-c", script, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={"PATH": "/usr/sbin:/usr/bin:/sbin:/bin", "PYTHONPATH": str(ROOT / "service"), "HOME": "/tmp"},
    )
    if r.returncode != 0 or not r.stdout.strip():
        pytest.fail(f"netns script failed ({r.returncode}):\n{r.stdout[-3000:]}\n{r.stderr[-5000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


# Shared by the netns tests: start `vdp serve --config`, wait for HTTP, fetch JSON.
HELPERS = textwrap.dedent(r"""
    import json, os, re, signal, subprocess, sys, time, urllib.request
    VDP = [sys.executable, "-c", "import sys; from vdp.cli import main; sys.exit(main())"]

    def get(port, path):
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=10) as r:
            return r.read().decode()

    # vdp serve's TOML: the paper profile on the given bus, raw log and store under tmp
    def config(tmp, root, interface, channel, port, extra=""):
        return f'''
    profile = "{root}/profiles/paper.toml"
    [bus]
    interface = "{interface}"
    channel = "{channel}"
    [raw_log]
    dir = "{tmp}/raw"
    [store]
    path = "{tmp}/state.sqlite"
    [api]
    port = {port}
    ''' + extra

    def serve(tmp, config):
        cfg = os.path.join(tmp, "vdp.toml")
        with open(cfg, "w") as f:
            f.write(config)
        err = open(os.path.join(tmp, "serve.err"), "w")
        proc = subprocess.Popen(VDP + ["serve", "--config", cfg], stdout=err, stderr=err)
        return proc

    def wait_http(proc, port, limit=60):
        end = time.monotonic() + limit
        while time.monotonic() < end:
            if proc.poll() is not None:
                raise SystemExit(f"vdp serve exited with {proc.returncode}")
            try:
                return json.loads(get(port, "/health"))
            except OSError:
                time.sleep(0.1)
        raise SystemExit("vdp serve did not answer")

    def frames_of(text):
        return int(re.search(r"(\d+) frames", text).group(1))
""")
