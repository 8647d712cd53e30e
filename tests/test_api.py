"""The REST API over a real Service (virtual bus, store, raw log) with a small fake pipeline."""

from __future__ import annotations

import json
import logging
import re
from dataclasses import replace
from pathlib import Path
from urllib.parse import unquote

import can
import pytest
from fastapi.testclient import TestClient

from helpers.live import NAMES, FakePipeline, make_settings, send, wait_frames, wait_up
from vdp.api import check_host, create_app
from vdp.live import Service
from vdp.settings import ApiSettings

TOKEN = "s3cret-token-for-tests-0123456789"


@pytest.fixture
def running(tmp_path):
    """(service, client, sender bus) factory; everything stopped at the end."""
    made = []

    def make(token=None, profile=None, **service):
        pipe = FakePipeline()
        settings = make_settings(tmp_path, token, **service)
        if profile is not None:
            settings = replace(settings, profile=profile)
        svc = Service(settings, pipeline=pipe)
        svc.start()
        wait_up(svc)
        client = TestClient(create_app(svc.settings, svc))
        tx = can.Bus(interface="virtual", channel=svc.bus_cfg.channel, preserve_timestamps=True)
        made.append((svc, tx))
        return svc, client, tx, pipe

    yield make
    for svc, tx in made:
        tx.shutdown()
        svc.stop()


def no_nan(text: str) -> None:
    assert "NaN" not in text and "Infinity" not in text


def test_health_and_estimates(running):
    svc, client, tx, pipe = running()
    r = client.get("/health")
    assert r.status_code == 200
    assert r.json()["status"] == "degraded" and "no frames received yet" in r.json()["reasons"]
    send(tx, 20)
    wait_frames(svc, 20)
    h = client.get("/health").json()
    assert "no frames received yet" not in h["reasons"]

    r = client.get("/estimates")
    assert r.status_code == 200
    no_nan(r.text)
    body = r.json()
    assert set(body["parameters"]) == set(NAMES)
    for p in body["parameters"].values():
        assert {"value", "std", "unit", "valid", "stage", "samples", "status"} <= set(p)
    assert body["parameters"]["l_f"]["value"] == pytest.approx(1.0 + 49 / 100)  # the last frame's byte
    ix = body["parameters"]["I_x"]
    assert ix["value"] is None and ix["std"] is None and ix["valid"] is False  # NaN -> null, not valid
    assert body["baseline_ekf"]["I_x"]["value"] is None
    assert body["stage"] == "stage2" and body["supervisor"]["active_stage"] == 2
    assert pipe.frames == 20


def test_status_reports_bus_decoding_channels_gating_and_logs(running):
    svc, client, tx, pipe = running()
    send(tx, 30)
    wait_frames(svc, 30)
    r = client.get("/status")
    assert r.status_code == 200
    no_nan(r.text)
    s = r.json()
    assert s["bus"]["state"] == "up" and s["bus"]["frames"] == 30 and s["queue"]["dropped"] == 0
    assert s["decode"]["errors"] == {"0x123": {"dlc": 2}} and s["decode"]["unknown_ids"][0]["id"] == "0x7FF"
    assert s["channels"]["speed"]["age"] is None and s["channels"]["yaw_rate"]["stale"] is False
    assert s["gating"]["window"] == {"stage": 2, "start": 2.0, "end": None, "samples": 7}
    assert s["raw_log"]["enabled"] is True and s["raw_log"]["frames"] == 30
    assert s["uptime_s"] >= 0 and s["store"]["state"] == "ok"


def test_history_is_paged(running):
    svc, client, tx, pipe = running()
    svc.commit()  # the start-up snapshot (the priors)
    for k in range(5):
        send(tx, 1, t0=1000.0 + k, first=10 * k)
        wait_frames(svc, k + 1)
        svc.commit()
    r = client.get("/estimates/history", params={"parameter": "l_f", "limit": 2})
    assert r.status_code == 200
    page = r.json()
    # one row from the start-up snapshot (l_f = prior) and one per changed value
    assert page["total"] == 6 and len(page["items"]) == 2 and page["next_offset"] == 2
    values = []
    offset = 0
    while offset is not None:
        page = client.get("/estimates/history", params={"parameter": "l_f", "limit": 2, "offset": offset}).json()
        values += [i["value"] for i in page["items"]]
        offset = page["next_offset"]
    assert values == pytest.approx([1.25, 1.0, 1.1, 1.2, 1.3, 1.4])
    everything = client.get("/estimates/history", params={"limit": 1000}).json()
    no_nan(json.dumps(everything))
    assert {i["parameter"] for i in everything["items"]} == set(NAMES)
    later = client.get("/estimates/history", params={"since": everything["items"][-1]["t"]}).json()
    assert 0 < later["total"] < everything["total"]
    assert client.get("/estimates/history", params={"parameter": "wheelbase"}).status_code == 422
    # the mass is published beside the six (core.mass): its history is asked for like theirs
    assert client.get("/estimates/history", params={"parameter": "mass"}).status_code == 200
    assert client.get("/estimates/history", params={"limit": 0}).status_code == 422
    assert client.get("/estimates/history", params={"since": "nan"}).status_code == 422


def test_reset_disabled_without_a_token(running):
    svc, client, tx, pipe = running(token=None)
    send(tx, 5)
    wait_frames(svc, 5)
    before = client.get("/estimates").json()["parameters"]
    for headers in ({}, {"Authorization": f"Bearer {TOKEN}"}):
        r = client.post("/reset", params={"stage": "all"}, headers=headers)
        assert r.status_code == 403 and "disabled" in r.json()["detail"]
    assert pipe.resets == []
    assert client.get("/estimates").json()["parameters"] == before


def test_reset_needs_the_right_token(running):
    svc, client, tx, pipe = running(token=TOKEN)
    send(tx, 5)
    wait_frames(svc, 5)
    before = client.get("/estimates").json()["parameters"]
    assert before["l_f"]["value"] != 1.25
    r = client.post("/reset", json={"stage": "1"})
    assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
    assert client.post("/reset", headers={"Authorization": "Basic abc"}).status_code == 401
    for wrong in ("nope", TOKEN[:-1], TOKEN + "x", "ü" * 40):
        header = f"Bearer {wrong}".encode()  # non-ASCII bytes must not break compare_digest
        r = client.post("/reset", json={"stage": "1"}, headers={"Authorization": header})
        assert r.status_code == 403, wrong
    svc.sync()
    assert pipe.resets == []
    assert client.get("/estimates").json()["parameters"] == before

    auth = {"Authorization": f"Bearer {TOKEN}"}
    for bad in ("3", 3, True, 1.5, None, "all "):
        assert client.post("/reset", json={"stage": bad}, headers=auth).status_code == 422, bad
    assert client.post("/reset", params={"stage": "3"}, headers=auth).status_code == 422
    assert pipe.resets == []
    r = client.post("/reset", json={"stage": 1}, headers=auth)
    assert r.status_code == 200 and r.json()["reset"] == "1"
    r = client.post("/reset", params={"stage": "2"}, headers=auth)
    assert r.status_code == 200 and r.json()["reset"] == "2"
    r = client.post("/reset", headers=auth)
    assert r.status_code == 200 and r.json()["reset"] == "all"
    assert pipe.resets == [1, 2, None]
    assert client.get("/estimates").json()["parameters"]["l_f"]["value"] == 1.25


@pytest.mark.parametrize("name", ["\u0160koda Octavia", 'Golf "R"; filename=x.sh', "two\nlines\r\nX-Evil: 1"])
def test_export_names_any_vehicle_in_its_header(running, tmp_path, name):
    """/export's file name is the vehicle's, as RFC 6266 has it: UTF-8 percent-encoded in filename*,
    an ASCII stand-in in filename.  Put in as it was, "Skoda" with a caron was a 500 in every
    format, a newline cut the connection and a quote added a parameter of its own."""
    from vdp.text import toml_str

    root = Path(__file__).resolve().parents[1]
    text = (root / "profiles" / "paper.toml").read_text().replace('"../dbc/vdp.dbc"', f'"{root / "dbc" / "vdp.dbc"}"')
    prof = tmp_path / "car.toml"
    prof.write_text(text.replace('name = "paper"', f"name = {toml_str(name)}", 1))
    svc, client, tx, pipe = running(profile=prof)
    for fmt, suffix in (("commonroad", "yaml"), ("carla", "json"), ("json", "json"), ("toml", "toml")):
        r = client.get("/export", params={"format": fmt})
        assert r.status_code == 200, (fmt, r.text)
        header = r.headers["content-disposition"]
        got = re.fullmatch(r"inline; filename=\"([ !#-\[\]-~]*)\"; filename\*=UTF-8''([A-Za-z0-9%._~-]+)", header)
        assert got, header  # one parameter each, printable ASCII, no quote or backslash inside the quotes
        assert unquote(got.group(2), errors="strict") == f"{name}.{fmt}.{suffix}"
        assert got.group(1).endswith(f".{fmt}.{suffix}")


def test_metrics_text_and_per_app_registry(running):
    svc, client, tx, pipe = running()
    send(tx, 12)
    wait_frames(svc, 12)
    r = client.get("/metrics")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain")
    text = r.text
    no_nan(text)
    assert "vdp_frames_received_total 12.0" in text
    assert 'vdp_estimate{parameter="l_f"}' in text
    assert 'vdp_estimate{parameter="I_x"}' not in text  # unknown: left out, not NaN
    assert 'vdp_estimate_valid{parameter="I_x"} 0.0' in text
    assert 'vdp_decode_errors_total{kind="dlc"} 2.0' in text
    assert "vdp_bus_up 1.0" in text
    # a second app in the same process has its own registry (no duplicate-metric error)
    svc2, client2, _, _ = running()
    assert "vdp_frames_received_total 0.0" in client2.get("/metrics").text


def test_openapi_says_value_and_std_are_nullable(running):
    svc, client, tx, pipe = running()
    schema = client.get("/openapi.json").json()
    est = schema["components"]["schemas"]["Estimate"]["properties"]
    for key in ("value", "std"):
        assert {"type": "null"} in est[key]["anyOf"], est[key]
        assert "valid is false" in est[key]["description"]
    assert "bearer" in json.dumps(schema["components"]["securitySchemes"]).lower()


def test_binding_elsewhere_than_loopback_warns(caplog):
    with caplog.at_level(logging.WARNING, logger="vdp.api.app"):
        check_host("127.0.0.1")
        assert not caplog.records
        check_host("0.0.0.0")
    assert "not only on this machine" in caplog.text
    assert ApiSettings().host == "127.0.0.1"


def test_app_factory_builds_its_service_in_the_lifespan(tmp_path, monkeypatch):
    import vdp.live.service as live

    made = []
    real = live.Service

    class Recording(real):
        def __init__(self, settings, **kw):
            super().__init__(settings, pipeline=FakePipeline(), **kw)
            made.append(self)

    monkeypatch.setattr(live, "Service", Recording)
    monkeypatch.setattr("vdp.live.Service", Recording)
    app = create_app(make_settings(tmp_path))
    assert not made  # nothing is built when the app is made
    with TestClient(app) as client:
        assert made and made[0].running
        assert client.get("/health").status_code == 200
    assert not made[0].running


def test_estimates_answered_before_fastapi_are_the_routes_own_answer(running):
    """GET /estimates skips FastAPI's middleware and routing (routes.answer_estimates): the same bytes and headers
    as the route."""
    import asyncio

    from vdp.api import routes

    svc, client, tx, pipe = running()
    send(tx, 20)
    wait_frames(svc, 20)
    for _ in range(50):  # the worker may publish a snapshot between two answers: take a pair with none between
        before = asyncio.run(routes.estimates(svc))  # the FastAPI route's own answer
        r = client.get("/estimates")
        own = asyncio.run(routes.estimates(svc))
        if own.body == before.body:
            break
    assert r.status_code == own.status_code == 200
    assert r.content == own.body
    assert {k: r.headers[k] for k in ("content-type", "content-length")} == {
        "content-type": own.headers["content-type"],
        "content-length": own.headers["content-length"],
    }
    client.app.state.service = None  # not there yet: FastAPI's route answers, as before
    try:
        assert client.get("/estimates").status_code == 503
    finally:
        client.app.state.service = svc
