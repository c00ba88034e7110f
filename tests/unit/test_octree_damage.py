"""Damaged COPC and EPT nodes: LAZ's decoder turns damaged bytes into garbage points kilometres
away without an error. A node whose points decode far outside its cube (more than the octree's
cube edge) is damaged: not drawn, said once an octree naming the file and the nodes."""

from __future__ import annotations

import io
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import GigapointWarning, InputError
from gigapoint.lod import convert
from gigapoint.lod.copc import HIERARCHY_ENTRY_DTYPE
from gigapoint.lod.voxel_octree import parse_voxel_name

laspy = pytest.importorskip("laspy")

DATA = Path(__file__).resolve().parent / "data"
COPC = DATA / "copclib" / "one_page.copc.laz"  # copc-lib's: 20 000 points, format 7, one hierarchy page
SETTINGS = gp.RenderSettings(backend="cpu", lod_threshold_px=0.0)


def _draw(cloud):
    cloud.load_hierarchy()
    return gp.render_frame(cloud, gp.Camera.fit(cloud.bounds, width=160, height=120), SETTINGS).image


def _chunk(name: str) -> tuple[int, int, int]:
    """(byte offset, points, first point in the file's order) of one_page's node ``name``."""
    c = gp.open(COPC)
    c.load_hierarchy()
    i = int(np.searchsorted(c.keys, parse_voxel_name(name)))
    assert c.keys[i] == parse_voxel_name(name) and c.counts[i] > 0
    offset = c.locators[i][0]
    first = sum(int(n) for loc, n in zip(c.locators, c.counts) if loc is not None and loc[0] < offset)
    return offset, int(c.counts[i]), first


def _damaged(folder: Path, names: list[str]) -> Path:
    """one_page with the first 8 bytes of each node's chunk zeroed (its first point's raw X and Y,
    which the others are coded against): laspy decodes the file without an error, those nodes'
    points around x, y = 0 (the file's offset), 636 km from the others, the rest exactly."""
    data = bytearray(COPC.read_bytes())
    for name in names:
        data[_chunk(name)[0] : _chunk(name)[0] + 8] = bytes(8)
    path = folder / "damaged.copc.laz"
    path.write_bytes(bytes(data))
    good, bad = laspy.read(COPC), laspy.read(io.BytesIO(bytes(data)))
    same = np.ones(len(good.points), bool)
    for name in names:
        offset, n, first = _chunk(name)
        same[first : first + n] = False
        assert np.all(np.abs(bad.x[first : first + n]) < 1000) and np.all(np.abs(bad.y[first : first + n]) < 1000)
    np.testing.assert_array_equal(np.asarray(bad.x)[same], np.asarray(good.x)[same])
    return path


def _dropped(folder: Path, name: str) -> Path:
    """one_page with node ``name``'s hierarchy entry saying it holds no points."""
    data = bytearray(COPC.read_bytes())
    offset, n, _ = _chunk(name)
    key_and_offset = np.array([(tuple(map(int, name.split("-"))), offset, 0, n)], HIERARCHY_ENTRY_DTYPE).tobytes()[:24]
    at = bytes(data).find(key_and_offset)
    assert at > 0
    data[at + 28 : at + 32] = bytes(4)  # its point_count
    path = folder / "dropped.copc.laz"
    path.write_bytes(bytes(data))
    return path


def _one_warning(fn, *args):
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        out = fn(*args)
    assert all(issubclass(w.category, GigapointWarning) for w in got)
    return out, [str(w.message) for w in got]


def test_a_damaged_copc_node_is_not_drawn_and_said_once(tmp_path):
    bad = _damaged(tmp_path, ["1-1-0-0"])
    cloud = gp.open(bad)
    image, said = _one_warning(_draw, cloud)
    assert said == [
        (
            f"{bad}: corrupt point data: node 1-1-0-0 decodes to points far outside its cube "
            "(y -47.250, its cube 848,949.410..849,203.885); its data is damaged and is not drawn"
        )
    ]
    assert cloud.n_points == 20_000 - 1500 and int(cloud.arena.batches["count"].sum()) == 18_500
    np.testing.assert_array_equal(image, _draw(gp.open(_dropped(tmp_path, "1-1-0-0"))))  # as if the node held none
    assert not np.array_equal(image, _draw(gp.open(COPC)))
    again, said = _one_warning(_draw, cloud)  # said once an octree
    assert said == [] and np.array_equal(again, image)
    memory, said = _one_warning(lambda: gp.open(bad).to_memory())
    assert len(said) == 1 and "node 1-1-0-0" in said[0] and memory.n_points == 18_500


def test_several_damaged_nodes_are_named_by_the_first_three(tmp_path):
    bad = _damaged(tmp_path, ["0-0-0-0", "1-0-0-0", "1-1-0-0", "2-1-0-1", "3-5-3-3"])
    _, said = _one_warning(_draw, gp.open(bad))
    assert said == [
        (
            f"{bad}: corrupt point data: nodes 0-0-0-0, 1-0-0-0, 1-1-0-0 and 2 more decode to points far outside their cubes "
            "(node 0-0-0-0: y -80.870, its cube 848,949.410..849,458.360); their data is damaged and is not drawn"
        )
    ]


def test_an_undamaged_copc_draws_every_point_without_a_word():
    cloud = gp.open(COPC)
    _, said = _one_warning(_draw, cloud)
    assert said == [] and cloud.n_points == 20_000 and int(cloud.arena.batches["count"].sum()) == 20_000


def test_convert_refuses_a_damaged_copc_as_a_damaged_laz(tmp_path):
    """convert reads a COPC file as the LAZ file it is: the LAS reader's check names the chunk."""
    bad = _damaged(tmp_path, ["1-1-0-0"])
    offset, n, first = _chunk("1-1-0-0")
    with pytest.raises(InputError, match=rf"^{bad}: corrupt LAZ point data: point {first:,} lies far outside the header's bounds .*"
                       rf"its LAZ chunk, points {first:,}..{first + n - 1:,}, is damaged"):  # fmt: skip
        convert([bad], tmp_path / "out", progress=False)


def test_a_damaged_ept_node_is_not_drawn(tmp_path):
    """Entwine's laszip node (point format 3) with 256 bytes zeroed: laspy decodes it, 87 of its
    points over 1,000 km away in x."""
    d = tmp_path / "ept"
    shutil.copytree(DATA / "pdal_ept" / "1.2-with-color", d)
    node = d / "ept-data" / "0-0-0-0.laz"
    data = bytearray(node.read_bytes())
    data[16116 : 16116 + 256] = bytes(256)
    node.write_bytes(bytes(data))
    las = laspy.read(node)
    far = np.flatnonzero(np.abs(las.x - las.header.mins[0]) > 1e6)
    assert len(las.points) == 1065 and len(far) == 87 and far[0] == 978
    cloud = gp.open(d)
    image, said = _one_warning(_draw, cloud)
    assert said[0] == (
        f"{d / 'ept.json'}: corrupt point data: node 0-0-0-0 decodes to points far outside its cube "
        "(y 22,271,716.960, its cube 848,899.000..853,536.000); its data is damaged and is not drawn"
    )
    assert len(said) == 2 and "no point is in view of the camera" in said[1]  # (it drew none)
    assert cloud.n_points == 0 and np.all(image == image[0, 0])  # the background alone
    whole = _draw(gp.open(DATA / "pdal_ept" / "1.2-with-color"))
    assert np.count_nonzero(np.any(whole != whole[0, 0], axis=-1)) > 1000
    with pytest.warns(GigapointWarning, match=r"ept.json: corrupt point data: node 0-0-0-0 decodes to points far outside its cube"):
        points = gp.open(d).node_points(0)  # (tools' and tests' way in: said too)
    assert len(points["xyz"]) == 0
