"""Every frame the kernel drops is counted: a receive buffer shrunk inside a private network namespace.

The service reads udp_multicast (the bus stand-in) with a receive buffer of a few KiB; while the
raw log is held (as a long pause of the receive thread would), a burst overflows the socket and
the kernel drops datagrams.  The counted drops must equal the frames missing from the raw log,
exactly, and /status, /metrics, /health and the raw log's index must say so.  Runs inside
``unshare -n`` (nothing reaches the host's network); skipped where that cannot be made.
"""

from __future__ import annotations

import textwrap

import pytest

from helpers.netns import ROOT, netns_reason, run_in_netns

pytestmark = [pytest.mark.slow, pytest.mark.netns, pytest.mark.timeout(600)]

SCRIPT = textwrap.dedent(r"""
    import glob, json, os, sys, time
    from pathlib import Path
    import can
    from vdp.live import Service
    from vdp.settings import BusSettings, RawLogSettings, ServiceSettings, Settings, StoreSettings, ApiSettings

    tmp, root = Path(sys.argv[1]), Path(sys.argv[2])
    group = "239.74.163.21"
    settings = Settings(
        profile=root / "profiles" / "paper.toml",
        bus=BusSettings(interface="udp_multicast", channel=group, bitrate=None, listen_only=False,
                        receive_buffer=4096),
        raw_log=RawLogSettings(dir=tmp / "raw", max_bytes=1 << 20, max_files=8),
        store=StoreSettings(path=tmp / "state.sqlite", commit_interval=0.05),
        api=ApiSettings(),
        service=ServiceSettings(publish_interval=0.05),
        source="test",
    )
    svc = Service(settings)
    svc.start()
    end = time.monotonic() + 30
    while not svc.link.up and time.monotonic() < end:
        time.sleep(0.01)
    tx = can.Bus(interface="udp_multicast", channel=group)

    def burst(n, first):
        for k in range(n):
            tx.send(can.Message(timestamp=first + k * 1e-4, arbitration_id=0x7F0, is_extended_id=False,
                                data=(first + k).to_bytes(8, "big")))

    def settle(count):
        # quiet until the receive thread has read everything the kernel kept
        last, end = -1, time.monotonic() + 30
        while time.monotonic() < end:
            time.sleep(0.3)
            if svc.intake.received == last:
                return
            last = svc.intake.received

    sent = 0
    out = {"buffer": svc.link.info.receive_buffer}
    with svc.rawlog._lock:              # the receive thread stalls on the raw log, as in a long pause
        burst(3000, 10000); sent += 3000
        time.sleep(0.3)
    settle(sent)
    svc.housekeeping()                  # the keeper reads the counter (it also does every 0.5 s)
    out["health"] = svc.health()
    out["status_bus"] = svc.status()["bus"]
    out["metrics"] = {k: v for k, v in svc.metrics().items() if k in ("kernel_drops", "frames", "healthy")}
    from vdp.api import create_app
    from prometheus_client import generate_latest
    app = create_app(settings, svc)
    from vdp.api import metrics as m
    m_text = generate_latest(app.state.registry).decode()
    out["prom"] = [ln for ln in m_text.splitlines() if ln.startswith("vdp_frames_lost")]
    tx.shutdown()
    svc.stop()
    lines = 0
    for p in glob.glob(str(tmp / "raw" / "vdp-*.log")):
        with open(p) as f:
            lines += sum(1 for ln in f if "#" in ln)
    out.update(sent=sent, received=svc.intake.received, raw_lines=lines,
               kernel_drops=svc.link.info.kernel_drops, raw_lost=svc.rawlog.lost)
    idx = tmp / "raw" / "vdp-index.jsonl"
    out["index"] = [json.loads(ln) for ln in idx.read_text().splitlines()] if idx.exists() else []
    print(json.dumps(out))
""")


def test_forced_kernel_drops_are_counted_exactly(tmp_path):
    why = netns_reason()
    if why:
        pytest.skip(why)
    out = run_in_netns(SCRIPT, str(tmp_path), str(ROOT))
    print({k: out[k] for k in ("sent", "received", "raw_lines", "kernel_drops", "buffer")})
    drops = out["kernel_drops"]
    assert drops and drops > 0, f"the burst should have overflowed a {out['buffer']}-byte buffer"
    # every frame is either in the raw log or counted as dropped: the count is exact
    assert out["raw_lost"] == 0
    assert out["received"] == out["raw_lines"]
    assert out["sent"] - out["raw_lines"] == drops
    # said everywhere
    assert out["status_bus"]["dropped"]["kernel"] == drops
    assert out["metrics"]["kernel_drops"] == drops and not out["metrics"]["healthy"]
    assert out["health"]["status"] == "degraded"
    assert any("dropped by the kernel" in r for r in out["health"]["reasons"])
    assert any('cause="kernel_receive_buffer"' in ln and ln.endswith(f" {float(drops)}") for ln in out["prom"])
    # the raw log's index: the file that was open during the burst carries them
    assert sum(e["dropped"]["kernel"] for e in out["index"]) == drops
    assert sum(e["frames"] for e in out["index"]) == out["raw_lines"]
