"""A COPC file cut off (a download stopped part-way): the nodes and hierarchy pages before the cut
are read, with one warning naming the file and the points left out; a cut before the root
hierarchy page (where gigapoint's, PDAL's and untwine's files keep it: after the points) is a
one-line error naming the file, its size and the size its header says."""

from __future__ import annotations

import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import GigapointWarning, InputError
from gigapoint.lod.copc import COPC_INFO_DTYPE, HIERARCHY_ENTRY_DTYPE, INFO_OFFSET, LAS14_HEADER_DTYPE, CopcCloud, open_copc
from gigapoint.lod.copc_write import write_copc
from gigapoint.lod.voxel_octree import key_to_voxel

EDGE, CUBE_MIN = 64.0, np.array([1000.0, 2000.0, 30.0])
#: The root, its eight children, and four children of each of two of them (a child page each, page_level=1).
KEYS = [1, *range(8, 16), *range(64, 68), *range(72, 76)]
#: The one warning of a file cut in its hierarchy whose points are whole (read as plain LAZ).
CUT_HIERARCHY = (
    r"truncated COPC file: its hierarchy is cut off \(EVLR 1 of 1 (\([\d,]+ bytes\) runs past the end of the file \([\d,]+ bytes\)|is cut off at byte [\d,]+): "
    r"(at least )?[\d,]+ bytes missing\), so it is read as a plain LAZ file, without its level of detail; the points are whole"
)


def _nodes():
    rng = np.random.default_rng(3)
    for key in KEYS:
        d, x, y, z = (int(v[0]) for v in key_to_voxel(np.array([key], np.uint64)))
        edge = EDGE / 2**d
        lo = CUBE_MIN + np.array([x, y, z]) * edge
        n = 200 + 37 * (key % 11)
        xyz = np.round(lo + rng.random((n, 3)) * edge * 0.98 + edge * 0.01, 2)
        yield key, xyz, None, {}


def _write(path, page_level=None):
    write_copc(path, _nodes(), scale=[0.01] * 3, offset=[0.0] * 3, cube_min=CUBE_MIN, cube_edge=EDGE, point_format=6, page_level=page_level)
    return path


def _layout(b: bytes):
    """(header, info, {page offset: entries}) of a whole COPC file."""
    hdr = np.frombuffer(b, LAS14_HEADER_DTYPE, count=1)[0]
    info = np.frombuffer(b, COPC_INFO_DTYPE, count=1, offset=INFO_OFFSET)[0]
    pages, todo = {}, [(int(info["root_hier_offset"]), int(info["root_hier_size"]))]
    while todo:
        off, size = todo.pop()
        pages[off] = e = np.frombuffer(b, HIERARCHY_ENTRY_DTYPE, count=size // 32, offset=off)
        todo += [(int(r["offset"]), int(r["byte_size"])) for r in e if r["point_count"] == -1]
    return hdr, info, pages


def _whole_points(b: bytes, end: int) -> tuple[int, int]:
    """(points, nodes) a reader finds in ``b`` cut at ``end``: of the nodes whose chunk lies
    before it, in pages reached through pages before it."""
    hdr, info, pages = _layout(b)
    points = nodes = 0
    todo = [int(info["root_hier_offset"])]
    while todo:
        off = todo.pop()
        for r in pages[off]:
            whole = int(r["offset"]) + int(r["byte_size"]) <= end
            if r["point_count"] == -1 and whole:
                todo.append(int(r["offset"]))
            elif r["point_count"] > 0 and whole:
                points, nodes = points + int(r["point_count"]), nodes + 1
    return points, nodes


def _drawn(cloud) -> int:
    """Points a frame of every node draws (every page read, every node decoded)."""
    cloud.load_hierarchy()
    cam = gp.Camera.fit(cloud.bounds, width=64, height=48)
    return gp.render_frame(cloud, cam, gp.RenderSettings(backend="cpu", point_budget=10**9, lod_threshold_px=0.0)).stats.points_processed


def _hierarchy_first(src, dst):
    """``src`` (one hierarchy page, after the points) rewritten with its page before the points:
    a layout COPC allows (the page's offset is the info VLR's), where a cut in the points leaves the hierarchy whole."""
    b = bytearray(src.read_bytes())
    hdr, info, pages = _layout(bytes(b))
    page, data = next(iter(pages.values())), int(hdr["offset_to_point_data"])
    shift = page.nbytes
    page = page.copy()
    page["offset"][page["point_count"] > 0] += shift
    h = hdr.copy()
    h["offset_to_point_data"] += shift
    h["start_of_first_evlr"] += shift
    i = info.copy()
    i["root_hier_offset"], i["root_hier_size"] = data, shift
    b[: LAS14_HEADER_DTYPE.itemsize] = h.tobytes()
    b[INFO_OFFSET : INFO_OFFSET + COPC_INFO_DTYPE.itemsize] = i.tobytes()
    table = np.frombuffer(bytes(b[data : data + 8]), np.int64)[0] + shift  # the LAZ chunk table's offset
    dst.write_bytes(bytes(b[:data]) + page.tobytes() + np.int64(table).tobytes() + bytes(b[data + 8 :]))
    return dst


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("copc_cut")
    flat, paged = _write(d / "flat.copc.laz"), _write(d / "paged.copc.laz", page_level=1)
    first = _hierarchy_first(flat, d / "first.copc.laz")
    total = sum(len(xyz) for _, xyz, _, _ in _nodes())
    for p in (flat, paged, first):  # whole, each reads every point
        assert _drawn(gp.open(p)) == total
    return flat, paged, first, total


def _loaded(cloud):
    assert cloud.wait(60)
    return cloud


def _cut(src, dst, end):
    dst.write_bytes(src.read_bytes()[:end])
    return dst


def _error(path, match):
    with pytest.raises(InputError, match=match) as e:
        _drawn(gp.open(path))
    assert "\n" not in str(e.value)


def test_a_cut_in_the_header_or_the_info_vlr_is_a_one_line_error(files, tmp_path):
    flat = files[0]
    _error(_cut(flat, tmp_path / "a.copc.laz", 300), r"a\.copc\.laz: truncated LAS 1\.4 header: the file has 300 bytes, the header needs 375$")
    _error(_cut(flat, tmp_path / "b.copc.laz", 450), r"b\.copc\.laz: truncated COPC file \(450 bytes: no room for the COPC info VLR\)$")


def test_a_cut_before_the_hierarchy_says_the_size_the_header_expects(files, tmp_path):
    """Cut in its points, the hierarchy after them is gone, and so is the LAZ chunk table:
    nothing can be read, as COPC or as LAZ (its chunks are of variable size). Cut in the
    hierarchy, the chunk table is whole: its points read as a plain LAZ file, every one."""
    flat, total = files[0], files[3]
    b = flat.read_bytes()
    hdr, info, _ = _layout(b)
    root, evlr = int(info["root_hier_offset"]), int(hdr["start_of_first_evlr"])
    size = f"{root + int(info['root_hier_size']):,}"
    where = rf"\(its hierarchy, at bytes {root:,}\.\.{size}, is cut off: no node can be found\)"
    data = int(hdr["offset_to_point_data"])
    mid = _cut(flat, tmp_path / "mid.copc.laz", (data + evlr) // 2)
    _error(mid, rf"mid\.copc\.laz: truncated COPC file: it has {(data + evlr) // 2:,} bytes, its header says at least {size} {where}$")
    with pytest.raises(InputError, match=r"mid\.copc\.laz: truncated LAZ file: its chunk table \(at byte [\d,]+\) lies past the end of the file .* without the table no point can be read$"):
        gp.open(mid, progressive=True).wait(60)
    for end in (evlr + 20, root + 40):
        p = _cut(flat, tmp_path / f"h{end}.copc.laz", end)
        with pytest.raises(InputError, match=rf"truncated COPC file: it has {end:,} bytes, its header says at least {size} {where}; its points can still be read as a plain LAZ file"):
            open_copc(p)  # (as an octree: gp.open reads it as LAZ, below)
        with pytest.warns(GigapointWarning, match=rf"{re.escape(str(p))}: {CUT_HIERARCHY}$"):
            assert gp.open(p).n_points == total  # a PointCloud, every point
        cloud = gp.open(p, progressive=True)
        with pytest.warns(GigapointWarning, match=rf"{re.escape(str(p))}: {CUT_HIERARCHY}$"):
            _loaded(cloud)  # (said by wait, in this thread)
        assert cloud.n_points == total
        cloud.close()


def test_a_cut_in_the_child_pages_reads_the_nodes_of_the_whole_pages(files, tmp_path):
    paged = files[1]
    b = paged.read_bytes()
    hdr, info, pages = _layout(b)
    root_end = int(info["root_hier_offset"]) + int(info["root_hier_size"])
    assert len(pages) == 3 and root_end < len(b) - 100
    for end in (root_end, len(b) - 40):  # both child pages gone; the last one cut
        p = _cut(paged, tmp_path / f"p{end}.copc.laz", end)
        want, _ = _whole_points(b, end)
        assert 0 < want < files[3]
        with pytest.warns(GigapointWarning, match=rf"p{end}\.copc\.laz: truncated COPC file: it has {end:,} bytes, its header says at least {len(b):,}: the nodes below {2 if end == root_end else 1} hierarchy pages past it are left out$"):
            cloud = gp.open(p)  # (said as the root page is read)
        assert isinstance(cloud, CopcCloud) and _drawn(cloud) == want


@pytest.mark.parametrize("where", [0.1, 0.5, 0.999])
def test_a_cut_in_the_points_of_a_file_with_its_hierarchy_first_reads_every_whole_node(files, tmp_path, where):
    """Its hierarchy whole before the points, a cut in them loses the nodes whose chunk it
    cuts or that lie after it, said once; every node before the cut is drawn, exactly."""
    first, total = files[2], files[3]
    b = first.read_bytes()
    hdr, info, pages = _layout(b)
    data, evlr = int(hdr["offset_to_point_data"]), int(hdr["start_of_first_evlr"])
    chunks = int(max(int(e["offset"]) + int(e["byte_size"]) for e in pages[int(info["root_hier_offset"])] if e["point_count"] > 0))  # (the chunk table, after them)
    end = data + 8 + int((chunks - data - 8) * where)
    p = _cut(first, tmp_path / "f.copc.laz", end)
    want, nodes = _whole_points(b, end)
    lost_nodes = sum(int((e["point_count"] > 0).sum()) for e in pages.values()) - nodes
    assert want < total and lost_nodes > 0
    said = (
        f"{p}: truncated COPC file: it has {end:,} bytes, its header says at least {evlr + 60:,}: "
        f"{total - want:,} points in {lost_nodes:,} nodes past the cut are left out"
    )
    with pytest.warns(GigapointWarning, match=f"^{re.escape(said)}$"):
        cloud = gp.open(p)
    assert cloud.n_points == want
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # said once
        assert _drawn(cloud) == want



# --------------------------------------------------------------------------- cut in its hierarchy: read as LAZ


@pytest.fixture(scope="module")
def autzen_cut(autzen_path, tmp_path_factory):
    """Autzen converted to COPC and cut inside its hierarchy EVLR (after the points: the LAZ chunk table whole)."""
    whole = tmp_path_factory.mktemp("autzen_cut") / "whole.copc.laz"
    gp.convert(autzen_path, whole)
    b = whole.read_bytes()
    _, info, _ = _layout(b)
    return _cut(whole, whole.with_name("cut.copc.laz"), int(info["root_hier_offset"]) + 40)


def _grid_points(cloud) -> np.ndarray:
    """The positions on the files' 0.01 grid, sorted: the cloud's points as a set."""
    xyz = np.round(cloud.positions(), 2)
    return xyz[np.lexsort(xyz.T[::-1])]


def test_a_copc_file_cut_in_its_hierarchy_opens_as_the_plain_laz_file_it_still_is(autzen_cut, autzen_path):
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        cloud = gp.open(autzen_cut)
    said = [str(w.message) for w in said if issubclass(w.category, GigapointWarning)]
    assert len(said) == 1 and re.fullmatch(f"{re.escape(str(autzen_cut))}: {CUT_HIERARCHY}", said[0]), said
    assert isinstance(cloud, gp.PointCloud) and cloud.n_points == 110_000
    np.testing.assert_array_equal(_grid_points(cloud), _grid_points(gp.open(autzen_path)))


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "gigapoint.cli", *map(str, args)], capture_output=True, text=True, timeout=300)


def test_cli_render_and_info_read_a_copc_file_cut_in_its_hierarchy_as_laz(autzen_cut, tmp_path):
    warning = rf"warning: {re.escape(str(autzen_cut))}: {CUT_HIERARCHY}"
    r = _cli("render", autzen_cut, "-o", tmp_path / "x.png", "--width", "64", "--height", "48")
    assert r.returncode == 0, r.stderr
    assert len(re.findall(warning, r.stderr)) == 1, r.stderr
    assert "wrote" in r.stdout and "110,000 points" in r.stdout and (tmp_path / "x.png").stat().st_size > 200
    r = _cli("info", autzen_cut)
    assert r.returncode == 0, r.stderr
    assert re.fullmatch(warning + "\n", r.stderr), r.stderr
    assert "format:      LAZ 1.4, point format 7" in r.stdout and "points:      110,000" in r.stdout


def test_telling_a_local_copc_file_from_a_cut_one_reads_its_head_once(files, tmp_path, monkeypatch):
    """``lod_source_kind`` of a local COPC file: one read of its head tells a COPC file and one cut
    in its hierarchy (read as LAZ) apart (is_copc_file, then is_cut_copc_laz read it twice)."""
    import builtins

    from gigapoint.lod import kinds
    from gigapoint.lod.reader import lod_source_kind

    flat = files[0]
    _, info, _ = _layout(flat.read_bytes())
    cut = _cut(flat, tmp_path / "cut.copc.laz", int(info["root_hier_offset"]) + 40)
    opened = []

    def counting(file, *args, **kwargs):
        opened.append(Path(file).name)
        return builtins.open(file, *args, **kwargs)

    monkeypatch.setattr(kinds, "open", counting, raising=False)
    assert [lod_source_kind(p) for p in (flat, cut)] == ["copc", None]
    assert opened == ["flat.copc.laz", "cut.copc.laz"]
