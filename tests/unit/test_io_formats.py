"""PLY, XYZ/TXT/CSV/PTS, NPY and NPZ round trips; registry choice by content and suffix; open_cloud."""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from gigapoint.core.chunk import DEFAULT_COLOR
from gigapoint.errors import InputError
from gigapoint.io import file_info, format_info, open_cloud, read_chunks, reader_for

RNG = np.random.default_rng(3)
N = 1234


def ref_points(n=N, seed=0):
    rng = np.random.default_rng(seed)
    xyz = np.column_stack([rng.uniform(-50, 50, n), rng.uniform(0, 10, n), rng.uniform(100, 101, n)])
    rgb = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    return xyz, rgb


def collect(path, chunk_size=10_000_000):
    chunks = list(read_chunks(path, chunk_size=chunk_size))
    xyz = np.concatenate([c.xyz for c in chunks])
    rgba = np.concatenate([c.rgba for c in chunks])
    attrs = {k: np.concatenate([c.attributes[k] for c in chunks]) for k in chunks[0].attributes}
    return chunks, xyz, rgba, attrs


def check_chunking(path, n):
    """Reading in small chunks yields the same points as one read, in bounded chunks."""
    _, xyz1, rgba1, attrs1 = collect(path)
    chunks, xyz2, rgba2, attrs2 = collect(path, chunk_size=100)
    assert all(len(c) <= 100 for c in chunks) and len(chunks) == -(-n // 100)
    np.testing.assert_array_equal(xyz1, xyz2)
    np.testing.assert_array_equal(rgba1, rgba2)
    for k in attrs1:
        np.testing.assert_array_equal(attrs1[k], attrs2[k])


# --- PLY ------------------------------------------------------------------------------------------


def ply_vertices(xyz, rgb=None, normals=False, intensity=False, xyz_type="f8", color_type="u1"):
    fields = [("x", xyz_type), ("y", xyz_type), ("z", xyz_type)]
    if normals:
        fields += [("nx", "f4"), ("ny", "f4"), ("nz", "f4")]
    if rgb is not None:
        fields += [("red", color_type), ("green", color_type), ("blue", color_type)]
    if intensity:
        fields += [("intensity", "u2")]
    v = np.zeros(len(xyz), dtype=fields)
    v["x"], v["y"], v["z"] = xyz.T
    if normals:
        nrm = np.tile(np.array([0, 0, 1], np.float32), (len(xyz), 1))
        v["nx"], v["ny"], v["nz"] = nrm.T
    if rgb is not None:
        v["red"], v["green"], v["blue"] = rgb.T
    if intensity:
        v["intensity"] = np.arange(len(xyz)) % 65535
    return v


@pytest.mark.parametrize("text,byte_order", [(True, "="), (False, "<"), (False, ">")])
def test_ply_round_trip(tmp_path, text, byte_order):
    xyz, rgb = ref_points()
    v = ply_vertices(xyz, rgb, normals=True, intensity=True)
    faces = np.array([([0, 1, 2],)], dtype=[("vertex_indices", "i4", (3,))])
    p = tmp_path / "v.ply"
    PlyData([PlyElement.describe(v, "vertex"), PlyElement.describe(faces, "face")], text=text, byte_order=byte_order).write(str(p))
    _, got, rgba, attrs = collect(p)
    np.testing.assert_allclose(got, xyz, rtol=1e-6 if text else 0)
    np.testing.assert_array_equal(rgba[:, :3], rgb)
    assert (rgba[:, 3] == 255).all()
    assert set(attrs) == {"nx", "ny", "nz", "intensity"}
    np.testing.assert_array_equal(attrs["nz"], 1)
    np.testing.assert_array_equal(attrs["intensity"], np.arange(N))
    assert attrs["nz"].dtype == v.dtype["nz"]  # as declared, text or binary (text gave float64)
    check_chunking(p, N)
    info = file_info(p)
    assert info["format"] == "PLY" and info["point_count"] == N and info["has_color"]
    np.testing.assert_allclose(info["bounds"]["min"], xyz.min(axis=0), rtol=1e-6)


def test_ply_without_color_float32_and_alpha(tmp_path):
    xyz, _ = ref_points(50)
    p = tmp_path / "plain.ply"
    PlyData([PlyElement.describe(ply_vertices(xyz, xyz_type="f4"), "vertex")]).write(str(p))
    _, got, rgba, attrs = collect(p)
    np.testing.assert_allclose(got, xyz.astype(np.float32))
    assert (rgba == np.array(DEFAULT_COLOR, np.uint8)).all()
    assert attrs == {}
    v = np.zeros(3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")])
    v["red"], v["alpha"] = 10, 128
    PlyData([PlyElement.describe(v, "vertex")]).write(str(p))
    _, _, rgba, _ = collect(p)
    np.testing.assert_array_equal(rgba[0], [10, 0, 0, 128])


def test_ply_16bit_and_float_colors(tmp_path):
    xyz, rgb = ref_points(20)
    p = tmp_path / "c16.ply"
    PlyData([PlyElement.describe(ply_vertices(xyz, rgb.astype(np.uint16) * 257, color_type="u2"), "vertex")]).write(str(p))
    np.testing.assert_array_equal(collect(p)[2][:, :3], rgb)
    PlyData([PlyElement.describe(ply_vertices(xyz, rgb / 255.0, color_type="f4"), "vertex")]).write(str(p))
    np.testing.assert_array_equal(collect(p)[2][:, :3], rgb)


@pytest.mark.parametrize("text,byte_order,kind", [(False, "<", "f4"), (False, ">", "f4"), (True, "=", "f4"), (False, "<", "u4")])
def test_ply_pcl_packed_rgb_is_the_colour(tmp_path, text, byte_order, kind):
    """PCL writes a PointXYZRGB's colour as one 4-byte 'rgb' (0x00RRGGBB: a float32's bits) or
    a uint 'rgba': they were an attribute of nonsense numbers, the points drawn grey."""
    xyz, rgb = ref_points(40)
    name = "rgb" if kind == "f4" else "rgba"
    v = np.zeros(40, [("x", "f4"), ("y", "f4"), ("z", "f4"), (name, kind)])
    v["x"], v["y"], v["z"] = xyz.T
    packed = (rgb[:, 0].astype(np.uint32) << 16) | (rgb[:, 1].astype(np.uint32) << 8) | rgb[:, 2] | (np.uint32(255) << 24 if kind == "u4" else 0)
    v[name] = packed.view(np.dtype(kind))
    p = tmp_path / "pcl.ply"
    PlyData([PlyElement.describe(v, "vertex")], text=text, byte_order=byte_order).write(str(p))
    _, _, rgba, attrs = collect(p)
    np.testing.assert_array_equal(rgba[:, :3], rgb)
    assert (rgba[:, 3] == 255).all() and attrs == {}
    info = file_info(p)
    assert info["has_color"] and info["attributes"] == []
    assert reader_for(p).header(p) == {"point_count": 40, "has_color": True, "attributes": [], "crs": None}


def test_ply_gaussian_splat_drawn_in_its_f_dc_colours(tmp_path):
    """A 3D Gaussian splat PLY (f_dc_0..2, opacity, scale_*, rot_*, f_rest_*) was drawn grey: its
    colour is 0.5 + 0.28209479 * f_dc, clamped to 0..1; every field stays an attribute."""
    fields = ["nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", *(f"f_rest_{i}" for i in range(45)), "opacity",
              "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]  # fmt: skip
    v = np.zeros(5, [("x", "f4"), ("y", "f4"), ("z", "f4"), *((f, "f4") for f in fields)])
    v["x"] = np.arange(5)
    v["f_dc_0"] = [-2, -1, 0, 1, 2]  # 0.5 + 0.282 * f_dc: -0.06 0.22 0.5 0.78 1.06
    v["f_dc_1"] = np.nan  # (a NaN: 0.5)
    v["f_dc_2"] = 1.7724539  # 1 / (2 * 0.28209479): exactly 1
    v["opacity"] = 3.5
    p = tmp_path / "splat.ply"
    PlyData([PlyElement.describe(v, "vertex")]).write(str(p))
    chunks, _, rgba, attrs = collect(p)
    np.testing.assert_array_equal(rgba, [[0, 128, 255, 255], [56, 128, 255, 255], [128, 128, 255, 255], [199, 128, 255, 255], [255, 128, 255, 255]])
    assert list(attrs) == fields and (attrs["opacity"] == 3.5).all() and attrs["f_dc_0"][0] == -2
    assert file_info(p)["has_color"] and file_info(p)["attributes"] == fields


@pytest.mark.parametrize("ending", [b"end_header \n", b"end_header\r\n", b"end_header\t\r\n"])
def test_ply_header_with_blanks_or_crlf_on_some_lines(tmp_path, ending):
    """plyfile takes the line end from a header's first line and no blank after a line's words:
    "end_header \n", or "end_header\r\n" after "ply\n", was "corrupt PLY header: line 8:
    early end-of-file", "ply \n" (a writer's first line) "unexpected characters after 'ply'"
    (binary, ASCII, and a vertex list read by plyfile)."""
    head = b"ply \nformat %s 1.0 \ncomment x \nelement vertex 2\nproperty float x\nproperty float y\nproperty float z \n%s" + ending
    p = tmp_path / "h.ply"
    xyz = np.array([[1, 2, 3], [4, 5, 6]], np.float32)
    p.write_bytes(head % (b"binary_little_endian", b"") + xyz.tobytes())
    np.testing.assert_array_equal(collect(p)[1], xyz)
    p.write_bytes(head % (b"ascii", b"") + b"1 2 3\n4 5 6\n")
    np.testing.assert_array_equal(collect(p)[1], xyz)
    p.write_bytes(head % (b"ascii", b"property list uchar float feat\n") + b"1 2 3 1 0.5\n4 5 6 0\n")
    np.testing.assert_array_equal(collect(p)[1], xyz)
    assert file_info(p)["point_count"] == 2


@pytest.mark.parametrize("line", [b"comment written before end_header\n", b"property float end_header\n"])
def test_ply_header_ends_at_its_end_header_line_not_the_first_end_header_word(tmp_path, line):
    """A comment or a property of that name held the word first: the header was cut there,
    "corrupt PLY header: line 5: early end-of-file" (a saved attribute 'end_header' among them)."""
    extra = b"property float end_header\n" in line
    p = tmp_path / "e.ply"
    rows = [(1, 2, 3, 7), (4, 5, 6, 8)] if extra else [(1, 2, 3), (4, 5, 6)]
    v = np.array(rows, [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("end_header", "<f4")][: len(rows[0])])
    props = b"property float x\nproperty float y\nproperty float z\n"
    head = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\n" + (props + line if extra else line + props) + b"end_header\n"
    p.write_bytes(head + v.tobytes())
    _, xyz, _, attrs = collect(p)
    np.testing.assert_array_equal(xyz, [[1, 2, 3], [4, 5, 6]])
    assert attrs.keys() == ({"end_header"} if extra else set())
    if extra:
        np.testing.assert_array_equal(attrs["end_header"], [7, 8])


def test_ply_list_property_in_vertex_falls_back_to_plyfile(tmp_path):
    xyz, _ = ref_points(30)
    v = np.zeros(30, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("tags", "O")])
    v["x"], v["y"], v["z"] = xyz.T.astype(np.float32)
    for i in range(30):
        v["tags"][i] = np.arange(i % 3, dtype=np.int32)
    p = tmp_path / "lists.ply"
    PlyData([PlyElement.describe(v, "vertex")]).write(str(p))
    _, got, _, attrs = collect(p)
    np.testing.assert_allclose(got, xyz.astype(np.float32))
    assert "tags" not in attrs


# --- text -----------------------------------------------------------------------------------------


def write_text(path, xyz, rgb=None, sep=" ", header=None, intensity=None, fmt="%.6f"):
    cols = [xyz]
    if intensity is not None:
        cols.append(intensity[:, None])
    if rgb is not None:
        cols.append(rgb)
    table = np.column_stack(cols)
    with open(path, "w") as f:
        if header:
            f.write(header + "\n")
        f.writelines(sep.join(fmt % v if i < 3 else f"{v:g}" for i, v in enumerate(row)) + "\n" for row in table)


@pytest.mark.parametrize("sep,suffix", [(" ", ".xyz"), ("\t", ".txt"), (",", ".csv"), (";", ".csv"), ("  ", ".asc")])
@pytest.mark.parametrize("header", [False, True])
def test_text_round_trip(tmp_path, sep, suffix, header):
    xyz, rgb = ref_points()
    p = tmp_path / f"pts{suffix}"
    write_text(p, xyz, rgb, sep=sep, header=sep.join(["X", "Y", "Z", "Red", "Green", "Blue"]) if header else None)
    _, got, rgba, attrs = collect(p)
    np.testing.assert_allclose(got, xyz, atol=5e-7)
    np.testing.assert_array_equal(rgba[:, :3], rgb)
    assert attrs == {}
    check_chunking(p, N)
    assert file_info(p)["point_count"] == N


def _reads_back_as_written(p, xyz, rgb) -> None:
    """The x y z r g b text file ``p`` (in a folder of its own) read as written: alone, by its
    info, and as the folder's one file of points."""
    _, got, rgba, attrs = collect(p)
    np.testing.assert_allclose(got, xyz, atol=5e-7)
    np.testing.assert_array_equal(rgba[:, :3], rgb)
    assert attrs == {}
    assert file_info(p)["columns"] == ["x", "y", "z", "r", "g", "b"]
    assert open_cloud(p.parent).n_points == len(xyz)


@pytest.mark.filterwarnings("error")  # (nor a word of a column of text)
@pytest.mark.parametrize("sep", [",", ";"])
@pytest.mark.parametrize("header", [False, True])
def test_text_lines_ending_with_a_separator_open_no_column(tmp_path, sep, header):
    """'1,2,3,255,0,0,' (exports that end every line with the separator) was "line 1: not numeric
    point data", with a header "column(s)  hold text, not numbers: left out", and a folder left the
    file out (not taken for points)."""
    xyz, rgb = ref_points(30)
    folder = tmp_path / "f"
    folder.mkdir()
    p = folder / "pts.csv"
    write_text(p, xyz, rgb, sep=sep, header=sep.join(["x", "y", "z", "r", "g", "b"]) if header else None)
    p.write_text("".join(line + sep + "\n" for line in p.read_text().splitlines()))
    _reads_back_as_written(p, xyz, rgb)


def test_text_layouts_by_column_count(tmp_path):
    xyz, rgb = ref_points(40)
    inten = np.arange(40.0)
    p = tmp_path / "a.pts"
    with open(p, "w") as f:  # PTS: count line, then x y z intensity r g b
        f.write("40\n")
    write_text(tmp_path / "body", xyz, rgb, intensity=inten)
    p.write_text(p.read_text() + (tmp_path / "body").read_text())
    _, got, rgba, attrs = collect(p)
    np.testing.assert_allclose(got, xyz, atol=5e-7)
    np.testing.assert_array_equal(rgba[:, :3], rgb)
    np.testing.assert_array_equal(attrs["intensity"], inten)
    q = tmp_path / "xyz_only.xyz"
    write_text(q, xyz)
    _, got, rgba, attrs = collect(q)
    assert (rgba == np.array(DEFAULT_COLOR, np.uint8)).all() and attrs == {}


def test_text_cloudcompare_header_comments_and_unit_colors(tmp_path):
    p = tmp_path / "cc.txt"
    p.write_text("//X,Y,Z,R,G,B,Nx,Ny,Nz\n# a comment\n1,2,3,1.0,0.5,0,0,0,1\n\n4,5,6,0,0,0.25,0,1,0\n")
    _, got, rgba, attrs = collect(p)
    np.testing.assert_array_equal(got, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(rgba[:, :3], [[255, 128, 0], [0, 0, 64]])
    np.testing.assert_array_equal(attrs["nz"], [1, 0])


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("sep", [" ", ",", ";", "\t"])
@pytest.mark.parametrize("mark", ["# note", "// note, with a comma"])
@pytest.mark.parametrize("header", [False, True])
def test_text_first_line_ending_with_a_comment(tmp_path, sep, mark, header):
    """'1 2 3 # note' on the first line of points was "line 1: not numeric point data" (after a
    header: "line 2 has 5 columns, the header names 3"), and a folder left the file out (a comment
    on every line: not taken for points); the same comment on a later line was read (loadtxt drops it)."""
    xyz, rgb = ref_points(30)
    folder = tmp_path / "f"
    folder.mkdir()
    p = folder / "pts.txt"
    write_text(p, xyz, rgb, sep=sep, header=sep.join(["x", "y", "z", "r", "g", "b"]) if header else None)
    lines = p.read_text().splitlines()
    p.write_text("".join(line + (f" {mark}" if i >= header else "") + "\n" for i, line in enumerate(lines)))
    _reads_back_as_written(p, xyz, rgb)


def test_text_content_sniffed_without_known_suffix(tmp_path):
    p = tmp_path / "points.dat"
    p.write_text("1 2 3\n4 5 6\n")
    assert reader_for(p).name == "XYZ/TXT/CSV"
    assert len(open_cloud(p)) == 2


# --- NPY / NPZ ------------------------------------------------------------------------------------


@pytest.mark.parametrize("layout", ["n3", "n4", "n6", "n7", "structured", "f32"])
def test_npy_layouts(tmp_path, layout):
    xyz, rgb = ref_points()
    if layout == "n3":
        arr = xyz
    elif layout == "n4":
        arr = np.column_stack([xyz, np.arange(N)])
    elif layout == "n6":
        arr = np.column_stack([xyz, rgb / 255.0])
    elif layout == "n7":
        arr = np.column_stack([xyz, rgb, np.full(N, 255)])
    elif layout == "f32":
        arr = xyz.astype(np.float32)
    else:
        arr = np.zeros(N, dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("intensity", "u2")])
        arr["x"], arr["y"], arr["z"] = xyz.T
        arr["red"], arr["green"], arr["blue"] = rgb.T
        arr["intensity"] = np.arange(N)
    p = tmp_path / "a.npy"
    np.save(p, arr)
    _, got, rgba, attrs = collect(p)
    np.testing.assert_allclose(got, xyz.astype(np.float32) if layout == "f32" else xyz, rtol=0)
    if layout in ("n6", "n7", "structured"):
        np.testing.assert_array_equal(rgba[:, :3], rgb)
    else:
        assert (rgba == np.array(DEFAULT_COLOR, np.uint8)).all()
    if layout in ("n4", "structured"):
        np.testing.assert_array_equal(attrs["intensity"], np.arange(N))
    check_chunking(p, N)
    assert file_info(p)["point_count"] == N


@pytest.mark.parametrize("name,kind", [("rgb", "<u4"), ("rgb", ">u4"), ("rgb", "<f4"), ("RGBA", "<u4")])
@pytest.mark.parametrize("container", ["npy", "npz"])
def test_npy_pcl_packed_rgb_is_the_colour(tmp_path, name, kind, container):
    """A structured array's packed 'rgb' (0xRRGGBB in a uint32, or a float32's bits, as PCL and
    Open3D exports write it; 'rgba' with its alpha in the top byte) stayed an attribute of
    nonsense numbers, the points drawn grey, where the PLY reader takes it for the colour."""
    xyz, rgb = ref_points(50)
    order = kind[0]
    arr = np.zeros(50, [("x", order + "f8"), ("y", order + "f8"), ("z", order + "f8"), (name, kind), ("intensity", order + "u2")])
    arr["x"], arr["y"], arr["z"] = xyz.T
    packed = (rgb[:, 0].astype(np.uint32) << 16) | (rgb[:, 1].astype(np.uint32) << 8) | rgb[:, 2] | (np.uint32(255) << 24 if name == "RGBA" else 0)
    arr[name] = packed.view(np.dtype(kind).newbyteorder("="))
    np.testing.assert_array_equal(arr[name].view(np.dtype("u4").newbyteorder(order)), packed)  # (written as meant)
    p = tmp_path / f"pcl.{container}"
    np.save(p, arr) if container == "npy" else np.savez(p, points=arr)
    _, got, rgba, attrs = collect(p)
    np.testing.assert_array_equal(got, xyz)
    np.testing.assert_array_equal(rgba[:, :3], rgb)
    assert (rgba[:, 3] == 255).all() and set(attrs) == {"intensity"}
    np.testing.assert_array_equal(attrs["intensity"], 0)
    check_chunking(p, 50)
    assert file_info(p)["has_color"]
    if container == "npy":
        assert file_info(p)["attributes"] == ["intensity"]
        assert reader_for(p).header(p) == {"point_count": 50, "has_color": True, "attributes": ["intensity"]}


@pytest.mark.parametrize("compressed", [False, True])
@pytest.mark.parametrize("keys", ["xyz_rgb", "positions_colors", "separate_xyz"])
def test_npz_round_trip(tmp_path, compressed, keys):
    xyz, rgb = ref_points()
    normals = np.tile([0.0, 0.0, 1.0], (N, 1))
    if keys == "xyz_rgb":
        arrays = {"xyz": xyz, "rgb": rgb, "intensity": np.arange(N, dtype=np.uint16), "normals": normals, "meta": np.arange(3)}
    elif keys == "positions_colors":
        arrays = {"positions": xyz, "colors": rgb.astype(np.uint16) * 257, "intensity": np.arange(N, dtype=np.uint16), "normals": normals}
    else:
        arrays = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "rgb": rgb, "intensity": np.arange(N, dtype=np.uint16), "normals": normals}
    p = tmp_path / "a.npz"
    (np.savez_compressed if compressed else np.savez)(p, **arrays)
    _, got, rgba, attrs = collect(p)
    np.testing.assert_array_equal(got, xyz)
    np.testing.assert_array_equal(rgba[:, :3], rgb)
    assert set(attrs) == {"intensity", "normals"}  # "meta" has another length: not an attribute
    np.testing.assert_array_equal(attrs["intensity"], np.arange(N))
    np.testing.assert_array_equal(attrs["normals"], normals)
    check_chunking(p, N)


# --- registry, open_cloud, info ---------------------------------------------------------------------


def test_format_chosen_by_content_over_suffix(tmp_path):
    from test_io_las import write_las

    las = tmp_path / "really_las.xyz"
    write_las(las, n=10)
    assert reader_for(las).name == "LAS/LAZ"
    npy = tmp_path / "really_npy.dat"
    np.save(tmp_path / "tmp.npy", np.zeros((4, 3)))
    npy.write_bytes((tmp_path / "tmp.npy").read_bytes())
    assert reader_for(npy).name == "NPY"
    ply = tmp_path / "really_ply.bin"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n")
    assert reader_for(ply).name == "PLY"
    assert len(open_cloud(las)) == 10


def test_open_cloud_directory_merges_sorted_files(tmp_path):
    from test_io_las import write_las

    d = tmp_path / "tiles"
    d.mkdir()
    xyz, rgb = ref_points(100)
    write_text(d / "b.xyz", xyz[50:], rgb[50:])
    write_text(d / "a.xyz", xyz[:50], rgb[:50])
    (d / "notes.md").write_text("not a cloud")
    cloud = open_cloud(d)
    assert cloud.name == "2 files" and cloud.n_points == 100
    np.testing.assert_allclose(np.sort(cloud.positions()[:, 0]), np.sort(xyz[:, 0]), atol=1e-5)
    extra = tmp_path / "c.las"
    write_las(extra, n=30)
    from gigapoint.errors import GigapointWarning

    with pytest.warns(GigapointWarning, match="3 files: attribute.s. classification, .* not in every file"):  # the LAS file's alone
        cloud = open_cloud(d, extra, chunk_size=7)
    assert cloud.name == "3 files" and cloud.n_points == 130


def test_open_cloud_skips_empty_file_among_several(tmp_path):
    from gigapoint.errors import GigapointWarning

    a = tmp_path / "a.xyz"
    a.write_text("1 2 3\n4 5 6\n")
    b = tmp_path / "b.xyz"
    b.write_text("x y z\n")
    with pytest.warns(GigapointWarning, match="holds no points"):
        cloud = open_cloud(a, b)
    assert cloud.n_points == 2


def test_open_cloud_progress_and_gigapoint_open(tmp_path, capsys):
    import gigapoint

    p = tmp_path / "a.xyz"
    write_text(p, *ref_points(500))
    cloud = gigapoint.open(p, progress=True, chunk_size=100)
    assert cloud.n_points == 500 and cloud.name == "a.xyz"
    assert capsys.readouterr().out == ""  # the bar goes to stderr


def test_format_info_text(tmp_path):
    p = tmp_path / "a.csv"
    p.write_text("x,y,z,intensity\n1,2,3,7\n4,5,6,8\n")
    info = file_info(p)
    assert info["point_count"] == 2 and info["attributes"] == ["intensity"]
    assert info["bounds"] == {"min": [1.0, 2.0, 3.0], "max": [4.0, 5.0, 6.0]}
    text = format_info(info)
    assert "points:      2" in text and "intensity" in text and "comma" in text


def test_info_of_a_text_file_names_attributes_as_reading_does(tmp_path):
    # info said "Foo/Bar" where the cloud read holds "foo_bar" (and --color-attribute takes that)
    p = tmp_path / "a.xyz"
    p.write_text("x y z Foo/Bar\n1 2 3 4\n4 5 6 8\n")
    assert file_info(p)["attributes"] == list(open_cloud(p).attributes) == ["Foo_Bar"]  # (as the file spells it: io._base.attribute_spelling)


def test_registry_takes_a_new_reader(tmp_path, monkeypatch):
    from gigapoint.core.chunk import PointChunk
    from gigapoint.io import registry
    from gigapoint.io._base import Reader

    monkeypatch.setattr(registry, "_READERS", list(registry.readers()))

    class FooReader(Reader):
        name = "FOO"
        suffixes = (".foo",)

        def sniff(self, head):
            return head.startswith(b"FOO!")

        def read_chunks(self, path, chunk_size=10):
            yield PointChunk(np.arange(6.0).reshape(2, 3))

        def info(self, path):
            return {"path": str(path), "format": "FOO", "point_count": 2}

    registry.register(FooReader())
    p = tmp_path / "x.anything"
    p.write_bytes(b"FOO!data")
    assert reader_for(p).name == "FOO"
    assert open_cloud(p).n_points == 2
    assert file_info(p)["format"] == "FOO"
    assert ".foo" in registry.supported_suffixes()


def test_text_comment_lines_before_the_header(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("# exported by a scanner\n# units: m\nX;Y;Z;Intensity\n1;2;3;9\n4;5;6;10\n")
    _, got, _, attrs = collect(p)
    np.testing.assert_array_equal(got, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(attrs["intensity"], [9, 10])


def test_text_with_byte_order_mark(tmp_path):
    p = tmp_path / "bom.csv"
    p.write_bytes("x,y,z\n1,2,3\n".encode("utf-8-sig"))
    np.testing.assert_array_equal(collect(p)[1], [[1, 2, 3]])


def test_attribute_names_that_cannot_name_a_file_are_mended_or_refused(tmp_path):
    """Octrees store an attribute in ``attr.<name>.npy``: a file's own field 'a/b' is read as
    'a_b' (NPZ, CSV; LAS extra bytes: test_io_las), a program's is a one-line InputError (the
    NPZ said "internal error: ValueError" and exit 2, a LAS conversion failed on 'attr.a/b.npy')."""
    import gigapoint as gp
    from gigapoint.errors import InputError

    np.savez(tmp_path / "a.npz", xyz=np.random.default_rng(1).random((10, 3)), **{"a/b": np.arange(10)})
    (tmp_path / "a.csv").write_text("x,y,z,a/b\n1,2,3,4\n5,6,7,8\n")
    assert list(open_cloud(tmp_path / "a.npz").attributes) == ["a_b"]
    np.testing.assert_array_equal(np.asarray(open_cloud(tmp_path / "a.csv").attributes["a_b"]), [4, 8])
    for name in ("a/b", "..", "", "x\\y"):
        with pytest.raises(InputError, match=f"^arrays: attribute name {name!r} cannot be stored".replace("\\", "\\\\")):
            gp.from_arrays(np.zeros((2, 3)), **{name: np.ones(2)})


def test_a_file_named_twice_is_read_once(tmp_path):
    """``gigapoint render a.laz a.laz`` (or a file and its folder) merged its points twice, in
    clouds, progressive octrees and conversions alike."""
    import gigapoint as gp
    from gigapoint.errors import GigapointWarning

    folder = tmp_path / "tiles"
    folder.mkdir()
    rng = np.random.default_rng(3)
    for name in ("a", "b"):
        np.save(folder / f"{name}.npy", rng.random((50, 3)))
    a = folder / "a.npy"
    for paths, want in (([a, a], 50), ([a, folder], 100), ([folder, str(a)], 100), ([a, tmp_path / "tiles" / ".." / "tiles" / "a.npy"], 50)):
        with pytest.warns(GigapointWarning, match=r"a.npy: named more than once; its points are read once"):
            cloud = open_cloud(*paths)
        assert cloud.n_points == want, paths
    with pytest.warns(GigapointWarning, match="named more than once"):
        octree = gp.open([a, a], progressive=True)
    octree.wait()
    assert octree.n_points == 50
    octree.close()
    with pytest.warns(GigapointWarning, match="named more than once"):
        result = gp.convert([a, folder], tmp_path / "out")
    assert result.points == 100
    linked = tmp_path / "same.npy"  # a hard link (or one file through two mounts): another path, the same file
    os.link(a, linked)
    with pytest.warns(GigapointWarning, match="same.npy: named more than once"):
        assert open_cloud(a, linked).n_points == 50
    from gigapoint.lod.progressive import open_sized  # what render and view open: it warned twice

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        cloud = open_sized([a, a], point_budget=10**6)
    assert cloud.n_points == 50 and [str(w.message) for w in seen] == [f"{a}: named more than once; its points are read once"]


def test_field_names_are_listed_as_read_and_two_of_one_lower_case_name_are_an_error(tmp_path):
    """Fields are read as the file spells them, but those gigapoint reads by name in lower case
    (io._base.attribute_spelling: NPY's 'Return_Number', PLY's 'scalar_Intensity' kept), and info
    lists them so (it listed the file's spelling, which --color-attribute then refused); two fields
    read under one name ('Intensity' and 'intensity', 'X' and 'x') were one: the last kept, the
    other lost without a word."""
    from gigapoint.errors import InputError

    PLY_XYZ = "property float x\nproperty float y\nproperty float z\n"
    p = tmp_path / "cc.ply"
    p.write_text("ply\nformat ascii 1.0\nelement vertex 2\n" + PLY_XYZ + "property float scalar_Intensity\nend_header\n1 2 3 7\n4 5 6 8\n")
    assert file_info(p)["attributes"] == list(open_cloud(p).attributes) == ["scalar_Intensity"]
    n = tmp_path / "s.npy"
    rec = np.zeros(2, [("X", "f8"), ("Y", "f8"), ("Z", "f8"), ("Return_Number", "u1")])
    np.save(n, rec)
    assert file_info(n)["attributes"] == list(open_cloud(n).attributes) == ["return_number"]
    clash = {
        "c.csv": ("x,y,z,Intensity,intensity\n1,2,3,10,20\n4,5,6,30,40\n", "'Intensity' and 'intensity'"),
        "red.csv": ("x,y,z,red,R,g,b\n1,2,3,10,20,1,1\n", "'red' and 'R'"),
        "c.ply": ("ply\nformat ascii 1.0\nelement vertex 1\n" + PLY_XYZ + "property float X\nend_header\n1 2 3 4\n", "'x' and 'X'"),
    }
    for name, (text, both) in clash.items():
        (tmp_path / name).write_text(text)
    np.save(tmp_path / "x.npy", np.zeros(2, [("x", "f8"), ("y", "f8"), ("z", "f8"), ("X", "f8")]))
    clash["x.npy"] = (None, "'x' and 'X'")
    for name, (_, both) in clash.items():
        for way in (open_cloud, file_info):
            with pytest.raises(InputError) as e:
                way(tmp_path / name)
            assert str(e.value).startswith(f"{tmp_path / name}: ") and f"fields {both} are both read as" in str(e.value), str(e.value)


@pytest.mark.parametrize("encoding", ["ascii", "binary_little_endian"])
def test_ply_attributes_keep_the_files_spelling_but_those_read_by_name(tmp_path, encoding):
    """A PLY file's attribute names came back in lower case: 'Amplitude' saved, 'amplitude' read
    (and info listed). Now the file's spelling stays; x/y/z, colours and the names gigapoint reads
    by name (LAS fields as PDAL spells them, 'Classification'; normals) are found in any case."""
    n = 4
    values = {"X": np.arange(n, dtype="f8"), "y": np.zeros(n), "Z": np.ones(n), "Red": np.full(n, 255, "u1"), "green": np.zeros(n, "u1"),
              "blue": np.zeros(n, "u1"), "Amplitude": np.arange(n, dtype="f4") / 2, "Classification": np.full(n, 2, "u1"),
              "NX": np.ones(n, "f4"), "scalar_Range_m": np.arange(n, dtype="f4")}  # fmt: skip
    vertex = np.zeros(n, [(name, v.dtype) for name, v in values.items()])
    for name, v in values.items():
        vertex[name] = v
    p = tmp_path / "named.ply"
    PlyData([PlyElement.describe(vertex, "vertex")], text=encoding == "ascii").write(str(p))
    cloud = open_cloud(p, colors="rgba")
    want = ["Amplitude", "classification", "nx", "scalar_Range_m"]
    assert list(cloud.attributes) == file_info(p)["attributes"] == want
    np.testing.assert_array_equal(cloud.attributes["Amplitude"], values["Amplitude"])
    np.testing.assert_array_equal(cloud.attributes["classification"], [2] * n)
    np.testing.assert_array_equal(cloud.rgba[:, 0], [255] * n)
    saved = tmp_path / "again.ply"  # gigapoint's writer keeps the names given: a round trip keeps them
    cloud.save(saved)
    assert list(open_cloud(saved).attributes) == want


def test_a_vertex_list_property_is_left_out_quietly_and_not_listed(tmp_path):
    """A list property inside the vertex element (its points read by plyfile, the list left out)
    was listed by info as an attribute the cloud did not have, and an empty list printed
    plyfile's "warning: loadtxt: input contained no data"."""
    p = tmp_path / "l.ply"
    p.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        + "property list uchar float feat\nproperty float q\nend_header\n1 2 3 2 0.5 0.5 7\n4 5 6 0 8\n7 8 9 1 1.0 9\n"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cloud = open_cloud(p)
        info = file_info(p)
    assert cloud.n_points == 3 and list(cloud.attributes) == info["attributes"] == ["q"]


def test_an_ascii_ply_s_lists_are_left_out_of_its_lines_and_a_line_they_do_not_fit_is_named(tmp_path):
    """An ASCII file's lists (before or inside the vertex element) were read by plyfile, its empty
    list's loadtxt warning hidden by a catch_warnings (process-wide: not for a loader's thread).
    Now they are left out of each line: every vertex as written, no warning; a bad line named."""
    head = "ply\nformat ascii 1.0\nelement face 2\nproperty list uchar int idx\nelement vertex 3\n"
    head += "property float x\nproperty float y\nproperty float z\n"
    p = tmp_path / "l.ply"
    p.write_text(head + "property list uchar float feat\nproperty uchar q\nend_header\n0\n3 1 2 3\n1 2 3 2 0.5 0.5 7\n4 5 6 0 8\n7 8 9 1 1.0 9\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        chunks = list(read_chunks(p))
    assert np.concatenate([c.xyz for c in chunks]).tolist() == [[1, 2, 3], [4, 5, 6], [7, 8, 9]]
    assert np.concatenate([c.attributes["q"] for c in chunks]).tolist() == [7, 8, 9]
    p.write_text(head + "property list uchar float feat\nproperty uchar q\nend_header\n0\n0\n1 2 3 0 7\n4 5 6 5 0.5 8\n7 8 9 0 9\n")
    with pytest.raises(InputError) as e:
        open_cloud(p)
    assert str(e.value) == f"{p}: line 15 has 6 values, the vertex element declares 4 besides its list feat (a length, then that many values)"


def test_float_colours_of_0_255_whose_first_chunks_are_all_0_or_1_are_not_white(tmp_path, monkeypatch):
    """A float 0..255 colour column whose first coloured chunk held only 0 and 1 was taken as 0..1
    and never revised: every later colour x 255, clipped, white. A later chunk above 1.5 now
    decides it again (as 8-bit colours are revised to 16-bit); chunks converted keep theirs."""
    import gigapoint
    from gigapoint.lod.progressive import loader

    n = 6000
    rng = np.random.default_rng(0)
    a = np.zeros((n, 6), np.float32)
    a[:, :3] = rng.random((n, 3)) * 10
    a[: n // 2, 3:] = rng.integers(0, 2, (n // 2, 3))
    a[n // 2 :, 3:] = rng.integers(2, 256, (n - n // 2, 3))
    np.save(tmp_path / "a.npy", a)
    np.savetxt(tmp_path / "a.txt", a, fmt="%.3f")
    for name in ("a.npy", "a.txt"):
        rgba = np.concatenate([c.rgba for c in read_chunks(tmp_path / name, chunk_size=1000)])
        assert (rgba[: n // 2, :3] == a[: n // 2, 3:] * 255).all()  # the 0..1 chunks as read before
        assert (rgba[n // 2 :, :3] == a[n // 2 :, 3:]).all()
    monkeypatch.setattr(loader, "DECODE_CHUNK", 1000)
    cloud = gigapoint.open(tmp_path / "a.npy", progressive=True)
    cloud.wait()
    got = np.concatenate([c.rgba for c in cloud.chunks()])
    assert len(got) == n and (got[:, :3] == 255).all(1).sum() == (a[:, 3:] == 1).all(1).sum()
    cloud.close()


def _pts_lines(n: int, seed: int) -> str:
    xyz, rgb = ref_points(n, seed)
    return "".join(f"{x:.3f} {y:.3f} {z:.3f} 7 {r} {g} {b}\n" for (x, y, z), (r, g, b) in zip(xyz, rgb))


def test_a_pts_file_holding_fewer_points_than_its_count_says_so_once(tmp_path):
    """A PTS file's first-line count was read and thrown away: one cut at a line's end (5 000
    declared, 4 000 there) loaded its 4 000 points without a word."""
    import gigapoint
    from gigapoint.errors import GigapointWarning

    p = tmp_path / "cut.pts"
    p.write_text("5000\n" + _pts_lines(4000, 0))
    message = f"{p}: PTS file declares 5,000 points, holds 4,000: those read"
    for read in (gigapoint.open, file_info):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            got = read(p)
        assert [str(w.message) for w in caught if issubclass(w.category, GigapointWarning)] == [message]
    assert got["point_count"] == 4000
    p.write_text("4000\n" + _pts_lines(4000, 0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert gigapoint.open(p).n_points == 4000


def test_a_multi_scan_pts_file_reads_every_scan(tmp_path):
    """A count line between two scans was "line 2002 has 1 columns, expected 7": it is the next
    scan's count, and the counts are summed."""
    import gigapoint
    from gigapoint.errors import GigapointWarning

    p = tmp_path / "scans.pts"
    p.write_text("2000\n" + _pts_lines(2000, 0) + "3000\n" + _pts_lines(3000, 1))
    want = np.concatenate([ref_points(2000, 0)[0], ref_points(3000, 1)[0]])
    for chunk_size in (700, 2000, 10_000):  # the count line within a chunk, first in one, ...
        got = np.concatenate([c.xyz for c in read_chunks(p, chunk_size=chunk_size)])
        np.testing.assert_allclose(got, want, atol=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert gigapoint.open(p).n_points == 5000
    p.write_text("2000\n" + _pts_lines(2000, 0) + "3000\n" + _pts_lines(2500, 1))
    with pytest.warns(GigapointWarning, match=r"scans\.pts: PTS file declares 5,000 points \(2 scans\), holds 4,500: those read"):
        assert gigapoint.open(p).n_points == 4500


def test_a_pts_file_of_many_scans_is_parsed_once_per_chunk(tmp_path, monkeypatch):
    """Each count line within a chunk cost a failed parse and a re-parse of the whole chunk:
    400 scans of 50 points took 16.7 s. The count lines are now found first."""
    from gigapoint.io import text

    calls = []
    parsed = text._parsed
    monkeypatch.setattr(text, "_parsed", lambda lines, *a: calls.append(len(lines)) or parsed(lines, *a))
    p = tmp_path / "many.pts"
    p.write_text("".join("50\n" + _pts_lines(50, seed) for seed in range(400)))
    got = np.concatenate([c.xyz for c in read_chunks(p)])
    want = np.concatenate([ref_points(50, seed)[0] for seed in range(400)])
    assert len(got) == 20_000
    np.testing.assert_allclose(got, want, atol=1e-3)
    assert len(calls) == 1
