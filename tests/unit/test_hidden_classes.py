"""hidden_classes: LAS classes left out while drawing (not while reading: io/filters.py), for
plain clouds (a filtered copy made once a set), octrees (nodes filtered as they load) and the
CLI; refused where a cloud cannot leave them out."""

from __future__ import annotations

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.core.cloud import PointCloud
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.errors import GigapointWarning, SettingsError

RED, BLUE = (255, 0, 0), (0, 0, 255)
FIXED = {"point_size": 1, "size_mode": "fixed"}
TOP = gp.Camera.top_down(((0, 0, 0), (100, 50, 1)), 0.5)  # 202x102 pixels, one per half unit, from x -0.5 and y 50.5


def two_classes(spacing: float = 2.5):
    """A grid over 100 x 50: class 2 (red) on the left half, class 6 (blue) on the right; each
    point in the middle of its own pixel of TOP."""
    grid = np.mgrid[0 : int(100 / spacing), 0 : int(50 / spacing)].reshape(2, -1).T * spacing + spacing / 2
    z = np.random.default_rng(0).uniform(0, 1, len(grid))
    xyz = np.c_[grid, z]
    classes = np.where(xyz[:, 0] < 50, 2, 6).astype(np.uint8)
    rgb = np.where(classes[:, None] == 2, RED, BLUE).astype(np.uint8)
    return xyz, rgb, classes


def pixels_of(image, rgb) -> int:
    return int(np.all(image[..., :3] == rgb, axis=-1).sum())


@pytest.mark.parametrize("scale", [None, 0.01], ids=["words", "compact"])
def test_hiding_a_class_draws_exactly_the_other_class_alone(scale):
    xyz, rgb, classes = two_classes()
    cloud = gp.from_arrays(xyz, rgb, classification=classes, scale=scale, colors="rgba")
    ground = classes == 2
    alone = gp.from_arrays(xyz[ground], rgb[ground], classification=classes[ground], scale=scale, colors="rgba")
    everything = gp.render(cloud, TOP, **FIXED)
    assert (pixels_of(everything, RED), pixels_of(everything, BLUE)) == (400, 400)
    hidden = gp.render(cloud, TOP, hidden_classes=(6,), **FIXED)
    assert (pixels_of(hidden, RED), pixels_of(hidden, BLUE)) == (400, 0)
    np.testing.assert_array_equal(hidden, gp.render(alone, TOP, **FIXED))
    # colour modes read the points drawn: classification's colour of class 2 alone, as the cloud of class 2 draws it
    np.testing.assert_array_equal(
        gp.render(cloud, TOP, hidden_classes=(6,), color_mode="classification", **FIXED),
        gp.render(alone, TOP, color_mode="classification", **FIXED),
    )
    # a pixel's point is the one drawn: frame.index into the filtered cloud, point_info its class
    frame = gp.render_frame(cloud, TOP, hidden_classes=(6,), **FIXED)
    picked = frame.index[frame.index >= 0]
    assert len(picked) == 400 and frame.points.n_points == 400
    assert {frame.point_info(int(i))["classification"] for i in picked} == {2}
    kept = cloud.attributes["classification"] == 2  # the drawn cloud's points: those of class 2, in the cloud's order
    np.testing.assert_array_equal(frame.points.positions(), cloud.positions()[kept])


def test_a_hidden_point_in_front_does_not_hide_the_point_behind():
    xyz = np.array([[10.25, 10.25, 0.0], [10.25, 10.25, 1.0]])  # one pixel of TOP; class 6 above (nearer the eye)
    cloud = gp.from_arrays(xyz, np.array([RED, BLUE], np.uint8), classification=np.array([2, 6], np.uint8), colors="rgba")
    row, col = int((50.5 - 10.25) // 0.5), int((10.25 + 0.5) // 0.5)  # TOP's pixel of (10.25, 10.25): rows down from y = 50.5
    assert tuple(gp.render(cloud, TOP, **FIXED)[row, col, :3]) == BLUE
    assert tuple(gp.render(cloud, TOP, hidden_classes=(6,), **FIXED)[row, col, :3]) == RED


def test_toggling_classes_filters_once_a_set_until_the_cloud_changes(monkeypatch):
    xyz, rgb, classes = two_classes()
    cloud = gp.from_arrays(xyz, rgb, classification=classes, colors="rgba")
    filtered = []
    without = PointCloud.without_classes

    def counted(self, hidden):
        filtered.append(tuple(hidden))
        return without(self, hidden)

    monkeypatch.setattr(PointCloud, "without_classes", counted)
    images = [gp.render(cloud, TOP, hidden_classes=h, **FIXED) for h in [(6,), (), (6,), (6,)]]
    assert [(pixels_of(i, RED), pixels_of(i, BLUE)) for i in images] == [(400, 0), (400, 400), (400, 0), (400, 0)]
    assert filtered == [(6,)]
    cloud.set_colors((0, 255, 0), np.flatnonzero(cloud.attributes["classification"] == 2))  # changed: filtered again, in its new colours
    again = gp.render(cloud, TOP, hidden_classes=(6,), **FIXED)
    assert filtered == [(6,), (6,)] and (pixels_of(again, (0, 255, 0)), pixels_of(again, RED)) == (400, 0)
    with pytest.warns(GigapointWarning, match="no point is in view"):  # every class hidden: the background
        assert not gp.render(cloud, TOP, hidden_classes=(2, 6), **FIXED)[..., :3].any()


@pytest.mark.parametrize(("fmt", "options"), [("gigapoint", {"layout": "words"}), ("gigapoint", {}), ("potree", {})], ids=["words", "compact", "potree"])
def test_an_octree_leaves_hidden_classes_out_of_the_nodes_it_loads(tmp_path, fmt, options):
    xyz, rgb, classes = two_classes(spacing=0.5)  # 20 000 points: inner nodes (samples of real points) and leaves
    cloud = gp.from_arrays(xyz, rgb, classification=classes, scale=0.01, colors="rgba")
    gp.convert(cloud, tmp_path / "tree", format=fmt, max_leaf=2_000, **options)
    tree = gp.open(tmp_path / "tree")
    assert len(tree.keys) > 4
    everything = gp.render(tree, TOP, **FIXED)
    red, blue = pixels_of(everything, RED), pixels_of(everything, BLUE)
    assert red > 5_000 and blue > 5_000
    hidden = gp.render(tree, TOP, hidden_classes=(6,), **FIXED)
    assert (pixels_of(hidden, RED), pixels_of(hidden, BLUE)) == (red, 0)  # the nodes drawn are the same, their class 6 left out
    loads = tree.arena.loads
    assert pixels_of(gp.render(tree, TOP, **FIXED), BLUE) == blue and tree.arena.loads > loads  # shown again: reloaded
    with pytest.warns(GigapointWarning, match="no point is in view"):
        assert not gp.render(tree, TOP, hidden_classes=(2, 6), **FIXED)[..., :3].any()


def test_an_octree_spends_the_budget_hidden_classes_leave_on_deeper_nodes(tmp_path):
    xyz, rgb, _ = two_classes(spacing=0.25)  # 80 000 points: a root of 15 601, two nodes of ~20 800, leaves of ~2 850
    classes = np.where(np.random.default_rng(1).permutation(len(xyz)) % 2 == 0, 2, 7).astype(np.uint8)  # half class 7, everywhere
    gp.convert(gp.from_arrays(xyz, rgb, classification=classes, scale=0.01, colors="rgba"), tmp_path / "tree", max_leaf=2_000)
    tree = gp.open(tmp_path / "tree")
    budget = {"point_budget": 40_000, "lod_threshold_px": 0, **FIXED}
    shown = gp.render_frame(tree, TOP, **budget).stats
    assert (shown.batches_rendered, shown.points_processed) == (2, 36_353)  # the root and one node below
    hidden = gp.render_frame(tree, TOP, hidden_classes=(7,), **budget)
    # by their whole counts the same two nodes, half their points drawn (18 125); by their kept
    # points, the nodes not loaded by the half the root kept (test_filtered_budget.py), eleven
    # nodes: the budget of points drawn, in full
    assert (hidden.stats.batches_rendered, hidden.stats.points_processed) == (11, 40_000)
    assert {hidden.point_info(int(i))["classification"] for i in np.unique(hidden.index[hidden.index >= 0])} == {2}


CAMERA = "eye=636590,849216,1100 target=636590,849216,460 up=0,1,0"  # straight down over the survey


def test_render_hidden_classes_draws_what_reading_without_them_draws(cli, tmp_path, autzen_path):
    # classification colours and 30-bit positions: the winner of a pixel is the same point whichever cloud holds it
    same = ("-W", 240, "-H", 160, "--camera", CAMERA, "--color-mode", "classification", "--no-adaptive-precision")
    rc, out, err = cli("render", autzen_path, "-o", tmp_path / "hidden.png", "--index-out", tmp_path / "hidden.npy", "--hidden-classes", "2", *same)
    assert rc == 0, err
    rc, _, err = cli("render", autzen_path, "-o", tmp_path / "dropped.png", "--drop-classes", "2", *same)
    assert rc == 0, err
    from PIL import Image

    hidden, dropped = (np.asarray(Image.open(tmp_path / f"{n}.png")) for n in ("hidden", "dropped"))
    np.testing.assert_array_equal(hidden, dropped)
    assert (hidden[..., :3] != 0).any(axis=-1).sum() > 10_000
    cloud = gp.open(autzen_path)
    index = np.load(tmp_path / "hidden.npy")
    drawn = cloud.without_classes((2,)).attributes["classification"][index[index >= 0]]
    assert len(drawn) > 10_000 and 2 not in set(drawn.tolist()) and 2 in set(cloud.attributes["classification"].tolist())


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ((7, 256), "hidden_classes: 256 is not a LAS class (whole numbers in 0..255), got (7, 256)"),
        ("7,-1", "hidden_classes: -1 is not a LAS class (whole numbers in 0..255), got '7,-1'"),
        ("7,x", "hidden_classes must be LAS classes (whole numbers in 0..255, e.g. 7,18), got '7,x'"),
        ((2.5,), "hidden_classes: 2.5 is not a LAS class (whole numbers in 0..255), got (2.5,)"),
    ],
)
def test_hidden_classes_are_whole_numbers_from_0_to_255(value, message):
    with pytest.raises(SettingsError) as err:
        gp.RenderSettings(hidden_classes=value)
    assert str(err.value) == message
    assert gp.RenderSettings(hidden_classes="18, 7,7").hidden_classes == (7, 18)
    assert gp.RenderSettings(hidden_classes=7).hidden_classes == (7,)


def test_render_hidden_classes_option_names_itself_when_bad(cli, tmp_path, autzen_path):
    rc, _, err = cli("render", autzen_path, "-o", tmp_path / "x.png", "--hidden-classes", "300")
    assert rc == 1 and err == "error: --hidden-classes: 300 is not a LAS class (whole numbers in 0..255), got '300'\n"
    assert not (tmp_path / "x.png").exists()


def test_a_cloud_without_classification_cannot_hide_classes(tmp_path):
    xyz, rgb, _ = two_classes()
    cloud = gp.from_arrays(xyz, rgb, name="plain")
    with pytest.raises(SettingsError) as err:
        gp.render(cloud, TOP, hidden_classes=(7, 18))
    assert str(err.value) == "hidden_classes: plain has no classification attribute, so no class 7,18 to hide"
    gp.convert(cloud, tmp_path / "tree")
    tree = gp.open(tmp_path / "tree")
    with pytest.raises(SettingsError, match=r"^hidden_classes: .* has no classification attribute, so no class 7,18 to hide$"):
        gp.render(tree, TOP, hidden_classes=(7, 18))
    assert gp.render(cloud, TOP, hidden_classes=(), **FIXED).any()  # none hidden: drawn as ever


def test_a_live_cloud_refuses_hidden_classes():
    from gigapoint.live import LiveCloud

    live = LiveCloud(name="scanner")
    xyz, rgb, classes = two_classes()
    live.push(xyz, rgb, classification=classes)
    with pytest.raises(SettingsError) as err:
        gp.render(live, TOP, hidden_classes=(6,))
    assert str(err.value) == (
        "hidden_classes: scanner is a live cloud, which draws every class; leave them out as it reads instead (--drop-classes, drop_classes=)"
    )


# ---------------------------------------------------------------- progressive octrees (KeptChunks)
EVERY = {"point_budget": 10**9, "lod_threshold_px": 0, **FIXED}  # every leaf drawn
VOXELS = {"point_budget": 3_000, "lod_threshold_px": 0, **FIXED}  # the root's voxels alone


def grown(spacing: float = 0.5, **kw):
    """A progressive octree of ``two_classes`` (20 000 points at 0.5: leaves of 2 000 at most
    under inner nodes of voxels)."""
    from gigapoint.lod.progressive import ProgressiveOctree

    xyz, rgb, classes = two_classes(spacing)
    tree = ProgressiveOctree("grown", max_leaf=2_000, **kw)
    tree.add(xyz, rgb, classification=classes)
    assert len(tree.inner_nodes()) > 4
    return tree


def drawn(tree, hidden=(), options=EVERY):
    """The DrawList of a frame of ``tree`` through TOP."""
    with tree.reading():
        return tree.prepare(TOP.view(tree.bounds), gp.RenderSettings(hidden_classes=hidden, **options))


def counting_filters(monkeypatch) -> list:
    """The octree chunks each frame filters (KeptChunks._filter's ``stale``), frame by frame."""
    from gigapoint.lod.progressive.octree import KeptChunks

    filtered, original = [], KeptChunks._filter

    def counted(self, source, stale, drawn):
        filtered.append(sorted(stale.tolist()))
        return original(self, source, stale, drawn)

    monkeypatch.setattr(KeptChunks, "_filter", counted)
    return filtered


@pytest.mark.parametrize("entries", ["leaves", "voxels"])
def test_a_progressive_octree_leaves_hidden_classes_out_of_its_leaves_and_voxels(entries):
    tree = grown()
    options = EVERY if entries == "leaves" else VOXELS
    everything = gp.render_frame(tree, TOP, **options)
    red, blue = pixels_of(everything.image, RED), pixels_of(everything.image, BLUE)
    assert red > 3_000 and blue > 3_000
    frame = gp.render_frame(tree, TOP, hidden_classes=(6,), **options)
    # the nodes drawn are the same, their class 6 left out (a voxel by its first point's class)
    assert (pixels_of(frame.image, RED), pixels_of(frame.image, BLUE)) == (red, 0)
    np.testing.assert_array_equal(drawn(tree, (6,), options).nodes, drawn(tree, (), options).nodes)
    picked = [frame.point_info(int(i)) for i in np.unique(frame.index[frame.index >= 0])]
    assert {p["classification"] for p in picked} == {2}
    assert {p["voxel"] for p in picked} == {entries == "voxels"}
    if entries == "leaves":  # every point of class 2, where the plain cloud of class 2 draws it
        xyz, rgb, classes = two_classes(0.5)
        alone = gp.from_arrays(xyz[classes == 2], rgb[classes == 2], colors="rgba")
        np.testing.assert_array_equal(frame.image, gp.render(alone, TOP, **FIXED))
    with pytest.warns(GigapointWarning, match="no point is in view"):  # every class hidden: the background
        assert not gp.render(tree, TOP, hidden_classes=(2, 6), **options)[..., :3].any()


def test_a_progressive_octree_spends_the_budget_hidden_classes_leave_on_deeper_octants():
    from gigapoint.lod.progressive import ProgressiveOctree

    xyz, rgb, _ = two_classes(spacing=0.25)  # 80 000 points: leaves of 550-650 (level 4) under a root of 15 833 voxels
    classes = np.where(np.random.default_rng(1).permutation(len(xyz)) % 2 == 0, 2, 7).astype(np.uint8)  # half class 7, everywhere
    tree = ProgressiveOctree("half", max_leaf=2_000)
    tree.add(xyz, rgb, classification=classes)
    budget = {"point_budget": 40_000, "lod_threshold_px": 0, **FIXED}

    def levels(hidden) -> list:  # how many nodes of each level a frame draws
        return np.bincount(tree.level[drawn(tree, hidden, budget).nodes]).tolist()

    shown = gp.render_frame(tree, TOP, **budget).stats
    assert (shown.batches_rendered, shown.points_processed) == (18, 39_359)  # nothing hidden: the selection of whole counts
    assert levels(()) == [1, 1, 0, 0, 16]
    hidden = gp.render_frame(tree, TOP, hidden_classes=(7,), **budget)
    # by whole counts the same 18 nodes, half their entries drawn (19 574); by the entries kept
    # in the chunks filtered, the others by the share their node or the nearest above it kept
    # (test_filtered_budget.py), 112 leaves: more entries, within the budget of entries drawn
    assert (hidden.stats.batches_rendered, hidden.stats.points_processed) == (113, 38_596)
    assert levels((7,)) == [0, 1, 0, 0, 112]  # (the root's voxels all replaced by those below)
    assert {hidden.point_info(int(i))["classification"] for i in np.unique(hidden.index[hidden.index >= 0])} == {2}
    assert levels(()) == [1, 1, 0, 0, 16]  # shown again: as before anything was hidden


def test_a_hidden_point_in_front_of_a_progressive_octree_does_not_hide_the_point_behind():
    from gigapoint.lod.progressive import ProgressiveOctree

    tree = ProgressiveOctree("two")
    tree.add(np.array([[10.25, 10.25, 0.0], [10.25, 10.25, 1.0]]), np.array([RED, BLUE], np.uint8), classification=np.array([2, 6], np.uint8))
    row, col = int((50.5 - 10.25) // 0.5), int((10.25 + 0.5) // 0.5)  # (TOP's rows down from y = 50.5, columns from x = -0.5)
    assert tuple(gp.render(tree, TOP, **EVERY)[row, col, :3]) == BLUE
    assert tuple(gp.render(tree, TOP, hidden_classes=(6,), **EVERY)[row, col, :3]) == RED


def test_toggling_classes_of_a_progressive_octree_filters_each_chunk_once_a_set(monkeypatch):
    tree = grown()
    filtered = counting_filters(monkeypatch)
    images = [gp.render(tree, TOP, hidden_classes=h, **EVERY) for h in [(6,), (), (6,), (6,)]]
    assert [(pixels_of(i, RED), pixels_of(i, BLUE)) for i in images] == [(10_000, 0), (10_000, 10_000), (10_000, 0), (10_000, 0)]
    chunks = sorted(drawn(tree).selection.ids.tolist())  # the chunks a frame draws: each filtered once
    assert filtered == [chunks]
    assert pixels_of(gp.render(tree, TOP, hidden_classes=(2,), **EVERY), BLUE) == 10_000  # another set: every chunk again
    assert filtered[1:] == [chunks]


def test_chunks_a_later_add_rewrites_are_filtered_again(monkeypatch):
    tree = grown()
    filtered = counting_filters(monkeypatch)
    assert pixels_of(gp.render(tree, TOP, hidden_classes=(6,), **EVERY), BLUE) == 0
    before = tree.pool.batch_version.copy()
    # above two pixels of the red half: one point of class 2 (green), one of class 6 (yellow)
    green, yellow = (0, 255, 0), (255, 255, 0)
    tree.add(np.array([[10.25, 10.25, 1.0], [20.25, 20.25, 1.0]]), np.array([green, yellow], np.uint8), classification=np.array([2, 6], np.uint8))
    image = gp.render(tree, TOP, hidden_classes=(6,), **EVERY)
    assert (pixels_of(image, green), pixels_of(image, yellow), pixels_of(image, RED), pixels_of(image, BLUE)) == (1, 0, 9_999, 0)
    chunks = drawn(tree).selection.ids.tolist()
    rewritten = [c for c in chunks if c >= len(before) or tree.pool.batch_version[c] > before[c]]
    assert len(filtered) == 2 and filtered[1] == sorted(rewritten) and 0 < len(rewritten) < len(chunks)  # those alone


@pytest.mark.filterwarnings("ignore:.*no point is in view")  # (a frame before the first points are in)
def test_a_progressive_load_never_draws_a_hidden_class(tmp_path, monkeypatch):
    from gigapoint.lod.progressive import loader

    xyz, rgb, classes = two_classes(0.25)  # 80 000 points, four a pixel
    gp.from_arrays(xyz, rgb, classification=classes, scale=0.01, colors="rgba").save(tmp_path / "two.las")
    for small in ("SLICE_POINTS", "SLICE_WHILE_DRAWING", "JOIN_WHILE_DRAWING"):  # a load of many insertions, frames between them
        monkeypatch.setattr(loader, small, 2_000)
    tree = gp.open(tmp_path / "two.las", progressive=True)
    partial = 0
    while True:
        loaded = not tree.loading
        held = tree.n_points
        image = gp.render(tree, TOP, hidden_classes=(6,), **EVERY)
        assert pixels_of(image, BLUE) == 0
        partial += 0 < held < len(xyz)
        if loaded:
            break
    assert tree.wait(timeout=60) and tree.n_points == len(xyz)
    assert partial >= 2 and pixels_of(image, RED) == 10_000  # frames drawn while it loaded, the last one every red pixel
    tree.close()


def test_wgpu_draws_a_growing_octree_without_hidden_classes_uploading_only_the_chunks_filtered_again():
    from wgpu_support import wgpu_or_skip

    from gigapoint.backends.numba_cpu import NumbaCpuBackend

    gpu, cpu = wgpu_or_skip(), NumbaCpuBackend()
    tree = grown()
    settings = gp.RenderSettings(hidden_classes=(6,), adaptive_precision=False, **EVERY)
    kept = None
    for x in (10.25, 30.25, 40.25):
        view = TOP.view(tree.bounds)
        with tree.reading():
            draw = tree.prepare(view, settings)
            args = (draw.points, draw.selection, TOP.width, TOP.height, view.near, view.far)
            before = gpu.memory["uploaded"]
            got = np.asarray(gpu.rasterize(*args))
            sent = gpu.memory["uploaded"] - before
            want = cpu.rasterize(*args)
        assert np.count_nonzero(got != want) <= 0.001 * want.size and np.count_nonzero(got != EMPTY_PIXEL) == 10_000  # class 2 alone
        entries = int(draw.points.batches["count"][draw.selection.ids].astype(np.int64).sum())
        if kept is not None:  # a chunk of points and its ancestors' voxel chunks filtered again: those alone sent (~7 kB)
            assert draw.points is kept and 0 < sent < 4 * entries  # (not even every entry's low word: 40 kB)
        kept = draw.points
        tree.add(np.array([[x, 10.25, 1.0]]), np.array([RED], np.uint8), classification=np.array([2], np.uint8))


def test_chunks_a_frame_no_longer_draws_give_their_slots_to_those_it_draws(monkeypatch):
    """Class 7 hidden (no point has it): every chunk kept whole. Small chunks, so the left half's
    chunks fill the slots made for them and the right half's take them back."""
    tree = grown(chunk=64)
    filtered = counting_filters(monkeypatch)
    halves = [gp.Camera.top_down(((x + 0.25, 0.25, 0), (x + 49.75, 49.75, 1)), 0.5) for x in (0, 50, 0)]  # each half's points
    pools = []
    for cam in halves:
        frame = gp.render_frame(tree, cam, hidden_classes=(7,), **EVERY)
        np.testing.assert_array_equal(frame.image, gp.render(tree, cam, **EVERY))  # as drawn without hiding
        assert pixels_of(frame.image, RED) + pixels_of(frame.image, BLUE) == 100 * 100
        pools.append(frame.points)
    left, right, again = filtered
    assert len(left) > 200 and len(right) > 200 and not set(left) & set(right)
    assert pools[0] is pools[1] is pools[2]  # not grown: the right half took back the slots it lacked, from the left half
    free = pools[0].n_chunks - len(left)
    assert set(again) < set(left) and len(again) == len(right) - free  # those filtered again, the rest kept


def test_a_progressive_octrees_memory_counts_the_chunks_it_keeps_without_hidden_classes():
    tree = grown()
    before = tree.memory()
    assert before["kept"] == 0
    frame = gp.render_frame(tree, TOP, hidden_classes=(6,), **EVERY)
    kept = frame.points  # KeptChunks' pool: the 10 000 entries of class 2, a low word and a colour each at least
    mem = tree.memory()
    assert mem["kept"] >= sum(kept.memory().values()) >= 8 * 10_000
    assert tree.nbytes - sum(before.values()) == mem["kept"]
    gp.render(tree, TOP, **EVERY)  # shown again: kept, so hiding them again filters nothing
    assert tree.memory() == mem
    tree.close()
    assert tree.memory()["kept"] == 0
