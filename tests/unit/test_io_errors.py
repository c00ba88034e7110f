"""Bad input, one case at a time: each raises the right InputError subclass, one line, path first, fast."""

from __future__ import annotations

import struct
import time
import warnings
import zipfile

import laspy
import numpy as np
import pytest
from test_io_las import write_las  # tests/unit is on sys.path (pytest rootdir-less import)

import gigapoint as gp
from gigapoint.errors import EmptyCloudError, GigapointError, GigapointWarning, InputError, UnsupportedFormatError
from gigapoint.io import file_info, open_cloud, read_chunks
from gigapoint.io.registry import reader_for


def patch(path, offset, fmt, value):
    with open(path, "r+b") as f:
        f.seek(offset)
        f.write(struct.pack("<" + fmt, value))


def raises(cls, path, fn=None, match=None):
    """Run the read (default: read every chunk) and check the error: class, one line, starts with the path."""
    fn = fn or (lambda p: [len(c) for c in read_chunks(p)])
    t0 = time.perf_counter()
    with pytest.raises(cls) as info:
        fn(path)
    elapsed = time.perf_counter() - t0
    msg = str(info.value)
    assert "\n" not in msg, msg
    assert msg.startswith(f"{path}: "), msg
    assert len(msg) < 400, msg
    if match:
        assert match in msg, msg
    assert elapsed < 5, f"took {elapsed:.1f} s"
    return msg


ALL_WAYS = [
    lambda p: list(read_chunks(p)),
    lambda p: open_cloud(p),
    lambda p: file_info(p),
]


# --- files that are not there or not files -------------------------------------------------------


@pytest.mark.parametrize("way", ALL_WAYS)
def test_missing_file(tmp_path, way):
    raises(InputError, tmp_path / "nope.laz", way, "no such file")


def test_missing_among_several(tmp_path):
    good = tmp_path / "a.las"
    write_las(good, n=10)
    raises(InputError, tmp_path / "b.las", lambda p: open_cloud(good, p), "no such file")


def test_directory_without_supported_files(tmp_path):
    (tmp_path / "readme.md").write_text("hello")
    raises(EmptyCloudError, tmp_path, open_cloud, "no supported point cloud file")


@pytest.mark.parametrize("way", [ALL_WAYS[0], ALL_WAYS[2]])
def test_directory_where_a_file_is_required(tmp_path, way):
    raises(InputError, tmp_path, way, "is a directory")


def test_unknown_format(tmp_path):
    p = tmp_path / "cloud.bin"
    p.write_bytes(bytes(range(256)) * 4)
    msg = raises(UnsupportedFormatError, p, match="unknown point cloud format")
    assert "LAS" in msg and "PLY" in msg  # tells what is supported
    raises(UnsupportedFormatError, p, file_info)
    q = tmp_path / "notes.dat"
    q.write_text("this is just prose\nnot points at all\n")
    raises(UnsupportedFormatError, q)


@pytest.mark.parametrize("suffix", [".las", ".laz", ".ply", ".xyz", ".csv", ".npy", ".npz", ".bin"])
def test_empty_file(tmp_path, suffix):
    p = tmp_path / f"empty{suffix}"
    p.write_bytes(b"")
    for way in ALL_WAYS:
        raises(EmptyCloudError, p, way, "empty")


# --- LAS / LAZ ------------------------------------------------------------------------------------


def test_wrong_signature_with_las_suffix(tmp_path):
    p = tmp_path / "fake.las"
    p.write_bytes(b"NOPE" + bytes(400))
    raises(InputError, p, match="not a LAS/LAZ file")


def test_truncated_header(tmp_path):
    p = tmp_path / "t.las"
    write_las(p, n=100)
    p.write_bytes(p.read_bytes()[:150])
    raises(InputError, p, match="truncated LAS header")


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_truncated_point_data(tmp_path, suffix):
    p = tmp_path / f"t{suffix}"
    write_las(p, n=120_000, point_format=3)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) * 2 // 3])
    for way in ALL_WAYS[:2]:
        raises(InputError, p, way, "truncated")


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_an_error_of_the_decoding_is_not_called_a_corrupt_file(tmp_path, suffix, monkeypatch):
    """Only laspy's and lazrs's failures mean the file is bad: a Dask worker's numba that could
    not compile the position kernel was reported as "truncated or corrupt LAS point data"."""
    from gigapoint.io import las

    p = tmp_path / f"fine{suffix}"
    write_las(p, n=1000)

    def broken(raw, scale, offset):
        raise RuntimeError("Cannot set NUMBA_NUM_THREADS to a different value once the threads have been launched")

    monkeypatch.setattr(las, "_positions", broken)
    with pytest.raises(RuntimeError, match="NUMBA_NUM_THREADS"):
        list(read_chunks(p))
    monkeypatch.undo()
    assert sum(len(c) for c in read_chunks(p)) == 1000


@pytest.mark.parametrize("suffix", [".las", ".laz"])
@pytest.mark.parametrize("version,fmt", [("1.2", 3), ("1.4", 6)])
@pytest.mark.parametrize("claimed", [10**12, 10**9, 1001])
def test_header_point_count_beyond_data(tmp_path, suffix, version, fmt, claimed):
    """A header claiming more points than present fails fast (10^12 on a tiny file included)."""
    p = tmp_path / f"c{suffix}"
    write_las(p, n=1000, point_format=fmt, version=version)
    if version == "1.4":
        patch(p, 247, "Q", claimed)
    else:  # LAS 1.0-1.3 counts are 32-bit
        claimed = min(claimed, 2**32 - 1)
        patch(p, 107, "I", claimed)
    assert p.stat().st_size < 100_000
    msg = raises(InputError, p)
    assert f"{claimed:,}" in msg
    raises(InputError, p, open_cloud)


def test_las_14_count_1e12_small_file(tmp_path):
    p = tmp_path / "huge.las"
    write_las(p, n=10, point_format=6, version="1.4")
    patch(p, 247, "Q", 10**12)
    patch(p, 107, "I", 0)
    p.write_bytes(p.read_bytes()[:1024])
    raises(InputError, p, match="1,000,000,000,000")


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_offset_to_point_data_past_end(tmp_path, suffix):
    p = tmp_path / f"o{suffix}"
    write_las(p, n=50)
    patch(p, 96, "I", 10**9)
    raises(InputError, p, match="offset to point data")
    raises(InputError, p, file_info, "offset to point data")


@pytest.mark.parametrize("field,offset,value", [
    ("x scale", 131, 1e300), ("y scale", 139, 0.0), ("z scale", 147, float("nan")),
    ("x offset", 155, float("inf")), ("y offset", 163, 1e200),
])
def test_absurd_scale_or_offset(tmp_path, field, offset, value):
    p = tmp_path / "s.las"
    write_las(p, n=50)
    patch(p, offset, "d", value)
    raises(InputError, p, match=f"absurd {field}")
    raises(InputError, p, file_info, f"absurd {field}")


def test_unsupported_version_and_point_format(tmp_path):
    p = tmp_path / "v.las"
    write_las(p, n=5)
    patch(p, 24, "B", 2)
    raises(InputError, p, match="unsupported LAS version 2.2")
    write_las(p, n=5)
    patch(p, 104, "B", 11)
    raises(InputError, p, match="point format 11")


def test_record_length_too_small(tmp_path):
    p = tmp_path / "r.las"
    write_las(p, n=5, point_format=3)
    patch(p, 105, "H", 20)
    raises(InputError, p, match="point record length 20")


def test_absurd_vlr_count(tmp_path):
    p = tmp_path / "v.las"
    write_las(p, n=5)
    patch(p, 100, "I", 4_000_000_000)
    raises(InputError, p, match="VLRs")


def test_evlr_longer_than_file(tmp_path):
    """An EVLR whose u64 length is absurd must not make laspy allocate it: its points, all
    before it, are read without it, with the one-line warning of an EVLR cut off."""
    header = laspy.LasHeader(point_format=6, version="1.4")
    las = laspy.LasData(header)
    las.x = las.y = las.z = np.arange(10.0)
    from laspy.vlrs.vlrlist import VLRList

    las.evlrs = VLRList([laspy.VLR(user_id="test", record_id=1, record_data=b"x" * 100)])
    p = tmp_path / "e.las"
    las.write(str(p))
    assert len(list(read_chunks(p))) == 1  # valid as written
    with open(p, "rb") as f:
        f.seek(235)
        start = struct.unpack("<Q", f.read(8))[0]
    patch(p, start + 20, "Q", 2**60)
    with pytest.warns(GigapointWarning, match=f"^{p}: truncated LAS file: its extended VLRs are cut .EVLR 1 of 1 .1,152,921,504,606,846,976 bytes. runs past"):
        assert sum(len(c) for c in read_chunks(p)) == 10
    patch(p, start + 20, "Q", 100)
    patch(p, 243, "I", 1_000_000)  # more EVLRs than fit
    with pytest.warns(GigapointWarning, match=r"EVLR 2 of 1,000,000 is cut off at byte [\d,]+: at least 60 bytes missing\); the points are whole$"):
        assert sum(len(c) for c in read_chunks(p)) == 10


def _las14_with_evlrs(tmp_path, suffix, n):
    """A LAS 1.4 file (point format 6) of ``n`` points with two 100-byte EVLRs after them: (path, xyz)."""
    from laspy.vlrs.vlrlist import VLRList

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales, header.offsets = [0.001] * 3, [0.0] * 3
    las = laspy.LasData(header)
    xyz = np.round(np.random.default_rng(5).uniform(0, 1000, (n, 3)), 3)
    las.x, las.y, las.z = xyz.T
    las.evlrs = VLRList([laspy.VLR(user_id="test", record_id=r, record_data=b"x" * 100) for r in (1, 2)])
    whole = tmp_path / f"whole{suffix}"
    las.write(str(whole))
    return whole, xyz


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_a_las_14_file_cut_before_its_evlrs_gives_the_points_before_the_cut(tmp_path, suffix):
    """A LAS 1.4 file with EVLRs after its points, cut off in its points: its EVLRs' check
    refused it up front, where a progressive load reads other cut files up to the cut. Now
    ``read_salvaged`` gives the points before the cut (LAZ: of its whole chunks, as
    test_io_laz_process's cut files), exactly the file's, then the one-line error. The plain
    reader still refuses it."""
    from gigapoint.io.las import LasReader, read_las_header

    n = 60_000
    whole, xyz = _las14_with_evlrs(tmp_path, suffix, n)
    data, hdr = whole.read_bytes(), read_las_header(whole)
    first, evlrs = hdr.offset_to_point_data, hdr.start_of_first_evlr
    mid, p = first + (evlrs - first) * 11 // 12, tmp_path / f"cut{suffix}"  # (LAZ: in its second chunk, of 10,000 points)
    problem = "truncated or corrupt LAZ file: chunk table offset" if suffix == ".laz" else "truncated LAS file: the header claims 60,000 points"
    p.write_bytes(data[:mid])
    raises(InputError, p, match=problem)
    got = []
    with pytest.raises(InputError, match=f"^{p}: {problem}"):
        for chunk in LasReader().read_salvaged(p, 20_000):
            got.append(chunk.xyz)
    got = np.concatenate(got)
    want = (mid - first) // 30 if suffix == ".las" else 50_000
    assert want - (5_000 if suffix == ".laz" else 0) <= len(got) <= want
    np.testing.assert_allclose(got, xyz[: len(got)], atol=1e-9)
    cloud = gp.open(p, progressive=True)
    with pytest.raises(GigapointError, match=f"{p}: {problem}"):
        cloud.wait(60)
    assert cloud.n_points == len(got)
    cloud.close()


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_a_las_14_file_cut_inside_its_evlrs_reads_every_point_with_a_warning(tmp_path, suffix):
    """A LAS 1.4 file cut before or inside its EVLRs (every point whole) was refused whole
    ("EVLR 1 of 2 ... runs past the end of the file"; cut just before them, drawn progressively
    with an error). Now every point is read, plain or progressive, with a one-line warning of
    what is missing; its EVLRs are left out (``gigapoint info`` warns too)."""
    from gigapoint.io.las import LasReader, read_las_header

    n = 3_000
    whole, xyz = _las14_with_evlrs(tmp_path, suffix, n)
    data, evlrs = whole.read_bytes(), read_las_header(whole).start_of_first_evlr
    p = tmp_path / f"cut{suffix}"
    said = "^{p}: truncated LAS file: its extended VLRs are cut \\({what}\\); the points are whole$"
    cuts = {
        evlrs: f"its 2 EVLRs, said to start at byte {evlrs:,}, lie past the end of the file \\({evlrs:,} bytes\\)",
        evlrs + 30: f"EVLR 1 of 2 is cut off at byte {evlrs + 30:,}: at least 30 bytes missing",
        evlrs + 60 + 40: f"EVLR 1 of 2 \\(100 bytes\\) runs past the end of the file \\({evlrs + 100:,} bytes\\): 60 bytes missing",
        evlrs + 160 + 59: f"EVLR 2 of 2 is cut off at byte {evlrs + 219:,}: at least 1 bytes missing",
        len(data) - 1: f"EVLR 2 of 2 \\(100 bytes\\) runs past the end of the file \\({len(data) - 1:,} bytes\\): 1 bytes missing",
    }
    for end, what in cuts.items():
        p.write_bytes(data[:end])
        match = said.format(p=p, what=what)
        with pytest.warns(GigapointWarning, match=match):
            got = np.concatenate([c.xyz for c in read_chunks(p, 1_000)])
        np.testing.assert_allclose(got, xyz, atol=1e-9)
        with pytest.warns(GigapointWarning, match=match):
            assert len(list(LasReader().read_salvaged(p, 1_000))) == 3
        with pytest.warns(GigapointWarning, match=match):
            assert gp.open(p).n_points == n
        with pytest.warns(GigapointWarning, match=match):
            assert file_info(p)["point_count"] == n
    cloud = gp.open(p, progressive=True)
    with pytest.warns(GigapointWarning, match=said.format(p=p, what=what)):
        _loaded(cloud)  # (said by wait, in this thread)
    assert cloud.n_points == n
    cloud.close()


def _loaded(cloud):
    assert cloud.wait(60)
    return cloud


def test_laz_chunk_table_absurd(tmp_path):
    p = tmp_path / "ct.laz"
    write_las(p, n=1000)
    data = p.read_bytes()
    start = struct.unpack_from("<I", data, 96)[0]
    table = struct.unpack_from("<q", data, start)[0]
    patch(p, table + 4, "I", 4_000_000_000)  # number of chunks
    raises(InputError, p, match="chunk table")
    patch(p, start, "q", 10**15)  # offset to the chunk table
    raises(InputError, p, match="chunk table offset")


def test_laz_corrupt_compressed_bytes(tmp_path):
    p = tmp_path / "g.laz"
    write_las(p, n=150_000)
    data = bytearray(p.read_bytes())
    third = len(data) // 3
    data[third : third + 5000] = np.random.default_rng(1).integers(0, 256, 5000, dtype=np.uint8).tobytes()
    p.write_bytes(bytes(data))
    try:
        n = sum(len(c) for c in read_chunks(p, chunk_size=50_000))
    except InputError as exc:  # what lazrs reports on this damage
        msg = str(exc)
        assert msg.startswith(f"{p}: ") and "\n" not in msg
    else:  # arithmetic decoding may also yield garbage points: never more or fewer than the header says
        assert n == 150_000


def test_zero_point_las(tmp_path):
    header = laspy.LasHeader(point_format=3, version="1.2")
    las = laspy.LasData(header)
    for suffix in (".las", ".laz"):
        p = tmp_path / f"zero{suffix}"
        las.write(str(p))
        for way in ALL_WAYS[:2]:
            raises(EmptyCloudError, p, way, "no points")
        assert file_info(p)["point_count"] == 0


def test_all_points_invalid(tmp_path):
    p = tmp_path / "nan.xyz"
    p.write_text("nan 1 2\ninf 3 4\n")
    assert sum(len(c) for c in read_chunks(p)) == 2  # NaN/inf are read ...
    raises(EmptyCloudError, p, open_cloud, "no valid points")  # ... and left out by build_cloud


def test_nan_points_skipped_with_warning(tmp_path):
    from gigapoint.errors import GigapointWarning

    p = tmp_path / "some_nan.xyz"
    p.write_text("nan 1 2\n1 2 3\n4 5 6\n")
    with pytest.warns(GigapointWarning, match="skipped 1"):
        cloud = open_cloud(p)
    assert cloud.n_points == 2 and cloud.skipped == 1


# --- PLY ------------------------------------------------------------------------------------------

PLY_ASCII = "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"


def test_ply_non_numeric(tmp_path):
    p = tmp_path / "bad.ply"
    p.write_text(PLY_ASCII.format(n=3) + "1 2 3\n4 five 6\n7 8 9\n")
    raises(InputError, p, match="line 9: 'five' is not a number")


def test_ply_wrong_column_count(tmp_path):
    p = tmp_path / "bad.ply"
    p.write_text(PLY_ASCII.format(n=3) + "1 2 3\n4 5\n7 8 9\n")
    raises(InputError, p, match="line 9 has 2 values")


def test_ply_ascii_fewer_lines_than_declared(tmp_path):
    p = tmp_path / "short.ply"
    p.write_text(PLY_ASCII.format(n=5) + "1 2 3\n4 5 6\n")
    raises(InputError, p, match="truncated PLY")


def test_ply_binary_truncated_and_huge_count(tmp_path):
    from plyfile import PlyData, PlyElement

    v = np.zeros(1000, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    p = tmp_path / "b.ply"
    PlyData([PlyElement.describe(v, "vertex")]).write(str(p))
    data = p.read_bytes()
    p.write_bytes(data[:-100])
    raises(InputError, p, match="truncated PLY")
    p.write_bytes(data.replace(b"element vertex 1000", b"element vertex 999999999999"))
    raises(InputError, p, match="truncated PLY")
    # opening it whole was refused for the memory 10^12 points would take ("open it with
    # progressive=True"), which then found it truncated: the header's count is checked first
    raises(InputError, p, fn=open_cloud, match="truncated PLY file: the header declares 999,999,999,999 vertices")


def test_ply_with_a_vertex_list_cut_off_is_truncated(tmp_path):
    """A PLY file whose vertices hold a list (read by plyfile) cut off, or whose header claims
    more vertices than it holds, said "corrupt PLY data: element 'vertex': row 27: property 'x':
    early end-of-file"; the other PLY paths say "truncated PLY file"."""
    from plyfile import PlyData, PlyElement

    v = np.zeros(30, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("tags", "O")])
    for i in range(30):
        v["tags"][i] = np.arange(i % 3, dtype=np.int32)
    p = tmp_path / "l.ply"
    PlyData([PlyElement.describe(v, "vertex")]).write(str(p))
    data = p.read_bytes()
    p.write_bytes(data[:-50])  # rows are 13 + 4 x (i % 3) bytes: 15 1/3 on average
    raises(InputError, p, match="truncated PLY file: 27 of 30 vertices present")
    p.write_bytes(data.replace(b"element vertex 30", b"element vertex 40"))
    raises(InputError, p, fn=open_cloud, match="truncated PLY file: 30 of 40 vertices present")


@pytest.mark.parametrize("byte_order", ["<", ">"])
def test_a_binary_mesh_ply_that_overstates_its_vertex_count_is_refused(tmp_path, byte_order):
    """A mesh (vertices, then faces) whose header declares more vertices than it holds read the
    faces' bytes as vertices (nonsense points, no error) while the faces had room for them; a correct
    mesh, triangles and quads mixed, reads its vertices only."""
    from plyfile import PlyData, PlyElement

    rng = np.random.default_rng(1)
    v = np.zeros(300, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    v["x"] = np.arange(300)
    faces = np.empty(40, dtype=[("vertex_indices", "O"), ("flags", "u1")])
    for i in range(40):
        faces[i] = (rng.integers(0, 300, 3 + i % 2).astype(np.int32), 7)
    p = tmp_path / "mesh.ply"
    PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(faces, "face")], byte_order=byte_order).write(str(p))
    assert open_cloud(p).n_points == 300 and file_info(p)["bounds"]["max"][0] == 299
    data = p.read_bytes()
    faces_bytes = len(data) - data.index(b"end_header\n") - len(b"end_header\n") - 300 * 12
    for declared in (301, 302, 307, 313):
        p.write_bytes(data.replace(b"element vertex 300", b"element vertex %d" % declared))
        raises(InputError, p, match=f"corrupt PLY file: the elements after its {declared} vertices (40 'face') do not fit the "
                                    f"{faces_bytes - 12 * (declared - 300)} bytes after them")
        raises(InputError, p, fn=file_info, match="the header's vertex count is not the number of vertices the file holds")
    p.write_bytes(data[:-30])  # the faces cut off
    raises(InputError, p, match="or the file is cut off")


def test_ply_ascii_count_beyond_its_bytes(tmp_path):
    """An ASCII header's count that the file's bytes cannot hold (6 bytes a vertex at least) is
    refused before the points are read; a file whose last line ends without a newline is not."""
    p = tmp_path / "a.ply"
    head = "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    p.write_text(head.format(999_999_999_999) + "0 0 0\n1 1 1\n")
    raises(InputError, p, fn=open_cloud, match="truncated PLY file: the header declares 999,999,999,999 vertices but only 12 bytes follow (room for 2 at most)")
    p.write_text(head.format(2) + "0 0 0\n1 1 1")
    assert len(open_cloud(p)) == 2


def test_ply_bad_header(tmp_path):
    p = tmp_path / "h.ply"
    p.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n")
    raises(InputError, p, match="end_header")
    p.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty floot x\nend_header\n")
    raises(InputError, p, match="corrupt PLY header")
    p.write_bytes(b"ply\nformat ascii 1.0\nelement face 1\nproperty float x\nend_header\n1\n")
    raises(InputError, p, match="no 'vertex' element")
    p.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float a\nend_header\n1\n")
    raises(InputError, p, match="no x, y, z")
    for element in (b"vertex -5", b"face -1\nproperty float q\nelement vertex 1"):  # numpy's "negative dimensions are not allowed"
        p.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement " + element + b"\nproperty float x\nproperty float y\nproperty float z\nend_header\n")
        raises(InputError, p, match="corrupt PLY header: element '" + element.split()[0].decode() + "' has a negative count (-")
        raises(InputError, p, fn=lambda q: reader_for(q).point_count(q), match="negative count")


def test_ply_zero_vertices(tmp_path):
    p = tmp_path / "z.ply"
    p.write_text(PLY_ASCII.format(n=0))
    raises(EmptyCloudError, p, match="no points")


# --- text -----------------------------------------------------------------------------------------


def test_csv_non_numeric(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("x,y,z\n1,2,3\n4,abc,6\n")
    raises(InputError, p, match="line 3: 'abc' is not a number")


def test_a_named_text_column_of_hex_colours_is_left_out_not_taken_for_a_comment(tmp_path):
    """'1,2,3,#ff0000' under 'x,y,z,color': the first line's '#' was taken for a comment (the
    comment-ending fix of this session), and the file refused: "line 2 has 3 columns, the header names 4"."""
    from gigapoint.errors import GigapointWarning

    for name, text in (("hex.csv", "x,y,z,color\n1,2,3,#ff0000\n4,5,6,#00ff00\n"), ("hex.txt", "x y z color\n1 2 3 #ff0000\n4 5 6 #00ff00\n")):
        p = tmp_path / name  # (spaces: "line 2 has 3 columns, expected 4", the lines' columns counted without the '#')
        p.write_text(text)
        with pytest.warns(GigapointWarning, match=rf"{name}: column\(s\) color hold text, not numbers: left out"):
            cloud = open_cloud(p)
        assert cloud.n_points == 2 and list(cloud.attributes) == []
        np.testing.assert_allclose(np.sort(cloud.positions()[:, 0]), [1, 4])


@pytest.mark.parametrize(
    ("name", "text", "attributes"),
    [
        ("spaces.xyz", "x y z intensity # exported by hand\n1 2 3 10\n4 5 6 20\n", {"intensity": [10, 20]}),  # "the header names 7"
        ("commas.csv", "x,y,z # site A\n1,2,3\n4,5,6\n", {}),  # "line 1: not numeric point data" (no header: 'z # site A')
        ("cc.txt", "//X,Y,Z,Intensity // CloudCompare\n1,2,3,10\n4,5,6,20\n", {"intensity": [10, 20]}),  # attribute 'intensity __ cloudcompare'
        # a mark inside a name is the name's, not a comment: "the header names 3" / "names 4"
        ("returns.csv", "x,y,z,#returns,intensity\n1,2,3,1,10\n4,5,6,2,20\n", {"#returns": [1, 2], "intensity": [10, 20]}),
        ("scan.xyz", "X Y Z Scan# Intensity # note\n1 2 3 7 10\n4 5 6 8 20\n", {"Scan#": [7, 8], "intensity": [10, 20]}),
    ],
    ids=["spaces", "commas", "cloudcompare", "hash-in-a-name", "hash-ending-a-name"],
)
def test_a_comment_ending_the_header_line_names_no_column(tmp_path, name, text, attributes):
    """A comment ending the header line ("x y z intensity # note") was split into column names,
    as one ending a line of points no longer is: dropped the same way."""
    p = tmp_path / name
    p.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (nothing left out, nothing said)
        cloud = open_cloud(p)
    order = np.argsort(cloud.positions()[:, 0])
    np.testing.assert_allclose(cloud.positions()[order], [[1, 2, 3], [4, 5, 6]], atol=1e-6)
    assert {a: cloud.attributes[a][order].tolist() for a in cloud.attributes} == attributes
    assert file_info(p)["attributes"] == list(attributes)


def test_a_hex_colour_column_under_a_header_ending_in_a_comment_is_named_as_the_header_names_it(tmp_path):
    """The text column left out was said as "color # hex" (the header's comment made part of its name)."""
    p = tmp_path / "hex.csv"
    p.write_text("x,y,z,color # hex\n1,2,3,#ff0000\n4,5,6,#00ff00\n")
    with pytest.warns(GigapointWarning) as said:
        cloud = open_cloud(p)
    assert [str(w.message) for w in said] == [f"{p}: column(s) color hold text, not numbers: left out"]
    assert cloud.n_points == 2 and list(cloud.attributes) == []


def test_text_columns_of_several_csvs_are_said_once_a_file(tmp_path):
    """Each file's layout is read once an operation: the empty-file check among several read it
    before the points did, and each file's text column was said twice."""
    files = [tmp_path / "a.csv", tmp_path / "b.csv"]
    for p in files:
        p.write_text("x,y,z,name\n1,2,3,foo\n4,5,6,bar\n")
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        cloud = gp.open(files)
    assert [str(w.message) for w in said] == [f"{p}: column(s) name hold text, not numbers: left out" for p in files]
    assert cloud.n_points == 4


def test_a_named_text_column_is_left_out_with_a_warning(tmp_path):
    """A CSV with a column of labels ("x,y,z,intensity,label") was refused whole ("'a' is not a
    number"): the named text column is left out, said once; the numbers in other columns are
    still checked on every line, and every line still has every column."""
    from gigapoint.errors import GigapointWarning

    p = tmp_path / "labels.csv"
    p.write_text("x,y,z,label,intensity\n1,2,3,tree,10\n4,5,6,roof,20\n")
    with pytest.warns(GigapointWarning, match=r"labels.csv: column\(s\) label hold text, not numbers: left out"):
        cloud = open_cloud(p)
    assert cloud.n_points == 2 and list(cloud.attributes) == ["intensity"]
    assert sorted(cloud.attributes["intensity"][:].tolist()) == [10, 20]
    for body, problem in (("7,8,9,car,x\n", "line 4: 'x' is not a number"), ("7,8,9\n", "line 4 has 3 columns, expected 5")):
        p.write_text("x,y,z,label,intensity\n1,2,3,tree,10\n4,5,6,roof,20\n" + body)
        with pytest.warns(GigapointWarning):
            raises(InputError, p, match=problem)
    p.write_text("x,y,z\nq,2,3\n")  # x, y and z are never left out
    raises(InputError, p, match="line 2: 'q' is not a number")
    for text in ('x,y,z,"name"\n"1","2","3","tree"\n"4","5","6","roof"\n', '"1","2","3"\n"4","5","6"\n'):  # a spreadsheet's quotes
        p.write_text(text)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", GigapointWarning)
            np.testing.assert_array_equal(open_cloud(p).bounds[1], [4, 5, 6])


def test_text_problems_on_lines_that_end_with_a_comment(tmp_path):
    """A line's trailing comment is no column: a named text column after one (whitespace between
    the columns) was "line 2 has 6 columns, expected 4", a bad number "has 5 columns"."""
    from gigapoint.errors import GigapointWarning

    p = tmp_path / "labels.xyz"
    p.write_text("x y z label\n1 2 3 tree # a note\n4 5 6 roof\n")
    with pytest.warns(GigapointWarning, match="label hold text"):
        cloud = open_cloud(p)
    np.testing.assert_array_equal(cloud.bounds, [[1, 2, 3], [4, 5, 6]])
    p.write_text("1 2 3 # a note\n4 5 x # another\n")
    raises(InputError, p, match="line 2: 'x' is not a number")
    p.write_text("1 2 3 # a note\n4 5 // another\n")
    raises(InputError, p, match="line 2 has 2 columns, expected 3")


def test_csv_wrong_column_count(tmp_path):
    p = tmp_path / "bad.xyz"
    p.write_text("1 2 3\n" * 5 + "1 2\n")
    raises(InputError, p, match="line 6 has 2 columns, expected 3")


def test_text_error_line_number_in_a_later_chunk(tmp_path):
    p = tmp_path / "late.xyz"
    p.write_text("1 2 3\n" * 250 + "1 2 x\n")
    raises(InputError, p, lambda q: list(read_chunks(q, chunk_size=100)), "line 251")


def test_text_too_few_columns(tmp_path):
    p = tmp_path / "two.xyz"
    p.write_text("1 2\n3 4\n")
    raises(InputError, p, match="expected at least 3")


def test_text_binary_content(tmp_path):
    p = tmp_path / "bin.xyz"
    p.write_bytes(b"\xff\xfe\x00\x01" * 100)
    raises(InputError, p, match="not UTF-8")


@pytest.mark.parametrize("text", ["x y z\n", "# only a comment\n", "\n\n"])
def test_text_without_points(tmp_path, text):
    p = tmp_path / "none.xyz"
    p.write_text(text)
    raises(EmptyCloudError, p, match="no points")


# --- NPY / NPZ ------------------------------------------------------------------------------------


def test_npy_truncated(tmp_path):
    p = tmp_path / "t.npy"
    np.save(p, np.zeros((1000, 3)))
    p.write_bytes(p.read_bytes()[:-200])
    raises(InputError, p, match="truncated NPY")


def test_npy_bad_shape_and_dtype(tmp_path):
    p = tmp_path / "s.npy"
    np.save(p, np.zeros((10, 5)))
    raises(InputError, p, match="(N, 3)")
    np.save(p, np.zeros(30))
    raises(InputError, p, match="(N, 3)")
    np.save(p, np.array([{"a": 1}] * 3, dtype=object), allow_pickle=True)
    raises(InputError, p, match="Python objects")
    np.save(p, np.zeros(4, dtype=[("a", "f8"), ("b", "f8")]))
    raises(InputError, p, match="without x, y, z")


def test_npy_and_npz_garbled_headers(tmp_path):
    """A garbled NPY header was numpy's tokenize.TokenError (a traceback naming no file), in an
    NPY file and an NPZ member alike, from reading its points, counting them, opening it
    progressively or asking for its info."""
    import gigapoint as gp

    p = tmp_path / "g.npy"
    np.save(p, np.zeros((100, 3)))
    data = p.read_bytes()
    p.write_bytes(data[:10] + b"garbage" + data[17:])
    raises(InputError, p, match="not an NPY header")
    raises(InputError, p, fn=file_info, match="not an NPY header")
    raises(InputError, p, fn=lambda q: gp.open(q, progressive=True).wait(), match="not an NPY header")
    q = tmp_path / "g.npz"
    with zipfile.ZipFile(q, "w") as zf:
        zf.writestr("xyz.npy", p.read_bytes())
    raises(InputError, q, match="not an NPY header")


def test_npy_zero_rows(tmp_path):
    p = tmp_path / "z.npy"
    np.save(p, np.zeros((0, 3)))
    raises(EmptyCloudError, p, match="no points")


def test_npz_problems(tmp_path):
    p = tmp_path / "k.npz"
    np.savez(p, foo=np.zeros((5, 3)), bar=np.zeros(5))
    raises(InputError, p, match="no point positions")
    np.savez(p, xyz=np.zeros((0, 3)))
    raises(EmptyCloudError, p, match="no points")
    np.savez_compressed(p, xyz=np.random.default_rng(0).random((5000, 3)))
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    raises(InputError, p, match="NPZ")
    q = tmp_path / "lies.npz"
    with zipfile.ZipFile(q, "w") as zf:  # header claims 10^12 rows
        zf.writestr("xyz.npy", b"\x93NUMPY\x01\x00v\x00{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000, 3), }".ljust(128, b" ")[:127] + b"\n" + bytes(48))
    raises(InputError, q, match="1000000000000")
    np.savez(p, xyz=np.zeros((50, 3)))  # a damaged member header (its magic, its name): zipfile's BadZipFile, a traceback
    data = p.read_bytes()
    for damaged in (b"PKxx" + data[4:], data[:30] + b"q" + data[31:]):
        p.write_bytes(damaged)
        raises(InputError, p, match="corrupt NPZ (zip) member 'xyz'")
        raises(InputError, p, fn=file_info, match="corrupt NPZ (zip) member 'xyz'")


@pytest.mark.parametrize("way", ALL_WAYS)
def test_npz_members_that_disagree_with_the_positions(tmp_path, way):
    """x, y, z of different lengths were an internal KeyError; colours of another row count (or
    not (N, 3)/(N, 4)) were dropped without a word, the cloud drawn grey."""
    p = tmp_path / "m.npz"
    x = np.arange(20.0)
    np.savez(p, x=x, y=x[:10], z=x)
    raises(InputError, p, way, "NPZ member 'y' has 10 rows, 'x' has 20")
    np.savez(p, x=x, y=x, z=np.zeros((20, 2)))
    raises(InputError, p, way, "NPZ member 'z' must be a numeric (N,) array")
    np.savez(p, xyz=np.zeros((20, 3)), rgb=np.zeros((5, 3), np.uint8))
    raises(InputError, p, way, "NPZ member 'rgb' has 5 rows, 'xyz' has 20")
    np.savez(p, x=x, y=x, z=x, colors=np.zeros((20, 2), np.uint8))
    raises(InputError, p, way, "NPZ member 'colors' must be an (N, 3) or (N, 4) colour array")
    np.savez(p, xyz=np.zeros((20, 3)), rgb=np.zeros((20, 3), np.uint8), other=np.zeros(7))  # other arrays: not per point, left out
    assert sum(len(c) for c in read_chunks(p)) == 20
    np.savez(p, xyz=np.zeros((20, 3)), color=np.arange(20))  # one value a point: an attribute, as before
    assert [sorted(c.attributes) for c in read_chunks(p)] == [["color"]]


def test_bad_chunk_size(tmp_path):
    p = tmp_path / "a.xyz"
    p.write_text("1 2 3\n")
    with pytest.raises(InputError, match="chunk_size"):
        list(read_chunks(p, chunk_size=0))


def test_a_ply_file_cut_off_gives_the_vertices_before_the_cut(tmp_path):
    """``read_salvaged`` (a progressive load's) of a binary PLY file cut off: the vertices before
    the cut, exactly the file's, then the one-line error; the plain reader still refuses it."""
    from plyfile import PlyData, PlyElement

    from gigapoint.io.ply import PlyReader

    v = np.zeros(1000, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    v["x"], v["y"], v["z"] = np.arange(1000), np.arange(1000) * 2, 7
    p = tmp_path / "b.ply"
    PlyData([PlyElement.describe(v, "vertex")]).write(str(p))
    data = p.read_bytes()
    p.write_bytes(data[: len(data) - 12 * 400 - 5])  # 599 vertices and 7 bytes of the 600th
    raises(InputError, p, match="truncated PLY")
    assert PlyReader().header(p, salvage=True)["truncated"].startswith("truncated PLY file: the header declares 1,000 vertices")
    got = []
    with pytest.raises(InputError, match=r"b\.ply: truncated PLY file: the header declares 1,000 vertices"):
        for chunk in PlyReader().read_salvaged(p, 250):
            got.append(chunk.xyz)
    xyz = np.concatenate(got)
    assert len(xyz) == 599
    np.testing.assert_array_equal(xyz, np.c_[v["x"], v["y"], v["z"]][: len(xyz)])
    cloud = gp.open(p, progressive=True)
    with pytest.raises(GigapointError, match=r"b\.ply: truncated PLY file"):
        cloud.wait(60)
    assert cloud.n_points == len(xyz)
    cloud.close()


@pytest.mark.parametrize("drop", [2, 15])
def test_an_ascii_ply_file_cut_mid_line_gives_every_whole_line_before_the_cut(tmp_path, drop):
    """An ASCII PLY file cut part-way through a vertex line (a download cut off): every whole line
    before it, then the one-line truncation error. The cut line's chunk was lost to "line 608 has
    1 values" (``drop`` 15: "600.2" of "600.25 1200.5 7.125"), or the line read as a vertex of
    z 7.12 (``drop`` 2: three values, the last cut short)."""
    from gigapoint.io.ply import PlyReader

    n = 1000
    xyz = np.c_[np.arange(n) + 0.25, np.arange(n) * 2 + 0.5, np.full(n, 7.125)]
    lines = [f"{x} {y} {z}\n" for x, y, z in xyz]
    text = PLY_ASCII.format(n=n) + "".join(lines[:600])
    p = tmp_path / "a.ply"
    p.write_text(text + lines[600][: len(lines[600]) - drop])
    got = []
    with pytest.raises(InputError, match=r"^\S*a\.ply: truncated PLY file: the header declares 1,000 vertices, only 600 lines of them are present \(the file ends part-way through the next\)$"):
        for chunk in PlyReader().read_salvaged(p, 250):
            got.append(chunk.xyz)
    np.testing.assert_array_equal(np.concatenate(got), xyz[:600])
    cloud = gp.open(p, progressive=True)
    with pytest.raises(GigapointError, match=r"a\.ply: truncated PLY file"):
        cloud.wait(60)
    assert cloud.n_points == 600
    cloud.close()


def test_an_attribute_of_other_shapes_in_two_files_is_one_line(tmp_path):
    """Two NPZ files whose ``normal`` is one value a point in one and three in the other: numpy's
    "all the input arrays must have same number of dimensions" when the cloud joined them."""
    n = 10
    np.savez(tmp_path / "a.npz", x=np.arange(n, dtype=float), y=np.zeros(n), z=np.zeros(n), normal=np.zeros(n))
    np.savez(tmp_path / "b.npz", x=np.arange(n, dtype=float), y=np.ones(n), z=np.zeros(n), normal=np.zeros((n, 3)))
    with pytest.raises(InputError, match=r"^2 files: attribute 'normal' holds 1 value a point in one file and 3 values in another$"):
        gp.open([tmp_path / "a.npz", tmp_path / "b.npz"])


@pytest.mark.parametrize(("value", "shown"), [("nan", "nan"), ("300", "300"), ("-1", "-1"), ("1.5", "1.5")])
def test_ply_ascii_integer_property_that_its_type_cannot_hold(tmp_path, value, shown):
    """A value an ASCII PLY's integer property cannot hold was cast as numpy casts: 300 wrapped
    to 44 in a uchar, a NaN became any number (numpy's warning, on a progressive load's thread).
    Now the line, the property and its declared type, as plyfile refuses such a file; x, y, z
    stay as parsed whatever their declared type."""
    p = tmp_path / "cast.ply"
    head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty int x\nproperty float y\nproperty float z\nproperty uchar intensity\nend_header\n"
    p.write_text(head + f"0 0 0 1\n1.5 1 1 {value}\n2 2 2 3\n")
    raises(InputError, p, fn=open_cloud, match=f"line 10: intensity is {shown}, not a uchar as the header declares")
    p.write_text(head + "0 0 0 1\n1.5 1 1 255\n2 2 2 0\n")
    cloud = open_cloud(p)
    assert sorted(cloud.attributes["intensity"].tolist()) == [0, 1, 255] and sorted(cloud.positions()[:, 0].round(6).tolist()) == [0, 1.5, 2]


@pytest.mark.parametrize("way", ALL_WAYS)
def test_bool_positions_in_npy_or_npz_are_refused_as_from_arrays_refuses_them(tmp_path, way):
    """Bool arrays were read as positions of 0 and 1 ("biuf" took them); gp.from_arrays refuses
    them ("xyz must hold numbers"), and so do the readers now."""
    flags = np.random.default_rng(0).random((20, 3)) > 0.5
    said = "xyz must hold numbers (integers or floats), got dtype bool"
    p = tmp_path / "b.npy"
    np.save(p, flags)
    assert raises(InputError, p, way) == f"{p}: NPY array: {said}"
    np.save(p, np.zeros((20, 6), bool))
    raises(InputError, p, way, said)
    table = np.zeros(20, [("x", "?"), ("y", "f4"), ("z", "f4")])
    np.save(p, table)
    raises(InputError, p, way, f"NPY array field 'x': {said}")
    q = tmp_path / "b.npz"
    np.savez(q, xyz=flags, rgb=np.zeros((20, 3), np.uint8))
    raises(InputError, q, way, f"NPZ member 'xyz': {said}")
    np.savez(q, x=flags[:, 0], y=np.zeros(20), z=np.zeros(20))
    raises(InputError, q, way, f"NPZ member 'x': {said}")
    with pytest.raises(InputError) as err:
        gp.from_arrays(flags)
    assert str(err.value) == f"arrays: {said}"


@pytest.mark.parametrize("way", ALL_WAYS)
def test_text_positions_in_npy_or_npz_are_said_in_one_wording(tmp_path, way):
    """Positions that are not numbers were said three ways ("expected a numeric array", "must be a
    numeric (N, 3) array, got shape ... dtype"): now as gp.from_arrays says them."""
    words = np.array([["1", "2", "3"]] * 20)
    said = "xyz must hold numbers (integers or floats), got dtype <U1"
    p = tmp_path / "w.npy"
    np.save(p, words)
    assert raises(InputError, p, way) == f"{p}: NPY array: {said}"
    q = tmp_path / "w.npz"
    np.savez(q, xyz=words, rgb=np.zeros((20, 3), np.uint8))
    assert raises(InputError, q, way) == f"{q}: NPZ member 'xyz': {said}"
    np.savez(q, x=words[:, 0], y=np.zeros(20), z=np.zeros(20))
    assert raises(InputError, q, way) == f"{q}: NPZ member 'x': {said}"
