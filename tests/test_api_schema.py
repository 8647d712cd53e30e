"""Schemathesis against the app's own OpenAPI schema: no 5xx, no response that breaks the schema.

The app runs over a real Service with the real pipeline, fed a few seconds of the
simulated drive, so the responses carry real estimates, history and status.
"""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import can
import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis import GenerationMode

from vdp.api import create_app
from vdp.live import Service
from vdp.settings import ApiSettings, BusSettings, RawLogSettings, ServiceSettings, Settings, StoreSettings
from vdp.sim.run import Simulation

ROOT = Path(__file__).resolve().parents[1]
TOKEN = "schemathesis-token-0123456789abcdef"
_n = itertools.count()


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("schema")
    s = Settings(
        profile=ROOT / "profiles" / "paper.toml",
        bus=BusSettings(interface="virtual", channel=f"test-schema-{next(_n)}", bitrate=None, listen_only=False),
        raw_log=RawLogSettings(dir=tmp / "raw", max_bytes=1 << 20, max_files=4),
        store=StoreSettings(path=tmp / "state.sqlite", commit_interval=0.1, synchronous="normal"),
        api=ApiSettings(reset_token=TOKEN),
        service=ServiceSettings(publish_interval=0.1),
        source="test",
    )
    svc = Service(s)
    svc.start()
    end = time.monotonic() + 60
    while not svc.link.up and time.monotonic() < end:
        time.sleep(0.01)  # a virtual bus delivers only to buses that already exist
    tx = can.Bus(interface="virtual", channel=svc.bus_cfg.channel, preserve_timestamps=True)
    frames = Simulation(s.profile, "paper", 1, "none", duration=8.0).frames()
    sent = 0
    for msg in frames:
        tx.send(msg)
        sent += 1
    end = time.monotonic() + 60
    while svc.intake.received < sent and time.monotonic() < end:
        time.sleep(0.01)
    svc.sync()
    svc.commit()
    yield svc
    tx.shutdown()
    svc.stop()


@pytest.fixture(scope="module")
def api_schema(service):
    return schemathesis.openapi.from_asgi("/openapi.json", create_app(service.settings, service))


def test_api_conforms_to_its_schema(api_schema):
    # schemathesis' pytest plugin (from_fixture) does not run under pytest 9: drive its
    # strategies with hypothesis directly, one operation at a time.
    ops = [r.ok() for r in api_schema.get_all_operations()]
    assert {f"{op.method.upper()} {op.path}" for op in ops} >= {
        "GET /health",
        "GET /estimates",
        "GET /estimates/history",
        "GET /status",
        "POST /reset",
        "GET /metrics",
    }
    for op in ops:
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):

            @given(case=op.as_strategy(generation_mode=mode))
            @settings(
                max_examples=25, deadline=None, suppress_health_check=list(HealthCheck), database=None, derandomize=True
            )  # the same cases every run: CI never flickers
            def run(case):
                _check(case, case.meta.generation.mode if case.meta else GenerationMode.POSITIVE)

            try:
                run()
            except Unsatisfiable:
                if mode is GenerationMode.POSITIVE:
                    raise  # an operation without parameters has no invalid input: nothing to try


def _check(case, mode):
    # Valid requests go with and without the token: both must answer within the schema.
    # Invalid ones keep what schemathesis made of the auth header (a refusal is a fine answer).
    with_token = mode is GenerationMode.POSITIVE and case.method == "POST" and hash(str(case.body)) % 2
    headers = {"Authorization": f"Bearer {TOKEN}"} if with_token else None
    response = case.call(headers=headers)
    assert response.status_code < 500, (case.method, case.path, response.text)
    assert "NaN" not in response.text and "Infinity" not in response.text
    case.validate_response(response)
