"""Live-service test helpers: a small fake pipeline, settings for a test service, a frame sender, waits."""

from __future__ import annotations

import itertools
import math
import time
from pathlib import Path

import can
import pytest

from vdp.core.result import Estimate, WindowSpan
from vdp.result import Clock, Freshness, RunResult
from vdp.settings import ApiSettings, BusSettings, RawLogSettings, ServiceSettings, Settings, StoreSettings

ROOT = Path(__file__).resolve().parents[2]
NAMES = ("l_f", "h", "C_K", "C_alpha", "I_z", "I_x")
_chan = itertools.count()


class FakePipeline:
    """What the service needs of vdp.pipeline.Pipeline; l_f follows the first data byte of each frame."""

    def __init__(self):
        self.frames = 0
        self.samples = 0
        self.last_bus_time = None
        self.resets: list = []
        self.restored = None
        self.lf = 1.25

    def restore(self, params):
        self.restored = params
        self.lf = params["l_f"].value

    def flush(self):
        pass

    def decode(self):
        return {
            "frames": self.frames,
            "errors": {"0x123": {"dlc": 2}},
            "errors_by_kind": {"dlc": 2},
            "unknown_ids": [{"id": "0x7FF", "count": 1}],
            "invalid_channels": [],
        }

    def result(self, trace=False):
        """The typed result, from the plain dicts below (which subclasses change)."""
        snap = self.snapshot()
        ekf = snap["baseline_ekf"]
        return RunResult(
            parameters={k: Estimate.from_dict(k, v) for k, v in snap["parameters"].items()},
            baseline_ekf=None if ekf is None else {k: Estimate.from_dict(k, v) for k, v in ekf.items()},
            stage=snap["stage"],
            supervisor=snap["supervisor"],
            windows=tuple(WindowSpan(**w) for w in snap["windows"]),
            resets=snap["resets"],
            capabilities=snap["capabilities"],
            decode=self.decode(),
            clock=Clock(),
            channels={k: Freshness(**v) for k, v in self.freshness().items()},
            frames=self.frames,
            samples=self.samples,
            bus_time=self.last_bus_time,
        )

    def feed(self, msg):
        self.frames += 1
        self.samples += 1
        self.last_bus_time = msg.timestamp
        if msg.data:
            self.lf = 1.0 + msg.data[0] / 100.0

    def snapshot(self):
        p = {
            n: {
                "value": 1.0 + i,
                "std": 0.1,
                "unit": "m",
                "valid": True,
                "stage": 1 if i < 3 else 2,
                "samples": self.samples,
                "status": "converged",
            }
            for i, n in enumerate(NAMES)
        }
        p["l_f"]["value"] = self.lf
        p["I_x"].update(value=math.nan, std=math.inf, status="not_identifiable")  # must come out null
        return {
            "parameters": p,
            "baseline_ekf": {k: dict(v) for k, v in p.items()},
            "stage": "stage2",
            "supervisor": {"active_stage": 2, "reasons": {"1": "steering", "2": "open"}, "windows": 2},
            "windows": [
                {"stage": 1, "start": 0.0, "end": 1.0, "samples": 5},
                {"stage": 2, "start": 2.0, "end": None, "samples": 7},
            ],
            "resets": {"ukf": 0, "ekf": 0},
            "capabilities": {"1": None, "2": None},
        }

    def freshness(self):
        return {"yaw_rate": {"age": 0.01, "stale": False}, "speed": {"age": math.nan, "stale": False}}

    def reset(self, stage=None):
        self.resets.append(stage)
        self.lf = 1.25


def make_settings(tmp_path: Path, token: str | None = None, **service) -> Settings:
    return Settings(
        profile=ROOT / "profiles" / "paper.toml",
        bus=BusSettings(interface="virtual", channel=f"test-api-{next(_chan)}", bitrate=None, listen_only=False),
        raw_log=RawLogSettings(dir=tmp_path / "raw", max_bytes=1 << 20, max_files=4),
        store=StoreSettings(path=tmp_path / "state.sqlite", commit_interval=0.05, synchronous="normal"),
        api=ApiSettings(reset_token=token),
        service=ServiceSettings(publish_interval=0.05, **service),
        source="test",
    )


def send(tx, n: int, t0: float = 1000.0, first: int = 40):
    for k in range(n):
        tx.send(
            can.Message(
                timestamp=t0 + 0.01 * k, arbitration_id=0x123, data=bytes([first + k % 10] * 8), is_extended_id=False
            )
        )


def wait_for(cond, what: str, limit: float = 60.0):
    """Poll a condition; the limit only guards against a hang, it is not what is tested."""
    end = time.monotonic() + limit
    while not cond():
        if time.monotonic() > end:
            pytest.fail(f"gave up waiting for: {what}")
        time.sleep(0.01)


def wait_up(svc):
    # a virtual bus delivers only to buses that exist: send nothing before the service's is open
    wait_for(lambda: svc.link.up, "the service's bus to open")


def wait_frames(svc, n: int):
    wait_for(lambda: svc.intake.received >= n, f"{n} frames to arrive")
    svc.sync()
