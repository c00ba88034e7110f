"""EPT (laszip and binary) read as octrees: small EPT trees written here, their renders equal to
the COPC of the same nodes and to brute force of the same points; malformed datasets fail in
one line naming the file."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import InputError
from gigapoint.lod import EptCloud, OctreeCloud
from gigapoint.lod.copc_write import write_copc
from gigapoint.lod.keys import key_of, point_codes
from gigapoint.lod.voxel_octree import voxel_name

laspy = pytest.importorskip("laspy")

SCALE = 0.01
WKT = 'PROJCS["WGS 84 / UTM zone 10N",AUTHORITY["EPSG","32610"]]'


def make_scene(n: int = 40_000, seed: int = 3) -> dict:
    """Points on a centimetre grid in UTM-sized coordinates, each assigned to one node of a
    4-level octree (every node's points inside its cube): {key: point indices}, arrays, cube."""
    rng = np.random.default_rng(seed)
    origin = np.array([500_000.0, 4_000_000.0, 80.0])
    xyz = origin + np.round(rng.uniform(0, 1, (n, 3)) * [200.0, 150.0, 30.0] / SCALE) * SCALE
    xyz[:, 2] += np.round((20 + 10 * np.sin(xyz[:, 0] / 20.0)) / SCALE) * SCALE  # hills, inside the cube
    edge = 256.0
    codes = point_codes(xyz, origin, edge)
    level = rng.choice(4, n, p=[0.05, 0.15, 0.3, 0.5])
    keys = np.zeros(n, np.uint64)
    for lv in range(4):
        m = level == lv
        keys[m] = key_of(codes[m], lv)
    order = np.lexsort((np.arange(n), keys))
    uniq, start = np.unique(keys[order], return_index=True)
    nodes = {int(k): order[s:e] for k, s, e in zip(uniq, start, [*start[1:], n])}
    rgb = (rng.integers(0, 256, (n, 3)) * 257).astype(np.uint16)
    attrs = {"intensity": rng.integers(0, 4000, n).astype(np.uint16), "classification": rng.integers(0, 10, n).astype(np.uint8)}
    return {"xyz": xyz, "rgb": rgb, "attrs": attrs, "nodes": nodes, "origin": origin, "edge": edge}


SCHEMA = [
    {"name": "X", "type": "signed", "size": 4, "scale": SCALE, "offset": 500_100.0},
    {"name": "Y", "type": "signed", "size": 4, "scale": SCALE, "offset": 4_000_100.0},
    {"name": "Z", "type": "signed", "size": 4, "scale": SCALE, "offset": 0.0},
    {"name": "Intensity", "type": "unsigned", "size": 2},
    {"name": "Classification", "type": "unsigned", "size": 1},
    {"name": "Red", "type": "unsigned", "size": 2},
    {"name": "Green", "type": "unsigned", "size": 2},
    {"name": "Blue", "type": "unsigned", "size": 2},
]


def write_ept(
    folder: Path, scene: dict, data_type: str, page_level: int | None = 2, extra: tuple = (), node_scales: dict | None = None, node_dims: dict | None = None
) -> Path:
    """An EPT dataset of ``scene`` in ``folder``; nodes at ``page_level`` that have children
    head hierarchy files of their own. ``extra``: (schema entry, stored values of every point)
    of further dimensions (in a laszip node, LAS extra bytes of the same name, given the
    (scale, offset) of ``node_scales`` in the extra-bytes VLR where it names them; ``node_dims``
    {node key: {name: (stored dtype, (scale, offset) or None)}}: that node's instead)."""
    node_scales, node_dims = node_scales or {}, node_dims or {}
    folder.mkdir(parents=True)
    (folder / "ept-data").mkdir()
    (folder / "ept-hierarchy").mkdir()
    xyz, nodes = scene["xyz"], scene["nodes"]
    schema = SCHEMA + [d for d, _ in extra]
    offsets = np.array([d["offset"] for d in SCHEMA[:3]])
    dt = np.dtype([(d["name"], {"signed": "<i", "unsigned": "<u", "float": "<f"}[d["type"]] + str(d["size"])) for d in schema])
    for key, idx in nodes.items():
        name = voxel_name(key)
        if data_type == "binary":
            rec = np.zeros(len(idx), dt)
            ints = np.rint((xyz[idx] - offsets) / SCALE).astype(np.int64)
            rec["X"], rec["Y"], rec["Z"] = ints.T
            rec["Intensity"], rec["Classification"] = scene["attrs"]["intensity"][idx], scene["attrs"]["classification"][idx]
            rec["Red"], rec["Green"], rec["Blue"] = scene["rgb"][idx].T
            for d, v in extra:
                rec[d["name"]] = v[idx]
            (folder / "ept-data" / f"{name}.bin").write_bytes(rec.tobytes())
        else:
            header = laspy.LasHeader(point_format=7, version="1.4")
            header.scales, header.offsets = [SCALE] * 3, offsets
            for d, _ in extra:
                stored, scaling = node_dims.get(key, {}).get(d["name"], (dt[d["name"]], node_scales.get(d["name"])))
                scale, offset = (np.array([v]) for v in scaling) if scaling else (None, None)
                header.add_extra_dim(laspy.ExtraBytesParams(d["name"], stored, scales=scale, offsets=offset))
            las = laspy.LasData(header)
            las.X, las.Y, las.Z = np.rint((xyz[idx] - offsets) / SCALE).astype(np.int32).T
            las.red, las.green, las.blue = scene["rgb"][idx].T
            las.intensity, las.classification = scene["attrs"]["intensity"][idx], scene["attrs"]["classification"][idx]
            for d, v in extra:
                field = las.points.array[d["name"]]  # as stored (las[name] = ... unscales by the VLR's scale)
                field[...] = v[idx].reshape(-1, *(1,) * (field.ndim - 1))  # (several values a point: each of them the value)
            las.write(str(folder / "ept-data" / f"{name}.laz"))
    keys = set(nodes)
    level = {k: (k.bit_length() - 1) // 3 for k in keys}
    heads = {k for k in keys if page_level and level[k] == page_level and any((c >> 3) == k for c in keys)}

    def head_of(k):
        while k > 1 and k not in heads:
            k >>= 3
        return k if k in heads else 1

    pages: dict[int, dict] = {1: {}}
    for h in heads:
        pages[h] = {}
        pages[1][voxel_name(h)] = -1
    for k in keys:
        pages[head_of(k)][voxel_name(k)] = len(nodes[k])
    for h, page in pages.items():
        (folder / "ept-hierarchy" / f"{voxel_name(h)}.json").write_text(json.dumps(page))
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    meta = {
        "bounds": [*scene["origin"], *(scene["origin"] + scene["edge"])],
        "boundsConforming": [*lo, *hi],
        "dataType": data_type,
        "hierarchyType": "json",
        "points": len(xyz),
        "schema": schema,
        "span": 128,
        "srs": {"authority": "EPSG", "horizontal": "32610", "wkt": WKT},
        "version": "1.0.0",
    }
    (folder / "ept.json").write_text(json.dumps(meta))
    return folder


@pytest.fixture(scope="module")
def scene():
    return make_scene()


@pytest.fixture(scope="module")
def datasets(scene, tmp_path_factory):
    d = tmp_path_factory.mktemp("ept")
    out = {t: write_ept(d / t, scene, t) for t in ("laszip", "binary")}
    nodes = ((k, scene["xyz"][i], scene["rgb"][i], {a: v[i] for a, v in scene["attrs"].items()}) for k, i in scene["nodes"].items())
    out["copc"] = d / "s.copc.laz"
    write_copc(
        out["copc"],
        nodes,
        scale=[SCALE] * 3,
        offset=[500_100.0, 4_000_100.0, 0.0],
        cube_min=scene["origin"],
        cube_edge=scene["edge"],
        wkt=WKT,
    )
    return out


@pytest.mark.parametrize("data_type", ["laszip", "binary"])
def test_ept_opens_as_an_octree_with_pages_on_demand(datasets, scene, data_type):
    for path in (datasets[data_type], datasets[data_type] / "ept.json"):
        c = gp.open(path)
        assert isinstance(c, EptCloud) and isinstance(c, OctreeCloud)
        assert c.n_points == len(scene["xyz"]) and c.meta["crs"] == "EPSG:32610"
        assert c.pending_pages > 0
    c.load_hierarchy()
    assert sorted(c.keys[c.counts > 0].tolist()) == sorted(scene["nodes"])
    assert int(c.counts.sum()) == len(scene["xyz"])
    k = next(iter(scene["nodes"]))
    i = int(np.searchsorted(c.keys, k))
    p = c.node_points(i)
    idx = scene["nodes"][k]
    np.testing.assert_allclose(p["xyz"], scene["xyz"][idx], atol=1e-6)  # the 30-bit node quantization
    np.testing.assert_array_equal(p["intensity"], scene["attrs"]["intensity"][idx])
    np.testing.assert_array_equal(p["rgba"].view(np.uint8).reshape(-1, 4)[:, :3], scene["rgb"][idx] >> 8)


@pytest.mark.parametrize("adaptive", [False, True])
def test_ept_and_copc_render_alike_and_like_brute_force(datasets, scene, adaptive):
    clouds = {k: gp.open(p) for k, p in datasets.items()}
    brute = gp.from_arrays(scene["xyz"], (scene["rgb"] >> 8).astype(np.uint8), **scene["attrs"])
    s = gp.RenderSettings(backend="cpu", adaptive_precision=adaptive, size_mode="fixed")  # one pixel a point: the exact comparison
    for view in ("iso", "top"):
        cam = gp.Camera.fit(brute.bounds, view=view, width=320, height=240)
        ref = gp.render_frame(brute, cam, s)
        images = {}
        for name, c in clouds.items():
            f = gp.render_frame(c, cam, s.replace(point_budget=10**9, lod_threshold_px=0.0))
            assert f.stats.points_processed == len(scene["xyz"])
            images[name] = f.image
            assert (f.empty != ref.empty).mean() < (0.05 if adaptive else 0.002)
            assert np.all(f.image == ref.image, axis=2).mean() > (0.8 if adaptive else 0.95)
        np.testing.assert_array_equal(images["laszip"], images["copc"])  # the same nodes, points and bboxes
        np.testing.assert_array_equal(images["binary"], images["copc"])
        # and with a budget: the same nodes chosen
        small = {n: gp.render_frame(c, cam, s.replace(point_budget=15_000)) for n, c in clouds.items()}
        assert len({f.stats.points_processed for f in small.values()}) == 1
        np.testing.assert_array_equal(small["binary"].image, small["copc"].image)


def test_octree_info_of_ept(datasets, scene):
    from gigapoint.io import format_info
    from gigapoint.lod import octree_info

    info = octree_info(datasets["binary"])
    assert info["point_count"] == len(scene["xyz"]) and sum(info["points_per_level"]) == len(scene["xyz"])
    assert info["crs"] == "EPSG:32610" and info["levels"] == 4
    text = format_info(info)
    assert "EPT (binary)" in text and "per level:" in text and "EPSG:32610" in text


# --------------------------------------------------------------------------- malformed datasets


@pytest.fixture
def broken(datasets, tmp_path):
    def copy(data_type="binary"):
        dst = tmp_path / f"b_{data_type}"
        shutil.copytree(datasets[data_type], dst)
        return dst

    return copy


def _fails(path, match):
    with pytest.raises(InputError, match=match) as e:
        c = gp.open(path)
        c.load_hierarchy()
        gp.render_frame(c, gp.Camera.fit(c.bounds, width=64, height=48), gp.RenderSettings(backend="cpu", lod_threshold_px=0.0))
    assert "\n" not in str(e.value)
    return str(e.value)


@pytest.mark.parametrize("missing", ["schema", "bounds", "dataType"])
def test_ept_json_with_missing_keys(broken, missing):
    d = broken()
    meta = json.loads((d / "ept.json").read_text())
    del meta[missing]
    (d / "ept.json").write_text(json.dumps(meta))
    msg = _fails(d, f"lacks '{missing}'")
    assert str(d / "ept.json") in msg


def test_ept_unsupported_and_invalid_metadata(broken):
    d = broken()
    meta = json.loads((d / "ept.json").read_text())
    (d / "ept.json").write_text(json.dumps(dict(meta, dataType="lzma")))
    _fails(d, r"dataType 'lzma' is not supported \(laszip, binary or zstandard\)")
    (d / "ept.json").write_text(json.dumps(dict(meta, schema=[{"name": "X", "type": "complex", "size": 4}])))
    _fails(d, "invalid ept.json")
    (d / "ept.json").write_text(json.dumps(dict(meta, points=-5)))  # taken as the cloud's count
    _fails(d, r"points must be a whole number >= 0, got -5")
    x_at_zero = [dict(dim, scale=0) if dim["name"] == "X" else dim for dim in meta["schema"]]  # every point on one line
    (d / "ept.json").write_text(json.dumps(dict(meta, schema=x_at_zero)))
    _fails(d, r"dimension 'X' has scale 0.0 and offset .*: a positive scale and a finite offset are needed")
    z_coarse = [dict(dim, scale=2.269e277) if dim["name"] == "Z" else dim for dim in meta["schema"]]  # a damaged scale: z of 1e286
    (d / "ept.json").write_text(json.dumps(dict(meta, schema=z_coarse)))
    _fails(d, r"corrupt ept.json schema: scale \[.*, 2.269e\+277\] and offset \[.*\] put its points beyond any coordinate \(±1e\+12\)")
    (d / "ept.json").write_text("{not json")
    _fails(d, "not valid JSON")


def test_an_ept_cube_beside_its_points(broken):
    """ept.json's cube (bounds) beside its points (boundsConforming) culled every node: a blank
    image and "no point is in view". Conforming bounds of zeros (missing) still open."""
    d = broken()
    meta = json.loads((d / "ept.json").read_text())
    b = meta["bounds"]
    edge = b[3] - b[0]
    moved = [b[0] + 10 * edge, b[1], b[2], b[3] + 10 * edge, b[4], b[5]]  # the cube moved away along x
    (d / "ept.json").write_text(json.dumps(dict(meta, bounds=moved)))
    _fails(d, r"corrupt ept.json \(boundsConforming, bounds\): the points' bounds \[.*\] lie outside the octree's cube \[.*\]; one of them is wrong$")
    (d / "ept.json").write_text(json.dumps(dict(meta, boundsConforming=[0, 0, 0, 0, 0, 0])))
    assert gp.open(d).bounds[0].tolist() == b[:3]  # the cube stands in


def test_ept_hierarchy_that_refers_to_itself(broken):
    d = broken()
    root = json.loads((d / "ept-hierarchy" / "0-0-0-0.json").read_text())
    child = next(k for k, v in root.items() if v == -1)
    page = json.loads((d / "ept-hierarchy" / f"{child}.json").read_text())
    page[child] = -1  # the page points to itself
    (d / "ept-hierarchy" / f"{child}.json").write_text(json.dumps(page))
    _fails(d, "refers to itself")
    page[child] = 5
    page["0-0-0-0"] = -1  # a child page that names the root: outside its subtree
    (d / "ept-hierarchy" / f"{child}.json").write_text(json.dumps(page))
    _fails(d, "outside its subtree")


def test_ept_missing_or_short_node_files(broken):
    d = broken()
    victim = min((d / "ept-data").iterdir())
    data = victim.read_bytes()
    victim.write_bytes(data[:-7])
    msg = _fails(d, "holds .* bytes")
    assert victim.stem in msg
    victim.unlink()
    msg = _fails(d, "no such file")
    assert str(victim) in msg
    d2 = broken("laszip")
    victim = min((d2 / "ept-data").iterdir())
    victim.write_bytes(b"LASF" + bytes(50))
    _fails(d2, f"cannot decode node {victim.stem}")


def test_ept_hierarchy_bad_entries(broken):
    d = broken()
    root = json.loads((d / "ept-hierarchy" / "0-0-0-0.json").read_text())
    (d / "ept-hierarchy" / "0-0-0-0.json").write_text(json.dumps(dict(root, **{"1-7-0-0": 3})))
    _fails(d, "outside the octree")
    (d / "ept-hierarchy" / "0-0-0-0.json").write_text(json.dumps(dict(root, **{"0-0-0-0": "many"})))
    _fails(d, "invalid point count")
    (d / "ept-hierarchy" / "0-0-0-0.json").write_text(json.dumps(dict(root, **{"0-0-0-0": 2**63})))  # an OverflowError (found by a fuzzer)
    _fails(d, "node 0-0-0-0 has an invalid point count 9223372036854775808")
    (d / "ept-hierarchy" / "0-0-0-0.json").unlink()
    _fails(d, "0-0-0-0.json: no such file")


def test_a_damaged_laszip_node_is_a_one_line_error(broken):
    """A LAZ node whose compressed points are overwritten: lazrs fails (or crashes: it decodes
    in a child process, io/laz_process.decode_block) and the error names the node."""
    d = broken("laszip")
    victim = max((d / "ept-data").iterdir(), key=lambda f: f.stat().st_size)
    data = bytearray(victim.read_bytes())
    at = len(data) // 2
    data[at : at + 4_000] = b"\xff" * 4_000
    victim.write_bytes(bytes(data))
    _fails(d, f"cannot decode node {victim.stem}")


@pytest.mark.parametrize("data_type", ["laszip", "binary"])
def test_a_truncated_node_file_is_named_not_ept_json(broken, data_type):
    """The error began with ept.json's path; the damaged file is the node's."""
    d = broken(data_type)
    victim = max((d / "ept-data").iterdir(), key=lambda f: f.stat().st_size)
    victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 2])
    msg = _fails(d, f"^{re.escape(str(victim))}: ")
    assert f"ept-data/{victim.name}: " in msg and "ept.json" not in msg, msg


def test_a_laszip_node_whose_header_disagrees_with_the_hierarchy(broken):
    """Checked before its header's count sizes anything (a corrupt count could ask for GBs)."""
    import laspy

    d = broken("laszip")
    victim = max((d / "ept-data").iterdir(), key=lambda f: f.stat().st_size)
    las = laspy.read(victim)
    n = len(las.points)
    las.points = las.points[: n - 5]
    las.write(victim)
    _fails(d, f"^{re.escape(str(victim))}: holds {n - 5:,} points, the hierarchy says {n:,}")


def test_an_ept_dataset_given_to_convert_is_named_as_one(datasets, tmp_path):
    """Its folder was 'holds no supported point cloud file', its ept.json 'unknown point cloud
    format (suffix .json)': as for a converted folder, the error says what it is."""
    for given in (datasets["binary"], datasets["binary"] / "ept.json"):
        with pytest.raises(InputError) as e:
            gp.convert(given, tmp_path / "out")
        assert str(e.value) == f"{given}: is an EPT dataset (an octree: open or render it as it is), not an input point cloud"
    assert not (tmp_path / "out").exists()


def test_the_classes_an_ept_schema_counts_or_bounds(broken, datasets):
    """What ept.json's Classification dimension says of the classes (the viewer's Classes panel
    lists them): Entwine's counts name them, a minimum and maximum bound them; nothing, or what
    is not a class, says nothing."""
    assert gp.open(datasets["binary"]).class_facts() == {}  # (SCHEMA states neither)
    d = broken()
    meta = json.loads((d / "ept.json").read_text())
    dim = next(s for s in meta["schema"] if s["name"] == "Classification")
    for stated, facts in [
        ({"counts": [{"value": 6, "count": 10}, {"value": 2, "count": 5}, {"value": 9, "count": 0}]}, {"classes": [2, 6]}),
        ({"minimum": 1, "maximum": 9}, {"class_range": (1, 9)}),
        ({"counts": [{"value": 2.5, "count": 1}], "minimum": 0, "maximum": 300}, {}),
    ]:
        dim.clear()
        dim.update({"name": "Classification", "type": "unsigned", "size": 1, **stated})
        (d / "ept.json").write_text(json.dumps(meta))
        assert gp.open(d).class_facts() == facts, stated


@pytest.mark.parametrize("data_type", ["laszip", "binary"])
def test_ept_dimensions_beyond_las_are_attributes(scene, tmp_path, data_type):
    """Entwine's OriginId and a source's extra bytes (here a scaled Reflectance) were dropped
    without a word: they are attributes under their own names (laszip: the node's LAS extra
    bytes), as the LAS and COPC readers read extra bytes, and ``info`` lists them; binary's
    ClassFlags is the LAS reader's four flags, its ScanChannel its scanner_channel."""
    from gigapoint.io import format_info
    from gigapoint.lod import octree_info

    n = len(scene["xyz"])
    rng = np.random.default_rng(9)
    origin, reflectance, flags = rng.integers(0, 4, n).astype(np.uint32), rng.integers(-2000, 2000, n).astype(np.int16), rng.integers(0, 16, n).astype(np.uint8)
    extra = [
        ({"name": "OriginId", "type": "unsigned", "size": 4}, origin),
        ({"name": "Reflectance", "type": "signed", "size": 2, "scale": 0.01, "offset": -5.0}, reflectance),
    ]
    channel = flags >> 2  # 0..3
    binary_only = ["key_point", "overlap", "scanner_channel", "synthetic", "withheld"] if data_type == "binary" else []
    if data_type == "binary":
        extra += [({"name": "ClassFlags", "type": "unsigned", "size": 1}, flags), ({"name": "ScanChannel", "type": "unsigned", "size": 1}, channel)]
    d = write_ept(tmp_path / "e", scene, data_type, extra=extra)
    c = gp.open(d)
    assert c.attribute_names == sorted(["OriginId", "Reflectance", "classification", "intensity", *binary_only])
    c.load_hierarchy()
    for i in np.flatnonzero(c.counts > 0).tolist()[:6]:
        idx = scene["nodes"][int(c.keys[i])]
        p = c.node_points(i)
        np.testing.assert_array_equal(p["OriginId"], origin[idx])
        assert p["OriginId"].dtype == np.uint32 and p["Reflectance"].dtype == np.float64
        np.testing.assert_allclose(p["Reflectance"], reflectance[idx] * 0.01 - 5.0)
        if data_type == "binary":
            for bit, name in enumerate(["synthetic", "key_point", "withheld", "overlap"]):
                np.testing.assert_array_equal(p[name], (flags[idx] >> bit) & 1)
            np.testing.assert_array_equal(p["scanner_channel"], channel[idx])
    info = octree_info(d)
    assert "OriginId" in info["attributes"] and "Reflectance" in info["attributes"]
    assert "OriginId, Reflectance, classification" in format_info(info)



@pytest.mark.parametrize(
    ("data_type", "in_schema", "in_node"),
    [("laszip", False, True), ("laszip", True, True), ("laszip", True, False), ("binary", True, False)],
    ids=["laszip-node-vlr-only", "laszip-schema-and-node-vlr", "laszip-schema-only", "binary-schema"],
)
def test_an_ept_extra_dimension_is_scaled_once(tmp_path, data_type, in_schema, in_node):
    """A scaled extra dimension of a laszip node whose extra-bytes VLR gives the scale (as laspy
    and PDAL read it) came back as whole numbers (-14 for -14.51: laspy's scaled values cast to
    the schema's int16) when ept.json gave none, and scaled twice (-5.1451) when ept.json gave
    the same: it is scaled once wherever the scale is given, a float64 attribute from the open."""
    from gigapoint.io import format_info
    from gigapoint.lod import octree_info

    scene = make_scene(n=3000, seed=5)
    stored = np.random.default_rng(4).integers(-2000, 2000, len(scene["xyz"])).astype(np.int16)
    entry = {"name": "Reflectance", "type": "signed", "size": 2, **({"scale": 0.01, "offset": -5.0} if in_schema else {})}
    d = write_ept(tmp_path / "e", scene, data_type, extra=[(entry, stored)], node_scales={"Reflectance": (0.01, -5.0)} if in_node else None)
    c = gp.open(d)
    c.load_hierarchy()
    for i in np.flatnonzero(c.counts > 0).tolist():
        p = c.node_points(i)
        assert p["Reflectance"].dtype == np.float64  # (the dtype fixed at open: whole numbers were cast to it)
        np.testing.assert_allclose(p["Reflectance"], stored[scene["nodes"][int(c.keys[i])]] * 0.01 - 5.0, rtol=0, atol=1e-9)
    assert "Reflectance, classification, intensity" in format_info(octree_info(d))


def _child_node(scene) -> int:
    """The key of a level-1 node (not the root) that holds points."""
    return min(k for k in scene["nodes"] if k.bit_length() == 4)


@pytest.mark.parametrize("data_type", ["laszip", "binary"])
def test_ept_extra_dimensions_of_each_type(tmp_path, data_type):
    """A scaled int32, a float32, a scaled float32 and a float64 dimension read back as the
    numbers written, each in the dtype ept.json's schema gives (a scale: float64, the float32
    scaled in float64); one laszip node that stores them
    otherwise but to the same values (the scale in its extra-bytes VLR, the same as the
    schema's; float32 where the schema says float64; uint16 where it says int32 unscaled) is
    read as the others."""
    scene = make_scene(n=3000, seed=6)
    rng = np.random.default_rng(8)
    n = len(scene["xyz"])
    written = {
        "Scaled": rng.integers(-(10**6), 10**6, n).astype(np.int32),
        "Float32": rng.normal(0.0, 1000.0, n).astype(np.float32),
        "Float64": rng.normal(0.0, 1e6, n),
        "ScaledFloat32": rng.normal(0.0, 1e4, n).astype(np.float32),
        "Count": rng.integers(0, 60_000, n).astype(np.int32),
    }
    child = _child_node(scene)
    in_child = scene["nodes"][child]
    written["Float64"][in_child] = written["Float64"][in_child].astype(np.float32)  # (exact in the node that stores float32)
    extra = [
        ({"name": "Scaled", "type": "signed", "size": 4, "scale": 0.001, "offset": 100.0}, written["Scaled"]),
        ({"name": "Float32", "type": "float", "size": 4}, written["Float32"]),
        ({"name": "Float64", "type": "float", "size": 8}, written["Float64"]),
        ({"name": "ScaledFloat32", "type": "float", "size": 4, "scale": 0.001}, written["ScaledFloat32"]),
        ({"name": "Count", "type": "signed", "size": 4}, written["Count"]),
    ]
    other = {child: {"Scaled": (np.int32, (0.001, 100.0)), "Float64": (np.float32, None), "Count": (np.uint16, None)}}
    d = write_ept(tmp_path / "e", scene, data_type, extra=extra, node_dims=other if data_type == "laszip" else None)
    dtypes = {"Scaled": np.float64, "Float32": np.float32, "Float64": np.float64, "ScaledFloat32": np.float64, "Count": np.int32}
    c = gp.open(d)
    c.load_hierarchy()
    for i in np.flatnonzero(c.counts > 0).tolist():
        idx = scene["nodes"][int(c.keys[i])]
        p = c.node_points(i)
        assert {a: p[a].dtype for a in written} == dtypes
        np.testing.assert_allclose(p["Scaled"], written["Scaled"][idx] * 0.001 + 100.0, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(p["ScaledFloat32"], written["ScaledFloat32"][idx].astype(np.float64) * 0.001)
        for name in ("Float32", "Float64", "Count"):
            np.testing.assert_array_equal(p[name], written[name][idx])


@pytest.mark.parametrize(
    ("entry", "child_stores", "match"),
    [
        (
            {"type": "signed", "size": 2, "scale": 0.01, "offset": -5.0},
            (np.int16, (0.1, 0.0)),
            r"is stored \* 0\.1 \+ 0 \(its extra-bytes VLR\), ept\.json's schema says \* 0\.01 \+ -5",
        ),
        (
            {"type": "signed", "size": 2, "scale": 0.01, "offset": -5.0},
            (np.float64, None),
            r"is stored as float64, unscaled, where ept\.json's schema scales stored int16",
        ),
        (
            {"type": "signed", "size": 2},
            (np.int16, (0.01, -5.0)),
            r"gives float64 values \(scaled by its extra-bytes VLR\), where the dataset's 'Reflectance' is int16",
        ),
        ({"type": "unsigned", "size": 1}, (np.float32, None), r"gives float32 values \(stored as float32\), where the dataset's 'Reflectance' is uint8"),
        # (an array type: its dtype was said as numpy's, "gives ('<i2', (3,)) values (stored as ('<i2', (3,)))")
        ({"type": "signed", "size": 2}, ("3i2", None), r"holds 3 values a point \(3 x int16\), where ept\.json's schema gives it one \(int16\)"),
    ],
    ids=["scaled-otherwise", "stored-scaled-already", "scaled-past-the-root", "float-for-int", "several-values-a-point"],
)
def test_an_ept_node_that_disagrees_with_the_schema_is_refused(tmp_path, entry, child_stores, match):
    """A laszip node whose extra-bytes VLR stores a dimension otherwise than ept.json's schema
    (and the root node) says was read without a word, its values wrong: the node's own scale
    applied over the schema's, the schema's applied to values stored already scaled, scaled
    values cast to the whole numbers of the dtype fixed at open. Decoding that node is a
    one-line error naming its file; the nodes that agree read as ever."""
    scene = make_scene(n=3000, seed=5)
    stored = np.random.default_rng(4).integers(0, 200, len(scene["xyz"]))
    child = _child_node(scene)
    d = write_ept(tmp_path / "e", scene, "laszip", extra=[({"name": "Reflectance", **entry}, stored)], node_dims={child: {"Reflectance": child_stores}})
    c = gp.open(d)
    c.load_hierarchy()
    for i in np.flatnonzero(c.counts > 0).tolist():
        key = int(c.keys[i])
        if key != child:
            c.node_points(i)
            continue
        with pytest.raises(InputError, match=match) as err:
            c.node_points(i)
        name = voxel_name(child)
        assert str(err.value).startswith(f"{d / 'ept-data' / name}.laz: node {name}'s extra dimension 'Reflectance' ")
        assert "\n" not in str(err.value) and str(err.value).endswith(": its values would be wrong")


def _with_array_nodes(folder: Path, scene: dict, arrays: dict, node_dims: dict | None = None) -> None:
    """``folder``'s laszip nodes rewritten with LAS extra-bytes arrays (several values a point, as
    laspy writes a normal): ``arrays`` {name: (stored (n, k) values of every point, stored dtype,
    (scales, offsets) or None)}; ``node_dims`` {node key: {name: (stored dtype, scaling)}}: that
    node's instead. ept.json is left as it is."""
    for key, idx in scene["nodes"].items():
        path = folder / "ept-data" / f"{voxel_name(key)}.laz"
        las = laspy.read(path)
        for name, (values, stored, scaling) in arrays.items():
            stored, scaling = (node_dims or {}).get(key, {}).get(name, (stored, scaling))
            scales, offsets = (np.asarray(v, np.float64) for v in scaling) if scaling else (None, None)
            las.add_extra_dim(laspy.ExtraBytesParams(name, f"{values.shape[1]}{np.dtype(stored).str[1:]}", scales=scales, offsets=offsets))
            las.points.array[name] = values[idx]  # (as stored: las[name] = ... unscales by the VLR's scale)
        las.write(str(path))


def _split_entries(name: str, k: int, **entry) -> list[dict]:
    """The schema entries Entwine writes for an extra-bytes array ``name`` of ``k`` values a point:
    PDAL's LAS reader splits it into dimensions ``name0`` .. (scaled ones as doubles)."""
    return [{"name": f"{name}{i}", **entry} for i in range(k)]


@pytest.mark.parametrize("data_type", ["laszip", "binary"])
def test_an_ept_extra_bytes_array_is_read_as_the_schemas_split_dimensions(tmp_path, data_type):
    """A source's extra-bytes array (3 doubles of a normal, 3 scaled int16s) is split by PDAL into
    dimensions ``normal0``, ``normal1``, .. of ept.json's schema; a laszip node that holds the array
    itself (one extra-bytes descriptor of 3 values) left those attributes zeros without a word.
    Each is the node's array's value of that place (scaled by its own scale and offset), as laspy
    reads the node, and a binary dataset of the same schema reads to the same numbers."""
    scene = make_scene(n=3000, seed=7)
    rng = np.random.default_rng(11)
    n = len(scene["xyz"])
    normal = rng.normal(0.0, 1.0, (n, 3))
    refl = rng.integers(-2000, 2000, (n, 3)).astype(np.int16)
    refl_scaling = ([0.01, 0.1, 1.0], [-5.0, 0.0, 2.0])
    refl_values = refl * np.array(refl_scaling[0]) + np.array(refl_scaling[1])
    double = {"type": "float", "size": 8}
    entries = _split_entries("normal", 3, **double) + _split_entries("refl", 3, **double)
    columns = [normal[:, i] for i in range(3)] + [refl_values[:, i] for i in range(3)]
    if data_type == "binary":
        d = write_ept(tmp_path / "e", scene, "binary", extra=list(zip(entries, columns, strict=True)))
    else:
        d = write_ept(tmp_path / "e", scene, "laszip")
        _with_array_nodes(d, scene, {"normal": (normal, np.float64, None), "refl": (refl, np.int16, refl_scaling)})
        meta = json.loads((d / "ept.json").read_text())
        (d / "ept.json").write_text(json.dumps(dict(meta, schema=meta["schema"] + entries)))
    c = gp.open(d)
    names = [e["name"] for e in entries]
    assert set(names) <= set(c.attribute_names)
    c.load_hierarchy()
    for i in np.flatnonzero(c.counts > 0).tolist():
        key = int(c.keys[i])
        idx = scene["nodes"][key]
        p = c.node_points(i)
        assert {a: p[a].dtype for a in names} == dict.fromkeys(names, np.float64)
        for k in range(3):
            np.testing.assert_array_equal(p[f"normal{k}"], normal[idx, k])
            np.testing.assert_allclose(p[f"refl{k}"], refl_values[idx, k], rtol=0, atol=1e-9)
        if data_type == "laszip":  # (laspy's reading of the node: its array, scaled by its VLR)
            node = laspy.read(d / "ept-data" / f"{voxel_name(key)}.laz")
            for k in range(3):
                np.testing.assert_array_equal(p[f"normal{k}"], np.asarray(node["normal"])[:, k])
                np.testing.assert_array_equal(p[f"refl{k}"], np.asarray(node["refl"])[:, k])


def test_an_ept_node_array_that_disagrees_with_the_split_schema_is_refused(tmp_path):
    """The schema's split dimensions (``refl0`` ..: int16, unscaled) read from a laszip node's
    array where it agrees; a node whose array gives other values (float32, that the int16 the
    dataset's ``refl0`` is cannot hold) is a one-line error naming the node's file, the schema's
    dimension and the value of the node's array it would be."""
    scene = make_scene(n=3000, seed=5)
    n = len(scene["xyz"])
    refl = np.random.default_rng(4).integers(-200, 200, (n, 2)).astype(np.int16)
    child = _child_node(scene)
    d = write_ept(tmp_path / "e", scene, "laszip")
    _with_array_nodes(d, scene, {"refl": (refl, np.int16, None)}, node_dims={child: {"refl": (np.float32, None)}})
    meta = json.loads((d / "ept.json").read_text())
    (d / "ept.json").write_text(json.dumps(dict(meta, schema=meta["schema"] + _split_entries("refl", 2, type="signed", size=2))))
    c = gp.open(d)
    c.load_hierarchy()
    for i in np.flatnonzero(c.counts > 0).tolist():
        key = int(c.keys[i])
        if key != child:
            p = c.node_points(i)
            assert p["refl0"].dtype == np.int16
            np.testing.assert_array_equal(np.stack([p["refl0"], p["refl1"]], axis=1), refl[scene["nodes"][key]])
            continue
        with pytest.raises(InputError) as err:
            c.node_points(i)
        name = voxel_name(child)
        assert str(err.value) == (
            f"{d / 'ept-data' / name}.laz: node {name}'s extra dimension 'refl0' (value 0 of the node's array 'refl') "
            "gives float32 values (stored as float32), where the dataset's 'refl0' is int16 (ept.json's schema, its root node): its values would be wrong"
        )


def test_an_ept_count_is_its_hierarchys_once_read(broken, scene):
    """ept.json's ``points`` beside what its hierarchy holds (PDAL's bcbf: 10 and 5): a render
    said "5 of 10 points drawn" of all there is. Once every page is read (``info``, a frame
    that reaches them) the count is the nodes'; ``info`` says ept.json's beside it."""
    from gigapoint.io import format_info
    from gigapoint.lod import octree_info

    d = broken()
    meta = json.loads((d / "ept.json").read_text())
    (d / "ept.json").write_text(json.dumps(dict(meta, points=meta["points"] + 777)))
    n = len(scene["xyz"])
    c = gp.open(d)
    assert c.pending_pages > 0 and c.n_points == n + 777  # (all it knows before its pages are read)
    f = gp.render_frame(c, gp.Camera.fit(c.bounds, width=64, height=48), gp.RenderSettings(backend="cpu", lod_threshold_px=0.0, point_budget=10**9))
    assert c.pending_pages == 0 and f.stats.points_processed == c.n_points == len(c) == n
    text = format_info(octree_info(d))
    assert f"points:      {n:,}\n" in text and f"mismatch:    the hierarchy's nodes hold {n:,} points, ept.json says {n + 777:,}\n" in text
