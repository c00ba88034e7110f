"""COPC: VoxelKey <-> integer keys, gigapoint's writer read back by laspy's CopcReader and by
gigapoint itself (point for point, image for image), hierarchy pages on demand, the CRS carried
through, and malformed files failing in one line."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import gigapoint as gp
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.errors import InputError
from gigapoint.io import laz_process
from gigapoint.lod import CopcCloud, OctreeCloud, convert, open_copc, open_octree
from gigapoint.lod.copc import COPC_INFO_DTYPE, HIERARCHY_ENTRY_DTYPE, INFO_OFFSET, LAS14_HEADER_DTYPE
from gigapoint.lod.copc_write import hierarchy_pages, write_copc
from gigapoint.lod.keys import key_cube
from gigapoint.lod.voxel_octree import key_to_voxel, voxel_name, voxel_to_key

laspy = pytest.importorskip("laspy")

AUTZEN = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "autzen_trim.laz"
OPTS = {"max_leaf": 4_000, "partition_points": 30_000}


# --------------------------------------------------------------------------- keys


def test_voxel_keys_map_onto_integer_keys_with_potree_child_order():
    # one level: the child digit is x·4 + y·2 + z
    assert voxel_to_key(0, 0, 0, 0).tolist() == [1]
    assert voxel_to_key([1, 1, 1], [1, 0, 0], [0, 1, 0], [0, 0, 1]).tolist() == [0o14, 0o12, 0o11]
    # two levels: x = 0b11, y = 0, z = 0b01 -> digits (1,0,0) = 4 then (1,0,1) = 5
    assert voxel_to_key(2, 3, 0, 1).tolist() == [(1 << 6) | (4 << 3) | 5]
    assert voxel_name((1 << 6) | (4 << 3) | 5) == "2-3-0-1"


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 20).flatmap(lambda d: st.tuples(st.just(d), *(st.integers(0, 2**d - 1),) * 3)))
def test_voxel_key_round_trip_and_cube(dxyz):
    d, x, y, z = dxyz
    key = voxel_to_key(d, x, y, z)
    assert [int(v[0]) for v in key_to_voxel(key)] == [d, x, y, z]
    assert int(key[0]) >> 3 == (int(voxel_to_key(d - 1, x >> 1, y >> 1, z >> 1)[0]) if d else 0)
    cmin, edge = key_cube(key, [10.0, 20.0, 30.0], 64.0)
    # laspy's VoxelKey.bounds: mins + (x, y, z) * side; the same cube
    np.testing.assert_allclose(cmin[0], np.array([10.0, 20.0, 30.0]) + np.array([x, y, z]) * 64.0 / 2**d)
    assert edge[0] == 64.0 / 2**d


def test_hierarchy_pages_split_at_page_levels():
    keys = [1, 8, 9, 64, 65, 72, 512]  # root, two children, grandchildren under 8 and 9, one great-grandchild
    entries = {k: (1000 + k, 10, 5) for k in keys}
    pages = hierarchy_pages(entries, 500, page_level=1)
    roots = [r for r, _ in pages]
    assert roots == [1, 8, 9, 64]  # nodes with children at levels 1, 2, 3... head pages
    by_root = dict(pages)
    root_page = by_root[1]
    assert root_page["point_count"].tolist() == [5, -1, -1]  # the root itself, then pointers to 8 and 9
    assert root_page["offset"][1] == 500 + root_page.nbytes  # page of node 8 right after the root page
    assert sorted(voxel_to_key(*(by_root[8]["key"][f] for f in ("level", "x", "y", "z"))).tolist()) == [8, 64, 65]
    assert by_root[8]["point_count"].tolist() == [5, -1, 5]  # 64 has a child: its own page
    total = sum(p.nbytes for _, p in pages)
    assert sum(len(p) for _, p in pages) * HIERARCHY_ENTRY_DTYPE.itemsize == total
    assert sum((p["point_count"] >= 0).sum() for _, p in pages) == len(keys)


# --------------------------------------------------------------------------- written by gigapoint


@pytest.fixture(scope="module")
def autzen_octrees(tmp_path_factory):
    if not AUTZEN.exists():
        pytest.skip("shared sample autzen_trim.laz not present")
    d = tmp_path_factory.mktemp("copc")
    convert([AUTZEN], d / "g", layout="words", **OPTS)  # format 1: the tight node boxes the COPC reader quantizes in too
    convert([AUTZEN], d / "a.copc.laz", format="copc", **OPTS)
    convert([AUTZEN], d / "p", format="potree", **OPTS)
    return d


def test_laspy_copc_reader_reads_every_point_and_the_hierarchy(autzen_octrees):
    path = autzen_octrees / "a.copc.laz"
    src = laspy.read(AUTZEN)
    with laspy.CopcReader.open(path) as r:
        assert r.header.version.minor == 4 and r.header.point_format.id == 7
        pts = r.query()
        assert len(pts) == len(src.points) == 110_000
        got = np.lexsort((np.asarray(pts.X), np.asarray(pts.Y), np.asarray(pts.Z)))
        want = np.lexsort((np.asarray(src.X), np.asarray(src.Y), np.asarray(src.Z)))
        for a, b in (("X", "X"), ("Y", "Y"), ("Z", "Z"), ("intensity", "intensity"), ("classification", "classification")):
            np.testing.assert_array_equal(np.asarray(pts[a])[got], np.asarray(src[b])[want], err_msg=a)
        np.testing.assert_array_equal(np.asarray(pts.gps_time)[got], np.asarray(src.gps_time)[want])
        np.testing.assert_array_equal(np.asarray(pts.return_number)[got], np.asarray(src.return_number)[want])
        red = np.asarray(src.red)[want]
        red8 = red >> 8 if red.max() > 255 else red  # autzen_trim holds 8-bit values in its 16-bit fields
        np.testing.assert_array_equal(np.asarray(pts.red)[got], red8 * 257)  # COPC: 16-bit colors
        # the hierarchy: the root page's entries are the gigapoint octree's nodes and counts
        from laspy.copc import HierarchyPage

        r.source.seek(r.copc_info.hierarchy_root_offset)
        page = HierarchyPage.from_bytes(r.source.read(r.copc_info.hierarchy_root_size))
        entries = {(k.level, k.x, k.y, k.z): e.point_count for k, e in page.entries.items()}
    g = open_octree(autzen_octrees / "g")
    want = {tuple(int(v) for v in dxyz): int(c) for *dxyz, c in zip(*key_to_voxel(g.keys), g.counts)}
    assert entries == want
    # laspy's level queries see the same levels
    with laspy.CopcReader.open(path) as r:
        assert len(r.query(level=0)) == int(g.counts[0])


def test_gigapoint_reads_its_copc_back_point_for_point(autzen_octrees):
    g = open_octree(autzen_octrees / "g")
    c = gp.open(autzen_octrees / "a.copc.laz")
    assert isinstance(c, CopcCloud) and isinstance(c, OctreeCloud)
    assert c.n_points == g.n_points == 110_000
    np.testing.assert_array_equal(c.keys, g.keys)
    np.testing.assert_array_equal(c.counts, g.counts)
    src = gp.open(AUTZEN)  # the flat reading of the input: its attributes are what COPC must carry
    # under point format 7's names: format 3's scan angle in degrees is scan_angle, 0.006 degree units
    assert c.attribute_names == sorted({*src.attributes, "scan_angle", "overlap", "scanner_channel"} - {"scan_angle_rank"})
    for i in np.flatnonzero(g.counts > 0).tolist():
        a, b = g.node_points(i), c.node_points(i)
        np.testing.assert_array_equal(b["xyz"], a["xyz"])  # same points, same order, same tight bbox
        np.testing.assert_array_equal(b["rgba"], a["rgba"])
        for k in set(src.attributes) - {"scan_angle_rank"}:
            np.testing.assert_array_equal(b[k], a[k], err_msg=k)
        np.testing.assert_array_equal(b["scan_angle"], np.rint(a["scan_angle_rank"] / 0.006).astype(np.int16))
        assert not b["overlap"].any() and not b["scanner_channel"].any()
    np.testing.assert_array_equal(c.nodes["bbox_min"], g.nodes["bbox_min"])


@pytest.mark.parametrize("adaptive", [False, True])
def test_copc_renders_like_the_gigapoint_octree_and_brute_force(autzen_octrees, adaptive):
    g = open_octree(autzen_octrees / "g")
    g.filtered_colors = False  # COPC points carry their own colors
    c = gp.open(autzen_octrees / "a.copc.laz")
    flat = gp.open(AUTZEN, colors="rgba")  # the octrees keep 32-bit colours; a compact cloud's are 16-bit by default
    s = gp.RenderSettings(backend="cpu", adaptive_precision=adaptive, size_mode="fixed")  # one pixel a point: the exact comparison
    for view in ("iso", "top"):
        cam = gp.Camera.fit(g.bounds, view=view, width=320, height=240)
        for budget, threshold in ((10**9, 0.0), (30_000, 100.0)):
            a = gp.render_frame(g, cam, s.replace(point_budget=budget, lod_threshold_px=threshold))
            b = gp.render_frame(c, cam, s.replace(point_budget=budget, lod_threshold_px=threshold))
            assert a.stats.points_processed == b.stats.points_processed
            np.testing.assert_array_equal(b.image, a.image)
        full = gp.render_frame(c, cam, s.replace(point_budget=10**9, lod_threshold_px=0.0))
        brute = gp.render_frame(flat, cam, s)
        assert full.stats.points_processed == brute.stats.points_processed == 110_000
        assert (full.empty != brute.empty).mean() < (0.05 if adaptive else 0.002)
        assert np.all(full.image == brute.image, axis=2).mean() > (0.8 if adaptive else 0.95)


def test_crs_carried_into_copc_and_potree(autzen_octrees):
    import json

    want = laspy.read(AUTZEN).header.vlrs.get("WktCoordinateSystemVlr")[0].string.strip("\0")
    c = gp.open(autzen_octrees / "a.copc.laz")
    assert c.meta["crs"] == want
    with laspy.open(autzen_octrees / "a.copc.laz") as r:
        assert r.header.vlrs.get("WktCoordinateSystemVlr")[0].string.strip("\0") == want
        assert r.header.global_encoding.wkt
    meta = json.loads((autzen_octrees / "p" / "metadata.json").read_text())
    assert meta["projection"] == want
    from gigapoint.lod import octree_info

    info = octree_info(autzen_octrees / "a.copc.laz")
    assert info["crs"] == want and info["levels"] == len(info["points_per_level"]) and sum(info["points_per_level"]) == 110_000
    # gigapoint's own octree holds it too (octree.json), and info shows it
    assert json.loads((autzen_octrees / "g" / "octree.json").read_text())["crs"] == want
    assert open_octree(autzen_octrees / "g").meta["crs"] == want and octree_info(autzen_octrees / "g")["crs"] == want


def test_crs_carried_from_a_progressive_octree_to_what_it_saves(tmp_path):
    """A progressive octree loads chunks, not files; its save() still takes the files' CRS and LAS grid."""
    import json

    if not AUTZEN.exists():
        pytest.skip("shared sample not present")
    want = laspy.read(AUTZEN).header.vlrs.get("WktCoordinateSystemVlr")[0].string.strip("\0")
    cloud = gp.open(AUTZEN, progressive=True)
    cloud.wait()
    cloud.save(tmp_path / "g", **OPTS)
    cloud.save(tmp_path / "c.copc.laz", format="copc", **OPTS)
    assert json.loads((tmp_path / "g" / "octree.json").read_text())["crs"] == want
    with laspy.open(tmp_path / "c.copc.laz") as r:
        assert r.header.vlrs.get("WktCoordinateSystemVlr")[0].string.strip("\0") == want
        np.testing.assert_array_equal(r.header.scales, laspy.read(AUTZEN).header.scales)  # the file's grid, not a guess
    demo = gp.demo(20_000, progressive=True)  # no file: no CRS, and saving still works
    demo.wait()
    demo.save(tmp_path / "d", **OPTS)
    assert json.loads((tmp_path / "d" / "octree.json").read_text())["crs"] is None


def test_plain_laz_still_opens_flat_and_is_not_copc(tmp_path):
    if not AUTZEN.exists():
        pytest.skip("shared sample not present")
    renamed = tmp_path / "not.copc.laz"
    shutil.copy(AUTZEN, renamed)
    for p in (AUTZEN, renamed):
        cloud = gp.open(p)
        assert not isinstance(cloud, OctreeCloud) and cloud.n_points == 110_000
    # autzen is LAZ 1.2: it was called "a LAS 1.4 file without the COPC info VLR first"
    with pytest.raises(InputError, match=r"not\.copc\.laz: not a COPC file \(a LAZ 1\.2 file without the COPC info VLR first\)") as e:
        gp.lod.open_copc(renamed)
    assert "\n" not in str(e.value)


def test_a_copc_file_reads_flat_through_the_las_reader(autzen_octrees):
    """A COPC file is a LAS 1.4 file: gp.open(..., chunk_size=...) reads it flat, every point."""
    flat = gp.open(autzen_octrees / "a.copc.laz", chunk_size=50_000)
    assert not isinstance(flat, OctreeCloud) and flat.n_points == 110_000


# --------------------------------------------------------------------------- hierarchy pages on demand


def _nodes_of(octree: OctreeCloud):
    """(key, xyz, rgb16, attributes) of every node, decoded (for write_copc)."""
    for i in range(len(octree.keys)):
        p = octree.node_points(i) if octree.counts[i] else {"xyz": np.zeros((0, 3)), "rgba": np.zeros(0, np.uint32)}
        rgb = p["rgba"].view(np.uint8).reshape(-1, 4)[:, :3].astype(np.uint16) * 257
        yield int(octree.keys[i]), p["xyz"], rgb, {k: v for k, v in p.items() if k in ("intensity", "classification")}


@pytest.fixture(scope="module")
def paged(autzen_octrees, tmp_path_factory):
    g = gp.open(autzen_octrees / "a.copc.laz").to_memory()
    path = tmp_path_factory.mktemp("paged") / "paged.copc.laz"
    summary = write_copc(path, _nodes_of(g), scale=[0.01] * 3, offset=[0.0] * 3,
                         cube_min=g.meta["cube_min"], cube_edge=g.meta["cube_edge"], page_level=1)  # fmt: skip
    assert summary["pages"] > 5
    return path, g


def test_child_pages_are_read_only_when_drawn(paged):
    path, g = paged
    c = gp.open(path)
    assert c.pending_pages > 0 and len(c.keys) < len(g.keys)
    cam = gp.Camera.fit(g.bounds, view="iso", width=160, height=120)
    s = gp.RenderSettings(backend="cpu", point_budget=15_000, size_mode="fixed")
    gp.render_frame(c, cam, s)
    assert c.pages_read > 1 and c.pending_pages > 0  # the pages the view needed, not all
    with laspy.CopcReader.open(path) as r:  # laspy follows the same child pages
        assert len(r.query()) == 110_000
    full = gp.render_frame(c, cam, s.replace(point_budget=10**9, lod_threshold_px=0.0))
    ref = gp.render_frame(g, cam, s.replace(point_budget=10**9, lod_threshold_px=0.0))
    assert c.pending_pages == 0 and full.stats.points_processed == 110_000
    np.testing.assert_array_equal(full.image, ref.image)


def test_nodes_resident_before_a_page_is_read_stay_resident(paged):
    path, g = paged
    c = gp.open(path)
    cam = gp.Camera.fit(g.bounds, view="iso", width=160, height=120)
    s = gp.RenderSettings(backend="cpu", point_budget=12_000, lod_threshold_px=50.0, size_mode="fixed")
    gp.render_frame(c, cam, s)
    loads = c.arena.loads
    resident = {int(c.keys[i]) for i in c.arena.resident}
    gp.render_frame(c, cam, s.replace(point_budget=60_000, lod_threshold_px=0.0))  # reads more pages: indices move
    assert {int(c.keys[i]) for i in c.arena.resident} >= resident
    again = gp.render_frame(c, cam, s.replace(point_budget=12_000, lod_threshold_px=50.0))
    assert c.arena.loads > loads and again.stats.points_processed <= 12_000
    np.testing.assert_array_equal(again.image, gp.render_frame(gp.open(path), cam, s).image)



def test_what_nodes_kept_follows_them_as_pages_are_read(paged):
    """Through hidden classes, a node once loaded is weighed by the points it kept (resident
    still or not: store.Arena.kept_counts); a page read numbers the nodes again, the counts
    follow them."""
    path, g = paged
    c = gp.open(path)
    c.arena = c.new_arena(800_000)  # (room for every node drawn here: never replaced)
    lo, hi = g.bounds
    corner = gp.Camera.fit((lo, lo + (hi - lo) * [0.3, 0.3, 1]), view="top", width=160, height=120)
    s = gp.RenderSettings(backend="cpu", point_budget=30_000, lod_threshold_px=0.0, size_mode="fixed", hidden_classes=(1,))
    gp.render_frame(c, corner, s)
    loaded = {int(c.keys[i]): i for i in c.arena.resident}
    gp.render_frame(c, gp.Camera.fit(g.bounds, view="iso", width=160, height=120), s.replace(point_budget=60_000))  # reads the other pages
    assert sum(int(c.keys[i]) != k for k, i in loaded.items()) == 3  # (nodes numbered again)
    loaded.update((int(c.keys[i]), i) for i in c.arena.resident)
    index_in_g = {k: i for i, k in enumerate(g.keys.tolist())}
    kept = [int(np.count_nonzero(g.node_points(index_in_g[k])["classification"] != 1)) if k in loaded else int(g.counts[index_in_g[k]]) for k in c.keys.tolist()]
    assert c.arena.kept_counts(c.counts, c.load_filter((1,)), None).tolist() == kept


# --------------------------------------------------------------------------- malformed files


def _patch(src: Path, dst: Path, offset: int, data: bytes) -> Path:
    b = bytearray(src.read_bytes())
    b[offset : offset + len(data)] = data
    dst.write_bytes(bytes(b))
    return dst


def _info(path: Path):
    b = path.read_bytes()
    hdr = np.frombuffer(b, LAS14_HEADER_DTYPE, count=1)[0]
    info = np.frombuffer(b, COPC_INFO_DTYPE, count=1, offset=INFO_OFFSET)[0]
    root = np.frombuffer(b, HIERARCHY_ENTRY_DTYPE, count=int(info["root_hier_size"]) // 32, offset=int(info["root_hier_offset"]))
    return b, hdr, info, root


def _draw(path: Path):
    cloud = gp.open(path)
    cloud.load_hierarchy()
    return gp.render_frame(cloud, gp.Camera.fit(cloud.bounds, width=64, height=48), gp.RenderSettings(backend="cpu", lod_threshold_px=0.0))


def _one_line_error(path, match):
    with pytest.raises(InputError, match=match) as e:
        _draw(path)
    assert "\n" not in str(e.value) and str(path) in str(e.value)
    return str(e.value)


def test_truncated_hierarchy_page(paged, tmp_path):
    path, _ = paged
    b, hdr, info, root = _info(path)
    off = INFO_OFFSET + COPC_INFO_DTYPE.fields["root_hier_size"][1]
    bad = _patch(path, tmp_path / "a.copc.laz", off, np.uint64(int(info["root_hier_size"]) - 12).tobytes())
    _one_line_error(bad, "truncated hierarchy page")
    cut = tmp_path / "cut.copc.laz"
    cut.write_bytes(b[: int(info["root_hier_offset"]) + 40])  # the file ends inside the root page
    with pytest.raises(InputError, match=rf"truncated COPC file: it has {len(cut.read_bytes()):,} bytes, its header says at least {len(b):,} .its hierarchy, .* is cut off"):
        open_copc(cut)  # as an octree (gp.open reads it as the plain LAZ file it still is: test_copc_cut.py)


def test_an_info_vlr_cube_that_does_not_hold_the_points(autzen_octrees, tmp_path):
    """A COPC info VLR whose cube misses the header's bounds (a 1 m cube, or one at the origin)
    culled every node: a blank image and "no point is in view". A cube too large for its nodes'
    keys draws what is decoded, and says once that the cubes do not match the points."""
    from gigapoint.errors import GigapointWarning

    path = autzen_octrees / "a.copc.laz"
    b, hdr, info, root = _info(path)
    center, half = info["center"].tolist(), float(info["halfsize"])
    at = INFO_OFFSET + COPC_INFO_DTYPE.fields["center"][1]
    for k, (c, h) in enumerate(((center, 1.0), ([0.0, 0.0, 0.0], half))):
        bad = _patch(path, tmp_path / f"c{k}.copc.laz", at, np.array([*c, h], np.float64).tobytes())
        _one_line_error(bad, r"corrupt COPC file \(header bounds, info VLR cube\): the points' bounds \[636002\.\.637179, .*\] lie outside the octree's cube")
    big = _patch(path, tmp_path / "big.copc.laz", at, np.array([*center, 1e15], np.float64).tobytes())
    with pytest.warns(GigapointWarning, match=r"big.copc.laz: node .*'s points \[.*\] lie outside its cube \[.*\]: the octree's cube does not match its points"):
        _draw(big)


def test_an_absurd_scale_is_a_corrupt_header(autzen_octrees, tmp_path):
    """A damaged scale (2e277 for z, found by flipping bytes) passed the finite check: its points
    decoded to z of 1e286 and drawing them gave NaN distances (an error naming no file)."""
    path = autzen_octrees / "a.copc.laz"
    at = LAS14_HEADER_DTYPE.fields["scale"][1] + 16  # the z scale
    bad = _patch(path, tmp_path / "s.copc.laz", at, np.array([2.269e277]).tobytes())
    _one_line_error(bad, r"corrupt COPC header: scale \[0\.01, 0\.01, 2\.269e\+277\] and offset \[.*\] put its points beyond any coordinate \(±1e\+12\)")


def test_chunk_offsets_past_the_end_of_the_file(paged, tmp_path):
    path, _ = paged
    b, hdr, info, root = _info(path)
    i = int(np.flatnonzero(root["point_count"] > 0)[0])
    where = int(info["root_hier_offset"]) + i * 32 + HIERARCHY_ENTRY_DTYPE.fields["offset"][1]
    bad = _patch(path, tmp_path / "b.copc.laz", where, np.uint64(len(b) + 1000).tobytes())
    msg = _one_line_error(bad, "lies past the end of the file")
    assert "node 0-0-0-0 has its chunk" in msg


def test_a_hierarchy_that_refers_to_itself(paged, tmp_path):
    path, _ = paged
    b, hdr, info, root = _info(path)
    i = int(np.flatnonzero(root["point_count"] == -1)[0])
    rec = root[i : i + 1].copy()
    rec["offset"], rec["byte_size"] = info["root_hier_offset"], info["root_hier_size"]  # a child page that is the root page
    bad = _patch(path, tmp_path / "c.copc.laz", int(info["root_hier_offset"]) + i * 32, rec.tobytes())
    _one_line_error(bad, "refers to itself")


def test_corrupt_keys_and_counts(paged, tmp_path):
    path, _ = paged
    b, hdr, info, root = _info(path)
    rec = root[1:2].copy()
    rec["key"]["x"] = 5  # outside the 2^1 grid of level 1
    bad = _patch(path, tmp_path / "d.copc.laz", int(info["root_hier_offset"]) + 32, rec.tobytes())
    _one_line_error(bad, "invalid node key 1-5-")
    rec = root[0:1].copy()
    rec["point_count"] = rec["point_count"] + 7  # the chunk holds fewer points than the entry says
    bad = _patch(path, tmp_path / "e.copc.laz", int(info["root_hier_offset"]), rec.tobytes())
    with pytest.raises(InputError, match="node 0-0-0-0") as e:
        _draw(bad)
    assert "\n" not in str(e.value)


# --------------------------------------------------------------------------- the CLI


def _cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "gigapoint.cli", *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=300)


def test_cli_convert_copc_info_and_render(tmp_path):
    if not AUTZEN.exists():
        pytest.skip("shared sample not present")
    out = tmp_path / "cli.copc.laz"
    r = _cli("convert", AUTZEN, "-o", out, "--format", "copc", "--max-leaf", "5000", "-q")
    assert r.returncode == 0, r.stderr
    assert out.is_file() and not (tmp_path / "cli.copc.laz.work").exists()
    r = _cli("convert", AUTZEN, "-o", out, "--format", "copc", "-q")
    assert r.returncode != 0 and "already exists; pass --overwrite" in r.stderr
    r = _cli("info", out)
    assert r.returncode == 0, r.stderr
    assert "COPC 1.4, point format 7" in r.stdout and "per level:" in r.stdout and "NAD_1983_HARN" in r.stdout
    assert "110,000" in r.stdout
    r = _cli("render", out, "-o", tmp_path / "x.png", "--width", "160", "--height", "120")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "x.png").stat().st_size > 500


def test_interrupted_copc_conversion_leaves_no_file_and_resumes(tmp_path, stop_conversion_after):
    if not AUTZEN.exists():
        pytest.skip("shared sample not present")
    out = tmp_path / "r.copc.laz"
    stop_conversion_after(1)
    with pytest.raises(KeyboardInterrupt):
        convert([AUTZEN], out, format="copc", max_leaf=3_000, partition_points=20_000)
    assert not out.exists() and (tmp_path / "r.copc.laz.work").is_dir()
    stop_conversion_after(None)
    res = convert([AUTZEN], out, format="copc", max_leaf=3_000, partition_points=20_000)
    assert res.resumed and out.is_file() and not (tmp_path / "r.copc.laz.work").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["r.copc.laz"]
    assert gp.open(out).n_points == 110_000


def test_attributes_without_a_las_field_go_to_extra_bytes(tmp_path):
    """Attributes point format 7 has no field for are written as LAS 1.4 extra bytes: laspy's
    CopcReader and gigapoint read them back point for point; what cannot be stored is named."""
    from gigapoint.core.chunk import PointChunk
    from gigapoint.errors import GigapointWarning

    rng = np.random.default_rng(3)
    n = 30_000
    xyz = np.round(rng.uniform(0, 100, (n, 3)), 3)
    rgba = rng.integers(0, 256, (n, 4), dtype=np.uint8)
    attrs = {
        "intensity": rng.integers(0, 65535, n).astype(np.uint16),
        "curvature": rng.normal(size=n).astype(np.float32),
        "label": rng.integers(0, 60_000, n).astype(np.uint16),
        "segment": rng.integers(-(2**40), 2**40, n).astype(np.int64),
        "ground": rng.random(n) < 0.5,
        "a_name_much_longer_than_thirty_two_bytes": np.zeros(n, np.uint8),
    }
    with pytest.warns(GigapointWarning, match="a_name_much_longer_than_thirty_two_bytes.*not written"):
        convert([PointChunk(xyz, rgba, attrs)], tmp_path / "x.copc.laz", format="copc", **OPTS)
    with laspy.CopcReader.open(tmp_path / "x.copc.laz") as r:
        pts = r.query()
        assert {"curvature", "label", "segment", "ground"} <= set(pts.point_format.extra_dimension_names)
        got_xyz = np.stack([pts.x, pts.y, pts.z], axis=1)
        got = {a: np.asarray(pts[a]) for a in ("intensity", "curvature", "label", "segment", "ground")}
    assert len(got_xyz) == n
    mm = lambda a: np.rint(a * 1000).astype(np.int64).T  # positions on their millimetre grid: exact ties
    want_order, got_order = np.lexsort(mm(xyz)), np.lexsort(mm(got_xyz))
    np.testing.assert_allclose(got_xyz[got_order], xyz[want_order], atol=5e-4)
    for a in ("intensity", "curvature", "label", "segment"):
        np.testing.assert_array_equal(got[a][got_order], attrs[a][want_order], err_msg=a)
    np.testing.assert_array_equal(got["ground"][got_order], attrs["ground"][want_order].astype(np.uint8))
    # gigapoint's own reader: the same values under the same names
    c = gp.open(tmp_path / "x.copc.laz")
    assert {"curvature", "label", "segment", "ground"} <= set(c.attribute_names)
    parts = [c.node_points(i) for i in np.flatnonzero(c.counts > 0).tolist()]
    mine = np.concatenate([p["xyz"] for p in parts])
    order = np.lexsort(mm(mine))
    for a in ("curvature", "label", "segment"):
        np.testing.assert_array_equal(np.concatenate([p[a] for p in parts])[order], attrs[a][want_order], err_msg=a)


@pytest.mark.parametrize("out", ["x.copc.laz", "octree"])
def test_an_attribute_of_several_values_a_point_is_converted_a_column_each(tmp_path, out):
    """An NPZ's (N, 3) normals and an (N, 2) attribute were left out of an octree conversion
    without a word (a COPC file, a gigapoint octree: neither had them). They are written a column
    each, as the point-file writers write them (``nx``, ``ny``, ``nz``; ``pair_0``, ``pair_1``),
    and read back under those names with their values."""
    rng = np.random.default_rng(6)
    n = 3000
    normals, pair = rng.normal(size=(n, 3)), rng.integers(-(2**31), 2**31 - 1, (n, 2)).astype(np.int32)
    np.savez(tmp_path / "pts.npz", xyz=rng.uniform(0, 50, (n, 3)), normals=normals, pair=pair, index=np.arange(n, dtype=np.uint32))
    gp.convert(tmp_path / "pts.npz", tmp_path / out)
    c = open_octree(tmp_path / out)
    want = {"nx": normals[:, 0], "ny": normals[:, 1], "nz": normals[:, 2], "pair_0": pair[:, 0], "pair_1": pair[:, 1]}
    assert {*want, "index"} <= set(c.attribute_names)
    parts = [c.node_points(i) for i in np.flatnonzero(c.counts > 0).tolist()]
    got = {a: np.concatenate([p[a] for p in parts]) for a in [*want, "index"]}
    at = np.argsort(got["index"])
    assert got["index"][at].tolist() == list(range(n))
    for a, v in want.items():
        assert got[a].dtype == v.dtype
        np.testing.assert_array_equal(got[a][at], v, err_msg=a)


def test_extra_bytes_descriptors_are_read_with_their_scale(tmp_path):
    """A COPC written elsewhere with a scaled extra bytes field: gigapoint applies scale and offset."""
    from gigapoint.lod.copc import EXTRA_BYTES_DTYPE, extra_fields, point_dtype

    d = np.zeros(3, EXTRA_BYTES_DTYPE)
    d[0]["data_type"], d[0]["name"] = 3, b"height_above_ground"
    d[0]["options"], d[0]["scale"][0], d[0]["offset"][0] = 8 | 16, 0.01, -5.0
    d[1]["data_type"], d[1]["options"] = 0, 3  # three undocumented bytes
    d[2]["data_type"], d[2]["name"] = 1, b"classification"  # clashes with a standard attribute: kept in place, not exposed
    fields = extra_fields([(b"LASF_Spec", 4, d.tobytes())])
    assert [f.name for f in fields] == ["height_above_ground", "_extra1", "_extra2"]
    rec = np.zeros(2, point_dtype(7, 36 + 2 + 3 + 1, fields))
    rec["height_above_ground"] = [500, 1234]
    np.testing.assert_allclose(fields[0].values(rec), [0.0, 7.34])
    with pytest.raises(ValueError, match="whole 192-byte descriptors"):
        extra_fields([(b"LASF_Spec", 4, d.tobytes()[:-1])])
    with pytest.raises(ValueError, match="smaller than point format 7 and 6 extra bytes"):
        point_dtype(7, 36 + 2, fields)


def test_extra_bytes_array_descriptors_hold_their_place_in_the_record():
    """Data types 11-20 are 2 values a point, 21-30 three (of type 1-10 of the same last digit):
    a 2 x uint16 array is ``pair_0``, ``pair_1`` after its 4 bytes' place; an array named as a
    standard field only holds its 3 x 8 bytes; 31 and up are one line naming the field."""
    from gigapoint.lod.copc import EXTRA_BYTES_DTYPE, extra_fields, point_dtype

    d = np.zeros(3, EXTRA_BYTES_DTYPE)
    d[0]["data_type"], d[0]["name"] = 1, b"flag"
    d[1]["data_type"], d[1]["name"] = 13, b"pair"  # 2 x unsigned short
    d[1]["options"], d[1]["scale"], d[1]["offset"] = 8, [0.5, 4.0, 0.0], [9.0, 9.0, 9.0]  # scaled, offsets not set
    d[2]["data_type"], d[2]["name"] = 30, b"gps_time"  # 3 x double, a standard attribute's name
    fields = extra_fields([(b"LASF_Spec", 4, d.tobytes())])
    assert [(f.attribute, f.scaling) for f in fields] == [("flag", None), ("pair_0", (0.5, 0.0)), ("pair_1", (4.0, 0.0)), ("_extra2", None)]
    rec = np.zeros(2, point_dtype(7, 36 + 1 + 4 + 24, fields))
    assert rec.dtype["pair"].shape == (2,) and rec.dtype["_extra2"].shape == (3,) and "extra_bytes" not in rec.dtype.names
    rec["pair"] = [[10, 20], [30, 40]]
    assert fields[1].values(rec).tolist() == [5.0, 15.0] and fields[2].values(rec).tolist() == [80.0, 160.0]
    d[2]["data_type"] = 31
    with pytest.raises(ValueError, match="field 'gps_time' has data type 31, which LAS 1.4 does not define"):
        extra_fields([(b"LASF_Spec", 4, d.tobytes())])


def test_a_scaled_float32_extra_bytes_field_is_scaled_in_float64():
    """A float32 extra bytes field with a scale came back float32 * scale, in float32 (NumPy 2
    keeps float32 times a Python float float32): 3e6 * 0.001 + 10 was 3010.000000 only to
    float32's 7 digits. It is scaled in float64, the attribute's dtype."""
    from gigapoint.lod.copc import EXTRA_BYTES_DTYPE, extra_fields

    d = np.zeros(1, EXTRA_BYTES_DTYPE)
    d[0]["data_type"], d[0]["name"] = 9, b"amplitude"  # 9: float
    d[0]["options"], d[0]["scale"][0], d[0]["offset"][0] = 8 | 16, 0.001, 10.0
    (field,) = extra_fields([(b"LASF_Spec", 4, d.tobytes())])
    rec = np.array([1234.567, -0.1, 3e6 + 1], [("amplitude", "<f4")])
    got = field.values(rec)
    assert field.value_dtype == got.dtype == np.float64
    np.testing.assert_array_equal(got, rec["amplitude"].astype(np.float64) * 0.001 + 10.0)


def _copc_with_arrays(path: Path, monkeypatch) -> Path:
    """A COPC file whose points hold LAS extra-bytes arrays, described as laspy describes them
    (data types 30 and 24 of LAS 1.4 R13, which R15 deprecates): ``normal`` (3 x float64),
    ``slope`` (3 x int16, each value its own scale and offset) and ``height`` (float32: the
    point's index, to match points up), in nodes 0-0-0-0 and its eight children."""
    from gigapoint.lod import copc_write
    from gigapoint.lod.copc import EXTRA_BYTES_RECORD, EXTRA_BYTES_USER_ID

    params = [
        laspy.ExtraBytesParams("normal", "3f8"),
        laspy.ExtraBytesParams("slope", "3i2", scales=np.array([0.5, 0.25, 2.0]), offsets=np.array([1.0, -2.0, 3.0])),
        laspy.ExtraBytesParams("height", "f4"),
    ]
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.add_extra_dims(params)
    descriptors = header.vlrs.get("ExtraBytesVlr")[0].record_data_bytes()
    monkeypatch.setattr(copc_write, "_extra_bytes_vlr", lambda extra: copc_write._vlr(EXTRA_BYTES_USER_ID, EXTRA_BYTES_RECORD, descriptors, "Extra Bytes"))
    rng = np.random.default_rng(8)
    keys = [1, *range(8, 16)]
    mins, edges = key_cube(keys, [0.0, 0.0, 0.0], 64.0)
    nodes, first = [], 0
    for key, lo, edge in zip(keys, mins, edges):
        n = 300
        attrs = {
            "normal": rng.normal(size=(n, 3)),
            "slope": rng.integers(-30_000, 30_000, (n, 3)).astype(np.int16),
            "height": np.arange(first, first + n, dtype=np.float32),
        }
        nodes.append((key, np.round(lo + rng.random((n, 3)) * edge, 2), None, attrs))
        first += n
    extra = {"normal": np.dtype(("<f8", (3,))), "slope": np.dtype(("<i2", (3,))), "height": np.dtype("<f4")}
    write_copc(path, nodes, scale=[0.01] * 3, offset=[0.0] * 3, cube_min=[0.0] * 3, cube_edge=64.0, extra=extra)
    return path


def test_extra_bytes_arrays_read_as_the_las_reader_names_them(tmp_path, monkeypatch):
    """A COPC file with LAS extra-bytes arrays (laspy's 3f8 normal, a scaled 3i2) was refused
    ("data type 30, which LAS 1.4 R15 no longer defines"), while the LAS reader opened the same
    file. Each value of an array is the attribute ``name_<k>``, as the LAS reader names it, with
    laspy's values (its own scale and offset applied), by nodes and for the whole file."""
    path = _copc_with_arrays(tmp_path / "arrays.copc.laz", monkeypatch)
    las = laspy.read(path)
    assert las.header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs[0].data_type == 30  # (laspy's code for 3 doubles)
    order = np.argsort(np.asarray(las.height))  # laspy's points in index order
    want = {f"normal_{k}": np.asarray(las.normal)[order, k] for k in range(3)}
    want |= {f"slope_{k}": np.asarray(las.slope)[order, k] for k in range(3)}
    assert want["slope_1"][:3].tolist() == (np.asarray(las.points.array["slope"])[order[:3], 1] * 0.25 - 2.0).tolist()  # (scaled)
    c = gp.open(path)
    assert isinstance(c, CopcCloud) and {*want, "height"} <= set(c.attribute_names)
    assert "normal" not in c.attribute_names
    parts = [c.node_points(i) for i in np.flatnonzero(c.counts > 0).tolist()]
    by_nodes = {a: np.concatenate([p[a] for p in parts]) for a in [*want, "height"]}
    whole = c.to_memory().attributes
    flat = gp.open(path, progressive=True)  # the LAS reader's names of the same file
    flat.wait()
    assert set(want) <= set(flat.attribute_names)
    for got in (by_nodes, whole):
        at = np.argsort(got["height"])
        for a, v in want.items():
            assert got[a].dtype == np.float64
            np.testing.assert_array_equal(got[a][at], v, err_msg=a)


@pytest.mark.parametrize("where", [0.3, 0.4, 0.5])
def test_damaged_chunks_that_crash_or_panic_lazrs_are_one_line_errors(autzen_octrees, tmp_path, monkeypatch, where):
    """20 kB of 0xFF in a node's compressed points: at 0.3 of the file lazrs's decoder crashes
    (SIGSEGV: it recurses until the stack overflows), at 0.4 it panics (pyo3's PanicException,
    a BaseException), at 0.5 it fails. Each is one line naming the file and the node: the nodes
    are decoded in a child process (io/laz_process.decode_block), which this process outlives."""
    src = autzen_octrees / "a.copc.laz"
    before = _draw(src).visibility
    at = int(src.stat().st_size * where)
    msg = _one_line_error(_patch(src, tmp_path / "bad.copc.laz", at, b"\xff" * 20_000), r"bad\.copc\.laz: cannot decode node \d+-\d+-\d+-\d+")
    assert {0.3: "crashed with SIGSEGV", 0.4: "PanicException", 0.5: "LazrsError"}[where] in msg
    after = _draw(src).visibility  # the undamaged file draws as before, whatever became of the child
    assert np.count_nonzero(after != EMPTY_PIXEL) > 0 and np.array_equal(after, before)
    if where != 0.3:  # decoded in this process (no child: not Linux, or switched off), a panic or error is one line too
        monkeypatch.setenv(laz_process.ENV_SWITCH, "0")
        _one_line_error(tmp_path / "bad.copc.laz", r"bad\.copc\.laz: cannot decode node \d+-\d+-\d+-\d+")


def test_an_extra_bytes_name_with_a_slash_is_read_as_the_las_reader_reads_it(tmp_path):
    """An Extra Bytes field named 'a/b' (another writer's file) is the attribute 'a_b' (octrees
    store attributes in files named after them: 'attr.a/b.npy' broke conversions)."""
    from gigapoint.core.chunk import PointChunk

    rng = np.random.default_rng(4)
    chunk = PointChunk(rng.uniform(0, 50, (2000, 3)), None, {"a_b": np.arange(2000, dtype=np.uint16)})
    out = tmp_path / "s.copc.laz"
    gp.convert([chunk], out, format="copc")
    data = bytearray(out.read_bytes())
    at = data.find(b"a_b\0")
    data[at : at + 3] = b"a/b"  # the field's name in the Extra Bytes VLR
    (tmp_path / "slash.copc.laz").write_bytes(bytes(data))
    cloud = gp.open(tmp_path / "slash.copc.laz")
    got = np.concatenate([cloud.node_points(i)["a_b"] for i in range(len(cloud.keys))])
    assert sorted(got.tolist()) == list(range(2000))


def test_the_output_grid_keeps_the_inputs_and_fits_potrees_unsigned_integers():
    """lod/grid.py: a LAS input's grid is kept (COPC: its offset too); Potree's integers count
    from the grid line at or below the points (a LAS offset above them made them negative, the
    writer clipped them to 0) and fit 31 bits (an offset in the middle of 300 km at 0.1 mm)."""
    from gigapoint.io.las_fields import default_step
    from gigapoint.lod.grid import output_grid

    st = {"lo": [99.95, 0, 0], "hi": [110.0, 1, 1], "source": {"scale": [1e-4] * 3, "offset": [100.0, 0, 0]}}
    s, o = output_grid(st)
    np.testing.assert_array_equal(s, [1e-4] * 3)
    np.testing.assert_array_equal(o, [100.0, 0, 0])
    s, o = output_grid(st, unsigned=True)
    np.testing.assert_array_equal(s, [1e-4] * 3)
    assert np.all(o <= st["lo"]) and np.allclose((o - [100.0, 0, 0]) / s, np.round((o - [100.0, 0, 0]) / s))  # on the input's grid
    wide = {"lo": [0, 0, 0], "hi": [3e5, 1, 1], "source": {"scale": [1e-4] * 3, "offset": [1.5e5, 0, 0]}}
    s, o = output_grid(wide, unsigned=True)
    assert np.all((np.array(wide["hi"]) - o) / s < 2**31 - 1) and np.all(o <= wide["lo"])
    assert default_step([0, 0, 0], [0.1, 0.1, 0.1]) == 1e-6 and default_step([0, 0, 0], [500, 1, 1]) == 0.001  # (0.1 / 2**16's power of ten)
    assert default_step([1e11] * 3, [1e11 + 0.1] * 3) == 2e-15 * (1e11 + 0.1)  # float64 tells no finer steps apart there
    assert output_grid({"lo": [0, 0, 0], "hi": [1, 1, 1], "chunk_scale": [0.01] * 3})[0].tolist() == [0.01] * 3  # gp.demo's grid


def test_has_color_false_writes_chunks_without_rgb_and_is_refused_for_files(tmp_path):
    """Chunks (a cloud) whose points have no colours of their own: ``has_color=False`` gives the
    COPC file point format 6 (the chunks' grey was written as format 7 colours). Files say it
    themselves: there, and with a value not a switch, it is a one-line error."""
    import re

    import laspy

    xyz = np.random.default_rng(4).uniform(0, 50, (5_000, 3))
    convert(gp.from_arrays(xyz), tmp_path / "plain.copc.laz", has_color=False, **OPTS)
    with laspy.CopcReader.open(tmp_path / "plain.copc.laz") as r:
        assert r.header.point_format.id == 6 and len(r.query()) == 5_000
    convert(gp.from_arrays(xyz), tmp_path / "grey.copc.laz", **OPTS)  # (None: as the cloud's files say; it has none: colours)
    with laspy.CopcReader.open(tmp_path / "grey.copc.laz") as r:
        assert r.header.point_format.id == 7
    refused = "convert: has_color=False is for a cloud's or chunks' points; files say themselves whether they have colours"
    with pytest.raises(InputError, match=f"^{re.escape(refused)}$"):
        convert([tmp_path / "plain.copc.laz"], tmp_path / "again", has_color=False)
    with pytest.raises(InputError, match=r"^convert: has_color must be True or False or None, got 'no'$"):
        convert(gp.from_arrays(xyz), tmp_path / "again", has_color="no")
    assert not (tmp_path / "again").exists()


def test_nir_without_colors_is_format_6_with_nir_in_extra_bytes(tmp_path):
    """Points with NIR but no colors were written as format 8, every point grey (info: 'color:
    yes'): now format 6, NIR an extra bytes field read back under its name."""
    rng = np.random.default_rng(8)
    n = 20_000
    xyz = np.round(rng.uniform(0, 100, (n, 3)), 3)
    nir = rng.integers(0, 65535, n).astype(np.uint16)
    from plyfile import PlyData, PlyElement

    v = np.zeros(n, [("x", "f8"), ("y", "f8"), ("z", "f8"), ("nir", "u2")])
    v["x"], v["y"], v["z"], v["nir"] = *xyz.T, nir
    PlyData([PlyElement.describe(v, "vertex")]).write(str(tmp_path / "nir.ply"))
    out = tmp_path / "nir.copc.laz"
    convert([tmp_path / "nir.ply"], out, format="copc", **OPTS)
    with laspy.CopcReader.open(out) as r:
        assert r.header.point_format.id == 6 and "red" not in r.header.point_format.dimension_names
        pts = r.query()
        got_xyz, got_nir = np.stack([pts.x, pts.y, pts.z], axis=1), np.asarray(pts["nir"])
    mm = lambda a: np.rint(a * 1000).astype(np.int64).T
    np.testing.assert_array_equal(got_nir[np.lexsort(mm(got_xyz))], nir[np.lexsort(mm(xyz))])
    from gigapoint.lod import octree_info

    info = octree_info(out)
    assert info["point_format"] == 6 and info["has_color"] is False
    c = gp.open(out)
    assert "nir" in c.attribute_names
    parts = [c.node_points(i) for i in np.flatnonzero(c.counts > 0).tolist()]
    mine = np.concatenate([p["xyz"] for p in parts])
    np.testing.assert_array_equal(np.concatenate([p["nir"] for p in parts])[np.lexsort(mm(mine))], nir[np.lexsort(mm(xyz))])


@pytest.mark.parametrize("point_format,version", [(1, "1.2"), (6, "1.4")])
def test_scan_angle_user_data_and_flags_survive_a_copc_conversion(tmp_path, point_format, version):
    """The LAS reader read no scan angle, user data or flags, and the COPC writer wrote them all
    0: now read back by laspy as written (formats 0-5's scan_angle_rank, degrees, as LAS 1.4's
    scan_angle, 0.006 degree units), and by gigapoint's COPC reader under LAS 1.4's names."""
    rng = np.random.default_rng(point_format)
    n = 20_000
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales, header.offsets = [0.001] * 3, [0.0] * 3
    las = laspy.LasData(header)
    xyz = np.round(rng.uniform(0, 100, (n, 3)), 3)
    las.x, las.y, las.z = xyz.T
    flags = ["scan_direction_flag", "edge_of_flight_line", "synthetic", "key_point", "withheld"] + (["overlap"] if point_format >= 6 else [])
    want = {f: rng.integers(0, 2, n).astype(np.uint8) for f in flags}
    want["user_data"] = rng.integers(0, 256, n).astype(np.uint8)
    if point_format >= 6:
        want["scanner_channel"] = rng.integers(0, 4, n).astype(np.uint8)
        want["scan_angle"] = rng.integers(-30_000, 30_001, n).astype(np.int16)
        for name, v in want.items():
            las[name] = v
    else:
        rank = rng.integers(-90, 91, n).astype(np.int8)
        for name, v in want.items():
            las[name] = v
        las.scan_angle_rank = rank
        want["scan_angle"] = np.rint(rank / 0.006).astype(np.int16)  # degrees in 0.006 degree units (LAS 1.4)
        assert want["scan_angle"][rank == 18].tolist()[:1] == [3000]
    src = tmp_path / "in.las"
    las.write(str(src))
    out = tmp_path / "out.copc.laz"
    convert([src], out, format="copc", **OPTS)
    with laspy.CopcReader.open(out) as r:
        pts = r.query()
        got_xyz = np.stack([pts.x, pts.y, pts.z], axis=1)
        got = {name: np.asarray(pts[name]) for name in want}
    mm = lambda a: np.rint(a * 1000).astype(np.int64).T
    order, got_order = np.lexsort(mm(xyz)), np.lexsort(mm(got_xyz))
    assert len(got_xyz) == n and np.count_nonzero(want["scan_angle"]) > n // 2
    for name, v in want.items():
        np.testing.assert_array_equal(got[name][got_order], v[order], err_msg=name)
    c = gp.open(out)  # gigapoint's COPC reader: the same values
    parts = [c.node_points(i) for i in np.flatnonzero(c.counts > 0).tolist()]
    mine_order = np.lexsort(mm(np.concatenate([p["xyz"] for p in parts])))
    for name, v in want.items():
        np.testing.assert_array_equal(np.concatenate([p[name] for p in parts])[mine_order], v[order], err_msg=name)
