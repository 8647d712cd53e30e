"""Limits before work: ASGI middleware in front of every route.

:class:`HostGuard` answers only requests naming this machine (DNS rebinding, loopback
included).  :class:`Gate` holds the rest.

FastAPI reads and parses a request's body before it runs the route's
dependencies, the token check among them: a 30 MB JSON body to ``POST /reset``
cost 60 MB of memory, a 150 MB one 630 MB, before "wrong token" (RELIABILITY.md).  So, before anything reads it:

- the token of a route that needs one is checked from the headers alone
  (401/403, the body never read);
- a body is capped at ``[api] max_body`` bytes: a larger Content-Length is
  refused at once (413), a chunked body is read in and cut off past the cap;
- a body must arrive within ``[api] header_timeout`` s (408): a client that
  trickles its body holds a request, and a worker, for no longer than that;
- at most ``max_requests`` requests are in flight (503 beyond), except
  ``GET /health``, which always has room: the health check is what tells an
  operator the service is overloaded.
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import json

TOKEN_ROUTES = {("POST", "/reset")}  # routes that need [api] reset_token, checked before their body is read
RESERVED = {("GET", "/health")}  # never refused for being busy
HOSTS_SEEN = 64  # distinct Host headers whose answer HostGuard keeps
_READ = (b"content-length", b"authorization", b"transfer-encoding")  # the headers the gate reads


class HostGuard:
    """ASGI middleware (vdp serve puts it outermost): 400 for a Host header that is not an allowed name,
    nor an IP address (bound to loopback: a loopback address).  Built by ``vdp.cli.serve._guard_hosts``."""

    def __init__(self, app, names: frozenset[str], any_address: bool = True):
        self.app = app
        self.names = names
        self.any_address = any_address  # False: loopback addresses only
        # each Host header's answer, as a client sends the same one on every request (parsing an address
        # was a tenth of the API thread's CPU at 50 req/s); bounded: a flood of made-up names clears it
        self._seen: dict[str, bool] = {}

    def allowed(self, host: str) -> bool:
        ok = self._seen.get(host)
        if ok is None:
            if len(self._seen) >= HOSTS_SEEN:
                self._seen.clear()
            ok = self._seen[host] = self._allowed(host)
        return ok

    def _allowed(self, host: str) -> bool:
        if host.startswith("["):  # [v6]:port
            name = host[1 : host.find("]")] if "]" in host else host
        else:
            name = host.rsplit(":", 1)[0] if host.count(":") == 1 else host
        name = name.lower()
        if name in self.names:
            return True
        try:
            addr = ipaddress.ip_address(name)
        except ValueError:
            return False
        return self.any_address or addr.is_loopback

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http":
            host = next((v.decode("latin-1") for k, v in scope["headers"] if k == b"host"), None)
            # no Host header at all (HTTP/1.0) cannot be a browser's: browsers always send one
            if host is not None and not self.allowed(host):
                await _answer(
                    send, 400, f"Host {host!r} is not one of this logger's names; add it to [api] allowed_hosts"
                )
                return
        await self.app(scope, receive, send)


def token_problem(token: str | None, header: str | None) -> tuple[int, str] | None:
    """(status, why) if the Authorization header does not carry ``token``; None if it does."""
    if not token:
        return 403, "POST /reset is disabled: no [api] reset_token is configured"
    scheme, _, cred = (header or "").strip().partition(" ")
    if scheme.lower() != "bearer" or not cred.strip():
        return 401, "a bearer token is required"
    # Constant time, on bytes: compare_digest refuses non-ASCII str.
    if not hmac.compare_digest(cred.strip().encode("utf-8", "replace"), token.encode("utf-8")):
        return 403, "wrong token"
    return None


class Gate:
    """ASGI middleware; ``settings`` is read per request (tests swap the app's settings)."""

    def __init__(self, app, settings, max_requests: int = 1024):
        self.app = app
        self.settings = settings
        self.max_requests = max_requests
        self.in_flight = 0

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        api = self.settings.api
        route = (scope["method"], scope["path"])
        headers = {k: v for k, v in scope["headers"] if k in _READ}
        if route not in RESERVED and self.in_flight >= self.max_requests:
            await _answer(send, 503, f"busy: {self.in_flight} requests in flight; try again shortly")
            return
        if route in TOKEN_ROUTES:
            auth = headers.get(b"authorization")
            problem = token_problem(api.reset_token, None if auth is None else auth.decode("latin-1"))
            if problem is not None:
                extra = [(b"www-authenticate", b"Bearer")] if problem[0] == 401 else []
                await _answer(send, problem[0], problem[1], extra)
                return
        length = headers.get(b"content-length")
        if length is not None and (not length.strip().isdigit() or int(length) > api.max_body):
            await _answer(send, 413, _too_large(api.max_body, length.decode("latin-1")))
            return
        self.in_flight += 1
        try:
            if length is None and b"transfer-encoding" not in headers:
                # no body (HTTP/1.1: neither header, none follows): the dashboard's GETs skip reading one,
                # whose wait_for costs a task a request
                await self.app(scope, receive, send)
                return
            body, why = await _read_body(receive, api.max_body, api.header_timeout)
            if why == "too_large":
                await _answer(send, 413, _too_large(api.max_body, "more"))
                return
            if why == "too_slow":
                late = f"the request body did not arrive within {api.header_timeout:g} s ([api] header_timeout)"
                await _answer(send, 408, late)
                return
            await self.app(scope, _replay(body, receive), send)
        finally:
            self.in_flight -= 1


def _too_large(cap: int, length: str) -> str:
    return f"request body too large: {length} bytes, at most {cap} are accepted ([api] max_body)"


async def _read_body(receive, cap: int, timeout: float) -> tuple[bytes, str | None]:
    """The whole body, read as it comes and given up past ``cap`` bytes or ``timeout`` s."""
    parts, size = [], 0
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while True:
        try:
            msg = await asyncio.wait_for(receive(), max(end - loop.time(), 0.0))
        except asyncio.TimeoutError:
            return b"", "too_slow"
        if msg["type"] == "http.disconnect":
            return b"".join(parts), None
        chunk = msg.get("body", b"")
        size += len(chunk)
        if size > cap:
            return b"", "too_large"
        parts.append(chunk)
        if not msg.get("more_body", False):
            return b"".join(parts), None


def _replay(body: bytes, receive):
    """A receive() that hands the app the body already read, then waits on the real one (disconnects)."""
    sent = False

    async def again():
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return again


async def _answer(send, code: int, detail: str, headers: list | None = None) -> None:
    body = json.dumps({"detail": detail}).encode()
    head = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    head.append((b"connection", b"close"))  # a body left unread (or still coming) ends with the connection
    await send({"type": "http.response.start", "status": code, "headers": head + (headers or [])})
    await send({"type": "http.response.body", "body": body})
