"""The panel's web server: the page, the past runs and one WebSocket per browser.

It relays the show's feed (:mod:`hilsim.show.feed`) to every browser and a browser's commands
back to the show. Every request passes the same guards, cheapest first, each refusal counted
and answered with a short status line (never a traceback):

1. **sender**: the client's address must be loopback, or in the allow-list that an address
   other than loopback requires (:class:`~hilsim.live.netguard.GuardConfig`'s rule);
2. **token**: every request carries ``?token=`` (random, printed with the URL);
3. **Host** and, on the WebSocket, **Origin**: the page's own address only (no other site's
   page in the same browser, no DNS rebinding);
4. **clients**: at most ``max_clients`` WebSockets at once;
5. per message: at most ``max_message_bytes``, ``rate_per_s`` a second (a token bucket), a JSON
   object with a known ``op`` and well-typed fields; anything else is dropped and counted.

GET never changes anything: commands arrive only over the WebSocket. A browser that stops
reading is sent only the newest state (older ones are skipped) and is closed after
``send_timeout_s`` without progress. The rules for users: ``docs/panel.md``.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import json
import math
import secrets
import time
from collections import deque
from dataclasses import dataclass, field
from http import HTTPStatus
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, unquote, urlsplit

from websockets.asyncio.server import ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from hilsim.live.netguard import GuardConfig, NetGuard, TokenBucket
from hilsim.panel.runs import Verdict, list_runs, run_file

__all__ = ["PanelConfig", "PanelServer", "new_token"]

COUNT_KINDS = (
    "requests",  # HTTP requests and WebSocket handshakes seen
    "sender",  # a client outside the allow-list
    "token",  # a wrong or missing token
    "origin",  # a foreign Host or Origin
    "clients",  # a WebSocket over the cap on clients
    "not_found",  # a path the panel does not serve
    "malformed",  # a message that is not a command
    "oversized",  # a message over max_message_bytes (the connection is closed)
    "flood",  # a message over the client's rate
    "slow",  # a client closed for not reading
    "commands",  # commands sent to the show
    "clamped",  # a joint value outside its limits, sent at the limit
    "internal",  # an unexpected exception (a bug; the request or message dropped)
)
OPS = frozenset({"cue", "joint", "release", "stop"})
EVENTS_KEPT = 200  # recent events a new browser is sent
#: the page's own inline script and style, and nothing from elsewhere
CSP = (
    "default-src 'self'; style-src 'unsafe-inline'; script-src 'unsafe-inline'; "
    "img-src 'self'; connect-src 'self'"
)


def new_token() -> str:
    return secrets.token_urlsafe(18)


@dataclass
class PanelConfig:
    """Where and how the panel listens. ``port`` 0: any free port."""

    host: str = "127.0.0.1"
    port: int = 8080
    token: str = field(default_factory=new_token)
    allow: tuple[str, ...] = ()
    max_clients: int = 8
    max_message_bytes: int = 4096
    rate_per_s: float = 60.0
    burst: int = 120
    send_timeout_s: float = 5.0
    write_limit: int = 64 * 1024  # bytes buffered for a browser before a send waits

    def __post_init__(self) -> None:
        # the network inputs' rule: another address than loopback needs an allow-list
        self.guard = GuardConfig(interface=self.host, allow=self.allow)


def _response(status: HTTPStatus, body: bytes = b"", ctype: str = "text/plain") -> Response:
    if not body:
        body = f"{status.value} {status.phrase}\n".encode()
    headers = Headers(
        [
            ("Content-Type", f"{ctype}; charset=utf-8" if ctype.startswith("text") else ctype),
            ("Content-Length", str(len(body))),
            ("Cache-Control", "no-store"),
            ("X-Content-Type-Options", "nosniff"),
            ("Referrer-Policy", "no-referrer"),  # the token stays out of other sites' logs
            ("Content-Security-Policy", CSP),
            ("Connection", "close"),
        ]
    )
    return Response(status.value, status.phrase, headers, body)


class _Client:
    """One browser: the newest state (older ones skipped) and a queue of the rest."""

    def __init__(self, ws: ServerConnection, host: str, cfg: PanelConfig) -> None:
        self.ws, self.host = ws, host
        self.state: str | None = None
        self.queue: deque[str] = deque(maxlen=1000)
        self.wake = asyncio.Event()
        self.bucket = TokenBucket(cfg.rate_per_s, cfg.burst, time.monotonic())

    def put(self, text: str, *, latest: bool = False) -> None:
        if latest:
            self.state = text
        else:
            self.queue.append(text)
        self.wake.set()


class PanelServer:
    """Serves one show's panel. ``feed``: the show's socket (None: past runs only); ``runs``:
    the directory of run directories; ``run_dir``: the show's own (its events are tailed)."""

    def __init__(
        self,
        config: PanelConfig,
        *,
        feed: Path | None,
        runs: Path | None,
        run_dir: Path | None = None,
        verdict: Verdict | None = None,
    ) -> None:
        self.config, self.feed_path, self.runs, self.run_dir = config, feed, runs, run_dir
        self.verdict = verdict
        self.guard = NetGuard(config.guard)
        self.counts: dict[str, int] = dict.fromkeys(COUNT_KINDS, 0)
        self.clients: set[_Client] = set()
        self.hello: dict[str, Any] | None = None
        self.last_state: str | None = None
        self.end: str | None = None
        self.events: deque[str] = deque(maxlen=EVENTS_KEPT)
        self.limits: dict[str, tuple[float, float]] = {}
        self.feed_up = False
        self._writer: asyncio.StreamWriter | None = None
        self._page = resources.files("hilsim.panel").joinpath("page.html").read_bytes()
        self.address: tuple[str, int] | None = None
        self.stopped = asyncio.Event()

    @property
    def url(self) -> str:
        assert self.address is not None
        host, port = self.address
        shown = f"[{host}]" if ":" in host else host
        return f"http://{shown}:{port}/?token={self.config.token}"

    # ------------------------------------------------------------------ running
    async def run(self, ready: Any = None) -> None:
        """Listen; call ``ready(url)`` once listening; serve until :attr:`stopped` is set."""
        cfg = self.config
        async with serve(
            self._handler,
            cfg.host,
            cfg.port,
            process_request=self._process_request,
            server_header=None,
            compression=None,
            max_size=cfg.max_message_bytes,
            max_queue=16,
            write_limit=cfg.write_limit,
            open_timeout=5,
            ping_interval=10,
            ping_timeout=10,
            close_timeout=2,
        ) as server:
            sock = next(iter(server.sockets))
            self.address = sock.getsockname()[:2]
            tasks = [asyncio.create_task(self._panel_facts())]
            if self.feed_path is not None:
                tasks.append(asyncio.create_task(self._read_feed(self.feed_path)))
            if self.run_dir is not None:
                tasks.append(asyncio.create_task(self._tail_events(self.run_dir)))
            if ready is not None:
                ready(self.url)
            try:
                await self.stopped.wait()
            finally:
                for task in tasks:
                    task.cancel()
                for client in list(self.clients):
                    with contextlib.suppress(Exception):
                        await client.ws.close(1001, "the panel is closing")

    # ------------------------------------------------------------------ HTTP and the guards
    def _process_request(self, conn: ServerConnection, request: Request) -> Response | None:
        try:
            return self._route(conn, request)
        except Exception:  # a bug must not reach the client as a traceback
            self.counts["internal"] += 1
            return _response(HTTPStatus.INTERNAL_SERVER_ERROR)

    def _route(self, conn: ServerConnection, request: Request) -> Response | None:
        counts = self.counts
        counts["requests"] += 1
        host = str(conn.remote_address[0]) if conn.remote_address else ""
        if not self.guard.sender_allowed(host):
            counts["sender"] += 1
            return _response(HTTPStatus.FORBIDDEN)
        if getattr(request, "method", "GET") != "GET":  # no state changes over HTTP at all
            counts["not_found"] += 1
            return _response(HTTPStatus.METHOD_NOT_ALLOWED)
        url = urlsplit(request.path)
        if url.path == "/favicon.ico":  # a browser asks for it by itself, without the token
            return _response(HTTPStatus.NOT_FOUND)
        token = parse_qs(url.query).get("token", [""])[0]
        if not secrets.compare_digest(token.encode(), self.config.token.encode()):
            counts["token"] += 1
            return _response(HTTPStatus.FORBIDDEN, b"403 Forbidden: open the URL hilsim printed\n")
        if not self._host_ok(request.headers.get("Host")):
            counts["origin"] += 1
            return _response(HTTPStatus.FORBIDDEN)
        path = url.path
        if path == "/ws":
            origin = request.headers.get("Origin")
            if origin is None or origin != f"http://{request.headers.get('Host')}":
                counts["origin"] += 1
                return _response(HTTPStatus.FORBIDDEN)
            if len(self.clients) >= self.config.max_clients:
                counts["clients"] += 1
                return _response(HTTPStatus.SERVICE_UNAVAILABLE)
            return None  # the WebSocket handshake goes on
        if path in ("/", "/index.html"):
            return _response(HTTPStatus.OK, self._page, "text/html")
        if path == "/api/runs":
            rows = [] if self.runs is None else list_runs(self.runs, self.verdict)
            body = json.dumps({"root": str(self.runs), "runs": rows}).encode()
            return _response(HTTPStatus.OK, body, "application/json")
        if path.startswith("/runs/") and self.runs is not None:
            name, _, rest = unquote(path[len("/runs/") :]).partition("/")
            found = run_file(self.runs, name, rest)
            if found is not None:
                ctype = "image/png" if found.suffix == ".png" else "image/svg+xml"
                return _response(HTTPStatus.OK, found.read_bytes(), ctype)
        counts["not_found"] += 1
        return _response(HTTPStatus.NOT_FOUND)

    def _host_ok(self, host_header: str | None) -> bool:
        """The Host header names this server by an IP address (or localhost) and its port:
        a page from another name (DNS rebinding) is refused."""
        if not host_header or self.address is None:
            return False
        host, sep, port = host_header.rpartition(":")
        if not sep or port != str(self.address[1]):
            return False
        host = host.strip("[]")
        if host == "localhost":
            return True
        try:
            ip = ipaddress.ip_address(host)
        except ValueError:
            return False
        bound = ipaddress.ip_address(self.address[0])
        return ip == bound or bound.is_unspecified or (ip.is_loopback and bound.is_loopback)

    # ------------------------------------------------------------------ a browser
    async def _handler(self, ws: ServerConnection) -> None:
        host = str(ws.remote_address[0]) if ws.remote_address else "?"
        client = _Client(ws, host, self.config)
        self.clients.add(client)
        sender = asyncio.create_task(self._sender(client))
        try:
            self._greet(client)
            async for message in ws:
                self._message(client, message)
        except ConnectionClosed as exc:
            codes = {f.code for f in (exc.rcvd, exc.sent) if f is not None}
            if 1009 in codes:  # over max_message_bytes: websockets closed it
                self.counts["oversized"] += 1
        finally:
            self.clients.discard(client)
            sender.cancel()

    def _greet(self, client: _Client) -> None:
        if self.hello is not None:
            client.put(json.dumps(self.hello))
        for line in self.events:
            client.put(line)
        if self.last_state is not None:
            client.put(self.last_state, latest=True)
        if self.end is not None:
            client.put(self.end)
        if not self.feed_up:
            client.put(json.dumps({"type": "gone", "feed": self.feed_path is not None}))

    async def _sender(self, client: _Client) -> None:
        ws, timeout = client.ws, self.config.send_timeout_s
        try:
            while True:
                await client.wake.wait()
                client.wake.clear()
                while client.queue:
                    await asyncio.wait_for(ws.send(client.queue.popleft()), timeout)
                if client.state is not None:
                    state, client.state = client.state, None
                    await asyncio.wait_for(ws.send(state), timeout)
        except TimeoutError:
            self.counts["slow"] += 1  # it stopped reading: closed, the others go on
            ws.transport.abort()
        except ConnectionClosed:
            pass

    def _message(self, client: _Client, message: str | bytes) -> None:
        counts = self.counts
        if not client.bucket.take(time.monotonic()):
            counts["flood"] += 1
            return
        try:
            cmd = json.loads(message)
        except (ValueError, UnicodeDecodeError):
            counts["malformed"] += 1
            return
        try:
            out = self._command(cmd, client.host)
        except Exception:
            counts["internal"] += 1
            return
        if out is None:
            counts["malformed"] += 1
            return
        counts["commands"] += 1
        self._send_feed(out)

    def _command(self, cmd: Any, host: str) -> dict[str, Any] | None:
        """A browser's message -> the feed's command, or None (malformed)."""
        if not isinstance(cmd, dict) or cmd.get("op") not in OPS:
            return None
        op = cmd["op"]
        if op == "stop":
            return {"op": "stop", "who": f"the panel's STOP ({host})"}
        if op == "cue":
            name = cmd.get("name")
            return {"op": "cue", "name": name} if _name(name) else None
        joint = cmd.get("joint")
        if op == "release":
            return {"op": "release", "joint": joint} if joint is None or _name(joint) else None
        deg = cmd.get("deg")
        if not _name(joint) or isinstance(deg, bool) or not isinstance(deg, int | float):
            return None
        if not math.isfinite(deg) or joint not in self.limits:
            return None
        lo, hi = self.limits[joint]
        if not lo <= deg <= hi:
            self.counts["clamped"] += 1
            deg = min(max(deg, lo), hi)
        return {"op": "joint", "joint": joint, "deg": float(deg)}

    # ------------------------------------------------------------------ the show's side
    def _send_feed(self, cmd: dict[str, Any]) -> None:
        writer = self._writer
        if writer is None or writer.is_closing():
            self._broadcast(json.dumps({"type": "reply", "ok": False, "error": "no show"}))
            return
        writer.write((json.dumps(cmd) + "\n").encode())

    def _broadcast(self, text: str, *, latest: bool = False) -> None:
        for client in self.clients:
            client.put(text, latest=latest)

    async def _read_feed(self, path: Path) -> None:
        try:
            reader, self._writer = await asyncio.open_unix_connection(str(path), limit=1 << 20)
        except OSError as exc:
            self._broadcast(json.dumps({"type": "gone", "feed": True, "error": str(exc)}))
            return
        self.feed_up = True
        try:
            while line := await reader.readline():
                text = line.decode().strip()
                kind = json.loads(text).get("type")
                if kind == "state":
                    self.last_state = text
                    self._broadcast(text, latest=True)
                    continue
                if kind == "hello":
                    self.hello = json.loads(text)
                    joints = self.hello.get("joints", [])
                    self.limits = {j["name"]: (j["min"], j["max"]) for j in joints}
                elif kind == "end":
                    self.end = text
                self._broadcast(text)
        except (OSError, ValueError):
            pass
        finally:
            self.feed_up = False
            self._writer.close()
            self._broadcast(json.dumps({"type": "gone", "feed": True}))

    async def _tail_events(self, run_dir: Path) -> None:
        """The show's events.jsonl, as its writer flushes it: each line to every browser."""
        path, pos, rest = run_dir / "events.jsonl", 0, b""
        while True:
            await asyncio.sleep(0.2)
            try:
                with path.open("rb") as f:
                    f.seek(pos)
                    data = f.read(1 << 20)
            except OSError:
                continue
            pos += len(data)
            *lines, rest = (rest + data).split(b"\n")
            for raw in lines:
                try:
                    ev = json.loads(raw)
                except ValueError:
                    continue
                keep = {k: ev.get(k) for k in ("t", "tick", "kind", "message")}
                text = json.dumps({"type": "event", **keep})
                self.events.append(text)
                self._broadcast(text)

    async def _panel_facts(self) -> None:
        while True:
            await asyncio.sleep(1.0)
            msg = {"type": "panel", "clients": len(self.clients), "counts": self.counts}
            self._broadcast(json.dumps(msg))


def _name(value: Any) -> bool:
    return isinstance(value, str) and 0 < len(value) <= 64 and value.isprintable()
