"""The viewer server: protocol, hostile input, static whitelist, tokens, picking, screenshots, many tabs."""

from __future__ import annotations

import io
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import warnings
from contextlib import contextmanager

import numpy as np
import pytest

pytest.importorskip("starlette")
pytest.importorskip("uvicorn")
pytest.importorskip("httpx")

from PIL import Image

with warnings.catch_warnings():  # Starlette >= 1.x prefers httpx2 for its test client; httpx still works
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

import gigapoint
from gigapoint.viewer import protocol as P
from gigapoint.viewer import session as S
from gigapoint.viewer.server import LOOPBACK_HOSTS, ViewerServer, create_app
from gigapoint.viewer.session import ViewerCore

pytestmark = [pytest.mark.timeout(120), pytest.mark.filterwarnings("ignore::DeprecationWarning")]

MARKER = np.array([637050.123456789, 4850040.987654321, 30.0])


@contextmanager
def served(cloud, point_size: int):
    """(a TestClient of the viewer's app, its ViewerCore) over ``cloud``: the tools' tests' client."""
    from starlette.testclient import TestClient

    from gigapoint.viewer.server import create_app
    from gigapoint.viewer.session import ViewerCore

    core = ViewerCore(cloud, gigapoint.RenderSettings(point_size=point_size))
    with TestClient(create_app(core)) as c:
        yield c, core
    core.close_all()


def marker_scene() -> gigapoint.PointCloud:
    """A 100 m x 80 m ground grid at UTM-sized coordinates and one marker point 20 m above its middle."""
    g = np.stack(np.meshgrid(np.linspace(0, 100, 160), np.linspace(0, 80, 128), indexing="ij"), -1).reshape(-1, 2)
    ground = np.column_stack([g[:, 0] + 637000.0, g[:, 1] + 4850000.0, 10.0 + 0.02 * g[:, 0]])
    xyz = np.vstack([ground, MARKER])
    rgb = np.zeros((len(xyz), 3), np.uint8)
    rgb[:, 1] = 200
    rgb[-1] = (255, 0, 0)
    intensity = np.ones(len(xyz), np.uint16)
    intensity[-1] = 4242
    return gigapoint.from_arrays(xyz, rgb, name="marker", intensity=intensity)


@pytest.fixture(scope="module")
def cloud():
    return marker_scene()


@pytest.fixture()
def core(cloud):
    c = ViewerCore(cloud)
    yield c
    c.close_all()


@pytest.fixture()
def client(core):
    with TestClient(create_app(core)) as c:
        yield c


def receive(ws, want, limit=200):
    """The next message for which want(kind, payload) is true; kind is 'json' or 'frame'."""
    for _ in range(limit):
        m = ws.receive()
        if m.get("bytes") is not None:
            item = ("frame", P.unpack_frame(m["bytes"]))
        elif m.get("text") is not None:
            item = ("json", json.loads(m["text"]))
        else:
            raise AssertionError(f"connection closed: {m}")
        if want(*item):
            return item[1]
    raise AssertionError("expected message never came")


def full_frame(seq=None):
    return lambda k, p: k == "frame" and p[0]["full"] and (seq is None or p[0]["seq"] == seq)


def reply(kind):
    return lambda k, p: k == "json" and p["type"] == kind


def jpeg_pixels(jpeg: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(jpeg)).convert("RGB"))


# --- HTTP: page, static whitelist, screenshot ---------------------------------------------------------------
def test_page_and_assets(client):
    r = client.get("/")
    assert r.status_code == 200 and "<canvas" in r.text and "static/viewer.js" in r.text
    assert "default-src 'none'" in r.headers["content-security-policy"]
    assert "http" not in r.text.replace("http-equiv", "")  # no CDN: every asset is ours
    for name, ctype in [("viewer.js", "javascript"), ("viewer.css", "text/css"), ("favicon.svg", "svg")]:
        r = client.get(f"/static/{name}")
        assert r.status_code == 200 and ctype in r.headers["content-type"] and len(r.content) > 100
    js = client.get("/static/viewer.js").text
    assert "//" not in js.replace("// ", "").replace("://", "") or "cdn" not in js.lower()


@pytest.mark.parametrize(
    "path",
    [
        "/static/../../etc/passwd",
        "/static/%2e%2e/%2e%2e/etc/passwd",
        "/static/%2e%2e%2f%2e%2e%2fetc%2fpasswd",
        "/static/..%2f..%2f..%2fetc%2fpasswd",
        "/static/..%5c..%5cetc%5cpasswd",
        "/static/%252e%252e%252fetc%252fpasswd",
        "/static//etc/passwd",
        "/static/viewer.js%00.png",
        "/static/index.html",
        "/static/__init__.py",
        "/static/../server.py",
        "/static/",
        "/etc/passwd",
        "/..%2f..%2fetc%2fpasswd",
    ],
)
def test_static_path_traversal_is_refused(client, path):
    r = client.get(path)
    assert r.status_code == 404
    assert "root:" not in r.text and "import" not in r.text


def test_screenshot_sizes(client, core):
    r = client.get("/screenshot?width=300&height=200")
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    assert 'filename="gigapoint_300x200.png"' in r.headers["content-disposition"]
    assert Image.open(io.BytesIO(r.content)).size == (300, 200)
    with client.websocket_connect("/ws?w=160&h=100") as ws:
        hello = receive(ws, reply("hello"))
        r = client.get(f"/screenshot?session={hello['session']}&scale=4")
        assert Image.open(io.BytesIO(r.content)).size == (640, 400)
        r = client.get(f"/screenshot?session={hello['session']}&width=320")
        assert Image.open(io.BytesIO(r.content)).size == (320, 200)  # the view's aspect
    # "²" passed isdigit() and failed int(): an internal server error (500); "٣" was taken as 3
    for bad in ["width=0&height=10", "width=99999&height=10", "scale=3", "width=-5", "width=1e3", "session=nope", "width=8000&height=8000",
                "width=²", "scale=²", "width=٣"]:
        r = client.get(f"/screenshot?{bad}")
        assert r.status_code == 400, bad
        assert "screenshot" in r.text


# --- tokens and hosts -----------------------------------------------------------------------------------------
def test_token_required_everywhere(core):
    token = "s3cret-t0ken"
    with TestClient(create_app(core, token=token)) as c:
        for path in ["/", "/static/viewer.js", "/screenshot?width=8&height=8", "/api/info"]:
            assert c.get(path).status_code == 403, path
            sep = "&" if "?" in path else "?"
            assert c.get(f"{path}{sep}token=wrong").status_code == 403, path
            assert c.get(f"{path}{sep}token={token}").status_code == 200, path
        page = c.get(f"/?token={token}").text
        assert f"static/viewer.js?token={token}" in page
        for url in ["/ws", "/ws?token=wrong"]:
            with pytest.raises(WebSocketDisconnect) as exc, c.websocket_connect(url) as ws:
                ws.receive()
            assert exc.value.code == 1008
        with c.websocket_connect(f"/ws?token={token}&w=64&h=64") as ws:
            assert receive(ws, reply("hello"))["cloud"]["points"] == core.cloud.n_points


def test_non_loopback_bind_makes_a_token(cloud):
    srv = ViewerServer(cloud, host="0.0.0.0", port=0)
    try:
        assert not srv.loopback and srv.token and len(srv.token) >= 20
        assert f"token={srv.token}" in srv.url
        assert ViewerServer(cloud, host="0.0.0.0", port=0).token != srv.token  # random each time
    finally:
        srv.sock.close()
    local = ViewerServer(cloud)
    try:
        assert local.loopback and local.token is None and local.url.startswith("http://127.0.0.1:")
    finally:
        local.sock.close()


def test_loopback_checks_host_and_origin(core):
    app = create_app(core, allowed_hosts=LOOPBACK_HOSTS)
    with TestClient(app, base_url="http://evil.example.com") as c:  # DNS rebinding
        assert c.get("/").status_code == 403
    with TestClient(app, base_url="http://127.0.0.1:8123") as c:
        assert c.get("/").status_code == 200
        with pytest.raises(WebSocketDisconnect), c.websocket_connect("ws://127.0.0.1:8123/ws", headers={"origin": "http://evil.example.com"}) as ws:
            ws.receive()
        with c.websocket_connect("ws://127.0.0.1:8123/ws?w=32&h=32", headers={"origin": "http://127.0.0.1:8123"}) as ws:
            receive(ws, reply("hello"))


# --- the websocket protocol -------------------------------------------------------------------------------------
HOSTILE = [
    "{not json",
    "[1, 2, 3]",
    '"just a string"',
    "null",
    '{"type": "launch_missiles"}',
    '{"type": ["orbit"]}',
    '{"type": "orbit", "dyaw": "ten"}',
    '{"type": "orbit", "dyaw": 1e300}',
    '{"type": "camera", "yaw": NaN}',
    '{"type": "camera", "distance": Infinity}',
    '{"type": "camera", "distance": 0}',
    '{"type": "camera", "target": [1, 2]}',
    '{"type": "camera", "target": [1, 2, NaN]}',
    '{"type": "resize", "width": 0, "height": 100}',
    '{"type": "resize", "width": 100000, "height": 100}',
    '{"type": "resize", "width": 10.5, "height": 100}',
    '{"type": "zoom", "factor": 0}',
    '{"type": "zoom", "factor": -2}',
    '{"type": "zoom", "factor": 2, "x": 5, "y": 0.5}',
    '{"type": "move", "forward": 1e300}',
    '{"type": "view", "name": "../../etc"}',
    '{"type": "fov", "value": 0}',
    '{"type": "pick", "x": -1, "y": 0.5}',
    '{"type": "pick", "x": 0.5, "y": 0.5, "pivot": "yes"}',
    '{"type": "settings", "values": {"point_budget": 1e12}}',
    '{"type": "settings", "values": {"threads": 1e12}}',
    '{"type": "settings", "values": {"no_such_field": 1}}',
    '{"type": "settings", "values": {"background": "#zzzzzz"}}',
    '{"type": "settings", "values": {"precision_threshold_px": -5}}',
    '{"type": "settings", "values": "all of them"}',
    '{"type": "quality", "jpeg_quality": 1000}',
    '{"type": "ping", "seq": -1}',
    "[" * 50_000,
    "x" * (P.MAX_MESSAGE + 10),
]


def test_hostile_messages_get_errors_and_the_connection_survives(client):
    with client.websocket_connect("/ws?w=96&h=64") as ws:
        hello = receive(ws, reply("hello"))
        receive(ws, full_frame())
        for text in HOSTILE:
            ws.send_text(text)
            err = receive(ws, lambda k, p: k == "json" and p["type"] in ("error", "settings", "pong"))
            assert err["type"] == "error", text[:60]
            assert isinstance(err["message"], str) and 0 < len(err["message"]) < 600
        ws.send_bytes(b"\x00\x01binary")
        assert receive(ws, reply("error"))["message"].startswith("binary")
        ws.send_json({"type": "ping", "t": 7})
        assert receive(ws, reply("pong"))["t"] == 7
        ws.send_json({"type": "refresh", "seq": 99})
        header, jpeg = receive(ws, full_frame(99))
        assert header["camera"] == hello["camera"]  # nothing hostile changed the camera
        assert (header["width"], header["height"]) == (96, 64) and jpeg[:2] == b"\xff\xd8"


def test_frame_shows_the_scene_and_settings_change_it(client):
    with client.websocket_connect("/ws?w=160&h=120") as ws:
        receive(ws, reply("hello"))
        header, jpeg = receive(ws, full_frame())
        img = jpeg_pixels(jpeg)
        assert header["points"] == header["points_total"] == 160 * 128 + 1
        green = (img[..., 1] > 120) & (img[..., 0] < 90)
        assert green.mean() > 0.05  # the ground is there
        assert img[0, 0].max() < 30  # black background in the corner
        ws.send_json({"type": "settings", "values": {"background": "#ffffff"}, "seq": 1})
        assert receive(ws, reply("settings"))["values"]["background"] == [255, 255, 255, 255]
        _, jpeg = receive(ws, full_frame(1))
        assert jpeg_pixels(jpeg)[0, 0].min() > 225


def test_moving_renders_coarse_then_refines_and_drops_stale_requests(client, core):
    with client.websocket_connect("/ws?w=320&h=240") as ws:
        hello = receive(ws, reply("hello"))
        receive(ws, full_frame())
        n = 40
        for i in range(1, n + 1):
            ws.send_json({"type": "orbit", "dyaw": 1.0, "dpitch": 0.0, "seq": i})
        t_last_input = time.monotonic()
        frames = []
        while True:
            header, _ = receive(ws, lambda k, p: k == "frame")
            frames.append(header)
            if header["full"] and header["seq"] == n:
                break
        assert time.monotonic() - t_last_input < 1.5  # refined within the second (+ slack for a loaded CI)
        assert len(frames) < n  # stale requests were dropped, not queued
        moving = [h for h in frames if not h["full"]]
        assert moving, "no reduced-resolution frame while moving"
        assert all(h["width"] == round(320 / h["scale"]) and h["scale"] > 1 for h in moving)
        assert frames[-1]["width"] == 320
        assert frames[-1]["camera"]["yaw"] == pytest.approx(hello["camera"]["yaw"] + n)


def marker_position(core, session_id):
    s = core.sessions[session_id]
    return s.last.camera


def test_pick_the_marker_and_set_it_as_pivot(client, core, cloud):
    with client.websocket_connect("/ws?w=200&h=160") as ws:
        hello = receive(ws, reply("hello"))
        ws.send_json({"type": "view", "name": "top", "seq": 1})
        receive(ws, full_frame(1))
        cam = core.sessions[hello["session"]].last.camera
        x, y, w, _ = cam.screen_rows() @ np.append(MARKER, 1.0)
        ws.send_json({"type": "pick", "x": (x / w) / cam.width, "y": (y / w) / cam.height, "id": 5})
        pick = receive(ws, reply("pick"))
        assert pick["id"] == 5 and pick["found"]
        info = pick["info"]
        assert info["index"] == int(np.argmax(cloud.attributes["intensity"]))
        assert info["intensity"] == 4242 and info["rgba"] == [255, 0, 0, 255]
        assert info["position"] == cloud.positions([info["index"]])[0].tolist()  # full float64 over the wire
        np.testing.assert_allclose(info["position"], MARKER, rtol=0, atol=1e-6)  # float32 would be off by ~0.03
        ws.send_json({"type": "pick", "x": 0.01, "y": 0.01, "id": 6})  # empty corner of the top view
        assert receive(ws, reply("pick")) == {"type": "pick", "id": 6, "found": False}
        ws.send_json({"type": "pick", "x": (x / w) / cam.width, "y": (y / w) / cam.height, "pivot": True, "seq": 2})
        assert receive(ws, reply("pick"))["pivot"] is True
        header, _ = receive(ws, full_frame(2))
        assert header["camera"]["target"] == info["position"]


def test_zoom_to_cursor_keeps_the_point_under_the_cursor(client, core):
    with client.websocket_connect("/ws?w=200&h=160") as ws:
        hello = receive(ws, reply("hello"))
        ws.send_json({"type": "view", "name": "top", "seq": 1})
        first, _ = receive(ws, full_frame(1))
        cam = core.sessions[hello["session"]].last.camera
        x, y, w, _ = cam.screen_rows() @ np.append(MARKER, 1.0)
        u, v = (x / w) / cam.width, (y / w) / cam.height
        ws.send_json({"type": "zoom", "factor": 0.5, "x": u, "y": v, "seq": 2})
        header, _ = receive(ws, full_frame(2))
        assert header["camera"]["distance"] == pytest.approx(first["camera"]["distance"] * 0.5)
        cam2 = core.sessions[hello["session"]].last.camera
        x2, y2, w2, _ = cam2.screen_rows() @ np.append(MARKER, 1.0)
        assert abs(x2 / w2 - x / w) < 1.0 and abs(y2 / w2 - y / w) < 1.0


def test_each_tab_has_its_own_camera_and_closing_releases_the_worker(client, core):
    with client.websocket_connect("/ws?w=64&h=48") as a, client.websocket_connect("/ws?w=64&h=48") as b:
        ha, hb = receive(a, reply("hello")), receive(b, reply("hello"))
        assert ha["session"] != hb["session"] and len(core.sessions) == 2
        a.send_json({"type": "orbit", "dyaw": 30.0, "seq": 1})
        fa, _ = receive(a, full_frame(1))
        b.send_json({"type": "refresh", "seq": 1})
        fb, _ = receive(b, full_frame(1))
        assert fa["camera"]["yaw"] != fb["camera"]["yaw"]
        threads = [s.thread for s in core.sessions.values()]
    deadline = time.monotonic() + 5
    while (core.sessions or any(t.is_alive() for t in threads)) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not core.sessions and not any(t.is_alive() for t in threads)


def test_render_failure_is_reported_and_settings_fall_back(client, monkeypatch):
    real = S.render_frame

    def flaky(cloud, camera, settings):
        if settings.adaptive_precision is False:
            raise gigapoint.GigapointError("backend exploded")
        return real(cloud, camera, settings)

    monkeypatch.setattr(S, "render_frame", flaky)
    with client.websocket_connect("/ws?w=64&h=48") as ws:
        receive(ws, full_frame())
        ws.send_json({"type": "settings", "values": {"adaptive_precision": False}})
        err = receive(ws, reply("error"))
        assert "backend exploded" in err["message"]
        assert receive(ws, reply("settings"))["values"]["adaptive_precision"] is True
        ws.send_json({"type": "refresh", "seq": 3})
        receive(ws, full_frame(3))


def test_session_limit(cloud):
    core = ViewerCore(cloud, max_sessions=2)
    with TestClient(create_app(core)) as c, c.websocket_connect("/ws?w=8&h=8") as a, c.websocket_connect("/ws?w=8&h=8") as b:
        receive(a, reply("hello"))
        receive(b, reply("hello"))
        with c.websocket_connect("/ws") as third:
            assert "too many" in receive(third, reply("error"))["message"]
    core.close_all()


# --- a real server: concurrency and clients that vanish ------------------------------------------------------------
@pytest.fixture()
def live(cloud):
    pytest.importorskip("websockets")
    srv = ViewerServer(cloud).start()
    yield srv
    srv.close()


def ws_url(srv, w=320, h=240):
    return f"ws://127.0.0.1:{srv.port}/ws?w={w}&h={h}"


def test_twenty_clients_at_once(live):
    from websockets.sync.client import connect

    results, errors = [], []
    start = threading.Barrier(20)

    def one(i):
        try:
            start.wait()
            with connect(ws_url(live, 160 + i, 120), open_timeout=30, max_size=2**24) as ws:
                hello = json.loads(ws.recv(timeout=30))
                ws.send(json.dumps({"type": "orbit", "dyaw": float(i), "seq": 1}))
                while True:
                    m = ws.recv(timeout=60)
                    if isinstance(m, bytes):
                        h, jpeg = P.unpack_frame(m)
                        if h["seq"] == 1 and h["full"]:
                            results.append((hello["session"], h["width"], jpeg[:2]))
                            return
        except Exception as exc:  # noqa: BLE001
            errors.append(repr(exc))

    threads = [threading.Thread(target=one, args=(i,)) for i in range(20)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(90)
    assert not errors, errors[:3]
    assert len(results) == 20 and len({r[0] for r in results}) == 20
    assert sorted(r[1] for r in results) == [160 + i for i in range(20)]
    assert all(r[2] == b"\xff\xd8" for r in results)
    deadline = time.monotonic() + 10
    while live.core.sessions and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not live.core.sessions


def test_websocket_origin_must_match_host_and_port(live):
    """Cross-site WebSocket hijacking from a page served on another port of the same host
    (any local dev server): its Origin names the host but not the port, and was let in."""
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    port = live.port
    for origin in [f"http://127.0.0.1:{port + 1}", "http://127.0.0.1", f"http://localhost:{port}",
                   f"http://127.0.0.1:{port}x", "null"]:  # fmt: skip
        with pytest.raises(InvalidStatus) as exc, connect(ws_url(live, 32, 32), origin=origin, open_timeout=10):
            pass
        assert exc.value.response.status_code == 403, origin
    for origin in [f"http://127.0.0.1:{port}", None]:  # the page itself; a client that is no browser sends none
        with connect(ws_url(live, 32, 32), origin=origin, open_timeout=10) as ws:
            assert json.loads(ws.recv(timeout=10))["type"] == "hello"


def test_other_sites_pages_cannot_make_the_server_render(live):
    """On loopback any page the user visits could ask for /screenshot (an <img>: 8192x4882
    pixels rendered for seconds under the lock the tabs need); browsers say where from."""
    import httpx

    base = f"http://127.0.0.1:{live.port}"
    for site in ["cross-site", "same-site"]:  # same-site: another port of 127.0.0.1
        for path in ["/screenshot?width=64&height=48", "/api/info"]:
            r = httpx.get(base + path, headers={"Sec-Fetch-Site": site}, timeout=30)
            assert (r.status_code, r.text) == (403, "forbidden: a request from another site's page"), (site, path)
    for headers in [{"Sec-Fetch-Site": "same-origin"}, {"Sec-Fetch-Site": "none"}, {}]:  # the viewer's download link; a typed URL; curl
        r = httpx.get(base + "/screenshot?width=64&height=48", headers=headers, timeout=30)
        assert r.status_code == 200 and Image.open(io.BytesIO(r.content)).size == (64, 48)
        assert httpx.get(base + "/api/info", headers=headers, timeout=30).json()["cloud"]["name"] == "marker"
    assert httpx.get(base + "/", headers={"Sec-Fetch-Site": "cross-site"}, timeout=30).status_code == 200  # Jupyter's iframe


def test_a_server_on_another_loopback_address_answers_its_own_url(cloud):
    import httpx

    srv = ViewerServer(cloud, host="127.0.0.2").start()
    try:
        assert srv.token is None and srv.url.startswith("http://127.0.0.2:")
        assert httpx.get(srv.url, timeout=30).status_code == 200  # was 403: its Host was not a loopback name
        r = httpx.get(srv.url, headers={"Host": "evil.example.com"}, timeout=30)  # DNS rebinding; it said "wrong or missing token"
        assert (r.status_code, r.text) == (403, "forbidden: the Host header must name this machine's loopback address (127.0.0.1, localhost)")
    finally:
        srv.close()


def test_disconnect_mid_frame_never_wedges(live):
    from websockets.sync.client import connect

    for i in range(6):
        ws = connect(ws_url(live, 2048, 2048), open_timeout=30, max_size=2**24)
        ws.recv(timeout=30)  # hello; the first 2048x2048 frame is rendering now
        ws.send(json.dumps({"type": "orbit", "dyaw": 5.0}))
        if i % 2:
            ws.close()
        else:
            ws.socket.close()  # vanish without a close handshake
    with connect(ws_url(live, 64, 48), open_timeout=30) as ws:
        json.loads(ws.recv(timeout=30))
        ws.send(json.dumps({"type": "refresh", "seq": 1}))
        while True:
            m = ws.recv(timeout=30)
            if isinstance(m, bytes) and P.unpack_frame(m)[0]["seq"] == 1:
                break

    def workers():
        return [t for t in threading.enumerate() if t.name.startswith("gigapoint-viewer-") and t.name != "gigapoint-viewer-server"]

    deadline = time.monotonic() + 20
    while (live.core.sessions or workers()) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not live.core.sessions and not workers()  # every tab's worker is gone


def test_viewer_for_jupyter(cloud):
    import httpx

    v = gigapoint.Viewer(cloud, display=False)
    try:
        assert v.url.startswith("http://127.0.0.1:")
        assert httpx.get(v.url, timeout=10).status_code == 200
        png = v.screenshot(240, 180)
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and Image.open(io.BytesIO(png)).size == (240, 180)
        img = np.asarray(Image.open(io.BytesIO(png)))
        assert (img[..., 1] > 120).mean() > 0.05  # the ground is in it
        for bad, problem in (  # "a" was int()'s ValueError, 100.5 cut to 100, scale 3 taken (the page refuses it)
            ({"width": "a"}, "width must be an integer from 1 to 8,192 pixels, got 'a'"),
            ({"height": 100.5}, "height must be an integer from 1 to 8,192 pixels, got 100.5"),
            ({"scale": 3}, "scale must be 1, 2 or 4, got 3"),
            ({"scale": 2.0}, "scale must be 1, 2 or 4, got 2.0"),
        ):
            with pytest.raises(gigapoint.GigapointError, match=f"^Viewer.screenshot: {re.escape(problem)}$"):
                v.screenshot(**bad)
        assert Image.open(io.BytesIO(v.screenshot(scale=2))).size == (2560, 1440)
    finally:
        v.close()
    with pytest.raises(httpx.TransportError):
        httpx.get(v.url, timeout=2)
    with pytest.raises(gigapoint.GigapointError, match=r"^Viewer of '.*': closed, its server stopped; open a new Viewer"):
        v.display()  # (it showed the frame of a server that was gone)
    with pytest.raises(gigapoint.GigapointError, match=r"^Viewer of '.*': closed, its server stopped; open a new Viewer to take a screenshot$"):
        v.screenshot(64, 48)  # (it still rendered the default view)
    assert repr(v).endswith(", closed)")
    with pytest.raises(gigapoint.GigapointError):
        gigapoint.Viewer(12345, display=False)
    for bad, problem in (
        ({"host": 5}, "host must be an address or a host name (127.0.0.1: this machine only), got 5"),  # an AttributeError
        ({"host": ""}, "host must be an address or a host name (127.0.0.1: this machine only), got ''"),
        ({"port": True}, "port must be in 0..65535, got True"),  # port 1
        ({"port": 70000}, "port must be in 0..65535, got 70000"),
        ({"port": "a"}, "port must be in 0..65535, got 'a'"),
        ({"display": "no"}, "Viewer: display must be True or False, got 'no'"),
    ):
        with pytest.raises(gigapoint.GigapointError, match=f"^{re.escape(problem)}$"):
            gigapoint.Viewer(cloud, **{"display": False, **bad})
    for bad in ({"width": 0}, {"height": -5}, {"width": 960.5}, {"height": True}):  # an IFrame of 0 pixels showed nothing
        with pytest.raises(gigapoint.GigapointError, match=r"^Viewer: (width|height) must be an integer from 1 to 16,384 pixels, got "):
            gigapoint.Viewer(cloud, display=False, **bad)


def test_viewer_redraw_shows_colours_the_program_changed():
    pytest.importorskip("websockets")
    from websockets.sync.client import connect

    cloud = marker_scene()
    with gigapoint.Viewer(cloud, display=False) as v, connect(ws_url(v.server, 160, 120)) as ws:

        def next_frame(timeout):
            while True:
                m = ws.recv(timeout=timeout)
                if isinstance(m, bytes) and P.unpack_frame(m)[0]["full"]:
                    return jpeg_pixels(P.unpack_frame(m)[1])

        assert (next_frame(30)[..., 1] > 120).mean() > 0.05  # the green ground
        cloud.set_colors([0, 0, 255])
        with pytest.raises(TimeoutError):
            next_frame(1.0)  # the tab does not watch the cloud
        v.redraw()
        img = next_frame(30)
        assert (img[..., 2] > 200).mean() > 0.05 and (img[..., 1] > 120).mean() < 0.001  # blue, no green left
    with pytest.raises(gigapoint.GigapointError, match=r"^Viewer of 'marker': closed, its server stopped; open a new Viewer to redraw the cloud$"):
        v.redraw()


def test_cli_view_serves_and_stops(tmp_path):
    env = {**os.environ, "BROWSER": "true"}
    bad = subprocess.run([sys.executable, "-m", "gigapoint.cli", "view"], check=False, capture_output=True, text=True, timeout=60, env=env)
    assert bad.returncode == 1 and bad.stderr.strip().startswith("error:") and len(bad.stderr.strip().splitlines()) == 1
    bad = subprocess.run([sys.executable, "-m", "gigapoint.cli", "view", str(tmp_path / "missing.laz"), "--no-browser"], check=False, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 1 and "missing.laz" in bad.stderr
    proc = subprocess.Popen(
        [sys.executable, "-m", "gigapoint.cli", "view", "--demo", "20000", "--no-browser"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("http://127.0.0.1:") and url.endswith("/")
        import httpx

        r = httpx.get(url, timeout=10)
        assert r.status_code == 200 and "<canvas" in r.text
        assert httpx.get(url + "screenshot?width=64&height=32", timeout=30).status_code == 200
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
    assert proc.returncode in (0, 130)


def test_octree_clouds_can_be_viewed_and_picked(tmp_path):
    lod = pytest.importorskip("gigapoint.lod")
    from gigapoint.io import demo_chunks

    lod.convert(list(demo_chunks(60_000, chunk_size=30_000)), tmp_path / "oct", max_leaf=5_000, partition_points=40_000)
    octree = lod.open_octree(tmp_path / "oct")
    core = ViewerCore(octree, gigapoint.RenderSettings(size_mode="fixed"))  # one-pixel points: a pixel shows its own point
    try:
        with TestClient(create_app(core)) as c, c.websocket_connect("/ws?w=200&h=150") as ws:
            hello = receive(ws, reply("hello"))
            assert hello["cloud"]["points"] == octree.n_points
            ws.send_json({"type": "view", "name": "top", "seq": 1})
            header, jpeg = receive(ws, full_frame(1))
            assert header["points"] > 0 and (jpeg_pixels(jpeg).sum(axis=2) > 30).mean() > 0.05
            ws.send_json({"type": "pick", "x": 0.5, "y": 0.5, "id": 1})
            pick = receive(ws, reply("pick"))
            assert pick["found"] and pick["info"]["source"] == "octree"  # exact: the arena still holds the frame's points
            exact = np.array(pick["info"]["position"])
            lo, hi = octree.bounds
            assert np.all(exact >= lo - 1e-6) and np.all(exact <= hi + 1e-6)
            close = gigapoint.Camera.orbit(lo + 0.25 * (hi - lo), yaw=0.0, pitch=60.0, distance=0.02 * float(np.max(hi - lo)), width=200, height=150)
            S.render_locked(octree, close, octree_settings := core.settings)  # another render, of nodes not drawn yet: the arena changes
            assert octree_settings is core.settings
            ws.send_json({"type": "pick", "x": 0.5, "y": 0.5, "id": 2})
            pick = receive(ws, reply("pick"))
            assert pick["info"]["source"] == "depth buffer"  # the arena may have changed: position from depth
            pixel_size = 2 * header["camera"]["distance"] * np.tan(np.radians(30)) / 150
            np.testing.assert_allclose(pick["info"]["position"], exact, atol=pixel_size)  # the pixel's centre, not the point
    finally:
        core.close_all()


def test_viewer_displays_an_iframe_under_ipython(cloud, monkeypatch):
    import types

    shown = []
    ipython = types.ModuleType("IPython")
    ipython.get_ipython = lambda: types.SimpleNamespace(displayhook=types.SimpleNamespace(exec_result=None))  # "inside IPython", no cell running
    display_mod = types.ModuleType("IPython.display")
    display_mod.IFrame = lambda url, width, height: ("iframe", url, width, height)
    display_mod.display = shown.append
    ipython.display = display_mod
    monkeypatch.setitem(sys.modules, "IPython", ipython)
    monkeypatch.setitem(sys.modules, "IPython.display", display_mod)
    for name in ("GIGAPOINT_VIEWER_URL", "JUPYTERHUB_SERVICE_PREFIX", "SSH_CONNECTION"):  # a local notebook (test_viewer_where_shown.py: the others)
        monkeypatch.delenv(name, raising=False)
    with gigapoint.Viewer(cloud, width=700, height=400) as v:
        assert shown == [("iframe", v.url, 700, 400)]


@pytest.mark.parametrize("fmt", ["potree", "copc"])
def test_the_viewer_offers_the_attributes_of_an_octree_read_node_by_node(tmp_path, fmt):
    """A Potree or COPC octree's ``attributes`` are empty until nodes are read: the viewer's
    'colour by attribute' list offered nothing for them."""
    out = tmp_path / ("o.copc.laz" if fmt == "copc" else "o")
    gigapoint.convert(marker_scene().chunks(), out, format=fmt)
    octree = gigapoint.open(out)
    assert not octree.attributes  # nothing read yet
    core = ViewerCore(octree)
    try:  # the format's own fields beside (Potree's classification, COPC's LAS fields)
        assert "intensity" in core.cloud_info()["attributes"] and set(core.cloud_info()["attributes"]) == set(octree.attribute_names)
    finally:
        core.close_all()


HUGE = "1" * 400  # a JSON integer past float's range: math.isfinite raised OverflowError


def test_integers_past_float_range_are_protocol_errors(client, caplog):
    """A huge integer is answered like any out-of-range number (was 'internal error: int too
    large to convert to float' and a logged traceback), and a huge ?w= no longer kills the socket."""
    with client.websocket_connect(f"/ws?w={HUGE}&h=64") as ws:
        hello = receive(ws, reply("hello"))
        assert hello["session"]
        for text in (
            f'{{"type": "orbit", "dyaw": {HUGE}, "dpitch": 0}}',
            f'{{"type": "camera", "target": [{HUGE}, 0, 0]}}',
            f'{{"type": "settings", "values": {{"point_budget": -{HUGE}}}}}',
        ):
            ws.send_text(text)
            err = receive(ws, reply("error"))
            assert "must be in" in err["message"] and "internal" not in err["message"], err["message"]
        ws.send_json({"type": "ping", "t": 3})
        assert receive(ws, reply("pong"))["t"] == 3
    assert not [r for r in caplog.records if r.exc_info]


def _closed_after(sock, limit: float = 5.0) -> float | None:
    """Seconds until the server closed ``sock`` while it was sent a byte every 0.1 s (None: still open)."""
    sock.settimeout(0.1)
    t = time.monotonic()
    while time.monotonic() - t < limit:
        try:
            sock.sendall(b"X")
            if sock.recv(1 << 16) == b"":
                return time.monotonic() - t
        except TimeoutError:
            pass
        except OSError:
            return time.monotonic() - t
    return None


def _eof(sock) -> bool:
    try:
        return sock.recv(1) == b""
    except TimeoutError:
        return False


def test_a_client_trickling_its_request_head_is_cut_off(cloud, monkeypatch):
    """uvicorn timed only the idle wait between requests: a client sending a header byte a second
    held its connection for ever, and 1,100 of them used up a usual limit of 1,024 open files, so
    the page no longer loaded. Each head now has HEAD_TIMEOUT_S and at most MAX_WAITING wait at
    once (the longest waiting closed); requests being answered and WebSockets are not cut."""
    import socket

    import httpx
    from websockets.sync.client import connect

    from gigapoint.viewer import server as server_module

    monkeypatch.setattr(server_module, "HEAD_TIMEOUT_S", 1.0)
    monkeypatch.setattr(server_module, "MAX_WAITING", 4)
    srv = ViewerServer(cloud).start()
    try:
        base = f"http://127.0.0.1:{srv.port}"
        s = socket.create_connection(("127.0.0.1", srv.port), timeout=5)
        s.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        assert 0.9 < _closed_after(s) < 2.5
        s = socket.create_connection(("127.0.0.1", srv.port), timeout=5)  # kept alive, then the next head trickled
        s.sendall(b"GET /api/info HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        assert s.recv(100).startswith(b"HTTP/1.1 200")
        assert 0.9 < _closed_after(s) < 2.5
        idle = [socket.create_connection(("127.0.0.1", srv.port), timeout=5) for _ in range(7)]
        time.sleep(0.3)
        for c in idle:
            c.settimeout(0.05)
        assert sum(_eof(c) for c in idle) == 3  # the 4 waiting at most stay (within their second)
        assert httpx.get(base + "/", timeout=5).status_code == 200  # a real client meanwhile
        slow = srv.core.screenshot
        monkeypatch.setattr(srv.core, "screenshot", lambda *a: time.sleep(1.5) or slow(*a))
        assert httpx.get(base + "/screenshot?width=32&height=24", timeout=10).status_code == 200  # answered past the deadline
        with connect(f"ws://127.0.0.1:{srv.port}/ws?w=64&h=48", open_timeout=10) as ws:
            assert json.loads(ws.recv(timeout=10))["type"] == "hello"
            time.sleep(1.5)
            ws.send(json.dumps({"type": "orbit", "dyaw": 1.0, "seq": 1}))
            while not isinstance(m := ws.recv(timeout=10), bytes) or P.unpack_frame(m)[0]["seq"] != 1:
                pass
    finally:
        srv.close()


def test_the_page_token_is_not_logged(cloud):
    """uvicorn at log_level 'info' logged each WebSocket as '"WebSocket /ws?token=..." [accepted]':
    the key to the viewer in a terminal or a log file; the query's values are hidden now."""
    import logging

    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    lines = []
    handler = logging.Handler()
    handler.emit = lambda record: lines.append(record.getMessage())
    srv = ViewerServer(cloud, token="TOKSECRET", log_level="info").start()
    logging.getLogger("uvicorn.error").addHandler(handler)
    try:
        with connect(f"ws://127.0.0.1:{srv.port}/ws?w=64&h=48&token=TOKSECRET", open_timeout=10) as ws:
            assert json.loads(ws.recv(timeout=10))["type"] == "hello"
        with pytest.raises(InvalidStatus), connect(f"ws://127.0.0.1:{srv.port}/ws?token=WRONGSECRET", open_timeout=10):
            pass
    finally:
        srv.close()
        logging.getLogger("uvicorn.error").removeHandler(handler)
    said = "\n".join(lines)
    assert '"WebSocket /ws?w=***&h=***&token=***" [accepted]' in said and '"WebSocket /ws?token=***" 403' in said, said
    assert "SECRET" not in said


def test_a_port_in_use_names_the_keywords_and_the_options(cloud, cli):
    """gp.Viewer's error says its keywords (host=, port=); `view` the options typed, as before."""
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        with pytest.raises(gigapoint.GigapointError, match=f"^host='127.0.0.1', port={port}: cannot listen there \\(Address already in use\\)$"):
            gigapoint.Viewer(cloud, port=port, display=False)
        rc, out, err = cli("view", "--demo", "1000", "--port", port, "--no-browser")
        assert (rc, out, err) == (1, "", f"error: --host 127.0.0.1 --port {port}: cannot listen there (Address already in use)\n")


def test_a_port_in_use_is_refused_before_any_point_is_read(cli, monkeypatch):
    """`view --demo 5000000 --no-progressive --port TAKEN` read the whole cloud (16.8 s) before it
    said the port was in use, and gp.Viewer(path, port=TAKEN) read the file first too: the socket
    is bound first, with the same one-line error."""
    import socket

    from gigapoint.cli import view_cmd
    from gigapoint.viewer import jupyter

    read = []
    monkeypatch.setattr(view_cmd, "open_files", lambda inputs, *args, **kwargs: read.append(inputs))
    monkeypatch.setattr(jupyter, "_as_cloud", read.append)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        with pytest.raises(gigapoint.GigapointError, match=f"^host='127.0.0.1', port={port}: cannot listen there \\(Address already in use\\)$"):
            gigapoint.Viewer("big.laz", port=port, display=False)
        rc, out, err = cli("view", "big.laz", "--port", port, "--no-browser")
        assert (rc, out, err) == (1, "", f"error: --host 127.0.0.1 --port {port}: cannot listen there (Address already in use)\n")
    assert read == []


def test_the_start_up_line_says_a_progressive_load_goes_on(cli, monkeypatch):
    """A progressive load (by default of inputs above the point budget) was said as "big.laz,
    250,000 points" (or "0 points"): the points in so far, as though they were the file's."""
    from gigapoint.lod.progressive import ProgressiveOctree
    from gigapoint.lod.progressive import loader as L

    go = threading.Event()
    chunks = L.Loader._chunks

    def held_after_the_first(self):  # the rest of the points come once the start-up line is said
        made = chunks(self)
        yield next(made)
        go.wait(60)
        yield from made

    def serve_until_loaded(self):  # instead of serving until Ctrl+C
        go.set()
        if isinstance(self.core.cloud, ProgressiveOctree):
            self.core.cloud.wait(60)
        self.close()

    monkeypatch.setattr(L, "DECODE_CHUNK", 400)
    monkeypatch.setattr(L.Loader, "_chunks", held_after_the_first)
    monkeypatch.setattr(ViewerServer, "serve_forever", serve_until_loaded)
    rc, _, err = cli("view", "--demo", 1000, "--progressive", "--no-browser")
    # (0 where the first chunk took over the 5 s the start-up waits for it: numba compiling on a busy machine)
    assert rc == 0 and re.search(r"^gigapoint viewer: demo\(1,000\), (0|400) of 1,000 points loaded so far \(loading\)$", err, re.MULTILINE), err
    rc, _, err = cli("view", "--demo", 1000, "--no-browser")  # read whole: as before
    assert rc == 0 and "gigapoint viewer: demo(1,000), 1,000 points\n" in err, err
