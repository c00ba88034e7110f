"""The viewer's class toggles (viewer/classes.py): the Classes panel's list for each kind of
cloud, hidden_classes set through the settings message and the frames drawn without them, bad
values answered with an error, the panel disabled where a cloud cannot hide classes."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("starlette")
pytest.importorskip("httpx")

from test_hidden_classes import two_classes  # class 2 on the left half, class 6 on the right
from test_viewer_server import full_frame, receive, reply  # the websocket helpers of the server's tests

import gigapoint as gp
from gigapoint.viewer.classes import class_panel
from gigapoint.viewer.server import create_app
from gigapoint.viewer.session import ViewerCore

pytestmark = [pytest.mark.timeout(120), pytest.mark.filterwarnings("ignore::DeprecationWarning")]

GROUND, BUILDING = (160, 82, 45), (255, 168, 0)  # the classification colour mode's classes 2 and 6
# 30-bit positions: a pixel draws the same point whichever cloud holds it (batch boxes differ)
DRAWN = gp.RenderSettings(color_mode="classification", size_mode="fixed", point_size=1, adaptive_precision=False)
TWO = [{"code": 2, "name": "ground", "color": "#a0522d"}, {"code": 6, "name": "building", "color": "#ffa800"}]


def pixels_of(image, rgb) -> int:
    return int(np.all(image[..., :3] == rgb, axis=-1).sum())


@pytest.fixture()
def two_class_cloud():
    xyz, rgb, classes = two_classes()
    return gp.from_arrays(xyz, rgb, classification=classes, name="two classes")


def connect(cloud, settings=DRAWN):
    from starlette.testclient import TestClient

    core = ViewerCore(cloud, settings)
    return core, TestClient(create_app(core))


def test_the_classes_message_lists_exactly_the_classes_a_cloud_holds(two_class_cloud):
    core, client = connect(two_class_cloud)
    with client, client.websocket_connect("/ws?w=160&h=120") as ws:
        hello = receive(ws, reply("hello"))
        assert hello["classes"] == {"enabled": True, "reason": "", "source": "cloud", "complete": True, "classes": TWO}
        assert hello["settings"]["hidden_classes"] == []
        assert {d["name"]: d["kind"] for d in hello["schema"]}["hidden_classes"] == "classes"  # editable through settings
        ws.send_json({"type": "classes"})
        assert receive(ws, reply("classes"))["classes"] == TWO
    core.close_all()


def test_hiding_a_class_redraws_without_it_and_showing_it_redraws_as_before(two_class_cloud):
    xyz, rgb, classes = two_classes()
    ground = classes == 2
    alone = gp.from_arrays(xyz[ground], rgb[ground], classification=classes[ground])
    core, client = connect(two_class_cloud)
    with client, client.websocket_connect("/ws?w=240&h=160") as ws:
        session_id = receive(ws, reply("hello"))["session"]
        session = core.sessions[session_id]
        receive(ws, full_frame())
        before = session.last.frame.image.copy()
        assert pixels_of(before, GROUND) > 100 and pixels_of(before, BUILDING) > 100
        ws.send_json({"type": "settings", "values": {"hidden_classes": [6]}, "seq": 1})
        assert receive(ws, reply("settings"))["values"]["hidden_classes"] == [6]
        receive(ws, full_frame(1))
        last = session.last
        hidden = last.frame.image
        assert pixels_of(hidden, BUILDING) == 0
        # exactly what the class-2 points alone draw from that camera
        np.testing.assert_array_equal(hidden, gp.render(alone, last.camera, DRAWN))
        ws.send_json({"type": "settings", "values": {"hidden_classes": []}, "seq": 2})
        receive(ws, full_frame(2))
        np.testing.assert_array_equal(session.last.frame.image, before)
    core.close_all()


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ([300], "settings: hidden_classes must be in [0, 255], got 300"),
        ([2.5], "settings: hidden_classes must be an integer, got 2.5"),
        ([True], "settings: hidden_classes must be a finite number, got True"),
        ("6", "settings: hidden_classes must be a list of LAS classes (whole numbers in 0..255)"),
        (list(range(257)), "settings: hidden_classes must be a list of LAS classes (whole numbers in 0..255)"),
    ],
)
def test_bad_hidden_classes_are_answered_with_an_error_line(two_class_cloud, value, message):
    core, client = connect(two_class_cloud)
    with client, client.websocket_connect("/ws?w=96&h=64") as ws:
        receive(ws, reply("hello"))
        ws.send_json({"type": "settings", "values": {"hidden_classes": value}})
        error = receive(ws, reply("error"))
        assert (error["message"], error["in_reply_to"]) == (message, "settings")
        ws.send_json({"type": "ping", "t": 5})  # the connection goes on, the settings as they were
        assert receive(ws, reply("pong"))["t"] == 5
        assert core.sessions[next(iter(core.sessions))].settings.hidden_classes == ()
    core.close_all()


def test_a_cloud_without_classification_disables_the_panel_and_refuses_hidden_classes():
    xyz, rgb, _ = two_classes()
    core, client = connect(gp.from_arrays(xyz, rgb, name="plain"), gp.RenderSettings())
    reason = "hidden_classes: plain has no classification attribute, so no class to hide"
    with client, client.websocket_connect("/ws?w=96&h=64") as ws:
        hello = receive(ws, reply("hello"))
        assert hello["classes"] == {"enabled": False, "reason": reason, "source": "none", "complete": True, "classes": []}
        ws.send_json({"type": "settings", "values": {"hidden_classes": [7]}})
        assert receive(ws, reply("error"))["message"] == f"settings: {reason}"
        ws.send_json({"type": "settings", "values": {"hidden_classes": []}})  # none hidden: nothing to refuse
        assert receive(ws, reply("settings"))["values"]["hidden_classes"] == []
    core.close_all()


def codes(panel) -> list[int]:
    return [c["code"] for c in panel["classes"]]


def test_a_progressive_cloud_lists_exactly_the_classes_its_points_hold(autzen_path, tmp_path, loaded):
    """A progressive cloud's Classes panel listed the 19 standard classes whatever it held
    (autzen_trim: 1 and 2), and was never complete, so the page asked for it again every 2 s for
    good. The octree counts its points' classes as they go in: the panel lists those, complete once
    loaded, more with a file of another class or an ``add`` of one."""
    laspy = pytest.importorskip("laspy")
    las = laspy.read(autzen_path)
    held = np.asarray(las.classification)
    water = laspy.LasData(las.header, las.points[:500].copy())  # (autzen's header: its CRS, no mixed-CRS warning)
    water.classification = np.full(500, 9, np.uint8)
    water.write(tmp_path / "water.las")

    cloud = loaded(autzen_path)
    panel = class_panel(cloud)
    assert (panel["enabled"], panel["source"], panel["complete"]) == (True, "cloud", True)
    assert codes(panel) == np.unique(held).tolist() == [1, 2]
    assert np.array_equal(cloud.points_per_class, np.bincount(held, minlength=256))
    cloud.add(las.xyz[:300], classification=np.full(300, 17, np.uint8))  # (bridge deck)
    assert codes(class_panel(cloud)) == [1, 2, 17]
    assert np.array_equal(cloud.points_per_class, np.bincount(held, minlength=256) + 300 * (np.arange(256) == 17))
    cloud.close()

    both = loaded(autzen_path, tmp_path / "water.las")
    assert codes(class_panel(both)) == [1, 2, 9]
    assert np.array_equal(both.points_per_class, np.bincount(np.concatenate([held, water.classification]), minlength=256))
    both.close()


def test_a_loading_progressive_cloud_lists_the_classes_seen_so_far_until_it_is_loaded(autzen_path, gated_loading):
    """While it loads the list is the classes of the points in so far, not complete (the page
    asks again); a strip that brings another class adds it; loaded, it is complete."""
    import threading

    las = pytest.importorskip("laspy").read(autzen_path)
    gate = threading.Event()
    autzen = (las.xyz, {"classification": np.asarray(las.classification)})
    water = (las.xyz[:500], {"classification": np.full(500, 9, np.uint8)})
    cloud = gated_loading([autzen, water], [None, gate], name="gated")
    cloud.wait_first_points()  # (autzen went in whole, as the first chunk does; water waits at the gate)
    panel = class_panel(cloud, hidden=(40,))  # (a class hidden and never seen is not listed: as for a cloud in memory)
    assert (panel["source"], panel["complete"], codes(panel)) == ("cloud", False, [1, 2])
    gate.set()
    assert cloud.wait(timeout=120)
    panel = class_panel(cloud)
    assert (panel["complete"], codes(panel)) == (True, [1, 2, 9])


def test_a_progressive_cloud_before_its_first_points_says_so_and_its_panel_is_not_complete(gated_loading):
    """Before its first points a progressive octree holds no attribute: its panel said it had no
    classification, complete (as if for good), and refused hidden classes for it. It says its
    first points are not in yet, not complete (the page asks again); then lists their classes."""
    import threading

    xyz, _, classes = two_classes()
    gate = threading.Event()
    cloud = gated_loading([(xyz, {"classification": classes})], [gate], name="held")
    reason = "hidden_classes: held's first points are not in yet; its classes are listed once they are"
    assert class_panel(cloud) == {"enabled": False, "reason": reason, "source": "none", "complete": False, "classes": []}
    gate.set()
    assert cloud.wait(timeout=120)
    assert class_panel(cloud) == {"enabled": True, "reason": "", "source": "cloud", "complete": True, "classes": TWO}


def test_an_octree_lists_the_classes_its_metadata_names(tmp_path, two_class_cloud):
    gp.convert(two_class_cloud, tmp_path / "potree", format="potree")
    meta_path = tmp_path / "potree" / "metadata.json"
    meta = json.loads(meta_path.read_text())
    entry = next(a for a in meta["attributes"] if a["name"] == "classification")
    assert (entry["min"], entry["max"]) == ([2.0], [6.0])
    # min and max bound them: the standard classes between, none above 6 or below 2, more to come as nodes load
    bounded = class_panel(gp.open(tmp_path / "potree"))
    assert (bounded["source"], bounded["complete"], codes(bounded)) == ("standard", False, [2, 3, 4, 5, 6])
    entry["histogram"] = [0] * 256  # PotreeConverter 2's counts of a 1-byte attribute: exactly the classes held
    entry["histogram"][2], entry["histogram"][6] = 400, 400
    meta_path.write_text(json.dumps(meta))
    listed = class_panel(gp.open(tmp_path / "potree"))
    assert (listed["source"], listed["complete"], listed["classes"]) == ("metadata", True, TWO)


def test_a_gigapoint_octree_lists_exactly_the_classes_its_class_counts_name(tmp_path, two_class_cloud):
    """Its Classes panel listed the standard classes within its classification's range (2..6 and
    up: 3, 4, 5 none of its points), more as nodes loaded; its per-node class counts name exactly
    the classes held, before any node is read."""
    gp.convert(two_class_cloud, tmp_path / "tree")
    tree = gp.open(tmp_path / "tree")
    assert tree.class_facts() == {"classes": [2, 6]}
    panel = class_panel(tree)
    assert (panel["source"], panel["complete"], panel["classes"]) == ("metadata", True, TWO)
    assert codes(class_panel(gp.open(tmp_path / "tree", drop_classes=[6]))) == [2]


def test_an_octree_without_a_list_offers_the_standard_classes_and_those_seen(tmp_path, two_class_cloud):
    gp.convert(two_class_cloud, tmp_path / "tree")
    (tmp_path / "tree" / "classes.npy").unlink()  # an octree written before class counts
    tree = gp.open(tmp_path / "tree")
    assert tree.class_facts()["class_range"][0] == 2  # the lowest class held; the highest only bounded
    lo, hi = tree.class_facts()["class_range"]
    assert codes(class_panel(tree)) == list(range(2, min(hi, 18) + 1))
    assert codes(class_panel(tree, hidden=(30,))) == [*range(2, min(hi, 18) + 1), 30]  # hidden ones stay, to be ticked again
    # a COPC file's header names no class: the standard 0..18, and once nodes are loaded the classes they hold
    xyz, rgb, classes = two_classes()
    gp.convert(gp.from_arrays(xyz, rgb, classification=np.where(classes == 6, 40, 2).astype(np.uint8)), tmp_path / "c.copc.laz")
    copc = gp.open(tmp_path / "c.copc.laz")
    assert codes(class_panel(copc)) == list(range(19))
    gp.render(copc, gp.Camera.top_down(((0, 0, 0), (100, 50, 1)), 0.5))
    assert codes(class_panel(copc)) == [*range(19), 40]
    assert codes(class_panel(copc, seen=False)) == list(range(19))  # (the render lock was busy: what the nodes hold left out)


def test_an_octree_opened_with_a_class_filter_lists_only_the_classes_it_keeps(tmp_path, two_class_cloud):
    """``view OCTREE --classes 2``: its Classes panel listed the standard classes, 6 among them,
    whose toggles did nothing (the filter drops them as nodes load); now those the filter keeps,
    before and after nodes are loaded, from its metadata's list too."""
    gp.convert(two_class_cloud, tmp_path / "tree")
    core, client = connect(gp.open(tmp_path / "tree", classes=[2]))
    with client, client.websocket_connect("/ws?w=240&h=160") as ws:
        hello = receive(ws, reply("hello"))
        assert (hello["classes"]["source"], codes(hello["classes"])) == ("metadata", [2])  # (its class counts list 2 and 6)
        receive(ws, full_frame())  # (its nodes loaded: class 2 alone seen)
        ws.send_json({"type": "classes"})
        assert receive(ws, reply("classes"))["classes"] == TWO[:1]
    core.close_all()
    (tmp_path / "tree" / "classes.npy").unlink()  # an octree written before class counts: its range's standard classes
    lo, hi = gp.open(tmp_path / "tree").class_facts()["class_range"]
    assert codes(class_panel(gp.open(tmp_path / "tree", drop_classes=[6, 9]))) == [c for c in range(lo, min(hi, 18) + 1) if c not in (6, 9)]
    gp.convert(two_class_cloud, tmp_path / "potree", format="potree")
    meta_path = tmp_path / "potree" / "metadata.json"
    meta = json.loads(meta_path.read_text())
    entry = next(a for a in meta["attributes"] if a["name"] == "classification")
    entry["histogram"] = [400 if c in (2, 6) else 0 for c in range(256)]  # its metadata lists 2 and 6
    meta_path.write_text(json.dumps(meta))
    listed = class_panel(gp.open(tmp_path / "potree", drop_classes=[2]))
    assert (listed["source"], listed["complete"], listed["classes"]) == ("metadata", True, TWO[1:])


def test_view_starts_with_the_hidden_classes_given(cli, autzen_path, monkeypatch, tmp_path):
    from gigapoint.viewer.server import ViewerServer

    served = []

    def serve(self):  # (not for ever: the settings each tab starts with, then closed)
        served.append(self.core.settings.hidden_classes)
        self.sock.close()

    monkeypatch.setattr(ViewerServer, "serve_forever", serve)
    rc, _, err = cli("view", autzen_path, "--hidden-classes", "7,2", "--no-browser")
    assert rc == 0, err
    assert served == [(2, 7)]  # each tab's first settings: its Classes panel starts with 2 and 7 unticked
    rc, _, err = cli("view", autzen_path, "--hidden-classes", "300", "--no-browser")
    assert rc == 1 and err == "error: --hidden-classes: 300 is not a LAS class (whole numbers in 0..255), got '300'\n"
    rc, _, err = cli("view", "--demo", "1000", "--progressive", "--hidden-classes", "7", "--no-browser")
    # a progressive octree hides classes as it draws: the demo town's (its classes 2, 5, 6, 9, 11),
    # known once its first points are in (before them it has no attribute: it was refused, or not,
    # as the load's first slice came before the check or after it)
    assert rc == 0, err
    assert served == [(2, 7), (7,)]
    xyz = tmp_path / "plain.xyz"
    xyz.write_text("".join(f"{i} {i % 7} {i % 3}\n" for i in range(2000)))
    rc, _, err = cli("view", xyz, "--progressive", "--hidden-classes", "7", "--no-browser")
    assert rc == 1 and err == "error: --hidden-classes: plain.xyz has no classification attribute, so no class to hide\n"
    assert len(err.splitlines()) == 1 and len(served) == 2


def test_view_of_an_octree_with_a_class_filter_draws_it_level_of_detail_without_the_others(cli, tmp_path, two_class_cloud, monkeypatch):
    from gigapoint.io.filters import point_filter
    from gigapoint.lod.store import OctreeCloud
    from gigapoint.viewer.server import ViewerServer

    gp.convert(two_class_cloud, tmp_path / "tree")
    served = []

    def serve(self):  # (not for ever: the cloud each tab draws, then closed)
        served.append(self.core.cloud)
        self.sock.close()

    monkeypatch.setattr(ViewerServer, "serve_forever", serve)
    rc, _, err = cli("view", tmp_path / "tree", "--classes", "2", "--no-browser")
    assert rc == 0, err
    (tree,) = served
    assert isinstance(tree, OctreeCloud) and tree.read_filter == point_filter(classes=[2])  # the octree itself, drawn level of detail
    core, client = connect(tree)
    with client, client.websocket_connect("/ws?w=240&h=160") as ws:
        session = core.sessions[receive(ws, reply("hello"))["session"]]
        receive(ws, full_frame())
        image = session.last.frame.image
        assert pixels_of(image, GROUND) > 300 and pixels_of(image, BUILDING) == 0  # (400 points of class 2, 400 of class 6)
    core.close_all()


def test_a_section_leaves_out_the_classes_hidden_and_is_drawn_again_when_they_change(two_class_cloud):
    """The section tool drew (and its CSV listed) the points of classes unticked in the Classes
    panel, where the volume tool leaves them out: a section across both halves counted class 6's
    points hidden from the view. It is of what the view shows, and follows the panel."""
    xyz, _, classes = two_classes()
    line, width = (1.0, 25.0, 99.0, 25.0), 5.0  # across both halves, 2 rows of the 2.5 grid
    in_corridor = (np.abs(xyz[:, 1] - 25.0) <= width / 2) & (xyz[:, 0] >= 1) & (xyz[:, 0] <= 99)
    core, client = connect(two_class_cloud)
    with client, client.websocket_connect("/ws?w=160&h=120") as ws:
        session = receive(ws, reply("hello"))["session"]
        ws.send_json({"type": "settings", "values": {"hidden_classes": [6]}})
        receive(ws, reply("settings"))
        ws.send_json({"type": "section", "action": "set", "points": [[*line[:2], 0], [*line[2:], 0]], "width": width})
        shown = receive(ws, reply("section_result"))
        assert shown["count"] == np.count_nonzero(in_corridor & (classes == 2)) == 40
        assert shown["distance"][1] < 49  # the left half's points alone
        rows = client.get(f"/section.csv?session={session}").text.splitlines()
        assert rows[0].endswith(",classification") and len(rows) == 41 and {r.rsplit(",", 1)[1] for r in rows[1:]} == {"2"}
        ws.send_json({"type": "settings", "values": {"hidden_classes": [2, 6]}})
        said = "two classes: no point passes the filter (drop classes 2, 6; corridor 1, 25 to 99, 25, width 5): 800 points read"
        assert receive(ws, reply("section_result"))["error"] == said  # nothing shown, nothing in the section
        ws.send_json({"type": "settings", "values": {"hidden_classes": []}})
        assert receive(ws, reply("section_result"))["count"] == np.count_nonzero(in_corridor) == 80
