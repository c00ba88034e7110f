"""The viewer's HTTP/WebSocket server (Starlette + uvicorn).

Routes: ``/`` the page, ``/static/<name>`` a fixed whitelist of assets held in memory (no
client path ever reaches the file system), ``/ws`` the tab's WebSocket, ``/screenshot`` a
PNG rendered server-side, ``/section.csv`` a tab's last cross-section's rows, ``/api/info`` the cloud and settings schema. With a token (always
on a non-loopback bind) every route needs ``?token=...``; on a loopback bind the Host header
must name the loopback (no DNS rebinding) and a WebSocket's Origin must match its Host, port included
(a token, which another site's page cannot know, lets a reverse proxy in: gp.Viewer behind a JupyterHub's).
Every address the page uses is relative to the page, so it works under any prefix a proxy strips.
``/screenshot``, ``/section.csv`` and ``/api/info`` refuse what another site's page asks for (Sec-Fetch-Site).
Each request head must arrive within HEAD_TIMEOUT_S, and at most MAX_WAITING connections wait
for one (clients that trickle their headers); uvicorn's log lines show queries without their values.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import hmac
import ipaddress
import json
import logging
import secrets
import socket
import struct
import threading
import time
from importlib import resources
from urllib.parse import quote, unquote, urlsplit

from ..errors import GigapointError, warnings_kept
from ..io.http import hidden_query
from ..live.wire import MAX_PUSH_BYTES
from . import protocol as P
from .session import SEND_TIMEOUT_S, ViewerCore

log = logging.getLogger("gigapoint.viewer")

STATIC_TYPES = {
    "viewer.js": "text/javascript; charset=utf-8",
    "viewer.css": "text/css; charset=utf-8",
    "favicon.svg": "image/svg+xml",
}
HEAD_TIMEOUT_S = 10.0  # seconds a request's head may take, from connecting or from the previous answer
MAX_WAITING = 256  # connections waiting for a request head at once; past it the one waiting longest is closed
MAX_PUSHERS = 8  # /push connections at once: each may hold a frame of up to MAX_PUSH_BYTES (300 of them: 19 GB)
TAB_WS_MAX_BYTES = P.MAX_MESSAGE * 4  # a tab's message, in bytes (its limit counts characters: up to 4 bytes each)
LOOPBACK_HOSTS = frozenset({"127.0.0.1", "localhost", "::1"})
CSP = (
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; "
    "connect-src 'self' ws: wss:; base-uri 'none'; form-action 'none'"
)  # no frame-ancestors: '*' admits http(s) parents only, and gp.Viewer's IFrame sits in notebooks of any scheme (vscode-webview:, file:)


def _require_starlette():
    try:
        import starlette  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError as exc:
        raise GigapointError(f"the viewer needs Starlette and uvicorn ({exc.name} is missing): pip install 'gigapoint[viewer]'") from None


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _internal_error(what: str, exc: Exception) -> dict:
    """The reply to a message that failed for a bug (logged with its traceback): an error for
    that message only, the connection kept (``/ws`` and ``/push`` alike)."""
    log.exception("viewer: %s failed", what)
    return {"type": "error", "message": f"internal error: {exc}"[:300]}


def _load_static() -> dict[str, bytes]:
    root = resources.files("gigapoint.viewer") / "static"
    out = {name: (root / name).read_bytes() for name in STATIC_TYPES}
    out["index.html"] = (root / "index.html").read_bytes()
    return out


def _host_name(value: str) -> str:
    """'127.0.0.1:8000' -> '127.0.0.1', '[::1]:80' -> '::1'."""
    try:
        return (urlsplit("//" + value).hostname or "").lower()
    except ValueError:
        return ""


def _same_origin(origin: str, host: str) -> bool:
    """Whether a WebSocket's Origin is the server's own, port included (a page served from
    another port of the same host is another origin: comparing host names let it in)."""
    try:
        o, h = urlsplit(origin), urlsplit("//" + host)
        default = {"http": 80, "https": 443}.get(o.scheme)  # (a Host header without a port: the scheme's default)
        return bool(o.hostname) and o.hostname == h.hostname and (o.port or default) == (h.port or default)
    except ValueError:  # a port that is not a number
        return False


def _push_kept(frame, live) -> int:
    """``frame`` pushed into ``live`` on a thread of the server's: its warnings (the cloud's "frames
    arrive faster") kept in ``live.warnings`` for the user's thread to issue (snapshot,
    save, close), as a Player's are: issued here they escaped the user's catch, at any moment."""
    with warnings_kept(live.warnings):
        return frame.push_into(live)


def create_app(core: ViewerCore, token: str | None = None, allowed_hosts=None):
    """The Starlette app serving ``core``; ``allowed_hosts`` None accepts any Host header."""
    _require_starlette()
    from starlette.applications import Starlette
    from starlette.concurrency import run_in_threadpool
    from starlette.responses import JSONResponse, PlainTextResponse, Response
    from starlette.routing import Route, WebSocketRoute
    from starlette.websockets import WebSocketDisconnect

    static = _load_static()
    query = f"?token={quote(token)}" if token else ""
    index = static.pop("index.html").replace(b"{{QUERY}}", query.encode())
    allowed = None if allowed_hosts is None else {h.lower() for h in allowed_hosts}
    pushers = set()  # the open /push connections (touched on the event loop only)

    def refusal(conn) -> str | None:
        """Why ``conn`` is refused (a loopback server without a token was refused for its Host
        with 'wrong or missing token'), or None."""
        if allowed is not None and _host_name(conn.headers.get("host", "")) not in allowed:
            return "forbidden: the Host header must name this machine's loopback address (127.0.0.1, localhost)"
        if token is not None and not hmac.compare_digest(conn.query_params.get("token", "").encode(), token.encode()):
            return "forbidden: wrong or missing token"
        return None

    def authorized(conn) -> bool:
        return refusal(conn) is None

    def denied(request):
        return PlainTextResponse(refusal(request), status_code=403)

    def cross_site(request) -> bool:
        # another site's page (an <img> of /screenshot at 8192 px) made the server render for
        # seconds each, holding the render lock the tabs need; the viewer's own page is same-origin
        return request.headers.get("sec-fetch-site", "same-origin") not in ("same-origin", "none")

    headers = {"Cache-Control": "no-store", "X-Content-Type-Options": "nosniff", "Referrer-Policy": "no-referrer"}

    async def page(request):
        if not authorized(request):
            return denied(request)
        return Response(index, media_type="text/html; charset=utf-8", headers={**headers, "Content-Security-Policy": CSP})

    async def asset(request):
        if not authorized(request):
            return denied(request)
        name = request.path_params["name"]
        if name not in STATIC_TYPES:  # a fixed whitelist: nothing from the client reaches the file system
            return PlainTextResponse("not found", status_code=404)
        return Response(static[name], media_type=STATIC_TYPES[name], headers=headers)

    async def info(request):
        if not authorized(request):
            return denied(request)
        if cross_site(request):
            return PlainTextResponse("forbidden: a request from another site's page", status_code=403)
        return JSONResponse(P.json_safe({"cloud": core.cloud_info(), "schema": P.settings_schema(type(core.settings))}), headers=headers)

    async def screenshot(request):
        if not authorized(request):
            return denied(request)
        if cross_site(request):
            return PlainTextResponse("forbidden: a request from another site's page", status_code=403)
        q = request.query_params
        try:
            args = {k: q.get(k) for k in ("width", "height", "scale")}
            for k, v in args.items():
                if v is not None and not (v.isascii() and v.isdigit() and len(v) <= 6):  # ("²".isdigit(): int() failed, a 500)
                    raise P.ProtocolError(f"screenshot: {k} must be a positive integer")
            scale = int(args["scale"] or 1)
            if scale not in (1, 2, 4):
                raise P.ProtocolError("screenshot: scale must be 1, 2 or 4")
            width = int(args["width"]) if args["width"] else None
            height = int(args["height"]) if args["height"] else None
            sid = q.get("session") or None
            if sid is not None and len(sid) > 64:
                raise P.ProtocolError("screenshot: unknown session")
            png = await run_in_threadpool(core.screenshot, sid, width, height, scale)
        except GigapointError as exc:
            return PlainTextResponse(str(exc), status_code=400)
        w, h = struct.unpack(">II", png[16:24])
        return Response(png, media_type="image/png", headers={**headers, "Content-Disposition": f'attachment; filename="gigapoint_{w}x{h}.png"'})

    async def section_csv(request):
        if not authorized(request):
            return denied(request)
        if cross_site(request):
            return PlainTextResponse("forbidden: a request from another site's page", status_code=403)
        sid = request.query_params.get("session", "")[:64]
        try:
            csv = await run_in_threadpool(core.section_csv, sid)
        except GigapointError as exc:
            return PlainTextResponse(str(exc), status_code=400)
        return Response(csv, media_type="text/csv", headers={**headers, "Content-Disposition": 'attachment; filename="section.csv"'})

    async def ws_endpoint(websocket):
        origin = websocket.headers.get("origin")
        # without a token, only the page's own origin (another site's page cannot set it); with one,
        # the token proves the page, and a proxy in between (nginx, Colab's) may name the server in Host
        if not authorized(websocket) or (token is None and origin and not _same_origin(origin, websocket.headers.get("host", ""))):
            await websocket.close(code=1008)
            return
        await websocket.accept()
        loop = asyncio.get_running_loop()
        send_lock = asyncio.Lock()
        gone = threading.Event()

        async def send(kind, payload):
            async with send_lock:
                if kind == "bytes":
                    await websocket.send_bytes(payload)
                else:
                    await websocket.send_text(json.dumps(P.json_safe(payload), separators=(",", ":")))

        def send_from_worker(kind, payload) -> bool:
            if gone.is_set():
                return False
            try:
                fut = asyncio.run_coroutine_threadsafe(send(kind, payload), loop)
            except RuntimeError:  # the loop is closed
                return False
            while True:
                try:
                    fut.result(timeout=SEND_TIMEOUT_S)
                    return True
                except concurrent.futures.TimeoutError:
                    if gone.is_set():
                        fut.cancel()
                        return False
                except Exception:  # noqa: BLE001 - the client went away mid-send
                    gone.set()
                    return False

        q = websocket.query_params
        try:
            w = P.integer({"type": "connect", "w": int(q.get("w", "1280"))}, "w", 1, P.MAX_VIEW_SIDE)
            h = P.integer({"type": "connect", "h": int(q.get("h", "720"))}, "h", 1, P.MAX_VIEW_SIDE)
        except (ValueError, P.ProtocolError):
            w, h = 1280, 720
        try:
            session = core.open_session(send_from_worker, w, h)
        except P.ProtocolError as exc:
            await send("json", {"type": "error", "message": str(exc)})
            await websocket.close(code=1013)
            return
        try:
            state, settings, _ = session.snapshot()
            await send(
                "json",
                {
                    "type": "hello",
                    "session": session.id,
                    "cloud": session.cloud_shown,
                    "schema": P.settings_schema(type(core.settings)),
                    "settings": P.settings_values(settings),
                    "classes": core.class_panel(settings.hidden_classes),  # the Classes panel's list
                    "camera": state.as_dict(),
                    "views": list(P.VIEW_NAMES),
                    "limits": {"max_view_side": P.MAX_VIEW_SIDE, "max_shot_side": P.MAX_SHOT_SIDE, "max_message": P.MAX_MESSAGE},
                },
            )
            while True:
                message = await websocket.receive()
                if message["type"] == "websocket.disconnect":
                    break
                kind = None
                try:
                    msg = P.parse_message(message.get("text"))
                    kind = msg["type"]
                    reply = session.handle(msg)
                except P.ProtocolError as exc:
                    reply = {"type": "error", "message": str(exc), "in_reply_to": kind}
                except Exception as exc:  # noqa: BLE001 - a bug: this message fails, the session goes on
                    reply = {**_internal_error(f"message {kind}", exc), "in_reply_to": kind}
                if reply is not None:
                    await send("json", reply)
        except (WebSocketDisconnect, RuntimeError, OSError, asyncio.CancelledError):
            pass
        except Exception:
            log.debug("viewer: websocket ended", exc_info=True)
        finally:
            gone.set()
            core.close_session(session)

    async def push_endpoint(websocket):
        """Frames from another process into a live cloud (live/wire.py): only with the push token
        printed at start; a malformed frame is answered with an error and the stream goes on."""
        from ..live.wire import decode_frame

        push_token = core.push_token
        given = websocket.query_params.get("push_token", "")
        if push_token is None or not authorized(websocket) or not hmac.compare_digest(given.encode(), push_token.encode()):
            await websocket.close(code=1008)  # unknown token: refused before anything is read
            return
        await websocket.accept()
        if len(pushers) >= MAX_PUSHERS:  # refused as /ws refuses a tab past its limit
            await websocket.send_text(json.dumps({"type": "error", "message": f"push: too many producers connected (limit {MAX_PUSHERS})"}))
            await websocket.close(code=1013)
            return
        pushers.add(websocket)
        try:
            while True:
                message = await websocket.receive()
                if message["type"] == "websocket.disconnect":
                    break
                try:
                    data = message.get("bytes")
                    try:
                        if data is None:
                            raise GigapointError("push: frames are binary messages (live/wire.py encode_frame)")
                        frame = decode_frame(data)
                    except GigapointError as exc:
                        core.cloud.refused(exc)  # counted, shown on the HUD; push counts its own
                        raise
                    seq = await run_in_threadpool(_push_kept, frame, core.cloud)
                    reply = {"type": "ack", "seq": seq}
                except GigapointError as exc:
                    reply = {"type": "error", "message": str(exc)[:500]}
                except Exception as exc:  # noqa: BLE001 - a bug must not cost the producer its connection (as /ws)
                    reply = _internal_error("a pushed frame", exc)
                await websocket.send_text(json.dumps(reply))
        except (WebSocketDisconnect, RuntimeError, OSError, asyncio.CancelledError):
            pass  # a producer gone mid-frame: nothing of its frame was pushed (frames are pushed whole)
        finally:
            pushers.discard(websocket)

    routes = [
        Route("/", page),
        Route("/index.html", page),
        Route("/static/{name}", asset),
        Route("/api/info", info),
        Route("/screenshot", screenshot),
        Route("/section.csv", section_csv),
        WebSocketRoute("/ws", ws_endpoint),
        WebSocketRoute("/push", push_endpoint),
    ]
    app = Starlette(routes=routes)
    app.state.core = core
    app.state.token = token
    return app


class _HiddenQueries(logging.Filter):
    """uvicorn at log_level 'info' (or 'debug') logs each WebSocket's path with its query: the
    page's token and the push token went to the terminal or a log file; their values hidden."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple):
            record.args = tuple(hidden_query(a) if isinstance(a, str) and a.startswith("/") else a for a in record.args)
        return True


_HIDDEN_QUERIES = _HiddenQueries()


def _head_deadline_protocol():
    """uvicorn's h11 protocol with a deadline on each request's head and a bound on the
    connections waiting for one (one class a server: its own waiting list). uvicorn times only
    the idle wait between requests: a client sending a header byte a second held its connection
    for ever, and 1,100 of them used up the usual limit of 1,024 open files (the page no longer
    loaded). A real client's head comes at once, so it is never the one waiting longest.

    Its WebSockets other than ``/push`` take messages of TAB_WS_MAX_BYTES at most: uvicorn has one
    ``ws_max_size`` for all, raised to MAX_PUSH_BYTES on a live viewer, so a tab's ``/ws`` read a
    64 MB message whole before refusing it; now refused by its frame's header (close 1009)."""
    import copy
    from collections import OrderedDict

    from uvicorn.protocols.http.h11_impl import H11Protocol

    waiting: OrderedDict = OrderedDict()  # protocol -> its deadline's timer, the longest waiting first
    tab_config = []  # the server's config copied with the tab's message limit (made at the first upgrade: loaded)

    class HeadDeadline(H11Protocol):
        def connection_made(self, transport) -> None:
            super().connection_made(transport)
            self._wait()

        def data_received(self, data: bytes) -> None:
            super().data_received(data)
            if self.transport.get_protocol() is not self or (self.cycle is not None and not self.cycle.response_complete):
                self._stop_waiting()  # a request is answered, or the connection became a WebSocket

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if not self.transport.is_closing() and (self.cycle is None or self.cycle.response_complete):
                self._wait()  # the next request's head (kept-alive connection)

        def connection_lost(self, exc) -> None:
            self._stop_waiting()
            super().connection_lost(exc)

        def handle_websocket_upgrade(self, event) -> None:
            # the path as the router matches it (unquoted: /pus%68 is /push); this protocol ends with the upgrade
            path = unquote(event.target.decode("latin-1").partition("?")[0])
            if path != "/push" and self.config.ws_max_size > TAB_WS_MAX_BYTES:
                if not tab_config:
                    tab_config.append(copy.copy(self.config))
                    tab_config[0].ws_max_size = TAB_WS_MAX_BYTES
                self.config = tab_config[0]
            super().handle_websocket_upgrade(event)

        def _wait(self) -> None:
            self._stop_waiting()
            while len(waiting) >= MAX_WAITING:
                waiting.popitem(last=False)[0]._give_up()
            waiting[self] = self.loop.call_later(HEAD_TIMEOUT_S, self._give_up)

        def _stop_waiting(self) -> None:
            timer = waiting.pop(self, None)
            if timer is not None:
                timer.cancel()

        def _give_up(self) -> None:
            self._stop_waiting()
            if not self.transport.is_closing():
                self.transport.close()

    return HeadDeadline


def check_address(host, port) -> None:
    """The checks of ``ViewerServer``'s host and port that need no socket (the live CLI makes them
    before its stream starts playing and recording)."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:  # True was port 1
        raise GigapointError(f"port must be in 0..65535, got {port!r}")
    if not isinstance(host, str) or not host.strip():  # 5: an AttributeError; "": "Name or service not known"
        raise GigapointError(f"host must be an address or a host name (127.0.0.1: this machine only), got {host!r}")


def listening_socket(host, port) -> socket.socket:
    """The socket a ``ViewerServer`` on ``host``:``port`` serves, bound and listening: made before
    the cloud is read, so that a port in use is said at once, not after the whole file was read."""
    check_address(host, port)
    sock = None
    try:
        family, kind, proto, _, addr = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        sock = socket.socket(family, kind, proto)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(addr)
    except OSError as exc:
        if sock is not None:
            sock.close()
        raise GigapointError(f"host={host!r}, port={port!r}: cannot listen there ({exc.strerror or exc})") from None
    sock.listen(128)  # (uvicorn listens again with its backlog)
    sock.setblocking(False)
    return sock


class ViewerServer:
    """The viewer bound to a socket: run it in the foreground (CLI) or in a background thread (Jupyter).
    ``sock``: one ``listening_socket(host, port)`` made before the cloud was read (the server owns it then)."""

    def __init__(self, cloud, host: str = "127.0.0.1", port: int = 0, token: str | None = None, settings=None, log_level: str = "warning",
                 sock: socket.socket | None = None):
        _require_starlette()
        import uvicorn

        # first: listening_socket checks host and port (a given socket's were checked when it was made)
        self.sock = sock if sock is not None else listening_socket(host, port)
        self.host = host
        self.loopback = is_loopback(host)
        self.token = token if token is not None else (None if self.loopback else secrets.token_urlsafe(18))
        try:
            self.core = ViewerCore(cloud, settings)
        except BaseException:
            if sock is None:  # (a given socket is closed by its maker)
                self.sock.close()
            raise
        # the address bound is allowed too: --host 127.0.0.2 answered its own URL with 403
        allowed = LOOPBACK_HOSTS | {host.strip("[]").lower()} if self.loopback and self.token is None else None
        self.app = create_app(self.core, self.token, allowed)
        self.port = self.sock.getsockname()[1]
        config = uvicorn.Config(
            self.app,
            log_level=log_level,
            lifespan="off",
            ws_max_size=TAB_WS_MAX_BYTES if self.core.push_token is None else MAX_PUSH_BYTES,  # a live cloud's /push takes frames (/ws: the tab's limit)
            ws_ping_interval=20.0,
            ws_ping_timeout=20.0,
            timeout_graceful_shutdown=2,
            access_log=False,
            http=_head_deadline_protocol(),
            backlog=128,  # also the connections accepted at once: 2048 opened more files than a usual limit (1024) before any was closed
        )
        for name in ("uvicorn.error", "uvicorn.access"):  # (once: the same filter)
            logging.getLogger(name).addFilter(_HIDDEN_QUERIES)
        self.server = uvicorn.Server(config)
        self.thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        host = self.host if self.host not in ("0.0.0.0", "::", "") else socket.gethostname()
        if ":" in host:
            host = f"[{host}]"
        return f"http://{host}:{self.port}/" + (f"?token={quote(self.token)}" if self.token else "")

    @property
    def push_url(self) -> str | None:
        """Where another process pushes frames into the live cloud shown (``ws://.../push?push_token=...``,
        with the page's ``token=`` too when the server needs one: not on loopback; live/wire.PushClient);
        None for other clouds."""
        token = self.core.push_token
        if token is None:
            return None
        base, _, query = self.url.partition("?")
        return base.rstrip("/").replace("http", "ws", 1) + "/push?" + (query + "&" if query else "") + f"push_token={token}"

    def serve_forever(self) -> None:
        """Serve in this thread until Ctrl+C (uvicorn installs its signal handlers in the main thread)."""
        try:
            self.server.run(sockets=[self.sock])
        finally:
            self.core.close_all()

    def start(self, timeout: float = 10.0) -> ViewerServer:
        """Serve from a background thread; returns once the server accepts connections."""
        self.thread = threading.Thread(target=self.serve_forever, name="gigapoint-viewer-server", daemon=True)
        self.thread.start()
        t0 = time.monotonic()
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() - t0 > timeout:
                raise GigapointError(f"viewer server on {self.host}:{self.port} did not start")
            time.sleep(0.01)
        return self

    @property
    def closed(self) -> bool:
        """Whether ``close`` was called (the server stops, or has)."""
        return bool(self.server.should_exit)

    def close(self) -> None:
        self.server.should_exit = True
        if self.thread is not None:
            self.thread.join(timeout=10)
        self.core.close_all()
        try:
            self.sock.close()
        except OSError:
            pass
