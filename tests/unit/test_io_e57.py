"""E57 (io/e57.py): scans moved by their poses, read in bounded chunks; colours, intensity,
invalid points; the header without the points; one-line errors; gp.open, progressive, CLI."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import EmptyCloudError, GigapointWarning, InputError, warnings_kept
from gigapoint.io import file_info, read_chunks
from gigapoint.io.e57 import rotation_matrix

pye57 = pytest.importorskip("pye57")

#: a quarter turn about z, then about x by 30 degrees (w, x, y, z), and a translation
TURN = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])
TILT = np.array([np.cos(np.pi / 12), np.sin(np.pi / 12), 0.0, 0.0])
SHIFT = np.array([636_000.0, 849_000.0, 400.0])


@pytest.fixture(scope="module")
def autzen(autzen_path):
    """autzen's points about their centre (scans' own frames are local: single-precision
    coordinates keep them to 1e-4 ft) with their 8-bit colours and intensity."""
    laspy = pytest.importorskip("laspy")
    las = laspy.read(str(autzen_path))
    xyz = np.column_stack([las.x, las.y, las.z])
    local = xyz - xyz.mean(axis=0)
    rgb = np.column_stack([las.red, las.green, las.blue]).astype(np.uint8)  # (autzen's colours are 8-bit in 16-bit fields)
    return SimpleNamespace(xyz=local, rgb=rgb, intensity=np.asarray(las.intensity, np.float64))


def scan_data(xyz, rgb=None, intensity=None, invalid=None) -> dict:
    data = {"cartesianX": xyz[:, 0].copy(), "cartesianY": xyz[:, 1].copy(), "cartesianZ": xyz[:, 2].copy()}
    if rgb is not None:
        data.update(colorRed=rgb[:, 0].copy(), colorGreen=rgb[:, 1].copy(), colorBlue=rgb[:, 2].copy())
    if intensity is not None:
        data["intensity"] = intensity.copy()
    if invalid is not None:
        data["cartesianInvalidState"] = invalid.astype(np.int8)
    return data


def write_e57(path: Path, scans: list[tuple[dict, np.ndarray, np.ndarray]]) -> Path:
    """An E57 file of (data, rotation, translation) scans. Each scan's cartesianBounds are its
    points' own (local, as the standard has them; pye57 writes them moved by the pose)."""
    e = pye57.E57(str(path), mode="w")
    for i, (data, rotation, translation) in enumerate(scans):
        local = np.column_stack([data[c] for c in ("cartesianX", "cartesianY", "cartesianZ")])
        if "cartesianInvalidState" in data:
            local = local[data["cartesianInvalidState"] == 0]
        lo, hi = local.min(axis=0), local.max(axis=0)
        header = SimpleNamespace(name=f"station {i}", rotation=rotation, translation=translation,
                                 xMinimum=lo[0], yMinimum=lo[1], zMinimum=lo[2], xMaximum=hi[0], yMaximum=hi[1], zMaximum=hi[2])  # fmt: skip
        e.write_scan_raw(data, scan_header=header)
    e.close()
    return path


def posed(local: np.ndarray, rotation, translation) -> np.ndarray:
    """What the file's common frame holds: float32 local coordinates (as pye57 stores them) moved by the pose."""
    return local.astype(np.float32).astype(np.float64) @ rotation_matrix(*rotation).T + translation


def test_rotation_matrix_is_the_quaternions():
    """A quarter turn about z takes x to y; the quaternion is normalized (files round it)."""
    np.testing.assert_allclose(rotation_matrix(*TURN) @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(rotation_matrix(*(2 * TILT)) @ [0.0, 1.0, 0.0], [0.0, np.cos(np.pi / 6), np.sin(np.pi / 6)], atol=1e-12)


def test_two_scans_are_read_moved_by_their_poses(autzen, tmp_path):
    """Each scan's points come back in the common frame: rotated, then translated, as its pose says."""
    a, b = autzen.xyz[:60_000], autzen.xyz[60_000:]
    path = write_e57(tmp_path / "two.e57", [(scan_data(a), TURN, SHIFT), (scan_data(b), TILT, -SHIFT)])
    got = np.concatenate([c.xyz for c in read_chunks(path)])
    want = np.concatenate([posed(a, TURN, SHIFT), posed(b, TILT, -SHIFT)])
    assert got.shape == (110_000, 3)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    cloud = gp.open(path)
    assert cloud.n_points == 110_000
    np.testing.assert_allclose(cloud.bounds[0], want.min(axis=0), atol=1e-3)  # (positions held on a grid)
    np.testing.assert_allclose(cloud.bounds[1], want.max(axis=0), atol=1e-3)


def test_the_header_gives_count_and_posed_bounds_without_the_points(autzen, tmp_path):
    """The count is the scans' childCount; the bounds each scan's cartesianBounds' corners moved
    by its pose: they hold every point (a rotated box's corners do), and, about z, are exact."""
    a, b = autzen.xyz[:50_000], autzen.xyz[50_000:]
    path = write_e57(tmp_path / "two.e57", [(scan_data(a), TURN, SHIFT), (scan_data(b), TILT, -SHIFT)])
    head = gp.io.reader_for(path).header(path)
    assert head["point_count"] == 110_000
    lo, hi = (np.array(v) for v in head["bounds"])
    pts = np.concatenate([posed(a, TURN, SHIFT), posed(b, TILT, -SHIFT)])
    assert np.all(lo <= pts.min(axis=0) + 1e-4) and np.all(hi >= pts.max(axis=0) - 1e-4)  # (points stored in single precision)
    turned = gp.io.reader_for(path).header(write_e57(tmp_path / "one.e57", [(scan_data(a), TURN, SHIFT)]))["bounds"]
    np.testing.assert_allclose(turned[0], posed(a, TURN, SHIFT).min(axis=0), atol=1e-3)
    np.testing.assert_allclose(turned[1], posed(a, TURN, SHIFT).max(axis=0), atol=1e-3)


def test_bounds_moved_by_the_pose_already_are_not_taken(autzen, tmp_path):
    """pye57 writes cartesianBounds moved by the pose: moved again they missed the points by the
    translation; outside the range the coordinates' nodes declare, they are not the scan's own, and
    info finds the bounds in the points."""
    path = tmp_path / "pye57.e57"
    e = pye57.E57(str(path), mode="w")
    e.write_scan_raw(scan_data(autzen.xyz[:1000]), rotation=np.array([1.0, 0, 0, 0]), translation=SHIFT)
    e.close()
    assert gp.io.reader_for(path).header(path)["bounds"] is None
    info = file_info(path)
    want = posed(autzen.xyz[:1000], [1, 0, 0, 0], SHIFT)
    assert info["bounds_source"] == "data"
    np.testing.assert_allclose(info["bounds"]["min"], want.min(axis=0), atol=1e-6)


def test_chunked_reading_equals_one_read(autzen, tmp_path):
    """Chunks smaller than a scan (libE57's reader filling buffers of that many points) give the
    same points, colours and attributes as one read, never more than asked a chunk."""
    a, b = autzen.xyz[:7_000], autzen.xyz[7_000:10_000]
    path = write_e57(tmp_path / "s.e57", [(scan_data(a, autzen.rgb[:7_000], autzen.intensity[:7_000]), TURN, SHIFT),
                                          (scan_data(b, autzen.rgb[7_000:10_000], autzen.intensity[7_000:10_000]), TILT, SHIFT)])  # fmt: skip
    whole = list(read_chunks(path, chunk_size=1_000_000))
    small = list(read_chunks(path, chunk_size=999))
    assert [len(c) for c in whole] == [7_000, 3_000]
    assert max(len(c) for c in small) == 999 and sum(len(c) for c in small) == 10_000
    for field in ("xyz", "rgba"):
        np.testing.assert_array_equal(np.concatenate([getattr(c, field) for c in small]), np.concatenate([getattr(c, field) for c in whole]))
    np.testing.assert_array_equal(np.concatenate([c.attributes["intensity"] for c in small]), np.concatenate([c.attributes["intensity"] for c in whole]))


def test_colours_and_intensity_are_scaled_by_the_scans_limits(autzen, tmp_path):
    """Colours of limits 0..255 stay as they are; intensity goes from its limits (autzen's
    0..254, as pye57 writes them) to LAS's 0..65535."""
    n = 5_000
    path = write_e57(tmp_path / "c.e57", [(scan_data(autzen.xyz[:n], autzen.rgb[:n], autzen.intensity[:n]), TURN, SHIFT)])
    (chunk,) = read_chunks(path)
    np.testing.assert_array_equal(chunk.rgba[:, :3], autzen.rgb[:n])
    assert (chunk.rgba[:, 3] == 255).all()
    lo, hi = autzen.intensity[:n].min(), autzen.intensity[:n].max()
    want = np.round((autzen.intensity[:n] - lo) / (hi - lo) * 65535).astype(np.uint16)
    assert chunk.attributes["intensity"].dtype == np.uint16
    np.testing.assert_array_equal(chunk.attributes["intensity"], want)
    assert chunk.attributes["intensity"].max() == 65535
    cloud = gp.open(path)
    assert sorted(cloud.attributes) == ["intensity"]


def test_invalid_points_are_skipped_and_said(autzen, tmp_path):
    """Points whose cartesianInvalidState is not 0 (1: direction only, 2: none) are left out with
    the invalid-points warning; the others keep their places and colours."""
    n = 2_000
    invalid = np.zeros(n, np.int8)
    invalid[[3, 500, 1999]] = [1, 2, 2]
    path = write_e57(tmp_path / "inv.e57", [(scan_data(autzen.xyz[:n], autzen.rgb[:n], invalid=invalid), TURN, SHIFT)])
    with pytest.warns(GigapointWarning, match=r"inv\.e57: skipped 3 invalid points"):
        cloud = gp.open(path)
    assert cloud.n_points == n - 3
    want = posed(autzen.xyz[:n], TURN, SHIFT)[invalid == 0]
    np.testing.assert_allclose(np.sort(cloud.positions()[:, 0]), np.sort(want[:, 0]), atol=1e-3)


def test_scans_of_different_fields_keep_the_attributes_all_have(autzen, tmp_path):
    """One scan with intensity, one without: intensity is left out of both, and said; the scan
    without colours is drawn in the default colour."""
    path = write_e57(tmp_path / "mixed.e57", [(scan_data(autzen.xyz[:100], autzen.rgb[:100], autzen.intensity[:100]), TURN, SHIFT),
                                              (scan_data(autzen.xyz[100:200]), TURN, SHIFT)])  # fmt: skip
    assert gp.io.reader_for(path).header(path)["attributes"] == []
    with pytest.warns(GigapointWarning, match=r"mixed\.e57: attribute\(s\) intensity not in every scan: left out"):
        chunks = list(read_chunks(path))
    assert [sorted(c.attributes) for c in chunks] == [[], []]
    np.testing.assert_array_equal(chunks[0].rgba[:, :3], autzen.rgb[:100])
    assert (chunks[1].rgba == (200, 200, 200, 255)).all()


def _scan_node(e, guid: str, doubles, integers=()):
    """A scan made of libE57's nodes in ``e`` (a file open for writing): its guid and a points
    prototype of double fields ``doubles`` and 0/1 integer fields ``integers``; returns its points
    node (pye57's write_scan_raw writes no spherical coordinates, time stamps or empty scans)."""
    from pye57 import libe57

    image = e.image_file
    scan = libe57.StructureNode(image)
    scan.set("guid", libe57.StringNode(image, guid))
    proto = libe57.StructureNode(image)
    for name in doubles:
        proto.set(name, libe57.FloatNode(image, 0.0, libe57.E57_DOUBLE))
    for name in integers:
        proto.set(name, libe57.IntegerNode(image, 0, 0, 1))
    points = libe57.CompressedVectorNode(image, proto, libe57.VectorNode(image, True))
    scan.set("points", points)
    e.data3d.append(scan)
    return points


def test_a_scan_without_points_takes_no_attribute_from_the_others(autzen, tmp_path):
    """An empty scan (a station aborted) of coordinates and colours, before one of intensity and no
    colours: the intensity is kept, unwarned (it was left out of the whole file, 'not in every
    scan'), and the header says no colours (it said the empty scan's)."""
    path = tmp_path / "aborted.e57"
    e = pye57.E57(str(path), mode="w")
    _scan_node(e, "{aborted}", ("cartesianX", "cartesianY", "cartesianZ", "colorRed", "colorGreen", "colorBlue"))
    n = 100
    lo, hi = autzen.xyz[:n].min(axis=0), autzen.xyz[:n].max(axis=0)
    header = SimpleNamespace(name="station 1", rotation=TURN, translation=SHIFT, xMinimum=lo[0], yMinimum=lo[1], zMinimum=lo[2],
                             xMaximum=hi[0], yMaximum=hi[1], zMaximum=hi[2])  # fmt: skip
    e.write_scan_raw(scan_data(autzen.xyz[:n], intensity=autzen.intensity[:n]), scan_header=header)
    e.close()
    head = gp.io.reader_for(path).header(path)
    assert (head["point_count"], head["attributes"], head["has_color"]) == (n, ["intensity"], False)
    with warnings_kept() as said:
        cloud = gp.open(path)
    assert said == []
    lo, hi = autzen.intensity[:n].min(), autzen.intensity[:n].max()
    want = np.round((autzen.intensity[:n] - lo) / (hi - lo) * 65535).astype(np.uint16)
    np.testing.assert_array_equal(np.sort(cloud.attributes["intensity"]), np.sort(want))


def test_spherical_scans_are_converted(tmp_path):
    """A scan of range, azimuth and elevation only: x = r cos(el) cos(az), y = r cos(el) sin(az), z = r sin(el)."""
    r, az, el = np.array([10.0, 20.0]), np.array([0.0, np.pi / 2]), np.array([0.0, np.pi / 6])
    path = tmp_path / "sph.e57"
    e = pye57.E57(str(path), mode="w")
    points = _scan_node(e, "{spherical}", ("sphericalRange", "sphericalAzimuth", "sphericalElevation"))
    arrays, buffers = e.make_buffers(["sphericalRange", "sphericalAzimuth", "sphericalElevation"], 2)
    arrays["sphericalRange"][:], arrays["sphericalAzimuth"][:], arrays["sphericalElevation"][:] = r, az, el
    writer = points.writer(buffers)
    writer.write(2)
    writer.close()
    e.close()
    (chunk,) = read_chunks(path)
    np.testing.assert_allclose(chunk.xyz, [[10.0, 0.0, 0.0], [0.0, 20 * np.cos(np.pi / 6), 10.0]], atol=1e-9)


def test_a_file_without_scans_is_the_empty_cloud_error(tmp_path):
    path = tmp_path / "none.e57"
    pye57.E57(str(path), mode="w").close()
    assert gp.io.reader_for(path).header(path)["point_count"] == 0
    with pytest.raises(EmptyCloudError, match=r"^.*none\.e57: E57 file holds no points \(0 scans\)$"):
        gp.open(path)


def test_truncated_corrupt_and_foreign_files_are_one_line_errors(autzen, tmp_path):
    """A file cut short, one with a damaged page of points (libE57's checksum) and a text file
    named .e57: one line each naming the file, from gp.open and info (which reads no points:
    the damaged page is found once they are read)."""
    good = write_e57(tmp_path / "good.e57", [(scan_data(autzen.xyz[:20_000]), TURN, SHIFT)])
    data = good.read_bytes()
    cut = tmp_path / "cut.e57"
    cut.write_bytes(data[: len(data) - 3000])
    damaged = tmp_path / "damaged.e57"
    damaged.write_bytes(data[:5000] + bytes(200) + data[5200:])  # inside the points' pages
    foreign = tmp_path / "notes.e57"
    foreign.write_text("x y z\n1 2 3\n")
    cases = [(cut, "corrupt or truncated E57 file: size in file header not same as actual", (gp.open, file_info)),
             (damaged, "corrupt E57 file: checksum mismatch", (gp.open,)),
             (foreign, "not an E57 file (starts with b'x y z\\n1 ', expected b'ASTM-E57')", (gp.open, file_info))]  # fmt: skip
    for path, problem, calls in cases:
        for call in calls:
            with pytest.raises(InputError) as err:
                call(path)
            assert str(err.value).startswith(f"{path}: {problem}"), str(err.value)
            assert "\n" not in str(err.value)


def test_progressive_loading_and_conversion_read_every_scan(autzen, tmp_path, loaded):
    a, b = autzen.xyz[:60_000], autzen.xyz[60_000:]
    path = write_e57(tmp_path / "two.e57", [(scan_data(a, autzen.rgb[:60_000]), TURN, SHIFT), (scan_data(b, autzen.rgb[60_000:]), TILT, SHIFT)])
    octree = loaded(path)
    assert octree.n_points == 110_000
    gp.convert(path, tmp_path / "out")
    assert gp.open(tmp_path / "out").n_points == 110_000


def test_cli_info_and_render(autzen, tmp_path, cli):
    path = write_e57(tmp_path / "site.e57", [(scan_data(autzen.xyz[:60_000], autzen.rgb[:60_000], autzen.intensity[:60_000]), TURN, SHIFT),
                                             (scan_data(autzen.xyz[60_000:], autzen.rgb[60_000:], autzen.intensity[60_000:]), TILT, SHIFT)])  # fmt: skip
    rc, out, _ = cli("info", path)
    assert rc == 0
    assert "format:      E57" in out
    assert "points:      110,000" in out
    assert "color:       yes" in out
    assert "attributes:  intensity" in out
    assert "scans:       2 (station 0, station 1)" in out
    png = tmp_path / "site.png"
    rc, _, err = cli("render", path, "-o", png, "-W", 160, "-H", 120)
    assert rc == 0, err
    from PIL import Image

    image = np.asarray(Image.open(png))
    background = image[0, 0]
    drawn = np.any(image[..., :3] != background[:3], axis=-1)
    assert drawn.sum() > 2_000  # autzen's colours over a good part of the frame


def test_without_pye57_the_error_says_what_to_install(autzen, tmp_path, monkeypatch):
    path = write_e57(tmp_path / "a.e57", [(scan_data(autzen.xyz[:10]), TURN, SHIFT)])
    monkeypatch.setitem(sys.modules, "pye57", None)  # (an import of it raises ImportError)
    with pytest.raises(InputError, match=r"a\.e57: reading E57 needs pye57 \(pip install 'gigapoint\[e57\]'\)$"):
        gp.open(path)


def test_time_stamps_flagged_invalid_are_nan(tmp_path):
    """A point whose isTimeStampInvalid is not 0 kept the meaningless timeStamp written for it as its
    timestamp; it is NaN now (the point and the other time stamps kept). pye57's write_scan_raw
    writes no time stamps: the scan is made of libE57's nodes, as the spherical one above."""
    from pye57 import libe57

    xyz = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    stamps, flags = np.array([10.5, 99.0, 12.25]), np.array([0.0, 1.0, 0.0])
    path = tmp_path / "stamps.e57"
    e = pye57.E57(str(path), mode="w")
    image = e.image_file
    points = _scan_node(e, "{stamps}", ("cartesianX", "cartesianY", "cartesianZ", "timeStamp"), ("isTimeStampInvalid",))
    fields = ["cartesianX", "cartesianY", "cartesianZ", "timeStamp", "isTimeStampInvalid"]
    arrays = {f: np.ascontiguousarray(v, np.float64) for f, v in zip(fields, [*xyz.T, stamps, flags])}
    buffers = libe57.VectorSourceDestBuffer()
    for f in fields:
        buffers.append(libe57.SourceDestBuffer(image, f, arrays[f], 3, True, True))
    writer = points.writer(buffers)
    writer.write(3)
    writer.close()
    e.close()
    (chunk,) = read_chunks(path)
    np.testing.assert_array_equal(chunk.attributes["timestamp"], [10.5, np.nan, 12.25])
    np.testing.assert_array_equal(chunk.xyz, xyz)
    cloud = gp.open(path)  # (NaN is no invalid point: all 3 kept)
    assert cloud.n_points == 3
    np.testing.assert_array_equal(np.asarray(cloud.attributes["timestamp"]), [10.5, np.nan, 12.25])
