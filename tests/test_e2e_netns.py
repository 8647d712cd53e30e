"""Cross-process end to end: `vdp simulate` on a udp_multicast bus, `vdp serve` in another process.

Everything runs inside a private network namespace (`unshare -n`: its own `lo`, with
a multicast route), so no packet ever reaches the host's network; the test skips
where that namespace cannot be made.
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import pytest

from helpers.netns import HELPERS, ROOT, netns_reason, run_in_netns
from vdp.io.logs import open_log

pytestmark = [pytest.mark.slow, pytest.mark.netns, pytest.mark.timeout(900)]

UDP_SCRIPT = HELPERS + textwrap.dedent(r"""
    tmp, root = sys.argv[1], sys.argv[2]
    port = 18080  # a private namespace: nothing else listens here
    proc = serve(tmp, config(tmp, root, "udp_multicast", "239.74.163.2", port))
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
    # the raw log files only, not the directory's lock file (.vdp.lock) nor the index (vdp-index.jsonl)
    raw = os.path.join(tmp, "raw")
    out["raw"] = sorted(os.path.join(raw, n) for n in os.listdir(raw) if n.endswith(".log"))
    out["index"] = open(os.path.join(raw, "vdp-index.jsonl")).read().splitlines()
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
    # the raw log's index: a line per closed file, its frames, and none lost before vdp read them
    index = [json.loads(line) for line in out["index"]]
    assert sum(e["frames"] for e in index) == sent and all(e["dropped"]["kernel"] == 0 for e in index)
    assert st["bus"]["dropped"]["kernel"] == 0
