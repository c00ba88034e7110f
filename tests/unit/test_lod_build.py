"""LOD octree building: keys, exactly-once storage, node bounds, samplers' spacing, color filtering."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial import cKDTree

import gigapoint as gp
from gigapoint.core import PointChunk
from gigapoint.io import demo_arrays
from gigapoint.lod import convert, open_octree
from gigapoint.lod.convert import hooks
from gigapoint.lod.keys import CODE_BITS, key_cube, key_name, key_of, level_of, name_key, point_codes


def _interrupt_after(monkeypatch, n):
    """The conversion stops (KeyboardInterrupt) once it has built ``n`` partitions in a run; None: never."""

    def hook(done):
        if done == n:
            raise KeyboardInterrupt(f"test interrupt after {done} partitions")

    monkeypatch.setattr(hooks, "after_partition_built", hook)


def _mm_chunks(n, seed=0, chunk=40_000):
    """Demo scene points on a millimetre grid (so positions compare exactly after quantization)."""
    xyz, rgba, attrs = demo_arrays(n, seed)
    xyz = np.round(xyz * 1000) / 1000
    return (
        [PointChunk(xyz[s : s + chunk], rgba[s : s + chunk], {k: v[s : s + chunk] for k, v in attrs.items()}) for s in range(0, n, chunk)],
        xyz,
        rgba,
        attrs,
    )


def _all_points(oc):
    xyz, rgba, inten = [], [], []
    for i in range(len(oc.keys)):
        p = oc.node_points(i)
        xyz.append(p["xyz"])
        rgba.append(p["rgba"])
        inten.append(p.get("intensity", np.zeros(len(p["xyz"]), np.uint16)))
    return np.concatenate(xyz), np.concatenate(rgba), np.concatenate(inten)


def _rows(xyz_mm: np.ndarray, rgba_u32: np.ndarray, inten) -> np.ndarray:
    ints = np.floor(xyz_mm * 1000 + 0.5).astype(np.int64)
    rows = np.column_stack([ints, rgba_u32.astype(np.int64), np.asarray(inten, np.int64)])
    return rows[np.lexsort(rows.T[::-1])]


def _checksum(rows: np.ndarray) -> int:
    """Order-independent: sum of a 64-bit mix of every row."""
    h = np.zeros(len(rows), np.uint64)
    with np.errstate(over="ignore"):
        for c in range(rows.shape[1]):
            h = (h ^ rows[:, c].astype(np.uint64)) * np.uint64(0x9E3779B97F4A7C15)
            h ^= h >> np.uint64(29)
        return int(h.sum(dtype=np.uint64))


@pytest.fixture(scope="module")
def grid_tree(tmp_path_factory):
    chunks, xyz, rgba, attrs = _mm_chunks(120_000)
    out = tmp_path_factory.mktemp("lod") / "grid"
    res = convert(chunks, out, sampler="grid", max_leaf=2_000, partition_points=30_000)
    return open_octree(out), res, xyz, rgba, attrs


@pytest.fixture(scope="module")
def poisson_tree(tmp_path_factory):
    chunks, xyz, _, _ = _mm_chunks(60_000, seed=3)
    out = tmp_path_factory.mktemp("lod") / "poisson"
    convert(chunks, out, sampler="poisson", max_leaf=2_000, partition_points=20_000)
    return open_octree(out), xyz


def test_keys_round_trip_and_potree_child_order():
    assert key_name(1) == "r" and name_key("r") == 1
    for name in ("r0", "r7", "r0123", "r7654321"):
        assert key_name(name_key(name)) == name
    assert level_of(np.array([1, 8, 15, name_key("r0123")], np.uint64)).tolist() == [0, 1, 1, 4]
    # child index = x*4 + y*2 + z, as in Potree
    pts = np.array([[0.9, 0.1, 0.1], [0.1, 0.9, 0.1], [0.1, 0.1, 0.9], [0.9, 0.9, 0.9]])
    codes = point_codes(pts, np.zeros(3), 1.0)
    assert [key_name(int(k)) for k in key_of(codes, 1)] == ["r4", "r2", "r1", "r7"]
    mins, edges = key_cube(np.array([name_key("r7"), name_key("r43")], np.uint64), np.zeros(3), 8.0)
    assert mins.tolist() == [[4, 4, 4], [4, 2, 2]] and edges.tolist() == [4, 2]


def test_every_point_stored_exactly_once(grid_tree):
    oc, res, xyz, rgba, attrs = grid_tree
    assert res.points == len(xyz) == oc.n_points == int(oc.nodes["count"].sum())
    got = _rows(*_all_points(oc))
    want = _rows(xyz, rgba.view(np.uint32).reshape(-1), attrs["intensity"])
    assert _checksum(got) == _checksum(want)
    np.testing.assert_array_equal(got, want)


def test_hierarchy_is_consistent_and_leaves_small(grid_tree):
    oc = grid_tree[0]
    keys = oc.keys
    assert keys[0] == 1 and np.all(np.diff(keys.astype(np.float64)) > 0)
    parents = keys[1:] >> np.uint64(3)
    assert np.isin(parents, keys).all()
    leaf = (oc.children < 0).all(axis=1)
    assert oc.nodes["count"][leaf].max() <= 2_000
    assert (oc.nodes["level"] == level_of(keys)).all()
    assert oc.levels.max() >= 3


def test_node_bounds_contain_their_points(grid_tree):
    oc = grid_tree[0]
    cmin, cedge = key_cube(oc.keys, oc.meta["cube_min"], oc.meta["cube_edge"])
    for i in range(len(oc.keys)):
        p = oc.node_points(i)["xyz"]
        if not len(p):
            continue
        rec = oc.nodes[i]
        tol = 1e-6 * oc.meta["cube_edge"]
        assert np.all(p >= rec["bbox_min"] - tol) and np.all(p <= rec["bbox_max"] + tol)
        assert np.all(p >= cmin[i] - tol) and np.all(p <= cmin[i] + cedge[i] + tol), f"node {i} points outside its cube"


def test_grid_sampler_one_point_per_cell(grid_tree):
    oc = grid_tree[0]
    cmin, cedge = key_cube(oc.keys, oc.meta["cube_min"], oc.meta["cube_edge"])
    inner = np.flatnonzero((oc.children >= 0).any(axis=1))
    assert len(inner) > 3
    for i in inner:
        p = oc.node_points(i)["xyz"]
        cells = np.clip(np.floor((p - cmin[i]) / (cedge[i] / 128)).astype(np.int64), 0, 127)
        ids = (cells[:, 0] * 128 + cells[:, 1]) * 128 + cells[:, 2]
        # 30-bit quantization can move a point across a cell border only by ~1e-9 of the node
        assert len(np.unique(ids)) >= len(ids) - 2, f"node {i}: {len(ids) - len(np.unique(ids))} shared cells"


def test_poisson_sampler_respects_spacing(poisson_tree):
    oc, xyz = poisson_tree
    assert oc.n_points == len(xyz)
    spacing = oc.meta["cube_edge"] / 128
    inner = np.flatnonzero((oc.children >= 0).any(axis=1))
    assert len(inner) > 1
    checked = 0
    for i in inner:
        p = oc.node_points(i)["xyz"]
        r = spacing / 2 ** int(oc.nodes["level"][i])
        pairs = cKDTree(p).query_pairs(r * (1 - 1e-6))
        assert not pairs, f"node {i} (level {oc.nodes['level'][i]}): {len(pairs)} pairs closer than {r}"
        checked += len(p)
    assert checked > 1000


def test_grid_color_filtering_averages_the_cell():
    """A root point's color is the mean of every input point in its 128³ root cell."""
    rng = np.random.default_rng(5)
    centres = np.array([[1.0, 1.0, 1.0], [60.0, 20.0, 5.0], [126.0, 126.0, 126.0]])
    xyz = np.concatenate([c + rng.random((3000, 3)) * 0.9 for c in centres])  # each cluster inside one 1-unit cell
    xyz = np.concatenate([xyz, [[0.0, 0.0, 0.0], [128.0, 128.0, 128.0]]])  # corners: cube edge 128 -> root cells of 1
    rgba = rng.integers(0, 256, (len(xyz), 4), dtype=np.uint8)
    rgba[:, 3] = 255
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        convert([PointChunk(xyz, rgba)], f"{d}/o", max_leaf=200)
        oc = open_octree(f"{d}/o")
        root = oc.node_points(0)
        assert oc.levels.max() >= 2
        cells = np.floor(xyz).clip(0, 127).astype(int)
        for pos, color in zip(root["xyz"], root["color"].view(np.uint8).reshape(-1, 4)):
            c = np.floor(pos).clip(0, 127).astype(int)
            members = np.all(cells == c, axis=1)
            expect = rgba[members, :3].astype(float).mean(axis=0)
            assert np.all(np.abs(color[:3] - expect) <= 0.51 + 1e-9), (pos, color, expect, members.sum())
        # and a leaf point keeps its own color
        leaf = int(np.flatnonzero((oc.children < 0).all(axis=1) & (oc.nodes["count"] > 0))[0])
        lp = oc.node_points(leaf)
        np.testing.assert_array_equal(lp["color"], lp["rgba"])


def _assert_same_octree(a, b):
    """The same nodes with the same payloads (the file layout, ``first``, may differ)."""
    np.testing.assert_array_equal(a.keys, b.keys)
    for f in ("count", "level", "bbox_min", "bbox_max"):
        np.testing.assert_array_equal(a.nodes[f], b.nodes[f])
    for i in range(len(a.keys)):
        sa = slice(int(a.nodes["first"][i]), int(a.nodes["first"][i] + a.nodes["count"][i]))
        sb = slice(int(b.nodes["first"][i]), int(b.nodes["first"][i] + b.nodes["count"][i]))
        for k in ("low", "med", "high", "color", "rgba"):
            np.testing.assert_array_equal(a.arrays[k][sa], b.arrays[k][sb])


@pytest.mark.parametrize("sampler", ["grid", "poisson"])
def test_result_does_not_depend_on_partitioning(tmp_path, sampler):
    """Out-of-core partitions and the upper tree give exactly the in-memory octree."""
    chunks = _mm_chunks(50_000, seed=11)[0]
    convert(chunks, tmp_path / "one", sampler=sampler, max_leaf=1_500)
    convert(chunks, tmp_path / "many", sampler=sampler, max_leaf=1_500, partition_points=4_000)
    _assert_same_octree(open_octree(tmp_path / "one"), open_octree(tmp_path / "many"))


def test_degenerate_inputs(tmp_path):
    same = np.tile([[5.0, 6.0, 7.0]], (30_000, 1))
    convert([PointChunk(same)], tmp_path / "same", max_leaf=1_000)
    oc = open_octree(tmp_path / "same")
    assert oc.n_points == 30_000 and int(oc.nodes["count"].sum()) == 30_000
    np.testing.assert_allclose(oc.node_points(len(oc.keys) - 1)["xyz"], same[:1].repeat(oc.nodes["count"][-1], 0))
    convert([PointChunk(np.array([[1.0, 2.0, 3.0]]))], tmp_path / "one")
    assert open_octree(tmp_path / "one").n_points == 1
    flat = np.column_stack([np.arange(5000.0), np.zeros(5000), np.zeros(5000)])  # a line: two degenerate axes
    convert([PointChunk(flat)], tmp_path / "flat", max_leaf=300)
    assert open_octree(tmp_path / "flat").n_points == 5000


def test_invalid_points_skipped_with_warning(tmp_path):
    from gigapoint.errors import EmptyCloudError, GigapointWarning

    xyz = np.array([[0.0, 0, 0], [np.nan, 0, 0], [1.0, 1, 1], [np.inf, 0, 0]])
    with pytest.warns(GigapointWarning, match="skipped 2 invalid"):
        res = convert([PointChunk(xyz)], tmp_path / "o")
    assert res.points == 2 and res.skipped == 2
    with pytest.raises(EmptyCloudError, match="no valid points"):
        convert([PointChunk(np.full((3, 3), np.nan))], tmp_path / "o2")
    bad = tmp_path / "bad.npy"  # a file's warning names the file, as a render's does (it said "bad")
    np.save(bad, xyz)
    with pytest.warns(GigapointWarning, match=f"^{re.escape(str(bad))}: skipped 2 invalid points"):
        convert(bad, tmp_path / "o3")
    one = tmp_path / "one.npy"  # (one skipped: said in the singular)
    np.save(one, xyz[:3])
    with pytest.warns(GigapointWarning, match=f"^{re.escape(str(one))}: skipped 1 invalid point \\("):
        convert(one, tmp_path / "o4")


def test_dense_spot_is_split_below_the_count_grid(tmp_path, monkeypatch):
    """A spot denser than the budget inside one 128³ count cell is re-partitioned at deeper levels."""
    import json

    rng = np.random.default_rng(2)
    xyz = np.concatenate([rng.random((5_000, 3)) * 1000, 500 + rng.random((35_000, 3)) * 0.5])
    xyz = np.round(xyz * 1000) / 1000
    rgba = rng.integers(0, 256, (len(xyz), 4), dtype=np.uint8)
    chunks = [PointChunk(xyz[s : s + 10_000], rgba[s : s + 10_000]) for s in range(0, len(xyz), 10_000)]
    _interrupt_after(monkeypatch, 1)
    with pytest.raises(KeyboardInterrupt):
        convert(chunks, tmp_path / "many", max_leaf=1_000, partition_points=4_000)
    state = json.loads((tmp_path / "many" / ".partial" / "state.json").read_text())
    levels = [p[0] for p in state["partitions"]]
    assert max(levels) > 7 and max(state["part_counts"]) <= 4_000
    _interrupt_after(monkeypatch, None)
    convert(chunks, tmp_path / "many", max_leaf=1_000, partition_points=4_000)  # not resumable (chunks): starts clean
    convert(chunks, tmp_path / "one", max_leaf=1_000)
    a, b = open_octree(tmp_path / "one"), open_octree(tmp_path / "many")
    np.testing.assert_array_equal(a.keys, b.keys)
    np.testing.assert_array_equal(a.nodes["count"], b.nodes["count"])
    assert (
        _checksum(_rows(*_all_points(a)))
        == _checksum(_rows(*_all_points(b)))
        == _checksum(_rows(xyz, rgba.view(np.uint32).reshape(-1), np.zeros(len(xyz))))
    )


def test_a_chunk_generator_converts_streaming_like_a_list(tmp_path, monkeypatch):
    """The procedural demo scene goes straight into convert() (no file): out of core, each chunk
    is spilled before the next is generated, and the octree equals the one from the same chunks
    as a list (held in memory: lod/convert/in_memory.py)."""
    import importlib

    from gigapoint.io import demo_chunks

    in_memory = importlib.import_module("gigapoint.lod.convert.in_memory")

    raw = tmp_path / "gen" / ".partial" / "raw"
    spilled_before = []

    def gen():
        for i, chunk in enumerate(demo_chunks(120_000, seed=4, chunk_size=30_000)):
            spilled_before.append(len(list(raw.glob("c*.xyz.npy"))) if raw.exists() else 0)
            yield chunk

    with monkeypatch.context() as m:
        m.setattr(in_memory, "fits_in_memory", lambda job: False)  # out of core however small
        r = convert(gen(), tmp_path / "gen", max_leaf=2_000, partition_points=50_000)
    assert r.points == 120_000 and spilled_before == [0, 1, 2, 3]  # chunk i is asked for after chunks 0..i-1 are on disk
    held = convert(list(demo_chunks(120_000, seed=4, chunk_size=30_000)), tmp_path / "list", max_leaf=2_000, partition_points=50_000)
    assert held.in_memory and not r.in_memory
    a, b = open_octree(tmp_path / "gen"), open_octree(tmp_path / "list")
    np.testing.assert_array_equal(a.keys, b.keys)
    np.testing.assert_array_equal(a.nodes, b.nodes)
    for k in ("low", "med", "high", "color", "rgba"):
        np.testing.assert_array_equal(a.arrays[k], b.arrays[k])


@pytest.mark.parametrize("sampler", ["grid", "poisson"])
def test_upper_tree_built_in_groups_keeps_the_octree_and_bounds_what_it_holds(tmp_path, monkeypatch, sampler):
    """With many partitions the roots' carried points are joined a group at a time, so the upper
    phase holds about the budget instead of every root's sample, and the octree is exactly the
    one built without partitions."""
    import importlib

    conv = importlib.import_module("gigapoint.lod.convert")  # the module (gigapoint.lod.convert is also the function)
    held = []
    join = conv._Converter._join_roots

    def spy(self, parts, top, dest):
        held.append((top, sum(int(np.load(p / "carry.codes.npy", mmap_mode="r").shape[0]) for p in parts)))
        return join(self, parts, top, dest)

    monkeypatch.setattr(conv._Converter, "_join_roots", spy)
    chunks = _mm_chunks(1_200_000, seed=5, chunk=200_000)[0]  # 16 partitions whose roots carry ~25 k points each
    budget = 100_000
    convert(chunks, tmp_path / "many", sampler=sampler, max_leaf=20_000, partition_points=budget)
    groups = [n for top, n in held if top != 1]
    final = [n for top, n in held if top == 1]
    assert len(groups) >= 2 and len(final) == 1
    assert max(groups + final) <= 1.25 * budget  # the coarsest groups that fit, or the finest possible
    assert final[0] < 0.5 * sum(groups)  # without groups it would hold all of them
    monkeypatch.setattr(conv._Converter, "_join_roots", join)
    convert(chunks, tmp_path / "one", sampler=sampler, max_leaf=20_000)
    _assert_same_octree(open_octree(tmp_path / "one"), open_octree(tmp_path / "many"))


def test_plan_groups_picks_the_coarsest_level_that_fits():
    from gigapoint.lod.convert import _plan_groups

    # eight partitions at level 2 under two level-1 nodes (prefixes 0-3 under 0, 8-11 under 1), 100 points each
    carried = {(2, p): 100 for p in (0, 1, 2, 3, 8, 9, 10, 11)}
    assert _plan_groups(carried, 800) == []  # everything fits at once
    assert _plan_groups(carried, 400) == [[1, 0, [[2, 0], [2, 1], [2, 2], [2, 3]]], [1, 1, [[2, 8], [2, 9], [2, 10], [2, 11]]]]
    carried[(1, 7)] = 50  # a coarser partition stays out of every group
    plan = _plan_groups(carried, 400)
    assert all([1, 7] not in members for _, _, members in plan) and len(plan) == 2


def test_a_frame_draws_node_by_node_in_the_morton_order_of_their_cubes(grid_tree):
    """The arena holds nodes in the order frames first needed them (coarse levels first, then
    finer ones wherever the camera went); a frame draws each node's slots together, nodes in
    the Morton order of their cubes (writes that stay in one part of the image at a time)."""
    import gigapoint as gp

    oc = open_octree(grid_tree[0].path)
    cam = gp.Camera.fit(oc.bounds, view="iso", width=1920, height=1080)
    for budget in (5_000, 30_000, 10**7):  # the arena filled level after level
        gp.render_frame(oc, cam, gp.RenderSettings(backend="cpu", point_budget=budget, lod_threshold_px=20.0))
    draw = oc.prepare(cam.view(oc.bounds), gp.RenderSettings(point_budget=10**7, lod_threshold_px=20.0))
    node_of = {int(s): nd for nd, slots in oc.arena.resident.items() for s in slots}
    node = np.array([node_of[int(s)] for s in draw.selection.ids])
    runs = node[np.r_[True, node[1:] != node[:-1]]]
    assert len(runs) == len(np.unique(node)) > 20  # one run of slots a node
    assert not (np.diff(draw.selection.ids) > 0).all()  # not the arena's order
    position = oc.keys[runs] << (np.uint64(3) * (CODE_BITS - level_of(oc.keys[runs])).astype(np.uint64))
    assert (position[1:] >= position[:-1]).all()


def test_an_iterable_of_what_is_not_a_point_chunk_is_a_one_line_error(tmp_path):
    """convert([cloud], out), or a list of paths and clouds, was an AttributeError ('PointCloud'
    object has no attribute 'xyz') from deep in the read phase. A cloud's long repr is quoted
    cut to 80 characters (errors.one_line_repr)."""
    from gigapoint.errors import InputError

    cloud = gp.from_arrays(np.random.default_rng(0).random((100, 3)))
    for inputs, what in (([cloud], f"inputs[0]: {cloud!r:.77}..."), ([PointChunk(np.zeros((5, 3))), "a.laz", cloud], "inputs[1]: 'a.laz'"), ([5], "inputs[0]: 5")):
        with pytest.raises(InputError) as e:
            convert(inputs, tmp_path / "o")
        assert str(e.value) == f"convert: {what} is neither a path nor a PointChunk (inputs are files and folders, a cloud, or PointChunks)"


@pytest.mark.parametrize("memory_limit", [None, "64M"], ids=["in_memory", "spilled"])
def test_an_empty_file_among_several_is_skipped_as_a_render_skips_it(tmp_path, memory_limit):
    """A folder of tiles with one empty tile rendered (the tile skipped with a warning) but did not
    convert: 'e.npy: NPY array holds no points (0 rows)', exit 1. Alone it is still an error."""
    from gigapoint.errors import EmptyCloudError, GigapointWarning

    a, e = tmp_path / "a.npy", tmp_path / "e.npy"
    np.save(a, np.random.default_rng(0).random((500, 3)))
    np.save(e, np.zeros((0, 3)))
    with pytest.warns(GigapointWarning, match=f"^{re.escape(str(e))}: holds no points, skipped$"):
        res = convert([e, a], tmp_path / "o", memory_limit=memory_limit)
    assert res.points == 500 and open_octree(tmp_path / "o").n_points == 500
    with pytest.raises(EmptyCloudError, match="holds no points"):
        convert([e], tmp_path / "o2", memory_limit=memory_limit)
