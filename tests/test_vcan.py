"""SocketCAN: `vdp serve` on a vcan0, fed by `vdp simulate`, in a private network namespace.

Runs where vcan0 can be created (`ip link add dev vcan0 type vcan`, inside
`unshare -n` so the host's interfaces are never touched); skips with the reason
elsewhere.  It also takes the interface down under the running service and up
again: the service must say so and resume by itself.
"""

from __future__ import annotations

import json
import textwrap

import pytest

from helpers.netns import HELPERS, ROOT, netns_reason, run_in_netns

pytestmark = [pytest.mark.slow, pytest.mark.netns, pytest.mark.timeout(900)]

SETUP = "ip link set lo up && ip link add dev vcan0 type vcan && ip link set vcan0 up"


def vcan_reason() -> str | None:
    return netns_reason(SETUP, "cannot create vcan0 here (no SocketCAN/vcan in this kernel?)")


VCAN_SCRIPT = HELPERS + textwrap.dedent(r"""
    tmp, root = sys.argv[1], sys.argv[2]
    port = 18080
    proc = serve(tmp, config(tmp, root, "socketcan", "vcan0", port, '''
    [service]
    reconnect_min = 0.1
    reconnect_max = 0.5
    silence = 1.0
    '''))
    out = {"first_health": wait_http(proc, port)}

    def simulate(seconds):
        r = subprocess.run(VDP + ["simulate", "--scenario", "paper", "--noise", "none", "--bus-interface",
                                  "socketcan", "--bus-channel", "vcan0", "--sim-speed", "1",
                                  "--duration", str(seconds)], capture_output=True, text=True, timeout=120)
        return frames_of(r.stdout)

    def settle(want):
        end = time.monotonic() + 20
        while time.monotonic() < end:
            st = json.loads(get(port, "/status"))
            if st["bus"]["frames"] >= want:
                break
            time.sleep(0.2)
        return json.loads(get(port, "/status"))

    out["sent1"] = simulate(6)
    out["status1"] = settle(out["sent1"])
    # the interface goes away under the service, then comes back
    subprocess.run(["ip", "link", "set", "vcan0", "down"], check=True)
    time.sleep(2.0)
    out["health_down"] = json.loads(get(port, "/health"))
    out["status_down"] = json.loads(get(port, "/status"))
    subprocess.run(["ip", "link", "set", "vcan0", "up"], check=True)
    end = time.monotonic() + 30
    while time.monotonic() < end and json.loads(get(port, "/status"))["bus"]["state"] != "up":
        time.sleep(0.1)
    time.sleep(1.0)
    out["sent2"] = simulate(3)
    out["status2"] = settle(out["sent1"] + out["sent2"])
    proc.send_signal(signal.SIGTERM)
    out["exit"] = proc.wait(60)
    out["serve_err"] = open(os.path.join(tmp, "serve.err")).read()[-3000:]
    print(json.dumps(out))
""")


def test_serve_on_vcan0_and_survive_the_interface_going_down(tmp_path):
    why = vcan_reason()
    if why:
        pytest.skip(why)
    out = run_in_netns(VCAN_SCRIPT, str(tmp_path), str(ROOT), setup=SETUP)
    s1 = out["status1"]
    assert s1["bus"]["interface"] == "socketcan" and s1["bus"]["frames"] == out["sent1"], out["serve_err"]
    assert s1["decode"]["decoded"] == out["sent1"] and s1["queue"]["dropped"] == 0
    # while down: no frames, and /health says why
    assert out["health_down"]["status"] == "degraded"
    # back up: it resumed by itself and got every frame sent after that
    s2 = out["status2"]
    assert s2["bus"]["state"] == "up"
    assert s2["bus"]["frames"] == out["sent1"] + out["sent2"], json.dumps(s2["bus"])
    assert out["exit"] == 0, out["serve_err"]
