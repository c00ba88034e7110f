"""Cross-sections of LOD octrees (lod/query.py): the nodes whose boxes meet the corridor, at every
level, hold every point of it once, so the section of a converted octree (gigapoint folders of
each sampler and layout, Potree 2.0, COPC) and of a progressive one (its leaves) is the section
of its source file; only the meeting nodes are read; autzen_trim.laz converted gives the .laz's
section; the corridor's box test against node boxes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_section import ORIGIN, WIDTH, line_of, scene, sorted_rows, write_las

import gigapoint as gp
from gigapoint.errors import EmptyCloudError
from gigapoint.io.filters import PointFilter
from gigapoint.lod.store import OctreeCloud

CONVERSIONS = {
    "grid": {"sampler": "grid"},
    "poisson": {"sampler": "poisson"},
    "words": {"layout": "words"},  # a version 1 folder
    "potree": {"format": "potree"},
    "copc": {"format": "copc"},
}


def rows(cut) -> np.ndarray:
    return sorted_rows(np.column_stack([cut.distance, cut.offset, cut.z, cut.classification]))


def big_scene() -> tuple[np.ndarray, np.ndarray]:
    """(xyz, classification): a plane rising 0.1 a unit of x over 300 x 300 units, a point a unit
    (class 2), and a wall across it at x = 150 (class 6), 10 high, a point each half unit."""
    x, y = np.meshgrid(np.arange(0.0, 300.0), np.arange(0.0, 300.0))
    plane = np.column_stack([x.ravel(), y.ravel(), 0.1 * x.ravel()])
    wy, wz = np.meshgrid(np.arange(0.0, 300.0, 0.5), np.arange(0.5, 10.1, 0.5))
    wall = np.column_stack([np.full(wy.size, 150.0), wy.ravel(), 15.0 + wz.ravel()])
    return np.concatenate([plane, wall]) + ORIGIN, np.repeat([2, 6], [len(plane), len(wall)]).astype(np.uint8)


@pytest.fixture(scope="module")
def octrees(tmp_path_factory):
    """The sloped plane and wall of test_section.py as a LAS file and converted each way ({name: path})."""
    folder = tmp_path_factory.mktemp("section_octree")
    xyz, classification = scene()
    las = write_las(folder / "straight.las", xyz + ORIGIN, classification)
    out = {"las": las}
    for name, options in CONVERSIONS.items():
        out[name] = folder / (f"{name}.copc.laz" if name == "copc" else name)
        gp.convert([las], out[name], max_leaf=300, **options)
    return out


@pytest.mark.parametrize("kind", list(CONVERSIONS))
def test_the_section_of_an_octree_is_the_section_of_its_source(octrees, kind):
    line = line_of("straight")
    want = gp.section(octrees["las"], line, WIDTH)
    octree = gp.open(octrees[kind])
    assert int(octree.counts.sum()) == octree.n_points == len(scene()[0]) and len(octree.keys) > 1  # every point in one node
    for source in (octree, octrees[kind]):  # opened, or its path
        cut = gp.section(source, line, WIDTH)
        assert cut.cloud.n_points == want.cloud.n_points == 36 * 5 + 5 * 5 * 29
        step = float(octree.meta["cube_edge"]) / 2**30  # 30-bit positions in the root's cube at worst
        np.testing.assert_allclose(rows(cut), rows(want), rtol=0, atol=2 * step + 1e-9 * np.abs(ORIGIN).max())
    walls = gp.section(octree, line, WIDTH, classes=[6])
    assert walls.cloud.n_points == 5 * 5 * 29 and set(walls.classification.tolist()) == {6}
    assert gp.section(octree, line, WIDTH, drop_classes=[6]).cloud.n_points == 36 * 5


def test_a_progressive_octree_sections_from_its_leaves(octrees):
    """Its inner nodes hold voxels (not points): the section comes from its leaves alone, and equals the file's."""
    from gigapoint.lod.progressive import ProgressiveOctree

    line = line_of("straight")
    xyz, classification = scene()
    octree = ProgressiveOctree("scene", max_leaf=200)
    octree.add(xyz + ORIGIN, classification=classification)
    assert len(octree.inner_nodes()) > 0 and len(octree.leaves()) > 4  # voxels above, points in the leaves
    cut = gp.section(octree, line, WIDTH)
    want = gp.section(octrees["las"], line, WIDTH)
    np.testing.assert_allclose(rows(cut), rows(want), rtol=0, atol=1e-6)
    walls = gp.section(octree, line, WIDTH, classes=[6])
    assert walls.cloud.n_points == 5 * 5 * 29


def test_only_the_nodes_meeting_the_corridor_are_read(tmp_path, monkeypatch):
    xyz, classification = big_scene()
    las = write_las(tmp_path / "big.las", xyz, classification)
    line = (ORIGIN[0] + 140.2, ORIGIN[1] + 100.2, ORIGIN[0] + 160.2, ORIGIN[1] + 110.2)  # 22 units, turned 26.6 degrees, across the wall
    want = gp.section(las, line, 2.0)
    reads = []
    real = OctreeCloud.node_points
    monkeypatch.setattr(OctreeCloud, "node_points", lambda self, index: reads.append(index) or real(self, index))
    for name in ("grid", "copc"):
        out = tmp_path / ("big.copc.laz" if name == "copc" else "big")
        gp.convert([las], out, max_leaf=500, **CONVERSIONS[name])
        octree = gp.open(out)
        reads.clear()
        cut = gp.section(octree, line, 2.0)
        assert cut.cloud.n_points == want.cloud.n_points > 40
        np.testing.assert_allclose(rows(cut), rows(want), rtol=0, atol=1e-5)
        full = int(np.count_nonzero(octree.counts))
        assert len(reads) == len(set(reads)) and 0 < len(reads) < full / 4, (name, len(reads), full)


def test_autzen_converted_gives_the_section_of_the_laz(autzen_path, tmp_path):
    lo, hi = gp.open(autzen_path).bounds
    line = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))  # corner to corner, 10 feet wide
    want = gp.section(autzen_path, line, 10)
    for out, options in ((tmp_path / "autzen", {}), (tmp_path / "autzen.copc.laz", {"format": "copc"})):
        gp.convert([autzen_path], out, max_leaf=4_000, **options)
        cut = gp.section(out, line, 10)
        assert cut.cloud.n_points == want.cloud.n_points > 1000
        np.testing.assert_allclose(rows(cut), rows(want), rtol=0, atol=1e-3)  # (the file's 0.01 ft grid)
        assert np.array_equal(np.sort(cut.classification), np.sort(want.classification))


def test_a_corridor_beside_the_octree_names_it(octrees):
    with pytest.raises(EmptyCloudError) as err:
        gp.section(octrees["grid"], (0, 0, 10, 0), 2)
    assert str(err.value) == f"{octrees['grid']}: no point passes the filter (corridor 0, 0 to 10, 0, width 2): no node of the octree meets the corridor"


@pytest.mark.parametrize("turn", [0.0, 30.0, 90.0, 135.0])
def test_the_corridor_meets_exactly_the_boxes_its_rectangle_overlaps(turn):
    """Boxes on a grid against the corridor, turned: the box test says what sampled points inside the boxes say."""
    a = math.radians(turn)
    corridor = PointFilter(corridor=(3.0, 4.0, 3.0 + 10 * math.cos(a), 4.0 + 10 * math.sin(a), 2.0))
    gx, gy = np.meshgrid(np.arange(-10.3, 16.0, 1.5), np.arange(-10.3, 16.0, 1.5))  # (no edge on the corridor's: rounding decides those)
    lo = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    hi = lo + [1.5, 1.5, 1.0]
    meets = corridor.meets(lo, hi)
    u = np.linspace(0, 1, 61)
    inside = []
    for b0, b1 in zip(lo, hi):  # a fine grid of points in the box, bounds included
        px, py = np.meshgrid(b0[0] + u * (b1[0] - b0[0]), b0[1] + u * (b1[1] - b0[1]))
        points = np.column_stack([px.ravel(), py.ravel(), np.zeros(px.size)])
        inside.append(len(corridor.kept(gp.PointChunk(points), "grid")) > 0)
    assert np.array_equal(meets, inside) and 4 < meets.sum() < len(lo) / 4
