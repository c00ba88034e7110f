"""A converted octree's per-node class counts (classes.npy, lod/class_counts.py): counted by the
converter from each node's points, in key order across node sets (partitions, groups, upper
nodes), the same in both layouts; none without classification; checked when the octree opens.
What they do to the point budget: test_filtered_budget.py."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from test_compact_octree import _write_las  # tests/unit is on sys.path

import gigapoint as gp
from gigapoint.errors import InputError
from gigapoint.io.filters import PointFilter
from gigapoint.lod.class_counts import CLASS_COUNT_DTYPE, kept_by_class
from gigapoint.lod.compact_octree import CompactOctree
from gigapoint.lod.convert import convert
from gigapoint.lod.octree_dir import OctreeDir
from gigapoint.lod.reader import open_octree


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    """A LAS file of classes 0-7 converted in both layouts, in several partitions (so node sets
    of partitions, groups and the upper nodes are joined)."""
    base = tmp_path_factory.mktemp("classes")
    src = _write_las(base / "eight.las", 60_000, 0.01, (500_000.0, 4_800_000.0, 100.0))
    opts = {"max_leaf": 2_000, "partition_points": 20_000}
    convert([src], base / "v2", **opts)
    convert([src], base / "v1", layout="words", **opts)
    return base / "v1", base / "v2"


def test_each_nodes_counts_are_the_classes_of_its_points(converted):
    v1, v2 = converted
    records = np.load(v2 / "classes.npy")
    assert (v1 / "classes.npy").read_bytes() == (v2 / "classes.npy").read_bytes()  # (layouts hold the same nodes)
    tree = gp.open(v2)
    assert records.dtype == CLASS_COUNT_DTYPE and len(tree.keys) > 30
    assert np.all(np.diff(records["node"].astype(np.int64) * 256 + records["class"]) > 0)  # by node, then class; each pair once
    want = []
    for i in range(len(tree.keys)):
        classes, counts = np.unique(tree.node_points(i)["classification"], return_counts=True)
        want += [(i, c, n) for c, n in zip(classes.tolist(), counts.tolist())]
    assert [tuple(r) for r in records.tolist()] == want
    np.testing.assert_array_equal(tree.class_counts, records)
    # what a filter keeps of each node: its points of the classes it lets pass
    kept = kept_by_class(records, len(tree.keys), PointFilter(classes=(2, 3, 5), drop_classes=(3,)))
    assert kept.tolist() == [int(np.isin(tree.node_points(i)["classification"], [2, 5]).sum()) for i in range(len(tree.keys))]


def test_both_layouts_get_the_same_counts_where_a_folder_is_opened(converted):
    """open_octree reads classes.npy once for whichever layout the folder has (each layout's
    reader read it on its own before: another reader would have had none)."""
    v1, v2 = converted
    words, compact = open_octree(v1), open_octree(v2)
    assert isinstance(compact, CompactOctree) and not isinstance(words, CompactOctree)
    records = np.load(v2 / "classes.npy")
    assert len(records) > 30 and int(records["count"].sum()) == 60_000
    np.testing.assert_array_equal(words.class_counts, records)
    np.testing.assert_array_equal(compact.class_counts, records)


def test_a_cloud_without_classification_has_none(tmp_path):
    xyz = np.random.default_rng(0).random((5_000, 3)) * 100
    gp.convert(gp.from_arrays(xyz, np.zeros((5_000, 3), np.uint8), scale=0.01, colors="rgba"), tmp_path / "oct", max_leaf=1_000)
    assert not (tmp_path / "oct" / "classes.npy").exists() and gp.open(tmp_path / "oct").class_counts is None


def test_a_replacement_without_classification_leaves_none_of_the_old_octrees(converted, tmp_path):
    """classes.npy is one of the octree's own files: an overwrite sets it aside with the others
    (left in place, the new octree's nodes did not add up to it: the octree did not open)."""
    out = tmp_path / "oct"
    shutil.copytree(converted[1], out)
    xyz = np.random.default_rng(0).random((5_000, 3)) * 100
    gp.convert(gp.from_arrays(xyz, np.zeros((5_000, 3), np.uint8), scale=0.01, colors="rgba"), out, max_leaf=1_000, overwrite=True)
    assert not (out / "classes.npy").exists() and gp.open(out).n_points == 5_000


def _records_changed(field: str, by: int):
    def change(d: OctreeDir) -> None:
        records = np.load(d.array("classes"))
        records[field][-1] += by
        np.save(d.array("classes"), records)

    return change


DAMAGE = {
    "a count off": (_records_changed("count", 1), "'s classes count"),
    "a node that is not there": (_records_changed("node", 10**6), "names node #10"),
    "another layout": (lambda d: np.save(d.array("classes"), np.zeros(3, np.uint32)), "not (node, class, count) ones"),
}


@pytest.mark.parametrize("case", list(DAMAGE))
def test_damaged_counts_are_a_one_line_error_naming_the_file(converted, tmp_path, case):
    damage, problem = DAMAGE[case]
    shutil.copytree(converted[1], tmp_path / "oct")
    damage(OctreeDir(tmp_path / "oct"))
    with pytest.raises(InputError) as err:
        gp.open(tmp_path / "oct")
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{tmp_path / 'oct' / 'classes.npy'}: ") and problem in msg, msg
