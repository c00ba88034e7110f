"""The viewer's section tool: the section of the viewer's cloud along two picked points, its
numbers and image in the reply, its CSV, the line drawn over the frames, bad messages refused."""

from __future__ import annotations

import base64
import io

import numpy as np
import pytest

pytest.importorskip("starlette")
pytest.importorskip("httpx")

from PIL import Image
from test_viewer_measure import screen, yellow
from test_viewer_server import full_frame, jpeg_pixels, receive, reply, served  # the websocket helpers of the server's tests

import gigapoint
from gigapoint.viewer import section_tool as ST
from gigapoint.viewer.server import create_app
from gigapoint.viewer.session import ViewerCore

pytestmark = [pytest.mark.timeout(120), pytest.mark.filterwarnings("ignore::DeprecationWarning")]

# a plane sloping up along x (z = 0.1 x) over 100 x 50 units, and a wall 20 high across it at x = 60
WALL_X, WALL_TOP = 60.0, 20.0
LINE = ([10.25, 25.0, 1.0], [89.75, 25.0, 9.0])  # along x, through the wall; its ends and edges off the 0.5 grid
WIDTH = 1.9
SIZE = [300, 120]


def plane_and_wall() -> gigapoint.PointCloud:
    gx, gy = np.meshgrid(np.arange(0, 100.01, 0.5), np.arange(0, 50.01, 0.5), indexing="ij")
    ground = np.column_stack([gx.ravel(), gy.ravel(), 0.1 * gx.ravel()])
    wy, wz = np.meshgrid(np.arange(0, 50.01, 0.5), np.arange(0.5, WALL_TOP + 0.01, 0.5), indexing="ij")
    wall = np.column_stack([np.full(wy.size, WALL_X), wy.ravel(), 0.1 * WALL_X + wz.ravel()])
    rgb = np.vstack([np.tile([0, 200, 0], (len(ground), 1)), np.tile([200, 200, 200], (len(wall), 1))]).astype(np.uint8)
    return gigapoint.from_arrays(np.vstack([ground, wall]), rgb, name="plane and wall")


@pytest.fixture(scope="module")
def cloud():
    return plane_and_wall()


@pytest.fixture()
def client(cloud):
    with served(cloud, 3) as pair:
        yield pair


def png_of(url: str) -> np.ndarray:
    head, data = url.split(",", 1)
    assert head == "data:image/png;base64"
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(data))))


def test_a_section_message_gets_the_section_of_the_line_with_its_image(client, cloud):
    c, core = client
    with c.websocket_connect("/ws?w=240&h=180") as ws:
        hello = receive(ws, reply("hello"))
        ws.send_json({"type": "section", "action": "set", "size": [8, 8]})
        first = receive(ws, reply("section"))
        assert first["width"] == 2.0 and first["points"] == [] and first["computing"] is False  # 1/50 of the 100 units along x
        ws.send_json({"type": "section", "action": "set", "points": list(LINE), "width": WIDTH, "size": SIZE, "id": 3})
        r = receive(ws, reply("section"))
        assert r["id"] == 3 and r["points"] == list(LINE) and r["width"] == WIDTH and r["computing"] is True
        result = receive(ws, reply("section_result"))
        csv = c.get(f"/section.csv?session={hello['session']}")  # (while the tab is open)
    expected = gigapoint.section(cloud, (10.25, 25, 89.75, 25), WIDTH)
    ground_rows = 159 * 3  # x 10.5..89.5 by 0.5, y 24.5..25.5 by 0.5
    assert result["count"] == len(expected.z) == ground_rows + 3 * 40  # the wall's 40 rows of 3
    assert result["length"] == 79.5 and result["width"] == WIDTH and result["line"] == [10.25, 25.0, 89.75, 25.0]
    assert result["distance"] == pytest.approx([0.25, 79.25])
    assert result["z"] == pytest.approx([1.05, 0.1 * WALL_X + WALL_TOP])
    assert result["units"] == hello["cloud"]["units"] and result["message"] == ""
    image = png_of(result["image"])
    assert image.shape[:2] == (SIZE[1], SIZE[0])
    own = np.asarray(expected.render(size=tuple(SIZE)))
    assert np.array_equal(image[..., :3], own[..., :3])  # gp.section's own render, pixel for pixel
    drawn = image[..., :3].max(axis=2) > 0
    assert drawn.sum() > 300 and drawn[:, : SIZE[0] // 2].any() and drawn[:, SIZE[0] // 2 :].any()
    tall = drawn.sum(axis=0).argmax()  # the wall is the tallest column, where the line crosses it
    assert abs(tall / SIZE[0] - (WALL_X - 10.25) / 79.5) < 0.03
    assert csv.status_code == 200 and csv.headers["content-type"].startswith("text/csv")
    lines = csv.text.splitlines()
    assert lines[0] == "distance_along,offset,z" and len(lines) == 1 + result["count"]
    assert lines[1].split(",")[0] == "0.250000"


def test_picked_points_make_the_line_drawn_over_the_frames(client, cloud):
    c, core = client
    with c.websocket_connect("/ws?w=240&h=180") as ws:
        hello = receive(ws, reply("hello"))
        ws.send_json({"type": "view", "name": "top", "seq": 1})
        receive(ws, full_frame(1))
        session = core.sessions[hello["session"]]
        cam = session.last.camera
        a, b = (np.array(p) for p in LINE)
        for k, p in enumerate((a, b), start=1):
            x, y = screen(cam, p) / (cam.width, cam.height)
            ws.send_json({"type": "section", "action": "add", "x": x, "y": y, "seq": 1 + k})
            r = receive(ws, reply("section"))
            assert len(r["points"]) == k and r["computing"] is (k == 2)
        picked = np.array(r["points"])
        assert np.abs(picked[:, :2] - [a[:2], b[:2]]).max() < 1.0  # the ground points under the clicks
        result = receive(ws, reply("section_result"))
        assert result["count"] > 500 and result["line"] == picked[:, :2].ravel().tolist()
        ws.send_json({"type": "refresh", "seq": 10})  # (the frame of the second click may have come before the result)
        _, jpeg = receive(ws, full_frame(10))
        img = jpeg_pixels(jpeg)
        mx, my = (screen(cam, picked[0]) + screen(cam, picked[1])) / 2
        red, green, blue = (int(v) for v in img[int(my), int(mx)])
        assert red < 90 and green > 170 and blue > 170 and not yellow(img, (mx, my))  # the section's cyan line
        ws.send_json({"type": "section", "action": "add", "x": 0.01, "y": 0.01})  # the sky of the top view's corner
        sky = receive(ws, reply("section"))
        assert sky["message"] == "no point here: nothing added" and len(sky["points"]) == 2
        ws.send_json({"type": "section", "action": "clear", "seq": 11})
        assert receive(ws, reply("section"))["points"] == []
        _, jpeg = receive(ws, full_frame(11))
        red, green, blue = (int(v) for v in jpeg_pixels(jpeg)[int(my), int(mx)])
        assert not (red < 90 and blue > 170)  # gone


@pytest.mark.parametrize(
    ("message", "error"),
    [
        ({"action": "erase"}, "section: action must be add, set or clear, got 'erase'"),
        ({"action": "set", "points": [[0, 0, 0]]}, "section: points must be a list of two points [x, y, z]"),
        ({"action": "set", "points": [[0, 0, 0], [0, "a", 0]]}, "section: point must be a finite number, got 'a'"),
        ({"action": "set", "points": [[0, 0, 0], [0, 0, 5]]}, "section: the two points are at the same x, y: the line has no length"),
        ({"action": "set", "width": 0}, "section: width must be above 0"),
        ({"action": "set", "width": -1}, "section: width must be in [0, 1e+13], got -1"),
        ({"action": "set", "size": [100]}, "section: size must be [width, height] in pixels"),
        ({"action": "add", "x": 2, "y": 0}, "section: x must be in [0, 1], got 2"),
    ],
)
def test_bad_section_messages_are_answered_with_an_error(client, message, error):
    c, core = client
    with c.websocket_connect("/ws?w=120&h=90") as ws:
        receive(ws, reply("hello"))
        ws.send_json({"type": "section", **message})
        assert receive(ws, reply("error"))["message"] == error
        ws.send_text('{"type": "section", "action": "set", "width": NaN}')  # (Python's JSON reads NaN)
        assert receive(ws, reply("error"))["message"] == "section: width must be a finite number, got nan"
        ws.send_json({"type": "ping", "t": 1})
        assert receive(ws, reply("pong"))["t"] == 1  # the connection goes on
        (session,) = core.sessions.values()
        assert session.section == [] and session.section_width == 2.0  # nothing of a refused message kept


def test_a_corridor_over_the_cap_is_thinned_and_says_so(client, cloud, monkeypatch):
    monkeypatch.setattr(ST, "MAX_POINTS", 300)
    c, _ = client
    with c.websocket_connect("/ws?w=120&h=90") as ws:
        receive(ws, reply("hello"))
        ws.send_json({"type": "section", "action": "set", "points": list(LINE), "width": WIDTH, "size": SIZE})
        result = receive(ws, reply("section_result"))
    assert result["count"] == 299  # every 2nd of the 597, the first included
    assert result["message"] == "597 points in the corridor: 1 point in 2 shown (at most 300); narrow or shorten it for all"


def test_an_empty_corridor_is_said_in_the_result(client):
    c, _ = client
    with c.websocket_connect("/ws?w=120&h=90") as ws:
        receive(ws, reply("hello"))
        ws.send_json({"type": "section", "action": "set", "points": [[500, 500, 0], [600, 500, 0]], "width": 1})
        result = receive(ws, reply("section_result"))
    assert "image" not in result and "no point" in result["error"], result


def test_a_converted_octree_gives_the_section_of_its_points(tmp_path, cloud):
    """Its nodes meeting the corridor, at every level, hold the corridor's points (lod/query.py)."""
    from starlette.testclient import TestClient

    gigapoint.convert(cloud, tmp_path / "oct", max_leaf=2_000)
    octree = gigapoint.open(tmp_path / "oct")
    assert len(octree.keys) > 8
    core = ViewerCore(octree)
    try:
        with TestClient(create_app(core)) as c, c.websocket_connect("/ws?w=120&h=90") as ws:
            hello = receive(ws, reply("hello"))
            ws.send_json({"type": "section", "action": "set", "points": list(LINE), "width": WIDTH})
            assert receive(ws, reply("section"))["computing"] is True
            result = receive(ws, reply("section_result"))
            csv = c.get(f"/section.csv?session={hello['session']}").text.splitlines()
    finally:
        core.close_all()
    assert result["count"] == len(gigapoint.section(cloud, (10.25, 25, 89.75, 25), WIDTH).z) == 597 and len(csv) == 1 + 597
    assert result["z"] == pytest.approx([1.05, 0.1 * WALL_X + WALL_TOP])


def test_a_local_copc_file_gives_the_section_of_its_nodes(tmp_path, cloud):
    from starlette.testclient import TestClient

    gigapoint.convert(cloud, tmp_path / "scan.copc.laz")
    octree = gigapoint.open(tmp_path / "scan.copc.laz")
    core = ViewerCore(octree)
    try:
        with TestClient(create_app(core)) as c, c.websocket_connect("/ws?w=120&h=90") as ws:
            receive(ws, reply("hello"))
            ws.send_json({"type": "section", "action": "set", "points": list(LINE), "width": WIDTH})
            result = receive(ws, reply("section_result"))
    finally:
        core.close_all()
    assert result["count"] == len(gigapoint.section(tmp_path / "scan.copc.laz", (10.25, 25, 89.75, 25), WIDTH).z) == 597
