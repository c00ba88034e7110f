"""Read filters on LOD octrees (``gp.open(octree, classes=..., clip=...)``, ``render OCTREE
--classes``): the octree is drawn level of detail, its nodes that do not meet the filter never
read, the others' points filtered as they load, their kept points weighing on the budget (as
hidden classes'); no point is read whole."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image
from test_hidden_classes import BLUE, FIXED, RED, TOP, pixels_of, two_classes  # class 2 (red) on the left half, class 6 (blue) on the right

import gigapoint as gp
from gigapoint.errors import EmptyCloudError, GigapointWarning, InputError
from gigapoint.io.filters import point_filter
from gigapoint.lod import reader
from gigapoint.lod.query import BOX_SLACK
from gigapoint.lod.store import Arena, OctreeCloud

EVERY = {"point_budget": 10**9, "lod_threshold_px": 0, **FIXED}  # every node meeting the filter drawn
FINE = gp.Camera.top_down(((0, 0, 0), (100, 50, 1)), 0.25)  # 401x201 pixels: each point of two_classes(0.25) its own
CLIP = (5.0, 5.0, 20.0, 20.0)  # class 2 alone, in one leaf's box
FORMATS = {"words": ("gigapoint", {"layout": "words"}), "compact": ("gigapoint", {}), "potree": ("potree", {})}


@pytest.fixture(scope="module")
def trees(tmp_path_factory) -> dict:
    """two_classes(0.25) converted in each format: 80 000 points, 40 000 of each class; a
    root of 15 601 points (7 810 of class 2), two nodes of ~20 800 below it (one of each class),
    43 nodes."""
    xyz, rgb, classes = two_classes(0.25)
    cloud = gp.from_arrays(xyz, rgb, classification=classes, scale=0.01, colors="rgba")
    out = {}
    for name, (fmt, options) in FORMATS.items():
        out[name] = tmp_path_factory.mktemp(name) / "tree"
        gp.convert(cloud, out[name], format=fmt, max_leaf=2_000, **options)
    return out


def _loads(monkeypatch) -> list[int]:
    """The nodes whose points the arena loads (``Arena._load``: read and decoded, every kind)."""
    loads: list[int] = []
    real = Arena._load
    monkeypatch.setattr(Arena, "_load", lambda self, nd, *rest: loads.append(nd) or real(self, nd, *rest))
    return loads


def _classes_drawn(frame) -> set[int]:
    return {frame.point_info(int(i))["classification"] for i in np.unique(frame.index[frame.index >= 0])}


def test_a_class_filter_spends_the_budget_on_the_class_kept(trees):
    budget = {"point_budget": 30_000, "lod_threshold_px": 0, **FIXED}
    plain = gp.open(trees["compact"])
    shown = gp.render_frame(plain, TOP, **budget)
    assert shown.stats.points_processed == 15_601  # the root alone: a node below it would pass the budget
    class_2_shown = int(np.count_nonzero(plain.arena.resident_classification() == 2))  # (one frame: the nodes it drew)
    ground = gp.open(trees["compact"], classes=[2])
    assert isinstance(ground, OctreeCloud) and ground.read_filter == point_filter(classes=[2])
    kept = gp.render_frame(ground, TOP, **budget)
    assert _classes_drawn(kept) == {2} and pixels_of(kept.image, BLUE) == 0
    # the budget class 6 leaves takes the node of class 2 below the root: more of it drawn, more pixels covered
    assert (class_2_shown, kept.stats.points_processed) == (7_810, 28_562)
    assert pixels_of(kept.image, RED) > pixels_of(shown.image, RED)


def test_render_of_an_octree_with_classes_reads_only_the_nodes_it_draws(cli, trees, tmp_path, monkeypatch):
    loads = _loads(monkeypatch)
    opened = []
    real_open = reader.open_filtered
    monkeypatch.setattr(reader, "open_filtered", lambda *a: opened.append(real_open(*a)) or opened[-1])
    size = ("-W", 201, "-H", 101, "--view", "top", "--size-mode", "fixed", "--point-budget", 30_000, "--lod-threshold-px", 0)
    rc, out, err = cli("render", trees["compact"], "-o", tmp_path / "ground.png", "--index-out", tmp_path / "ground.npy", "--classes", "2", *size)
    assert rc == 0, err
    assert out.startswith(f"wrote {tmp_path / 'ground.png'} (201x101, 28,562 of 80,000 points drawn)")
    image = np.asarray(Image.open(tmp_path / "ground.png"))
    assert pixels_of(image, RED) > 5_000 and pixels_of(image, BLUE) == 0
    (tree,) = opened  # the octree drawn level of detail: its index buffer names points of its arena
    index = np.load(tmp_path / "ground.npy")
    assert set(tree.arena.attributes.at("classification", index[index >= 0]).tolist()) == {2}
    # no full read: the root and the two nodes below it loaded, once each (the one of class 6
    # found to keep none), and two of the 8 leaves, of the node of class 6 (guessed to keep
    # store.MIN_KEPT_SHARE of their points, the least a node not loaded is taken to keep: they
    # keep none): points read bounded by the budget, not the octree
    assert sorted(loads) == [0, 1, 2, 9, 10] and int(tree.counts[loads].sum()) == 62_812 < tree.n_points


@pytest.mark.parametrize("kind", FORMATS)
def test_a_clip_box_draws_no_point_outside_and_reads_no_node_outside(trees, monkeypatch, kind):
    loads = _loads(monkeypatch)
    tree = gp.open(trees[kind], clip=CLIP)
    lo, hi = tree.bounds  # what a view frames: where the points kept can be
    assert (lo[:2].tolist(), hi[:2].tolist()) == ([5.0, 5.0], [20.0, 20.0])
    frame = gp.render_frame(tree, FINE, **EVERY)
    inside = 60 * 60  # a point every 0.25 from 5.125 to 19.875 in x and y
    assert frame.stats.points_processed == inside and np.count_nonzero(frame.index >= 0) == inside  # each its own pixel
    positions = np.array([frame.point_info(int(i))["position"] for i in frame.index[frame.index >= 0]])
    assert np.all((positions[:, :2] >= CLIP[:2]) & (positions[:, :2] <= CLIP[2:]))
    # the nodes loaded, once each, are those whose boxes (widened by the slack) meet the box: the
    # root, the node of class 2 below it and one of its leaves, of the 11 holding points
    pad = BOX_SLACK * float(tree.meta["cube_edge"])
    lo, hi = tree.box_min - pad, tree.box_min + tree.box_size + pad
    meeting = np.flatnonzero((tree.counts > 0) & np.all((hi[:, :2] >= CLIP[:2]) & (lo[:, :2] <= CLIP[2:]), axis=1))
    assert sorted(loads) == meeting.tolist() and len(meeting) == 3 and np.count_nonzero(tree.counts) == 11


@pytest.mark.parametrize("kind", FORMATS)
def test_a_budget_for_every_point_draws_what_the_points_kept_draw(trees, kind):
    xyz, rgb, classes = two_classes(0.25)
    box = (30.0, 5.0, 70.0, 45.0)  # across both halves: the clip box and the class both decide
    kept = point_filter(classes=[2], clip=box).keeps(xyz, classes, "test")
    brute = gp.from_arrays(xyz[kept], rgb[kept], classification=classes[kept], scale=0.01, colors="rgba")
    image = gp.render(gp.open(trees[kind], classes=[2], clip=box), FINE, **EVERY)
    np.testing.assert_array_equal(image, gp.render(brute, FINE, **EVERY))
    assert pixels_of(image, RED) == np.count_nonzero(kept) == 80 * 160 and pixels_of(image, BLUE) == 0
    # hidden classes join the read filter: class 2 hidden as well, nothing is left
    with pytest.warns(GigapointWarning, match="no point is in view"):
        assert not gp.render(gp.open(trees[kind], classes=[2], clip=box), FINE, hidden_classes=(2,), **EVERY)[..., :3].any()


def test_a_filter_no_node_meets_and_a_filter_an_octree_cannot_apply_say_so(trees, tmp_path):
    tree = trees["compact"]
    with pytest.raises(EmptyCloudError) as err:
        gp.open(tree, clip=(500, 500, 600, 600))
    assert str(err.value) == f"{tree}: no point passes the filter (clip 500, 500, 600, 600): no node of the octree meets the filter's region"
    xyz = np.random.default_rng(1).uniform(0, 10, (5_000, 3))
    gp.convert(gp.from_arrays(xyz), tmp_path / "plain")
    with pytest.raises(InputError) as err:
        gp.open(tmp_path / "plain", drop_classes=[7])
    assert str(err.value) == f"{tmp_path / 'plain'}: holds no classification, which the filter (drop classes 7) needs"
    with pytest.raises(InputError) as err:  # an octree still opens alone
        gp.open(tree, tmp_path / "plain", classes=[2])
    assert str(err.value) == f"{tree}: a converted octree folder opens alone, drawn level of detail as stored; it cannot join other files"
