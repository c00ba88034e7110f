"""LAS/LAZ reading: round trips over versions 1.0-1.4 and point formats 0-10, chunking, colors."""

from __future__ import annotations

import laspy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import gigapoint as gp
from gigapoint.core.chunk import DEFAULT_COLOR
from gigapoint.errors import InputError
from gigapoint.io import file_info, open_cloud, read_chunks, reader_for

RNG = np.random.default_rng(7)
COLOR_FORMATS = {2, 3, 5, 7, 8, 10}
GPS_FORMATS = {1, 3, 4, 5, 6, 7, 8, 9, 10}


def write_las(path, n=1000, point_format=3, version="1.2", scale=0.001, offset=(500_000.0, 4_000_000.0, 100.0), color16=True, seed=0):
    """Write a LAS/LAZ file (by suffix) with known values; return the arrays written."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=point_format, version="1.1" if version == "1.0" else version)
    header.scales = np.array([scale] * 3)
    header.offsets = np.array(offset)
    las = laspy.LasData(header)
    xyz = np.column_stack([rng.uniform(0, 1000, n), rng.uniform(0, 800, n), rng.uniform(0, 50, n)]) + np.array(offset)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    ref = {"xyz": xyz}
    ref["intensity"] = rng.integers(0, 65535, n).astype(np.uint16)
    las.intensity = ref["intensity"]
    ref["classification"] = rng.integers(0, 31, n).astype(np.uint8)
    las.classification = ref["classification"]
    nret = rng.integers(1, 6, n).astype(np.uint8)
    ret = np.minimum(rng.integers(1, 6, n), nret).astype(np.uint8)
    las.return_number, las.number_of_returns = ret, nret
    ref["return_number"], ref["number_of_returns"] = ret, nret
    ref["point_source_id"] = rng.integers(0, 65535, n).astype(np.uint16)
    las.point_source_id = ref["point_source_id"]
    if point_format in GPS_FORMATS:
        ref["gps_time"] = rng.uniform(0, 1e6, n)
        las.gps_time = ref["gps_time"]
    for name, values in scan_fields(point_format, n, rng).items():
        las[name] = ref[name] = values
    if point_format in COLOR_FORMATS:
        rgb8 = rng.integers(0, 256, (n, 3)).astype(np.uint16)
        rgb = rgb8 * 257 if color16 else rgb8
        las.red, las.green, las.blue = rgb[:, 0], rgb[:, 1], rgb[:, 2]
        ref["rgb8"] = rgb8.astype(np.uint8)
    las.write(str(path))
    if version == "1.0":  # laspy writes 1.1 at the oldest; 1.0 has the same header layout
        with open(path, "r+b") as f:
            f.seek(25)
            f.write(b"\x00")
    return ref


def scan_fields(point_format, n, rng) -> dict:
    """Random values of the scan angle, user data and flag fields of ``point_format``, as laspy names them."""
    out = {"user_data": rng.integers(0, 256, n).astype(np.uint8)}
    flags = ["scan_direction_flag", "edge_of_flight_line", "synthetic", "key_point", "withheld"]
    if point_format >= 6:
        out["scan_angle"] = rng.integers(-15_000, 15_001, n).astype(np.int16)
        out["scanner_channel"] = rng.integers(0, 4, n).astype(np.uint8)
        flags.append("overlap")
    else:
        out["scan_angle_rank"] = rng.integers(-90, 91, n).astype(np.int8)
    out.update({f: rng.integers(0, 2, n).astype(np.uint8) for f in flags})
    return out


SCAN_FIELDS = ("scan_angle_rank", "scan_angle", "user_data", "scan_direction_flag", "edge_of_flight_line", "synthetic", "key_point",
               "withheld", "overlap", "scanner_channel")  # fmt: skip


def collect(path, chunk_size=10_000_000):
    chunks = list(read_chunks(path, chunk_size=chunk_size))
    xyz = np.concatenate([c.xyz for c in chunks])
    rgba = np.concatenate([c.rgba for c in chunks])
    attrs = {k: np.concatenate([c.attributes[k] for c in chunks]) for k in chunks[0].attributes}
    return chunks, xyz, rgba, attrs


FORMAT_VERSIONS = [(f, "1.2") for f in range(4)] + [(4, "1.3"), (5, "1.3")] + [(f, "1.4") for f in range(6, 11)] + [(0, "1.0"), (1, "1.1"), (3, "1.3"), (3, "1.4")]


@pytest.mark.parametrize("suffix", [".las", ".laz"])
@pytest.mark.parametrize("point_format,version", FORMAT_VERSIONS)
def test_round_trip_all_point_formats(tmp_path, point_format, version, suffix):
    path = tmp_path / f"pf{point_format}_{version}{suffix}"
    ref = write_las(path, n=777, point_format=point_format, version=version)
    _, xyz, rgba, attrs = collect(path)
    assert len(xyz) == 777
    assert xyz.dtype == np.float64
    np.testing.assert_allclose(xyz, ref["xyz"], rtol=0, atol=0.001 / 2 + 1e-9)
    if point_format in COLOR_FORMATS:
        np.testing.assert_array_equal(rgba[:, :3], ref["rgb8"])  # 16-bit colors scaled to 8 bits
    else:
        assert (rgba == np.array(DEFAULT_COLOR, np.uint8)).all()  # no RGB: default color
    assert (rgba[:, 3] == 255).all()
    for name in ("intensity", "classification", "return_number", "number_of_returns", "point_source_id"):
        np.testing.assert_array_equal(attrs[name], ref[name], err_msg=name)
    if point_format in GPS_FORMATS:
        np.testing.assert_array_equal(attrs["gps_time"], ref["gps_time"])
    else:
        assert "gps_time" not in attrs
    # the scan angle, user data and flags: lost before, in every conversion
    assert {k for k in attrs if k in SCAN_FIELDS} == {k for k in ref if k in SCAN_FIELDS}
    for name in SCAN_FIELDS:
        if name in ref:
            assert attrs[name].dtype == ref[name].dtype and ref[name].min() < ref[name].max(), name
            np.testing.assert_array_equal(attrs[name], ref[name], err_msg=name)
    picked = gp.open(path).point_info(123)  # (the cloud's order is its own: the written point found by position)
    i = int(np.argmin(np.abs(ref["xyz"] - picked["position"]).sum(axis=1)))
    assert {k: picked[k] for k in SCAN_FIELDS if k in ref} == {k: int(ref[k][i]) for k in SCAN_FIELDS if k in ref}
    info = file_info(path)
    assert info["format"] == ("LAZ" if suffix == ".laz" else "LAS")
    assert info["las_version"] == version
    assert info["point_format"] == point_format
    assert info["point_count"] == 777
    assert info["has_color"] == (point_format in COLOR_FORMATS)


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_chunking_gives_the_same_points(tmp_path, suffix):
    path = tmp_path / f"c{suffix}"
    write_las(path, n=10_001, point_format=7, version="1.4")
    one, xyz1, rgba1, attrs1 = collect(path)
    many, xyz2, rgba2, attrs2 = collect(path, chunk_size=999)
    assert len(one) == 1
    assert [len(c) for c in many] == [999] * 10 + [11]
    np.testing.assert_array_equal(xyz1, xyz2)
    np.testing.assert_array_equal(rgba1, rgba2)
    for k in attrs1:
        np.testing.assert_array_equal(attrs1[k], attrs2[k])


def test_8bit_colors_stored_in_16bit_fields_kept(tmp_path):
    path = tmp_path / "c8.las"
    ref = write_las(path, n=500, point_format=2, color16=False)
    _, _, rgba, _ = collect(path)
    np.testing.assert_array_equal(rgba[:, :3], ref["rgb8"])


def test_16bit_decision_is_per_file_not_per_chunk(tmp_path):
    """A dark first chunk (all values <= 255 in 16-bit) must not switch the file to 8-bit."""
    header = laspy.LasHeader(point_format=2, version="1.2")
    las = laspy.LasData(header)
    n = 2000
    las.x = np.arange(n, dtype=float)
    las.y = np.zeros(n)
    las.z = np.zeros(n)
    rgb = np.full(n, 200 * 257, np.uint16)
    rgb[:1000] = 200  # first half very dark in 16-bit terms: 200/65535
    las.red = las.green = las.blue = rgb
    path = tmp_path / "dark.las"
    las.write(str(path))
    # first chunk has only values <= 255: judged 8-bit, then the next chunk (>255) switches to 16-bit
    chunks = list(read_chunks(path, chunk_size=1000))
    assert chunks[1].rgba[0, 0] == 200
    # one chunk: 16-bit for all
    (whole,) = list(read_chunks(path, chunk_size=5000))
    assert whole.rgba[0, 0] == 0 and whole.rgba[1500, 0] == 200


def test_open_cloud_las_utm_precision(tmp_path):
    path = tmp_path / "utm.laz"
    ref = write_las(path, n=3000, point_format=3, scale=0.01)
    cloud = open_cloud(path)
    assert cloud.n_points == 3000
    assert cloud.name == "utm.laz"
    lo, hi = cloud.bounds
    np.testing.assert_allclose(lo, ref["xyz"].min(axis=0), atol=0.006)
    np.testing.assert_allclose(hi, ref["xyz"].max(axis=0), atol=0.006)
    # every written point comes back (order changes: Morton order)
    got = np.round(cloud.positions(), 2)
    want = np.round(ref["xyz"], 2)
    np.testing.assert_allclose(got[np.lexsort(got.T[::-1])], want[np.lexsort(want.T[::-1])], atol=0.011)
    assert set(cloud.attributes) >= {"intensity", "classification", "gps_time"}


def test_file_info_las_fields(tmp_path):
    path = tmp_path / "i.las"
    write_las(path, n=100, point_format=1, version="1.4", scale=0.01, offset=(10.0, 20.0, 30.0))
    info = file_info(path)
    assert info["scale"] == [0.01, 0.01, 0.01]
    assert info["offset"] == [10.0, 20.0, 30.0]
    assert info["crs"] is None
    assert info["file_size"] == path.stat().st_size
    assert "gps_time" in info["attributes"]
    assert len(info["bounds"]["min"]) == 3


def test_crs_from_geokeys_without_pyproj(tmp_path):
    from laspy.vlrs.known import GeoKeyDirectoryVlr, GeoKeyEntryStruct

    header = laspy.LasHeader(point_format=0, version="1.2")
    vlr = GeoKeyDirectoryVlr()
    vlr.geo_keys_header.number_of_keys = 1
    key = GeoKeyEntryStruct()
    key.id, key.tiff_tag_location, key.count, key.value_offset = 3072, 0, 1, 32633
    vlr.geo_keys = [key]
    header.vlrs.append(vlr)
    las = laspy.LasData(header)
    las.x = las.y = las.z = np.arange(5.0)
    path = tmp_path / "crs.las"
    las.write(str(path))
    assert file_info(path)["crs"] == "EPSG:32633"  # from the GeoKey without pyproj, or pyproj's to_epsg()


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_extra_bytes_are_read_as_attributes(tmp_path, suffix):
    """Extra bytes are attributes (scaled where the file scales them), after the standard ones; an
    array of 3 a point is 3 attributes (direction_0..2: it was left out without a word). They
    were dropped: a file's HeightAboveGround or amplitude could not be coloured by, and a live
    cloud's saved extras did not come back."""
    header = laspy.LasHeader(point_format=3, version="1.4")
    header.add_extra_dim(laspy.ExtraBytesParams(name="height_above_ground", type=np.float32))
    header.add_extra_dim(laspy.ExtraBytesParams(name="amplitude", type=np.uint16, scales=np.array([0.5]), offsets=np.array([10.0])))
    header.add_extra_dim(laspy.ExtraBytesParams(name="direction", type="3f8"))
    header.add_extra_dim(laspy.ExtraBytesParams(name="a/b", type=np.uint8))  # read as a_b: names are file name parts
    header.add_extra_dim(laspy.ExtraBytesParams(name="..", type=np.uint8))  # left out
    las = laspy.LasData(header)
    las.x = las.y = las.z = np.arange(20.0)
    las.height_above_ground = np.arange(20, dtype=np.float32)
    las.amplitude = 10.0 + 0.5 * np.arange(20)
    las.direction = np.arange(60.0).reshape(20, 3)
    path = tmp_path / f"eb{suffix}"
    las.write(str(path))
    _, xyz, _, attrs = collect(path)
    np.testing.assert_array_equal(xyz[:, 0], np.arange(20.0))
    assert list(attrs)[-6:] == ["height_above_ground", "amplitude", "direction_0", "direction_1", "direction_2", "a_b"] and "intensity" in attrs
    for k in range(3):
        np.testing.assert_array_equal(attrs[f"direction_{k}"], np.arange(60.0).reshape(20, 3)[:, k])
    np.testing.assert_array_equal(attrs["height_above_ground"], np.arange(20, dtype=np.float32))
    np.testing.assert_array_equal(attrs["amplitude"], 10.0 + 0.5 * np.arange(20))
    assert "height_above_ground" in file_info(path)["dimensions"] and file_info(path)["attributes"][-6:] == list(attrs)[-6:]
    assert reader_for(path).header(path)["attributes"] == list(attrs)  # before reading (render --color-attribute's check)
    cloud = gp.open(path, progressive=True)
    assert cloud.wait() and cloud.attribute_names[-6:] == tuple(attrs)[-6:]
    result = gp.convert(path, tmp_path / "octree")  # ('a/b' made the conversion fail on a file 'attr.a/b.npy')
    assert result.points == 20 and "a_b" in gp.open(tmp_path / "octree").node_points(0)


@settings(max_examples=25, deadline=None)
@given(
    scale=st.sampled_from([1e-3, 0.01, 0.25, 1.0]),
    offset=st.floats(-1e7, 1e7, allow_nan=False),
    n=st.integers(1, 300),
    chunk=st.integers(1, 400),
    seed=st.integers(0, 2**16),
)
def test_round_trip_property(tmp_path_factory, scale, offset, n, chunk, seed):
    """Any scale/offset/count/chunk size: every point comes back within half a scale step, in order."""
    rng = np.random.default_rng(seed)
    ints = rng.integers(-(2**31) + 1, 2**31 - 1, (n, 3))
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales = np.array([scale] * 3)
    header.offsets = np.array([offset] * 3)
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = ints[:, 0], ints[:, 1], ints[:, 2]
    path = tmp_path_factory.mktemp("prop") / "p.las"
    las.write(str(path))
    chunks = list(read_chunks(path, chunk_size=chunk))
    assert all(len(c) <= chunk for c in chunks)
    xyz = np.concatenate([c.xyz for c in chunks])
    np.testing.assert_array_equal(xyz, ints * scale + offset)


def test_las14_with_only_the_legacy_count(tmp_path):
    import struct

    path = tmp_path / "legacy.las"
    write_las(path, n=321, point_format=3, version="1.4")
    with open(path, "r+b") as f:
        f.seek(107)
        f.write(struct.pack("<I", 321))
        f.seek(247)
        f.write(struct.pack("<Q", 0))
    _, xyz, _, _ = collect(path)
    assert len(xyz) == 321
    assert file_info(path)["point_count"] == 321


def _with_extra_bytes(path, point_format, version, color16, n=3000):
    """``write_las``'s file with extra bytes of every size and kind added (a scaled one, an
    array of 3, signed, unsigned, float), random values; returns laspy's view of the points."""
    write_las(path, n=n, point_format=point_format, version=version, color16=color16, offset=(636_000.0, 849_000.0, 400.0), scale=0.01)
    las = laspy.read(str(path))
    rng = np.random.default_rng(point_format)
    extras = {"i8": np.int8, "u16": np.uint16, "i32": np.int32, "f32": np.float32, "u64": np.uint64, "normal": "3f8"}
    for name, t in extras.items():
        las.add_extra_dim(laspy.ExtraBytesParams(name=name, type=t))
        values = rng.integers(-100, 100, (n, 3)) * 0.25 if name == "normal" else rng.integers(0, 120, n).astype(t) - (t is np.int8) * 60
        setattr(las, name, values)
    las.add_extra_dim(laspy.ExtraBytesParams(name="amplitude", type=np.uint16, scales=np.array([0.5]), offsets=np.array([10.0])))
    las.amplitude = 10.0 + 0.5 * rng.integers(0, 1000, n)
    las.write(str(path))
    return laspy.read(str(path))


@pytest.mark.parametrize("color16", [True, False])
@pytest.mark.parametrize("point_format,version", [(0, "1.2"), (1, "1.0"), (3, "1.2"), (5, "1.3"), (6, "1.4"), (8, "1.4"), (10, "1.4")])
def test_small_files_decode_by_numpy_like_the_kernel(tmp_path, monkeypatch, color16, point_format, version):
    """Files up to NUMPY_MAX points are decoded by numpy and laspy, a field at a time (a small
    file's first open compiles no kernel); larger ones by one parallel pass over the records
    (io/las._decode_records): both give laspy's positions, colours and attributes, bit fields
    and extra bytes of every size included, with laspy's dtypes, in the same order."""
    from gigapoint.io import las

    path = tmp_path / "a.las"
    if version == "1.0":  # (laspy writes no 1.0 with extra bytes)
        write_las(path, n=3000, point_format=point_format, version=version, color16=color16, offset=(636_000.0, 849_000.0, 400.0), scale=0.01)
        ref = laspy.read(str(path))
    else:
        ref = _with_extra_bytes(path, point_format, version, color16)
    small = list(read_chunks(path, chunk_size=1000))
    monkeypatch.setattr(las, "NUMPY_MAX", 0)
    large = list(read_chunks(path, chunk_size=1000))
    assert len(small) == len(large) == 3
    for a, b in zip(small, large):
        np.testing.assert_array_equal(a.xyz, b.xyz)
        np.testing.assert_array_equal(a.rgba, b.rgba)
        assert list(a.attributes) == list(b.attributes)
        for k, v in b.attributes.items():
            assert v.dtype == a.attributes[k].dtype and np.array_equal(v, a.attributes[k]), k
    got = {k: np.concatenate([c.attributes[k] for c in large]) for k in large[0].attributes}
    np.testing.assert_array_equal(np.concatenate([c.xyz for c in large]), np.column_stack([ref.x, ref.y, ref.z]))
    for k, v in got.items():
        want = np.asarray(ref[k[:-2]])[:, int(k[-1])] if k.startswith("normal_") else np.asarray(ref[k])
        assert v.dtype == want.dtype and np.array_equal(v, want), k
    if version != "1.0":
        assert list(got)[-9:] == ["i8", "u16", "i32", "f32", "u64", "normal_0", "normal_1", "normal_2", "amplitude"]
        assert np.ptp(got["i8"]) > 50 and got["i8"].min() < 0 and got["amplitude"].dtype == np.float64
    if point_format in COLOR_FORMATS:
        assert np.ptp(np.concatenate([c.rgba for c in small])[:, :3]) > 100  # real colors, not a constant
    assert np.ptp(got["return_number"]) > 0 and np.ptp(got["classification"]) > 10


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_records_read_into_a_reused_buffer_are_laspys(tmp_path, monkeypatch, suffix):
    """LAS/LAZ records are read into one buffer reused chunk after chunk (io/las._Records),
    not laspy's new bytearray a chunk: the chunks, all held at once, are what laspy's own
    ``read_points`` gives (the way a point source _Records does not know keeps). A LAZ's
    ``fast`` records come from the decoding child process (io/laz_process.py)."""
    from gigapoint.io import las, laz_process

    path = tmp_path / f"r{suffix}"
    write_las(path, n=5_003, point_format=3)
    fast = list(read_chunks(path, chunk_size=1_000))
    monkeypatch.setenv(laz_process.ENV_SWITCH, "0")  # laspy's way in this process
    made = []

    class LaspysWay(las._Records):
        def __init__(self, reader, most):
            super().__init__(reader, most)
            made.append(self.fill is not None)  # the buffer was in use
            self.fill = None

    monkeypatch.setattr(las, "_Records", LaspysWay)
    slow = list(read_chunks(path, chunk_size=1_000))
    assert made == [True] and [len(c) for c in fast] == [len(c) for c in slow] == [1_000] * 5 + [3]
    for a, b in zip(fast, slow):
        np.testing.assert_array_equal(a.xyz, b.xyz)
        np.testing.assert_array_equal(a.rgba, b.rgba)
        assert a.attributes.keys() == b.attributes.keys()
        for k in a.attributes:
            np.testing.assert_array_equal(a.attributes[k], b.attributes[k])
            assert a.attributes[k].dtype == b.attributes[k].dtype


def test_files_of_point_formats_0_5_and_6_10_keep_one_scan_angle(tmp_path):
    """Formats 0-5 hold the scan angle as scan_angle_rank (int8 degrees), 6-10 as scan_angle
    (int16, 0.006 degrees): merged, neither name was in every file and the scan angle was left
    out. Now the former is read as scan_angle where files differ: through gp.open of both (also
    chunked), a progressive load and a COPC conversion, every point's angle kept; files that agree keep their name."""
    a = write_las(tmp_path / "a.las", n=500, point_format=3, seed=1)
    b = write_las(tmp_path / "b.las", n=400, point_format=7, version="1.4", seed=2)
    write_las(tmp_path / "c.las", n=300, point_format=1, seed=3)
    assert a["scan_angle_rank"][a["scan_angle_rank"] == 18].size and b["scan_angle"].min() < -1000
    xyz = np.concatenate([a["xyz"], b["xyz"]])
    angle = np.concatenate([np.rint(a["scan_angle_rank"] / 0.006), b["scan_angle"]]).astype(np.int16)  # 18 degrees: 3000
    mm = lambda p: np.lexsort(np.rint(np.asarray(p) * 1000).astype(np.int64).T)  # points matched by position
    want = angle[mm(xyz)]
    dropped = r": attribute\(s\) overlap, scanner_channel not in every file"
    for paths, chunked in ((("a.las", "b.las"), False), (("b.las", "a.las"), False), (("a.las", "b.las"), True)):
        with pytest.warns(gp.GigapointWarning, match=dropped):
            cloud = gp.open(*(tmp_path / p for p in paths), chunked=chunked)
        got = np.asarray(cloud.attributes["scan_angle"])
        assert "scan_angle_rank" not in cloud.attributes and got.dtype == np.int16
        np.testing.assert_array_equal(got[mm(cloud.positions())], want)
    live = gp.open(tmp_path / "a.las", tmp_path / "b.las", progressive=True)
    with pytest.warns(gp.GigapointWarning, match=dropped):  # (issued by wait, in this thread)
        assert live.wait(timeout=120)
    assert live.n_points == 900
    slots = np.concatenate([live.node_entries(n) for n in live.leaves()])
    assert "scan_angle_rank" not in live.attribute_names
    np.testing.assert_array_equal(np.asarray(live.attributes["scan_angle"])[slots][mm(live.positions(slots))], want)
    live.close()
    with pytest.warns(gp.GigapointWarning, match=dropped):
        gp.convert([tmp_path / "a.las", tmp_path / "b.las"], tmp_path / "out.copc.laz", format="copc")
    copc = gp.open(tmp_path / "out.copc.laz")
    parts = [copc.node_points(i) for i in np.flatnonzero(copc.counts > 0).tolist()]
    got_xyz = np.concatenate([p["xyz"] for p in parts])
    np.testing.assert_array_equal(np.concatenate([p["scan_angle"] for p in parts])[mm(got_xyz)], want)
    # formats that agree: each file's own name, in degrees
    assert np.asarray(gp.open(tmp_path / "a.las", tmp_path / "c.las").attributes["scan_angle_rank"]).dtype == np.int8


# autzen_trim's second LAZ chunk (points 50 000..99 999) holds bytes 285 651..548 073; 4 000 zeros at
# 300 000 decode without a word from lazrs, into points 52 450.. far outside the header's bounds
DAMAGE = (
    "corrupt LAZ point data: point 52,450 lies far outside the header's bounds (z -151.260, bounds 406.260..520.510); "
    "its LAZ chunk, points 50,000..99,999, is damaged: 50,000 of the 110,000 points read"
)


def damaged_autzen(autzen_path, folder):
    """autzen_trim with 4 000 bytes of its second LAZ chunk zeroed (laspy reads it whole: garbage from point 52 450)."""
    data = bytearray(autzen_path.read_bytes())
    data[300_000:304_000] = bytes(4000)
    path = folder / "damaged.laz"
    path.write_bytes(bytes(data))
    las = laspy.read(str(path))
    xyz, h = np.column_stack([las.x, las.y, las.z]), las.header
    outside = np.flatnonzero(np.any((xyz < h.mins) | (xyz > h.maxs), axis=1))
    assert len(xyz) == 110_000 and outside[0] == 52_450 and len(outside) > 40_000
    return path


@pytest.mark.parametrize("chunk_size", [30_000, 70_000, 2_000_000])
@pytest.mark.parametrize("decoding", ["child", "here", "kernel"])
def test_a_damaged_laz_gives_the_chunks_before_the_damage_then_names_it(tmp_path, autzen_path, monkeypatch, chunk_size, decoding):
    """LAZ's decoder does not notice damaged bytes: gp.open gave 110 000 points, 47 550 of them
    ±2e7 m away, without a word. The first point outside the header's bounds is named, with its
    LAZ chunk; the points of the chunks before it are given (exactly the file's), then the error:
    whatever the reads' size (30 000: the damaged chunk begins inside a read), decoded by a
    child, in this process or by the parallel kernel."""
    from gigapoint.io import las

    monkeypatch.setenv("GIGAPOINT_LAZ_PROCESS", "0" if decoding == "here" else "1")
    if decoding == "kernel":
        monkeypatch.setattr(las, "NUMPY_MAX", 0)
    path = damaged_autzen(autzen_path, tmp_path)
    got = []
    with pytest.raises(InputError) as err:
        got.extend(c.xyz for c in read_chunks(path, chunk_size))
    assert str(err.value) == f"{path}: {DAMAGE}"
    want = laspy.read(str(autzen_path))
    np.testing.assert_array_equal(np.concatenate(got), np.column_stack([want.x, want.y, want.z])[:50_000])


def test_a_damaged_laz_fails_open_and_a_progressive_load_keeps_what_precedes_it(tmp_path, autzen_path):
    """As a file cut off: gp.open refuses it in one line, a progressive load draws the chunks before the damage."""
    path = damaged_autzen(autzen_path, tmp_path)
    with pytest.raises(InputError) as err:
        gp.open(path)
    assert str(err.value) == f"{path}: {DAMAGE}"
    cloud = gp.open(path, progressive=True)
    with pytest.raises(InputError) as err:
        cloud.wait(timeout=60)
    assert str(err.value) == f"{path}: {DAMAGE}" and cloud.n_points == 50_000
    cloud.close()


def test_a_las_record_outside_the_header_bounds_is_named(tmp_path, las_writer):
    """A LAS record stands alone: the points before the damaged one are given, then it is named."""
    import struct

    path = las_writer(tmp_path / "a.las", 3000)
    data = bytearray(path.read_bytes())
    (start,), (size,) = struct.unpack_from("<I", data, 96), struct.unpack_from("<H", data, 105)
    struct.pack_into("<i", data, start + 1234 * size, -(2**31))  # point 1 234's X
    path.write_bytes(bytes(data))
    lo, hi = laspy.read(str(path)).header.mins[0], laspy.read(str(path)).header.maxs[0]
    with pytest.raises(InputError) as err:
        gp.open(path)
    assert str(err.value) == (
        f"{path}: corrupt LAS point data: point 1,234 lies far outside the header's bounds "
        f"(x -2,147,483.648, bounds {lo:,.3f}..{hi:,.3f}): 1,234 of the 3,000 points read"
    )
    cloud = gp.open(path, progressive=True)
    with pytest.raises(InputError, match="point 1,234 lies far outside"):
        cloud.wait(timeout=60)
    assert cloud.n_points == 1234
    cloud.close()


def test_header_bounds_a_hair_off_are_not_damage(tmp_path, autzen_path):
    """Headers round their bounds: autzen's rounded to whole metres (its points up to 0.24 m
    outside them, 24 scale steps) read whole, as do bounds of zeros (never filled in) and min > max;
    and stale ones (a writer that did not update them: other tools read such files), each end
    moved in by a quarter of the extent (the points up to 30 m outside in z, 300 in x)."""
    import struct

    data = bytearray(autzen_path.read_bytes())
    true = struct.unpack_from("<6d", data, 179)  # max x, min x, max y, ...
    stale = [v + (true[2 * a] - true[2 * a + 1]) / 4 * (1 if k else -1) for a in range(3) for k, v in enumerate(true[2 * a : 2 * a + 2])]
    for bounds in ([round(v) for v in true], [0.0] * 6, [1.0, 2.0] * 3, stale):
        struct.pack_into("<6d", data, 179, *bounds)  # max x, min x, max y, ...
        (tmp_path / "a.laz").write_bytes(bytes(data))
        assert sum(len(c) for c in read_chunks(tmp_path / "a.laz")) == 110_000


def test_a_damaged_points_chunk_is_found_in_chunks_of_any_size(autzen_path):
    """The chunk a damaged point spoils: the chunk table's (COPC's nodes are chunks of variable
    size), the LASzip VLR's fixed size without one, the record alone in a LAS file."""
    import dataclasses

    from gigapoint.io.las import _damaged_span, read_las_header

    hdr = read_las_header(autzen_path)
    assert hdr.laz_chunks == [50_000] * 3 and _damaged_span(hdr, 52_450) == (50_000, 100_000)
    odd = dataclasses.replace(hdr, laz_chunks=[10, 5, 20])
    assert [_damaged_span(odd, i) for i in (0, 9, 10, 14, 15, 34)] == [(0, 10), (0, 10), (10, 15), (10, 15), (15, 35), (15, 35)]
    assert _damaged_span(dataclasses.replace(hdr, laz_chunks=None), 100_001) == (100_000, 150_000)
    assert _damaged_span(dataclasses.replace(hdr, compressed=False), 7) == (7, 8)
