"""The progressive octree (lod/progressive): built while points arrive, drawn at any moment.

Against plain numpy: every point added is in exactly one leaf (positions at 30 bits in the
leaf's cube, colours and attributes exact); every inner node holds one voxel per occupied cell
of its 128³ grid with the rounded mean colour of the points in that cell; leaf contents do not
depend on batch size or order; the finished octree renders like a brute-force render and like
a converted octree; a reader drawing while a writer inserts sees consistent frames.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import threading
import time

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.errors import GigapointError, GigapointWarning, InputError, SettingsError
from gigapoint.io import demo_arrays
from gigapoint.lod.keys import CODE_BITS, point_codes
from gigapoint.lod.progressive import ProgressiveOctree
from gigapoint.lod.progressive import kernels as K
from gigapoint.lod.progressive.kernels import GRID_BITS
from gigapoint.lod.progressive.octree import CHUNK
from gigapoint.lod.progressive.octree import MAX_LEAF as MAX_LEAF_DEFAULT

EXACT = gp.RenderSettings(backend="cpu", size_mode="fixed")  # the one-pixel render


@pytest.fixture(scope="module")
def scene():
    xyz, rgba, attrs = demo_arrays(120_000, seed=4)
    return xyz, rgba, attrs


def _cube(xyz):
    """The root cube given up front (as a loader does from LAS headers): the tree is then the
    same whatever the batches (without it, the first batch's bounds set the cube)."""
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    return lo - 0.5, float(np.max(hi - lo)) + 1.0


def _filled(scene, batch=20_000, order=None, max_leaf=3_000, **kw) -> ProgressiveOctree:
    xyz, rgba, attrs = scene
    idx = np.arange(len(xyz)) if order is None else order
    o = ProgressiveOctree("t", max_leaf=max_leaf, cube=_cube(xyz), **kw)
    for s in range(0, len(idx), batch):
        sl = idx[s : s + batch]
        o.add(xyz[sl], rgba[sl], **{a: v[sl] for a, v in attrs.items()})
    return o


@pytest.fixture(scope="module")
def octree(scene):
    return _filled(scene)


def _leaf_points(o: ProgressiveOctree) -> dict:
    """Every leaf's points: positions, u32 colours, attributes (concatenated, leaf by leaf)."""
    slots = np.concatenate([o.node_entries(n) for n in o.leaves()])
    return {"xyz": o.positions(slots), "color": o.pool.color[slots], **{a: v[slots] for a, v in o.attributes.items()}}


def _voxel_keys(o: ProgressiveOctree) -> np.ndarray:
    """The voxel table's keys ((list, cell)), by voxel id; each id once."""
    used = o._hkeys != K.EMPTY_KEY
    keys = np.full(o.n_voxels, K.EMPTY_KEY)
    keys[o._hvals[used]] = o._hkeys[used]
    assert used.sum() == o.n_voxels and (keys != K.EMPTY_KEY).all()
    return keys


def _match(got: np.ndarray, want: np.ndarray, tol: float) -> np.ndarray:
    """For each of ``got``, the index of the point of ``want`` it is (within ``tol``); each used once."""
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(want).query(got, k=1)
    assert len(got) == len(want) and dist.max() <= tol
    assert len(np.unique(idx)) == len(want)  # every point, once: duplicates of the input would show here
    return idx


def test_every_point_is_in_exactly_one_leaf(scene, octree):
    xyz, rgba, attrs = scene
    o = octree
    assert o.n_points == len(xyz)
    assert int(o.count[o.leaves()].sum()) == len(xyz)
    assert all(o.count[n] <= o.max_leaf for n in o.leaves())
    got = _leaf_points(o)
    # a point's position is kept at 30 bits of the cube of the leaf it first landed in (at worst
    # the root's): about a micrometre here, far below the data's millimetres
    tol = np.sqrt(3) * o.edge / 2**30
    match = _match(got["xyz"], xyz, tol)
    np.testing.assert_array_equal(got["color"], rgba.view(np.uint32).reshape(-1)[match])
    for a in ("intensity", "classification"):
        np.testing.assert_array_equal(got[a], attrs[a][match])


def test_leaves_cover_their_cubes_and_inner_nodes_hold_no_points(octree):
    o = octree
    for n in o.leaves():
        p = o.positions(o.node_entries(n))
        assert np.all(p >= o.cmin[n] - 1e-9) and np.all(p <= o.cmin[n] + o.cedge[n] + 1e-9)
    for n in o.inner_nodes():
        kids = o.children[n][o.children[n] >= 0]
        assert len(kids) and np.all(o.level[kids] == o.level[n] + 1)


def test_voxels_are_the_occupied_cells_with_their_mean_colour(scene, octree):
    """... and each voxel's attributes are those of one of its cell's points (its first)."""
    xyz, rgba, attrs = scene
    o = octree
    codes = point_codes(xyz, o.origin, o.edge)
    checked = 0
    for n in o.inner_nodes():
        lev = int(o.level[n])
        prefix = np.uint64(int(o.key[n]) ^ (1 << 3 * lev))
        inside = (codes >> np.uint64(3 * (CODE_BITS - lev))) == prefix
        cl = min(lev + GRID_BITS, CODE_BITS)
        cells = (codes[inside] >> np.uint64(3 * (CODE_BITS - cl))) & np.uint64((1 << 3 * (cl - lev)) - 1)
        uniq, inverse = np.unique(cells, return_inverse=True)
        sums = np.zeros((len(uniq), 4), np.int64)
        np.add.at(sums, inverse, rgba[inside].astype(np.int64))
        cnt = np.bincount(inverse)
        mean = ((sums + (cnt // 2)[:, None]) // cnt[:, None]).astype(np.uint8)
        slots = o.node_entries(n)
        assert len(slots) == len(uniq)  # one voxel per occupied cell
        # each voxel sits at its cell's centre: find its cell from its position
        pos = o.positions(slots)
        ijk = np.floor((pos - o.cmin[n]) / (o.cedge[n] / (1 << (cl - lev)))).astype(np.int64)
        vcell = np.zeros(len(slots), np.uint64)
        for b in range(cl - lev):
            digit = ((ijk[:, 0] >> b) & 1) << 2 | ((ijk[:, 1] >> b) & 1) << 1 | ((ijk[:, 2] >> b) & 1)
            vcell |= digit.astype(np.uint64) << np.uint64(3 * b)
        k = np.searchsorted(uniq, vcell)
        assert np.array_equal(uniq[k], vcell)
        np.testing.assert_array_equal(o.pool.color[slots].view(np.uint8).reshape(-1, 4), mean[k])
        for a, values in attrs.items():  # (cell, value) of the voxel among those of the cell's points
            have = (inverse.astype(np.int64) << 32) | values[inside].astype(np.int64)
            assert np.isin((k.astype(np.int64) << 32) | o.pool.attributes[a][slots].astype(np.int64), have).all(), a
        checked += 1
    assert checked >= 3


@pytest.mark.parametrize("batch, shuffle", [(7_000, False), (50_000, True), (120_000, False)])
def test_leaf_contents_do_not_depend_on_batches_or_order(scene, octree, batch, shuffle):
    order = np.random.default_rng(3).permutation(len(scene[0])) if shuffle else None
    _assert_same_leaves(octree, _filled(scene, batch=batch, order=order))


def _assert_same_leaves(a: ProgressiveOctree, b: ProgressiveOctree, tol: float = 1e-6) -> None:
    """The same leaves (keys) holding the same points (as sets, within ``tol``), and as many voxels."""

    def leaves(o):
        return {int(o.key[n]): o.positions(o.node_entries(n)) for n in o.leaves()}

    la, lb = leaves(a), leaves(b)
    assert la.keys() == lb.keys()
    for key in la:
        _match(la[key], lb[key], tol)
    assert a.n_voxels == b.n_voxels


@pytest.mark.parametrize("max_leaf", [3_000, 20_000])
def test_its_tree_is_the_converters_tree_of_the_same_cube(scene, max_leaf):
    """The contract one LOD builder rests on (issue #18, item 3; docs/lod.md): in the same cube
    and with the same leaf size, the octree grown batch by batch has the nodes the converter's
    split of the sorted codes has (lod/build.split_tree): the same inner nodes, the same leaves,
    each holding the same points. (Every node split holds more than max_leaf points at the end,
    and every node holding more must have split.)"""
    from gigapoint.lod.build import sort_codes, split_tree
    from gigapoint.lod.keys import ROOT_KEY

    xyz, rgba, _ = scene
    origin, edge = _cube(xyz)
    o = _filled((xyz, rgba, {}), batch=7_000, order=np.random.default_rng(5).permutation(len(xyz)), max_leaf=max_leaf)
    codes, order = sort_codes(point_codes(xyz, origin, edge))
    tree = split_tree(codes, ROOT_KEY, max_leaf)
    runs = {int(k): (int(s), int(e)) for k, s, e, leaf in zip(tree.keys, tree.starts, tree.ends, tree.leaf) if leaf and e > s}
    assert {int(o.key[n]) for n in o.leaves()} == set(runs)
    assert {int(o.key[n]) for n in o.inner_nodes()} == {int(k) for k, leaf in zip(tree.keys, tree.leaf) if not leaf}
    assert len(runs) > 4 and sum(e - s for s, e in runs.values()) == len(xyz)
    for n in o.leaves():
        s, e = runs[int(o.key[n])]
        # the same points, at 30 bits in the cube they first landed in: the root's at worst
        _match(o.positions(o.node_entries(n)), xyz[order[s:e]], edge / 2**29)


def test_a_tree_shaped_from_all_the_points_is_the_same_and_spills_none(scene, octree):
    """``expect`` with every point (weight 1) splits up front exactly the leaves the points
    would overflow: the same leaves and voxels as inserting them without it, and no point is
    taken out of a leaf to be inserted again."""
    xyz = scene[0]
    assert octree.spilled > 0
    o = ProgressiveOctree("t", max_leaf=3_000, cube=_cube(xyz))
    assert o.expect(xyz, 1.0) > 0
    assert o.n_points == 0 and o.n_nodes > 1 and not len(o.leaves())  # nodes, all empty
    cam = gp.Camera.fit(octree.bounds, view="iso", width=64, height=48)
    with pytest.warns(GigapointWarning, match="no point is in view"):  # empty nodes draw nothing
        assert not (gp.render_frame(o, cam, EXACT).visibility != EMPTY_PIXEL).any()
    _add_all(o, scene, 20_000)
    assert o.spilled == 0
    _assert_same_leaves(octree, o)


@pytest.mark.parametrize("mode", ["classification", "intensity", "attribute"])
def test_an_attribute_color_mode_before_the_first_points_draws_the_background(mode):
    """Before its first points a progressive cloud knows no attributes: its first frame in
    color_mode classification said "t has no classification attribute (attributes: none)"."""
    o = ProgressiveOctree("t")
    cam = gp.Camera.look_at((0, -10, 5), (0, 0, 0), width=8, height=6)
    settings = EXACT.given(color_mode=mode, color_attribute="intensity" if mode == "attribute" else None)
    with pytest.warns(GigapointWarning, match="holds none"):
        f = gp.render_frame(o, cam, settings)
    assert f.image.reshape(-1, 4).tolist() == [[0, 0, 0, 255]] * 48
    xyz, rgba, attrs = demo_arrays(1_000, seed=4)
    o.add(xyz, rgba, classification=attrs["classification"])  # its attributes now known: one it lacks is named
    with pytest.raises(SettingsError, match="no (intensity attribute|attribute 'intensity')") if mode != "classification" else contextlib.nullcontext():
        gp.render_frame(o, cam, settings)


def test_a_tree_shaped_from_a_sample_holds_every_point_and_spills_few(scene, octree):
    """A sample of every 16th point standing for 16 each: every point in exactly one leaf, no
    leaf over its limit, the voxels the points' cells and colours; a leaf the sample missed or
    underestimated splits as usual. Points outside the cube in the sample are left out, and
    nothing changes without a cube."""
    xyz = scene[0]
    o = ProgressiveOctree("t", max_leaf=3_000, cube=_cube(xyz))
    far = np.array([[1e6, 1e6, 1e6]])
    assert o.expect(np.concatenate([xyz[::16], far]), 16.0) > 0
    _add_all(o, scene, 20_000)
    assert o.spilled < octree.spilled // 4
    test_every_point_is_in_exactly_one_leaf(scene, o)
    test_voxels_are_the_occupied_cells_with_their_mean_colour(scene, o)
    assert ProgressiveOctree("t").expect(xyz, 16.0) == 0  # no cube yet
    for sample, weight, message in ((xyz[:, :2], 16.0, "shape"), (xyz, 0, "weight"), (xyz, float("nan"), "weight"), (xyz, "16", "weight")):
        with pytest.raises(InputError, match=f"t: expect: .*{message}"):
            o.expect(sample, weight)


def test_a_tree_that_holds_points_is_shaped_for_as_many_again(scene):
    """A tree holding the scene, told that as many points again will come (every 4th point,
    4 each: a second snapshot of the same scene): the leaves they would overflow are split now,
    their points moved once to the leaves they end in, none lost; the points then added go
    straight to their leaves (a plain twin spills many times more), and every point is in one
    leaf, twice, with the voxels of their cells."""
    xyz = scene[0]
    o, twin = _filled(scene), _filled(scene)
    before = o.spilled
    assert o.expect(xyz[::4], 4.0) > 0
    moved = o.spilled - before
    assert moved > 0 and o.n_points == len(xyz) and int(o.count[o.leaves()].sum()) == len(xyz)
    _add_all(o, scene, 20_000)
    _add_all(twin, scene, 20_000)
    assert o.spilled - before - moved < (twin.spilled - before) // 4
    assert o.n_points == 2 * len(xyz) and int(o.count[o.leaves()].sum()) == 2 * len(xyz)
    assert o.count[o.leaves()].max() <= o.max_leaf
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(xyz).query(_leaf_points(o)["xyz"], k=1)
    assert dist.max() <= np.sqrt(3) * o.edge / 2**30 and (np.bincount(idx, minlength=len(xyz)) == 2).all()
    test_voxels_are_the_occupied_cells_with_their_mean_colour(scene, o)  # each point twice: the same means


def _add_all(o: ProgressiveOctree, scene, batch: int) -> None:
    xyz, rgba, attrs = scene
    for s in range(0, len(xyz), batch):
        o.add(xyz[s : s + batch], rgba[s : s + batch], **{a: v[s : s + batch] for a, v in attrs.items()})


def test_points_in_the_last_octant_of_an_odd_node_reach_a_leaf():
    """Routing bounded child 7's codes by (prefix << 3 | 8): for an odd prefix that is the node's
    first code, so the last octant of every odd node lost its points (a snapshot's first batch
    kept 635 422 of 1 048 576); the last child now takes the rest of its parent's run."""
    xyz = np.array([[0.9, 0.9, 0.9], [0.95, 0.95, 0.95], [0.97, 0.99, 0.98], [0.1, 0.1, 0.1]])
    o = ProgressiveOctree("corner", cube=(np.zeros(3), 1.0), max_leaf=1)
    o.add(xyz)
    leaves = o.leaves()
    assert int(o.count[leaves].sum()) == len(xyz) == o.points
    _match(np.concatenate([o.positions(o.node_entries(n)) for n in leaves]), xyz, 1e-6)


@pytest.mark.parametrize("n", [1, 2, 1_000, 70_000])
def test_a_set_is_sorted_by_its_full_codes_whatever_its_ties(n):
    """A set is sorted as keys of (code prefix, index); points whose prefixes tie (a few, or a
    dense cluster in a wide cube) come in full-code order, their colours with them."""
    from gigapoint.lod.progressive import kernels as K

    rng = np.random.default_rng(5)
    codes = rng.integers(0, 1 << 63, n, dtype=np.uint64)
    codes[: n // 2] &= ~np.uint64((1 << 40) - 1)  # a cluster: its prefixes tie beyond insertion sort's runs
    codes[n // 4 : n // 3] = codes[0]  # equal codes
    rgba = rng.integers(0, 1 << 32, n, dtype=np.uint64).astype(np.uint32)
    bits = max(1, (n - 1).bit_length())
    keys = np.empty(n, np.uint64)
    K.sort_keys(codes, bits, keys)
    keys.sort()
    order, sorted_codes, sorted_rgba = np.empty(n, np.int64), np.empty(n, np.uint64), np.empty(n, np.uint32)
    K.code_order(keys, codes, rgba, bits, order, sorted_codes, sorted_rgba)
    assert np.array_equal(np.sort(order), np.arange(n))
    assert np.array_equal(sorted_codes, np.sort(codes)) and np.array_equal(codes[order], sorted_codes)
    assert np.array_equal(rgba[order], sorted_rgba)


def test_trimming_frees_the_room_and_the_octree_grows_on_the_same(scene, octree):
    """trim() (when loading ends) gives back the pool's spare chunks and the voxel table; points
    added afterwards land exactly as without it: the same leaves and voxel colours."""
    xyz, rgba, attrs = scene
    half = len(xyz) // 2
    o = ProgressiveOctree("t", max_leaf=3_000, cube=_cube(xyz), capacity=len(xyz) * 4)
    for s in range(0, half, 20_000):
        o.add(xyz[s : s + 20_000], rgba[s : s + 20_000], **{a: v[s : s + 20_000] for a, v in attrs.items()})
    before = o.nbytes
    o.trim()
    assert o.nbytes < before / 2 and o.pool.n_chunks == o._n_chunks
    for s in range(half, len(xyz), 20_000):
        o.add(xyz[s : s + 20_000], rgba[s : s + 20_000], **{a: v[s : s + 20_000] for a, v in attrs.items()})
    assert o.n_points == octree.n_points and o.n_voxels == octree.n_voxels

    def entries(t):
        return {int(t.key[n]): (np.sort(t.pool.color[t.node_entries(n)]), t.positions(t.node_entries(n))) for n in range(t.n_nodes)}

    a, b = entries(o), entries(octree)
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key][0], b[key][0])
        if len(a[key][1]):
            _match(a[key][1], b[key][1], 1e-6)


def test_the_voxel_table_is_presized_from_the_second_batch_and_the_tree_is_the_same(scene, octree):
    """The first batch (the first image waits for it) enters its voxels in a table of its own
    size; the second presizes the table for the expected points, so that it is not rebuilt
    while they come; leaves and voxels are those of an octree that was not presized."""
    xyz, rgba, attrs = scene
    o = ProgressiveOctree("t", max_leaf=3_000, cube=_cube(xyz), capacity=4_000_000)
    presized = 3 * int(4_000_000 * 0.5) // 2  # two thirds full with the voxels of the expected points
    sizes = []
    for s in range(0, len(xyz), 20_000):
        o.add(xyz[s : s + 20_000], rgba[s : s + 20_000], **{a: v[s : s + 20_000] for a, v in attrs.items()})
        sizes.append(len(o._hkeys))
    assert sizes[0] < presized // 8 <= presized <= sizes[1] == sizes[-1]
    _assert_same_leaves(o, octree)
    assert o.n_voxels == octree.n_voxels
    assert np.array_equal(np.sort(_voxel_keys(o)), np.sort(_voxel_keys(octree)))


def test_a_frame_is_drawn_while_the_presized_table_is_filled(scene, monkeypatch):
    """The presized voxel table (0.13 s to fill for 16 M expected points) is made before the
    insertion takes the write lock: a frame drawn meanwhile (the first image, while the loader
    inserts its second slice) does not wait for the fill, and the insertion then enters its
    voxels in that table."""
    import gigapoint.lod.progressive.octree as progressive_octree

    xyz, rgba, attrs = scene
    o = ProgressiveOctree("t", max_leaf=3_000, cube=_cube(xyz), capacity=4_000_000)
    presized = 3 * int(4_000_000 * 0.5) // 2
    made, drawn, real = [], [], progressive_octree._voxel_table

    def voxel_table(size):
        if size >= presized:

            def frame():
                with o.reading():
                    drawn.append(size)

            reader = threading.Thread(target=frame)
            reader.start()
            reader.join(10)  # under the write lock, the frame would wait for the insertion to end
            made.append((size, not reader.is_alive()))
        return real(size)

    monkeypatch.setattr(progressive_octree, "_voxel_table", voxel_table)
    for s in range(0, 60_000, 20_000):
        o.add(xyz[s : s + 20_000], rgba[s : s + 20_000], **{a: v[s : s + 20_000] for a, v in attrs.items()})
    assert len(made) == 1 and made[0][1], made  # made once, and a frame was drawn meanwhile
    assert drawn == [made[0][0]] and len(o._hkeys) == made[0][0]


_UNCACHED_COMPILES = """
import gc
import gigapoint as gp
from numba.core.caching import NullCache
from numba.core.dispatcher import Dispatcher
from gigapoint.io import demo_arrays
from gigapoint.lod.progressive import ProgressiveOctree
xyz, rgba, attrs = demo_arrays(20_000, seed=1)
o = ProgressiveOctree("t", capacity=100_000)
o.add(xyz, rgba, **attrs)
o.add(xyz + 1.0, rgba, **attrs)
cam = gp.Camera.fit(o.bounds, view="iso", width=160, height=120)
gp.render_frame(o, cam, gp.RenderSettings(backend="cpu"))
gp.render_frame(o, cam, gp.RenderSettings(backend="cpu", size_mode="adaptive"))
print([f"{d.py_func.__module__}.{d.py_func.__qualname__}" for d in gc.get_objects()
       if isinstance(d, Dispatcher) and d.signatures and isinstance(d._cache, NullCache)])
"""


def test_a_new_process_inserts_and_draws_with_nothing_compiled_that_numba_cannot_cache():
    """The first image waits for every compilation of its process: inserting and drawing must use
    cached kernels only (numba's typed List made in Python compiled its methods in every process,
    0.2 s of the first insertion). The first process fills numba's cache where it is empty (a
    kernel compiled there compiles numba's own helpers too); the second must compile nothing."""
    import subprocess
    import sys

    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", _UNCACHED_COMPILES], capture_output=True, text=True, timeout=600)
        assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "[]"


_FORK_AFTER_LOADING = """
import multiprocessing, sys
import numba, numpy as np
import gigapoint as gp
np.save(sys.argv[1], np.random.default_rng(0).random((20_000, 3)))
cloud = gp.open(sys.argv[1], progressive=True)
assert cloud.wait(timeout=300) and cloud.n_points == 20_000
process = multiprocessing.get_context("fork").Process(target=print, args=("child",))
process.start()
process.join(60)
print(numba.threading_layer(), process.exitcode)
"""


def test_a_process_forked_after_a_progressive_load_gets_a_sound_tbb(tmp_path):
    """The loader thread's first kernel started numba's threads: TBB shuts them down before a
    fork only from the thread that started them, so every fork of the main thread afterwards
    (ffmpeg for ``gigapoint render --turntable``, multiprocessing) printed "Numba: Attempted to
    fork from a non-main thread, the TBB library may be in an invalid state in the child
    process." The thread that opens the octree starts them."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _FORK_AFTER_LOADING, str(tmp_path / "p.npy")], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    layer, exitcode = out.stdout.split()[-2:]
    if layer != "tbb":
        pytest.skip(f"numba's threading layer is {layer}: the check is TBB's")
    assert exitcode == "0" and "Attempted to fork" not in out.stderr, out.stderr[-2000:]


def test_trim_cuts_the_pool_in_place_and_growth_copies_it_once(scene, octree):
    """trim() keeps the pool's arrays (views of their used part: the room cut off was never
    written), so loading ends without copying the pool; a pool that runs out of chunks grows its
    streams by the same factor, so the next points need no second copy; the leaves are the same."""
    xyz, rgba, attrs = scene
    o = ProgressiveOctree("t", max_leaf=3_000, cube=_cube(xyz), capacity=len(xyz) * 4)
    o.add(xyz, rgba, **attrs)
    low, ext = o.pool.low, o.pool.ext
    o.trim()
    assert np.shares_memory(o.pool.low, low) and np.shares_memory(o.pool.ext, ext)
    assert o.pool.n_chunks == o._n_chunks and o.pool.n_streams == o._streams_in_use()
    small = ProgressiveOctree("t", max_leaf=3_000, cube=_cube(xyz))
    grown = []
    for s in range(0, len(xyz), 20_000):
        pool = small.pool
        small.add(xyz[s : s + 20_000], rgba[s : s + 20_000], **{a: v[s : s + 20_000] for a, v in attrs.items()})
        if pool is not None and small.pool is not pool:
            grown.append((small.pool.n_chunks / pool.n_chunks, small.pool.n_streams / pool.n_streams))
    assert grown and all(abs(c - st) < 0.01 or st >= c for c, st in grown)  # streams never grow less than chunks
    keys = [{int(t.key[n]): int(t.count[n]) for n in t.leaves()} for t in (small, octree)]
    assert keys[0] == keys[1] and small.n_voxels == octree.n_voxels


def test_trimmed_memory_is_the_points_and_voxels_in_the_compact_layout(scene, octree):
    """Once trimmed, a point takes its low word, 60 stream bits, colour and attributes; a voxel its
    low word, colour and attributes (no other position words, no build state); beyond them only
    the chunks' unfilled tails, the batch records and the nodes."""
    xyz, rgba, attrs = scene
    o = _filled(scene, max_leaf=MAX_LEAF_DEFAULT, capacity=len(xyz))
    cam = gp.Camera.fit(o.bounds, view="iso", width=160, height=120)
    every_point = EXACT.replace(point_budget=60_000, lod_threshold_px=0.0)  # no leaf drawn as its grid sample
    before = gp.render_frame(o, cam, every_point)
    lit = before.visibility != EMPTY_PIXEL
    won_before = o.positions((before.visibility[lit] & np.uint64(0xFFFFFFFF)).astype(np.int64))  # each pixel's point
    o.trim()
    mem = o.memory()
    assert mem["voxels"] == 0  # colour sums, keys, slots and table dropped
    extra = sum(v.dtype.itemsize for v in attrs.values())
    entries = (4 + 4 + extra) * (o.n_points + o.n_voxels) + 7.5 * o.n_points
    lists = np.count_nonzero(o.list_count[: o.n_nodes * 8])
    tails = lists * CHUNK * (4 + 4 + extra + 8)  # at most a chunk's room a list
    assert o.nbytes <= entries + tails + mem["nodes"] + mem["batches"]
    assert o.nbytes / o.n_points <= 1.3 * (16 + extra) + 8 * o.n_voxels / o.n_points  # was 19 + 32 bytes a voxel more
    # the same depths once trimmed (its leaves' points reordered: the same points), and the same
    # colour wherever the same point wins a pixel (where two tie in depth, the first in the pool
    # wins: not always the same one now)
    after = gp.render_frame(o, cam, every_point)
    np.testing.assert_array_equal(after.visibility >> np.uint64(32), before.visibility >> np.uint64(32))
    won_after = o.positions((after.visibility[lit] & np.uint64(0xFFFFFFFF)).astype(np.int64))
    same = np.all(won_after == won_before, axis=1)
    assert same.mean() > 0.95
    np.testing.assert_array_equal(after.image[lit][same], before.image[lit][same])


def _leaf_rows(o: ProgressiveOctree, node: int):
    """A leaf's entries in list order: cells of its 128³ grid (from the low words), positions, colours, attributes."""
    slots = o.node_entries(node)
    low = o.pool.low[slots]
    cell = ((low >> 3) & 127) | (((low >> 13) & 127) << 7) | (((low >> 23) & 127) << 14)
    return cell, o.positions(slots), o.pool.color[slots], {a: v[slots] for a, v in o.pool.attributes.items()}


def _rows(pos, color, attrs) -> np.ndarray:
    """Each entry's position, colour and attributes as one row of bytes (rows compared as sets)."""
    cols = [pos, color[:, None].astype(np.float64), *(v[:, None].astype(np.float64) for v in attrs.values())]
    return np.ascontiguousarray(np.hstack(cols)).view(np.uint8).reshape(len(pos), -1)


def _assert_leaves_begin_with_their_grid_sample(o: ProgressiveOctree, before: dict) -> None:
    """kernels.order_leaves against numpy: the leaf begins with the first point (in the old
    order) of every occupied cell of its grid, one a cell, and holds the same points after them;
    every point's position, colour and attributes moved as one."""
    for node, (cell, pos, color, attrs) in before.items():
        first = np.unique(cell, return_index=True)[1]
        got = _leaf_rows(o, node)
        k = int(o.grid_sample[node])
        assert k == len(first)
        assert len(np.unique(got[0][:k])) == k and set(got[0][:k].tolist()) == set(cell.tolist())  # one a cell, every cell
        old, new = _rows(pos, color, attrs), _rows(*got[1:])
        np.testing.assert_array_equal(new[:k][np.argsort(got[0][:k])], old[first])  # each cell's first (np.unique: by cell)
        rest = np.setdiff1d(np.arange(len(cell)), first)
        assert sorted(bytes(r) for r in new[k:]) == sorted(bytes(r) for r in old[rest])  # and the others


@pytest.mark.parametrize("max_leaf", [3_000, MAX_LEAF_DEFAULT])
def test_trimmed_leaves_begin_with_one_point_of_each_cell_of_their_grid(scene, max_leaf):
    """trim() (when loading ends) reorders every leaf of more than a chunk so that it begins with
    a sample of one point a cell of its own 128³ grid; points added later to a leaf undo its
    sample (until the next trim), and leaves of one chunk are left alone."""
    xyz, rgba, attrs = scene
    n = len(xyz)  # attributes of every width the kernel moves: 1, 2, 4 and 8 bytes
    attrs = {**attrs, "angle": np.arange(n, dtype=np.float32) * 0.25, "gps_time": np.arange(n) * 1.5 + 1e9}
    half = n // 2
    o = ProgressiveOctree("t", max_leaf=max_leaf, cube=_cube(xyz))
    o.add(xyz[:half], rgba[:half], **{a: v[:half] for a, v in attrs.items()})
    big = [int(n) for n in o.leaves() if o.count[n] > CHUNK]
    assert big and not o.grid_sample.any()
    before = {n: _leaf_rows(o, n) for n in big}
    o.trim()
    _assert_leaves_begin_with_their_grid_sample(o, before)
    assert all(0 < o.grid_sample[n] < o.count[n] for n in big)  # a sample, not every point
    small = [n for n in o.leaves() if o.count[n] <= CHUNK]
    assert not o.grid_sample[small].any()
    counts = o.count.copy()
    o.add(xyz[half:], rgba[half:], **{a: v[half:] for a, v in attrs.items()})
    assert all(not o.leaf[n] or o.count[n] > counts[n] for n in big)  # each took points, or split
    assert not o.grid_sample[big].any()  # so its sample no longer covers its points
    changed = [int(n) for n in o.leaves() if o.count[n] > CHUNK]
    before = {n: _leaf_rows(o, n) for n in changed}
    o.trim()
    _assert_leaves_begin_with_their_grid_sample(o, before)


def test_a_leaf_small_on_screen_draws_its_grid_sample_with_the_footprint_of_its_points(scene):
    """Where a leaf's children would be too small on screen to be drawn (half its projected
    size under the LOD threshold), a trimmed leaf draws its grid sample alone, as a converted
    octree draws an inner node and not its children: fewer points, the same footprint.
    (bench_progressive.py --parts frames: the 8 M town then draws 0.88-1.0x the points of its
    converted octree, 1.13-1.19x before.)"""
    from scipy.ndimage import binary_dilation

    o = _filled(scene, max_leaf=MAX_LEAF_DEFAULT)
    o.trim()
    sample = o.grid_sample.copy()
    for view, threshold in (("iso", 100.0), ("top", 60.0)):  # leaves of 160-230 px: their children's octants under it
        cam = gp.Camera.fit(o.bounds, view=view, width=320, height=200)
        s = EXACT.replace(point_budget=200_000, lod_threshold_px=threshold)
        f = gp.render_frame(o, cam, s)
        o.grid_sample[:] = 0  # every leaf's points
        try:
            g = gp.render_frame(o, cam, s)
        finally:
            o.grid_sample[:] = sample
        assert f.stats.points_processed < 0.8 * g.stats.points_processed
        a = binary_dilation(f.visibility != EMPTY_PIXEL, iterations=2)
        b = binary_dilation(g.visibility != EMPTY_PIXEL, iterations=2)
        assert (a & b).sum() / (a | b).sum() >= 0.95


def test_the_points_per_class_count_every_valid_point_added_by_class(scene):
    """Counted as points go in (the viewer's Classes panel lists the classes held): batch after
    batch, splits and root growth aside (points moved, not added); invalid points and values
    that are no LAS class (a classification widened to int16: -1, 300) are not counted; none
    once the attribute is dropped or the octree closed."""
    xyz, rgba, attrs = scene
    classes = attrs["classification"]
    o = ProgressiveOctree("counted", max_leaf=5_000)  # (leaves split, the root grows: points moved, counted once)
    assert o.class_facts() == {} and not o.points_per_class.any()
    o.add(xyz[:60_000] * 0.5, rgba[:60_000], classification=classes[:60_000])
    o.add(xyz[60_000:], rgba[60_000:], classification=classes[60_000:])
    expected = np.bincount(classes, minlength=256)
    assert np.array_equal(o.points_per_class, expected)
    assert o.class_facts() == {"classes": np.unique(classes).tolist()}
    odd = np.array([7, -1, 300, 7, 40], np.int16)  # (widens the octree's classification: -1 and 300 hide nothing)
    bad = xyz[:5].copy()
    bad[4] = np.nan  # (skipped: its 40 is not counted)
    assert o.add(bad, classification=odd) == 4
    expected[7] += 2
    assert np.array_equal(o.points_per_class, expected) and o.n_points == len(xyz) + 4
    with pytest.warns(GigapointWarning, match="classification not in every file"):
        o.keep_attributes([])  # (a loader's file without classification)
    assert o.class_facts() == {} and not o.points_per_class.any()
    o.close()
    p = ProgressiveOctree("closed")
    p.add(xyz[:1000], classification=classes[:1000])
    p.close()
    assert not p.points_per_class.any()


def test_a_leaf_drawn_as_its_grid_sample_weighs_the_entries_it_keeps_while_classes_are_hidden(scene):
    """With hidden classes, the budget counts what a filtered sample keeps, not its whole size:
    the budget the hidden entries leave draws one more leaf."""
    o = _filled(scene, max_leaf=MAX_LEAF_DEFAULT)
    o.trim()
    cam = gp.Camera.fit(o.bounds, view="iso", width=320, height=200)
    s = EXACT.replace(point_budget=60_000, lod_threshold_px=100.0)  # leaves of 160-230 px: drawn as their samples
    shown = gp.render_frame(o, cam, s).stats
    assert (shown.batches_rendered, shown.points_processed) == (3, 58_519)
    hidden = gp.render_frame(o, cam, s.replace(hidden_classes=(2,)))
    # by the samples' whole sizes the same 3 nodes (39 125 entries of other classes drawn); the
    # samples not yet filtered weighed by the share their nodes' filtered chunks kept (store.kept_shares):
    # 59 413 of the 60 000 (49 784 when they counted whole)
    assert (hidden.stats.batches_rendered, hidden.stats.points_processed) == (4, 59_413)
    assert 2 not in {hidden.point_info(int(i))["classification"] for i in np.unique(hidden.index[hidden.index >= 0])}


def test_voxels_draw_where_the_three_word_layout_drew_them(octree):
    """A voxel is stored as its low word alone, its chunk's box moved half a 1024-cell: drawn at
    30 bits it lands on the pixels of the three-word layout's voxel (its cell's centre in the
    node's cube), as before this layout."""
    from types import SimpleNamespace

    from gigapoint.backends.numba_cpu import NumbaCpuBackend
    from gigapoint.core.compact import full_words
    from gigapoint.core.selection import batch_matrices

    o = octree
    cam = gp.Camera.fit(o.bounds, view="iso", width=240, height=180)
    view = cam.view(o.bounds)
    settings = EXACT.replace(point_budget=30_000, adaptive_precision=False)
    with o.reading():
        draw = o.prepare(view, settings)
        pool, sel = draw.points, draw.selection
        assert o.n_voxels and np.any(o.leaf[pool.chunk_node[sel.ids]] == 0)  # voxels drawn
        med, high = (w.copy() for w in full_words(pool))
        voxel = np.repeat(pool.packing["code"] == 0, pool.chunk)
        med[voxel] = high[voxel] = 0  # the three-word voxel: its cell's centre, nothing under the low word
        node = pool.chunk_node[sel.ids]
        old = SimpleNamespace(name="old", batches=pool.batches, low=pool.low, med=med, high=high, color=pool.color, attributes={},
                              version=None, batch_version=None)  # fmt: skip
        mats = batch_matrices(view.rows, o.cmin[node], o.cmin[node] + o.cedge[node, None])
        cpu = NumbaCpuBackend()
        got = cpu.rasterize(pool, sel, 240, 180, view.near, view.far)
        want = cpu.rasterize(old, type(sel)(sel.ids, sel.bits, mats, sel.projected_px, sel.n_culled), 240, 180, view.near, view.far)
    assert np.count_nonzero(got != EMPTY_PIXEL) > 1000
    # the same entry wins each pixel (depths differ in their last float32 bits: the matrices' rounding)
    assert np.count_nonzero((got & np.uint64(0xFFFFFFFF)) != (want & np.uint64(0xFFFFFFFF))) <= 0.001 * got.size


def test_the_root_grows_to_take_points_outside_it(scene):
    xyz, rgba, _ = scene
    o = ProgressiveOctree("grow", max_leaf=2_000)
    centre = xyz[(xyz[:, 0] < np.median(xyz[:, 0])) & (xyz[:, 1] < np.median(xyz[:, 1]))]
    o.add(centre[:20_000])
    o.add(xyz)  # reaches beyond the first cube on every side
    assert o.n_points == 20_000 + len(xyz)
    assert int(o.count[o.leaves()].sum()) == o.n_points
    got = o.positions(np.concatenate([o.node_entries(n) for n in o.leaves()]))
    want = np.concatenate([centre[:20_000], xyz])
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(got).query(want, k=1)
    assert dist.max() <= np.sqrt(3) * o.edge / 2**30
    # the new root samples every point, those added before it grew too
    root_cells = len(o.node_entries(o.root))
    assert root_cells > 0 and o.level[o.root] == 0


def test_a_point_beyond_the_roots_reach_is_refused_before_the_root_grows(scene):
    """A batch with a point the root cannot grow to take is a one-line InputError that changes
    nothing: the root grew as far as its levels allowed first (a 1 km cube 2**19 times as wide,
    every leaf 19 levels deeper, able to split twice more at most, the voxels of 19 new roots)."""
    xyz, _, _ = scene
    o = ProgressiveOctree("far", max_leaf=2_000)
    o.add(xyz[:50_000])
    before = (o.origin.copy(), o.edge, o.n_nodes, o.n_voxels, o.level[: o.n_nodes].copy())
    with pytest.raises(InputError, match=r"^far: points span more than the octree's 21 levels resolve"):
        o.add(np.array([[1e11, 1e11, 1e11]]))
    assert o.origin.tolist() == before[0].tolist() and (o.edge, o.n_nodes, o.n_voxels) == before[1:4]
    assert o.level[: o.n_nodes].tolist() == before[4].tolist() and o.n_points == 50_000


def test_renders_like_brute_force_at_a_budget_covering_every_point(scene, octree):
    xyz, rgba, attrs = scene
    cloud = gp.from_arrays(xyz, rgba, **attrs)
    cam = gp.Camera.fit(octree.bounds, view="iso", width=320, height=200)
    every = EXACT.replace(point_budget=10**9, lod_threshold_px=0.0)
    f = gp.render_frame(octree, cam, every)
    assert f.stats.points_processed == len(xyz)  # the leaves, no voxel
    ref = gp.render_frame(cloud, cam, EXACT)
    a, b = f.visibility != EMPTY_PIXEL, ref.visibility != EMPTY_PIXEL
    assert (a & b).sum() / (a | b).sum() >= 0.95
    same = np.all(f.image == ref.image, axis=-1)
    assert same.mean() > 0.9


def test_renders_like_a_converted_octree_at_the_same_budget(scene, octree, tmp_path):
    xyz, rgba, attrs = scene
    gp.convert([gp.PointChunk(xyz, rgba, attrs)], tmp_path / "oct", max_leaf=3_000)
    converted = gp.open(tmp_path / "oct")
    from scipy.ndimage import binary_dilation

    for view in ("iso", "top"):
        cam = gp.Camera.fit(octree.bounds, view=view, width=320, height=200)
        s = EXACT.replace(point_budget=40_000)
        f, g = gp.render_frame(octree, cam, s), gp.render_frame(converted, cam, s)
        assert abs(f.stats.points_processed - g.stats.points_processed) <= 0.1 * g.stats.points_processed
        # the same density over the same footprint (the samples themselves differ: voxel centres
        # against sampled points), so compare the footprints: coverage closed over 2-pixel gaps
        a = binary_dilation(f.visibility != EMPTY_PIXEL, iterations=2)
        b = binary_dilation(g.visibility != EMPTY_PIXEL, iterations=2)
        assert (a & b).sum() / (a | b).sum() >= 0.95


def test_adaptive_points_are_sized_like_the_plain_clouds(scene):
    """The default (adaptive) point size comes from the point spacing; the octree's chunks all
    carry their node's cube as box, so it gives the spacing from its voxel grids instead: the
    picture is as solid as the plain cloud's of the same points (not 16-pixel blobs)."""
    xyz, rgba, attrs = scene
    plain = gp.from_arrays(xyz, rgb=rgba)
    cam = gp.Camera.fit(plain.bounds, view="iso", width=320, height=240)
    every = gp.RenderSettings(backend="cpu", point_budget=10**9, lod_threshold_px=0)
    octree = _filled(scene, max_leaf=50_000)  # leaves of many chunks (the default), each with the leaf's cube as box
    lit = [(gp.render_frame(c, cam, every).visibility != EMPTY_PIXEL).mean() for c in (plain, octree)]
    assert lit[0] > 0.2 and abs(lit[1] / lit[0] - 1) < 0.1, lit


def test_a_drawn_child_replaces_its_parents_voxels_of_its_octant(octree):
    """Within the budget; no voxel is drawn where a child of its node is drawn, every chunk once."""
    cam = gp.Camera.fit(octree.bounds, view="iso", width=320, height=200)
    pool = octree.pool
    for budget in (5_000, 30_000, 80_000):
        draw = octree.prepare(cam.view(octree.bounds), EXACT.replace(point_budget=budget))
        chunks = draw.selection.ids
        assert len(np.unique(chunks)) == len(chunks)
        drawn = set(draw.nodes.tolist())
        assert {int(pool.chunk_node[c]) for c in chunks} == drawn
        entries = int(pool.batches["count"][chunks].astype(np.int64).sum())
        assert entries <= max(budget, int(octree.count[octree.root]))
        for c in chunks.tolist():
            node = int(pool.chunk_node[c])
            if octree.leaf[node]:
                continue
            slots = np.arange(c * pool.chunk, c * pool.chunk + int(pool.batches["count"][c]))
            octants = ((octree.positions(slots) - octree.cmin[node]) // (octree.cedge[node] / 2)).astype(int)
            for d in np.unique(octants[:, 0] * 4 + octants[:, 1] * 2 + octants[:, 2]).tolist():
                assert int(octree.children[node, d]) not in drawn


@pytest.mark.parametrize("grid", ["none", "on the grid", "off it midway"])
def test_drawing_while_another_thread_inserts(scene, grid):
    """... with the points on a grid (chunks in their levels' bits), and with a batch off it
    midway (every chunk made wide while frames are drawn)."""
    xyz, rgba, attrs = scene if grid == "none" else _on_grid(scene)
    o = ProgressiveOctree("live", max_leaf=2_000, grid=None if grid == "none" else (_UTM, _MM))
    o.add(xyz[:5_000], rgba[:5_000])
    cam = gp.Camera.fit((xyz.min(axis=0), xyz.max(axis=0)), width=160, height=120)

    def insert():
        for s in range(5_000, len(xyz), 5_000):
            off = 0.37 * _MM if grid == "off it midway" and s == len(xyz) // 2 else 0.0
            o.add(xyz[s : s + 5_000] + off, rgba[s : s + 5_000])

    def draw():
        with o.reading():
            drawn = o.prepare(cam.view(o.bounds), EXACT.replace(point_budget=10**9, lod_threshold_px=0))
            ids = drawn.selection.ids
            b = drawn.points.batches[ids]
            # no torn node: every drawn chunk belongs to a drawn node and is full but the last
            assert len(np.unique(ids)) == len(ids)
            assert int(b["count"].astype(np.int64).sum()) == sum(int(o.count[n]) for n in drawn.nodes)
        f = gp.render_frame(o, cam, EXACT.replace(point_budget=10**9, lod_threshold_px=0))
        assert f.stats.points_processed <= o.n_points  # no point drawn twice (nor a voxel with its points)

    assert _draw_while(insert, draw) >= 3 and o.n_points == len(xyz)
    assert o._narrow == (grid == "on the grid") and (grid != "on the grid" or np.all(_chunk_widths(o)[1] < 20))


def test_n_points_read_during_an_insertion_never_goes_back(scene, monkeypatch):
    """An insertion that splits leaves takes their points out and puts them back: n_points, read
    by other threads without the lock (a HUD, a test), says the count of the last finished one."""
    xyz, rgba, _ = scene
    o = ProgressiveOctree("split", max_leaf=2_000)
    o.add(xyz[:1_900], rgba[:1_900])
    seen = []
    write_sets = ProgressiveOctree._write_sets

    def watched(self, sets, routes):  # (the split leaves' points are out now, back in once written)
        seen.append(self.n_points)
        write_sets(self, sets, routes)

    monkeypatch.setattr(ProgressiveOctree, "_write_sets", watched)
    o.add(xyz[1_900:6_000], rgba[1_900:6_000])  # (the root leaf overflows: split, its 1 900 points spilled)
    assert o.spilled >= 1_900 and seen == [1_900]
    assert o.n_points == len(o) == 6_000


def _draw_while(write, draw) -> int:
    """``write`` in another thread while ``draw`` draws frames, until it ends (three frames at
    least); an exception of ``write`` is raised here. Returns the frames drawn."""
    errors = []

    def run():
        try:
            write()
        except BaseException as exc:  # noqa: BLE001 - raised in the test's thread
            errors.append(exc)

    t = threading.Thread(target=run)
    t.start()
    frames = 0
    while t.is_alive() or frames < 3:
        draw()
        frames += 1
    t.join()
    if errors:
        raise errors[0]
    return frames


def test_drawing_while_another_thread_orders_the_leaves(scene):
    """Leaves are reordered (a grid sample first) a few at a time while frames are drawn: every
    frame, at any moment, draws the same points (the same depth at every pixel as before any
    leaf was ordered): no leaf is seen half moved."""
    o = _filled(scene, max_leaf=3_000)
    cam = gp.Camera.fit(o.bounds, view="iso", width=160, height=120)
    every = EXACT.replace(point_budget=10**9, lod_threshold_px=0)  # every point: no leaf drawn as its sample
    want = gp.render_frame(o, cam, every).visibility >> np.uint64(32)
    before = {int(n): _leaf_rows(o, n) for n in o.leaves() if o.count[n] > CHUNK}

    def order():
        while o.order_leaves(max_points=5_000):  # one or two leaves a call
            pass

    def draw():
        np.testing.assert_array_equal(gp.render_frame(o, cam, every).visibility >> np.uint64(32), want)

    assert _draw_while(order, draw) >= 3
    _assert_leaves_begin_with_their_grid_sample(o, before)


def test_an_empty_first_chunk_does_not_hold_the_load_up():
    """The second chunk waits for the first slice to be in: a source whose first chunk held no
    point inserted no slice, and the load waited for good (wait() timed out, 0 points)."""
    from gigapoint.core.chunk import PointChunk
    from gigapoint.io import demo_chunks
    from gigapoint.lod.progressive import Loader

    def chunks():
        yield PointChunk(np.empty((0, 3)), np.empty((0, 4), np.uint8), {})
        yield from demo_chunks(60_000, chunk_size=20_000)

    o = ProgressiveOctree("empty first")
    o.attach(Loader(o, [("src", chunks)], None).start())
    try:
        assert o.wait(timeout=60) and o.n_points == 60_000
    finally:
        o.close()  # (lets a held-up loader go)


def test_the_second_chunk_is_decoded_once_the_first_is_in(scene, monkeypatch):
    """Decoding holds the GIL (lazrs; the demo generator's kernels): the decoder makes the second
    chunk only once the first is inserted, so the first insertion, and the first image, do not
    wait for it; after that it decodes ahead of the insertions as before."""
    from gigapoint.core.chunk import PointChunk
    from gigapoint.lod.progressive import loader
    from gigapoint.lod.progressive.loader import open_progressive

    monkeypatch.setattr(loader, "SLICE_POINTS", 10_000)  # (chunks of 10 000 each inserted: none joined)
    xyz, rgba, _ = scene
    events = []

    def chunks():
        for k, s in enumerate(range(0, 40_000, 10_000)):
            events.append(f"decoded {k}")
            yield PointChunk(xyz[s : s + 10_000], rgba[s : s + 10_000].view(np.uint8).reshape(-1, 4))

    real_add = ProgressiveOctree.add_read  # (the loader inserts a file's points through add_read)

    def slow_add(self, *args, **kwargs):
        if not self.n_points:
            time.sleep(0.3)  # a slow first insertion: an eager decoder would make chunk 1 meanwhile
        n = real_add(self, *args, **kwargs)
        events.append("inserted")
        return n

    monkeypatch.setattr(ProgressiveOctree, "add_read", slow_add)
    cloud = open_progressive([("chunks", chunks)], 40_000, None, "chunks")
    try:
        cloud.wait(timeout=60)
    finally:
        cloud.close()
    assert events[:3] == ["decoded 0", "inserted", "decoded 1"], events
    assert events.count("inserted") == 4 and cloud.n_points == 0  # closed: its memory freed


def test_frames_and_the_loader_take_turns():
    """SimLOD's schedule: a renderer drawing back to back does not stop the loader (one slice a
    frame at least), and while frames are drawn the loader inserts small slices between them."""
    from gigapoint.lod.progressive.loader import SLICE_WHILE_DRAWING

    cloud = gp.demo(3_000_000, progressive=True)
    try:
        while cloud.n_points == 0:
            cloud.wait(timeout=0.01)
        cam = gp.Camera.fit(cloud.bounds, width=96, height=64)
        seen, deltas = cloud.n_points, []
        for _ in range(2_000):  # tiny frames, back to back: 40 at least, until the loader has inserted 5 slices
            gp.render_frame(cloud, cam, EXACT)
            deltas.append(cloud.n_points - seen)
            seen = cloud.n_points
            if len(deltas) >= 40 and sum(deltas) >= 5 * SLICE_WHILE_DRAWING:
                break
        assert sum(deltas) >= 5 * SLICE_WHILE_DRAWING  # the loader went on while frames were drawn
        assert np.median(deltas) <= SLICE_WHILE_DRAWING  # in small slices, mostly one a frame
    finally:
        cloud.close()


def test_bad_input_is_a_one_line_error():
    o = ProgressiveOctree("bad")
    with pytest.raises(InputError, match="shape"):
        o.add(np.zeros((4, 2)))
    with pytest.raises(InputError, match="rows"):
        o.add(np.zeros((4, 3)), rgb=np.zeros((3, 3), np.uint8))
    assert o.add(np.array([[np.nan, 0, 0], [1, 2, 3.0]])) == 1 and o.skipped == 1
    assert o.add(np.empty((0, 3))) == 0
    # attributes are numbers of at most 8 bytes: a complex one was moved as 8 of its 16 bytes,
    # an object one a TypeError traceback (the plain cloud took all three)
    for values in (np.ones(2, complex), np.array(["a", "b"]), np.array([None, 1])):
        message = f"attribute 'label' has dtype {values.dtype}: attributes are numbers"
        with pytest.raises(InputError, match=f"^bad: {message}"):
            ProgressiveOctree("bad").add(np.zeros((2, 3)), label=values)
        with pytest.raises(InputError, match=f"^arrays: {message}"):
            gp.from_arrays(np.zeros((2, 3)), label=values)
    assert ProgressiveOctree("ok").add(np.zeros((2, 3)), flag=np.ones(2, bool), h=np.ones(2, np.float16)) == 2
    # positions or colours that are not numbers: a ValueError or UFuncTypeError traceback (the colours in from_arrays too)
    with pytest.raises(InputError, match=r"^bad: xyz must hold numbers \(integers or floats\), got dtype <U1$"):  # (parsed "1" as 1.0 too)
        o.add([["a", "b", "c"]])
    with pytest.raises(InputError, match=r"^bad: xyz must have shape \(N, 3\), got \(\)$"):  # (said (1,))
        o.add(None)
    for make in (lambda rgb: o.add(np.zeros((2, 3)), rgb=rgb), lambda rgb: gp.from_arrays(np.zeros((2, 3)), rgb)):
        with pytest.raises(InputError, match=r": colors must be numbers, got dtype <U1$"):
            make([["r", "g", "b"]] * 2)
    assert o.n_points == 1


@pytest.mark.parametrize(
    "kw, problem",
    [
        ({"chunk": 0}, "chunk must be an integer from 16 to 1,048,576 points, got 0"),  # a ZeroDivisionError
        ({"chunk": -5}, "chunk must be an integer from 16 to 1,048,576 points, got -5"),  # an OverflowError
        ({"chunk": 10**9}, "chunk must be an integer from 16 to 1,048,576 points, got 1000000000"),  # a 447 GiB allocation
        ({"capacity": "a"}, "capacity must be an integer >= 0 points, got 'a'"),  # int()'s ValueError
        ({"capacity": -5}, "capacity must be an integer >= 0 points, got -5"),
        ({"cube": 5}, "cube must be (origin x, y, z; edge), got 5"),  # a TypeError
        ({"cube": ((0, 0), 1.0)}, "cube must be (origin x, y, z; edge), got ((0, 0), 1.0)"),
        ({"cube": ((0, 0, 0), -1.0)}, "cube must have a finite origin and a positive finite edge, got ((0, 0, 0), -1.0)"),  # taken
        ({"cube": ((np.nan, 0, 0), 1.0)}, "cube must have a finite origin and a positive finite edge, got ((nan, 0, 0), 1.0)"),
        ({"attributes": 5}, "attributes must be a dict of names and dtypes, got int"),
    ],
)
def test_odd_octree_settings_are_one_line_errors(kw, problem):
    with pytest.raises(InputError, match=f"^bad: {re.escape(problem)}$"):
        ProgressiveOctree("bad", **kw)


@pytest.mark.parametrize("chunk", [16, 100, 5_000])
def test_any_chunk_size_holds_the_same_leaves(scene, octree, chunk):
    _assert_same_leaves(octree, _filled(scene, chunk=chunk), tol=3**0.5 * octree.edge / 2**30)


def test_a_source_without_a_valid_point_ends_as_the_plain_cloud_does(tmp_path, capsys):
    """Every point NaN: ``wait`` raises the plain cloud's one-line EmptyCloudError (the load
    ended quietly with an empty octree, and ``gigapoint render --progressive`` wrote a
    background image and exited 0); a file with some valid points loads them."""
    from gigapoint.cli import main
    from gigapoint.errors import EmptyCloudError

    bad, some = tmp_path / "allnan.xyz", tmp_path / "some.xyz"
    bad.write_text("nan 2 3\nnan 2 3\n")
    some.write_text("1 2 3\nnan 2 3\n4 5 6\n")
    with pytest.raises(EmptyCloudError) as plain:
        gp.open(bad)
    cloud = gp.open(bad, progressive=True)
    with pytest.raises(EmptyCloudError) as progressive:
        cloud.wait()
    assert str(progressive.value) == str(plain.value) == f"{bad}: no valid points (2 invalid points: NaN, inf or beyond ±1e+12)"
    cloud = gp.open(some, progressive=True)
    with pytest.warns(GigapointWarning, match=r"skipped 1 invalid point \("):  # (issued by wait, in this thread)
        assert cloud.wait()
    assert cloud.n_points == 2 and cloud.skipped == 1
    with pytest.raises(EmptyCloudError) as converted:  # the converter named the dataset ("allnan"), not the file
        gp.convert(bad, tmp_path / "tree")
    assert str(converted.value) == str(plain.value) and not (tmp_path / "tree").exists()
    out = tmp_path / "a.png"
    assert main(["render", str(bad), "-o", str(out), "--progressive"]) != 0
    assert not out.exists() and f"error: {bad}: no valid points" in capsys.readouterr().err
    # many such files: the first three named, then '...' (a conversion named every one of them)
    many = [tmp_path / f"nan{i}.xyz" for i in range(5)]
    for f in many:
        f.write_text("nan 2 3\n")
    want = f"{many[0]}, {many[1]}, {many[2]} ...: no valid points (5 invalid points: NaN, inf or beyond ±1e+12)"
    with pytest.raises(EmptyCloudError) as plain:
        gp.open(many)
    cloud = gp.open(many, progressive=True)
    with pytest.raises(EmptyCloudError) as progressive:
        cloud.wait()
    with pytest.raises(EmptyCloudError) as converted:
        gp.convert(many, tmp_path / "tree")
    assert str(plain.value) == str(progressive.value) == str(converted.value) == want


def test_invalid_points_skipped_while_loading_are_warned_of_as_the_plain_cloud_does(tmp_path, capsys):
    """A file with some invalid points: the plain cloud, the converter and ``gigapoint render``
    warn that they were skipped; the progressive load left them out without a word."""
    from gigapoint.cli import main

    some = tmp_path / "some.xyz"
    some.write_text("1 2 3\nnan 2 3\n4 5 6\n")
    cloud = gp.open(some, progressive=True)
    with pytest.warns(GigapointWarning) as caught:  # (issued by wait, in this thread)
        assert cloud.wait(timeout=120)
    assert cloud.n_points == 2
    assert [str(w.message) for w in caught] == [f"{some}: skipped 1 invalid point (NaN, inf or beyond ±1e+12)"]
    out = tmp_path / "a.png"
    assert main(["render", str(some), "-o", str(out), "--progressive", "-W", "32", "-H", "24"]) == 0
    assert f"warning: {some}: skipped 1 invalid point (" in capsys.readouterr().err and out.exists()


def test_add_refuses_unknown_attributes_and_widens_a_dtype_a_batch_does_not_fit():
    """An attribute outside the first add's set is a one-line InputError and changes nothing
    (it was dropped silently); values an attribute's dtype cannot hold widen it to numpy's dtype
    for both, every value kept (they were cast: 1.5 -> 1, 70 000 -> 4 464 in uint16)."""
    o = ProgressiveOctree("attrs")
    xyz = np.array([[0.0, 0, 0], [1, 2, 3], [np.nan, 0, 0]])
    assert o.add(np.full((2, 3), np.nan)) == 0  # no valid point: it fixes no attribute set (then 'intensity' was refused)
    assert o.skipped == 2
    assert o.add(xyz, intensity=np.array([1, 2, 3], np.uint16), height=np.array([0.5, 1.5, 2.5], np.float32)) == 2
    assert o.attribute_names == ("intensity", "height") and o.skipped == 3
    with pytest.raises(InputError, match="'foo' is not one of this cloud's \\(intensity, height\\)"):
        o.add(xyz, foo=np.arange(3))
    assert o.n_points == 2 and o.skipped == 3
    assert o.add(xyz[:2], intensity=np.array([7, 65535], np.int32)) == 2  # int32 into uint16: widened to int32
    assert o.add(xyz[:2], intensity=np.array([70_000, -1]), height=np.array([0.1, 1e300])) == 2  # int64; float64
    assert o.add(xyz[:2], intensity=np.array([1.5, 2.0])) == 2  # a fraction: float64
    assert o.add(xyz[:1]) == 1  # missing ones: 0
    got = _leaf_points(o)
    assert np.asarray(got["intensity"]).dtype == np.float64 and np.asarray(got["height"]).dtype == np.float64
    assert sorted(got["intensity"].tolist()) == sorted([1, 2, 7, 65535, 70_000, -1, 1.5, 2.0, 0])
    want_height = np.concatenate([np.float32([0.5, 1.5]), np.float32([0, 0]), [0.1, 1e300], [0, 0, 0]])
    assert sorted(got["height"].tolist()) == sorted(want_height.tolist())


def test_several_files_keep_the_attributes_they_all_have_in_any_order(tmp_path):
    """As ``gigapoint.open`` of several files: a file without an attribute drops it for all
    points (it was kept and filled with zeros when that file came second, and an attribute only
    a later file had was dropped: the set depended on the order); a list of paths is accepted."""
    import laspy

    def write(path, fmt, seed):
        header = laspy.LasHeader(point_format=fmt, version="1.2")
        header.scales, header.offsets = [0.01] * 3, [0, 0, 0]
        las = laspy.LasData(header)
        rng = np.random.default_rng(seed)
        las.x, las.y, las.z = rng.uniform(0, 100, 3000), rng.uniform(0, 100, 3000), rng.uniform(0, 10, 3000)
        las.intensity = rng.integers(1, 1000, 3000)
        if fmt == 1:
            las.gps_time = rng.uniform(1, 1e5, 3000)
        las.write(str(path))
        return path

    plain_only = write(tmp_path / "a.las", 0, 1)  # no GPS time
    with_time = write(tmp_path / "b.las", 1, 2)
    dropped = r"^2 files: attribute\(s\) gps_time not in every file: left out \(only those all the files have are kept\)$"
    with pytest.warns(GigapointWarning, match=dropped):  # it went without a word, in every route
        want = gp.open(plain_only, with_time)
    with pytest.warns(GigapointWarning, match=dropped):
        assert sorted(gp.open(with_time, plain_only, chunked=True).attributes) == sorted(want.attributes)
    assert "gps_time" not in want.attributes and "intensity" in want.attributes

    for paths in ([plain_only, with_time], [with_time, plain_only]):
        cloud = gp.open(paths, progressive=True)  # one list, as gp.open(a, b)
        with pytest.warns(GigapointWarning, match=dropped):  # (issued by wait, in this thread)
            assert cloud.wait(timeout=120) and cloud.n_points == 6000
        assert sorted(cloud.attributes) == sorted(want.attributes)
        got = _leaf_points(cloud)
        assert sorted(got["intensity"].tolist()) == sorted(np.asarray(want.attributes["intensity"]).tolist())
        cloud.close()
    with pytest.warns(GigapointWarning, match=dropped):
        assert gp.open([plain_only, [with_time]]).n_points == 6000


def test_files_whose_attribute_dtypes_differ_load_as_the_plain_cloud_holds_them(tmp_path, las_writer, loaded):
    """A LAS file's uint16 intensity and a PLY file's float32 one: the plain cloud holds float32
    (numpy's dtype for both), and so does the progressive octree, in either order, every value
    kept (LAS first, the PLY's fractions were cast to uint16 before)."""
    from plyfile import PlyData, PlyElement

    las = las_writer(tmp_path / "a.las", 2_000, seed=1)
    rng = np.random.default_rng(2)
    v = np.zeros(1_500, dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("intensity", "f4")])
    v["x"], v["y"], v["z"], v["intensity"] = rng.uniform(0, 100, 1_500), rng.uniform(0, 100, 1_500), rng.uniform(0, 10, 1_500), rng.uniform(0, 1, 1_500)
    ply = tmp_path / "b.ply"
    PlyData([PlyElement.describe(v, "vertex")]).write(str(ply))
    dropped = (
        "2 files: attribute.s. classification, edge_of_flight_line, gps_time, key_point, number_of_returns, point_source_id, return_number, "
        "scan_angle_rank, scan_direction_flag, synthetic, user_data, withheld not in every file"
    )
    with pytest.warns(GigapointWarning, match=dropped):
        plain = gp.open(las, ply)
    want = np.asarray(plain.attributes["intensity"])
    assert want.dtype == np.float32 and sorted(plain.attributes) == ["intensity"]

    for paths in ((las, ply), (ply, las)):
        with pytest.warns(GigapointWarning, match=dropped):
            cloud = loaded(*paths)
        assert cloud.n_points == 3_500
        got = np.asarray(_leaf_points(cloud)["intensity"])
        assert got.dtype == np.float32 and sorted(cloud.attributes) == ["intensity"]
        np.testing.assert_array_equal(np.sort(got), np.sort(want))
        cloud.close()


def test_an_error_inserting_a_files_points_names_that_file(tmp_path):
    """An error the octree raises inserting a chunk named the octree, "2 files", not the file
    the chunk came from: a second NPZ file whose 'normal' is (N, 3) where the first's is 1-D;
    the first file's points stay drawable."""
    rng = np.random.default_rng(5)
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    np.savez(a, xyz=rng.uniform(0, 10, (500, 3)), normal=rng.random(500).astype(np.float32))
    np.savez(b, xyz=rng.uniform(0, 10, (400, 3)), normal=rng.random((400, 3)).astype(np.float32))
    cloud = gp.open(a, b, progressive=True)
    try:
        with pytest.raises(InputError, match=rf"^{re.escape(str(b))}: attribute 'normal' must be 1-D of length 400, got shape \(400, 3\)$"):
            cloud.wait(timeout=120)
        assert cloud.n_points == 500 and str(cloud.error).startswith(str(b))
    finally:
        cloud.close()


def test_an_empty_octree_draws_nothing_and_a_single_point_draws():
    o = ProgressiveOctree("one")
    cam = gp.Camera.look_at((0, -10, 5), (0, 0, 0), width=32, height=24)
    with pytest.warns(gp.GigapointWarning, match="no point is in view of the camera \\(it holds none"):
        assert gp.render_frame(o, cam, EXACT).stats.visible_pixels == 0
    o.add(np.array([[0.0, 0.0, 0.0]]), rgb=np.array([[255, 0, 0]], np.uint8))
    f = gp.render_frame(o, cam, EXACT)
    assert f.stats.visible_pixels == 1 and f.stats.points_processed == 1


def test_a_first_batch_of_one_point_leaves_the_root_room_to_grow(tmp_path):
    """The first batch's extent made the root cube, 2e-11 wide for one point: the root then grew
    its CODE_BITS levels to 4e-5 and any point farther away was refused ("points span more than
    the octree's 21 levels resolve"): an add() of one point, then of others a metre away; or
    ``gp.open`` of files without header bounds whose first file holds one point."""
    xyz = np.array([[636000.0, 848000.0, 400.0], [636001.0, 848000.0, 400.0], [646000.0, 849000.0, 420.0]])
    rgb = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], np.uint8)
    o = ProgressiveOctree("one")
    assert o.add(xyz[:1], rgb=rgb[:1], intensity=np.array([7], np.uint16)) == 1
    assert o.add(xyz[1:], rgb=rgb[1:], intensity=np.array([8, 9], np.uint16)) == 2
    assert o.points == 3 and o.bounds[1].tolist() == [646000.0, 849000.0, 420.0]
    held = _leaf_points(o)
    order = np.argsort(held["intensity"])
    np.testing.assert_allclose(held["xyz"][order], xyz, atol=1e-3)
    assert held["color"][order].tolist() == np.c_[rgb, np.full(3, 255, np.uint8)].view(np.uint32).ravel().tolist()
    (tmp_path / "one.xyz").write_text("10 20 30\n")
    np.savetxt(tmp_path / "many.xyz", np.random.default_rng(0).random((1000, 3)) * 100)
    files = [tmp_path / "one.xyz", tmp_path / "many.xyz"]
    cloud = gp.open(files, progressive=True)
    assert cloud.wait(timeout=120) and cloud.points == gp.open(files).n_points == 1001
    cam = gp.Camera.fit(cloud.bounds, view="top", width=64, height=48)
    assert gp.render_frame(cloud, cam, EXACT.replace(point_budget=10**9, lod_threshold_px=0)).stats.points_processed == 1001


def test_open_progressive_loads_several_files_in_the_background(tmp_path, las_writer):
    a = las_writer(tmp_path / "a.las", 60_000, seed=1)
    b = las_writer(tmp_path / "b.las", 40_000, seed=2)
    cloud = gp.open(a, b, progressive=True)
    assert cloud.wait(timeout=120)
    assert cloud.progress == 1.0 and not cloud.loading and cloud.error is None
    assert repr(cloud).endswith(" voxels)")
    plain = gp.open(a, b)
    assert cloud.n_points == plain.n_points == 100_000
    assert sorted(cloud.attributes) == sorted(plain.attributes)
    cam = gp.Camera.fit(plain.bounds, view="top", width=200, height=150)
    every = EXACT.replace(point_budget=10**9, lod_threshold_px=0)
    x = gp.render_frame(cloud, cam, every).visibility != EMPTY_PIXEL
    y = gp.render_frame(plain, cam, every).visibility != EMPTY_PIXEL
    assert (x & y).sum() / (x | y).sum() >= 0.95
    cloud.close()


def test_a_source_failing_part_way_keeps_what_was_loaded():
    """A file found corrupt part-way (here: a source that raises after two chunks): what was
    loaded stays drawable, the error is one line naming the file, wait() raises it, no hang."""
    from gigapoint.io import demo_chunks
    from gigapoint.lod.progressive import Loader

    def chunks():
        for i, chunk in enumerate(demo_chunks(90_000, chunk_size=30_000)):
            if i == 2:
                raise InputError("tiles/b.laz: corrupt LAZ chunk 2 (lazrs: invalid data)")
            yield chunk

    o = ProgressiveOctree("failing")
    o.attach(Loader(o, [("tiles/b.laz", chunks)], 90_000).start())
    with pytest.raises(GigapointError) as err:
        o.wait(timeout=60)
    assert "tiles/b.laz" in str(err.value) and "\n" not in str(err.value)
    assert o.n_points == 60_000 and o.error is not None and o.progress == pytest.approx(60_000 / 90_000)
    assert repr(o) == f"ProgressiveOctree('failing', 60,000 points, {o.n_nodes} nodes, {o.n_voxels:,} voxels, loading stopped: {err.value})"
    cam = gp.Camera.fit(o.bounds, width=64, height=48)
    assert gp.render_frame(o, cam, EXACT).stats.visible_pixels > 0


def test_gigapoint_view_says_on_the_terminal_that_loading_stopped(tmp_path, capsys, monkeypatch):
    """``gigapoint view`` of a file found bad part-way went on serving the points before the bad
    line, and only the viewer's HUD said why: the terminal showed "0 points" and the URL. It
    prints the one-line error too (the viewer keeps serving what was loaded)."""
    import threading

    from gigapoint.cli import main
    from gigapoint.viewer.server import ViewerServer

    xyz = np.round(np.random.default_rng(5).random((2_000, 3)) * 100, 3)
    lines = [f"{x},{y},{z}\n" for x, y, z in xyz]
    lines[1_500] = "garbage,line\n"
    path = tmp_path / "mid.csv"
    path.write_text("x,y,z\n" + "".join(lines))

    def serve_until_loaded(self):  # instead of serving until Ctrl+C
        with contextlib.suppress(GigapointError):
            self.core.cloud.wait(60)
        for thread in threading.enumerate():
            if thread.name == "gigapoint-load-report":
                thread.join(10)

    monkeypatch.setattr(ViewerServer, "serve_forever", serve_until_loaded)
    assert main(["view", str(path), "--progressive", "--no-browser"]) == 0
    err = capsys.readouterr().err
    assert f"warning: loading stopped: {path}: line 1502 has 2 columns, expected 3; showing the 1,500 points loaded\n" in err, err


def test_a_text_file_bad_part_way_keeps_the_points_before_its_bad_line(tmp_path):
    """The text reader parsed a chunk of lines (a million) whole: a bad line 150 000 lines in lost
    them all, so a progressive load of a 200 000-line CSV kept nothing. Now the lines before the
    bad one come first, then the one-line error."""
    from gigapoint.io import read_chunks

    xyz = np.round(np.random.default_rng(5).random((2_000, 3)) * 100, 3)
    lines = [f"{x},{y},{z}\n" for x, y, z in xyz]
    lines[1_500] = "garbage,line\n"
    path = tmp_path / "mid.csv"
    path.write_text("x,y,z\n" + "".join(lines))
    got = []
    with pytest.raises(InputError, match=r"mid.csv: line 1502 has 2 columns, expected 3$"):
        for chunk in read_chunks(path, chunk_size=1_000):
            got.append(chunk.xyz)
    np.testing.assert_array_equal(np.concatenate(got), xyz[:1_500])  # 1 000, then the 500 before the bad line
    cloud = gp.open(path, progressive=True)
    with pytest.raises(InputError, match="line 1502"):
        cloud.wait(60)
    assert cloud.n_points == 1_500
    with pytest.raises(InputError, match="line 1502"):
        gp.open(path)  # a plain cloud is still all or nothing
    cloud.close()


def test_the_repr_says_how_far_loading_is():
    from gigapoint.io import demo_chunks
    from gigapoint.lod.progressive import Loader

    go = threading.Event()

    def chunks():
        for i, chunk in enumerate(demo_chunks(90_000, chunk_size=30_000)):
            if i == 1:
                go.wait(60)
            yield chunk

    o = ProgressiveOctree("slow")
    o.attach(Loader(o, [("slow.las", chunks)], 90_000).start())
    deadline = time.monotonic() + 60
    while o.n_points < 30_000 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert repr(o).endswith(", loading: 33% read)")
    go.set()
    assert o.wait(60) and repr(o).endswith(" voxels)")
    o.close()
    assert repr(o) == "ProgressiveOctree('slow', 0 points, 0 nodes, 0 voxels, closed)"


def test_a_one_node_octree_reads_one_node():
    o = ProgressiveOctree("tiny")
    o.add(np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]]))
    assert repr(o) == "ProgressiveOctree('tiny', 2 points, 1 node, 0 voxels)"


def test_loading_stops_at_its_memory_limit_and_keeps_what_it_holds():
    """A source larger than memory allows: the loader stops once the octree holds
    ``memory_limit`` bytes (one line saying where and why), and what it holds draws."""
    from gigapoint.errors import MemoryLimitError

    for bad, match in ((-5, "below the 16M minimum"), (1 << 20, "below the 16M minimum"), ("lots", "cannot read 'lots'")):
        with pytest.raises(InputError, match=f"^memory_limit: .*{match}"):  # said before anything is read
            gp.demo(50_000_000, progressive=True, memory_limit=bad)
    cloud = gp.demo(50_000_000, progressive=True, memory_limit="40M")
    with pytest.raises(MemoryLimitError) as err:
        cloud.wait(timeout=120)
    msg = str(err.value)
    assert "\n" not in msg and "demo(50,000,000): loading stopped at" in msg and "of 50,000,000 points" in msg
    assert re.search(r"the octree holds \d+\.\d MiB, its memory limit \(40\.0 MiB;", msg), msg  # was "0.0 GiB ... (0.0 GiB"
    assert 0 < cloud.n_points < 50_000_000 and cloud.progress < 1
    # one slice at most beyond the limit, and a pool step: far below the 50 M points' ~1.5 GB
    assert cloud.nbytes < 200 << 20
    cam = gp.Camera.fit(cloud.bounds, width=64, height=48)
    assert gp.render_frame(cloud, cam, EXACT).stats.visible_pixels > 0
    cloud.close()


def test_a_billion_point_input_allocates_for_what_it_holds_not_its_total():
    """The pool is presized from the header's total only up to a bound: a 10^9-point input
    draws its first points at once instead of allocating tens of GB first."""
    import time

    t = time.perf_counter()
    cloud = gp.demo(10**9, progressive=True)
    try:
        while cloud.n_points == 0 and time.perf_counter() - t < 60:
            time.sleep(0.01)
        assert cloud.n_points > 0
        assert cloud.nbytes < 2 << 30
    finally:
        cloud.close()


@pytest.mark.timeout(120)  # (it hung for good)
def test_an_error_inserting_the_first_slice_ends_the_load_instead_of_hanging(monkeypatch):
    """The decoder waits for the first slice to be in before it decodes the second; an error
    inserting that slice left the loader waiting for the decoder and the decoder for the slice:
    wait() never returned (a LAS header's zero bounds did it)."""
    def refuse(self, *args, **kwargs):
        time.sleep(0.3)  # as an insertion takes: the decoder is then waiting for it (at once, its turn was cancelled)
        raise InputError(f"{self.name}: refused on purpose")

    monkeypatch.setattr(ProgressiveOctree, "add_read", refuse)
    cloud = gp.demo(3_000_000, progressive=True)
    with pytest.raises(InputError, match=r"^demo\(3,000,000\): refused on purpose$"):
        cloud.wait(timeout=60)
    cloud.loader._thread.join(10)
    assert cloud.loader.done and not cloud.loader._thread.is_alive()
    cloud.close()


@pytest.mark.timeout(120)  # (it hung for good)
@pytest.mark.parametrize("mins, maxs", [((0, 0, 0), (0, 0, 0)), ((-1e12,) * 3, (1e12,) * 3), ((5, 5, 5), (1, 1, 1))])
def test_a_headers_wrong_bounds_do_not_spoil_the_octree(tmp_path, las_writer, mins, maxs):
    """A LAS header's bounds make the root cube up front: zeros (some writers) hung the load
    (the points spanned more levels than the octree has, then the hang above), 1e12 (beyond what
    its integers reach) drew the points 25 % off. Bounds the points cannot have are left out, and
    a cube that misses the first points is started again from them."""
    import struct

    path = las_writer(tmp_path / "h.las", 30_000, seed=4)
    data = bytearray(path.read_bytes())
    struct.pack_into("<6d", data, 179, maxs[0], mins[0], maxs[1], mins[1], maxs[2], mins[2])  # max x, min x, max y, ...
    path.write_bytes(bytes(data))
    plain = gp.open(path)
    cloud = gp.open(path, progressive=True)
    assert cloud.wait(timeout=60) and cloud.n_points == plain.n_points
    cam = gp.Camera.fit_cloud(plain, width=160, height=120)
    a = gp.render_frame(plain, cam, EXACT).visibility != EMPTY_PIXEL
    b = gp.render_frame(cloud, cam, EXACT.replace(point_budget=10**9, lod_threshold_px=0)).visibility != EMPTY_PIXEL
    assert (a & b).sum() / (a | b).sum() >= 0.97
    assert int(cloud.level[: cloud.n_nodes].max()) <= 6  # a root of the points' size, not of the header's


def test_a_file_cut_off_shows_the_points_before_the_cut(tmp_path, las_writer):
    """A LAS file cut off was refused at open, nothing of it drawn: its points before the cut
    load (exactly the file's first ones), then the error says where it ends. The plain cloud
    still refuses it; ``gigapoint render`` says the error and writes no image; ``gigapoint view``
    of a file this small (under the point budget) loads it progressively, to draw those points."""
    import laspy

    from gigapoint.lod.progressive import open_sized

    full = las_writer(tmp_path / "full.las", 50_000, seed=2)
    data = full.read_bytes()
    bad = tmp_path / "b.las"
    bad.write_bytes(data[:-300_000])
    record = laspy.open(full).header.point_format.size
    fits = (len(data) - 300_000 - laspy.open(full).header.offset_to_point_data) // record
    with pytest.raises(GigapointError, match="b.las: truncated"):
        gp.open(bad)
    cloud = gp.open(bad, progressive=True)
    with pytest.raises(GigapointError, match=rf"b\.las: truncated LAS file: the header claims 50,000 points, only {fits:,} could be read"):
        cloud.wait(60)
    assert 0 < cloud.n_points == fits
    f = laspy.read(full)
    expected = np.c_[f.x, f.y, f.z][:fits]
    got = cloud._all_points()[0]  # (chunks() and save() refuse a load that ended in an error)
    np.testing.assert_allclose(got[np.lexsort(got.T)], expected[np.lexsort(expected.T)], atol=1e-6)
    cloud.close()
    assert isinstance(open_sized([bad], point_budget=10**9), ProgressiveOctree)
    out = tmp_path / "b.png"
    result = _cli("render", bad, "-o", out)
    assert result.returncode == 1 and "b.las: truncated LAS file: the header claims" in result.stderr and not out.exists()


def test_closing_mid_load_stops_the_loader_and_frees_memory():
    cloud = gp.demo(3_000_000, progressive=True)
    for bad in ("1", float("nan"), True):  # "1" was a TypeError of the comparison inside
        with pytest.raises(InputError, match=r"^demo\(3,000,000\): wait: timeout must be a number of seconds or None, got "):
            cloud.wait(bad)
    assert cloud.wait(0) in (True, False)
    cloud.close()
    assert not cloud.loader._thread.is_alive()
    assert cloud.progress < 1.0  # (a load closed part-way said 1.0, as one read to the end)
    assert cloud.pool is None and cloud.n_points == 0


@pytest.mark.timeout(180)  # (render's wait loop, on wait() alone, would spin for good)
def test_a_load_closed_part_way_does_not_count_as_finished(tmp_path, monkeypatch):
    """wait() said True after a close part-way, as though every point were read: save() went on
    (a close from another thread between its wait and its check saved part of the input as the
    whole), and ``gigapoint render`` drew the freed octree."""
    from gigapoint.cli import render_cmd

    cloud = gp.demo(50_000_000, progressive=True)
    while cloud.n_points == 0:
        cloud.wait(timeout=0.01)
    cloud.loader.close()  # the loader stopped, the octree not freed yet: a close() under way in another thread
    assert cloud.n_points > 0 and cloud.wait() is False and cloud.wait(timeout=1) is False
    with pytest.raises(InputError, match=r"^demo\(50,000,000\): the octree is closed \(its points were freed\); open it again to save it$"):
        cloud.save(tmp_path / "part")
    assert not (tmp_path / "part").exists()
    cloud.close()
    assert cloud.wait() is False

    def closed_while_read(*args, **kwargs):
        loading = gp.demo(50_000_000, progressive=True)
        threading.Timer(0.5, loading.close).start()
        return loading

    monkeypatch.setattr(render_cmd, "open_files", closed_while_read)
    stopped = r"^demo\(50,000,000\): loading was stopped before every point was read \(the octree was closed\)$"
    with pytest.raises(GigapointError, match=stopped):
        render_cmd.open_inputs(["unused"], 1_000)


def test_the_viewer_redraws_while_it_loads_and_says_how_far():
    import time

    from gigapoint.io import demo_chunks
    from gigapoint.lod.progressive import Loader
    from gigapoint.viewer.protocol import unpack_frame
    from gigapoint.viewer.session import ViewerCore

    def slow():  # a source that takes about 1.5 s: frames are drawn while it loads
        for chunk in demo_chunks(200_000, chunk_size=20_000):
            time.sleep(0.15)
            yield chunk

    cloud = ProgressiveOctree("slow")
    cloud.attach(Loader(cloud, [("slow", slow)], 200_000).start())
    while cloud.n_points == 0:
        time.sleep(0.01)
    core = ViewerCore(cloud)
    headers = []

    def send(kind, payload):
        if kind == "bytes":
            headers.append(unpack_frame(payload)[0])
        return True

    core.open_session(send, 96, 64)
    try:
        assert core.watcher is not None
        cloud.wait(timeout=60)
        assert core.watcher.finished.wait(10)
        time.sleep(0.5)  # the last redraw
        notes = [h["note"] for h in headers]
        assert any(n.startswith("loading: ") and "M points/s" in n for n in notes)
        assert notes[-1].startswith("loaded 200,000 points") and headers[-1]["points_total"] == 200_000
        assert len({h["points_total"] for h in headers}) >= 3  # frames of a growing cloud
        assert 0 < headers[0]["load_progress"] < 1 and headers[-1]["load_progress"] == 1
    finally:
        core.close_all()


@pytest.mark.gpu
@pytest.mark.parametrize(
    "page_chunks",
    [
        None,
        8,  # several pages: a page's streams are handed out as the pool fills (wgpu context.in_place_ext_ranges)
    ],
)
def test_wgpu_draws_the_growing_octree_uploading_only_what_changed(scene, page_chunks):
    """The pool is in the compact layout: its point chunks' streams are uploaded as they change
    too, also where the pool spans several GPU pages (``page_chunks`` chunks a page). With the
    changed chunks' runs each sent on its own (merge gap 0) only they are sent; with the
    default gap, runs close together go as one write: fewer writes, the bytes between them
    added, the same image."""
    from wgpu_support import wgpu_or_skip

    from gigapoint.backends.numba_cpu import NumbaCpuBackend

    options = {} if page_chunks is None else {"page_bytes": 2 * page_chunks * CHUNK * 4, "memory_budget": 1 << 30}
    gpu, merged = wgpu_or_skip(**options), wgpu_or_skip(**options)
    gpu.ctx.cache.merge_gap_bytes = 0
    cpu = NumbaCpuBackend()
    xyz, rgba, _ = scene
    strips = np.argsort(xyz[:, 0], kind="stable")  # arriving strip by strip, as a scan does: a batch changes its part of the tree
    xyz, rgba = xyz[strips], rgba[strips]
    o = ProgressiveOctree("gpu", max_leaf=3_000, cube=_cube(xyz), capacity=4 * len(xyz))  # a pool that need not grow (small leaves: many voxels)
    cam = gp.Camera.fit((xyz.min(axis=0), xyz.max(axis=0)), view="iso", width=200, height=150)
    s = EXACT.replace(point_budget=10**9, lod_threshold_px=0, adaptive_precision=False)  # all three words of every point
    pool = None
    for k, start in enumerate(range(0, len(xyz), 40_000)):
        o.add(xyz[start : start + 40_000], rgba[start : start + 40_000])
        view = cam.view(o.bounds)
        with o.reading():
            draw = o.prepare(view, s)
            args = (draw.points, draw.selection, 200, 150, view.near, view.far)
            before, merged_before = gpu.memory, merged.memory
            got = np.asarray(gpu.rasterize(*args))
            sent = gpu.memory["uploaded"] - before["uploaded"]
            np.testing.assert_array_equal(np.asarray(merged.rasterize(*args)), got)
            want = cpu.rasterize(*args)
        assert np.count_nonzero(got != want) <= 0.001 * want.size
        if k:  # a batch rewrites part of the pool: the rest stays on the GPU
            assert draw.points is pool
            assert 0 < sent < 0.8 * 4 * 4 * int(draw.points.batches["count"].astype(np.int64).sum())
            writes = gpu.memory["refresh_writes"] - before["refresh_writes"]
            merged_writes = merged.memory["refresh_writes"] - merged_before["refresh_writes"]
            assert 0 < merged_writes < writes
            merged_sent = merged.memory["uploaded"] - merged_before["uploaded"]
            assert sent <= merged_sent <= sent + writes * merged.ctx.cache.merge_gap_bytes  # at most a gap a merge
        pool = draw.points


_UTM = np.array([500_000.0, 4_000_000.0, 100.0])  # a LAS file's offset: coordinates of UTM size
_MM = 0.001


def _on_grid(scene, shifted: float = 0.0, every: int = 0):
    """The scene on a millimetre grid through _UTM (as a LAS file holds it); every ``every``-th
    point moved ``shifted`` grid steps off it along each axis (another file's grid)."""
    xyz, rgba, attrs = scene
    xyz = _UTM + np.round(xyz / _MM) * _MM
    if every:
        xyz[::every] += shifted * _MM
    return xyz, rgba, attrs


def _grid_filled(points, batch: int = 20_000, rounds=(slice(None),)) -> ProgressiveOctree:
    xyz, rgba, attrs = points
    o = ProgressiveOctree("grid", max_leaf=3_000, grid=(_UTM, _MM))
    for part in rounds:
        idx = np.arange(len(xyz))[part]
        for s in range(0, len(idx), batch):
            sl = idx[s : s + batch]
            o.add(xyz[sl], rgba[sl], **{a: v[sl] for a, v in attrs.items()})
        o.trim()
    return o


def _off_grid(xyz) -> np.ndarray:
    """How far each point is off the millimetre grid through _UTM, in steps (its worst axis)."""
    steps = (xyz - _UTM) / _MM
    return np.abs(steps - np.round(steps)).max(axis=1)


def _grid_rows(xyz) -> np.ndarray:
    """Points as integer steps of the millimetre grid through _UTM, sorted (a set with repeats)."""
    rows = np.round((xyz - _UTM) / _MM).astype(np.int64)
    return rows[np.lexsort(rows.T)]


def _chunk_widths(o: ProgressiveOctree) -> tuple[np.ndarray, np.ndarray]:
    """(point chunks in use, the stream bits an axis each holds)."""
    pool = o.pool
    used = np.flatnonzero((pool.packing["code"] != 0) & (pool.batches["count"] > 0))
    return used, (pool.packing["code"][used] & 0xFF).astype(np.int64)


def test_trim_keeps_points_on_the_source_grid_in_the_bits_it_needs(scene):
    """With the source's grid (a LAS file's offset and scale) the root cube is 2^B grid steps,
    aligned to the grid, and trim rewrites every point chunk in the compact layout with the bits
    its node's cube needs (B - level - 10 an axis, not 20): its stream is that much smaller,
    each point is its source coordinate again (the cell centre, where quantizing and spilling
    had moved it by a few 30-bit cells), and frames draw the same image."""
    from gigapoint.core.compact import stream_words

    xyz, rgba, attrs = points = _on_grid(scene)
    o = _grid_filled(points, rounds=())
    for s in range(0, len(xyz), 20_000):
        o.add(xyz[s : s + 20_000], rgba[s : s + 20_000], **{a: v[s : s + 20_000] for a, v in attrs.items()})
    steps = (o.origin - _UTM) / _MM + 0.5
    bits = int(np.log2(o.edge / _MM))
    assert o.edge == 2.0**bits * _MM and np.abs(steps - np.round(steps)).max() < 1e-6 and np.all(o.origin <= xyz.min(axis=0))
    cam = gp.Camera.fit(o.bounds, view="iso", width=200, height=150)
    every = EXACT.replace(point_budget=10**9, lod_threshold_px=0)
    o.order_leaves()  # as trim does first: the image compared below is of the same order
    wide_image = gp.render_frame(o, cam, every).image
    wide_bytes, wide_words = 8 * o.pool.stream * int(np.count_nonzero(o.pool.packing["code"][: o._n_chunks])), o.pool.low.copy()
    o.trim()
    used, e = _chunk_widths(o)
    assert len(used) and np.array_equal(e, bits - o.level[o.pool.chunk_node[used]] - 10)  # every chunk compact, as its cube needs
    counts = o.pool.batches["count"].astype(np.int64)
    assert o.pool.ext.nbytes == 8 * int(stream_words(3 * (o.pool.packing["code"] & 0xFF).astype(np.int64), counts).sum())
    assert o.pool.ext.nbytes < 0.4 * wide_bytes
    np.testing.assert_array_equal(o.pool.low, wide_words[: len(o.pool.low)])  # the low words stay (trim cuts the room off)
    leaf_points = _leaf_points(o)
    got = leaf_points["xyz"]
    idx = _match(got, xyz, 1e-3 * _MM)  # each point its own source coordinate (30-bit cell centres: ~1e-4 of a step)
    np.testing.assert_array_equal(np.round((got - _UTM) / _MM), np.round((xyz[idx] - _UTM) / _MM))
    for a, v in attrs.items():  # attributes in their real range (core/attributes.py), read back as they were
        np.testing.assert_array_equal(leaf_points[a], v[idx])
        assert o.attributes[a].dtype == v.dtype
    assert o.memory()["attributes"] == o.attributes.nbytes
    np.testing.assert_array_equal(gp.render_frame(o, cam, every).image, wide_image)


def test_points_on_the_grid_are_written_in_the_bits_their_leaves_need_while_the_octree_fills(scene):
    """With the source's grid, points go into chunks of B - level - 10 bits an axis as they come
    (kernels.write_points writes each as its grid cell), not 60 bits to be packed at trim: the
    tree is the one the same points build without a grid, every point is its grid point exactly
    while the octree fills (spilled points too), and ordering leaves moves each point whole."""
    xyz, rgba, attrs = points = _on_grid(scene)
    o = _grid_filled(points, rounds=())
    for s in range(0, len(xyz), 20_000):
        o.add(xyz[s : s + 20_000], rgba[s : s + 20_000], **{a: v[s : s + 20_000] for a, v in attrs.items()})
    wide = ProgressiveOctree("wide", max_leaf=3_000, cube=(o.origin, o.edge))  # the same cube, no grid: wide chunks
    for s in range(0, len(xyz), 20_000):
        wide.add(xyz[s : s + 20_000], rgba[s : s + 20_000], **{a: v[s : s + 20_000] for a, v in attrs.items()})
    assert o._narrow and not o._packed and o.spilled > 10_000  # (points spilled from split leaves: written again)
    used, e = _chunk_widths(o)
    bits = int(np.log2(o.edge / _MM))
    assert len(used) and np.array_equal(e, bits - o.level[o.pool.chunk_node[used]] - 10)
    assert o._n_words < 0.4 * wide._n_words
    assert {int(o.key[n]): int(o.count[n]) for n in o.leaves()} == {int(wide.key[n]): int(wide.count[n]) for n in wide.leaves()}
    assert o.n_voxels == wide.n_voxels
    got = _leaf_points(o)
    assert _off_grid(got["xyz"]).max() < 1e-3
    np.testing.assert_array_equal(_grid_rows(got["xyz"]), _grid_rows(xyz))
    idx = _match(got["xyz"], xyz, 1e-3 * _MM)
    np.testing.assert_array_equal(got["color"], rgba.view(np.uint32).reshape(-1)[idx])
    big = [int(n) for n in o.leaves() if o.count[n] > CHUNK]
    before = {n: _leaf_rows(o, n) for n in big}
    o.order_leaves()
    _assert_leaves_begin_with_their_grid_sample(o, before)


def test_points_off_the_source_grid_keep_their_chunks_wide(scene):
    """A chunk holding a point off the grid (another file's offset: 0.37 of a step) stays wide,
    60 bits a point, and its points where they were; the other chunks are compact."""
    xyz, rgba, attrs = points = _on_grid(scene, shifted=0.37, every=997)
    o = _grid_filled(points)
    used, e = _chunk_widths(o)
    pos = o.positions(np.concatenate([np.arange(c * CHUNK, c * CHUNK + o.pool.batches["count"][c]) for c in used]))
    owner = np.repeat(used, o.pool.batches["count"][used].astype(np.int64))
    frac = (pos - _UTM) / _MM
    off = np.abs(frac - np.round(frac)).max(axis=1) > 0.1
    shifted_chunks = np.unique(owner[off])
    assert off.sum() == len(range(0, len(xyz), 997))
    assert set(used[e == 20]) == set(shifted_chunks) and np.all(e[~np.isin(used, shifted_chunks)] < 20)
    _match(_leaf_points(o)["xyz"], xyz, 2e-3 * _MM)  # the wide ones as quantized: within a few 30-bit cells of the root


def test_a_grid_step_far_wider_than_the_points_spread_finds_them_off_it():
    """Points a metre apart on a 10 km 'grid' were within GRID_TOLERANCE of one node: on the grid,
    and written there. The snap must stay within float64 rounding of the points' size."""
    from gigapoint.core.compact import GRID_TOLERANCE

    xyz = np.asarray(_UTM) + np.random.default_rng(3).uniform(0, 1, (2_000, 3))
    assert not K.on_grid(xyz, np.asarray(_UTM, np.float64), 1e4, GRID_TOLERANCE)
    on = np.asarray(_UTM) + np.random.default_rng(3).integers(0, 10**6, (2_000, 3)) * _MM  # a LAS file's millimetres
    assert K.on_grid(on, np.asarray(_UTM, np.float64), _MM, GRID_TOLERANCE)


def test_points_added_after_trim_build_the_same_octree_and_a_point_off_the_grid_widens_it(scene):
    """An ``add`` after a trim writes on: points on the grid into chunks of their levels' bits
    (each stream given room for a whole chunk again), and the octree ends as one filled without
    a trim between; a point off the grid then makes every chunk wide (their points the cell
    centres), itself kept where it was."""
    points = _on_grid(scene)
    half = len(points[0]) // 2
    twice = _grid_filled(points, rounds=(slice(0, half), slice(half, None)))
    once = _grid_filled(points)
    used, e = _chunk_widths(twice)
    assert np.all(e < 20) and twice._packed
    assert twice.n_nodes == once.n_nodes and twice.n_voxels == once.n_voxels
    for o in (twice, once):
        assert o.n_points == len(points[0])
    a, b = _leaf_points(twice), _leaf_points(once)
    for name in a:
        order_a = np.lexsort(np.column_stack([a["xyz"], a["color"]]).T)
        order_b = np.lexsort(np.column_stack([b["xyz"], b["color"]]).T)
        np.testing.assert_allclose(a[name][order_a], b[name][order_b], atol=1e-3 * _MM, rtol=0)
    assert twice.expect(points[0][::10], 40.0) > 0 and not twice._packed  # shaping the tree splits leaves: unpacked first
    _match(_leaf_points(twice)["xyz"], points[0], 1e-3 * _MM)
    twice.trim()
    twice.add(points[0][:10], points[1][:10], **{k: v[:10] for k, v in points[2].items()})
    assert not twice._packed and twice._narrow and np.all(_chunk_widths(twice)[1] < 20)
    np.testing.assert_array_equal(_grid_rows(_leaf_points(twice)["xyz"]), _grid_rows(np.concatenate([points[0], points[0][:10]])))
    off = points[0][:10] + 0.37 * _MM  # another file's grid
    twice.add(off, points[1][:10], **{k: v[:10] for k, v in points[2].items()})
    assert not twice._narrow and np.all(twice.pool.packing["code"][twice.pool.packing["code"] != 0] == 20 | 20 << 8 | 20 << 16)
    got = _leaf_points(twice)["xyz"]
    np.testing.assert_array_equal(_grid_rows(got[_off_grid(got) < 0.1]), _grid_rows(np.concatenate([points[0], points[0][:10]])))
    np.testing.assert_array_equal(_grid_rows(got[_off_grid(got) >= 0.1] - 0.37 * _MM), _grid_rows(points[0][:10]))  # (as quantized)


def test_a_las_file_loads_into_its_own_grid(tmp_path, las_writer):
    """gigapoint.open(..., progressive=True) of a LAS file takes its grid from the header (offset,
    scale): once loaded, each point chunk holds the bits the file's millimetres need, and every
    point is the file's."""
    import laspy

    f = las_writer(tmp_path / "a.las", 80_000, seed=3)
    cloud = gp.open(f, progressive=True)
    cloud.wait(timeout=120)
    las = laspy.read(str(f))
    assert cloud.grid is not None and cloud.grid[1] == 0.001 and np.array_equal(cloud.grid[0], las.header.offsets)
    _, e = _chunk_widths(cloud)
    assert len(e) and np.all(e < 20)
    xyz = np.column_stack([las.x, las.y, las.z])
    chunks = list(cloud.chunks())
    got = np.concatenate([c.xyz for c in chunks])
    idx = _match(got, xyz, 1e-6)
    np.testing.assert_array_equal(np.round(got / 0.001), np.round(xyz[idx] / 0.001))
    for name in ("intensity", "classification", "return_number", "gps_time", "point_source_id"):  # packed: held in their range
        np.testing.assert_array_equal(np.concatenate([c.attributes[name] for c in chunks]), np.asarray(las[name])[idx])
    held = cloud.attributes
    n = cloud.pool.n_points  # entries: points, voxels and the chunks' room
    assert held.nbytes_of("return_number") == held.nbytes_of("gps_time") == 0 and held.nbytes_of("intensity") == 2 * n  # one value each
    info = cloud.pool.point_info(int(cloud.node_entries(cloud.leaves()[0])[0]))
    assert info["return_number"] == las.return_number[0] and isinstance(info["intensity"], int)
    cloud.save(tmp_path / "saved.copc.laz", format="copc")  # the packed pool read leaf by leaf
    saved = laspy.read(str(tmp_path / "saved.copc.laz"))
    assert len(saved.points) == len(las.points)
    for name in ("X", "Y", "Z", "intensity", "classification"):
        np.testing.assert_array_equal(np.sort(np.asarray(saved[name])), np.sort(np.asarray(las[name])))
    cloud.close()


def test_attributes_are_held_in_their_range_while_the_octree_fills(scene):
    """While points come, each attribute is held as the values so far need (core/attributes.py
    holder_for: one value, an integer range in a narrow dtype, else its dtype), widened where a
    batch does not fit: a constant costs nothing while loading, and every point (and voxel)
    keeps its values exactly, through trim and later adds."""
    xyz, rgba, _ = scene
    n = len(xyz)
    rng = np.random.default_rng(5)
    first_half = np.arange(n) < n // 2
    attrs = {
        "source": np.full(n, 7, np.uint16),  # one value throughout
        "intensity": np.where(first_half, rng.integers(100, 300, n), rng.integers(0, 60_000, n)).astype(np.uint16),
        "time": np.where(np.arange(n) < n // 3, 5.0, rng.random(n) * 1e6),  # one value, then many
        "offset": rng.integers(-70_000, -69_900, n).astype(np.int32),  # a byte's range, far from 0
    }
    o = ProgressiveOctree("t", max_leaf=3_000, cube=_cube(xyz))
    forms = []
    for s in range(0, n, 20_000):
        sl = slice(s, s + 20_000)
        o.add(xyz[sl], rgba[sl], **{a: v[sl] for a, v in attrs.items()})
        forms.append({a: o.pool.attributes.held_dtype(a) for a in attrs})
    assert forms[0]["source"] == forms[-1]["source"] == "uint16 constant 7"
    assert forms[0]["intensity"].startswith("uint16 in uint8") and forms[-1]["intensity"] == "uint16"
    assert forms[0]["time"] == "float64 constant 5.0" and forms[-1]["time"] == "float64"
    assert all(f["offset"].startswith("int32 in uint8 - ") for f in forms)
    held, entries = o.pool.attributes, o.pool.n_points
    assert held.nbytes_of("source") == 0 and held.nbytes_of("offset") == entries and held.nbytes_of("intensity") == 2 * entries

    def check(want):
        got = _leaf_points(o)
        match = _match(got["xyz"], xyz, np.sqrt(3) * o.edge / 2**30)
        for a, v in want.items():
            np.testing.assert_array_equal(got[a], v[match], err_msg=a)
        voxels = np.concatenate([o.node_entries(v) for v in o.inner_nodes()])
        for a, v in o.pool.attribute_rows(voxels).items():  # a voxel's: one of its cell's points'
            assert np.isin(v, want[a]).all(), a

    check(attrs)
    o.trim()
    assert o.pool.attributes.held_dtype("source") == "uint16 constant 7"
    check(attrs)
    more = {"source": np.full(1000, 8, np.uint16), "intensity": np.zeros(1000, np.uint16), "time": np.ones(1000),
            "offset": np.full(1000, 2**30, np.int32)}  # fmt: skip
    o.add(xyz[:1000] + 0.001, rgba[:1000], **more)
    assert o.pool.attributes.held_dtype("source").startswith("uint16 in uint8") and o.pool.attributes.held_dtype("offset") == "int32"
    got = _leaf_points(o)
    both = {a: np.concatenate([attrs[a], more[a]]) for a in attrs}
    match = _match(got["xyz"], np.concatenate([xyz, xyz[:1000] + 0.001]), np.sqrt(3) * o.edge / 2**30)
    for a, v in both.items():
        np.testing.assert_array_equal(got[a], v[match], err_msg=a)
    o.close()


def test_trim_packs_outside_the_lock_and_gives_way_to_an_add(scene, monkeypatch, tmp_path):
    """Packing is worked out while frames can take the lock (0.3 s at 20 M points would stall
    the viewer once loaded); an ``add`` that comes before it is taken wins: the packed copy is
    dropped, and the octree holds every point, wide."""
    xyz, rgba, attrs = points = _on_grid(scene)
    half = len(xyz) // 2
    free = []
    streams_on_grid = ProgressiveOctree._streams_on_grid

    def probe(self, state):
        def take():
            got = self.lock.lock.acquire(timeout=5)
            free.append(got)
            if got:
                self.lock.lock.release()

        t = threading.Thread(target=take)
        t.start()
        t.join()
        return streams_on_grid(self, state)

    monkeypatch.setattr(ProgressiveOctree, "_streams_on_grid", probe)
    o = _grid_filled(points)
    assert free == [True] and o._packed
    o.close()  # frees the packed pool; adding to a closed octree is refused, not a new tree started
    with pytest.raises(InputError, match="^grid: the octree is closed"):
        o.add(xyz[:100], rgba[:100], **{a: v[:100] for a, v in attrs.items()})
    assert o.n_points == 0 and o.pool is None
    with pytest.raises(InputError, match="^grid: the octree is closed"):
        o.save(tmp_path / "closed")
    assert not (tmp_path / "closed").exists()
    o = _grid_filled(points, rounds=(slice(0, half),))  # packed, then ...
    o.add(xyz[:10], rgba[:10], **{a: v[:10] for a, v in attrs.items()})  # ... unpacked by an add
    with o.lock:
        state = o._pack_state()
    o.add(xyz[half:], rgba[half:], **{a: v[half:] for a, v in attrs.items()})
    o._pack(state)
    assert not o._packed and o.n_points == len(xyz) + 10
    np.testing.assert_array_equal(_grid_rows(_leaf_points(o)["xyz"]), _grid_rows(np.concatenate([xyz, xyz[:10]])))


def test_a_grown_root_stays_on_the_grid_and_bad_grids_are_refused():
    """One point, then points ever farther out: the root grows from a cube 2 grid steps wide and
    stays aligned, so trim still packs and every point is exact; a grid without a positive,
    finite step or point is a one-line error."""
    rng = np.random.default_rng(3)
    o = ProgressiveOctree("grown", max_leaf=500, grid=(_UTM, _MM))
    first = _UTM + 0.123
    o.add(first[None, :])
    parts = [first[None, :]]
    for radius in (1.0, 30.0, 900.0):
        part = _UTM + np.round(rng.uniform(-radius, radius, (3_000, 3)) / _MM) * _MM
        o.add(part)
        parts.append(part)
    o.trim()
    assert o._packed and o._grid_bits() is not None and o.edge > 1800  # grown from 2 steps: ~20 times
    _, e = _chunk_widths(o)
    assert np.any(e < 20)
    np.testing.assert_array_equal(_grid_rows(_leaf_points(o)["xyz"]), _grid_rows(np.concatenate(parts)))
    for grid in (((0, 0, 0), 0.0), ((0, 0, 0), -1e-3), ((np.nan, 0, 0), 1e-3), ((0, 0, 0), np.inf)):
        with pytest.raises(InputError, match="grid must be"):
            ProgressiveOctree("bad", grid=grid)
    far = ProgressiveOctree("far", grid=(_UTM + 1e20, _MM))  # a point float64 cannot reach the data from: no grid
    far.add(parts[1])
    far.trim()
    assert far.grid is None and far.edge < 10 and not far._packed
    np.testing.assert_array_equal(_grid_rows(_leaf_points(far)["xyz"]), _grid_rows(parts[1]))


def test_a_header_without_a_usable_grid_loads_without_one(tmp_path, las_writer, monkeypatch):
    """A header whose scale is 0 or NaN (a damaged file) gives no grid: the points load wide,
    as before, with no error about a grid nobody asked for."""
    from gigapoint.io.las import LasReader
    from gigapoint.lod.progressive import file_sources

    f = las_writer(tmp_path / "a.las", 5_000, seed=1)
    assert file_sources([f])[4][1] == 0.001
    header = LasReader.header
    for scale, step in (([0.0] * 3, None), ([np.nan] * 3, None), ([-0.001] * 3, 0.001)):  # a negative scale: a mirrored axis, its step 0.001
        monkeypatch.setattr(LasReader, "header", lambda self, path, salvage=False, scale=scale: {**header(self, path, salvage), "scale": scale})
        grid = file_sources([f])[4]
        assert grid is None if step is None else grid[1] == step


def test_files_on_two_grids_load_exactly(tmp_path):
    """Two LAS files of one scene whose offsets differ by 0.4 of their millimetre: the octree's
    grid is the first file's, the second file's points are off it and their chunks stay wide;
    every point of both is where its file has it."""
    import laspy

    xyz, rgba, _ = demo_arrays(60_000, seed=5)
    paths = []
    for k, offset in enumerate((0.0, 0.0004)):
        header = laspy.LasHeader(point_format=2, version="1.2")
        header.scales, header.offsets = [0.001] * 3, [offset] * 3
        las = laspy.LasData(header)
        part = xyz[k::2] + (25.0 if k else 0.0)  # the second file beside the first: leaves of their own
        las.x, las.y, las.z = part[:, 0], part[:, 1], part[:, 2]
        paths.append(tmp_path / f"{k}.las")
        las.write(str(paths[-1]))
    cloud = gp.open(*paths, progressive=True)
    cloud.wait(timeout=120)
    assert cloud.grid is not None and np.array_equal(cloud.grid[0], [0.0, 0.0, 0.0])
    _, e = _chunk_widths(cloud)
    assert np.any(e == 20) and np.any(e < 20)  # the second file's chunks wide, the first's compact
    want = np.concatenate([np.column_stack([r.x, r.y, r.z]) for r in (laspy.read(str(p)) for p in paths)])
    got = cloud._all_points()[0]  # (chunks() and save() refuse a load that ended in an error)
    _match(got, want, 1e-5)  # within a 30-bit cell of the root (~2e-6 m), where the files have them
    cloud.close()


@pytest.mark.gpu
def test_wgpu_draws_the_octree_on_its_grid_as_the_cpu_does(scene):
    """The trimmed pool's compact point chunks (and the chunks an add writes on after it) through the GPU's
    decoder: the CPU's image."""
    from wgpu_support import wgpu_or_skip

    from gigapoint.backends.numba_cpu import NumbaCpuBackend

    gpu, cpu = wgpu_or_skip(), NumbaCpuBackend()
    points = _on_grid(scene)
    o = _grid_filled(points, rounds=(slice(0, 100_000),))
    s = EXACT.replace(point_budget=10**9, lod_threshold_px=0, adaptive_precision=False)  # all three words of every point
    for k in range(2):
        assert o._packed != bool(k)
        cam = gp.Camera.fit(o.bounds, view="iso", width=200, height=150)
        view = cam.view(o.bounds)
        with o.reading():
            draw = o.prepare(view, s)
            args = (draw.points, draw.selection, 200, 150, view.near, view.far)
            got, want = np.asarray(gpu.rasterize(*args)), cpu.rasterize(*args)
        assert np.count_nonzero(want != EMPTY_PIXEL) > 1000 and np.count_nonzero(got != want) <= 0.001 * want.size
        o.add(points[0][100_000:], points[1][100_000:], **{a: v[100_000:] for a, v in points[2].items()})  # written on: streams given room again, each chunk in its level's bits


@pytest.mark.parametrize("fmt", ["gigapoint", "potree", "copc"])
def test_save_writes_a_converted_octree_of_its_points(scene, octree, tmp_path, fmt):
    out = tmp_path / ("x.copc.laz" if fmt == "copc" else fmt)
    result = octree.save(out, format=fmt)
    assert result.points == octree.n_points
    saved = gp.open(out)
    assert saved.n_points == octree.n_points
    cam = gp.Camera.fit(octree.bounds, view="top", width=200, height=150)
    every = EXACT.replace(point_budget=10**9, lod_threshold_px=0)
    a = gp.render_frame(saved, cam, every).visibility != EMPTY_PIXEL
    b = gp.render_frame(octree, cam, every).visibility != EMPTY_PIXEL
    assert (a & b).sum() / (a | b).sum() >= 0.95
    with pytest.raises(GigapointError, match="overwrite"):
        octree.save(out, format=fmt)
    with pytest.raises(InputError, match=rf"^{re.escape(octree.name)}: save: unknown option\(s\) banana; it takes chunk_size, client, "):
        octree.save(tmp_path / "b", banana=1)  # a TypeError inside
    if fmt == "gigapoint":  # name= another was "multiple values for keyword argument 'name'"
        octree.save(tmp_path / "named", name="my scan")
        assert json.loads((tmp_path / "named" / "octree.json").read_text())["name"] == "my scan"


def test_save_keeps_its_tree_and_reads_nothing_again(scene, tmp_path, monkeypatch):
    """save() converts the octree's own tree (lod/convert/seeded.py): the saved octree's leaves
    are this octree's leaves, its inner nodes its inner nodes (the converter then samples them
    from their leaves), every point once, and neither the read spill nor the distribute phase
    runs. With another leaf size the points are converted from scratch, as before."""
    import importlib

    partition = importlib.import_module("gigapoint.lod.convert.partition")
    read = importlib.import_module("gigapoint.lod.convert.read")
    xyz, rgba, attrs = scene
    o = _filled(scene, max_leaf=3_000)

    def never(*args, **kwargs):
        raise AssertionError("a grown tree is not read or distributed again")

    monkeypatch.setattr(read.ReadPhase, "read", never)  # the read phase of a conversion of chunks, held or spilled
    monkeypatch.setattr(partition.PartitionPhases, "_append", never)
    result = o.save(tmp_path / "g")
    assert result.points == len(xyz)
    keys = np.load(tmp_path / "g" / "keys.npy")
    counts = np.load(tmp_path / "g" / "nodes.npy")["count"].astype(np.int64)
    parents = {int(k) >> 3 for k in keys}
    saved_leaves = {int(k) for k in keys if int(k) not in parents}
    assert saved_leaves == {int(o.key[n]) for n in o.leaves()}
    assert {int(k) for k in keys} - saved_leaves == {int(o.key[n]) for n in o.inner_nodes()}
    assert counts.sum() == len(xyz)
    saved = gp.open(tmp_path / "g")
    points = [saved.node_points(i) for i in range(len(keys))]
    idx = _match(np.concatenate([p["xyz"] for p in points]), xyz, 1e-3)  # every input point once, at its place
    assert np.array_equal(np.concatenate([p["rgba"] for p in points]).view(np.uint32).reshape(-1), rgba.view(np.uint32).reshape(-1)[idx])
    assert np.array_equal(np.concatenate([p["intensity"] for p in points]), attrs["intensity"][idx])
    with pytest.raises(AssertionError, match="not read or distributed again"):
        o.save(tmp_path / "other", max_leaf=2_000)  # another leaf size: converted from scratch


def test_a_tree_that_grows_while_it_is_saved_is_not_saved_half(scene):
    """Points added between the plan and the reading of the leaves (a live cloud's snapshot, a
    program's add) may have split a leaf: the save stops with a one-line error, and no output
    looks complete (the converter leaves it unfinished)."""
    xyz, rgba, _ = scene
    o = _filled((xyz[:60_000], rgba[:60_000], {}), max_leaf=3_000)
    tree = o.grown()
    first = tree.points(tree.leaf_keys[:2])
    assert len(first["xyz"]) == int(tree.leaf_counts[:2].sum())
    chunks = o.chunks(points_per_chunk=1)  # the path of save(max_leaf=...) and of a live cloud's LAS
    next(chunks)
    o.add(xyz[60_000:], rgba[60_000:])
    with pytest.raises(GigapointError, match="changed while it was being saved"):
        tree.points(tree.leaf_keys[:2])
    with pytest.raises(GigapointError, match="changed while it was being saved"):
        next(chunks)


def _cli(*args):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "gigapoint.cli", *map(str, args)], capture_output=True, text=True, timeout=300)


def test_render_builds_an_octree_for_inputs_above_the_budget_and_waits_for_it(tmp_path, las_writer):
    """``gigapoint render`` of an input above the point budget loads it progressively, waits for
    the whole file, and draws the finished octree (the API's image); a file the header says is
    small opens as a PointCloud as before."""
    from PIL import Image

    from gigapoint.cli.render_cmd import make_camera

    f = las_writer(tmp_path / "a.las", 60_000, seed=1)
    out = tmp_path / "a.png"
    r = _cli("render", f, "-o", out, "--point-budget", 20_000, "--size-mode", "fixed", "-W", 160, "-H", 120, "--view", "top", "--stats")
    assert r.returncode == 0, r.stderr
    assert "(progressive octree layout)" in " ".join(r.stderr.split())  # --stats: what the octree holds, per component
    cloud = gp.open(f, progressive=True)
    cloud.wait(timeout=120)
    assert cloud.n_points == 60_000
    mem = cloud.memory()
    # a low word an entry (the voxels' low word holds their position), and a point's bits on the
    # file's grid once loaded: less than half the 60 bits a point holds while the octree fills
    low, ext = cloud.pool.low.nbytes, cloud.pool.ext.nbytes
    assert sum(mem.values()) == cloud.nbytes and mem["positions"] == low + ext
    assert low >= 4 * (60_000 + cloud.n_voxels) and ext < 7.5 * 60_000 / 2
    cam = make_camera(cloud, 160, 120, "top", None, "perspective", 60.0)
    want = gp.render_frame(cloud, cam, EXACT.replace(point_budget=20_000)).image
    np.testing.assert_array_equal(np.asarray(Image.open(out).convert("RGB")), want[..., :3])
    cloud.close()
    # below the budget: the plain cloud, every point drawn
    r = _cli("render", f, "-o", tmp_path / "b.png", "--size-mode", "fixed", "-W", 160, "-H", 120, "--stats")
    assert r.returncode == 0 and "60,000 of 60,000 points" in r.stderr, r.stderr


def _same_octree(o: ProgressiveOctree, want: ProgressiveOctree, attrs) -> None:
    """Pool, nodes and voxels of ``o`` the same as ``want``'s."""
    assert (o.n_nodes, o.n_voxels, o.points) == (want.n_nodes, want.n_voxels, want.points)
    n, lists = o.n_nodes, o.n_nodes * 8
    for a in ("key", "leaf", "count", "first_chunk", "list_count"):
        np.testing.assert_array_equal(getattr(o, a)[: lists if a in ("first_chunk", "list_count") else n], getattr(want, a)[: lists if a in ("first_chunk", "list_count") else n])
    used = o._n_chunks * o.pool.chunk
    for got, ref in [(o.pool.low, want.pool.low), (o.pool.color, want.pool.color), (o.vox_sum[: o.n_voxels], want.vox_sum[: want.n_voxels])]:
        np.testing.assert_array_equal(got[: len(got) if got.ndim > 1 else used], ref[: len(ref) if ref.ndim > 1 else used])
    np.testing.assert_array_equal(o.pool.ext[: o._n_words], want.pool.ext[: want._n_words])
    for a in attrs:
        np.testing.assert_array_equal(o.pool.attributes[a][:used], want.pool.attributes[a][:used])


@pytest.mark.parametrize("mode", ["kept", "held"])
def test_work_arrays_kept_between_batches_build_the_same_octree_and_are_let_go(scene, mode):
    """``add`` keeps its work arrays from one batch to the next (up to keep_work_bytes; all of
    them within holding_work, a snapshot's batches): a batch must not see the last one's
    leftovers (sort keys, voxel cell entries, split leaves' points in the same arrays): the pool,
    nodes and voxels come out as when every batch makes its own. ``trim`` (the loader's end) and
    the end of holding_work let them go; beyond the bound nothing more is kept."""
    xyz, rgba, attrs = scene

    def filled(o, block=None):
        worked = []
        with block or contextlib.nullcontext():
            for s in range(0, len(xyz), 20_000):
                o.add(xyz[s : s + 20_000], rgba[s : s + 20_000], **{a: v[s : s + 20_000] for a, v in attrs.items()})
                worked.append(o.memory()["work"])
        return worked

    def keeping(limit: int | None) -> ProgressiveOctree:
        return type("Keeping", (ProgressiveOctree,), {"keep_work_bytes": limit})("t", max_leaf=3_000, cube=_cube(xyz))

    fresh = keeping(0)
    assert set(filled(fresh)) == {0}
    o = ProgressiveOctree("t", max_leaf=3_000, cube=_cube(xyz))
    worked = filled(o, o.holding_work() if mode == "held" else contextlib.nullcontext())
    assert min(worked) > 0  # kept from the first batch on
    _same_octree(o, fresh, attrs)
    if mode == "held":
        assert o.memory()["work"] == 0
    else:
        assert 0 < o.memory()["work"] <= o.keep_work_bytes
        o.trim()
        assert o.memory()["work"] == 0
    bounded = keeping(max(worked) // 3)
    assert 0 < max(filled(bounded)) <= bounded.keep_work_bytes
    _same_octree(bounded, fresh, attrs)


def test_voxel_cell_entry_arrays_are_made_once_with_room_as_the_entries_grow(scene, monkeypatch):
    """A batch in no spatial order makes more voxel cell entries a point as the tree deepens
    (the demo town's 8 M in 10^6 batches: 0.50, 0.54, 0.89, 1.23 M over the first four): its
    entries' work arrays are made once, with room for 1.5 entries a point of the set, not made
    again each time the entries outgrow them (each time faulting their pages in again); their
    colour sums are u32 (a set under 2^24 points). The octree is the one built without kept
    arrays and with u64 sums."""
    from gigapoint.lod.progressive import octree as octree_module

    xyz, rgba, attrs = scene
    asked, made = [], []
    get = octree_module._Work.get

    def recording(work, name, n, *args, **kwargs):
        before = work.arrays.get(name)
        a = get(work, name, n, *args, **kwargs)
        if name == "e_cell":
            asked.append(n)
            made.append(work.arrays.get(name) is not before)
        return a

    monkeypatch.setattr(octree_module._Work, "get", recording)
    o = _filled(scene, batch=40_000, max_leaf=10_000)
    assert max(asked) > 1.3 * asked[0]  # the entries grew past the first batch's (0.93 -> 1.31 a point)
    assert made[0] and not any(made[1:])
    e_sum = o._work.arrays["e_sum"]
    assert len(o._work.arrays["e_cell"]) == len(e_sum) == int(1.5 * 40_000) and e_sum.dtype == np.uint32
    monkeypatch.setattr(octree_module._Work, "get", get)
    monkeypatch.setattr(octree_module, "_U32_SUMS_BELOW", 0)  # u64 sums, as a set of 2^24 points has them
    fresh = ProgressiveOctree("t", max_leaf=10_000, cube=_cube(xyz))
    fresh._work = octree_module._Work(0)
    for s in range(0, len(xyz), 40_000):
        fresh.add(xyz[s : s + 40_000], rgba[s : s + 40_000], **{a: v[s : s + 40_000] for a, v in attrs.items()})
    assert fresh.memory()["work"] == 0
    _same_octree(o, fresh, attrs)


def _voxel_mean(vox_sum: np.ndarray) -> np.ndarray:
    """kernels._mean_color's rounded mean of each voxel's (r, g, b, a) sums."""
    n = vox_sum[:, 4:5].astype(np.int64)
    return (vox_sum[:, :4].astype(np.int64) + n // 2) // n


def test_voxel_colour_sums_stay_in_32_bits_past_16_8_million_points():
    """255 times a voxel's count overflowed its u32 sums past 16.8 M points (a live cloud's
    snapshots of one scene, taken long enough): its colour became garbage. The sums are halved
    instead (kernels.VOXEL_WEIGHT_BITS), the mean kept."""
    from numba import njit

    from gigapoint.lod.progressive import kernels as K

    @njit
    def add(vox_sum, batches):
        for e in range(batches.shape[0]):
            K._add_sums(vox_sum, 0, batches, e)

    n = 1 << 20
    one = np.array([200, 100, 50, 255, 1], np.uint64) * n  # a batch of 2^20 points of one colour
    vox = np.zeros((1, 5), np.uint32)
    add(vox, np.tile(one, (40, 1)))  # 42 M points
    assert vox[0, 4] < 1 << K.VOXEL_WEIGHT_BITS
    np.testing.assert_array_equal(_voxel_mean(vox)[0], [200, 100, 50, 255])
    # two colours in turn, 3 points of the first to 1 of the second: as the rule says (Python's
    # integers, which do not overflow), near the mean (the points added since the last halving
    # weigh twice as much as those before)
    other = np.array([0, 40, 250, 255, 1], np.uint64) * (n // 3)
    batches = np.tile(np.stack([one, other]), (30, 1))
    vox[:] = 0
    add(vox, batches)
    want = [0] * 5
    for b in batches.tolist():
        total = [w + x for w, x in zip(want, b)]
        k = 0
        while total[4] >> k >= 1 << K.VOXEL_WEIGHT_BITS:
            k += 1
        want = [(t + ((1 << k) >> 1)) >> k for t in total]
    np.testing.assert_array_equal(vox[0], want)
    assert np.abs(_voxel_mean(vox)[0, :3] - np.array([150, 85, 100])).max() <= 8
    # a voxel's sums set at once from a billion points (the build state rebuilt after a trim)
    billion = (np.array([[17, 34, 51, 255, 1]], np.uint64) * 10**9)
    vox[:] = 7
    K.set_voxel_sums(vox, np.zeros(1, np.int64), billion)
    np.testing.assert_array_equal(_voxel_mean(vox)[0], [17, 34, 51, 255])


def test_the_voxel_table_grows_for_new_voxels_not_for_every_entry(scene, monkeypatch):
    """A batch in no spatial order (the demo's generator order) has ~2 voxel cell entries a
    point, most of them voxels already: the table is asked for room for the new ones only
    (kernels.voxel_lookup counts them before voxel_enter enters them; at 20 M points a doubling
    to 384 MB and a rebuild, 0.7 s, were spared), so it ends the smallest power of two at most
    two thirds full, and every voxel is found in it with its id."""
    from gigapoint.lod.progressive import kernels as K
    from gigapoint.lod.progressive import octree as octree_module

    calls = []  # (entries looked up, room asked for, voxels before, voxels after)
    lookup, ensure, enter = K.voxel_lookup, octree_module.ProgressiveOctree._ensure_hash, K.voxel_enter

    def counted_lookup(hkeys, hvals, node, cell, vid, is_new):
        calls.append([len(node)])
        return lookup(hkeys, hvals, node, cell, vid, is_new)

    def counted_ensure(self, extra, table=None):
        if calls and len(calls[-1]) == 1:
            calls[-1] += [extra, self.n_voxels]
        return ensure(self, extra, table)

    def counted_enter(hkeys, hvals, node, cell, next_vid, vid, is_new, n_parts):
        got = enter(hkeys, hvals, node, cell, next_vid, vid, is_new, n_parts)
        calls[-1].append(got)
        return got

    monkeypatch.setattr(K, "voxel_lookup", counted_lookup)
    monkeypatch.setattr(K, "voxel_enter", counted_enter)
    monkeypatch.setattr(octree_module.ProgressiveOctree, "_ensure_hash", counted_ensure)
    o = _filled(scene, batch=30_000)
    monkeypatch.undo()
    m, extra, before, after = np.array(calls).T
    np.testing.assert_array_equal(extra, after - before)  # room for the new voxels, exactly
    assert (m >= extra).all() and (m[1:] > extra[1:]).all()  # ... fewer than the entries: after the first batch some are voxels already
    smallest = 1 << 17  # the table's first size
    while smallest < 3 * o.n_voxels // 2:
        smallest *= 2
    assert len(o._hkeys) == smallest
    vid, is_new = np.empty(o.n_voxels, np.int64), np.empty(o.n_voxels, np.uint8)
    keys = _voxel_keys(o)
    node = (keys >> np.uint64(3 * GRID_BITS)).astype(np.int64)
    cell = keys & np.uint64((1 << 3 * GRID_BITS) - 1)
    assert K.voxel_lookup(o._hkeys, o._hvals, node, cell, vid, is_new) == 0
    np.testing.assert_array_equal(vid, np.arange(o.n_voxels))


@pytest.mark.parametrize("parts", [2, 3, 5])
def test_voxel_ids_entered_in_parallel_are_those_entered_in_order(parts):
    """kernels.voxel_ids enters a batch's new keys in parallel, each part of the table taking the
    keys whose home slot is in it; a key whose probe would run out of its part (or off the
    table's end, wrapping) is entered after them. The ids are the same as entered in order
    (entry order), and every key is found again, whichever way it went in."""
    from gigapoint.lod.progressive import kernels as K
    from gigapoint.lod.progressive.octree import _voxel_table

    size = 64
    mask = size - 1

    def home(node, cell):
        return (((node << 21 | cell) * 0x9E3779B97F4A7C15) % 2**64 >> 32) & mask

    # keys crowding the last slot of part 0 and of the table: their probes must leave the part
    # (the wrap-around too); then random ones up to two thirds full
    share = size // parts
    edge_keys = [(n, c) for n in range(1, 3) for c in range(4000) if home(n, c) in (share - 1, size - 1)][:6]
    assert len(edge_keys) == 6
    rng = np.random.default_rng(parts)
    others = {(int(n), int(c)) for n, c in zip(rng.integers(3, 50, 60), rng.integers(0, 1 << 21, 60))}
    keys = edge_keys + sorted(others - set(edge_keys))[: 2 * size // 3 - len(edge_keys)]
    node = np.array([k[0] for k in keys], np.int64)
    cell = np.array([k[1] for k in keys], np.uint64)
    first, second = keys[: len(keys) // 2], keys[len(keys) // 2 :]  # two batches: the second finds the first's keys
    tables = {}
    for n_parts in (1, parts):
        hkeys, hvals = _voxel_table(size)
        got = []
        next_vid = 100
        for batch in (first, second, keys):
            b_node, b_cell = node[[keys.index(k) for k in batch]], cell[[keys.index(k) for k in batch]]
            vid, is_new = np.empty(len(batch), np.int64), np.empty(len(batch), np.uint8)
            next_vid = K.voxel_ids(hkeys, hvals, b_node, b_cell, next_vid, vid, is_new, n_parts)
            got.append((vid.copy(), is_new.copy()))
        tables[n_parts] = (got, next_vid, int(np.count_nonzero(hkeys != K.EMPTY_KEY)))
    (want, want_next, want_used), (got, got_next, got_used) = tables[1], tables[parts]
    assert got_next == want_next == 100 + len(keys) and got_used == want_used == len(keys)
    for (v1, n1), (v2, n2) in zip(want, got):
        np.testing.assert_array_equal(v2, v1)
        np.testing.assert_array_equal(n2, n1)
    vid_all, new_all = got[2]  # all keys again: all found, with the ids they got in entry order
    assert not new_all.any()
    np.testing.assert_array_equal(vid_all, 100 + np.arange(len(keys)))


@pytest.mark.parametrize("cube_given", [True, False])
def test_every_node_knows_the_box_of_the_points_below_it(scene, cube_given):
    """Each node keeps the bounding box of the points in its subtree (frames select and cull
    nodes by it, not by their cubes: a node of a flat town is a thin slab of its cube), through
    splits (their points inserted again), and a root that grows (no cube given: the first
    batch's bounds, then points beyond them)."""
    xyz, rgba, attrs = scene
    order = np.argsort(np.linalg.norm(xyz - xyz.min(axis=0), axis=1))  # outwards from a corner: without a cube the root grows
    o = ProgressiveOctree("t", max_leaf=3_000, **({"cube": _cube(xyz)} if cube_given else {}))
    for s in range(0, len(xyz), 20_000):
        sl = order[s : s + 20_000]
        o.add(xyz[sl], rgba[sl], **{a: v[sl] for a, v in attrs.items()})
    assert o.n_nodes > 50 and o.spilled > 0 and (o.root == 0) == cube_given  # the root grew where no cube was given
    n = o.n_nodes
    below = {i: [] for i in range(n)}
    for leaf in o.leaves().tolist():
        pts = o.positions(o.node_entries(leaf))
        node = leaf
        while node >= 0:
            below[node].append(pts)
            node = int(o.parent[node])
    for node in range(n):
        if not below[node]:  # no points below (made empty): no box, drawn by its cube
            assert np.all(o.point_min[node] > o.point_max[node])
            continue
        pts = np.concatenate(below[node])
        tol = o.cedge[node] * 2.0**-28  # positions are stored to 30 bits of their leaf's cube
        np.testing.assert_allclose(o.point_min[node], pts.min(axis=0), rtol=0, atol=tol)
        np.testing.assert_allclose(o.point_max[node], pts.max(axis=0), rtol=0, atol=tol)
    np.testing.assert_allclose(o.point_min[o.root], xyz.min(axis=0), rtol=0, atol=1e-6)
    np.testing.assert_allclose(o.point_max[o.root], xyz.max(axis=0), rtol=0, atol=1e-6)


def test_nodes_selected_by_their_points_box_draw_fewer_points_and_the_same_picture():
    """Flat ground and one tower in a corner: most nodes' points are a thin slab of their cube
    (the cloud's bounds do not cut them down: the tower spans them). Selected by the box of
    their points, nodes project smaller, so a frame draws fewer entries (the LOD rule of a
    converted octree, whose nodes carry their points' boxes), and the same picture."""
    rng = np.random.default_rng(3)
    ground = np.column_stack([rng.uniform(0, 1000, 200_000), rng.uniform(0, 1000, 200_000), rng.uniform(0, 2, 200_000)])
    tower = np.column_stack([rng.uniform(0, 20, 20_000), rng.uniform(0, 20, 20_000), rng.uniform(0, 600, 20_000)])
    xyz = np.vstack([ground, tower])
    o = ProgressiveOctree("ground and tower", max_leaf=3_000)
    o.add(xyz, rng.integers(0, 256, (len(xyz), 4)).astype(np.uint8))
    cam = gp.Camera.fit(o.bounds, view="iso", width=320, height=240)
    frames = {}
    try:
        for flag in (True, False):
            ProgressiveOctree.select_by_points = flag
            frames[flag] = gp.render_frame(o, cam, EXACT)
    finally:
        ProgressiveOctree.select_by_points = True
    by_box, by_cube = frames[True], frames[False]
    assert by_box.stats.points_processed < 0.85 * by_cube.stats.points_processed
    assert abs(int((~by_box.empty).sum()) - int((~by_cube.empty).sum())) <= 0.01 * (~by_cube.empty).sum()
    assert (by_box.empty == by_cube.empty).mean() > 0.97


def test_a_frame_draws_node_by_node_in_the_morton_order_of_their_cubes(scene):
    """Batches arriving from all over the cloud interleave the nodes' chunks in the pool; a
    frame still draws each node's chunks together, nodes in the Morton order of their cubes
    (writes that stay in one part of the image at a time: 1.1-1.6x faster frames of the town)."""
    xyz = scene[0]
    o = _filled(scene, batch=5_000, order=np.random.default_rng(2).permutation(len(xyz)))
    cam = gp.Camera.fit(o.bounds, view="iso", width=1920, height=1080)
    chunks = o.prepare(cam.view(o.bounds), EXACT.replace(point_budget=10**7, lod_threshold_px=20.0)).selection.ids
    node = o.pool.chunk_node[chunks].astype(np.int64)
    runs = node[np.r_[True, node[1:] != node[:-1]]]
    assert len(runs) == len(np.unique(node)) > 20  # one run of chunks a node
    assert (np.diff(np.sort(chunks)) > 0).all() and not (np.diff(chunks) > 0).all()  # not the pool's order
    position = o.key[runs] << (np.uint64(3) * (CODE_BITS - o.level[runs]).astype(np.uint64))
    assert (np.diff(position.astype(np.float64)) >= 0).all() and (position[1:] >= position[:-1]).all()


@pytest.mark.parametrize("parts", [1, 2, 3])
def test_the_radix_sort_of_keys_is_numpys_sort(parts):
    """``radix_sort`` (the keys' sort where numpy's is slower) sorts like numpy: random keys,
    keys whose top digits all agree (a set from one leaf: digits skipped), ties of the sorted
    bits left in their order, and 0, 1, 2 keys."""
    from gigapoint.lod.progressive.kernels import radix_sort

    rng = np.random.default_rng(parts)
    for n in (300_001, 3_001):  # (its buckets sorted by 8-bit digits; by insertion where a few keys)
        _sorts_like_numpy(radix_sort, rng, n, parts)
    for n in (0, 1, 2):
        keys = np.array([7 << 20, 3 << 20][:n], np.uint64)
        radix_sort(keys, np.empty(n, np.uint64), 19, parts)
        assert keys.tolist() == sorted([7 << 20, 3 << 20][:n])


def _sorts_like_numpy(radix_sort, rng, n, parts):
    index = np.arange(n, dtype=np.uint64)
    cases = {
        "random": rng.integers(0, 1 << 45, n, dtype=np.uint64) << np.uint64(19) | index,
        "one leaf": (np.uint64(0x2B5) << np.uint64(52)) | (rng.integers(0, 1 << 20, n, dtype=np.uint64) << np.uint64(19)) | index,
        "ties": rng.integers(0, 50, n, dtype=np.uint64) << np.uint64(19) | index,
        "sorted": np.arange(n, dtype=np.uint64) << np.uint64(19) | index,
        "clustered": (rng.integers(0, 8, n, dtype=np.uint64) << np.uint64(58)) | (rng.integers(0, 1 << 12, n, dtype=np.uint64) << np.uint64(30)) | index,
    }
    for name, keys in cases.items():
        want = np.sort(keys)
        got = keys.copy()
        radix_sort(got, np.empty(n, np.uint64), 19, parts)
        np.testing.assert_array_equal(got, want, err_msg=name)
        # only the bits from lo_bit up are sorted on: the index bits' order is kept (stable)
        shuffled = keys[rng.permutation(n)]
        got = shuffled.copy()
        radix_sort(got, np.empty(n, np.uint64), 19, parts)
        order = np.argsort(shuffled >> np.uint64(19), kind="stable")
        np.testing.assert_array_equal(got, shuffled[order], err_msg=name)


def test_a_voxels_mean_colour_and_a_slots_chunk_are_the_integer_divisions():
    """write_voxels' mean colour (one reciprocal, not four integer divisions) and a slot's chunk
    (a product, not a division) are exactly (sum + n // 2) // n and slot // chunk_size: sums at
    and next to every rounding boundary, counts up to 2^24, slots up to 2^32, chunks 16..2^20."""
    from numba import njit

    from gigapoint.lod.progressive.kernels import _chunk_of, _mean_color

    @njit
    def mismatches(sums, slots, chunk_sizes):
        bad = 0
        for v in range(sums.shape[0]):
            n = sums[v, 4]
            want = np.uint32(0)
            for ch in range(4):
                want |= np.uint32((sums[v, ch] + (n >> np.uint32(1))) // n) << np.uint32(8 * ch)
            bad += _mean_color(sums, v) != want
        for c in chunk_sizes:
            for s in slots:
                bad += _chunk_of(s, 1.0 / c) != s // c
        return bad

    rng = np.random.default_rng(5)
    m = 400_000
    n = np.concatenate([rng.integers(1, 1 << 24, m // 2), rng.integers(1, 300, m // 2)]).astype(np.uint32)
    k = rng.integers(0, 256, (m, 4))
    sums = np.empty((m, 5), np.uint32)
    sums[:, :4] = np.clip(k * n[:, None] - (n[:, None] >> 1) + rng.integers(-2, 3, (m, 4)), 0, 255 * n[:, None])
    sums[:, 4] = n
    chunk_sizes = np.array([16, 2048, 3000, 1 << 20], np.int64)
    near = (rng.integers(0, (1 << 32) // (1 << 20), 20_000) * (1 << 20))[:, None] + np.arange(-2, 3) * 1
    slots = np.clip(np.concatenate([near.ravel(), rng.integers(0, 1 << 32, 20_000), [0, (1 << 32) - 1]]), 0, (1 << 32) - 1).astype(np.uint32)
    assert mismatches(sums, slots, chunk_sizes) == 0


def test_the_tree_is_the_same_by_either_sort_of_the_keys(scene, octree, monkeypatch):
    """numpy's sort or the radix sort, whichever is faster here: the same octree."""
    import gigapoint.lod.progressive.octree as octree_module

    for kind in ("numpy", "radix"):
        monkeypatch.setattr(octree_module, "_KEY_SORT", [kind])
        _assert_same_leaves(_filled(scene), octree)


@pytest.mark.parametrize("n", [1, 3])
def test_a_tiny_cloud_is_drawn_where_the_plain_cloud_draws_it(n):
    """One point (or three within a millimetre), framed by ``Camera.fit_cloud`` from a
    micrometre away: each node's precision follows its whole cube (where its points are
    quantized), not the cube clipped to the data, which for one point is a point: 10 bits of the
    cube put the point off the image (the frame was empty; ``gigapoint render`` of a LAS file of
    one point drew nothing)."""
    xyz = np.array([[1.0, 2.0, 3.0], [1.001, 2.0, 3.0], [1.0, 2.002, 3.001]])[:n]
    plain = gp.from_arrays(xyz)
    for view, grid in (("auto", None), ("auto", ((0, 0, 0), 0.001)), ("top", ((0, 0, 0), 0.001)), ("iso", None)):
        octree = ProgressiveOctree("tiny", grid=grid)  # as from a LAS file of one point at scale 0.001
        octree.add(xyz)
        cam = gp.Camera.fit_cloud(plain, view=view, width=64, height=48)
        want = gp.render_frame(plain, cam, gp.RenderSettings(size_mode="fixed")).visibility != EMPTY_PIXEL
        got = gp.render_frame(octree, cam, gp.RenderSettings(size_mode="fixed")).visibility != EMPTY_PIXEL
        assert want.sum() >= 1 and got.sum() == want.sum(), view
        # at this zoom (a pixel is 2e-9 m) float32's matrices may move a point one pixel
        np.testing.assert_allclose(np.argwhere(got), np.argwhere(want), atol=1, err_msg=view)


def test_an_octree_among_files_or_opened_progressively_is_a_one_line_error(tmp_path, capsys):
    """A converted folder (or EPT, or a URL) opens alone, as itself: among other files, with
    ``progressive=True`` or with cloud options it was read as a folder of point files ("holds
    no supported point cloud file") or a URL as a path ("http:/host/...: no such file")."""
    from gigapoint.cli import main

    xyz = np.random.default_rng(5).uniform(0, 50, (3000, 3))
    octree = ProgressiveOctree("small")
    octree.add(xyz)
    octree.save(tmp_path / "tree")
    points = tmp_path / "p.npy"
    np.save(points, xyz)
    alone = "tree: a converted octree folder opens alone, drawn level of detail as stored; "
    cases = [
        (([tmp_path / "tree", points], {}), alone + "it cannot join other files"),
        (([tmp_path / "tree"], {"progressive": True}), alone + "progressive=True builds an octree from point files"),
        (([points, tmp_path / "tree"], {"progressive": True}), alone + "progressive=True builds an octree from point files"),
        (([tmp_path / "tree"], {"colors": "rgba"}), alone + "it takes no options \\(colors\\)"),
        ((["http://127.0.0.1:9/a.copc.laz"], {"progressive": True}), "^http://127.0.0.1:9/a.copc.laz: a URL opens alone"),
    ]
    for (paths, options), message in cases:
        with pytest.raises(InputError, match=message):
            gp.open(paths, **options)
    assert gp.open(tmp_path / "tree").n_points == 3000  # alone: as itself
    assert main(["render", str(tmp_path / "tree"), str(points), "-o", str(tmp_path / "a.png")]) != 0
    assert "tree: a converted octree folder opens alone" in capsys.readouterr().err and not (tmp_path / "a.png").exists()
    for command in ("render", "view"):  # --progressive of a converted folder drew it as stored, without a word
        extra = ["-o", str(tmp_path / "b.png")] if command == "render" else ["--no-browser"]
        assert main([command, str(tmp_path / "tree"), "--progressive", *extra]) == 1
        assert capsys.readouterr().err == f"error: {tmp_path / 'tree'}: a converted octree folder opens alone, drawn level of detail as stored; --progressive builds an octree from point files\n"


def test_normals_are_estimated_on_a_cloud_held_in_memory():
    """``estimate_normals`` of a progressive octree raised a TypeError traceback (its
    ``positions`` takes slots); it is a one-line error naming what it takes, and lighting's
    message says where normals can be estimated."""
    octree = ProgressiveOctree("grown")
    octree.add(np.random.default_rng(2).uniform(0, 10, (500, 3)))
    with pytest.raises(GigapointError, match=r"^grown: estimate_normals takes a cloud held in memory \(gigapoint.open\(path\)\), not a ProgressiveOctree$"):
        gp.estimate_normals(octree)
    with pytest.raises(GigapointError, match=r"has no normals .* on a cloud held in memory \(gigapoint.open\(path\)\)$"):
        gp.render(octree, lighting=True)


def test_a_pick_says_whether_it_is_a_voxel():
    """``point_info`` marks an inner node's voxel (a cell centre with its cell's mean colour),
    which is not a measured point; a leaf's point is one."""
    xyz = np.random.default_rng(8).uniform(0, 100, (40_000, 3)) * (1, 1, 0.05)
    octree = ProgressiveOctree("picks", max_leaf=2_000)
    octree.add(xyz)
    cam = gp.Camera.fit_cloud(octree, width=160, height=100)
    for threshold, voxels in ((5_000.0, True), (0.0, False)):  # only the root's voxels / every leaf drawn
        frame = gp.render_frame(octree, cam, gp.RenderSettings(size_mode="fixed", lod_threshold_px=threshold))
        picked = frame.index[frame.index >= 0][::50]
        assert len(picked) > 20 and {frame.point_info(int(i))["voxel"] for i in picked} == {voxels}


def _threads_seen(monkeypatch, module, name) -> list:
    """The thread counts numba had at each call of ``module.name`` (a kernel the call runs)."""
    import numba

    seen, real = [], getattr(module, name)

    def recording(*args, **kwargs):
        seen.append(numba.get_num_threads())
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, recording)
    return seen


def test_a_small_batch_is_inserted_on_the_calling_thread_alone(scene, monkeypatch):
    """Waking numba's sleeping threads costs ~0.1 ms a parallel kernel on a VM, more than a small
    batch's work (50 points an add: 2.5 ms a call, 0.15 ms on one thread): a batch below
    SMALL_BATCH points runs on the calling thread, a larger one on all, and the count is back
    after the add, whether it inserted or raised. The tree is the same either way. Where
    idle threads take up work at once (spinning OpenMP, TBB) every batch runs on all."""
    import numba

    from gigapoint.core import threads
    from gigapoint.core.threads import SMALL_BATCH

    xyz, rgba, attrs = scene
    monkeypatch.setattr(threads, "threads_awake", lambda: False)
    seen = _threads_seen(monkeypatch, K, "write_points")
    before = numba.get_num_threads()
    small = _filled(scene, batch=1_000)
    assert set(seen) == {1} and numba.get_num_threads() == before
    seen.clear()
    large = _filled(scene, batch=SMALL_BATCH)
    assert set(seen) == {before} and numba.get_num_threads() == before
    _assert_same_leaves(small, large, tol=3**0.5 * large.edge / 2**30)  # (positions held at 30 bits an axis of the root cube: within a step)
    with pytest.raises(InputError, match="is not one of this cloud's"):
        small.add(xyz[:10], rgba[:10], banana=np.zeros(10))
    assert numba.get_num_threads() == before
    monkeypatch.setattr(threads, "threads_awake", lambda: True)
    seen.clear()
    small.add(xyz[:100], rgba[:100], **{a: v[:100] for a, v in attrs.items()})
    assert set(seen) == {before}


def test_many_small_files_load_in_joined_batches(tmp_path, monkeypatch):
    """A progressive load of many small files inserted each file's points on its own (2 000 files
    of 50 points: 6 s, the plain cloud 1.2 s): runs of small chunks are joined into batches of
    SLICE_POINTS points or more (here 10 000), after the first chunk (the first image). Every point is in once."""
    from gigapoint.lod.progressive import loader

    SMALL_BATCH = 10_000
    monkeypatch.setattr(loader, "SLICE_POINTS", SMALL_BATCH)
    xyz = demo_arrays(15_000, seed=2)[0]
    for k in range(300):
        np.save(tmp_path / f"t{k:04d}.npy", xyz[k * 50 : (k + 1) * 50])
    sizes, real_add = [], ProgressiveOctree.add_read

    def counting_add(self, xyz, *args, **kwargs):
        sizes.append(len(xyz))
        return real_add(self, xyz, *args, **kwargs)

    monkeypatch.setattr(ProgressiveOctree, "add_read", counting_add)
    cloud = gp.open(tmp_path, progressive=True)
    assert cloud.wait(timeout=60)
    assert sizes == [50, SMALL_BATCH, 15_000 - 50 - SMALL_BATCH]
    got = _leaf_points(cloud)["xyz"]
    assert len(got) == len(xyz)
    _match(got, xyz, 3**0.5 * cloud.edge / 2**30)  # (one leaf: positions held at 30 bits an axis of the root cube)
    cloud.close()


def test_a_progressive_open_reads_each_file_once_and_las_headers_give_the_cube(tmp_path, las_writer, monkeypatch):
    """file_sources asked every file's reader for info(): an NPY (or PLY, text) file's info reads
    all its points for its bounds, so a large one was read whole before open returned, then again
    by the loader; a LAS file's opened it with laspy (VLRs, CRS) for what its header holds. Now
    each file's points are read once, by the loader, and LAS headers still give the root cube."""
    from gigapoint.io.numpy_io import NpyReader
    from gigapoint.lod.progressive.loader import file_sources

    xyz = demo_arrays(30_000, seed=4)[0]
    np.save(tmp_path / "a.npy", xyz[:20_000])
    np.save(tmp_path / "c.npy", xyz[20_000:])
    las = las_writer(tmp_path / "b.las", 10_000, seed=5)
    reads, real_chunks = [], NpyReader.read_chunks

    def counting_chunks(self, path, *args, **kwargs):
        reads.append(os.path.basename(path))
        return real_chunks(self, path, *args, **kwargs)

    monkeypatch.setattr(NpyReader, "read_chunks", counting_chunks)
    cloud = gp.open([tmp_path / "a.npy", tmp_path / "c.npy"], progressive=True)
    assert cloud.wait(timeout=60) and cloud.n_points == 30_000
    assert reads == ["a.npy", "c.npy"]
    cloud.close()
    _, total, bounds, _, grid = file_sources([las])
    points = gp.open(las).positions()
    assert total == 10_000 and grid is not None
    np.testing.assert_allclose(bounds[0], points.min(axis=0), atol=0.01)  # the header's (its grid's rounding)
    np.testing.assert_allclose(bounds[1], points.max(axis=0), atol=0.01)


def test_joined_chunks_keep_their_order_attributes_and_the_points_before_an_error():
    """The loader's joins: consecutive small chunks with the same attributes, in order; a chunk
    with other attributes (or a large one) is not joined; a source's error comes after the
    points read before it are given, so they stay drawable."""
    from gigapoint.core.chunk import PointChunk
    from gigapoint.lod.progressive.loader import _joined

    def chunk(n, start, **attrs):
        xyz = np.arange(start, start + n, dtype=np.float64)[:, None] * np.ones(3)
        return PointChunk(xyz, None, {a: np.full(n, v, np.uint16) for a, v in attrs.items()})

    def source():
        yield "a", chunk(5, 0)
        yield "b", chunk(5, 5)
        yield "c", chunk(5, 10)
        yield "d", chunk(5, 15, intensity=7)
        yield "e", chunk(20, 20)
        yield "f", chunk(5, 40)
        raise InputError("g: corrupt")

    got = []
    with pytest.raises(InputError, match="g: corrupt"):
        for name, c in _joined(source(), 8):
            got.append((name, len(c), sorted(c.attributes), c.xyz[:, 0].tolist()))
    assert [(n, k, a) for n, k, a, _ in got] == [("a", 5, []), ("c", 10, []), ("d", 5, ["intensity"]), ("e", 20, []), ("f", 5, [])]
    assert [x for *_, xs in got for x in xs] == list(range(45))  # every point once, in order


def test_the_faster_key_sort_is_timed_on_the_first_large_set_which_comes_sorted(monkeypatch):
    """Which sort serves the keys is timed once, on the first set of at least _TIME_SORT_FROM
    keys (real keys: the radix sort's speed depends on the digits they share, which random keys
    never do), and that set comes out sorted; smaller sets before it take numpy's, untimed."""
    import gigapoint.lod.progressive.octree as octree_module
    from gigapoint.lod.progressive.octree import _TIME_SORT_FROM, sort_keys_in_place

    monkeypatch.setattr(octree_module, "_KEY_SORT", [])
    rng = np.random.default_rng(3)
    for n in (1000, _TIME_SORT_FROM):
        bits = (n - 1).bit_length()
        keys = rng.integers(0, 1 << 40, n, dtype=np.uint64) << np.uint64(bits) | np.arange(n, dtype=np.uint64)
        want = np.sort(keys)
        sort_keys_in_place(keys, bits, np.empty(n, np.uint64))
        np.testing.assert_array_equal(keys, want)
        assert len(octree_module._KEY_SORT) == (1 if n >= _TIME_SORT_FROM else 0)  # timed at the large set only
    assert octree_module._KEY_SORT[0] in ("numpy", "radix")


def test_points_on_a_las_grid_decode_to_the_file_values(tmp_path, las_writer):
    """A LAS file's points in grid chunks (each at its cell's centre: layout codes under 20) decode
    to the file's values to float64 rounding, before and after ``trim``. The decoder added the
    half 30-bit cell floor-quantized words need to these words too: scale * 2^(B - 31) past them
    (3.05e-7 ft in autzen's 2^16-step nodes; 4.9e-7 in these 2^20-step ones, 4e6 units in the last place)."""
    import laspy

    path = las_writer(tmp_path / "grid.las", 30_000, seed=3)
    las = laspy.read(str(path))
    src = np.stack([las.X, las.Y, las.Z], axis=1).astype(np.int64)
    want = np.stack([las.x, las.y, las.z], axis=1)[np.lexsort(src.T)]
    o = gp.open(path, progressive=True)
    o.wait()
    for trimmed in (False, True):
        if trimmed:
            o.trim()
        slots = np.concatenate([o.node_entries(n) for n in o.leaves()])
        assert (o.pool.packing["code"][slots // o.pool.chunk] & 0xFF).max() < 20  # grid chunks, none wide
        got = o.positions(slots)
        q = np.round(got / 0.001).astype(np.int64)
        np.testing.assert_array_equal(q[np.lexsort(q.T)], src[np.lexsort(src.T)])
        err = np.abs(got[np.lexsort(q.T)] - want)
        assert (err / np.spacing(np.abs(want).max(axis=0))).max() <= 4, err.max(axis=0)


def test_the_automatic_intensity_range_is_the_points_held():
    """Colour by intensity without ``intensity_range``: the range is that of the pool's entries
    the chunks hold (points and voxels), not of its every entry: those no chunk fills read 0
    (intensities of 1000..1100 drew over 923..1096, no grey under 100)."""
    rng = np.random.default_rng(3)
    n = 30_000
    o = ProgressiveOctree("p", max_leaf=2_000)
    o.add(rng.random((n, 3)) * [300, 200, 20], intensity=rng.integers(1000, 1101, n).astype(np.uint16))
    assert o.pool.n_points > 2 * int(o.pool.batches["count"].sum())  # most of the pool is empty room
    cam = gp.Camera.fit(o.bounds, view="top", width=300, height=300)
    f = gp.render_frame(o, cam, EXACT.replace(color_mode="intensity"))
    grey = f.image[f.visibility != EMPTY_PIXEL][:, 0]
    assert grey.min() == 0 and grey.max() == 255


def test_added_float_colours_keep_the_range_of_the_first_colours_added():
    """Each add() judged its float colours by their own range (as a live push did): a 0..1 batch
    that overshot to 1.025 was read as 0..255, almost black beside the batch before it."""
    o = ProgressiveOctree("t")
    xyz = np.random.default_rng(2).random((200, 3)) * 10
    o.add(xyz[:100], np.tile((0.5, 0.5, 1.0), (100, 1)))
    o.add(xyz[100:], np.tile((0.5, 0.5, 1.025), (100, 1)))
    colors = np.unique(_leaf_points(o)["color"].view(np.uint8).reshape(-1, 4), axis=0)
    assert colors.tolist() == [[128, 128, 255, 255]]  # (the second batch alone: [0, 0, 1, 255])
    o.close()
