"""An audit of what reaches the viewer from outside: its routes through a real server, hostile
websocket messages, bodies pushed into a live cloud, live sources, and the files an octree's
metadata names. Each fixed case says what it did before; the others show the cases that held."""

from __future__ import annotations

import json
import logging
import shutil
import socket
import struct
import threading
import tracemalloc

import numpy as np
import pytest

pytest.importorskip("starlette")
pytest.importorskip("uvicorn")
pytest.importorskip("httpx")

from test_viewer_server import full_frame, marker_scene, receive, reply, served  # the websocket helpers of the server's tests

import gigapoint as gp
from gigapoint.errors import InputError
from gigapoint.live import LiveCloud
from gigapoint.live.sources import FramesDir, open_source
from gigapoint.live.wire import encode_frame
from gigapoint.viewer import session as S
from gigapoint.viewer.server import ViewerServer

pytestmark = [pytest.mark.timeout(120), pytest.mark.filterwarnings("ignore::DeprecationWarning")]


@pytest.fixture(scope="module")
def cloud():
    return marker_scene()


# --- the routes, through uvicorn (no test client in between to tidy the path) -------------------------------
def raw_get(port: int, target: str) -> tuple[int, bytes]:
    """(status, body) of ``GET target`` sent as it is written."""
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(f"GET {target} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n".encode())
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    return int(head.split(b" ")[1]), body


def test_a_real_server_binds_loopback_and_serves_only_its_assets(cloud):
    srv = ViewerServer(cloud).start()
    try:
        assert srv.sock.getsockname()[0] == "127.0.0.1" and srv.token is None
        for target in ["/static/../../etc/passwd", "/static/..%2f..%2fetc%2fpasswd", "/static/%2e%2e%2f%2e%2e%2fetc%2fpasswd",
                       "/static/%2e%2e/%2e%2e/etc/passwd", "/static//etc/passwd", "/static/%2Fetc%2Fpasswd", "/../../../etc/passwd",
                       "/static/viewer.js/../../server.py", "/static/..\\..\\server.py", "//etc/passwd", "http://evil.example/static/x"]:  # fmt: skip
            status, body = raw_get(srv.port, target)
            assert status == 404 and b"root:" not in body and b"import" not in body, target
        # the session id of /section.csv and /screenshot is a key, never a path
        assert raw_get(srv.port, "/section.csv?session=../../etc/passwd") == (400, b"section: no section drawn in this tab yet")
        assert raw_get(srv.port, "/screenshot?session=../../etc/passwd") == (400, b"screenshot: unknown session")
        status, body = raw_get(srv.port, "/static/viewer.js?../../etc/passwd")  # a query is no part of the name
        assert status == 200 and body.startswith(b"// gigapoint viewer client")
    finally:
        srv.close()


# --- websocket messages ----------------------------------------------------------------------------------------
MEASURED = [[637000, 4850000, 10], [637010, 4850000, 10], [637010, 4850010, 10]]
TOOL_MESSAGES = [  # (message, the start of the error it gets)
    ({"type": "measure", "action": "close"}, "measure: a polygon needs 3 points or more; 0 measured"),
    ({"type": "measure", "action": "restore", "points": [[1, 2, 3]] * 1_000_000}, "message of 11000052 characters exceeds the limit of 16384"),
    ({"type": "measure", "action": "restore", "points": [[1, 2, 3]] * 1001}, "measure: points must be a list of at most 1000 points"),
    ({"type": "measure", "action": "restore", "points": [[1e308, 0, 0]]}, "measure: point must be in [-1e+13, 1e+13], got 1e+308"),
    ({"type": "measure", "action": "restore", "points": "abc"}, "measure: points must be a list"),
    ({"type": "volume"}, "volume: close the measurement into a polygon first"),
    ({"type": "section", "action": "set", "points": [[0, 0, 0]]}, "section: points must be a list of two points"),
    ({"type": "section", "action": "set", "points": [[0, 0, 0], [0, 0, 5]]}, "section: the two points are at the same x, y"),
    ({"type": "section", "action": "set", "size": [1e9, 5]}, "section: size must be in [8, 2048]"),
    ({"type": "settings", "values": {"point_budget": -5}}, "settings: point_budget must be an integer >= 1, got -5"),
    ({"type": "view", "name": ["top"]}, "view: unknown view"),
]


def test_tool_messages_out_of_range_get_one_line_errors_and_the_tab_renders_on(cloud):
    with served(cloud, 2) as (client, _), client.websocket_connect("/ws?w=96&h=64") as ws:
        hello = receive(ws, reply("hello"))
        for message, said in TOOL_MESSAGES:
            ws.send_text(json.dumps(message).replace("1e+308", "1e308"))
            err = receive(ws, lambda k, p: k == "json" and p["type"] in ("error", "measure", "section", "volume", "settings"))
            assert err["type"] == "error" and err["message"].startswith(said), (message, err)
            assert "\n" not in err["message"] and "Traceback" not in err["message"]
        for count in (1, 2):  # a polygon of 1 and 2 points is no polygon
            ws.send_json({"type": "measure", "action": "restore", "points": [MEASURED[count - 1]]})
            assert receive(ws, reply("measure"))["area"] is None
            ws.send_json({"type": "measure", "action": "close"})
            assert receive(ws, reply("error"))["message"] == f"measure: a polygon needs 3 points or more; {count} measured"
        ws.send_json({"type": "measure", "action": "restore", "points": [MEASURED[2]], "closed": True})
        assert receive(ws, reply("measure"))["area"] == 50.0
        ws.send_text('{"type": "volume", "gsd": -1}')
        assert receive(ws, reply("error"))["message"] == "volume: gsd must be in [0, 1e+13], got -1"
        ws.send_json({"type": "refresh", "seq": 7})
        header, jpeg = receive(ws, full_frame(7))
        assert header["camera"] == hello["camera"] and jpeg[:2] == b"\xff\xd8"


def test_a_frame_that_fails_for_a_bug_is_logged_with_its_traceback_and_the_tab_gets_one_line(cloud, monkeypatch, caplog):
    """A render that raised anything but a GigapointError was said to the tab ("render failed:
    boom") and nowhere else: its traceback was lost."""
    real = S.render_frame

    def buggy(cloud, camera, settings):
        if settings.point_size == 7:
            raise ZeroDivisionError("boom")
        return real(cloud, camera, settings)

    monkeypatch.setattr(S, "render_frame", buggy)
    caplog.set_level(logging.ERROR, logger="gigapoint.viewer")
    with served(cloud, 2) as (client, _), client.websocket_connect("/ws?w=64&h=48") as ws:
        receive(ws, full_frame())
        ws.send_json({"type": "settings", "values": {"point_size": 7}})
        assert receive(ws, reply("error"))["message"] == "render failed: boom"
        ws.send_json({"type": "refresh", "seq": 5})
        receive(ws, full_frame(5))  # back on the settings that worked
    failed = [r for r in caplog.records if r.getMessage() == "viewer: a frame failed"]
    assert len(failed) == 1 and failed[0].exc_info[0] is ZeroDivisionError


# --- frames pushed into a live cloud ---------------------------------------------------------------------------
@pytest.fixture()
def pushed_to():
    """(a live cloud, a /push websocket into it)."""
    from starlette.testclient import TestClient

    from gigapoint.viewer.server import create_app
    from gigapoint.viewer.session import ViewerCore

    live = LiveCloud(keep=5, bounds=((-12, -12, -2), (12, 12, 2)))
    core = ViewerCore(live)
    try:
        with TestClient(create_app(core)) as client, client.websocket_connect(f"/push?push_token={core.push_token}") as ws:
            yield live, ws
    finally:
        core.close_all()


def framed(header: dict, body: bytes = b"") -> bytes:
    head = json.dumps(header).encode()
    return b"GPL1" + struct.pack("<I", len(head)) + head + body


def answer(ws, message) -> dict:
    (ws.send_text if isinstance(message, str) else ws.send_bytes)(message)
    return json.loads(ws.receive_text())


def xyz_array(shape) -> dict:
    return {"name": "xyz", "dtype": "<f4", "shape": shape}


SIX_FLOATS = np.arange(6, dtype=np.float32).tobytes()


@pytest.mark.parametrize(
    "message, said",
    [  # each was acknowledged: the bytes were split otherwise than the producer meant, or an array replaced
        (framed({"type": "points", "arrays": [xyz_array([2.5, 3])]}, SIX_FLOATS), "push: array xyz: shape must be a list of whole numbers, got [2.5, 3]"),
        (framed({"type": "points", "arrays": [xyz_array([True, 3])]}, SIX_FLOATS[:12]), "push: array xyz: shape must be a list of whole numbers, got [True, 3]"),
        (framed({"type": "points", "arrays": [xyz_array([1, 3]), xyz_array([1, 3])]}, SIX_FLOATS), "push: array xyz is given twice"),
    ],
)
def test_pushed_shapes_are_whole_numbers_and_each_array_comes_once(pushed_to, message, said):
    live, ws = pushed_to
    assert answer(ws, message) == {"type": "error", "message": said}
    assert live.n_frames == 0 and live.stats.frames_rejected == 1
    assert answer(ws, encode_frame("points", xyz=np.ones((4, 3), np.float32)))["type"] == "ack"  # the stream goes on


def test_a_depth_frame_with_a_3x3_camera_matrix_can_be_pushed(pushed_to):
    """encode_frame (PushClient.push_depth) sends intrinsics flat: a 3x3 matrix arrived as 9
    numbers, which push_depth refused ('got shape (9,)'); a nested one too."""
    live, ws = pushed_to
    depth = np.full((4, 6), 1200, np.uint16)
    matrix = [[3.0, 0.0, 2.5], [0.0, 3.0, 1.5], [0.0, 0.0, 1.0]]
    assert answer(ws, encode_frame("depth", depth=depth, intrinsics=matrix)) == {"type": "ack", "seq": 0}
    header = {"type": "depth", "arrays": [{"name": "depth", "dtype": "<u2", "shape": [4, 6]}], "intrinsics": matrix}
    assert answer(ws, framed(header, depth.tobytes())) == {"type": "ack", "seq": 1}
    assert answer(ws, encode_frame("depth", depth=depth, intrinsics=(3, 3, 2.5, 1.5))) == {"type": "ack", "seq": 2}
    xyz = live.frame_points()[0].reshape(3, 24, 3)
    assert np.array_equal(xyz[0], xyz[2]) and np.array_equal(xyz[1], xyz[2])  # the same 24 points as (fx, fy, cx, cy) gives
    assert np.allclose(xyz[2, 0], [(0 - 2.5) * 1.2 / 3, (0 - 1.5) * 1.2 / 3, 1.2])  # pixel (0, 0) at 1.2 m: (u - cx) z / fx
    assert np.allclose(np.ptp(xyz[2], axis=0), [5 * 1.2 / 3, 3 * 1.2 / 3, 0])  # the 6 x 4 pixels


HOSTILE_BODIES = [  # (message, the start of its error)
    (b"", "push: not a frame message"),
    (b"GPL1", "push: not a frame message"),
    (b"GPL1" + struct.pack("<I", 2**32 - 1) + b"{}", "push: header of 4294967295 bytes runs past"),
    (framed({"type": "points", "arrays": [xyz_array([10**12, 3])]}, SIX_FLOATS), "push: array xyz: unsupported dtype '<f4' or shape (1000000000000, 3)"),
    (framed({"type": "points", "arrays": [xyz_array([10**7, 10**7, 3])]}, SIX_FLOATS), "push: array xyz (1,200,000,000,000,000 bytes) runs past"),
    (framed({"type": "points", "arrays": [xyz_array([-2, 3])]}, SIX_FLOATS), "push: array xyz: unsupported dtype"),
    (framed({"type": "points", "arrays": [{"name": "xyz", "dtype": ">f4", "shape": [2, 3]}]}, SIX_FLOATS), "push: array xyz: unsupported dtype '>f4'"),
    (framed({"type": "points", "arrays": [{"name": "xyz", "dtype": "|O", "shape": [2, 3]}]}, SIX_FLOATS), "push: array xyz: unsupported dtype '|O'"),
    (encode_frame("points", xyz=np.ones((2, 3), np.float32)) + b"xx", "push: 2 bytes after the last array"),
    (encode_frame("points", xyz=np.full((5, 3), np.nan, np.float32)), "live: push: none of the frame's 5 points is valid"),
    (encode_frame("points", xyz=np.ones((2, 3)), pose=np.full((4, 4), np.nan)), "live: push: pose holds NaN or inf"),
    (encode_frame("points", xyz=np.ones((2, 2), np.float32)), "live: push: xyz must have shape (N, 3), got (2, 2)"),
    (encode_frame("depth", depth=np.ones((4, 6), np.uint16), intrinsics=(np.nan, 3, 2.5, 1.5)), "live: push_depth: intrinsics need finite fx, fy > 0"),
    ("a text message", "push: frames are binary messages"),
]


def test_hostile_bodies_are_refused_without_allocating_what_they_claim(pushed_to):
    live, ws = pushed_to
    for message, said in HOSTILE_BODIES:
        tracemalloc.start()
        try:
            reply_ = answer(ws, message)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert reply_["type"] == "error" and reply_["message"].startswith(said), (message[:80], reply_)
        assert peak < 8 << 20, (said, peak)  # a header claiming 10**12 points allocates nothing of them
    assert live.n_frames == 0 and live.stats.frames_rejected == len(HOSTILE_BODIES)


# --- live sources ----------------------------------------------------------------------------------------------
def test_a_live_source_must_be_named(tmp_path, monkeypatch):
    """'' was the current folder, played as a folder of frames (`gigapoint view --live ''`); a
    URL was said as a missing file with one slash lost ('http:/host/x.bag')."""
    np.save(tmp_path / "000.npy", np.ones((5, 3), np.float32))
    monkeypatch.chdir(tmp_path)
    assert isinstance(open_source("."), FramesDir)  # the folder named as such plays
    for spec in ("", "  ", 5):
        with pytest.raises(InputError, match=r"^live: a source is demo, a recording, a bag, a TUM sequence or a folder of frames, got "):
            open_source(spec)
    with pytest.raises(InputError) as err:
        open_source("http://user:secret@example.com/run.bag")
    assert str(err.value) == "http://user:***@example.com/run.bag: live sources are read from this machine's files, not from URLs"


# --- files an octree's metadata names --------------------------------------------------------------------------
def test_an_octree_attribute_named_out_of_its_folder_is_refused(tmp_path):
    """An attribute's name is part of its file's name: '/../../outside/secret' (and a folder
    'field.attr.' in the octree) read outside/secret.npy as the octree's attribute."""
    octree = tmp_path / "octree"
    gp.convert(gp.demo(3000, colors="rgba"), octree)
    meta_file = next(p for p in (octree / "octree.json", octree / "metadata.json") if p.exists())
    meta = json.loads(meta_file.read_text())
    evil = "/../../outside/secret"
    (tmp_path / "outside").mkdir()
    (octree / "field.attr.").mkdir()
    (octree / "attr.").mkdir()
    renamed = {"intensity": evil, "attr.intensity": f"attr.{evil}"}
    for name in ("field.attr.intensity.npy", "attr.intensity.npy"):
        if (octree / name).exists():
            shutil.move(octree / name, tmp_path / "outside" / "secret.npy")
    meta["attributes"] = {renamed.get(k, k): v for k, v in meta["attributes"].items()}
    if "fields" in meta:  # version 2: one field per attribute, named after it
        meta["fields"] = [renamed.get(k, k) for k in meta["fields"]]
        meta["field_dtypes"] = {renamed.get(k, k): v for k, v in meta["field_dtypes"].items()}
    meta_file.write_text(json.dumps(meta))
    with pytest.raises(InputError) as err:
        gp.open(octree)
    assert str(err.value) == (
        f"{meta_file}: invalid metadata (attribute name '{evil}' cannot be stored (a file name part: not empty, '.' or '..', no /, \\ or NUL))"
    )


# --- a cloud that loads while it is shown ----------------------------------------------------------------------
def test_the_auto_view_of_a_loading_cloud_frames_every_point_loaded(strips_loading):
    """The 'auto' view (a new tab's first view, key 5) framed the points the cloud held
    when the viewer started, for good: a file read west to east was framed on its first strip
    (target x 52 of 0..1000). It frames what is loaded, as the same points held in memory are framed."""
    from gigapoint.viewer.session import ViewerCore

    xyz, cloud, go_on = strips_loading
    core, in_memory = ViewerCore(cloud), ViewerCore(gp.from_arrays(xyz))
    try:
        go_on.set()
        cloud.wait(timeout=60)
        assert core.watcher.finished.wait(10)
        shown, reference = core.default_state(1280, 720), in_memory.default_state(1280, 720)
        assert np.linalg.norm(shown.target - reference.target) < 20, (shown.target, reference.target)  # (a 1000 x 1000 scene)
        assert shown.distance == pytest.approx(reference.distance, rel=0.05)
    finally:
        core.close_all()
        in_memory.close_all()


def test_a_tab_opened_before_the_first_point_is_fit_to_the_points_once_they_come(gated_loading):
    """A tab opened while a loading cloud held no point yet (`gigapoint view` serves after 5 s
    without one; its page opens at once) was fit to an empty box: the origin at a distance of
    5e-08, its zoom held under 0.01, and it showed nothing once the points came. It is fit to
    them, as the 'auto' view; a tab moved meanwhile keeps its view. It follows the 'auto' view
    until moved: fit once, to the points of the watcher's first look, it kept the first strip's
    framing (this test failed alone, numba's kernels cold, the load slower than a tick)."""
    import threading
    import time

    from gigapoint.viewer.protocol import unpack_frame
    from gigapoint.viewer.session import ViewerCore

    xyz = np.random.default_rng(1).uniform((637000, 4850000, 0), (638000, 4851000, 5), (100_000, 3))
    go_on = threading.Event()
    strips = [(xyz[first : first + 20_000], None) for first in range(0, len(xyz), 20_000)]
    cloud = gated_loading(strips, [go_on] + [None] * (len(strips) - 1), name="late", total=len(xyz))
    core = ViewerCore(cloud)
    frames = {"untouched": [], "moved": []}

    def sent_to(tab):
        return lambda kind, payload: kind != "bytes" or frames[tab].append(unpack_frame(payload)[0]) or True

    try:
        untouched, moved = (core.open_session(sent_to(tab), 96, 64) for tab in frames)
        assert untouched.snapshot()[0].distance == pytest.approx(2.047978442474518)  # (no point yet: Camera.fit frames an empty box as a 1-unit cube, no longer 1e-6)
        moved.handle({"type": "orbit", "dyaw": 30})
        chosen = moved.snapshot()[0].as_dict()
        go_on.set()
        cloud.wait(timeout=60)
        assert core.watcher.finished.wait(10)
        time.sleep(0.5)  # the last frames
        shown = untouched.snapshot()[0]
        assert shown.as_dict() == core.default_state(96, 64).as_dict()  # the 'auto' view of the points loaded
        assert frames["untouched"][-1]["camera"] == shown.as_dict() and frames["untouched"][-1]["visible_pixels"] > 1000
        held = ViewerCore(gp.from_arrays(xyz))  # the same points held in memory
        in_memory = held.default_state(96, 64)
        held.close_all()
        assert np.linalg.norm(shown.target - in_memory.target) < 20 and shown.distance == pytest.approx(in_memory.distance, rel=0.05)
        assert moved.snapshot()[0].as_dict() == chosen
    finally:
        core.close_all()


def test_a_loading_clouds_reframe_reads_the_bounds_and_tells_each_tab_once(gated_loading, monkeypatch):
    """As a loading cloud's points doubled, its watcher reframed (the bounds read, the tab opened
    before the first point told) and then redrew (the bounds read again, every tab told again): two
    reads and two frames asked of that tab each time. One redraw does both, once; and a redraw is
    not the user's doing: the tab Viewer.screenshot shows (the one last moved) stays."""
    import threading

    from gigapoint.viewer.session import ViewerCore
    from gigapoint.viewer.watch import LoadWatcher

    gate = threading.Event()
    cloud = gated_loading([(np.random.default_rng(1).uniform(0, 1000, (20_000, 3)), None)], [gate])
    core = ViewerCore(cloud)
    core.watcher.stop()  # (its redraws every 0.25 s: this test runs its last one itself)
    core.watcher._thread.join(10)
    try:
        blind, moved = core.open_session(lambda kind, payload: True, 96, 64), core.open_session(lambda kind, payload: True, 96, 64)
        moved.handle({"type": "orbit", "dyaw": 30})
        blind.handle({"type": "refresh"})  # (not a move: it stays fit to nothing, and is the active tab)
        assert blind.snapshot()[0].distance == pytest.approx(2.047978442474518) and core.last_active is blind  # (the 1-unit framing of no point)
        gate.set()
        assert cloud.wait(timeout=60)
        reads = []
        take_bounds = core._take_bounds
        monkeypatch.setattr(core, "_take_bounds", lambda: reads.append(1) or take_bounds())
        versions = {s: s.version for s in (blind, moved)}
        watcher = LoadWatcher(core, cloud, interval_s=0.01).start()  # done: one last redraw, framing the points
        assert watcher.finished.wait(60)  # (it waits for the render lock: a tab's first frame, kernels cold)
        assert len(reads) == 1 and {s: s.version - versions[s] for s in versions} == {blind: 1, moved: 1}
        assert blind.snapshot()[0].as_dict() == core.default_state(96, 64).as_dict()
        assert core.last_active is blind
    finally:
        core.close_all()


def test_a_screenshot_counts_the_pixels_its_supersampling_renders(cloud, monkeypatch):
    """The screenshot's limit (40 M pixels) counted the image's, not the render's: a tab at
    anti-aliasing 4 asked for 4096x4096 (16.8 M) rendered 16384x16384, 268 M pixels (~21 bytes
    each: 5.6 GB, a minute under the render lock). Refused in one line, nothing rendered; the
    size it allows is drawn."""
    rendered, render_locked = [], S.render_locked

    def recorded(cloud, cam, *args, **kw):
        rendered.append((cam.width, cam.height))
        assert cam.width * cam.height < 10_000, "rendered a screenshot over the limit"  # (not 5.6 GB here)
        return render_locked(cloud, cam, *args, **kw)

    monkeypatch.setattr(S, "render_locked", recorded)
    core = S.ViewerCore(cloud, gp.RenderSettings(supersample=4))
    try:
        with pytest.raises(S.P.ProtocolError, match=r"^screenshot: 4096x4096 at supersample 4 renders 16384x16384, over 40,000,000 pixels"):
            core.screenshot(None, 4096, 4096)
        with pytest.raises(S.P.ProtocolError, match=r"renders 6328x6328, over"):  # (40.04 M pixels)
            core.screenshot(None, 1582, 1582)
        assert rendered == []
        assert core.screenshot(None, 64, 48)[:4] == b"\x89PNG" and rendered == [(64, 48)]
    finally:
        core.close_all()


def test_a_tabs_frames_lower_their_supersampling_to_the_pixel_limit(cloud, monkeypatch):
    """Only screenshots counted the pixels supersampling renders: a 4096x4096 tab at anti-aliasing
    4 rendered 268 M pixels a frame. Its frames render at the highest supersample within the
    screenshots' limit (40 M), and the HUD says so."""
    asked, render_locked = [], S.render_locked
    small = S.ViewerCore(cloud).default_state(32, 32).camera(32, 32)

    def recorded(cloud, cam, settings, **kw):  # what the renderer is asked for; a small frame drawn in its place
        asked.append((cam.width, cam.height, settings.supersample))
        return render_locked(cloud, small, settings.replace(supersample=1), **kw)

    monkeypatch.setattr(S, "render_locked", recorded)
    headers, sent = [], threading.Semaphore(0)

    def send(kind, payload):
        if kind == "bytes":
            headers.append(S.P.unpack_frame(payload)[0])
            sent.release()
        return True

    core = S.ViewerCore(cloud, gp.RenderSettings(supersample=4))
    try:
        tab = core.open_session(send, 4096, 4096)
        assert sent.acquire(timeout=60)
        for size in ((2000, 1500), (64, 48)):
            tab.handle({"type": "resize", "width": size[0], "height": size[1]})
            assert sent.acquire(timeout=60)
    finally:
        core.close_all()
    assert asked == [(4096, 4096, 1), (2000, 1500, 2), (64, 48, 4)]  # 16.8 M, 12 M and 49 k pixels rendered
    assert [h["note"] for h in headers] == [
        "anti-aliasing 4 lowered to 1 at 4096x4096 (at most 40,000,000 pixels rendered a frame)",
        "anti-aliasing 4 lowered to 2 at 2000x1500 (at most 40,000,000 pixels rendered a frame)",
        "",
    ]
