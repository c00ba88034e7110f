"""The viewer behind a prefix-stripping reverse proxy, as jupyter-server-proxy serves it on a
JupyterHub: https://hub/user/NAME/proxy/PORT/... reaches the viewer as /..., its Host header the hub's."""

from __future__ import annotations

import asyncio
import re
import socket
import threading
import time
from urllib.parse import urljoin, urlsplit

import numpy as np
import pytest

pytestmark = [pytest.mark.timeout(180)]
pytest.importorskip("starlette")
pytest.importorskip("uvicorn")
httpx = pytest.importorskip("httpx")
pytest.importorskip("websockets")

import gigapoint
from gigapoint.viewer import jupyter

PREFIX = "/user/x/proxy/"
HUB_HOST = "hub.example.org"  # what the browser's Host header names; jupyter-server-proxy passes it on
CHROMIUM_EXTRA_ARGS = [f"--host-resolver-rules=MAP {HUB_HOST} 127.0.0.1"]  # the browser (conftest.py) reaches the proxy by the hub's name


def proxy_app(keep_host: bool):
    """A Starlette app forwarding ``/user/x/proxy/PORT/rest`` (HTTP and WebSocket) to
    ``127.0.0.1:PORT/rest``: the Host header kept (jupyter-server-proxy) or made the target's (nginx's default)."""
    from starlette.applications import Starlette
    from starlette.responses import Response
    from starlette.routing import Route, WebSocketRoute
    from websockets.asyncio.client import connect

    def target(conn) -> tuple[str, dict]:
        port, rest = conn.path_params["port"], conn.path_params["rest"]
        headers = {k: v for k, v in conn.headers.items() if k.lower() not in ("connection", "upgrade", "content-length") and not k.lower().startswith("sec-websocket")}
        if not keep_host:
            headers["host"] = f"127.0.0.1:{port}"
        query = f"?{conn.url.query}" if conn.url.query else ""
        return f"127.0.0.1:{port}/{rest}{query}", headers

    async def http(request):
        where, headers = target(request)
        async with httpx.AsyncClient(timeout=120) as client:
            r = await client.request(request.method, f"http://{where}", headers=headers, content=await request.body())
        return Response(r.content, r.status_code, headers={k: v for k, v in r.headers.items() if k.lower() not in ("content-length", "content-encoding", "transfer-encoding", "connection")})

    async def ws(websocket):
        where, headers = target(websocket)
        origin, host = headers.pop("origin", None), headers.pop("host")
        headers.pop("user-agent", None)
        try:  # the address names the Host header; the connection goes to the viewer
            backend = await connect(f"ws://{host}/{where.partition('/')[2]}", host="127.0.0.1", port=websocket.path_params["port"], additional_headers=headers, origin=origin, max_size=None)
        except Exception:  # noqa: BLE001 - the viewer refused: so does the proxy
            await websocket.close(code=1008)
            return
        await websocket.accept()

        async def to_backend():
            while True:
                m = await websocket.receive()
                if m["type"] == "websocket.disconnect":
                    break
                await backend.send(m["bytes"] if m.get("bytes") is not None else m["text"])

        async def to_browser():
            async for m in backend:
                await (websocket.send_bytes(m) if isinstance(m, bytes) else websocket.send_text(m))

        pumps = [asyncio.create_task(to_backend()), asyncio.create_task(to_browser())]
        await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
        for p in pumps:
            p.cancel()
        await backend.close()

    path = PREFIX + "{port:int}/{rest:path}"
    return Starlette(routes=[Route(path, http, methods=["GET", "POST", "HEAD"]), WebSocketRoute(path, ws)])


@pytest.fixture(params=[True, False], ids=["host-kept", "host-rewritten"], scope="module")
def proxy(request):
    """The proxy's base address (``http://127.0.0.1:N``), served from a background thread."""
    import uvicorn

    server = uvicorn.Server(uvicorn.Config(proxy_app(keep_host=request.param), host="127.0.0.1", port=0, log_level="warning", lifespan="off"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started and time.monotonic() < deadline:
        time.sleep(0.02)
    port = server.servers[0].sockets[0].getsockname()[1]
    yield f"http://127.0.0.1:{port}", request.param
    server.should_exit = True
    thread.join(timeout=10)


def scene():
    """A green ground: any frame that shows it has green pixels (the page's background has none)."""
    g = np.stack(np.meshgrid(np.linspace(0, 100, 120), np.linspace(0, 80, 96), indexing="ij"), -1).reshape(-1, 2)
    xyz = np.column_stack([g, np.zeros(len(g))])
    rgb = np.zeros((len(g), 3), np.uint8)
    rgb[:, 1] = 220
    return gigapoint.from_arrays(xyz, rgb, name="ground")


@pytest.fixture()
def viewer(proxy, monkeypatch):
    """A Viewer told (as on a JupyterHub with jupyter-server-proxy) that the browser reaches it through the proxy."""
    base, keep_host = proxy
    monkeypatch.setenv("JUPYTERHUB_SERVICE_PREFIX", "/user/x/")
    monkeypatch.setattr(jupyter, "_importable", lambda name: name == "jupyter_server_proxy")
    with gigapoint.Viewer(scene(), display=False) as v:
        yield v, base, keep_host


def test_the_page_is_served_through_a_prefix_stripping_proxy(viewer):
    """Every address the page names resolves under the proxy's prefix and answers 200 there: an
    absolute one (/static/..., /ws) would reach the hub's root instead of the viewer."""
    v, base, keep_host = viewer
    page_url = base + v.shown_at
    assert v.shown_at.startswith(f"{PREFIX}{v.server.port}/?token=")
    headers = {"Host": HUB_HOST} if keep_host else {}
    page = httpx.get(page_url, headers=headers, timeout=30)
    assert page.status_code == 200, page.text  # (403: the Host header named the hub, not the loopback)
    refs = re.findall(r'(?:src|href)="([^"]+)"', page.text)
    assert len(refs) == 3 and not [r for r in refs if r.startswith("/") or urlsplit(r).scheme], refs
    for ref in refs:
        asset = httpx.get(urljoin(page_url, ref), headers=headers, timeout=30)
        assert asset.status_code == 200, (ref, asset.status_code)
        if ref.startswith("static/viewer.js"):  # the script's own addresses: relative too ("ws", "screenshot")
            assert not re.findall(r"""["'`]/[A-Za-z]""", asset.text)
    shot = httpx.get(urljoin(page_url, "screenshot?width=64&height=48&token=" + v.server.token), headers=headers, timeout=60)
    assert shot.status_code == 200 and shot.content[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_websocket_works_through_the_proxy(viewer):
    """The tab's WebSocket, its Origin the hub's page: the proxy's Host is the hub (kept) or the viewer's own (rewritten)."""
    from websockets.sync.client import connect

    v, base, _ = viewer
    page_url = base.replace("http://127.0.0.1", f"ws://{HUB_HOST}") + v.shown_at  # the Host header the hub's name
    to_proxy = socket.create_connection(("127.0.0.1", urlsplit(base).port))
    with connect(urljoin(page_url, "ws?w=32&h=24&token=" + v.server.token), sock=to_proxy, origin=f"https://{HUB_HOST}", open_timeout=30) as ws:
        hello = ws.recv(timeout=30)
        assert '"type":"hello"' in hello
        assert isinstance(ws.recv(timeout=60), bytes)  # a frame came through


@pytest.mark.browser
def test_a_browser_sees_points_through_the_proxy(viewer, browser):
    """Chromium loads the page from the proxy by the hub's name (so its Host and Origin are the hub's) and draws a frame of the cloud."""
    v, base, keep_host = viewer
    if not keep_host:
        pytest.skip("the browser's Host is the proxy's own address either way")
    ctx = browser.new_context(viewport={"width": 290 + 320, "height": 240})
    try:
        pg = ctx.new_page()
        errors = []
        pg.on("pageerror", lambda e: errors.append(str(e)))
        pg.goto(base.replace("127.0.0.1", HUB_HOST) + v.shown_at)
        pg.wait_for_function("() => document.getElementById('canvas').dataset.full === 'true'", timeout=60_000)
        rgba = pg.evaluate(
            "() => { const c = document.getElementById('canvas'); return Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data); }"
        )
        pixels = np.asarray(rgba, np.uint8).reshape(-1, 4)
        green = (pixels[:, 1] > 150) & (pixels[:, 0] < 80)
        assert green.mean() > 0.05, green.mean()  # the ground, not the background
        assert not errors, errors
    finally:
        ctx.close()
