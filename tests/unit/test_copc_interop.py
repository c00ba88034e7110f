"""COPC files gigapoint did not write: copc-lib's (data/copclib/, made by its make.py; their
layouts are described there) read point for point as laspy decodes them, every node of the
hierarchy copclib's reader finds (nodes.json) found once, by nodes, progressively and flat, and
drawn like the points themselves; and gigapoint's own COPC output read by copclib."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.lod import CopcCloud, convert
from gigapoint.lod.copc_write import write_copc
from gigapoint.lod.voxel_octree import voxel_name

laspy = pytest.importorskip("laspy")

DATA = Path(__file__).resolve().parent / "data" / "copclib"
FILES = sorted(p.name for p in DATA.glob("*.copc.laz"))
MANIFEST = json.loads((DATA / "nodes.json").read_text())
AUTZEN = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "autzen_trim.laz"
N = 20_000
CHECKED = ("intensity", "classification", "return_number", "number_of_returns", "gps_time", "user_data", "point_source_id",
           "scan_angle", "scan_direction_flag", "edge_of_flight_line")  # fmt: skip


def _all_nodes(cloud: CopcCloud) -> list[int]:
    """Indices of the nodes holding points, in the order their chunks lie in the file (laspy's)."""
    cloud.load_hierarchy()
    full = np.flatnonzero(cloud.counts > 0).tolist()
    return sorted(full, key=lambda i: cloud.locators[i][0])


def _rgb8(las) -> np.ndarray:
    """The 8-bit colours gigapoint shows for a file's 16-bit fields (8-bit values in them as they are)."""
    rgb = np.stack([np.asarray(las[c]) for c in ("red", "green", "blue")], 1)
    return (rgb >> 8 if rgb.max() > 255 else rgb).astype(np.uint8)


def test_fixtures_are_small_and_hold_the_layouts():
    assert FILES == ["nir_extra.copc.laz", "one_page.copc.laz", "own_pages.copc.laz", "shared_keys.copc.laz"]
    assert sum((DATA / f).stat().st_size for f in FILES) < 1_200_000
    assert [len(MANIFEST[f]["pages"]) for f in FILES] == [1, 1, 7, 8]
    assert all(sum(MANIFEST[f]["nodes"].values()) == N for f in FILES)
    assert "0-0-0-0" not in MANIFEST["nir_extra.copc.laz"]["nodes"]  # no root node


@pytest.mark.parametrize("name", FILES)
def test_copclib_file_reads_point_for_point_by_nodes(name):
    path = DATA / name
    las = laspy.read(path)
    c = gp.open(path)
    assert isinstance(c, CopcCloud) and c.n_points == len(las.points) == N
    assert c.meta["spacing"] == c.meta["cube_edge"] / 128  # make.py's halfsize / 64
    edge = (las.header.maxs - las.header.mins).max() * (2 if name == "own_pages.copc.laz" else 1)  # the cube around the points
    np.testing.assert_allclose(c.meta["cube_edge"], edge)
    np.testing.assert_allclose(np.add(c.meta["cube_min"], edge / 2), (las.header.mins + las.header.maxs) / 2)
    nodes = _all_nodes(c)
    assert c.pending_pages == 0 and c.pages_read == len(MANIFEST[name]["pages"])
    assert {voxel_name(int(c.keys[i])): int(c.counts[i]) for i in nodes} == MANIFEST[name]["nodes"]
    parts = [c.node_points(i) for i in nodes]
    got = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    assert len(got["xyz"]) == N  # every node's points once
    h = las.header
    for a, axis in enumerate("XYZ"):  # positions on the file's grid, exactly
        np.testing.assert_array_equal(np.rint((got["xyz"][:, a] - h.offsets[a]) / h.scales[a]).astype(np.int64), np.asarray(las[axis]))
    for k in CHECKED:
        np.testing.assert_array_equal(got[k], np.asarray(las[k]), err_msg=k)
    fmt = h.point_format.id
    if fmt >= 7:
        np.testing.assert_array_equal(got["rgba"].view(np.uint8).reshape(-1, 4)[:, :3], _rgb8(las))
    if fmt == 8:
        np.testing.assert_array_equal(got["nir"], np.asarray(las.nir))
        for f in ("FIELD_0", "FIELD_1"):  # copclib's extra bytes (EbVlr(2)): unsigned chars
            assert got[f].dtype == np.uint8
            np.testing.assert_array_equal(got[f], np.asarray(las[f]), err_msg=f)
        assert int(got["FIELD_1"].astype(np.int64).sum()) == int(np.asarray(las.FIELD_1).astype(np.int64).sum()) > 0


@pytest.mark.parametrize("name", FILES)
def test_copclib_file_reads_flat_and_progressively(name):
    path = DATA / name
    las = laspy.read(path)
    want = np.sort(np.asarray(las.gps_time))
    flat = gp.open(path, chunk_size=8_000)
    assert flat.n_points == N
    np.testing.assert_array_equal(np.sort(flat.attributes["gps_time"]), want)
    p = gp.open(path, progressive=True)
    assert p.wait(120) and p.error is None and p.n_points == N
    chunks = list(p.chunks())
    np.testing.assert_array_equal(np.sort(np.concatenate([ch.attributes["gps_time"] for ch in chunks])), want)
    assert int(sum(ch.attributes["intensity"].astype(np.int64).sum() for ch in chunks)) == int(np.asarray(las.intensity).astype(np.int64).sum())


@pytest.mark.parametrize("name", FILES)
def test_copclib_file_renders_like_its_points(name):
    path = DATA / name
    las = laspy.read(path)
    xyz = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], 1)
    rgb = _rgb8(las) if las.header.point_format.id >= 7 else None
    brute = gp.from_arrays(xyz, rgb, colors="rgba")
    c = gp.open(path)
    s = gp.RenderSettings(backend="cpu", size_mode="fixed", point_budget=10**9, lod_threshold_px=0.0)
    for view in ("top", "iso"):
        cam = gp.Camera.fit(brute.bounds, view=view, width=200, height=150)
        a, b = gp.render_frame(c, cam, s), gp.render_frame(brute, cam, s)
        assert a.stats.points_processed == b.stats.points_processed == N
        covered = (~b.empty).mean()
        assert covered > 0.1  # the sample fills the view
        assert (a.empty != b.empty).mean() < 0.002
        if rgb is not None:
            assert np.all(a.image == b.image, axis=2).mean() > 0.95
    # a budgeted frame draws the top of the octree: fewer points, spread over the whole view
    few = gp.render_frame(gp.open(path), cam, s.replace(point_budget=3_000, lod_threshold_px=50.0))
    assert 0 < few.stats.points_processed < N and (~few.empty).mean() > 0.1 * covered


def test_copclib_shared_key_pages_are_read_when_drawn():
    """copclib lists a page's key twice in the parent page: the node (its points) and the
    pointer to the page below it; the node draws before its page is read."""
    path = DATA / "shared_keys.copc.laz"
    c = gp.open(path)
    assert c.pages_read == 1 and c.pending_pages == 4  # the depth-1 pages; three more below them
    full = c.counts > 0
    assert full.sum() == 7 and int(c.counts[full].sum()) == sum(v for k, v in MANIFEST[path.name]["nodes"].items() if k < "2")
    cam = gp.Camera.fit(c.bounds, view="top", width=64, height=48)
    gp.render_frame(c, cam, gp.RenderSettings(backend="cpu", point_budget=N, lod_threshold_px=0.0))
    assert c.pending_pages == 0 and int(c.counts.sum()) == N


# --------------------------------------------------------------------------- copclib reads gigapoint's


@pytest.fixture(scope="module")
def ours(tmp_path_factory):
    if not AUTZEN.exists():
        pytest.skip("shared sample autzen_trim.laz not present")
    d = tmp_path_factory.mktemp("ours")
    convert([AUTZEN], d / "a.copc.laz", format="copc", max_leaf=4_000, partition_points=30_000)
    g = gp.open(d / "a.copc.laz").to_memory()
    nodes = []
    for i in range(len(g.keys)):  # the same octree written with a page a level (write_copc's page_level)
        p = g.node_points(i) if g.counts[i] else {"xyz": np.zeros((0, 3)), "rgba": np.zeros(0, np.uint32)}
        rgb = p["rgba"].view(np.uint8).reshape(-1, 4)[:, :3].astype(np.uint16) * 257
        nodes.append((int(g.keys[i]), p["xyz"], rgb, {k: p[k] for k in ("intensity", "classification") if k in p}))
    write_copc(d / "paged.copc.laz", nodes, scale=[0.01] * 3, offset=[0.0] * 3, cube_min=g.meta["cube_min"],
               cube_edge=g.meta["cube_edge"], page_level=1)  # fmt: skip
    return d


@pytest.mark.parametrize("name", ["a.copc.laz", "paged.copc.laz"])
def test_copclib_reads_gigapoints_copc(ours, name):
    copc = pytest.importorskip("copclib")
    src = laspy.read(AUTZEN)
    r = copc.FileReader(str(ours / name))
    nodes = r.GetAllNodes()
    assert sum(n.point_count for n in nodes) == r.copc_config.las_header.point_count == 110_000
    assert len({(n.key.d, n.key.x, n.key.y, n.key.z) for n in nodes}) == len(nodes)  # each node once
    assert r.ValidateSpatialBounds(False)  # every node's points inside its cube
    pages = {(k.d, k.x, k.y, k.z) for k in r.GetPageList()}
    assert len(pages) == 1 if name == "a.copc.laz" else len(pages) > 5
    assert {(n.page_key.d, n.page_key.x, n.page_key.y, n.page_key.z) for n in nodes} <= pages
    pts = r.GetAllPoints()
    assert len(pts) == 110_000
    got = np.rint(np.stack([np.asarray(pts.x), np.asarray(pts.y), np.asarray(pts.z)], 1) / 0.01).astype(np.int64)
    want = np.stack([np.asarray(src.X), np.asarray(src.Y), np.asarray(src.Z)], 1)
    np.testing.assert_array_equal(got[np.lexsort(got.T)], want[np.lexsort(want.T)])
    assert int(np.asarray(pts.classification).astype(np.int64).sum()) == int(np.asarray(src.classification).astype(np.int64).sum())
    if name == "a.copc.laz":
        assert "Lambert_Conformal_Conic" in r.copc_config.wkt


@pytest.mark.parametrize("pointer", [False, True])
def test_a_key_twice_of_the_same_kind_is_still_an_error(tmp_path, pointer):
    """A node listed twice, or two pointers to pages of one key, is no layout: one line."""
    from gigapoint.errors import InputError
    from gigapoint.lod.copc import COPC_INFO_DTYPE, HIERARCHY_ENTRY_DTYPE, INFO_OFFSET

    b = bytearray((DATA / "shared_keys.copc.laz").read_bytes())
    info = np.frombuffer(bytes(b), COPC_INFO_DTYPE, count=1, offset=INFO_OFFSET)[0]
    off, size = int(info["root_hier_offset"]), int(info["root_hier_size"])
    page = np.frombuffer(bytes(b[off : off + size]), HIERARCHY_ENTRY_DTYPE).copy()
    same = np.flatnonzero((page["point_count"] == -1) == pointer)
    page[same[1]] = page[same[0]]  # that entry twice
    b[off : off + size] = page.tobytes()
    (tmp_path / "bad.copc.laz").write_bytes(bytes(b))
    with pytest.raises(InputError, match=rf"bad\.copc\.laz: the hierarchy page at byte {off:,} lists a node twice"):
        gp.open(tmp_path / "bad.copc.laz")


def test_the_crs_copclib_writes_in_an_evlr_is_read_and_carried(tmp_path):
    """copclib writes its WKT as an EVLR (LASF_Projection 2112), not a VLR: the octree's meta,
    ``info`` and a conversion of the file all have it."""
    from gigapoint.lod import octree_info

    path = DATA / "one_page.copc.laz"
    header = laspy.read(path).header
    assert not header.vlrs.get("WktCoordinateSystemVlr")
    want = header.evlrs.get("WktCoordinateSystemVlr")[0].string.strip("\0")
    assert want.startswith('PROJCS["NAD_1983_HARN_Lambert_Conformal_Conic"')
    assert gp.open(path).meta["crs"] == want and octree_info(path)["crs"] == want
    assert gp.open(DATA / "own_pages.copc.laz").meta["crs"] is None  # (written without one)
    convert([path], tmp_path / "again.copc.laz", format="copc")
    with laspy.open(tmp_path / "again.copc.laz") as r:  # gigapoint's COPC: a WKT VLR
        assert r.header.vlrs.get("WktCoordinateSystemVlr")[0].string.strip("\0") == want
    assert gp.open(tmp_path / "again.copc.laz").meta["crs"] == want


def crs_past_a_mib(folder) -> Path:
    """one_page.copc.laz with a 1.2 MiB EVLR put between its hierarchy EVLR and its WKT EVLR
    (the EVLRs' count 2 -> 3; nothing moves before it): its CRS lies past the first MiB of EVLRs."""
    data = bytearray((DATA / "one_page.copc.laz").read_bytes())
    start = int.from_bytes(data[235:243], "little")
    wkt_at = start + 60 + int.from_bytes(data[start + 20 : start + 28], "little")
    filler = 1_200_000
    head = (b"\0\0" + b"filler".ljust(16, b"\0") + (1).to_bytes(2, "little") + filler.to_bytes(8, "little") + b"\0" * 32)
    data[243:247] = (3).to_bytes(4, "little")
    path = Path(folder) / "far_crs.copc.laz"
    path.write_bytes(bytes(data[:wkt_at]) + head + b"x" * filler + bytes(data[wkt_at:]))
    return path


def test_a_crs_past_the_first_mib_of_evlrs_is_found_in_a_local_file(tmp_path, monkeypatch):
    """The WKT EVLR 1.2 MiB past the hierarchy's: the octree had no CRS (its EVLRs read in one
    go only within 1 MiB). A local file's EVLR headers are read one by one, then the WKT's bytes
    (not the filler's); the LAS header parse (mixed CRSs, convert) finds it too."""
    from gigapoint.io.http import LocalFile
    from gigapoint.io.las import read_las_header

    want = laspy.read(DATA / "one_page.copc.laz").header.evlrs.get("WktCoordinateSystemVlr")[0].string.strip("\0")
    path = crs_past_a_mib(tmp_path)
    assert laspy.read(path).header.evlrs.get("WktCoordinateSystemVlr")[0].string.strip("\0") == want  # (a valid file)
    sizes, read = [], LocalFile.read
    monkeypatch.setattr(LocalFile, "read", lambda self, o, k: sizes.append(k) or read(self, o, k))
    assert gp.open(path).meta["crs"] == want
    assert max(sizes) < 100_000, sizes
    assert read_las_header(path).crs() == want and gp.io.file_info(path)["crs"] == want


def test_a_hierarchy_without_a_root_node_draws_at_any_size():
    """nir_extra's hierarchy starts at depth 1 (no root entry: an empty root); a small view,
    whose depth-1 cubes are under the LOD threshold, still draws them, not an empty image."""
    c = gp.open(DATA / "nir_extra.copc.laz")
    assert c.counts[0] == 0 and int(c.keys[0]) == 1
    depth1 = sum(v for k, v in MANIFEST["nir_extra.copc.laz"]["nodes"].items() if k.startswith("1-"))
    cam = gp.Camera.fit(c.bounds, width=64, height=48)
    s = gp.RenderSettings(backend="cpu", lod_threshold_px=100.0)
    f = gp.render_frame(c, cam, s)
    assert f.stats.points_processed == depth1 == 6_496 and (~f.empty).sum() > 300
