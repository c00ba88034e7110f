"""The measuring tool closed into a polygon: its area and perimeter in the reply, the closing
segment drawn over the frames, and the stockpile volume inside it (gp.volume of the viewer's
cloud, off the render loop), bad messages refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("starlette")
pytest.importorskip("httpx")
pytest.importorskip("scipy")  # (gp.volume fills the surface's holes by a TIN)

from test_viewer_measure import screen, yellow
from test_viewer_server import full_frame, jpeg_pixels, receive, reply, served  # the websocket helpers of the server's tests

import gigapoint
from gigapoint.viewer import measure as M
from gigapoint.viewer import volume_tool as VT
from gigapoint.viewer.server import create_app
from gigapoint.viewer.session import ViewerCore

pytestmark = [pytest.mark.timeout(120), pytest.mark.filterwarnings("ignore::DeprecationWarning")]

FEET = {"horizontal": {"name": "foot", "symbol": "ft", "metres": 0.3048}, "vertical": {"name": "foot", "symbol": "ft", "metres": 0.3048}, "vertical_assumed": False}


def shoelace(xy) -> float:
    """The area of the polygon through ``xy`` (written out here, vertex by vertex)."""
    twice = sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(xy, [*xy[1:], xy[0]]))
    return abs(twice) / 2


def test_a_closed_measurement_gives_the_polygons_area_and_perimeter():
    # a concave pentagon on UTM-sized coordinates, its heights all different (the area is horizontal)
    xy = [(637010.0, 4850020.0), (637050.0, 4850020.0), (637050.0, 4850050.0), (637030.0, 4850035.0), (637010.0, 4850050.0)]
    points = [[x, y, 10.0 + k] for k, (x, y) in enumerate(xy)]
    local = [(x - 637000.0, y - 4850000.0) for x, y in xy]  # (exact in floats: the shoelace in the test loses no digits)
    perimeter = sum(math.dist(a, b) for a, b in zip(local, [*local[1:], local[0]]))
    s = M.summary(points, FEET, closed=True)
    assert s["closed"] is True and len(s["segments"]) == 5
    assert s["area"] == pytest.approx(shoelace(local), rel=1e-12) and shoelace(local) == 40 * 30 - 40 * 15 / 2  # the box less the notch
    assert s["perimeter"] == pytest.approx(perimeter, rel=1e-12) == s["total"]["horizontal"]
    assert s["segments"][-1] == {"length": pytest.approx(math.hypot(30, 4)), "horizontal": 30.0, "vertical": -4.0}  # back to the first
    assert s["total"]["vertical"] == 0.0  # round the ring: back to where it began
    opened = M.summary(points, FEET)
    assert opened["closed"] is False and opened["area"] is None and opened["perimeter"] is None and len(opened["segments"]) == 4
    two = M.summary(points[:2], FEET, closed=True)  # no polygon below 3 points
    assert two["closed"] is False and two["area"] is None and len(two["segments"]) == 1
    degrees = {"horizontal": {"name": "degree", "symbol": "°", "metres": None}, "vertical": FEET["vertical"], "vertical_assumed": False}
    assert M.summary(points, degrees, closed=True)["area"] is None  # degrees squared are no area
    assert M.drawn(points, True) == [*points, points[0]] and M.drawn(points[:2], True) == points[:2]


def test_the_grid_offered_spans_the_polygon_500_pixels_but_no_finer_than_the_points():
    # a 240 x 200 lattice 0.25 apart: its box runs through the outer points, 239 x 199 spacings
    assert VT.point_spacing(([0.125, 0.125, 5], [59.875, 49.875, 9]), 48_000) == pytest.approx(0.25, rel=1e-12)
    assert VT.default_gsd(TOE, 0.01) == (0.06, "a grid of 0.06: the polygon about 500 pixels across")  # 30 / 500
    assert VT.default_gsd(TOE, 0.2489) == (0.25, "a grid of 0.25, the points' mean spacing: the polygon 120 pixels across")
    assert VT.toe(TOE) == {"type": "Polygon", "coordinates": [[[15.0, 15.0], [45.0, 15.0], [45.0, 35.0], [15.0, 35.0], [15.0, 15.0]]], "source": "the measured polygon"}


def test_the_point_spacing_of_a_regular_grid_is_its_spacing_whatever_its_size():
    """A k x k grid d apart: its box, (k - 1) d a side, holds (k - 1)^2 cells, not k^2 (box area
    / points read a 10 x 10 grid 1 apart as 0.9 and a 3 x 3 one as 0.67); a line's points: its
    length / (n - 1); one point, or all at one spot: none."""
    for k in (2, 3, 10, 100, 1000):
        for d in (0.25, 1.0, 2.5):
            assert VT.point_spacing(([7.0, -3.0, 0.0], [7.0 + (k - 1) * d, -3.0 + (k - 1) * d, 1.0]), k * k) == pytest.approx(d, rel=1e-12)
            assert VT.point_spacing(([7.0, -3.0], [7.0 + (k - 1) * d, -3.0]), k) == pytest.approx(d, rel=1e-12)
    assert VT.point_spacing(([0.0, 0.0, 0.0], [5.0, 5.0, 0.0]), 1) == VT.point_spacing(([5.0, 5.0, 0.0], [5.0, 5.0, 1.0]), 40) == 0.0


def sloped(x, y):
    return 10.0 + 0.3 * x + 0.2 * y  # its mean over a square is its value at the square's centre


def offered_volume(xy, toe) -> tuple[float, float]:
    """The fill above z 3 of the sloped surface sampled at ``xy``, inside ``toe``, on the grid the
    panel offers (the viewer's defaults: ``default_gsd`` of the points' spacing), and its gsd."""
    points = gigapoint.from_arrays(np.column_stack([xy, sloped(xy[:, 0], xy[:, 1])]))
    gsd, _ = VT.default_gsd([[*p, 0.0] for p in toe], VT.point_spacing(points.bounds, points.n_points))
    return gigapoint.volume(points, VT.toe(toe), gsd, base=3.0).fill, gsd


@pytest.mark.filterwarnings("error::gigapoint.errors.GigapointWarning")  # (no pixel of these toes is empty)
def test_the_offered_grid_measures_a_surface_of_known_volume_on_grids_of_any_size_and_on_scattered_points():
    """A sloped surface sampled on k x k grids 2.5 apart, the toe round them half a spacing out
    (each point's own cell): its volume above z 3 is the toe's area times the height at its
    centre. The grid offered was the box's area / points, 1.7 for 3 x 3 (36 % of the toe's
    pixels empty: 16 % short) and 2.2 for 10 x 10 (5 % short); it is now the spacing. 2,500
    random points on 50 x 50: within 1 %."""
    for k in (3, 10, 100):
        ticks = 0.37 + 2.5 * np.arange(k)  # (points off the pixel edges, which lie on multiples of the gsd)
        x, y = np.meshgrid(ticks, ticks)
        lo, hi = ticks[0] - 1.25, ticks[-1] + 1.25
        fill, gsd = offered_volume(np.column_stack([x.ravel(), y.ravel()]), [[lo, lo], [hi, lo], [hi, hi], [lo, hi]])
        exact = (hi - lo) ** 2 * (sloped((lo + hi) / 2, (lo + hi) / 2) - 3.0)
        assert gsd == 2.5 and fill == pytest.approx(exact, rel=1e-6), (k, fill, exact)
    scattered = np.random.default_rng(7).uniform(0.0, 50.0, (2_500, 2))
    fill, gsd = offered_volume(scattered, [[0.0, 0.0], [50.0, 0.0], [50.0, 50.0], [0.0, 50.0]])
    assert gsd == 1.0 and fill == pytest.approx(50.0 * 50.0 * (sloped(25.0, 25.0) - 3.0), rel=0.01)


# a flat plane at z 10 over 60 x 50 with a box pile 20 x 10 x 3 standing on it (600 cubic units),
# sampled every 0.25 off the box's edges, so a TIN between the points puts each wall where it is
GROUND_Z, BOX, BOX_HEIGHT = 10.0, (20.0, 40.0, 20.0, 30.0), 3.0
TOE = [[15.0, 15.0, GROUND_Z], [45.0, 15.0, GROUND_Z], [45.0, 35.0, GROUND_Z], [15.0, 35.0, GROUND_Z]]  # 30 x 20 around it


def pile(classification: bool = False) -> gigapoint.PointCloud:
    gx, gy = np.meshgrid(np.arange(0.125, 60, 0.25), np.arange(0.125, 50, 0.25), indexing="ij")
    x, y = gx.ravel(), gy.ravel()
    on_box = (x > BOX[0]) & (x < BOX[1]) & (y > BOX[2]) & (y < BOX[3])
    z = GROUND_Z + BOX_HEIGHT * on_box
    rgb = np.where(on_box[:, None], [200, 120, 40], [0, 160, 0]).astype(np.uint8)
    extra = {"classification": np.where(on_box, 6, 2).astype(np.uint8)} if classification else {}
    return gigapoint.from_arrays(np.column_stack([x, y, z]), rgb, name="pile", **extra)


@pytest.fixture(scope="module")
def cloud():
    return pile()


@pytest.fixture()
def client(cloud):
    with served(cloud, 3) as pair:
        yield pair


def close_toe(ws) -> dict:
    ws.send_json({"type": "measure", "action": "restore", "points": TOE})
    receive(ws, reply("measure"))
    ws.send_json({"type": "measure", "action": "close", "seq": 5})
    return receive(ws, reply("measure"))


def grid_error(gsd: float) -> float:
    """How far the volume of a box of whole pixels may be off (docs/guide.md, section 8): the toe's pixels count whole or not at all."""
    width, length = BOX[1] - BOX[0], BOX[3] - BOX[2]
    return BOX_HEIGHT * ((width + 2 * gsd) * (length + 2 * gsd) - width * length)


def test_closing_the_measurement_around_a_pile_gives_its_area_and_volume(client):
    c, core = client
    with c.websocket_connect("/ws?w=240&h=180") as ws:
        hello = receive(ws, reply("hello"))
        ws.send_json({"type": "volume"})
        assert receive(ws, reply("error"))["message"] == "volume: close the measurement into a polygon first (3 points or more, C)"
        ws.send_json({"type": "view", "name": "top", "seq": 1})
        receive(ws, full_frame(1))
        session = core.sessions[hello["session"]]
        cam = session.last.camera
        closing = (screen(cam, np.array(TOE[-1])) + screen(cam, np.array(TOE[0]))) / 2  # the middle of the side from the last point to the first
        m = close_toe(ws)
        assert m["closed"] is True and m["area"] == 600.0 and m["perimeter"] == 100.0 and len(m["segments"]) == 4
        _, jpeg = receive(ws, full_frame(5))
        assert yellow(jpeg_pixels(jpeg), closing)  # the closing side is drawn
        ws.send_json({"type": "volume", "base": "plane", "id": 4})
        started = receive(ws, reply("volume"))
        assert started == {"type": "volume", "id": 4, "job": started["job"], "computing": True, "gsd": 0.25, "base": "plane"}  # the points' spacing
        result = receive(ws, reply("volume_result"))
        ws.send_json({"type": "measure", "action": "open", "seq": 6})
        assert receive(ws, reply("measure"))["closed"] is False
        _, jpeg = receive(ws, full_frame(6))
        assert not yellow(jpeg_pixels(jpeg), closing)  # open again: a polyline
    assert result["id"] == started["job"] and "error" not in result, result
    assert result["gsd"] == 0.25 and result["gsd_note"] == "a grid of 0.25, the points' mean spacing: the polygon 120 pixels across"
    assert result["note"] == "" and result["warnings"] == []  # all the box's points read; none of its pixels empty
    assert abs(result["fill"] - 600.0) < grid_error(0.25) and result["fill"] == pytest.approx(600.0, rel=0.01)
    assert result["cut"] == pytest.approx(0.0, abs=0.5) and result["net"] == pytest.approx(result["fill"] - result["cut"])
    assert result["base"]["type"] == "plane" and result["base"]["z"] == pytest.approx(GROUND_Z, abs=1e-3)
    assert result["base"]["slope"] == pytest.approx([0.0, 0.0], abs=1e-5)  # the plane is flat
    assert result["polygon_area"] == 600.0 and result["area"] == pytest.approx(600.0, rel=0.01)
    assert result["height"] == pytest.approx(BOX_HEIGHT, abs=1e-3) and result["highest"][2] == pytest.approx(GROUND_Z + BOX_HEIGHT, abs=1e-3)
    assert result["filled"] < 0.01 and result["empty"] == 0.0  # a point in (nearly) every pixel
    assert result["units"] == {"length": "units", "area": "square units", "volume": "cubic units"}  # arrays: no CRS


def test_a_flat_base_and_a_gsd_asked_for(client):
    c, _ = client
    with c.websocket_connect("/ws?w=120&h=90") as ws:
        receive(ws, reply("hello"))
        close_toe(ws)
        ws.send_json({"type": "volume", "base": GROUND_Z - 1, "gsd": 0.5})
        assert receive(ws, reply("volume"))["gsd"] == 0.5
        result = receive(ws, reply("volume_result"))
    # a base 1 below the ground: the whole 30 x 20 polygon 1 high besides the pile, within the 0.5 grid's error
    assert abs(result["fill"] - (600.0 + 600.0)) < grid_error(0.5) + 1.0 * 0.5 * 100
    assert result["base"] == {"type": "elevation", "z": GROUND_Z - 1} and result["gsd_note"] == "a grid of 0.5"


@pytest.mark.parametrize(
    ("message", "error"),
    [
        ({"base": "flat"}, "volume: base must be 'plane', 'lowest' or an elevation (a number), got 'flat'"),
        ({"base": [1]}, "volume: base must be a finite number, got [1]"),
        ({"gsd": 0}, "volume: gsd must be above 0"),
        ({"gsd": 0.001}, "volume: a gsd of 0.001 makes the polygon 30,000 pixels across, over 4,096: give 0.0073 or more"),
        ({"gsd": 1e-300}, "volume: a gsd of 1e-300 makes the polygon 3e+301 pixels across, over 4,096: give 0.0073 or more"),  # (not 302 digits)
    ],
)
def test_bad_volume_messages_are_answered_with_an_error(client, message, error):
    c, _ = client
    with c.websocket_connect("/ws?w=120&h=90") as ws:
        receive(ws, reply("hello"))
        close_toe(ws)
        ws.send_json({"type": "volume", **message})
        assert receive(ws, reply("error"))["message"] == error
        ws.send_json({"type": "measure", "action": "undo"})
        assert receive(ws, reply("measure"))["closed"] is True  # a triangle
        ws.send_json({"type": "measure", "action": "undo"})
        assert receive(ws, reply("measure"))["closed"] is False  # 2 points: a polyline again
        ws.send_json({"type": "measure", "action": "close"})
        assert receive(ws, reply("error"))["message"] == "measure: a polygon needs 3 points or more; 2 measured"


def test_a_polygon_off_the_data_says_so_in_the_result(client):
    c, _ = client
    with c.websocket_connect("/ws?w=120&h=90") as ws:
        receive(ws, reply("hello"))
        ws.send_json({"type": "measure", "action": "restore", "points": [[500, 500, 0], [600, 500, 0], [600, 600, 0]], "closed": True})
        assert receive(ws, reply("measure"))["closed"] is True  # (a reconnected page's closed polygon)
        ws.send_json({"type": "volume"})
        result = receive(ws, reply("volume_result"))
    assert result["error"] == "the measured polygon: no point of pile lies in its box x 499.5..600.5, y 499.5..600.5"  # (two pixels of 0.25 beyond it)


def test_a_polygon_of_absurd_vertices_is_named_as_measured_not_as_geojson(client):
    """Its vertex error named "the GeoJSON geometry", which the user never gave: the viewer's
    polygon is named as every other volume message names it."""
    c, _ = client
    with c.websocket_connect("/ws?w=120&h=90") as ws:
        receive(ws, reply("hello"))
        ws.send_json({"type": "measure", "action": "restore", "points": [[-1e13, -1e13, 0], [1e13, -1e13, 0], [1e13, 1e13, 0]], "closed": True})
        receive(ws, reply("measure"))
        ws.send_json({"type": "volume"})
        result = receive(ws, reply("volume_result"))
    assert result["error"] == "volume: the measured polygon: a polygon vertex lies beyond ±1e+12 ([-10000000000000.0, -10000000000000.0]): no point can be there"


def test_a_toe_beyond_the_data_is_warned_of_in_the_result_not_on_the_servers_stderr(client, capfd, recwarn):
    """gp.volume warns of a pile whose pixels are more than 1 % empty: issued on the volume's
    thread, that warning went to the server's terminal, once per request, and the panel said only
    "25.0 % left empty"; the warning, which says why and how to mend it, is the result's to show."""
    beyond = [[30.0, 15.0, GROUND_Z], [70.0, 15.0, GROUND_Z], [70.0, 35.0, GROUND_Z], [30.0, 35.0, GROUND_Z]]  # x 60..70 beyond the data
    c, _ = client
    with c.websocket_connect("/ws?w=120&h=90") as ws:
        receive(ws, reply("hello"))
        ws.send_json({"type": "measure", "action": "restore", "points": beyond, "closed": True})
        receive(ws, reply("measure"))
        ws.send_json({"type": "volume", "gsd": 0.25})
        result = receive(ws, reply("volume_result"))
    assert result["empty"] == 0.25  # its east quarter
    said = "the measured polygon: 25.0% of the pile's pixels hold no height and count no volume (its figures are short by them): "
    assert result["warnings"] == [said + "the toe runs beyond the data's footprint (draw it inside the points)"]
    assert [str(w.message) for w in recwarn] == [] and capfd.readouterr().err == ""  # not issued by the server too


def test_an_octree_gives_the_volume_of_its_nodes_points_and_hidden_classes_are_left_out(tmp_path):
    """A converted octree's nodes meeting the polygon's box, at every level, hold its points
    (lod/query.py): the volume of the cloud's; the pile's class hidden in the Classes panel: no pile."""
    from starlette.testclient import TestClient

    gigapoint.convert(pile(classification=True), tmp_path / "oct", max_leaf=2_000)
    octree = gigapoint.open(tmp_path / "oct")
    assert len(octree.keys) > 8
    core = ViewerCore(octree)
    try:
        with TestClient(create_app(core)) as c, c.websocket_connect("/ws?w=120&h=90") as ws:
            receive(ws, reply("hello"))
            close_toe(ws)
            ws.send_json({"type": "volume", "gsd": 0.25})
            whole = receive(ws, reply("volume_result"))
            ws.send_json({"type": "settings", "values": {"hidden_classes": [6]}})
            receive(ws, reply("settings"))
            ws.send_json({"type": "volume", "gsd": 0.25})
            hidden = receive(ws, reply("volume_result"))
    finally:
        core.close_all()
    expected = gigapoint.volume(pile(), VT.toe(TOE), 0.25)
    assert whole["fill"] == pytest.approx(expected.fill, rel=1e-9) and abs(whole["fill"] - 600.0) < grid_error(0.25)
    assert hidden["fill"] == pytest.approx(0.0, abs=1e-6) and hidden["height"] == pytest.approx(0.0, abs=1e-3)  # the ground only


BOW_TIE = [[15.0, 15.0, GROUND_Z], [45.0, 15.0, GROUND_Z], [15.0, 35.0, GROUND_Z], [45.0, 35.0, GROUND_Z]]  # its 2nd and 4th edges cross
CROSSING = "the polygon crosses itself (edges 2 and 4): no area or volume; move a point so that no two edges cross"


def test_a_polygon_crossing_itself_has_no_area_and_its_volume_is_refused(client):
    """A bow tie's shoelace area (600 - 600 = 0 here) is no area, and gp.volume's pixels inside
    it (the even-odd rule) are both triangles: the reply says so instead, the volume is refused."""
    s = M.summary(BOW_TIE, FEET, closed=True)
    assert s["crossing"] == CROSSING and s["area"] is None and s["perimeter"] == pytest.approx(60 + 2 * math.hypot(30, 20))
    assert M.summary(TOE, FEET, closed=True)["crossing"] is None and M.summary(BOW_TIE, FEET)["crossing"] is None  # (open: a polyline may cross)
    c, _ = client
    with c.websocket_connect("/ws?w=120&h=90") as ws:
        receive(ws, reply("hello"))
        ws.send_json({"type": "measure", "action": "restore", "points": BOW_TIE, "closed": True})
        m = receive(ws, reply("measure"))
        assert m["closed"] is True and m["area"] is None and m["crossing"] == CROSSING
        ws.send_json({"type": "volume", "base": "plane"})
        assert receive(ws, reply("error"))["message"] == f"volume: {CROSSING}"
        ws.send_json({"type": "measure", "action": "undo"})  # a triangle: an area again
        m = receive(ws, reply("measure"))
        assert m["crossing"] is None and m["area"] == 300.0


FLAT_POLYGONS = [  # closed measurements without area, on the pile's ground
    [[15.0, 15.0, GROUND_Z], [30.0, 15.0, GROUND_Z], [45.0, 15.0, GROUND_Z]],  # along x
    [[15.0, 15.0, GROUND_Z], [45.0, 35.0, GROUND_Z], [45.0, 35.0, GROUND_Z]],  # two points, one picked twice
    [[15.1, 15.7, GROUND_Z], [15.3, 17.1, GROUND_Z], [15.7, 19.9, GROUND_Z]],  # slanted: its shoelace rounds to a hair above 0
]


@pytest.mark.parametrize("points", FLAT_POLYGONS, ids=["along_x", "two_points", "slanted"])
def test_a_polygon_of_points_on_one_line_is_refused_for_having_no_area(client, points):
    """Three points on a line closed into a polygon were computed, to "no pixel centre of the 0.25
    grid lies inside it: give a finer gsd" (no gsd helps); two points' error was gp.volume's
    dump of the GeoJSON made of them ("volume: clip_polygon={'type': 'Polygon', ...")."""
    c, _ = client
    with c.websocket_connect("/ws?w=120&h=90") as ws:
        receive(ws, reply("hello"))
        ws.send_json({"type": "measure", "action": "restore", "points": points, "closed": True})
        assert receive(ws, reply("measure"))["area"] < 1e-12
        ws.send_json({"type": "volume"})
        said = receive(ws, lambda k, p: k == "json" and p["type"] in ("error", "volume_result"))
    assert said == {"type": "error", "message": "volume: the polygon's points lie on one line: it has no area; move a point off the line", "in_reply_to": "volume"}


def test_a_box_over_the_cap_is_read_thinned_and_its_volume_stays_near_the_whole_ones(client, cloud, monkeypatch):
    """The polygon's box holds 124 x 84 = 10,416 points: above a cap of 3,000 every 4th is read
    (never more than the cap held), the grid no finer than their spacing, and the result says so;
    the volume within the coarser grid's error of the whole box's."""
    box_points, seen, step = VT.points_in_box(cloud, TOE, 0.25, (), 3_000)
    assert (seen, step, box_points.n_points) == (10_416, 4, 2_604)
    whole, seen, step = VT.points_in_box(cloud, TOE, 0.25, (), 20_000)
    assert (seen, step, whole.n_points) == (10_416, 1, 10_416)
    every_4th = np.concatenate([c.xyz for c in cloud.chunks()])
    every_4th = every_4th[np.all((every_4th[:, :2] >= [14.5, 14.5]) & (every_4th[:, :2] <= [45.5, 35.5]), axis=1)][::4]  # of the box's, in the cloud's order
    assert sorted(map(tuple, box_points.positions().round(3))) == sorted(map(tuple, every_4th.round(3)))
    monkeypatch.setattr(VT, "MAX_POINTS", 3_000)
    c, _ = client
    with c.websocket_connect("/ws?w=120&h=90") as ws:
        receive(ws, reply("hello"))
        close_toe(ws)
        ws.send_json({"type": "volume", "gsd": 0.25})
        assert receive(ws, reply("volume"))["gsd"] == 0.25  # (asked for; coarsened once the points are read)
        result = receive(ws, reply("volume_result"))
    assert "error" not in result, result
    spacing = VT.point_spacing(box_points.bounds, box_points.n_points)  # 4 times fewer points of the 0.25 lattice: twice as far apart
    assert result["gsd"] == float(f"{spacing:.2g}") == 0.5 and result["gsd_note"] == "a grid of 0.5, the points' mean spacing: the polygon 60 pixels across"
    assert result["note"] == "on thinned points: 1 in 4 of the 10,416 in the polygon's box (at most 3,000 kept); draw a smaller polygon for all"
    uncapped = gigapoint.volume(cloud, VT.toe(TOE), 0.25).fill
    assert abs(result["fill"] - uncapped) < grid_error(0.5) and abs(result["fill"] - 600.0) < grid_error(0.5), (result["fill"], uncapped)


def test_an_octree_box_is_read_down_to_the_levels_the_grid_needs(autzen_layered, autzen_path):
    """Most of autzen at a 16 ft grid: its octree's levels down to 2.3 ft (a quarter pixel) are
    read, not every point of the box, under the cap that would have thinned them all; the panel's
    volume is then gp.volume's of the octree (the same levels; its points at their 30-bit positions,
    not put back on the LAS grid: a few on a pixel edge fall into the next pixel, 3e-5 of the fill),
    and a fine grid reads every point."""
    octree = gigapoint.open(autzen_layered["gigapoint"])
    toe = [[636200.0, 849000.0, 0.0], [636900.0, 849000.0, 0.0], [636900.0, 849400.0, 0.0], [636200.0, 849400.0, 0.0]]

    def in_box(gsd):  # autzen's points in the box read: two pixels beyond the polygon
        return gigapoint.open(autzen_path, clip=[636200.0 - 2 * gsd, 849000.0 - 2 * gsd, 636900.0 + 2 * gsd, 849400.0 + 2 * gsd]).n_points

    sampled, seen, step = VT.points_in_box(octree, toe, 16.0, (), 60_000)
    assert step == 1 and sampled.n_points == seen < 0.75 * in_box(16.0) and in_box(16.0) > 60_000
    every, seen, step = VT.points_in_box(octree, toe, 2.0, (), 200_000)  # 0.5 ft of 2: the deepest level, 0.57 ft
    assert seen == every.n_points == in_box(2.0) and step == 1
    panel = gigapoint.volume(sampled, VT.toe(toe), 16.0, base="lowest")
    assert panel.fill == pytest.approx(gigapoint.volume(autzen_layered["gigapoint"], VT.toe(toe), 16.0, base="lowest", full=False).fill, rel=1e-4)
