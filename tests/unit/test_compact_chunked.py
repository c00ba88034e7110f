"""The chunked build (core/chunked.py): the same cloud as build_cloud, array for array and pixel
for pixel, without holding every point's float64 position."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint import Camera, RenderSettings
from gigapoint.core import PointChunk, build_cloud
from gigapoint.core.chunked import ReadOnce, build_cloud_chunked
from gigapoint.core.palette import PaletteColors
from gigapoint.errors import EmptyCloudError, GigapointWarning, InputError
from gigapoint.io.demo import demo_chunks

AUTZEN = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "autzen_trim.laz"
FIELDS = ("batches", "low", "med", "high", "color", "ext", "packing")


def assert_same_cloud(got, want):
    assert got.layout == want.layout
    for f in FIELDS:
        a, b = getattr(got, f), getattr(want, f)
        if b is None:
            assert a is None, f
            continue
        if isinstance(b, PaletteColors):  # colors="auto" chose per-block palettes: their arrays
            assert isinstance(a, PaletteColors) and (a.shift, a.n) == (b.shift, b.n), f
            np.testing.assert_array_equal(a.words, b.words, err_msg=f)
            np.testing.assert_array_equal(a.palette, b.palette, err_msg=f)
            continue
        assert a.dtype == b.dtype, f
        np.testing.assert_array_equal(a, b, err_msg=f)
    assert sorted(got.attributes) == sorted(want.attributes)
    for name, values in want.attributes.items():
        assert got.attributes[name].dtype == values.dtype
        np.testing.assert_array_equal(got.attributes[name], values, err_msg=name)
    assert got.source_scale == want.source_scale
    assert got.skipped == want.skipped
    for a, b in zip(got.bounds, want.bounds):
        np.testing.assert_array_equal(a, b)


def assert_same_images(got, want):
    settings = RenderSettings(backend="cpu", size_mode="fixed")
    for view in ("top", "iso", "front"):
        cam = Camera.fit(want.bounds, view=view, width=160, height=120)
        a = gp.render_frame(got, cam, settings)
        b = gp.render_frame(want, cam, settings)
        assert a.stats.points_processed == want.n_points
        np.testing.assert_array_equal(a.visibility, b.visibility)
        np.testing.assert_array_equal(a.image, b.image)
    close = Camera.orbit(want.bounds[0] + 0.5 * (want.bounds[1] - want.bounds[0]), 30.0, 35.0, 60.0, width=160, height=120)
    np.testing.assert_array_equal(gp.render_frame(got, close, settings).image, gp.render_frame(want, close, settings).image)


@pytest.mark.parametrize(
    ("scale", "batch_size", "partition_points", "read_once"),
    [(0.01, 1000, 20_000, False), (0.01, 10_240, 50_000, False), (None, 777, 30_000, False), (0.01, 1000, 20_000, True), (None, 777, 30_000, True)],
)
def test_equals_build_cloud(scale, batch_size, partition_points, read_once, tmp_path):
    n = 250_000

    def source():
        return demo_chunks(n, seed=3, chunk_size=60_000, scale=scale)

    want = build_cloud(source(), name="town", batch_size=batch_size)
    got = build_cloud_chunked(source, name="town", batch_size=batch_size, partition_points=partition_points, tmpdir=tmp_path, read_once=read_once)
    assert want.layout == ("words" if scale is None else "compact")
    assert_same_cloud(got, want)
    assert_same_images(got, want)
    assert list(tmp_path.iterdir()) == []  # the spill folder is gone
    if scale is not None:  # exact at the source's scale: the decoded points are the source's
        xyz = np.concatenate([c.xyz for c in source()])
        q = np.round(got.positions() / scale).astype(np.int64)
        assert np.abs(got.positions() / scale - q).max() < 1e-3
        want_q = np.round(xyz / scale).astype(np.int64)
        np.testing.assert_array_equal(q[np.lexsort(q.T)], want_q[np.lexsort(want_q.T)])


def test_many_partitions_carry_batches_across_them(tmp_path):
    """Partitions much smaller than a batch: most batches gather points of several partitions."""
    n = 60_000

    def source():
        return demo_chunks(n, seed=1, chunk_size=25_000, scale=0.01)

    got = build_cloud_chunked(source, batch_size=4096, partition_points=500, tmpdir=tmp_path)
    assert_same_cloud(got, build_cloud(source(), batch_size=4096))


def test_large_partitions_take_the_parallel_sort(tmp_path):
    """Partitions above 2^20 points: the radix sort and the parallel gathers (the 10⁹ path)."""
    n = 2_400_000

    def source():
        return demo_chunks(n, seed=5, chunk_size=800_000, scale=0.01)

    got = build_cloud_chunked(source, partition_points=1_300_000, tmpdir=tmp_path)
    assert_same_cloud(got, build_cloud(source()))


@pytest.mark.parametrize("read_once", [False, True])
def test_invalid_points_mixed_attributes_wide_batches(rng, tmp_path, read_once):
    """NaN/inf points skipped and counted, only the attributes every chunk has kept, a chunk off
    the grid (wide batches), non-opaque colours kept 32-bit: all as build_cloud does."""
    utm = np.array([636_000.0, 5_012_000.0, 120.0])
    chunks = []
    for k in range(4):
        xyz = utm + np.round(rng.random((30_000, 3)) * [400.0, 300.0, 30.0], 2)
        if k == 2:
            xyz = xyz + 0.003  # off the 1 cm grid: its batches are stored wide
        xyz[rng.integers(0, len(xyz), 50)] = np.nan
        xyz[5, 1] = np.inf
        rgba = rng.integers(0, 256, (len(xyz), 4), dtype=np.uint8)
        attrs = {"intensity": rng.integers(0, 65535, len(xyz)).astype(np.uint16)}
        if k != 1:
            attrs["classification"] = rng.integers(0, 20, len(xyz)).astype(np.uint8)
        chunks.append(PointChunk(xyz, rgba, attrs, scale=(0.01, 0.01, 0.01)))
    with pytest.warns(GigapointWarning, match="skipped"), pytest.warns(GigapointWarning, match="classification not in every file"):
        want = build_cloud(chunks, batch_size=2000)
    with pytest.warns(GigapointWarning, match="skipped"), pytest.warns(GigapointWarning, match="classification not in every file"):
        got = build_cloud_chunked(lambda: chunks, batch_size=2000, partition_points=7_000, tmpdir=tmp_path, read_once=read_once)
    assert got.skipped == want.skipped > 0
    assert sorted(got.attributes) == ["intensity"]
    assert got.color.dtype == np.uint32  # not opaque: 32-bit colours
    assert ((got.packing["code"] & 0xFF) == 20).any()  # some wide batches
    assert_same_cloud(got, want)


def test_a_source_read_once_is_read_back_as_it_came_colour_bits_and_scale_included(rng, tmp_path):
    """ReadOnce's later passes give each chunk as the source gave it (gigapoint tile writes its
    tiles from them: a file's 16-bit colours read back without their bits were written as 8-bit)."""
    chunks = [
        PointChunk(rng.random((500, 3)), rng.integers(0, 256, (500, 4), dtype=np.uint8), {"intensity": rng.integers(0, 65535, 500).astype(np.uint16)},
                   scale=(0.01, 0.01, 0.01), color_bits=16),
        PointChunk(rng.random((300, 3)), rng.integers(0, 256, (300, 4), dtype=np.uint8), {"intensity": np.zeros(300, np.uint16)}, color_bits=8),
    ]  # fmt: skip
    once = ReadOnce(lambda: chunks, tmp_path, "src")
    assert all(got is want for got, want in zip(once.first(), chunks, strict=True))  # (the first pass: the source's own)
    again = list(once.last())
    assert [(len(c), c.scale, c.color_bits) for c in again] == [(500, (0.01, 0.01, 0.01), 16), (300, None, 8)]
    for got, want in zip(again, chunks):
        np.testing.assert_array_equal(got.xyz, want.xyz)
        np.testing.assert_array_equal(got.rgba, want.rgba)
        np.testing.assert_array_equal(got.attributes["intensity"], want.attributes["intensity"])
    assert list(tmp_path.iterdir()) == []  # the last pass removed what it read


def test_a_source_read_once_is_called_once_and_its_copy_never_outgrows_the_points(rng, tmp_path, monkeypatch):
    """read_once: the source is called once (the survey), its chunks as read (2-D attributes,
    an empty chunk, a byte-sized attribute before an 8-byte one: aligned views) kept in the
    build's folder for the later passes, which give the cloud the source gives; the spill pass
    removes each chunk file once read, so the folder never holds much more than the points once."""
    from gigapoint.core import chunked

    chunks = []
    for k in range(5):
        m = 0 if k == 3 else 20_000 + 7 * k
        attrs = {"flag": rng.integers(0, 2, m).astype(np.uint8), "t": rng.random(m), "rg": rng.integers(0, 999, (m, 2)).astype(np.uint16)}
        chunks.append(PointChunk(np.round(rng.random((m, 3)) * 500.0, 2), rng.integers(0, 256, (m, 4), dtype=np.uint8), attrs, scale=(0.01,) * 3))
    calls = []

    def source():
        calls.append(1)
        return iter(chunks)

    folder_bytes = []
    spill = chunked._spill

    def spilling(src, *args):
        def watched():
            for chunk in src():
                folder_bytes.append(sum(f.stat().st_size for f in Path(args[1]).iterdir()))
                yield chunk

        return spill(watched, *args)

    monkeypatch.setattr(chunked, "_spill", spilling)
    got = build_cloud_chunked(source, batch_size=3000, partition_points=9_000, tmpdir=tmp_path, read_once=True)
    assert len(calls) == 1
    assert_same_cloud(got, build_cloud(iter(chunks), batch_size=3000))
    assert got.attributes["rg"].shape == (sum(len(c) for c in chunks), 2)
    point_bytes = sum(c.xyz.nbytes + c.rgba.nbytes + sum(v.nbytes for v in c.attributes.values()) for c in chunks)
    assert len(folder_bytes) == 5 and max(folder_bytes) <= point_bytes + 64 * 5  # (each chunk file's padding)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not AUTZEN.exists(), reason="shared sample missing")
def test_open_decodes_a_laz_file_once_when_chunked(monkeypatch, tmp_path):
    """gp.open(LAZ, chunked=True) decodes the file once (io.Reader.reads_slowly), not once a
    pass, and gives the cloud a plain open gives; a LAS file is read a pass at a time still."""
    from gigapoint.io.las import LasReader

    reads = []
    read_chunks = LasReader.read_chunks

    def counting(self, path, *args, **kwargs):
        reads.append(path)
        return read_chunks(self, path, *args, **kwargs)

    monkeypatch.setattr(LasReader, "read_chunks", counting)
    got = gp.open(AUTZEN, chunked=True, chunk_size=30_000)
    assert len(reads) == 1
    assert_same_cloud(got, gp.open(AUTZEN))
    import laspy

    las = tmp_path / "autzen.las"
    laspy.read(str(AUTZEN)).write(str(las))
    reads.clear()
    gp.open(las, chunked=True, chunk_size=30_000)
    assert len(reads) == 3


def test_a_full_disk_while_keeping_a_source_read_once_is_one_line(monkeypatch, tmp_path):
    import errno

    from gigapoint.core import chunked

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(chunked, "append_file", full)
    points = np.random.default_rng(1).uniform(0, 10, (1000, 3))
    with pytest.raises(InputError, match=r"full: spilling points to .*gigapoint_chunked_.* failed: No space left on device \(the chunked build needs ~30 bytes a point of free disk there; pass tmpdir="):
        chunked.build_cloud_chunked(lambda: iter([PointChunk(points, None)]), name="full", tmpdir=tmp_path, read_once=True)
    assert not list(tmp_path.iterdir())

    def failing():  # the source's own error is not the spill's
        yield PointChunk(points, None)
        raise OSError(errno.EIO, "Input/output error", "in.laz")

    monkeypatch.undo()
    with pytest.raises(OSError, match="Input/output error") as caught:
        chunked.build_cloud_chunked(failing, name="bad", tmpdir=tmp_path, read_once=True)
    assert not isinstance(caught.value, InputError) and not list(tmp_path.iterdir())


def test_options_and_errors(tmp_path):
    def source():
        return demo_chunks(20_000, chunk_size=7_000, scale=0.01)

    got = build_cloud_chunked(source, attributes=False, colors="rgba", tmpdir=tmp_path)
    assert got.attributes == {}
    assert got.color.dtype == np.uint32
    assert_same_cloud(got, build_cloud([PointChunk(c.xyz, c.rgba, scale=c.scale) for c in source()], colors="rgba"))
    with pytest.raises(InputError, match="compact layout needs"):
        build_cloud_chunked(lambda: demo_chunks(1000), layout="compact", tmpdir=tmp_path)
    with pytest.raises(EmptyCloudError, match="no valid points"):
        build_cloud_chunked(lambda: [PointChunk(np.full((10, 3), np.nan))], tmpdir=tmp_path)
    passes = []

    def shrinking():  # fewer points on every pass
        passes.append(1)
        return demo_chunks(20_000 - 3000 * len(passes), chunk_size=7_000)

    with pytest.raises(InputError, match="same points each time"):
        build_cloud_chunked(shrinking, tmpdir=tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_demo_chunked_equals_in_memory():
    a = gp.demo(120_000, seed=2, scale=0.01, chunked=True)
    b = gp.demo(120_000, seed=2, scale=0.01, chunked=False)
    assert a.layout == "compact" and a.source_scale == (0.01, 0.01, 0.01)
    assert_same_cloud(a, b)
    c = gp.demo(50_000, scale=0.01, chunked=True, attributes=False)
    assert c.attributes == {} and c.n_points == 50_000


def test_memory_holds_no_float64_copy_of_all_points(tmp_path):
    """numpy's allocations at their peak (tracemalloc) stay near the finished arrays' bytes: one
    float64 xyz of all points (24 bytes a point), as build_cloud holds, would break the bound."""
    n, part, chunk = 2_000_000, 100_000, 100_000

    def source():
        return demo_chunks(n, chunk_size=chunk, scale=0.01)

    build_cloud_chunked(lambda: demo_chunks(50_000, chunk_size=chunk, scale=0.01), partition_points=part, tmpdir=tmp_path)  # JIT
    tracemalloc.start()
    try:
        cloud = build_cloud_chunked(source, partition_points=part, tmpdir=tmp_path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    held = cloud.nbytes
    assert held / n < 10.5  # compact positions, 16-bit colour, 3 bytes of attributes
    # the finished arrays, plus ~100 bytes a point of one chunk or partition and the cell histogram
    bound = held + 100 * max(part, chunk) + 20_000_000
    assert peak < bound, (peak / n, bound / n)
    assert bound < held + 24 * n  # the bound is tight enough to catch a float64 (n, 3) array


@pytest.mark.skipif(not AUTZEN.exists(), reason="shared sample missing")
def test_open_chunked_equals_open(tmp_path):
    """A LAS file (real scale, UTM offsets, 15 bytes of attributes) read chunked."""
    want = gp.open(AUTZEN)
    got = gp.open(AUTZEN, chunked=True, chunk_size=30_000)
    assert got.layout == "compact"
    assert_same_cloud(got, want)


def test_a_full_disk_while_spilling_is_one_line_naming_the_folder(monkeypatch, tmp_path):
    """The spill needs ~30 bytes a point of disk: an OSError there (ENOSPC) becomes one line
    naming the cloud, the folder and the space needed; the temporary folder is removed."""
    import errno

    from gigapoint.core import chunked

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(chunked, "_spill", full)
    rng = np.random.default_rng(1)
    points = rng.uniform(0, 10, (1000, 3))

    def source():
        return iter([PointChunk(points, None)])

    with pytest.raises(InputError, match=r"spilling 1,000 points to .*gigapoint_chunked_.* failed: No space left on device .*tmpdir="):
        chunked.build_cloud_chunked(source, name="full", tmpdir=tmp_path)
    assert not list(tmp_path.iterdir())

    def short(*args, **kwargs):  # numpy's tofile on a full disk: no errno, its own numbers
        raise OSError("26454 requested and 2560 written")

    monkeypatch.setattr(chunked, "_spill", short)
    with pytest.raises(InputError, match=r"failed: only 2560 of 26454 bytes written \(is the disk full\?\) \(the chunked build needs"):
        chunked.build_cloud_chunked(source, name="full", tmpdir=tmp_path)


def test_open_builds_big_files_chunked_by_their_headers(monkeypatch):
    """``gp.open`` (``chunked=None``) takes the bounded-memory build when the files' headers
    count more than CHUNKED_ABOVE points, and the in-memory one otherwise or when told."""
    import gigapoint.core.chunked as chunked_module

    calls = []
    real = chunked_module.build_cloud_chunked
    monkeypatch.setattr(chunked_module, "build_cloud_chunked", lambda *a, **k: calls.append(1) or real(*a, **k))
    small = gp.open(AUTZEN)
    assert calls == []
    monkeypatch.setattr(chunked_module, "CHUNKED_ABOVE", 100_000)  # autzen_trim holds 110 000
    big = gp.open(AUTZEN)
    assert calls == [1]
    assert_same_cloud(big, small)
    gp.open(AUTZEN, chunked=False)
    assert calls == [1]


def test_a_cloud_too_big_for_this_machine_is_refused_before_anything_is_read(monkeypatch, tmp_path):
    """Without the check, ``gp.demo(10**13)`` generated for hours before being killed for
    memory, and a file's build spilled two passes' worth before its disk was full: now one
    line, at once, with the figures and what to do instead."""
    import shutil

    from gigapoint.core import chunked
    from gigapoint.errors import MemoryLimitError

    with pytest.raises(MemoryLimitError, match=r"^demo\(10,000,000,000,000\): 10,000,000,000,000 points held in memory take 50.0 TB or more, .*progressive=True"):
        gp.demo(10**13)  # on any machine: 5 bytes a point at least
    with pytest.raises(InputError, match=r"^demo: n_points must be an integer >= 1, got 2.5$"):
        gp.demo(2.5)
    # a file (its header's count) against a machine of 1 MB: 110 000 points in memory are more
    monkeypatch.setattr(chunked, "physical_memory", lambda: 1 << 20)
    with pytest.raises(MemoryLimitError, match=r"^autzen_trim.laz: 110,000 points held in memory take .* this machine has 0.0 GB: .*chunked=True"):
        gp.open(AUTZEN)
    monkeypatch.setattr(chunked, "physical_memory", lambda: 1 << 40)
    # the bounded-memory build's spill against a disk of 1 MB free, named
    free = shutil.disk_usage(tmp_path)._replace(free=1 << 20)
    monkeypatch.setattr(chunked.shutil, "disk_usage", lambda path: free)
    monkeypatch.setattr(chunked.tempfile, "tempdir", str(tmp_path))
    with pytest.raises(MemoryLimitError, match=rf"^autzen_trim.laz: building 110,000 points in bounded memory spills .* to {tmp_path}, which has 0.0 GB free \(TMPDIR"):
        gp.open(AUTZEN, chunked=True)
    with pytest.raises(MemoryLimitError, match=r"^demo\(60,000,000\): building 60,000,000 points .* spills 1.7 GB or more"):
        gp.demo(60_000_000)  # chunked above 50 M: refused before a point is generated
    assert not list(tmp_path.iterdir())
    monkeypatch.undo()
    assert gp.open(AUTZEN, chunked=True).n_points == 110_000  # room: built


@pytest.mark.parametrize(("bad", "shown"), [(None, "None"), (5, "5"), (np.zeros(3), "array([0., 0., 0.])")])
def test_open_of_something_that_is_not_a_path_is_one_line(bad, shown):
    with pytest.raises(InputError) as e:
        gp.open(bad)
    assert str(e.value) == f"open: paths[0]: {shown} is not a path (a str or os.PathLike)"
    with pytest.raises(InputError) as e:  # the entry named
        gp.open([AUTZEN, bad], progressive=True)
    assert str(e.value) == f"open: paths[1]: {shown} is not a path (a str or os.PathLike)"


def test_the_cli_demo_refuses_more_points_than_memory_holds(monkeypatch, tmp_path, capsys):
    from gigapoint.cli import main
    from gigapoint.core import chunked

    monkeypatch.setattr(chunked, "physical_memory", lambda: 1 << 30)
    out = tmp_path / "d.png"
    assert main(["demo", "-n", "30000000", "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert err == "error: demo(30,000,000): 30,000,000 points held in memory take 1.4 GB or more, and this machine has 1.1 GB: take fewer --points"
    assert not out.exists()
