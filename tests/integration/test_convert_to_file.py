"""``convert`` into one plain point file (lod/convert/to_file.py): tiles merged, filtered, into
one .las/.laz/.ply file, faithful to the inputs' integers, classes, colours and CRS."""

from __future__ import annotations

import importlib

import laspy
import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import EmptyCloudError, GigapointWarning, InputError
from gigapoint.io import read_chunks
from gigapoint.io.filters import PointFilter
from gigapoint.io.las import read_las_header, wkt_of
from gigapoint.lod import ConvertError, convert

CLIP = (636_500.0, 849_000.0, 637_000.0, 849_300.0)


def _tile(path, n: int, seed: int, color_factor: int):
    """A LAS tile (format 3, millimetre grid) of random points; its colours stored x ``color_factor`` (257: 16-bit, 1: 8-bit values)."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.001] * 3, [0.0] * 3
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = (rng.integers(0, 1_000_000, n, dtype=np.int32) for _ in range(3))
    rgb = rng.integers(0, 256, (3, n)).astype(np.uint16) * color_factor
    las.red, las.green, las.blue = rgb
    las.classification = rng.integers(0, 8, n).astype(np.uint8)
    las.write(str(path))
    return path


def _wkt(path) -> str | None:
    hdr = read_las_header(path)
    return wkt_of(hdr.vlrs + hdr.evlrs)


def test_two_tiles_merge_into_one_laz_of_their_integers_classes_and_colours(tmp_path):
    a = _tile(tmp_path / "a.las", 3_000, 1, 257)
    b = _tile(tmp_path / "b.las", 2_000, 2, 1)  # 8-bit values in the 16-bit fields: written back so
    res = convert([a, b], tmp_path / "merged.laz")
    merged, sources = laspy.read(str(tmp_path / "merged.laz")), [laspy.read(str(p)) for p in (a, b)]
    assert (res.points, res.nodes, res.format) == (5_000, 0, "laz")
    for field in ("X", "Y", "Z", "classification", "red", "green", "blue"):
        assert np.array_equal(np.asarray(merged[field]), np.concatenate([np.asarray(s[field]) for s in sources])), field
    assert list(merged.header.scales) == [0.001] * 3


def test_autzen_ground_through_the_cli_holds_its_class_2_points_and_crs(cli, autzen_path, tmp_path):
    src = laspy.read(str(autzen_path))
    ground = src.classification == 2
    out = tmp_path / "ground.laz"
    rc, stdout, err = cli("convert", autzen_path, "-o", out, "--classes", "2", "-q")
    assert rc == 0, err
    assert stdout.startswith(f"{out}: {np.count_nonzero(ground):,} points (laz), ")
    written = laspy.read(str(out))
    assert np.array_equal(written.X, src.X[ground]) and np.array_equal(written.Z, src.Z[ground])
    assert np.array_equal(written.red, src.red[ground])  # (autzen's 8-bit values, as it stores them)
    assert _wkt(out) == _wkt(autzen_path) is not None


def test_a_clip_box_keeps_the_points_inside_it(autzen_path, tmp_path):
    src = laspy.read(str(autzen_path))
    xy = np.stack([src.x, src.y], axis=1)
    inside = np.all((xy >= CLIP[:2]) & (xy <= CLIP[2:]), axis=1)
    res = convert(autzen_path, tmp_path / "clip.las", clip=CLIP)
    written = laspy.read(str(tmp_path / "clip.las"))
    assert res.points == len(written.points) == np.count_nonzero(inside) > 0
    assert np.array_equal(written.X, src.X[inside]) and np.array_equal(written.gps_time, src.gps_time[inside])


def _rows(chunks) -> np.ndarray:
    """Points as sorted rows of position, colour and classification."""
    chunks = list(chunks)
    xyz = np.concatenate([c.xyz for c in chunks])
    rest = np.concatenate([np.column_stack([c.rgba, c.attributes["classification"]]) for c in chunks]).astype(np.float64)
    rows = np.column_stack([xyz, rest])
    return rows[np.lexsort(rows.T[::-1])]


def test_a_ply_output_reads_back_as_the_points_it_was_written_from(autzen_path, tmp_path):
    res = convert(autzen_path, tmp_path / "clip.ply", clip=CLIP)
    back, source = gp.open(tmp_path / "clip.ply", colors="rgba"), gp.open(autzen_path, clip=CLIP, colors="rgba")
    assert res.points == back.n_points == source.n_points
    assert np.array_equal(back.bounds, source.bounds)
    # every point (the clouds hold positions quantized each its own way): as the readers give them, exact
    assert np.array_equal(_rows(read_chunks(tmp_path / "clip.ply")), _rows(PointFilter(clip=CLIP).apply(read_chunks(autzen_path), autzen_path)))
    assert (tmp_path / "clip.ply").read_bytes().startswith(f"ply\nformat binary_little_endian 1.0\nelement vertex {res.points:020d}\n".encode())


def test_an_existing_output_is_refused_before_anything_is_read(autzen_path, tmp_path, monkeypatch):
    out = tmp_path / "ground.laz"
    out.write_bytes(b"the user's file")

    def no_read(*args):
        raise AssertionError("read")

    monkeypatch.setattr(importlib.import_module("gigapoint.lod.convert.to_file"), "read_chunks", no_read)
    with pytest.raises(InputError, match=r"ground\.laz: exists; pass overwrite=True to replace it$"):
        convert(autzen_path, out, classes=2)
    assert out.read_bytes() == b"the user's file"


def test_an_input_named_as_the_output_is_refused(tmp_path):
    a = _tile(tmp_path / "a.las", 100, 1, 257)
    with pytest.raises(InputError, match=r"a\.las: is one of the inputs; write it elsewhere"):
        convert(a, a, overwrite=True)
    assert len(laspy.read(str(a)).points) == 100


@pytest.mark.parametrize(
    ("option", "named"),
    [
        ({"sampler": "poisson"}, "--sampler"),
        ({"memory_limit": "1G"}, "--memory-limit"),
        ({"max_leaf": 1000}, "--max-leaf"),
        ({"layout": "words"}, "--layout"),
        ({"colors": "rgb565"}, "--colors"),
        ({"encoding": "BROTLI"}, "encoding"),
        ({"client": 2}, "--dask/--workers (client)"),
        ({"name": "scan"}, "name"),
    ],
)
def test_an_octree_option_with_a_point_file_output_is_refused_in_one_line(autzen_path, tmp_path, option, named):
    with pytest.raises(ConvertError) as info:
        convert(autzen_path, tmp_path / "out.laz", **option)
    assert str(info.value) == f"{tmp_path / 'out.laz'}: {named}: an option of an octree, not of a plain LAZ file"
    assert not (tmp_path / "out.laz").exists()


def test_the_cli_refuses_octree_options_with_a_point_file_output(cli, autzen_path, tmp_path):
    out = tmp_path / "out.las"
    rc, _, err = cli("convert", autzen_path, "-o", out, "--sampler", "poisson", "--workers", "2")
    assert (rc, err.strip()) == (1, f"error: {out}: --sampler, --dask/--workers (client): options of an octree, not of a plain LAS file")


def test_a_filter_keeping_nothing_is_its_error_and_leaves_no_file(autzen_path, tmp_path):
    with pytest.raises(EmptyCloudError, match=r"autzen_trim\.laz: no point passes the filter \(classes 200\): 110,000 points read$"):
        convert(autzen_path, tmp_path / "none.laz", classes=200)
    assert list(tmp_path.iterdir()) == []


def test_invalid_points_are_skipped_with_a_warning(tmp_path):
    xyz = np.array([[0.0, 0.0, 0.0], [np.nan, 1.0, 1.0], [1.0, 2.0, 3.0]])
    src = tmp_path / "pts.npy"
    np.save(src, xyz)
    with pytest.warns(GigapointWarning, match=r"pts\.npy: skipped 1 invalid points"):
        res = convert(src, tmp_path / "pts.las")
    written = laspy.read(str(tmp_path / "pts.las"))
    assert (res.points, res.skipped) == (2, 1)
    off = np.abs(np.column_stack([written.x, written.y, written.z]) - xyz[[0, 2]])
    assert np.all(off <= written.header.scales / 2)  # (on the grid made from their bounds)
