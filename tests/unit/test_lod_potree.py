"""Potree 2.0: writer output re-read by the reader (DEFAULT and BROTLI), hand-made files, bad files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.core import PointChunk
from gigapoint.errors import InputError
from gigapoint.io import demo_arrays
from gigapoint.lod import convert, open_octree
from gigapoint.lod.keys import name_key
from gigapoint.lod.potree import HIERARCHY_DTYPE, decode_node

pytest.importorskip("brotli")


def _chunks(n=50_000, more=False):
    xyz, rgba, attrs = demo_arrays(n, seed=7)
    xyz = np.round(xyz * 1000) / 1000
    if more:  # attributes beyond intensity and classification: a LAS field under Potree's name, extras, a boolean
        rng = np.random.default_rng(7)
        attrs.update(return_number=rng.integers(1, 5, n).astype(np.uint8), gps_time=rng.uniform(0, 1e6, n),
                     height=rng.uniform(-2, 40, n).astype(np.float32), flag=rng.random(n) < 0.5)  # fmt: skip
    return [PointChunk(xyz, rgba, attrs)]


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    d = tmp_path_factory.mktemp("potree")
    out = {}
    for fmt, enc in (("gigapoint", "DEFAULT"), ("potree", "DEFAULT"), ("potree", "BROTLI")):
        path = d / f"{fmt}_{enc}"
        convert(_chunks(more=True), path, format=fmt, max_leaf=3_000, partition_points=20_000, **({"encoding": enc} if fmt == "potree" else {}))
        out[(fmt, enc)] = path
    return out


@pytest.mark.parametrize("encoding", ["DEFAULT", "BROTLI"])
def test_potree_round_trip(converted, encoding):
    ref = open_octree(converted[("gigapoint", "DEFAULT")])
    pot = open_octree(converted[("potree", encoding)])
    meta = json.loads((converted[("potree", encoding)] / "metadata.json").read_text())
    assert meta["encoding"] == encoding and meta["points"] == ref.n_points
    # every attribute, LAS fields under PotreeConverter's names (read back as gigapoint's): the
    # writer kept intensity and classification only
    names = ["position", "intensity", "classification", "return number", "gps-time", "height", "flag", "rgb"]
    assert [a["name"] for a in meta["attributes"]] == names
    assert [a["type"] for a in meta["attributes"]] == ["int32", "uint16", "uint8", "uint8", "double", "float", "uint8", "uint16"]
    from gigapoint.lod import octree_info

    # gigapoint info names them as gigapoint does (it said "return number", which --color-attribute does not take)
    assert octree_info(converted[("potree", encoding)])["attributes"] == ["intensity", "classification", "return_number", "gps_time", "height", "flag"]
    np.testing.assert_array_equal(pot.keys, ref.keys)
    np.testing.assert_array_equal(pot.nodes["count"], ref.nodes["count"])
    for i in range(len(ref.keys)):
        a, b = ref.node_points(i), pot.node_points(i)
        if not len(a["xyz"]):
            continue
        order_a = np.lexsort(np.round(a["xyz"] * 1000).T)
        order_b = np.lexsort(np.round(b["xyz"] * 1000).T)  # BROTLI permutes points into Morton order
        np.testing.assert_allclose(b["xyz"][order_b], a["xyz"][order_a], atol=1e-6)
        np.testing.assert_array_equal(b["rgba"][order_b], a["rgba"][order_a])
        for name in ("intensity", "classification", "return_number", "gps_time", "height", "flag"):
            np.testing.assert_array_equal(b[name][order_b], np.asarray(a[name][order_a]).astype(b[name].dtype), err_msg=name)


def test_potree_hierarchy_breadth_first(converted):
    path = converted[("potree", "DEFAULT")]
    meta = json.loads((path / "metadata.json").read_text())
    recs = np.frombuffer((path / "hierarchy.bin").read_bytes(), HIERARCHY_DTYPE)
    assert meta["hierarchy"]["firstChunkSize"] == len(recs) * 22
    # replay the viewer: children created in child-index order, records consumed in sequence
    names = ["r"]
    for i, r in enumerate(recs):
        names += [names[i] + str(c) for c in range(8) if r["mask"] >> c & 1]
        assert (r["type"] == 1) == (r["mask"] == 0)
    assert len(names) == len(recs)
    assert sum(int(r["size"]) for r in recs) == (path / "octree.bin").stat().st_size
    assert meta["boundingBox"]["max"][0] - meta["boundingBox"]["min"][0] == pytest.approx(
        meta["boundingBox"]["max"][2] - meta["boundingBox"]["min"][2]
    )


def test_brotli_decoder_hand_made_vector():
    """One point X=1, Y=2, Z=4 (+ 65536 on X), rgb (1, 2, 4): Morton bits placed by hand."""
    import brotli

    lower = (1 << 0) | (1 << (3 * 1 + 1)) | (1 << (3 * 2 + 2))
    upper = 1 << 0  # X bit 16
    rgb = (1 << 0) | (1 << 4) | (1 << 8)
    raw = np.array([upper, lower], "<u8").tobytes() + np.array([7], "<u2").tobytes() + bytes([2]) + np.array([rgb], "<u8").tobytes()
    attrs = [
        {"name": "position", "type": "int32", "numElements": 3},
        {"name": "intensity", "type": "uint16", "numElements": 1},
        {"name": "classification", "type": "uint8", "numElements": 1},
        {"name": "rgb", "type": "uint16", "numElements": 3},
    ]
    d = decode_node(brotli.compress(raw), 1, attrs, "BROTLI")
    assert d["position"].tolist() == [[65537, 2, 4]]
    assert d["rgb"].tolist() == [[1, 2, 4]] and d["intensity"].tolist() == [7] and d["classification"].tolist() == [2]


def _write_potree(path, hierarchy: bytes, first: int, nodes_bin: bytes):
    path.mkdir()
    meta = {
        "version": "2.0", "name": "hand", "points": 3, "hierarchy": {"firstChunkSize": first, "stepSize": 4, "depth": 1},
        "offset": [10.0, 20.0, 30.0], "scale": [0.5, 0.5, 0.5], "spacing": 1.0,
        "boundingBox": {"min": [10.0, 20.0, 30.0], "max": [18.0, 28.0, 38.0]}, "encoding": "DEFAULT",
        "attributes": [{"name": "position", "type": "int32", "numElements": 3, "size": 12, "elementSize": 4}],
    }  # fmt: skip
    (path / "metadata.json").write_text(json.dumps(meta))
    (path / "hierarchy.bin").write_bytes(hierarchy)
    (path / "octree.bin").write_bytes(nodes_bin)


def test_reader_follows_proxy_chunks(tmp_path):
    pts = np.array([[0, 0, 0], [2, 2, 2], [12, 4, 4]], "<i4")  # root: 2 points; r4 (x high half): 1 point
    octree = pts.tobytes()
    root_chunk = np.array([(0, 1 << 4, 2, 0, 24), (2, 0, 1, 44, 22)], HIERARCHY_DTYPE)  # r4 is a proxy -> chunk at 44
    sub_chunk = np.array([(1, 0, 1, 24, 12)], HIERARCHY_DTYPE)
    _write_potree(tmp_path / "p", root_chunk.tobytes() + sub_chunk.tobytes(), 44, octree)
    oc = open_octree(tmp_path / "p")
    assert oc.keys.tolist() == [1, name_key("r4")]
    assert oc.nodes["count"].tolist() == [2, 1]
    np.testing.assert_allclose(oc.node_points(1)["xyz"], [[16.0, 22.0, 32.0]], atol=1e-6)
    np.testing.assert_allclose(oc.node_points(0)["xyz"], [[10, 20, 30], [11, 21, 31]], atol=1e-6)
    # no rgb attribute (PotreeConverter --attributes intensity): the grey of a LAS file without colours, not white
    assert oc.node_points(0)["rgba"].view(np.uint8).reshape(-1, 4).tolist() == [[200, 200, 200, 255]] * 2


def test_a_potree_octrees_data_file_given_alone_names_its_folder(converted, tmp_path):
    """octree.bin or hierarchy.bin given as a point file (or a COPC file) said "unknown point cloud
    format (suffix '.bin', ...)" ("not a COPC file" as a URL): it names the folder that opens."""
    from gigapoint.lod.copc import open_copc

    folder = converted[("potree", "DEFAULT")]
    for name in ("octree.bin", "hierarchy.bin"):
        for open_ in (gp.open, open_copc):
            with pytest.raises(InputError) as e:
                open_(folder / name)
            assert str(e.value) == f"{folder / name}: a Potree octree's {name}, part of its folder; open the folder {folder}"
    (tmp_path / "octree.bin").write_bytes((folder / "octree.bin").read_bytes()[:64])  # no metadata.json beside it: no Potree octree's
    with pytest.raises(InputError, match=r"octree\.bin: unknown point cloud format \(suffix '\.bin'"):
        gp.open(tmp_path / "octree.bin")


def test_reader_bad_files_one_line_errors(tmp_path):
    _write_potree(tmp_path / "bad", b"\x00" * 21, 21, b"")
    with pytest.raises(InputError, match="hierarchy") as e:
        open_octree(tmp_path / "bad")
    assert "\n" not in str(e.value)
    (tmp_path / "bad2").mkdir()
    (tmp_path / "bad2" / "metadata.json").write_text("{not json")
    with pytest.raises(InputError, match="metadata.json"):
        open_octree(tmp_path / "bad2")
    short = np.array([(1, 0, 5, 0, 60)], HIERARCHY_DTYPE)  # 5 points claimed, 60 bytes, file empty
    _write_potree(tmp_path / "bad3", short.tobytes(), 22, b"\x00" * 12)
    with pytest.raises(InputError, match="cannot decode node r .bytes 0..60 lie beyond the file's 12"):
        open_octree(tmp_path / "bad3")
    wrong = np.array([(1, 0, 2, 0, 12)], HIERARCHY_DTYPE)  # 2 points in 12 bytes: DEFAULT needs 24
    _write_potree(tmp_path / "bad4", wrong.tobytes(), 22, b"\x00" * 12)
    with pytest.raises(InputError, match="cannot decode node r .node holds 12 bytes, 2 points need 24"):
        open_octree(tmp_path / "bad4")


@pytest.mark.parametrize(
    "change, problem",
    [
        ({"scale": [0.0, 0.0, 0.0]}, r"scale must be positive: \[0.0, 0.0, 0.0\]"),  # every point drawn at the offset
        ({"scale": [0.001, 0.001]}, r"scale is not three finite numbers"),
        ({"offset": [0.0, float("nan"), 0.0]}, r"offset is not three finite numbers"),
        ({"boundingBox": {"min": [1.0, 1.0, 1.0], "max": [0.0, 0.0, 0.0]}}, r"boundingBox.min \[1.0, 1.0, 1.0\] exceeds boundingBox.max"),
    ],
)
def test_metadata_that_cannot_place_points_is_refused_at_open(converted, tmp_path, change, problem):
    import shutil

    path = tmp_path / "meta"
    shutil.copytree(converted[("potree", "DEFAULT")], path)
    meta = json.loads((path / "metadata.json").read_text())
    open_octree(path)  # the copy opens before its metadata is changed
    meta.update(change)
    (path / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=f"invalid Potree hierarchy/metadata \\({problem}") as e:
        open_octree(path)
    assert "\n" not in str(e.value) and str(path) in str(e.value)


@pytest.mark.parametrize(
    "change, problem",
    [  # found by a fuzzer: each was a traceback (KeyError 'position' when a node was drawn; inf and NaN cameras)
        ({"attributes": "renamed"}, r"invalid Potree hierarchy/metadata \(its attributes hold no 'position' of three numbers\)"),
        ({"offset": [0.0, 0.0, 1e308]}, r"corrupt Potree metadata: scale \[.*\] and offset \[0.0, 0.0, 1e\+308\] put its points beyond any coordinate"),
        ({"scale": [0.001, 0.001, 2.269e277]}, r"corrupt Potree metadata: scale \[0.001, 0.001, 2.269e\+277\] and offset"),
    ],
)
def test_metadata_whose_points_cannot_be_drawn_is_refused_at_open(converted, tmp_path, change, problem):
    import shutil

    path = tmp_path / "meta"
    shutil.copytree(converted[("potree", "DEFAULT")], path)
    meta = json.loads((path / "metadata.json").read_text())
    if change.get("attributes") == "renamed":
        change = {"attributes": [dict(a, name="where") if a["name"] == "position" else a for a in meta["attributes"]]}
    meta.update(change)
    (path / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=problem) as e:
        open_octree(path)
    assert "\n" not in str(e.value) and str(path) in str(e.value)


def test_a_bounding_box_beside_the_points_is_refused_at_open(converted, tmp_path):
    """A boundingBox beside the position attribute's min/max culled every node: a blank image
    and "no point is in view"."""
    import shutil

    path = tmp_path / "moved"
    shutil.copytree(converted[("potree", "DEFAULT")], path)
    meta = json.loads((path / "metadata.json").read_text())
    box = meta["boundingBox"]
    edge = box["max"][0] - box["min"][0]
    meta["boundingBox"] = {k: [v[0] + 10 * edge, v[1], v[2]] for k, v in box.items()}
    (path / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"metadata.json: corrupt Potree metadata \(position min/max, boundingBox\): the points' bounds .* "
                       r"lie outside the octree's cube .*; one of them is wrong$"):  # fmt: skip
        open_octree(path)
    # float positions: the writer chooses its cube, then rounds the points to its grid, a step beyond at most
    xyz = np.random.default_rng(0).random((5000, 3)) * 100
    convert(gp.from_arrays(xyz), tmp_path / "floats", format="potree")
    assert open_octree(tmp_path / "floats").n_points == 5000


def test_corrupt_brotli_node_fails_in_one_line_when_drawn(converted, tmp_path):
    import shutil

    from gigapoint import Camera, RenderSettings, render_frame

    path = tmp_path / "broken"
    shutil.copytree(converted[("potree", "BROTLI")], path)
    data = bytearray((path / "octree.bin").read_bytes())
    data[: len(data) // 2] = bytes(len(data) // 2)  # the first nodes (the root among them) zeroed
    (path / "octree.bin").write_bytes(bytes(data))
    oc = open_octree(path)  # sizes cannot be checked without decompressing: opening succeeds
    with pytest.raises(InputError, match=r"octree.bin: cannot decode node r") as e:
        render_frame(oc, Camera.fit(oc.bounds, width=64, height=48), RenderSettings(backend="cpu"))
    assert "\n" not in str(e.value)


# --------------------------------------------------------------------------- nodes loaded on demand


@pytest.fixture(scope="module")
def big_potree(tmp_path_factory):
    """Potree directories far larger than the node cache a test gives them (BROTLI smaller: its writer is slow)."""
    from gigapoint.io import demo_chunks

    d = tmp_path_factory.mktemp("potree_lazy")
    for enc, n in LAZY_SIZES.items():
        convert(
            list(demo_chunks(n, seed=5, chunk_size=200_000)),
            d / enc,
            format="potree",
            encoding=enc,
            max_leaf=4_000,
            partition_points=150_000,
        )
    return d


LAZY_SIZES = {"DEFAULT": 400_000, "BROTLI": 100_000}


def _spy_decode(monkeypatch):
    from gigapoint.lod import potree

    decoded = []
    real = potree.decode_node

    def spy(blob, n, attributes, encoding):
        decoded.append(n)
        return real(blob, n, attributes, encoding)

    monkeypatch.setattr(potree, "decode_node", spy)
    return decoded


def _views(oc):
    from gigapoint import Camera

    lo, hi = oc.bounds
    cams = [Camera.fit(oc.bounds, view=v, width=320, height=240) for v in ("iso", "top")]
    spots = ((100, 100), (600, 200), (300, 700), (700, 700), (100, 500))
    return cams + [Camera.look_at((x, y, hi[2] + 30), (x + 150, y + 150, lo[2]), width=320, height=240) for x, y in spots]


@pytest.mark.parametrize("encoding", ["DEFAULT", "BROTLI"])
def test_potree_nodes_load_on_demand_into_the_bounded_arena(big_potree, encoding, monkeypatch):
    from gigapoint import RenderSettings, render_frame
    from gigapoint.lod.store import ARENA_CHUNK, Arena

    decoded = _spy_decode(monkeypatch)
    oc = open_octree(big_potree / encoding)
    assert oc.n_points == LAZY_SIZES[encoding] and len(oc.keys) > 50
    assert decoded == [] and oc.node_reads == 0 and oc.bytes_read == 0 and oc.arrays == {}  # nothing read at open
    cams = _views(oc)
    root = int(oc.nodes["count"][0])
    s = RenderSettings(backend="cpu", point_budget=2 * root, lod_threshold_px=10.0)

    def selected(cam):
        near, far = cam.clip_range(oc.bounds)
        ids, _, _ = oc.select_nodes(cam.view(oc.bounds), s)
        return ids[oc.nodes["count"][ids] > 0]

    def slots(ids):
        return int(sum(-(-int(oc.nodes["count"][i]) // ARENA_CHUNK) for i in ids))

    # a node cache that holds the largest frame and no more: well below the dataset
    capacity = max(slots(selected(cam)) for cam in cams) * ARENA_CHUNK
    assert capacity < oc.n_points and oc.node_reads == 0
    oc.arena = Arena(capacity, oc.name, oc.bounds, oc._attribute_dtypes())
    arena = oc.arena
    # the first frame loads exactly the nodes it draws, each once
    render_frame(oc, cams[0], s)
    drawn = selected(cams[0])
    assert len(drawn) > 1 and sorted(arena.resident) == sorted(drawn.tolist())
    assert oc.node_reads == len(drawn) == len(decoded) and sorted(decoded) == sorted(oc.nodes["count"][drawn].tolist())
    assert oc.bytes_read == int(oc.byte_size[drawn].sum()) < (big_potree / encoding / "octree.bin").stat().st_size / 2
    # the same view again reads nothing
    render_frame(oc, cams[0], s)
    assert oc.node_reads == len(drawn)
    # other views evict and load; the cache keeps its buffers and size
    seen = set(drawn.tolist())
    for cam in cams[1:]:
        f = render_frame(oc, cam, s)
        assert oc.arena is arena and arena.n_points == capacity
        assert slots(arena.resident) <= capacity // ARENA_CHUNK
        assert 0 < f.stats.points_processed <= s.point_budget
        seen |= set(selected(cam).tolist())
    assert slots(seen) > capacity // ARENA_CHUNK  # more than fits was drawn: nodes were evicted
    assert oc.node_reads == len(decoded) == arena.loads  # every load is one read, nothing else is read


@pytest.mark.parametrize("encoding", ["DEFAULT", "BROTLI"])
def test_potree_on_demand_images_equal_eager_decoding(big_potree, encoding):
    """Every node decoded up front (to_memory, the reader's former path) draws the same pixels."""
    from gigapoint import RenderSettings, render_frame

    lazy = open_octree(big_potree / encoding)
    eager = open_octree(big_potree / encoding).to_memory()
    assert eager.arrays["low"].shape == (LAZY_SIZES[encoding],)
    np.testing.assert_array_equal(np.array(lazy.bounds), np.array(eager.bounds))  # metadata bounds == decoded bounds
    s = RenderSettings(backend="cpu", point_budget=2 * int(lazy.nodes["count"][0]), lod_threshold_px=30.0)
    for cam in _views(lazy)[::3]:
        for settings in (
            s,
            s.replace(color_mode="intensity", intensity_range=(0, 60_000)),
            s.replace(point_budget=10**9, lod_threshold_px=0.0),
        ):
            a, b = render_frame(lazy, cam, settings), render_frame(eager, cam, settings)
            assert a.stats.points_processed == b.stats.points_processed > 0
            assert (~a.empty).sum() > 1000
            np.testing.assert_array_equal(a.image, b.image)
            np.testing.assert_array_equal(a.depth, b.depth)


def test_pack_records_are_numpys_records_and_statistics():
    """pack_records (one pass from the unsorted inputs, what the build writes into octree.bin) =
    the points gathered and encoded field by field in numpy, byte for byte, and its minimum and
    maximum of each field = numpy's, for every attribute type, a field the points lack (zeros),
    a float attribute with a NaN (it wins, as in numpy's min), several of its tasks."""
    from gigapoint.lod.potree import _TYPES, pack_records, record_dtype, write_layout

    rng = np.random.default_rng(3)
    m, n = 40_000, 30_000
    xyz = rng.uniform(0, 500, (m, 3)) + [1000.0, 2000.0, 0.0]
    rgba = rng.integers(0, 2**32, m, dtype=np.uint32)
    attrs = {
        "classification": rng.integers(0, 32, m).astype(np.uint8),  # (no intensity: written as zeros)
        "small": rng.integers(-128, 128, m).astype(np.int8),
        "short": rng.integers(-30000, 30000, m).astype(np.int16),
        "word": rng.integers(0, 2**32, m, dtype=np.uint32),
        "signed": rng.integers(-(2**31), 2**31, m).astype(np.int32),
        "big": rng.integers(-(2**62), 2**62, m, dtype=np.int64),
        "huge": rng.integers(0, 2**64 - 1, m, dtype=np.uint64),
        "height": rng.uniform(-5, 40, m).astype(np.float32),
        "gps_time": rng.uniform(0, 1e6, m),
        "flag": rng.random(m) < 0.5,
    }
    attrs["gps_time"][7] = np.nan
    idx = rng.choice(m, n, replace=False)
    layout = write_layout({a: v.dtype for a, v in attrs.items()})
    scale, offset = np.array([0.001, 0.002, 0.01]), np.array([999.0, 1999.5, -1.0])
    out = np.zeros(n * record_dtype(layout).itemsize, np.uint8)
    stats = pack_records(xyz, rgba, attrs, idx, layout, scale, offset, out)

    ref = np.zeros(n, record_dtype(layout))
    q = np.floor((xyz[idx] - offset) / scale + 0.5)
    ref["position"] = np.clip(q.astype(np.int64), 0, 2**31 - 1)
    rgb16 = rgba[idx].view(np.uint8).reshape(-1, 4)[:, :3].astype(np.uint16) * np.uint16(257)
    ref["rgb"] = rgb16
    expected = {"position": [q.min(axis=0).tolist(), q.max(axis=0).tolist()], "rgb": [rgb16.min(axis=0).tolist(), rgb16.max(axis=0).tolist()]}
    for a, t, _ in layout:
        if a in ("position", "rgb"):
            continue
        v = attrs[a][idx].astype(_TYPES[t]) if a in attrs else np.zeros(n, _TYPES[t])
        ref[a] = v
        expected[a] = [[float(v.min())], [float(v.max())]]
    assert out.tobytes() == ref.tobytes()
    assert stats.keys() == expected.keys()
    for a in stats:
        np.testing.assert_array_equal(np.array(stats[a], float), np.array(expected[a], float), err_msg=a)
    assert np.isnan(stats["gps_time"][0][0]) and np.isnan(stats["gps_time"][1][0])
    assert stats["intensity"] == [[0.0], [0.0]]
    assert stats["huge"][1][0] == float(attrs["huge"][idx].max())  # above 2^53: rounded as numpy rounds its maximum


# PotreeConverter 2.1.1's output (data/potree_converter/make.py says how it was made): 1200
# points of the demo town in town.laz, a fifth with dark 16-bit colours, signed scan angle ranks
POTREE_CONVERTER = Path(__file__).parent / "data" / "potree_converter"


@pytest.mark.parametrize("encoding", ["DEFAULT", "BROTLI"])
def test_potree_converter_output_reads_back_as_its_input(encoding):
    import laspy

    src = laspy.read(POTREE_CONVERTER / "town.laz")
    pot = gp.open(POTREE_CONVERTER / f"town_{encoding}")
    meta = json.loads((POTREE_CONVERTER / f"town_{encoding}" / "metadata.json").read_text())
    assert pot.n_points == meta["points"] == len(src.points) == 1200
    got = [pot.node_points(i) for i in range(len(pot.keys)) if pot.nodes["count"][i]]
    got = {k: np.concatenate([g[k] for g in got]) for k in got[0]}
    # positions as PotreeConverter stores them: truncated to its grid, one step up in BROTLI
    # (its Morton codes count from a node minimum that starts at int32(INT64_MAX) = -1)
    scale, offset = np.array(meta["scale"]), np.array(meta["offset"])
    want = ((np.stack([src.x, src.y, src.z], 1) - offset) / scale).astype(np.int32) + (encoding == "BROTLI")
    have = np.round((got["xyz"] - offset) / scale).astype(np.int64)
    i, j = np.lexsort(want.T), np.lexsort(have.T)
    np.testing.assert_array_equal(have[j], want[i])  # every point once
    # colours as gigapoint reads the LAS file: 16-bit (>> 8) for all, the dark ones (under 256) too
    rgb16 = np.stack([src.red, src.green, src.blue], 1)[i]
    assert (rgb16.max(axis=1) < 256).sum() == 244
    np.testing.assert_array_equal(got["rgba"].view(np.uint8).reshape(-1, 4)[j, :3], rgb16 >> 8)
    # every LAS field and extra byte PotreeConverter wrote, as the file's values (the scan angle rank signed)
    # named as gigapoint's LAS reader names them (LAS's fields as laspy does, extra bytes as they
    # are), which also gives the bit fields PotreeConverter does not write
    assert set(pot.attribute_names) <= set(gp.open(POTREE_CONVERTER / "town.laz").attributes)
    assert pot.attribute_names == [
        "classification", "gps_time", "height above ground", "intensity", "number_of_returns", "point_source_id", "quality",
        "return_number", "scan_angle_rank", "tilt", "user_data"]  # fmt: skip
    for name in pot.attribute_names:
        values = np.asarray(src[name])[i]
        assert got[name].dtype == values.dtype, name
        np.testing.assert_array_equal(got[name][j], values, err_msg=name)
    assert got["scan_angle_rank"].min() == -90
    np.testing.assert_allclose(pot.meta["bounds"]["min"], src.header.mins)
    np.testing.assert_allclose(pot.meta["bounds"]["max"], src.header.maxs)


def test_our_potree_metadata_names_las_fields_as_potree_converter_does(tmp_path):
    """The same LAS file through our writer and PotreeConverter: each field PotreeConverter wrote
    has its name and type in ours (Potree's viewer knows fields by these names), and the grid and
    cube are the same."""
    convert([POTREE_CONVERTER / "town.laz"], tmp_path / "p", format="potree")
    ours = json.loads((tmp_path / "p" / "metadata.json").read_text())
    theirs = json.loads((POTREE_CONVERTER / "town_DEFAULT" / "metadata.json").read_text())
    types = {a["name"]: a["type"] for a in ours["attributes"]}
    # (scan angle rank: LAS's int8, which PotreeConverter calls uint8; our records say int8)
    want = {a["name"]: "int8" if a["name"] == "scan angle rank" else a["type"] for a in theirs["attributes"]}
    assert {n: types.get(n) for n in want} == want
    assert ours["scale"] == theirs["scale"] and ours["spacing"] == pytest.approx(theirs["spacing"])
    for a, b in ((ours["offset"], theirs["offset"]), (ours["boundingBox"]["min"], theirs["boundingBox"]["min"]),
                 (ours["boundingBox"]["max"], theirs["boundingBox"]["max"])):  # fmt: skip
        np.testing.assert_allclose(a, b, atol=0.0101)  # (ours may start a grid step lower)


def test_info_says_what_a_potree_converter_directory_holds(tmp_path):
    """No rgb attribute (PotreeConverter --attributes intensity): no colour; more points in the
    nodes than the metadata counts (its poisson_average: copies in inner nodes): said."""
    from gigapoint.lod import octree_info

    pts = np.array([[0, 0, 0], [2, 2, 2], [12, 4, 4]], "<i4")
    _write_potree(tmp_path / "p", np.array([(1, 0, 3, 0, 36)], HIERARCHY_DTYPE).tobytes(), 22, pts.tobytes())
    info = octree_info(tmp_path / "p")
    assert info["point_count"] == 3 and info["has_color"] is False and "copies" not in info["details"]["octree"]
    meta = json.loads((tmp_path / "p" / "metadata.json").read_text())
    meta["points"] = 2
    meta["attributes"].append({"name": "rgb", "type": "uint16", "numElements": 3, "size": 6, "elementSize": 2})
    (tmp_path / "p" / "metadata.json").write_text(json.dumps(meta))
    (tmp_path / "p" / "octree.bin").write_bytes(np.zeros(3, [("position", "<i4", (3,)), ("rgb", "<u2", (3,))]).tobytes())
    (tmp_path / "p" / "hierarchy.bin").write_bytes(np.array([(1, 0, 3, 0, 54)], HIERARCHY_DTYPE).tobytes())
    info = octree_info(tmp_path / "p")
    assert info["point_count"] == 3 and info["has_color"] is True
    assert info["details"]["octree"].endswith("; 1 of the points are copies of the metadata's 2 in inner nodes (PotreeConverter's poisson_average)")


@pytest.mark.parametrize("encoding", ["DEFAULT", "BROTLI"])
def test_an_attribute_of_several_numbers_is_one_attribute_a_number(tmp_path, encoding):
    """A 3-float extra bytes field (a LAS '3f4' normal, which PotreeConverter keeps as one
    attribute of numElements 3) reads as normal_0 .. normal_2, as gigapoint's LAS reader reads it."""
    import brotli

    pts = np.array([[0, 0, 0], [2, 2, 2], [12, 4, 4]], "<i4")
    normal = np.array([[0.5, -1, 2], [3, 4, 5], [-6, 7, 8.25]], "<f4")
    rec = np.zeros(3, [("position", "<i4", (3,)), ("normal", "<f4", (3,)), ("quality", "u1")])
    rec["position"], rec["normal"], rec["quality"] = pts, normal, [7, 8, 9]
    # BROTLI: attribute by attribute; positions as Morton codes (hand-made: x, y, z bits interleaved)
    morton = [sum(((int(p[a]) >> b) & 1) << (3 * b + a) for b in range(16) for a in range(3)) for p in pts]
    blob = rec.tobytes() if encoding == "DEFAULT" else brotli.compress(
        np.array([[0, m] for m in morton], "<u8").tobytes() + normal.tobytes() + rec["quality"].tobytes())  # fmt: skip
    _write_potree(tmp_path / "p", np.array([(1, 0, 3, 0, len(blob))], HIERARCHY_DTYPE).tobytes(), 22, blob)
    meta = json.loads((tmp_path / "p" / "metadata.json").read_text())
    meta["encoding"] = encoding
    meta["attributes"] += [{"name": "normal", "type": "float", "numElements": 3, "size": 12, "elementSize": 4},
                           {"name": "quality", "type": "uint8", "numElements": 1, "size": 1, "elementSize": 1}]  # fmt: skip
    (tmp_path / "p" / "metadata.json").write_text(json.dumps(meta))
    oc = gp.open(tmp_path / "p")
    assert oc.attribute_names == ["normal_0", "normal_1", "normal_2", "quality"]
    got = oc.node_points(0)
    order = np.lexsort(np.round(got["xyz"]).T)  # (BROTLI: Morton order)
    want = np.lexsort((pts * 0.5 + [10, 20, 30]).T)
    for k in range(3):
        assert got[f"normal_{k}"].dtype == np.float32
        np.testing.assert_array_equal(got[f"normal_{k}"][order], normal[want, k])
    np.testing.assert_array_equal(got["quality"][order], np.array([7, 8, 9])[want])


def _points_of(cloud) -> dict:
    """Every point of an octree's nodes ({field: values}), in node order."""
    got = [cloud.node_points(i) for i in range(len(cloud.keys)) if cloud.nodes["count"][i]]
    return {k: np.concatenate([g[k] for g in got]) for k in got[0]}


@pytest.mark.parametrize("encoding", ["DEFAULT", "BROTLI"])
def test_points_without_colours_make_a_potree_folder_without_rgb(tmp_path, encoding):
    """As PotreeConverter 2: a LAS file without RGB (point format 1), or a cloud converted with
    has_color=False, gets no rgb attribute in metadata.json and no rgb bytes in its records (it
    got the grey of points without colours, 6 bytes a point); the folder reads back: the same
    points and intensities, the grey of a colourless LAS file, no colour says info."""
    import laspy

    from gigapoint.core.chunk import DEFAULT_COLOR
    from gigapoint.lod import octree_info

    rng = np.random.default_rng(5)
    n = 6_000
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = [0.01] * 3, [1000.0, 2000.0, 0.0]
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = (rng.integers(0, 50_000, n, dtype=np.int32) for _ in range(3))
    las.intensity = rng.integers(0, 65536, n).astype(np.uint16)
    las.classification = rng.integers(0, 8, n).astype(np.uint8)
    las.write(str(tmp_path / "norgb.las"))
    convert([tmp_path / "norgb.las"], tmp_path / "las", format="potree", encoding=encoding, max_leaf=1_000)
    xyz = np.stack([las.x, las.y, las.z], axis=1)
    convert(gp.from_arrays(xyz), tmp_path / "cloud", format="potree", encoding=encoding, max_leaf=1_000, has_color=False)

    for out in (tmp_path / "las", tmp_path / "cloud"):
        meta = json.loads((out / "metadata.json").read_text())
        names = [a["name"] for a in meta["attributes"]]
        assert "rgb" not in names and names[:3] == ["position", "intensity", "classification"], out
        assert octree_info(out)["has_color"] is False
        if encoding == "DEFAULT":  # a node's bytes: its points' records, of the attributes stated, nothing more
            record_size = sum(a["size"] for a in meta["attributes"])
            if out.name == "cloud":  # (the LAS file's have its fields too: returns, GPS time, ...)
                assert names == ["position", "intensity", "classification"] and record_size == 12 + 2 + 1
            assert (out / "octree.bin").stat().st_size == n * record_size
        back = _points_of(open_octree(out))
        assert len(back["xyz"]) == n
        have, want = np.round((back["xyz"] - [1000.0, 2000.0, 0.0]) / 0.01).astype(np.int64), np.stack([las.X, las.Y, las.Z], 1)
        i, j = np.lexsort(want.T), np.lexsort(have.T)
        np.testing.assert_array_equal(have[j], want[i])
        assert (back["rgba"] == np.array(DEFAULT_COLOR, np.uint8).view(np.uint32)[0]).all()
        if out.name == "las":
            np.testing.assert_array_equal(back["intensity"][j], np.asarray(las.intensity)[i])
