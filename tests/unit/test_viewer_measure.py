"""The viewer's measuring tool: lengths of picked points in the reply, the polyline drawn over the frames."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest

pytest.importorskip("starlette")
pytest.importorskip("httpx")

from PIL import Image
from test_viewer_server import full_frame, jpeg_pixels, receive, reply, served  # the websocket helpers of the server's tests

import gigapoint
from gigapoint.render.camera import Camera
from gigapoint.viewer import measure as M
from gigapoint.viewer.server import create_app
from gigapoint.viewer.session import ViewerCore

pytestmark = [pytest.mark.timeout(120), pytest.mark.filterwarnings("ignore::DeprecationWarning")]

# two dense patches (every point of a patch at one place) on UTM-sized coordinates: 30 m east,
# 40 m north and 15 m above each other: horizontal 50, height 15, 3D sqrt(2725)
A = np.array([637010.25, 4850020.5, 12.0])
B = np.array([637040.25, 4850060.5, 27.0])


@pytest.fixture(scope="module")
def cloud():
    xyz = np.repeat([A, B], 200, axis=0)
    rgb = np.repeat([[0, 200, 0], [0, 0, 200]], 200, axis=0).astype(np.uint8)
    return gigapoint.from_arrays(xyz, rgb, name="patches", scale=0.01)  # as a LAS file at cm: picks give its values


@pytest.fixture()
def client(cloud):
    with served(cloud, 5) as pair:
        yield pair


def screen(cam, p) -> np.ndarray:
    """Pixel coordinates (x, y) of world point ``p`` in ``cam``'s image."""
    x, y, w, _ = cam.screen_rows() @ np.append(p, 1.0)
    return np.array([x / w, y / w])


def measure_at(ws, cam, p, **kw) -> dict:
    x, y = screen(cam, p) / (cam.width, cam.height)
    ws.send_json({"type": "measure", "action": "add", "x": x, "y": y, **kw})
    return receive(ws, reply("measure"))


def test_summary_lengths():
    s = M.summary([[0, 0, 0], [3, 4, 12], [3, 4, 2]])
    assert s["segments"] == [{"length": 13.0, "horizontal": 5.0, "vertical": 12.0}, {"length": 10.0, "horizontal": 0.0, "vertical": -10.0}]
    assert s["total"] == {"length": 23.0, "horizontal": 5.0, "vertical": 2.0}
    assert M.summary([])["segments"] == [] and M.summary([])["total"]["length"] == 0.0


def test_measuring_two_picked_points_gives_their_lengths(client):
    c, core = client
    with c.websocket_connect("/ws?w=240&h=180") as ws:
        hello = receive(ws, reply("hello"))
        ws.send_json({"type": "view", "name": "top", "seq": 1})
        receive(ws, full_frame(1))
        cam = core.sessions[hello["session"]].last.camera
        first = measure_at(ws, cam, A, id=7)
        assert first["id"] == 7 and first["added"] and first["points"] == [A.tolist()] and first["segments"] == []
        m = measure_at(ws, cam, B)
        assert m["points"] == [A.tolist(), B.tolist()]
        assert m["segments"] == [{"length": math.sqrt(2725.0), "horizontal": 50.0, "vertical": 15.0}]
        assert m["total"] == {"length": math.sqrt(2725.0), "horizontal": 50.0, "vertical": 15.0}
        assert m["units"] == hello["cloud"]["units"] == {"horizontal": None, "vertical": None, "vertical_assumed": False}  # arrays: no CRS
        ws.send_json({"type": "measure", "action": "add", "x": 0.01, "y": 0.99})  # empty sky
        sky = receive(ws, reply("measure"))
        assert sky["added"] is False and sky["message"] == "no point here: nothing added" and len(sky["points"]) == 2
        ws.send_json({"type": "measure", "action": "undo"})
        assert receive(ws, reply("measure"))["points"] == [A.tolist()]
        ws.send_json({"type": "measure", "action": "clear"})
        assert receive(ws, reply("measure"))["points"] == []
        ws.send_json({"type": "measure", "action": "erase"})
        assert receive(ws, reply("error"))["message"] == "measure: action must be add, restore, undo, clear, close or open, got 'erase'"
        ws.send_json({"type": "measure", "action": "add", "x": 2})
        assert receive(ws, reply("error"))["message"] == "measure: x must be in [0, 1], got 2"


def test_a_measurement_in_feet_says_so(autzen_path):
    """A LAS file's CRS in feet: hello's cloud and each measure reply name the unit (the HUD's)."""
    from starlette.testclient import TestClient

    core = ViewerCore(gigapoint.open(autzen_path), gigapoint.RenderSettings(point_size=3))
    feet = {"horizontal": {"name": "foot", "symbol": "ft", "metres": 0.3048}, "vertical": {"name": "foot", "symbol": "ft", "metres": 0.3048}, "vertical_assumed": True}
    try:
        with TestClient(create_app(core)) as c, c.websocket_connect("/ws?w=160&h=120") as ws:
            assert receive(ws, reply("hello"))["cloud"]["units"] == feet
            ws.send_json({"type": "view", "name": "top", "seq": 1})
            receive(ws, full_frame(1))
            ws.send_json({"type": "measure", "action": "add", "x": 0.5, "y": 0.5})  # the middle of the town, seen from above
            m = receive(ws, reply("measure"))
            assert m["added"] and m["units"] == feet
            p = m["points"][0]
            ws.send_json({"type": "measure", "action": "restore", "points": [[p[0] + 300, p[1] + 400, p[2] - 12]]})
            m = receive(ws, reply("measure"))
            assert m["units"] == feet and m["total"]["horizontal"] == pytest.approx(500.0) and m["total"]["vertical"] == pytest.approx(-12.0)
    finally:
        core.close_all()


def test_a_reconnected_page_gets_its_measurement_back(client):
    """The page re-sends its points after a lost connection (viewer.js, hello): the new session
    draws and measures them as the old one did."""
    c, core = client
    with c.websocket_connect("/ws?w=240&h=180") as ws:
        hello = receive(ws, reply("hello"))
        ws.send_json({"type": "view", "name": "top", "seq": 1})
        receive(ws, full_frame(1))
        cam = core.sessions[hello["session"]].last.camera
        measure_at(ws, cam, A)
        before = measure_at(ws, cam, B)
    with c.websocket_connect("/ws?w=240&h=180") as ws:  # a new session: it measures nothing yet
        hello = receive(ws, reply("hello"))
        session = core.sessions[hello["session"]]
        assert session.measure == []
        ws.send_json({"type": "measure", "action": "restore", "points": before["points"], "seq": 2})
        after = receive(ws, reply("measure"))
        assert after["points"] == [A.tolist(), B.tolist()] and after["segments"] == before["segments"] and after["total"] == before["total"]
        _, jpeg = receive(ws, full_frame(2))
        cam = session.last.camera
        assert yellow(jpeg_pixels(jpeg), (screen(cam, A) + screen(cam, B)) / 2)  # drawn again
        ws.send_json({"type": "measure", "action": "restore", "points": [[1, 2]]})
        assert receive(ws, reply("error"))["message"] == "measure: point must be a list of three numbers"
        ws.send_json({"type": "measure", "action": "restore", "points": [[0, 0, 0]] * M.MAX_POINTS})
        assert receive(ws, reply("error"))["message"] == f"measure: points must be a list of at most {M.MAX_POINTS} points in all"
        assert session.measure == [A.tolist(), B.tolist()]  # a refused restore adds nothing


def yellow(img, xy) -> bool:
    """The measuring colour at pixel ``xy`` (through JPEG: loosely)."""
    r, g, b = (int(v) for v in img[int(xy[1]), int(xy[0])][:3])
    return r > 180 and g > 150 and b < 110


def test_frames_draw_the_measurement_where_the_points_are_as_the_camera_moves(client):
    c, core = client
    with c.websocket_connect("/ws?w=240&h=180") as ws:
        hello = receive(ws, reply("hello"))
        ws.send_json({"type": "view", "name": "top", "seq": 1})
        _, before = receive(ws, full_frame(1))
        session = core.sessions[hello["session"]]
        cam = session.last.camera
        mid = (screen(cam, A) + screen(cam, B)) / 2
        assert not yellow(jpeg_pixels(before), mid)
        measure_at(ws, cam, A, seq=2)
        measure_at(ws, cam, B, seq=3)
        _, jpeg = receive(ws, full_frame(3))
        img = jpeg_pixels(jpeg)
        assert yellow(img, mid) and yellow(img, (screen(cam, A) * 0.8 + screen(cam, B) * 0.2))
        assert img[5, 5].max() < 30 and img[-5, -5].max() < 30  # far from it: the black background
        ws.send_json({"type": "orbit", "dyaw": 40.0, "dpitch": -30.0, "seq": 4})
        ws.send_json({"type": "pan", "dx": 0.3, "dy": 0.0, "seq": 5})
        _, jpeg = receive(ws, full_frame(5))
        img, cam2 = jpeg_pixels(jpeg), session.last.camera
        a2, b2 = screen(cam2, A), screen(cam2, B)
        assert np.abs((a2 + b2) / 2 - mid).max() > 30 and not yellow(img, mid)
        assert yellow(img, (a2 + b2) / 2) and yellow(img, a2 * 0.8 + b2 * 0.2)
        shot = np.asarray(Image.open(io.BytesIO(c.get(f"/screenshot?session={hello['session']}").content)))
        x, y = (a2 + b2) / 2
        assert tuple(shot[int(y), int(x)][:3]) == M.COLOR  # the screenshot has it too, exactly


CAM = Camera.look_at(eye=(0, -10, 0), target=(0, 0, 0), up=(0, 0, 1), fov=60, width=200, height=160)


def test_draw_puts_the_segment_between_the_projected_points_and_leaves_the_rest():
    image = np.full((160, 200, 3), 40, np.uint8)
    p, q = np.array([-3.0, 0, -2]), np.array([3.0, 0, 2])
    out = M.draw(image, CAM, [p, q])
    assert (image == 40).all()  # the frame's own image is not drawn on
    a, b = screen(CAM, p), screen(CAM, q)
    for t in (0.25, 0.5, 0.75):
        x, y = a + t * (b - a)
        assert tuple(out[int(y), int(x)]) == M.COLOR
    for x, y in a, b:  # the points: 7 x 7 squares
        assert (out[int(y) - 3 : int(y) + 4, int(x) - 3 : int(x) + 4] == M.COLOR).all()
    changed = np.nonzero((out != 40).any(axis=2))
    assert len(changed[0]) < 0.05 * out.shape[0] * out.shape[1]  # only along the line
    assert (out[:20] == 40).all() and (out[:, :20] == 40).all()
    cam2 = Camera.look_at(eye=(4, -10, 0), target=(4, 0, 0), up=(0, 0, 1), fov=60, width=200, height=160)
    moved = M.draw(image, cam2, [p, q])
    x, y = (a + b) / 2
    x2, y2 = screen(cam2, (p + q) / 2)
    assert x2 < x - 40 and tuple(moved[int(y2), int(x2)]) == M.COLOR and (moved[int(y), int(x)] == 40).all()  # the camera went right: the line left

def test_draw_cuts_what_is_behind_the_camera():
    image = np.zeros((160, 200, 3), np.uint8)
    assert (M.draw(image, CAM, [[0, -20, 0], [1, -30, 1]]) == 0).all()  # all behind: nothing
    out = M.draw(image, CAM, [[0, 0, -1], [0, -20, -1]])  # from in front of the eye to behind it
    a = screen(CAM, np.array([0, 0, -1.0]))
    assert tuple(out[int(a[1]), int(a[0])]) == M.COLOR
    cols = np.nonzero((out == M.COLOR).all(axis=2))[1]
    assert cols.min() >= 97 and cols.max() <= 103  # a vertical line under the centre, no mirrored part
    assert (out[: int(a[1]) - 4] == 0).all()  # nothing above the point: it runs down to the image's edge
