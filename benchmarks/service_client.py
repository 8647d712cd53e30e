"""HTTP client side of the live-service benchmarks; run in its own process by them.

    python benchmarks/service_client.py rate  --port P --rate 50 --count 3000 --seconds 90
    python benchmarks/service_client.py burst --port P --clients 200 --requests 5

- ``rate``: one keep-alive client sending requests on a fixed schedule (open loop:
  a slow answer does not push the next one back), cycling through the GET endpoints;
- ``burst``: ``clients`` clients, each its own connection, all started at once, each
  sending ``requests`` requests one after another.

Prints one JSON line: latencies (ms) overall and per endpoint, status codes, failures.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time

import httpx

PATHS = ["/health", "/estimates", "/status", "/metrics", "/estimates/history?limit=100"]


def pct(xs: list[float], q: float) -> float | None:
    if not xs:
        return None
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, int(round(q / 100.0 * (len(s) - 1)))))]


def summary(results: list[tuple[str, int | None, float, str | None]], wall: float) -> dict:
    """results: (path, status or None, latency ms, error)."""
    lat = [r[2] for r in results]
    out = {
        "requests": len(results),
        "wall_s": wall,
        "ok": sum(1 for r in results if r[1] == 200),
        "failed": [f"{p}: {s} {e or ''}".strip() for p, s, _, e in results if s != 200][:20],
        "failed_count": sum(1 for r in results if r[1] != 200),
        "latency_ms": {q: pct(lat, float(q[1:])) for q in ("p50", "p90", "p99")} | {"max": max(lat, default=None)},
        "per_path": {},
    }
    for p in dict.fromkeys(r[0] for r in results):
        xs = [r[2] for r in results if r[0] == p]
        if xs:
            out["per_path"][p] = {"n": len(xs), "p50": pct(xs, 50), "p99": pct(xs, 99), "max": max(xs)}
    return out


def rate(port: int, per_s: float, count: int, seconds: float, paths: list[str] | None = None) -> dict:
    paths = paths or PATHS
    base = f"http://127.0.0.1:{port}"
    results = []
    with httpx.Client(base_url=base, timeout=30.0) as c:
        c.get("/health")  # connect before the clock starts
        t0 = time.perf_counter()
        for k in range(count):
            due = t0 + k / per_s
            now = time.perf_counter()
            if due > now:
                time.sleep(due - now)
            if now - t0 > seconds:
                break
            path = paths[k % len(paths)]
            s = time.perf_counter()
            try:
                r = c.get(path)
                results.append((path, r.status_code, 1000 * (time.perf_counter() - s), None))
            except httpx.HTTPError as exc:
                results.append((path, None, 1000 * (time.perf_counter() - s), type(exc).__name__))
    return summary(results, time.perf_counter() - t0)


async def burst(port: int, clients: int, requests: int) -> dict:
    base = f"http://127.0.0.1:{port}"
    results: list = []
    gate = asyncio.Event()

    async def one(i: int) -> None:
        # its own connection: 200 clients are 200 sockets, not one pool
        async with httpx.AsyncClient(base_url=base, timeout=60.0, limits=httpx.Limits(max_connections=1)) as c:
            await gate.wait()
            for k in range(requests):
                path = PATHS[(i + k) % len(PATHS)]
                s = time.perf_counter()
                try:
                    r = await c.get(path)
                    results.append((path, r.status_code, 1000 * (time.perf_counter() - s), None))
                except httpx.HTTPError as exc:
                    results.append((path, None, 1000 * (time.perf_counter() - s), type(exc).__name__))

    tasks = [asyncio.create_task(one(i)) for i in range(clients)]
    await asyncio.sleep(0.2)
    t0 = time.perf_counter()
    gate.set()
    await asyncio.gather(*tasks)
    return summary(results, time.perf_counter() - t0)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mode", choices=("rate", "burst"))
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--rate", type=float, default=50.0)
    ap.add_argument("--count", type=int, default=3000)
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--clients", type=int, default=200)
    ap.add_argument("--requests", type=int, default=5)
    ap.add_argument("--paths", default="", help="rate: comma-separated paths to cycle (default: the mix)")
    a = ap.parse_args()
    if a.mode == "rate":
        out = rate(a.port, a.rate, a.count, a.seconds, [p for p in a.paths.split(",") if p] or None)
    else:
        out = asyncio.run(burst(a.port, a.clients, a.requests))
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
