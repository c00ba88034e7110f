"""The point budget through a load filter (hidden classes, a read filter): a node not yet loaded
(a progressive octree's chunk not yet filtered) is weighed by the share of its points its
nearest loaded ancestor kept (store.kept_shares), so a frame spends the budget close to full;
the selections that follow, on the kept counts of what loaded, drop what passes the budget.
A converted octree's per-node class counts (classes.npy) tell a class filter's kept counts
before anything loads: the first selection spends the budget, and is the only one."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from test_hidden_classes import FIXED, TOP, counting_filters, two_classes

import gigapoint as gp
from gigapoint.lod import store
from gigapoint.lod.progressive import ProgressiveOctree
from gigapoint.lod.progressive import octree as progressive
from gigapoint.lod.store import Arena, OctreeCloud

MIDDLE = (10.0, 0.0, 60.0, 50.0)  # a clip box over half the octree (x 10-60), its sides through the nodes below the root


def half_hidden():
    """two_classes(0.25) (80 000 points) with half of them class 7, everywhere."""
    xyz, rgb, _ = two_classes(spacing=0.25)
    classes = np.where(np.random.default_rng(1).permutation(len(xyz)) % 2 == 0, 2, 7).astype(np.uint8)
    return xyz, rgb, classes


@pytest.fixture(scope="module")
def half(tmp_path_factory):
    """half_hidden converted: a root of 15 601 points, two nodes of ~20 800 below it, leaves of ~2 850."""
    path = tmp_path_factory.mktemp("half") / "tree"
    xyz, rgb, classes = half_hidden()
    gp.convert(gp.from_arrays(xyz, rgb, classification=classes, scale=0.01, colors="rgba"), path, max_leaf=2_000)
    return path


@pytest.fixture(scope="module")
def half_before_counts(half, tmp_path_factory):
    """``half`` as octrees written before class counts are: without classes.npy."""
    path = tmp_path_factory.mktemp("before") / "tree"
    shutil.copytree(half, path)
    (path / "classes.npy").unlink(missing_ok=True)  # (main before them wrote none)
    return path


def grown_half() -> ProgressiveOctree:
    tree = ProgressiveOctree("half", max_leaf=2_000)
    tree.add(*half_hidden()[:2], classification=half_hidden()[2])
    return tree


def selections(monkeypatch) -> list[int]:
    """The points each selection of a converted octree draws (the kept points of the nodes
    ``_resident_selection`` makes resident), selection by selection."""
    drawn, original = [], OctreeCloud._resident_selection

    def recorded(self, view, settings, **kw):
        ids = original(self, view, settings, **kw)
        drawn.append(sum(int(self.arena.batches["count"][self.arena.resident[i]].sum()) for i in ids.tolist()))
        return ids

    monkeypatch.setattr(OctreeCloud, "_resident_selection", recorded)
    return drawn


@pytest.mark.parametrize(("budget", "first"), [(20_000, 18_125), (30_000, 29_998), (40_000, 40_000)])
@pytest.mark.parametrize("filtered", ["hidden class 7", "classes=[2]"])
def test_class_counts_let_the_first_selection_spend_the_budget(half, monkeypatch, budget, first, filtered):
    """Every node's kept points known before any loads: one selection, the budget spent (40 000:
    18 125 without the counts, below; 20 000: 7 795; 30 000: 7 795), no share guessed."""
    drawn = selections(monkeypatch)
    passes, shares = [], store.kept_shares
    monkeypatch.setattr(store, "kept_shares", lambda *a: passes.append(1) or shares(*a))
    tree, options = (gp.open(half), {"hidden_classes": (7,)}) if filtered == "hidden class 7" else (gp.open(half, classes=[2]), {})
    frame = gp.render_frame(tree, TOP, point_budget=budget, lod_threshold_px=0, **options, **FIXED)
    # (20 000: the root's 7 795 kept and one node's 10 330 below it; the other's would pass it)
    assert drawn == [first] and frame.stats.points_processed == first and not passes
    assert first >= 0.9 * budget


def test_the_second_selection_already_spends_the_budget_in_full(half_before_counts, monkeypatch):
    drawn = selections(monkeypatch)
    frame = gp.render_frame(gp.open(half_before_counts), TOP, hidden_classes=(7,), point_budget=40_000, lod_threshold_px=0, **FIXED)
    # the first knows nothing kept (the root and a node by their whole counts: 18 125 of theirs
    # drawn); the second weighs the nodes below by the half the root kept: 40 000, all the
    # budget, the third the same. (Weighed whole: 28 536, 34 285, 35 710 ... 37 156 in 9 selections)
    assert drawn == [18_125, 40_000, 40_000]
    assert frame.stats.points_processed == 40_000


@pytest.mark.parametrize("budget", [20_000, 30_000, 40_000])
@pytest.mark.parametrize("kind", ["converted", "converted before class counts", "progressive"])
def test_the_budget_hidden_classes_leave_is_spent_close_to_full_and_never_passed(half, half_before_counts, kind, budget):
    tree = {"converted": lambda: gp.open(half), "converted before class counts": lambda: gp.open(half_before_counts), "progressive": grown_half}[kind]()
    drawn = gp.render_frame(tree, TOP, hidden_classes=(7,), point_budget=budget, lod_threshold_px=0, **FIXED).stats.points_processed
    # weighed whole, the nodes not yet loaded left most of it: 7 795, 18 125, 37 156 drawn
    # (converted), 7 925, 7 925, 22 512 (progressive)
    assert 0.9 * budget <= drawn <= budget


def test_a_kept_share_guessed_too_low_drops_the_nodes_past_the_budget(sides, monkeypatch):
    drawn = selections(monkeypatch)
    frame = gp.render_frame(gp.open(sides, classes=[2]), TOP, point_budget=25_000, lod_threshold_px=0, **FIXED)
    # the root keeps 55 % of its points, so the node on the left is guessed to keep 55 % of its
    # 20 752: loaded, it keeps all of them, root and node 29 364 past the budget: the next
    # selection drops it again, the root alone within the budget
    assert drawn == [8_612, 29_364, 8_612]
    assert frame.stats.points_processed == 8_612


@pytest.mark.parametrize(("budget", "first", "before"), [(15_000, 14_228, 3_882), (18_000, 17_119, 3_882), (20_000, 19_092, 3_882)])
def test_class_counts_and_a_clip_box_let_the_first_selection_spend_the_budget(half, monkeypatch, budget, first, before):
    """Class 7 hidden and a clip box over half the octree: a node not loaded is weighed by the
    points its classes keep (the class counts) times the share of its box inside the clip box,
    so the first selection spends 95 % of the budget (class 7 hidden alone: 18 125 of 20 000
    above), where it weighed every node whole and drew the root alone (``before``), leaving the
    budget to the selections after it."""
    drawn = selections(monkeypatch)
    frame = gp.render_frame(gp.open(half, clip=MIDDLE), TOP, hidden_classes=(7,), point_budget=budget, lod_threshold_px=0, **FIXED)
    assert drawn[0] == first >= 0.94 * budget > before
    assert 0.94 * budget <= frame.stats.points_processed <= budget


@pytest.mark.parametrize("kind", ["converted", "progressive"])
def test_the_last_selection_weighs_what_is_not_loaded_whole(sides, monkeypatch, kind):
    """Selections run out (one after the first here) while guesses still load nodes: the last
    weighs those not loaded by all their points, so what it draws fits whatever they keep."""
    monkeypatch.setattr(store, "KEPT_ROUNDS", 1)
    monkeypatch.setattr(progressive, "KEPT_ROUNDS", 1)
    if kind == "converted":
        tree, options = gp.open(sides, classes=[2]), {}  # (guessed by the share the root kept, the left node would pass it: as above)
    else:
        xyz, rgb, classes = two_classes(0.25)  # class 2 on the left, 6 on the right: the root keeps half, its octants one or none
        tree, options = ProgressiveOctree("sides", max_leaf=2_000), {"hidden_classes": (6,)}
        tree.add(xyz, rgb, classification=classes)
    frame = gp.render_frame(tree, TOP, point_budget=25_000, lod_threshold_px=0, **options, **FIXED)
    assert frame.stats.points_processed <= 25_000


def test_a_progressive_octree_knows_what_a_chunk_kept_once_its_slot_is_taken_back(monkeypatch):
    tree = grown_half()
    filtered = counting_filters(monkeypatch)
    gp.render_frame(tree, TOP, hidden_classes=(7,), point_budget=40_000, lod_threshold_px=0, **FIXED)
    kept, pool = tree._kept, tree.pool
    chunks = np.intersect1d(np.flatnonzero(pool.chunk_node[: pool.n_chunks] == tree.root), np.concatenate(filtered))
    # the root's voxels filtered by the first selection, their slots given to the leaves drawn since
    assert len(chunks) == 4 and np.all(kept.slot_of[chunks] == -1)
    counts, known = kept.kept_counts(pool, (7,))
    entries = [np.arange(c * pool.chunk, c * pool.chunk + pool.batches["count"][c]) for c in chunks]
    not_hidden = [int(np.count_nonzero(pool.attributes.at("classification", e) != 7)) for e in entries]
    assert known[chunks].all() and counts[chunks].tolist() == not_hidden


def test_frames_that_load_nothing_weigh_the_nodes_again_only_once_a_node_comes_or_goes(half_before_counts, monkeypatch):
    """The shares are a pass over every node (10^5 and more in a big octree) each selection makes,
    two or more a frame: the arena reuses its kept counts until its resident nodes change."""
    tree = gp.open(half_before_counts)
    options = {"hidden_classes": (7,), "lod_threshold_px": 0, **FIXED}
    gp.render_frame(tree, TOP, point_budget=20_000, **options)
    passes, shares = [], store.kept_shares
    monkeypatch.setattr(store, "kept_shares", lambda *a: passes.append(1) or shares(*a))
    frame = gp.render_frame(tree, TOP, point_budget=20_000, **options)
    assert len(passes) == 0 and frame.stats.points_processed == 18_125  # (as the frame before it)
    frame = gp.render_frame(tree, TOP, point_budget=40_000, **options)  # the leaves loaded: weighed again
    assert len(passes) > 0 and frame.stats.points_processed == 40_000
    arena, keep = tree.arena, tree.load_filter((7,))
    nodes = np.array(list(arena.resident))
    kept = [int(arena.batches["count"][arena.resident[i]].sum()) for i in nodes.tolist()]
    assert arena.kept_counts(tree.counts, keep, tree.parent)[nodes].tolist() == kept


def test_a_progressive_octree_weighs_its_chunks_again_only_once_one_is_written_or_filtered(monkeypatch):
    """As above, a progressive octree's costs walk every chunk the estimates leave entries out
    of: frames reuse them until a chunk is written or filtered."""
    tree = grown_half()
    options = {"hidden_classes": (7,), "lod_threshold_px": 0, **FIXED}
    first = gp.render_frame(tree, TOP, point_budget=20_000, **options).stats.points_processed
    passes, shares = [], progressive.kept_shares
    monkeypatch.setattr(progressive, "kept_shares", lambda *a: passes.append(1) or shares(*a))
    again = gp.render_frame(tree, TOP, point_budget=20_000, **options).stats.points_processed
    assert len(passes) == 0 and again == first == 19_574
    deeper = gp.render_frame(tree, TOP, point_budget=40_000, **options).stats.points_processed  # more chunks filtered
    assert len(passes) > 0 and deeper == 38_596
    tree.add(*half_hidden()[:2], classification=half_hidden()[2])  # every chunk written again: twice the points
    passes.clear()
    grown = gp.render_frame(tree, TOP, point_budget=40_000, **options).stats.points_processed
    assert len(passes) > 0 and grown == 39_861  # (as without reusing the costs)



def converted_sides(path, **options):
    xyz, rgb, classes = two_classes(0.25)
    classes[(classes == 6) & (np.random.default_rng(2).random(len(xyz)) < 0.1)] = 2
    gp.convert(gp.from_arrays(xyz, rgb, classification=classes, scale=0.01, colors="rgba"), path, max_leaf=2_000, **options)
    (path / "classes.npy").unlink()  # (as octrees written before class counts: what the arena kept is weighed, not known ahead)
    return path


@pytest.fixture(scope="module")
def sides(tmp_path_factory):
    """two_classes(0.25) converted, a tenth of the right side's points class 2 too: a root of
    15 601 points (8 612 of class 2), a node below it on each side: 20 752 on the left (all of
    class 2), 20 782 on the right (2 011)."""
    return converted_sides(tmp_path_factory.mktemp("sides") / "tree")


@pytest.fixture(scope="module")
def sides_in_words(tmp_path_factory):
    """sides in the three-word layout (an arena of low, med and high words, no streams)."""
    return converted_sides(tmp_path_factory.mktemp("sides_in_words") / "tree", layout="words")


def test_a_node_the_arena_dropped_is_weighed_by_the_points_it_kept(sides, monkeypatch):
    """An arena too small for both sides drops the nodes of one as the camera looks at the
    other; back again, they are weighed by what they kept when loaded (not by the share the
    root keeps): the same points drawn, and only the nodes drawn that were dropped loaded."""
    tree = gp.open(sides)
    tree.arena = tree.new_arena(60_000)  # 15 slots
    left = gp.Camera.top_down(((0, 0, 0), (25, 25, 1)), 0.125)
    right = gp.Camera.top_down(((75, 25, 0), (100, 50, 1)), 0.125)
    prepared = []
    monkeypatch.setattr(OctreeCloud, "prepare", lambda self, view, settings, prepare=OctreeCloud.prepare: prepared.append(prepare(self, view, settings)) or prepared[-1])
    frames = []
    for camera in [left, right, left, right, left]:
        resident, loads = set(tree.arena.resident), tree.arena.loads
        frame = gp.render_frame(tree, camera, hidden_classes=(6,), point_budget=30_000, lod_threshold_px=0, **FIXED)
        frames.append((frame.stats.points_processed, tree.arena.loads - loads, len(set(prepared[-1].nodes.tolist()) - resident)))
    # (points drawn, nodes loaded, nodes drawn that were not resident): the left draws the root
    # and the left node (8 612 + 20 752), the right the root, the right node and its children
    # (11 830); the left node is dropped meanwhile and loaded alone on the way back. (Weighed by
    # the root's share, 11 455, it left room for its 4 children: loaded, then dropped again as
    # it kept all its points: 5 loads; and 3 back on the right, 5 again on the left)
    assert frames == [(29_364, 6, 2), (11_830, 5, 5), (29_364, 1, 1), (11_830, 0, 0), (29_364, 0, 0)]
    assert tree.arena.n_slots == 15  # (the arena the test made: never replaced)


@pytest.mark.parametrize("layout", ["sides", "sides_in_words"])
def test_an_arena_replaced_by_a_larger_one_hands_over_its_nodes_and_what_each_kept(layout, request, monkeypatch):
    """A budget raised past what the arena holds replaces it: the new one holds the old one's
    nodes, filter and kept counts, so its frames draw and load what they would have, had the
    arena been large enough all along (not every node loaded again, weighed by estimates)."""
    path = request.getfixturevalue(layout)
    loaded = []
    load = Arena._load
    monkeypatch.setattr(Arena, "_load", lambda self, nd, *rest: loaded.append(nd) or load(self, nd, *rest))
    options = {"hidden_classes": (6,), "lod_threshold_px": 0, **FIXED}
    replaced, large = gp.open(path), gp.open(path)
    replaced.arena, large.arena = replaced.new_arena(20_000), large.new_arena(200_000)  # 5 slots, 49
    frames = {}
    for tree in (replaced, large):
        frames[tree] = []
        for budget in [20_000, 35_000, 35_000]:
            loaded.clear()
            frame = gp.render_frame(tree, TOP, point_budget=budget, **options)
            frames[tree].append((frame.stats.points_processed, len(loaded), frame.image))
    assert replaced.arena.n_slots == 64  # (replaced by the second frame)
    # (points drawn, nodes loaded): the root (8 612 kept); then the nodes below it, the root not
    # loaded again (a new arena that held nothing: 5 loads); then nothing more to load
    assert [f[:2] for f in frames[replaced]] == [f[:2] for f in frames[large]] == [(8_612, 1), (34_520, 4), (34_520, 0)]
    for (*_, image), (*_, same) in zip(frames[replaced], frames[large]):
        np.testing.assert_array_equal(image, same)  # the nodes handed over as they were loaded
    np.testing.assert_array_equal(replaced.arena.kept, large.arena.kept)
    assert replaced.arena.loads == large.arena.loads == 5
