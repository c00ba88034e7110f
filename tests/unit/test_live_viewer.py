"""A LiveCloud in the viewer: redraws as frames arrive, the HUD line, pushed frames over /push with the token."""

from __future__ import annotations

import json
import time
import warnings

import numpy as np
import pytest

pytest.importorskip("starlette")
pytest.importorskip("uvicorn")
pytest.importorskip("httpx")

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from gigapoint.live import LiveCloud
from gigapoint.live.wire import encode_frame
from gigapoint.viewer import protocol as P
from gigapoint.viewer.server import create_app
from gigapoint.viewer.session import ViewerCore
from gigapoint.viewer.watch import LiveWatcher

pytestmark = [pytest.mark.timeout(120), pytest.mark.filterwarnings("ignore::DeprecationWarning")]


def patch(k, n=2000):
    rng = np.random.default_rng(k)
    return rng.uniform(-1, 1, (n, 3)) * [10, 10, 1], np.full((n, 3), (255, 40 * k % 255, 0), np.uint8)


@pytest.fixture()
def live_core():
    live = LiveCloud(keep=5, bounds=((-12, -12, -2), (12, 12, 2)))
    live.push(*patch(0))
    core = ViewerCore(live)
    yield live, core
    core.close_all()


def frames_from(ws, want=1, limit=100):
    out = []
    for _ in range(limit):
        m = ws.receive()
        if m.get("bytes") is not None:
            out.append(P.unpack_frame(m["bytes"]))
            if len(out) >= want:
                return out
    raise AssertionError("no frame")


def test_a_live_core_has_a_push_token_a_watcher_and_a_hud_line(live_core):
    live, core = live_core
    assert isinstance(core.watcher, LiveWatcher) and core.push_token and len(core.push_token) >= 20
    assert core.note.startswith("live: ") and "1 frames" in core.note and "2,000 live points" in core.note


def test_tabs_redraw_when_frames_arrive_and_latency_is_measured(live_core):
    live, core = live_core
    with TestClient(create_app(core)) as client, client.websocket_connect("/ws?w=64&h=48") as ws:
        json.loads(ws.receive_text())  # hello
        header, _ = frames_from(ws)[0]
        assert header["points_total"] == 2000
        for k in range(1, 4):
            live.push(*patch(k))
            deadline = time.monotonic() + 10
            while True:
                header, _ = frames_from(ws)[0]
                if header["points_total"] == 2000 * (k + 1) or time.monotonic() > deadline:
                    break
            assert header["points_total"] == 2000 * (k + 1)
        assert len(live.stats.latencies) >= 1 and live.stats.latency_ms(50) < 10_000
        time.sleep(0.3)
        assert "latency" in core.note and "frames/s in" in core.note


def test_the_panels_cloud_line_follows_a_live_cloud(live_core):
    """The panel's cloud line (points, batches) was hello's alone and went stale as frames were
    pushed: a frame's header carries it again once it changed, and only then."""
    live, core = live_core
    with TestClient(create_app(core)) as client, client.websocket_connect("/ws?w=64&h=48") as ws:
        hello = json.loads(ws.receive_text())
        assert hello["cloud"]["points"] == 2000
        header, _ = frames_from(ws)[0]
        assert "cloud" not in header  # unchanged since hello
        live.push(*patch(1))
        deadline, lines = time.monotonic() + 10, []
        while header["points_total"] != 4000 and time.monotonic() < deadline:
            header, _ = frames_from(ws)[0]
            lines += [header["cloud"]] if "cloud" in header else []
        assert header["points_total"] == 4000 and [line["points"] for line in lines] == [4000] == [live.n_points]
        assert lines[0]["name"] == hello["cloud"]["name"] and lines[0]["batches"] == len(live.batches)
        ws.send_text(json.dumps({"type": "orbit", "dyaw": 0.1, "dpitch": 0.0}))
        header, _ = frames_from(ws)[0]
        assert "cloud" not in header  # said once


def test_push_needs_the_token_and_a_malformed_frame_does_not_stop_the_stream(live_core):
    live, core = live_core
    with TestClient(create_app(core)) as client:
        for query in ("", "?push_token=wrong"):
            with pytest.raises(WebSocketDisconnect) as err, client.websocket_connect("/push" + query) as ws:
                ws.receive_text()
            assert err.value.code == 1008
        assert live.stats.frames_in == 1
        with client.websocket_connect(f"/push?push_token={core.push_token}") as ws:
            xyz, rgb = patch(7)
            ws.send_bytes(encode_frame("points", xyz=xyz, rgb=rgb, time=3.0))
            assert json.loads(ws.receive_text()) == {"type": "ack", "seq": 1}
            ws.send_bytes(encode_frame("points", xyz=xyz)[:-7])  # cut short
            reply = json.loads(ws.receive_text())
            assert reply["type"] == "error" and "cut short" in reply["message"]
            ws.send_bytes(encode_frame("points", xyz=np.full((5, 3), np.nan)))
            reply = json.loads(ws.receive_text())
            assert reply["type"] == "error" and "none of the frame's 5 points is valid" in reply["message"]
            ws.send_text("hello")
            assert json.loads(ws.receive_text())["type"] == "error"
            ws.send_bytes(encode_frame("depth", depth=np.full((4, 6), 1200, np.uint16), intrinsics=(3, 3, 2.5, 1.5)))
            assert json.loads(ws.receive_text()) == {"type": "ack", "seq": 2}
        assert live.stats.frames_in == 3 and live.n_points == 2000 + 2000 + 24 and live.stats.frames_rejected == 3


def test_a_frame_that_fails_in_a_way_nobody_foresaw_does_not_cost_the_producer_its_connection(live_core, monkeypatch):
    """A pushed frame that raised anything but a GigapointError (a wire message with a shape of
    [2**62, 4] did: numpy's product wrapped) ended the producer's connection; it is answered as
    an error, as /ws answers a message that fails, and the stream goes on."""
    from gigapoint.live import wire

    real = wire.decode_frame
    monkeypatch.setattr(wire, "decode_frame", lambda data: (_ for _ in ()).throw(ValueError("boom")) if data == b"BUG!" else real(data))
    live, core = live_core
    with TestClient(create_app(core)) as client, client.websocket_connect(f"/push?push_token={core.push_token}") as ws:
        ws.send_bytes(b"BUG!")
        assert json.loads(ws.receive_text()) == {"type": "error", "message": "internal error: boom"}
        ws.send_bytes(encode_frame("points", xyz=patch(8)[0]))
        assert json.loads(ws.receive_text())["type"] == "ack"


def test_a_plain_cloud_has_no_push_route(live_core):
    import gigapoint as gp

    core = ViewerCore(gp.from_arrays(patch(1)[0]))
    try:
        with TestClient(create_app(core)) as client, pytest.raises(WebSocketDisconnect), client.websocket_connect("/push?push_token=x") as ws:
            ws.receive_text()
    finally:
        core.close_all()


def test_gp_viewer_of_a_live_cloud_shows_frames_pushed_after_it_started():
    import io

    from PIL import Image

    import gigapoint as gp

    live = gp.LiveCloud(keep=3, bounds=((-12, -12, -2), (12, 12, 2)))
    with gp.Viewer(live, display=False) as viewer:
        with warnings.catch_warnings(record=True) as said:  # an empty view is normal in a viewer: not said (view_frame)
            warnings.simplefilter("always")
            empty = np.asarray(Image.open(io.BytesIO(viewer.screenshot(64, 48))))
        assert [str(w.message) for w in said] == []
        live.push(*patch(2, n=20_000))
        shot = np.asarray(Image.open(io.BytesIO(viewer.screenshot(64, 48))))
        assert viewer.push_url.startswith("ws://127.0.0.1:") and viewer.push_url.endswith(viewer.server.core.push_token)
    assert (empty[..., :3] == empty[0, 0, :3]).all()  # nothing yet: background only
    assert (shot[..., 0] == 255).sum() > 100  # the frame's red points


def test_the_push_url_works_on_a_server_off_loopback():
    """Off loopback every route wants the page's token= as well: the printed push URL carries
    it, and a PushClient given the page's URL keeps it; without it the push is refused."""
    from urllib.parse import parse_qs, urlsplit

    from gigapoint.errors import GigapointError
    from gigapoint.live.wire import PushClient
    from gigapoint.viewer.server import ViewerServer

    live = LiveCloud(keep=2, bounds=((-12, -12, -2), (12, 12, 2)))
    srv = ViewerServer(live, host="0.0.0.0", port=0)
    try:
        url = urlsplit(srv.push_url)
        query = parse_qs(url.query)
        assert url.path == "/push" and query["token"] == [srv.token] and query["push_token"] == [srv.core.push_token]
        with TestClient(srv.app) as client:
            with client.websocket_connect(f"/push?{url.query}") as ws:
                ws.send_bytes(encode_frame("points", xyz=patch(1)[0]))
                assert json.loads(ws.receive_text()) == {"type": "ack", "seq": 0}
            with pytest.raises(WebSocketDisconnect), client.websocket_connect(f"/push?push_token={srv.core.push_token}") as ws:
                ws.receive_text()
        captured = {}

        def fake_connect(ws_url, **_):  # PushClient's URL, without a network
            captured["url"] = ws_url
            raise OSError("no server here")

        import websockets.sync.client as wsc

        real, wsc.connect = wsc.connect, fake_connect
        try:
            with pytest.raises(GigapointError, match="refused"):
                PushClient(srv.url, srv.core.push_token)
        finally:
            wsc.connect = real
        assert parse_qs(urlsplit(captured["url"]).query) == {"token": [srv.token], "push_token": [srv.core.push_token]}
    finally:
        srv.sock.close()
        srv.core.close_all()


def _pushed(header: bytes, body: bytes) -> bytes:
    import struct

    return b"GPL1" + struct.pack("<I", len(header)) + header + body


HUGE = b"1" * 400  # a JSON integer past float's range
XYZ = b'"arrays":[{"name":"xyz","dtype":"<f4","shape":[2,3]}]'
DEPTH = b'"arrays":[{"name":"depth","dtype":"<f4","shape":[2,3]}]'
ODD_HEADERS = [
    b'{"type":"points",' + XYZ + b',"time":' + HUGE + b"}",
    b'{"type":"points",' + XYZ + b',"pose":[' + HUGE + b",0,0,0,0,0,0,0,0,0,0,0,0,0,0,0]}",
    b'{"type":"depth",' + DEPTH + b',"intrinsics":[1,1,1,' + HUGE + b"]}",
    b'{"type":"points","arrays":[{"name":"xyz","dtype":"<f4","shape":[1e400,3]}]}',
    b'{"type":"points","arrays":[{"name":"xyz","dtype":["<f4"],"shape":[2,3]}]}',
    b'{"type":["points"],' + XYZ + b"}",
]


def test_odd_push_headers_are_one_line_input_errors_counted_on_the_hud(live_core, caplog):
    """A JSON integer past float's range, an infinite shape or a list where a name belongs was an
    'internal error' (OverflowError, TypeError: unhashable list) with a logged traceback, and
    the frame was not counted as refused."""
    live, core = live_core
    with TestClient(create_app(core)) as client, client.websocket_connect(f"/push?push_token={core.push_token}") as ws:
        for header in ODD_HEADERS:
            ws.send_bytes(_pushed(header, np.zeros(6, np.float32).tobytes()))
            reply = json.loads(ws.receive_text())
            assert reply["type"] == "error" and reply["message"].startswith("push") and "internal" not in reply["message"], (header[:60], reply)
        ws.send_bytes(encode_frame("points", xyz=patch(8)[0]))
        assert json.loads(ws.receive_text())["type"] == "ack"
    assert live.stats.frames_rejected == len(ODD_HEADERS)
    assert not [r for r in caplog.records if r.exc_info]


def test_producers_past_the_limit_are_refused_with_a_message():
    """/push had no limit: 300 producers each holding a 64 MB frame ask for 19 GB (/ws has one)."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    from gigapoint.viewer.server import ViewerServer

    live = LiveCloud(keep=2, bounds=((-12, -12, -2), (12, 12, 2)))
    srv = ViewerServer(live).start()
    url = srv.push_url
    try:
        producers = [connect(url, open_timeout=10) for _ in range(8)]  # MAX_PUSHERS
        with connect(url, open_timeout=10) as extra:
            assert json.loads(extra.recv(timeout=10)) == {"type": "error", "message": "push: too many producers connected (limit 8)"}
            with pytest.raises(ConnectionClosed):
                extra.recv(timeout=10)
            assert extra.close_code == 1013
        producers[0].send(encode_frame("points", xyz=patch(1)[0]))
        assert json.loads(producers[0].recv(timeout=10)) == {"type": "ack", "seq": 0}
        producers.pop().close()  # one leaves: a new one gets in
        deadline = time.monotonic() + 10
        while True:  # (the server may not have seen the close yet)
            try:
                with connect(url, open_timeout=10) as again:
                    again.send(encode_frame("points", xyz=patch(2)[0]))
                    reply = json.loads(again.recv(timeout=10))
            except ConnectionClosed:
                reply = {"type": "closed"}
            if reply["type"] == "ack" or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        assert reply == {"type": "ack", "seq": 1}
        for p in producers:
            p.close()
    finally:
        srv.close()


def test_only_push_takes_large_messages_on_a_live_viewer():
    """uvicorn's one ws_max_size, raised to the 64 MB push limit on a live viewer, let a tab's /ws
    send 64 MB before its message was refused. /ws now closes with 1009 (too big) past the tab's
    limit, as on a plain viewer; /push (its path quoted too) still takes a frame that size."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    from gigapoint.viewer.server import ViewerServer

    tab_limit = P.MAX_MESSAGE * 4  # bytes (the tab's limit counts characters)
    live = LiveCloud(keep=2, bounds=((-12, -12, -2), (12, 12, 2)))
    srv = ViewerServer(live).start()
    try:
        with connect(f"ws://127.0.0.1:{srv.port}/ws?w=64&h=48", open_timeout=10, max_size=2**24) as tab:
            assert json.loads(tab.recv(timeout=10))["type"] == "hello"
            tab.send("x" * (tab_limit + 1))
            with pytest.raises(ConnectionClosed):
                while True:  # (frames drawn before the message may come first)
                    assert "exceeds the limit" not in str(tab.recv(timeout=10))  # read whole, then refused
            assert tab.close_code == 1009
        frame = encode_frame("points", xyz=patch(1, n=4000)[0])
        assert len(frame) > tab_limit
        for path in (srv.push_url, srv.push_url.replace("/push?", "/pus%68?")):
            with connect(path, open_timeout=10) as producer:
                producer.send(frame)
                assert json.loads(producer.recv(timeout=10))["type"] == "ack"
    finally:
        srv.close()


def test_a_warning_of_a_pushed_frame_reaches_the_user_at_the_cloud_s_next_call():
    """The cloud's "frames arrive faster" of a frame pushed over /push was warned on the server's
    thread: past the user's catch, at any moment. Now kept in ``live.warnings``, as a Player's,
    and issued by the user's next snapshot, save or close, at the user's line."""
    from gigapoint.errors import GigapointWarning

    live = LiveCloud(keep=1, name="cam", bounds=((-12, -12, -2), (12, 12, 2)))
    core = ViewerCore(live)
    try:
        with warnings.catch_warnings(record=True) as meanwhile:
            warnings.simplefilter("always")
            # the lock held: the pushed frames wait for it, the oldest dropped
            with TestClient(create_app(core)) as client, client.websocket_connect(f"/push?push_token={core.push_token}") as ws, live.reading():
                for k in range(3):
                    ws.send_bytes(encode_frame("points", xyz=patch(k)[0]))
                    assert json.loads(ws.receive_text()) == {"type": "ack", "seq": k}
        assert [str(w.message) for w in meanwhile if w.category is GigapointWarning] == []
        assert live.stats.frames_dropped == 2 and len(live.warnings) == 1
        with pytest.warns(GigapointWarning, match="^cam: frames arrive faster than they are copied into the ring") as caught:
            live.close()
        assert [w.filename for w in caught] == [__file__]
    finally:
        core.close_all()
