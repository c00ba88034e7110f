"""EPT datasets and COPC files that Entwine and PDAL wrote (PDAL's test data, data/pdal_ept/,
README.md there): read point for point as laspy (LAZ nodes) or numpy (binary records) decode
them, drawn like their points, and their damage refused in one line naming the file."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import gigapoint as gp
from gigapoint.errors import InputError
from gigapoint.lod import CopcCloud, EptCloud
from gigapoint.lod.voxel_octree import voxel_name

laspy = pytest.importorskip("laspy")

DATA = Path(__file__).resolve().parent / "data" / "pdal_ept"
COPC = ["1.2-with-color.copc.laz", "autzen_clip_native.copc.laz", "autzen_clip_4326.copc.laz"]
# full precision: the brute-force draw is of float64 positions (adaptive precision moves a
# point of a small node by up to a pixel, by design)
#: gigapoint's names of the LAS fields an EPT schema holds (binary: the same in PDAL's CamelCase)
LAS_FIELDS = ("intensity", "classification", "return_number", "number_of_returns", "point_source_id", "gps_time",
              "user_data", "scan_direction_flag", "edge_of_flight_line")  # fmt: skip
SETTINGS = gp.RenderSettings(backend="cpu", size_mode="fixed", point_budget=10**9, lod_threshold_px=0.0, adaptive_precision=False)


def _rgb8(rgb: np.ndarray) -> np.ndarray:
    """The 8-bit colours gigapoint shows for 16-bit fields (8-bit values in them as they are)."""
    return (rgb >> 8 if rgb.max() > 255 else rgb).astype(np.uint8)


def _assert_on_grid(xyz: np.ndarray, ints, scales, offsets) -> None:
    """Positions equal, on the file's integer grid (gigapoint keeps them node-relative)."""
    for a in range(3):
        np.testing.assert_array_equal(np.rint((xyz[:, a] - offsets[a]) / scales[a]).astype(np.int64), np.asarray(ints[a]))


def _records(name: str) -> tuple[np.ndarray, np.ndarray, list, list]:
    """A binary dataset's root node as numpy reads its schema: records, xyz, scales, offsets."""
    meta = json.loads((DATA / name / "ept.json").read_text())
    types = {"signed": "<i", "unsigned": "<u", "float": "<f"}
    dt = np.dtype([(d["name"], types[d["type"]] + str(d["size"])) for d in meta["schema"]])
    rec = np.fromfile(DATA / name / "ept-data" / "0-0-0-0.bin", dt)
    scale = {d["name"]: (d.get("scale", 1.0), d.get("offset", 0.0)) for d in meta["schema"]}
    xyz = np.stack([rec[a] * scale[a][0] + scale[a][1] for a in "XYZ"], 1)
    return rec, xyz, [scale[a][0] for a in "XYZ"], [scale[a][1] for a in "XYZ"]


def _all_points(cloud) -> dict:
    """Every node's points, nodes in key order."""
    cloud.load_hierarchy()
    parts = [cloud.node_points(int(i)) for i in np.flatnonzero(cloud.counts > 0)]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _renders_like(cloud, xyz: np.ndarray, rgb: np.ndarray | None) -> None:
    """``cloud`` drawn whole equals a brute-force draw of ``xyz`` (and ``rgb``), top and iso."""
    brute = gp.from_arrays(xyz, rgb, colors="rgba" if rgb is not None else "default")
    for view in ("top", "iso"):
        cam = gp.Camera.fit(brute.bounds, view=view, width=160, height=120)
        a, b = gp.render_frame(cloud, cam, SETTINGS), gp.render_frame(brute, cam, SETTINGS)
        assert a.stats.points_processed == b.stats.points_processed == len(xyz)
        assert (~b.empty).sum() > 0
        np.testing.assert_array_equal(a.empty, b.empty)
        assert (a.image != b.image).any(axis=2).sum() <= 3  # (of two points in a pixel at one depth, either)


def test_fixtures_are_small():
    files = [f for f in DATA.rglob("*") if f.is_file()]
    assert sum(f.stat().st_size for f in files) < 1_500_000
    assert len(list(DATA.glob("*/ept.json"))) == 7 and len(list(DATA.glob("*.copc.laz"))) == 3


def test_entwine_laszip_reads_point_for_point_and_draws_like_its_points():
    path = DATA / "1.2-with-color"
    c = gp.open(path)
    assert isinstance(c, EptCloud) and c.n_points == 1_065
    assert c.meta["crs"].startswith('PROJCS["NAD_1983_HARN_Lambert_Conformal_Conic"')
    las = laspy.read(path / "ept-data" / "0-0-0-0.laz")
    got, h = _all_points(c), las.header
    _assert_on_grid(got["xyz"], [las.X, las.Y, las.Z], h.scales, h.offsets)
    for k in LAS_FIELDS:
        np.testing.assert_array_equal(got[k], np.asarray(las[k]), err_msg=k)
    assert np.asarray(las.user_data).max() == 149 and np.asarray(las.scan_direction_flag).sum() == 567
    # degrees (format 3's scan_angle_rank) in LAS 1.4's 0.006 degree steps, as COPC's scan_angle
    np.testing.assert_array_equal(got["scan_angle"], np.rint(np.asarray(las.scan_angle_rank) / 0.006))
    rgb = _rgb8(np.stack([np.asarray(las[k]) for k in ("red", "green", "blue")], 1))
    np.testing.assert_array_equal(got["rgba"].view(np.uint8).reshape(-1, 4)[:, :3], rgb)
    _renders_like(gp.open(path), np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], 1), rgb)


def test_entwine_hierarchy_steps_are_read_when_drawn():
    """lone-star: the root page names five nodes -1 (their subtrees in files of their own);
    two of them hold a child at depth 3, whose points are read once its page is."""
    c = gp.open(DATA / "lone-star-laszip")
    assert c.n_points == 518_862 and c.meta["crs"] == "EPSG:26912"
    assert c.pages_read == 1 and c.pending_pages == 5
    c.load_hierarchy()
    assert c.pages_read == 6 and c.pending_pages == 0 and int(c.counts.sum()) == 518_862
    assert c.points_per_level() == [41_998, 166_916, 270_355, 39_593]
    index = {voxel_name(int(k)): i for i, k in enumerate(c.keys)}
    for name, n in (("3-5-4-3", 18_266), ("3-5-4-4", 21_327)):
        las = laspy.read(DATA / "lone-star-laszip" / "ept-data" / f"{name}.laz")
        assert int(c.counts[index[name]]) == n == len(las.points)
        p = c.node_points(index[name])
        h = las.header
        _assert_on_grid(p["xyz"], [las.X, las.Y, las.Z], h.scales, h.offsets)
        np.testing.assert_array_equal(p["gps_time"], np.asarray(las.gps_time))


def test_entwines_origin_ids_are_read():
    """PDAL's lone-star (Entwine, laszip): OriginId, the source file of each point, 0..3 in node 3-5-4-3."""
    c = gp.open(DATA / "lone-star-laszip")
    c.load_hierarchy()
    i = [voxel_name(int(k)) for k in c.keys].index("3-5-4-3")
    las = laspy.read(DATA / "lone-star-laszip" / "ept-data" / "3-5-4-3.laz")
    got = c.node_points(i)["OriginId"]
    np.testing.assert_array_equal(got, np.asarray(las["OriginId"]))
    assert np.bincount(got).tolist() == [7_788, 7_228, 2_223, 1_027]


@pytest.mark.parametrize("name", ["ellipsoid-binary-2k", "ellipsoid-zstandard-2k"])
def test_entwine_binary_and_zstandard_read_point_for_point(name):
    if name.startswith("ellipsoid-zstandard"):
        pytest.importorskip("zstandard")
    rec, xyz, scales, offsets = _records("ellipsoid-binary-2k")  # the zstandard node holds the same records
    c = gp.open(DATA / name)
    assert c.n_points == len(rec) == 2_000 and c.meta["crs"] == "EPSG:3857"
    got = _all_points(c)
    _assert_on_grid(got["xyz"], [rec["X"], rec["Y"], rec["Z"]], scales, offsets)
    for k in LAS_FIELDS:
        np.testing.assert_array_equal(got[k], rec["".join(w.title() for w in k.split("_"))], err_msg=k)
    assert rec["EdgeOfFlightLine"].sum() > 0 and np.ptp(rec["ScanAngleRank"]) > 50
    np.testing.assert_array_equal(got["scan_angle"], np.rint(rec["ScanAngleRank"] / 0.006))  # (float degrees)
    rgb = _rgb8(np.stack([rec["Red"], rec["Green"], rec["Blue"]], 1))
    np.testing.assert_array_equal(got["rgba"].view(np.uint8).reshape(-1, 4)[:, :3], rgb)
    _renders_like(gp.open(DATA / name), xyz, rgb)


def test_zstandard_without_its_package_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "zstandard", None)  # (import raises ImportError)
    path = DATA / "ellipsoid-zstandard-2k"
    with pytest.raises(InputError) as e:
        gp.open(path)
    assert str(e.value) == f"{path / 'ept.json'}: EPT dataType 'zstandard' needs the zstandard package (pip install 'gigapoint[lod]')"


def test_a_damaged_zstandard_node_is_one_line(tmp_path):
    pytest.importorskip("zstandard")
    import shutil

    d = tmp_path / "z"
    shutil.copytree(DATA / "ellipsoid-zstandard-2k", d)
    node = d / "ept-data" / "0-0-0-0.zst"
    data = bytearray(node.read_bytes())
    data[len(data) // 2 :] = b"\x00" * (len(data) - len(data) // 2)
    node.write_bytes(bytes(data))
    with pytest.raises(InputError, match=rf"^{node}: cannot decode node 0-0-0-0 \(.+\)$"):
        gp.open(d).node_points(0)
    (d / "ept-hierarchy" / "0-0-0-0.json").write_text('{"0-0-0-0": 1999}')  # a count the records are not
    node.write_bytes((DATA / "ellipsoid-zstandard-2k" / "ept-data" / "0-0-0-0.zst").read_bytes())
    with pytest.raises(InputError) as e:
        gp.open(d).node_points(0)
    assert str(e.value) == f"{node}: holds more than 87,956 bytes unpacked, 1,999 points of 44 bytes need 87,956"
    (d / "ept-hierarchy" / "0-0-0-0.json").write_text('{"0-0-0-0": 2001}')
    with pytest.raises(InputError) as e:
        gp.open(d).node_points(0)
    assert str(e.value) == f"{node}: holds 88,000 bytes unpacked, 2,001 points of 44 bytes need 88,044"


def test_bcbf_one_point_a_level_with_no_scale(tmp_path):
    """PDAL's toy set: XYZ only, no scale or offset (1 and 0), five nodes down to depth 4, each
    one point at 1, 1, 999."""
    c = gp.open(DATA / "bcbf")
    got = _all_points(c)
    assert sorted(voxel_name(int(k)) for k, n in zip(c.keys, c.counts) if n) == ["0-0-0-0", "1-1-1-1", "2-2-2-3", "3-4-4-7", "4-8-8-15"]
    np.testing.assert_array_equal(got["xyz"], [[1.0, 1.0, 999.0]] * 5)
    assert c.meta["crs"] == "+proj=geocent +R=1000 +units=m +no_defs"
    cam = gp.Camera.fit(c.bounds, view="top", width=64, height=64)
    f = gp.render_frame(c, cam, SETTINGS)
    brute = gp.render_frame(gp.from_arrays(got["xyz"]), cam, SETTINGS)
    assert f.stats.points_processed == 5 and (~f.empty).sum() == (~brute.empty).sum() >= 1
    np.testing.assert_array_equal(f.empty, brute.empty)
    # 'auto' frames a sample of the points: five at one spot framed the eye 5e-5 from them, in
    # front of the near plane that the 2 km cube sets (a blank image, "no point is in view")
    r = subprocess.run([sys.executable, "-m", "gigapoint.cli", "render", str(DATA / "bcbf"), "-o", str(tmp_path / "b.png"), "-W", "64", "-H", "48"],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0 and r.stderr == "", r.stderr
    assert (np.asarray(Image.open(tmp_path / "b.png"))[..., :3] > 0).any(axis=2).sum() >= 1
    # its count is its hierarchy's, 5 (ept.json says 10: "1 of 10 points drawn" where all were)
    assert r.stdout == f"wrote {tmp_path / 'b.png'} (64x48, 1 of 5 points drawn)\n"
    assert c.n_points == len(c) == 5 and c.meta["stated_points"] == 10


@pytest.mark.parametrize(
    ("name", "node", "message"),
    [
        ("ellipsoid-nopoints", "0-0-0-0.bin", "no such file"),
        ("bad-pointcount/laszip", "0-0-0-0.laz", "holds 1,065 points, the hierarchy says 1,000"),
        ("lone-star-invalid-tile", "2-2-2-2.laz", "cannot decode node 2-2-2-2: no readable LAS header ('utf-8' codec can't decode byte 0x8f in position 0: invalid start byte)"),
    ],
)
def test_pdals_broken_datasets_fail_in_one_line_naming_the_node(name, node, message):
    """PDAL's reader fails on each (its EptReaderTest): reading the node (as a frame does) fails in one line naming it."""
    c = gp.open(DATA / name)
    c.load_hierarchy()
    index = {voxel_name(int(k)): i for i, k in enumerate(c.keys)}[node.split(".")[0]]
    with pytest.raises(InputError) as e:
        c.node_points(index)
    text = str(e.value)
    assert text == f"{DATA / name / 'ept-data' / node}: {message}"


@pytest.mark.parametrize("name", COPC)
def test_pdal_copc_reads_point_for_point_and_draws_like_its_points(name):
    path = DATA / name
    las = laspy.read(path)
    c = gp.open(path)
    assert isinstance(c, CopcCloud) and c.n_points == len(las.points)
    got, h = _all_points(c), las.header
    assert len(got["xyz"]) == len(las.points)
    ints = np.rint((got["xyz"] - h.offsets) / h.scales).astype(np.int64)
    rgb = _rgb8(np.stack([np.asarray(las[k]) for k in ("red", "green", "blue")], 1))
    mine = np.column_stack([ints, got["gps_time"].view(np.int64), got["rgba"].view(np.uint8).reshape(-1, 4)[:, :3]])
    want = np.column_stack([las.X, las.Y, las.Z, np.asarray(las.gps_time).view(np.int64), rgb])
    # the same rows (the nodes' order is not the file's)
    np.testing.assert_array_equal(mine[np.lexsort(mine.T)], want[np.lexsort(want.T)])
    _renders_like(gp.open(path), np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], 1), rgb)
    p = gp.open(path, progressive=True)
    # (a generous bound, returned from as soon as the load ends: a cold kernel cache on a loaded machine took over 60 s)
    assert p.wait(300) and p.error is None and p.n_points == len(las.points)


def test_gigapoint_info_of_pdals_datasets():
    runs = {}
    for name in ("1.2-with-color", "lone-star-laszip", "ellipsoid-binary-2k", "bcbf", "bad-pointcount/laszip"):
        r = subprocess.run([sys.executable, "-m", "gigapoint.cli", "info", str(DATA / name)], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        runs[name] = r.stdout
    assert "EPT (laszip)" in runs["1.2-with-color"] and "points:      1,065" in runs["1.2-with-color"]
    assert "13 nodes in 4 levels, 6 hierarchy pages" in runs["lone-star-laszip"]
    assert "per level:   0: 41,998, 1: 166,916, 2: 270,355, 3: 39,593" in runs["lone-star-laszip"]
    assert "EPT (binary)" in runs["ellipsoid-binary-2k"] and "crs:         EPSG:3857" in runs["ellipsoid-binary-2k"]
    assert "5 nodes in 5 levels" in runs["bcbf"]
    # ept.json's count and its hierarchy's disagree: the hierarchy's is the count (a frame draws it), both said
    assert "points:      5\n" in runs["bcbf"] and "mismatch:    the hierarchy's nodes hold 5 points, ept.json says 10\n" in runs["bcbf"]
    assert "points:      1,000\n" in runs["bad-pointcount/laszip"]
    assert "mismatch:    the hierarchy's nodes hold 1,000 points, ept.json says 1,065\n" in runs["bad-pointcount/laszip"]
    assert all("mismatch" not in runs[k] for k in ("1.2-with-color", "lone-star-laszip", "ellipsoid-binary-2k"))
