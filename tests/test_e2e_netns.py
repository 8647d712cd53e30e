"""Cross-process end to end: `vdp simulate` on a udp_multicast bus, `vdp serve` in another process.

Everything runs inside a private network namespace (`unshare -n`: its own `lo`, with
a multicast route), so no packet ever reaches the host's network; the test skips
where that namespace cannot be made.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from vdp.io.logs import open_log

ROOT = Path(__file__).resolve().parents[1]

pytestmark = [pytest.mark.slow, pytest.mark.netns, pytest.mark.timeout(900)]

NETNS_SETUP = "ip link set lo up && ip link set lo multicast on && ip route add 224.0.0.0/4 dev lo"


def netns_reason() -> str | None:
    """Why a private network namespace with multicast on lo cannot be made here (None: it can)."""
    if not shutil.which("unshare") or not shutil.which("ip"):
        return "needs unshare (util-linux) and ip (iproute2)"
    try:
        r = subprocess.run(["unshare", "-n", "bash", "-c", NETNS_SETUP], capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"unshare -n failed: {exc}"
    if r.returncode != 0:
        return f"unshare -n is not permitted here: {(r.stderr or r.stdout).strip()[:200]}"
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

UDP_SCRIPT = HELPERS + textwrap.dedent(r"""
    tmp, root = sys.argv[1], sys.argv[2]
    port = 18080  # a private namespace: nothing else listens here
    proc = serve(tmp, f'''
    profile = "{root}/profiles/paper.toml"
    [bus]
    interface = "udp_multicast"
    channel = "239.74.163.2"
    [raw_log]
    dir = "{tmp}/raw"
    [store]
    path = "{tmp}/state.sqlite"
    [api]
    port = {port}
    ''')
    out = {"first_health": wait_http(proc, port)}
    sim = subprocess.run(VDP + ["simulate", "--scenario", "paper", "--noise", "none", "--seed", "1",
                                "--bus-interface", "udp_multicast", "--sim-speed", "1", "--duration", "12"],
                         capture_output=True, text=True, timeout=120)
    out["sim"] = sim.stdout + sim.stderr
    out["sent"] = frames_of(sim.stdout)
    end = time.monotonic() + 20
    while time.monotonic() < end:
        st = json.loads(get(port, "/status"))
        if st["estimation"]["frames"] >= out["sent"]:
            break
        time.sleep(0.2)
    out["status"] = json.loads(get(port, "/status"))
    out["estimates_text"] = get(port, "/estimates")
    out["health"] = json.loads(get(port, "/health"))
    out["metrics"] = get(port, "/metrics")
    proc.send_signal(signal.SIGTERM)
    out["exit"] = proc.wait(60)
    out["raw"] = sorted(os.path.join(tmp, "raw", n) for n in os.listdir(os.path.join(tmp, "raw")))
    out["serve_err"] = open(os.path.join(tmp, "serve.err")).read()[-3000:]
    print(json.dumps(out))
""")


def test_simulate_and_serve_in_two_processes_over_udp_multicast(tmp_path):
    why = netns_reason()
    if why:
        pytest.skip(why)
    out = run_in_netns(UDP_SCRIPT, str(tmp_path), str(ROOT))
    sent = out["sent"]
    st = out["status"]
    assert sent > 5000, out["sim"]
    assert out["first_health"]["status"] == "degraded"  # no frames yet: it says so
    assert st["bus"]["state"] == "up" and st["bus"]["interface"] == "udp_multicast"
    assert st["bus"]["frames"] == sent and st["queue"]["dropped"] == 0, out["serve_err"]
    assert st["decode"]["decoded"] == sent and st["decode"]["errors"] == {}
    assert st["estimation"]["frames"] == sent and st["estimation"]["errors"] == 0
    assert "NaN" not in out["estimates_text"]
    est = json.loads(out["estimates_text"])
    # The receiver stamps frames with its own clock; at 1x that is the drive's own timing,
    # and stage 1's filter has run on the frames that crossed the process boundary.
    assert all(est["parameters"][n]["samples"] > 0 for n in ("l_f", "h", "C_K")), est["parameters"]
    assert f"vdp_frames_received_total {float(sent)}" in out["metrics"]
    assert out["exit"] == 0, out["serve_err"]
    # SIGTERM closed the raw log: complete files holding every frame
    files = [Path(p) for p in out["raw"]]
    assert files and not any(p.name.endswith("current.log") for p in files)
    total = 0
    for p in files:
        src = open_log(p)
        total += sum(1 for _ in src)
        assert src.stats.bad == 0
    assert total == sent
