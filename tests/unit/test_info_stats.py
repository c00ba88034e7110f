"""``gigapoint info --stats`` and ``gigapoint.io.point_stats``: what the points hold, every point
read once in chunks, numbers checked against laspy's and numpy's."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.errors import EmptyCloudError, InputError
from gigapoint.io import point_stats
from gigapoint.io.stats import class_name

laspy = pytest.importorskip("laspy")

#: byte offset of the header's max X in LAS 1.0-1.4 (max X, min X, max Y, min Y, max Z, min Z)
HEADER_MAX_X = 179


def write_tile(path: Path, n: int, seed: int, classes: list[int], adjusted_time: bool = False) -> Path:
    """A LAS 1.2 point format 3 tile of ``n`` points: classes drawn from ``classes``, returns
    1..3 of 1..3, two flight lines, 16-bit colours."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.01] * 3, [500000.0, 4000000.0, 0.0]
    if adjusted_time:
        header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
    las = laspy.LasData(header)
    las.x = 500000 + rng.random(n) * 100
    las.y = 4000000 + rng.random(n) * 100
    las.z = 100 + rng.random(n) * 10
    las.classification = rng.choice(classes, n)
    las.number_of_returns = rng.integers(1, 4, n)
    las.return_number = [rng.integers(1, k + 1) for k in las.number_of_returns]
    las.point_source_id = rng.choice([11, 12], n)
    las.intensity = rng.integers(0, 4000, n)
    las.gps_time = rng.random(n) * 100 + (0.0 if adjusted_time else 300_000)
    las.red, las.green, las.blue = (rng.integers(0, 65536, n) for _ in range(3))
    las.write(path)
    return path


def expected_returns(las) -> dict:
    r, n = np.asarray(las.return_number), np.asarray(las.number_of_returns)
    return {"single": int(np.sum((r == 1) & (n == 1))), "first": int(np.sum(r == 1)), "last": int(np.sum(r == n)),
            "intermediate": int(np.sum((r > 1) & (r < n)))}  # fmt: skip


def test_autzen_stats_are_laspys_numbers(autzen_path):
    """True bounds, each attribute's min/max/mean, the class histogram, returns, flight lines,
    gps_time and colours of autzen, as laspy reads them."""
    las = laspy.read(autzen_path)
    s = point_stats(autzen_path, chunk_size=7_000)  # (16 chunks: the running sums add up)
    xyz = np.column_stack([las.x, las.y, las.z])
    assert s["point_count"] == len(xyz) and s["invalid_points"] == 0
    assert s["bounds"] == {"min": xyz.min(axis=0).tolist(), "max": xyz.max(axis=0).tolist()}
    assert s["header_bounds_differ"] == []
    for name in ("intensity", "classification", "return_number", "number_of_returns", "point_source_id", "gps_time", "scan_angle_rank", "user_data"):
        v = np.asarray(las[name])
        assert s["attributes"][name]["min"] == v.min() and s["attributes"][name]["max"] == v.max(), name
        assert s["attributes"][name]["mean"] == pytest.approx(v.astype(np.float64).mean(), rel=1e-12), name
    codes, counts = np.unique(np.asarray(las.classification), return_counts=True)
    assert [(c["class"], c["name"], c["count"]) for c in s["classification"]] == [(int(c), class_name(int(c)), int(k)) for c, k in zip(codes, counts)]
    assert [c["name"] for c in s["classification"]] == ["unclassified", "ground"]
    assert [c["percent"] for c in s["classification"]] == pytest.approx((100 * counts / len(xyz)).tolist())
    assert {k: s["returns"][k] for k in ("single", "first", "last", "intermediate")} == expected_returns(las)
    pairs, n_pairs = np.unique(np.column_stack([las.return_number, las.number_of_returns]), axis=0, return_counts=True)
    assert [(p["return_number"], p["number_of_returns"], p["count"]) for p in s["returns"]["by_number"]] == [(*map(int, p), int(k)) for p, k in zip(pairs, n_pairs)]
    ids, per_id = np.unique(np.asarray(las.point_source_id), return_counts=True)
    assert s["point_source_ids"] == {"count": len(ids), "points": {str(i): int(k) for i, k in zip(ids, per_id)}}
    assert s["gps_time"] == {"min": las.gps_time.min(), "max": las.gps_time.max(), "kind": "seconds of a GPS week"}  # (global encoding 0)
    rgb = np.column_stack([las.red, las.green, las.blue])
    assert rgb.max() <= 255 and s["color"] == {"bits": 8, "min": rgb.min(axis=0).tolist(), "max": rgb.max(axis=0).tolist()}


def test_info_stats_prints_autzens_classes_returns_and_colours(cli, autzen_path):
    las = laspy.read(autzen_path)
    rc, out, err = cli("info", "--stats", autzen_path)
    assert rc == 0, err
    lines = out.splitlines()
    assert lines[0] == str(autzen_path)
    assert "  points:      110,000, 0 of them invalid (NaN, inf or beyond ±1e+12): skipped" in lines
    assert "  bounds min:  636001.76, 848935.20, 406.26 (the points'; the header's the same)" in lines
    n1, n2 = (int(np.sum(las.classification == c)) for c in (1, 2))
    words = [line.split() for line in lines]  # (the columns' widths aside)
    classes = words.index(["classes:", "1", "unclassified", f"{n1:,}", f"{100 * n1 / len(las):.2f}%"])
    assert words[classes + 1] == ["2", "ground", f"{n2:,}", f"{100 * n2 / len(las):.2f}%"]
    r = expected_returns(las)
    assert f"  returns:     single {r['single']:,}, first {r['first']:,}, last {r['last']:,}, intermediate {r['intermediate']:,}" in lines
    assert "  sources:     1 flight line (point_source_id 7326: 110,000)" in lines
    assert ["intensity", "0", f"{las.intensity.max()}", f"{las.intensity.mean():.10g}"] in words
    assert ["gps_time", f"{las.gps_time.min():.10g}", f"{las.gps_time.max():.10g}", f"{las.gps_time.mean():.10g}"] in words
    assert "  color:       red 40..236, green 55..228, blue 52..219 (8-bit values in 16-bit LAS fields)" in lines


def test_a_folder_of_two_tiles_is_summed_and_each_gives_one_object_a_file(cli, tmp_path):
    a = write_tile(tmp_path / "a.las", 300, 1, [2, 6])
    b = write_tile(tmp_path / "b.las", 200, 2, [2, 9, 19])
    both = [laspy.read(a), laspy.read(b)]
    rc, out, err = cli("info", "--stats", "--json", tmp_path)
    assert rc == 0, err
    [s] = map(json.loads, out.splitlines())  # one object: the folder summed
    classes = np.concatenate([np.asarray(t.classification) for t in both])
    assert s["path"] == str(tmp_path) and s["files"] == 2 and s["point_count"] == 500
    assert [(c["class"], c["name"], c["count"]) for c in s["classification"]] == [
        (2, "ground", int(np.sum(classes == 2))), (6, "building", int(np.sum(classes == 6))),
        (9, "water", int(np.sum(classes == 9))), (19, "overhead structure", int(np.sum(classes == 19)))]  # fmt: skip
    intensity = np.concatenate([np.asarray(t.intensity) for t in both])
    assert s["attributes"]["intensity"] == {"min": intensity.min(), "max": intensity.max(), "mean": pytest.approx(intensity.mean(), rel=1e-12)}
    xyz = np.concatenate([np.column_stack([t.x, t.y, t.z]) for t in both])
    assert s["bounds"] == {"min": xyz.min(axis=0).tolist(), "max": xyz.max(axis=0).tolist()}
    returns = [expected_returns(t) for t in both]
    assert {k: s["returns"][k] for k in returns[0]} == {k: returns[0][k] + returns[1][k] for k in returns[0]}
    ids = np.concatenate([np.asarray(t.point_source_id) for t in both])
    assert s["point_source_ids"] == {"count": 2, "points": {"11": int(np.sum(ids == 11)), "12": int(np.sum(ids == 12))}}
    assert s["color"]["bits"] == 16  # (values above 255: 16-bit colours, read >> 8)
    red8 = np.concatenate([np.asarray(t.red) >> 8 for t in both])
    assert (s["color"]["min"][0], s["color"]["max"][0]) == (red8.min(), red8.max())
    rc, out, err = cli("info", "--stats", "--json", "--each", tmp_path)
    each = [json.loads(line) for line in out.splitlines()]
    assert rc == 0 and [(e["path"], e["point_count"]) for e in each] == [(str(a), 300), (str(b), 200)]


def test_a_stale_header_is_reported_beside_the_points_true_bounds(cli, tmp_path):
    path = write_tile(tmp_path / "stale.las", 100, 3, [2])
    las = laspy.read(path)
    data = bytearray(path.read_bytes())
    true_max_x = float(las.x.max())
    struct.pack_into("<d", data, HEADER_MAX_X, true_max_x - 20)  # a writer that did not update it
    path.write_bytes(bytes(data))
    s = point_stats(path)
    assert s["header_bounds_differ"] == [str(path)]
    assert s["bounds"]["max"][0] == true_max_x and s["header_bounds"]["max"][0] == true_max_x - 20
    rc, out, err = cli("info", "--stats", path)
    assert rc == 0, err
    lines = out.splitlines()
    assert f"  bounds max:  {true_max_x:.2f}, {las.y.max():.2f}, {las.z.max():.2f}" in lines
    assert f"  header max:  {true_max_x - 20:.2f}, {las.y.max():.2f}, {las.z.max():.2f}" in lines
    assert "  stale:       the header's bounds are not its points' (stale.las)" in lines


def test_adjusted_standard_gps_time_is_shown_as_dates(tmp_path):
    """Global encoding bit 0: gps_time counts from the GPS epoch less 1e9 s (GPS second 1e9 was
    2011-09-14 01:46:40 GPS)."""
    path = write_tile(tmp_path / "adjusted.las", 50, 4, [2], adjusted_time=True)
    t = laspy.read(path).gps_time
    s = point_stats(path)["gps_time"]
    assert s["kind"] == "adjusted standard GPS time" and (s["min"], s["max"]) == (t.min(), t.max())
    assert s["first"] == f"2011-09-14 01:{46 + int(40 + t.min()) // 60:02d}:{int(40 + t.min()) % 60:02d}"


def test_invalid_points_are_counted_and_left_out(tmp_path):
    path = tmp_path / "points.xyz"
    path.write_text("1 2 3 10\nnan 5 6 20\n4 5 6 30\n")
    s = point_stats(path)
    assert (s["point_count"], s["invalid_points"]) == (3, 1)
    assert s["bounds"] == {"min": [1.0, 2.0, 3.0], "max": [4.0, 5.0, 6.0]} and s["color"] is None


def test_a_truncated_file_is_a_one_line_error(cli, tmp_path):
    path = write_tile(tmp_path / "cut.las", 200, 5, [2])
    path.write_bytes(path.read_bytes()[:-1000])
    with pytest.raises(InputError, match=f"^{path}: truncated LAS file"):
        point_stats(path)
    rc, out, err = cli("info", "--stats", path)
    assert rc != 0 and out == "" and len(err.strip().splitlines()) == 1 and err.startswith(f"error: {path}: truncated LAS file")


@pytest.mark.parametrize("filtered", [[], ["--classes", "2"]])
def test_the_progress_bar_counts_every_point_read(cli, autzen_path, monkeypatch, filtered):
    """Those a filter keeps too: the bar's total is the header's count, of every point read."""
    from gigapoint.cli import info_cmd

    seen = []

    def bar(description, total):
        seen.append(total)
        return info_cmd.contextlib.nullcontext(seen.append)

    monkeypatch.setattr(info_cmd, "progress_bar", bar)
    rc, out, err = cli("info", "--stats", *filtered, autzen_path)
    assert rc == 0 and seen[0] == 110_000 and seen[-1] == 110_000


def test_class_names_above_the_standard_ones():
    assert [class_name(c) for c in (0, 7, 18, 19, 22, 23, 63, 64, 255)] == [
        "created, never classified", "low point (noise)", "high noise", "overhead structure", "temporal exclusion", "reserved", "reserved",
        "user defined", "user defined"]  # fmt: skip


def test_point_stats_takes_a_list_of_paths_as_gp_open_does(autzen_path):
    """point_stats([a]) was pathlib's TypeError ("expected str, bytes or os.PathLike object, not list")."""
    assert point_stats([autzen_path]) == point_stats(autzen_path)
    assert point_stats((autzen_path,))["point_count"] == 110_000


def test_point_stats_names_itself_in_its_input_errors(autzen_path):
    """Its inputs' errors said "open: inputs[1]: ..." (point_files_of's default), not its own name."""
    with pytest.raises(InputError, match=r"^point_stats: inputs\[1\]: 5 is not a path \(a str or os\.PathLike\)$"):
        point_stats([autzen_path, 5])


@pytest.mark.parametrize("given", [None, 30_000])
def test_stats_read_chunks_of_the_stream_size_unless_told(autzen_path, monkeypatch, given):
    """``info --stats`` (file_stats) reads in chunks of STREAM_CHUNK_SIZE (its peak memory is a chunk
    or two: not DEFAULT_CHUNK_SIZE's 2 M points), or of the ``chunk_size`` given; each told to ``on_chunk``."""
    from gigapoint.io import file_stats
    from gigapoint.io._base import DEFAULT_CHUNK_SIZE, STREAM_CHUNK_SIZE
    from gigapoint.io.las import LasReader

    read, asked = LasReader.read_chunks, []

    def recorded(self, path, chunk_size, **kw):
        asked.append(chunk_size)
        return read(self, path, chunk_size, **kw)

    monkeypatch.setattr(LasReader, "read_chunks", recorded)
    sizes = []
    stats = file_stats(autzen_path, on_chunk=sizes.append) if given is None else file_stats(autzen_path, given, on_chunk=sizes.append)
    assert STREAM_CHUNK_SIZE < DEFAULT_CHUNK_SIZE
    assert asked == [given or STREAM_CHUNK_SIZE]
    assert sizes == ([110_000] if given is None else [30_000] * 3 + [20_000]) and stats.result()["point_count"] == 110_000


def in_polygon(xy: np.ndarray, ring: list) -> np.ndarray:
    """Brute force, point by point against every edge: even-odd crossings of a ray towards +x."""
    x, y = xy[:, 0], xy[:, 1]
    inside = np.zeros(len(xy), bool)
    for (x0, y0), (x1, y1) in zip(ring, ring[1:] + ring[:1]):
        crosses = (y0 > y) != (y1 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            at = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (x < at)
    return inside


#: a concave site boundary across autzen (feet), its corners off the points' 0.01 grid: no point on an edge
SITE = [(636150.005, 849000.003), (636900.007, 848980.001), (636700.003, 849250.009), (636450.001, 849150.007), (636300.009, 849420.005)]


def test_info_stats_of_class_2_are_laspys_ground_points(cli, autzen_path):
    """``--classes 2``: the ground's count and its true bounds (its height range), the filter and
    the points read and kept said in the text and in the JSON."""
    las = laspy.read(autzen_path)
    ground = np.asarray(las.classification) == 2
    xyz = np.column_stack([las.x, las.y, las.z])[ground]
    rc, out, err = cli("info", "--stats", "--json", "--classes", "2", autzen_path)
    assert rc == 0, err
    s = json.loads(out)
    assert s["point_count"] == int(ground.sum()) == 26_107
    assert s["filter"] == {"applied": "classes 2", "points_read": 110_000, "points_kept": 26_107}
    assert s["bounds"] == {"min": xyz.min(axis=0).tolist(), "max": xyz.max(axis=0).tolist()}
    assert s["header_bounds"] is None and s["header_bounds_differ"] == []  # (the header's are of every point: not compared)
    assert [(c["class"], c["count"]) for c in s["classification"]] == [(2, 26_107)]
    rc, out, err = cli("info", "--stats", "--classes", "2", autzen_path)
    assert rc == 0, err
    lines = out.splitlines()
    assert lines[1:4] == [
        "  filter:      classes 2: 26,107 of 110,000 points read kept",
        "  points:      26,107, 0 of them invalid (NaN, inf or beyond ±1e+12): skipped",
        f"  bounds min:  {xyz[:, 0].min():.2f}, {xyz[:, 1].min():.2f}, {xyz[:, 2].min():.2f} (the points')",
    ]
    assert point_stats(autzen_path, classes=2) == {**s, "path": str(autzen_path)}  # (Python's the same)
    rc, out, err = cli("info", "--stats", "--json", autzen_path)
    assert rc == 0 and json.loads(out)["filter"] is None


def test_info_stats_inside_a_site_boundary_count_the_points_in_it(cli, autzen_path, tmp_path):
    """``--clip-polygon site.geojson`` (and ``--classes 2``: the site's ground): the counts and
    bounds of a brute-force point-in-polygon test."""
    site = tmp_path / "site.geojson"
    ring = [list(p) for p in SITE]
    site.write_text(json.dumps({"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [[*ring, ring[0]]]}}))
    las = laspy.read(autzen_path)
    xyz = np.column_stack([las.x, las.y, las.z])
    inside = in_polygon(xyz, SITE)
    ground = inside & (np.asarray(las.classification) == 2)
    assert 0 < ground.sum() < inside.sum() < len(xyz)
    for extra, kept in (([], inside), (["--classes", "2"], ground)):
        rc, out, err = cli("info", "--stats", "--json", "--clip-polygon", site, *extra, autzen_path)
        assert rc == 0, err
        s = json.loads(out)
        assert s["point_count"] == s["filter"]["points_kept"] == int(kept.sum()) and s["filter"]["points_read"] == 110_000
        assert s["bounds"] == {"min": xyz[kept].min(axis=0).tolist(), "max": xyz[kept].max(axis=0).tolist()}
        described = f"clip polygon {site} (5 vertices)"
        assert s["filter"]["applied"] == ("classes 2; " + described if extra else described)


def test_the_filter_line_of_one_point_read_says_1_point(cli, tmp_path):
    """'1 of 1 point read kept', not '1 of 1 points read kept'."""
    one = write_tile(tmp_path / "one.las", 1, 1, [2])
    rc, out, err = cli("info", "--stats", "--classes", "2", one)
    assert rc == 0, err
    assert out.splitlines()[1] == "  filter:      classes 2: 1 of 1 point read kept"


def test_a_filter_without_stats_is_a_one_line_error(cli, autzen_path):
    """Without --stats info reads headers only: a filter would be ignored, without a word."""
    rc, out, err = cli("info", "--classes", "2", "--clip", "0,0,1,1", autzen_path)
    assert rc == 1 and out == ""
    assert err.strip().splitlines() == ["error: --classes and --clip: only with --stats (info reads the headers only; --stats reads the points, those the filter keeps)"]


def test_a_filter_that_keeps_nothing_is_its_own_error(cli, autzen_path, tmp_path):
    """No stats of no point: the filter's one-line error (a file, a folder summed; python's too)."""
    rc, out, err = cli("info", "--stats", "--classes", "9", autzen_path)
    assert rc == 1 and out == ""
    assert err.strip().splitlines() == [f"error: {autzen_path}: no point passes the filter (classes 9): 110,000 points read"]
    with pytest.raises(EmptyCloudError, match=r"no point passes the filter \(clip 0, 0, 1, 1\): 110,000 points read$"):
        point_stats(autzen_path, clip=(0, 0, 1, 1))
    write_tile(tmp_path / "a.las", 300, 1, [2, 6])
    write_tile(tmp_path / "b.las", 200, 2, [2, 9, 19])
    rc, out, err = cli("info", "--stats", "--classes", "7", tmp_path)
    assert rc == 1 and out == ""
    assert err.strip().splitlines() == [f"error: {tmp_path}: no point passes the filter (classes 7): 500 points read"]


def test_a_folders_tiles_are_filtered_each_and_summed(cli, tmp_path):
    """Summed: the tiles' kept points and points read; ``--each``: a tile none of whose points
    is kept shows its 0, the others theirs (no error: the filter kept points)."""
    a = write_tile(tmp_path / "a.las", 300, 1, [2, 6])
    b = write_tile(tmp_path / "b.las", 200, 2, [2, 9, 19])
    nine = int(np.sum(np.asarray(laspy.read(b).classification) == 9))
    rc, out, err = cli("info", "--stats", "--json", "--classes", "9", tmp_path)
    assert rc == 0, err
    s = json.loads(out)
    assert (s["files"], s["point_count"], s["filter"]) == (2, nine, {"applied": "classes 9", "points_read": 500, "points_kept": nine})
    rc, out, err = cli("info", "--stats", "--json", "--each", "--classes", "9", tmp_path)
    assert rc == 0, err
    each = [json.loads(line) for line in out.splitlines()]
    assert [(e["path"], e["point_count"], e["filter"]["points_read"], e["bounds"]) for e in each] == [(str(a), 0, 300, None), (str(b), nine, 200, each[1]["bounds"])]
    rc, out, err = cli("info", "--stats", "--each", "--classes", "7", tmp_path)  # (none kept anywhere: each shown, then the error)
    assert rc == 1 and out.count("  filter:      classes 7: 0 of ") == 2
    assert err.strip().splitlines() == [f"error: {tmp_path}: no point passes the filter (classes 7): 500 points read"]  # (the files as given)


@pytest.fixture(scope="module")
def autzen_octrees(autzen_path, tmp_path_factory):
    """autzen_trim.laz converted to a gigapoint octree and a Potree 2.0 one, of many nodes each."""
    folder = tmp_path_factory.mktemp("autzen_octrees")
    out = {"gigapoint": folder / "gigapoint", "potree": folder / "potree"}
    gp.convert([autzen_path], out["gigapoint"], max_leaf=4_000)
    gp.convert([autzen_path], out["potree"], max_leaf=4_000, format="potree")
    return out


def octree_step(octree: Path) -> float:
    """How far an octree's decoded positions may lie from its source's: a node's 30-bit grid, at
    worst the root cube's edge / 2**30 (1.1e-6 ft for autzen)."""
    return float(gp.open(octree).meta["cube_edge"]) / 2**30


#: a clip box across autzen's middle (feet): it misses some nodes
AUTZEN_CLIP = "636200,849000,636600,849300"


@pytest.mark.parametrize("kind", ["gigapoint", "potree"])
@pytest.mark.parametrize("filtered", [[], ["--classes", "2"], ["--clip", AUTZEN_CLIP]], ids=["all", "classes", "clip"])
def test_info_stats_of_an_octree_are_those_of_its_source_file(cli, autzen_path, autzen_octrees, kind, filtered):
    """Every point lives in one node: the octree's statistics, its nodes read one at a time, are
    the LAZ file's (counts, classes, returns, flight lines, colours and attribute ranges exactly,
    means to float sums' order); its positions to its 30-bit grid (bounds within a step). A clip
    box's missed nodes are not read; the filter keeps the same points."""
    octree = autzen_octrees[kind]
    runs = [cli("info", "--stats", "--json", *filtered, path) for path in (autzen_path, octree)]
    assert [rc for rc, _, _ in runs] == [0, 0], runs
    want, got = (json.loads(out) for _, out, _ in runs)
    assert got["path"] == str(octree) and got["point_count"] == want["point_count"] > 0 and got["invalid_points"] == 0
    for key in ("classification", "returns", "point_source_ids"):
        assert got[key] == want[key], key
    assert got["color"]["min"] == want["color"]["min"] and got["color"]["max"] == want["color"]["max"]
    assert got["attributes"].keys() == want["attributes"].keys()
    for name, a in want["attributes"].items():
        assert (got["attributes"][name]["min"], got["attributes"][name]["max"]) == (a["min"], a["max"]), name
        assert got["attributes"][name]["mean"] == pytest.approx(a["mean"], rel=1e-12), name
    for end in ("min", "max"):
        np.testing.assert_allclose(got["bounds"][end], want["bounds"][end], rtol=0, atol=octree_step(octree))
    assert got["header_bounds"] is None  # (an octree has no header: its metadata's bounds are not compared)
    if filtered:
        assert got["filter"]["applied"] == want["filter"]["applied"] and got["filter"]["points_kept"] == want["point_count"]
        read = got["filter"]["points_read"]
        assert read < 110_000 if filtered[0] == "--clip" else read == 110_000  # (the nodes the box misses: not read)


def test_info_stats_of_an_octree_count_its_nodes_points_on_the_bar(cli, autzen_octrees, monkeypatch):
    """The bar has no total (an octree's nodes are counted as they are read) and ends at every point."""
    from gigapoint.cli import info_cmd

    seen = []

    def bar(description, total):
        seen.append(total)
        return info_cmd.contextlib.nullcontext(seen.append)

    monkeypatch.setattr(info_cmd, "progress_bar", bar)
    rc, out, err = cli("info", "--stats", autzen_octrees["gigapoint"])
    assert rc == 0, err
    assert seen[0] is None and len(seen) > 2 and seen[-1] == 110_000
    assert out.splitlines()[1:3] == ["  points:      110,000, 0 of them invalid (NaN, inf or beyond ±1e+12): skipped", "  bounds min:  636001.76, 848935.20, 406.26 (the points')"]


@pytest.mark.parametrize("kind", ["gigapoint", "potree"])
def test_point_stats_of_an_octree_folder_names_what_gives_its_statistics(autzen_path, autzen_octrees, kind):
    """io reads point files; an octree's nodes are lod's to read (io cannot import lod). An
    octree folder was read as a folder of files ("crc.npy: NPY array: expected an (N, 3) ...
    array", "directory holds no supported point cloud file"): one line naming what reads it,
    alone or beside a file, and what it names gives its statistics."""
    from gigapoint.lod.query import octree_stats

    octree = autzen_octrees[kind]
    said = f"{octree}: an LOD octree; its statistics: gigapoint info --stats {octree} or gigapoint.lod.query.octree_stats"
    for paths in ([octree], [[autzen_path, str(octree)]]):
        with pytest.raises(InputError) as refused:
            point_stats(*paths)
        assert str(refused.value) == said
    assert octree_stats(octree).result()["point_count"] == 110_000


def test_info_stats_of_an_octree_no_node_of_which_meets_the_clip_box(cli, autzen_octrees):
    """No node read: the filter's one-line error, not statistics of no point."""
    octree = autzen_octrees["potree"]
    rc, out, err = cli("info", "--stats", "--clip", "0,0,1,1", octree)
    assert rc == 1 and out == ""
    assert err.strip().splitlines() == [f"error: {octree}: no point passes the filter (clip 0, 0, 1, 1): no node of the octree meets its region"]


def test_info_stats_of_an_ept_dataset_are_its_points(cli, tmp_path):
    """An EPT dataset's nodes (test_ept.py's), read one at a time: its points' counts, classes
    and ranges, of every point and of class 2."""
    from test_ept import make_scene, write_ept

    scene = make_scene(n=3_000)
    ept = write_ept(tmp_path / "ept", scene, "laszip")
    classes, intensity = scene["attrs"]["classification"], scene["attrs"]["intensity"]
    for filtered, kept in (([], np.ones(len(classes), bool)), (["--classes", "2"], classes == 2)):
        rc, out, err = cli("info", "--stats", "--json", *filtered, ept)
        assert rc == 0, err
        s = json.loads(out)
        assert s["point_count"] == int(kept.sum()) > 0
        assert [(c["class"], c["count"]) for c in s["classification"]] == [(int(c), int(n)) for c, n in zip(*np.unique(classes[kept], return_counts=True))]
        i = intensity[kept]
        assert s["attributes"]["intensity"]["min"] == i.min() and s["attributes"]["intensity"]["max"] == i.max()
        assert s["attributes"]["intensity"]["mean"] == pytest.approx(i.mean(), rel=1e-12)
        xyz = scene["xyz"][kept]
        np.testing.assert_allclose(s["bounds"]["min"], xyz.min(axis=0), rtol=0, atol=scene["edge"] / 2**30 + 1e-6)
        np.testing.assert_allclose(s["bounds"]["max"], xyz.max(axis=0), rtol=0, atol=scene["edge"] / 2**30 + 1e-6)


def test_info_stats_of_an_octree_over_http_is_refused(cli):
    """Every node would be downloaded: one line, before any is (no server here)."""
    url = "http://127.0.0.1:9/scan.copc.laz"
    rc, out, err = cli("info", "--stats", url)
    assert rc == 1 and out == ""
    assert err.strip().splitlines() == [f"error: {url}: an octree over HTTP; --stats reads local octrees and point files"]


def test_info_stats_of_a_local_copc_file_reads_it_as_the_laz_file_it_is(cli, autzen_path, tmp_path):
    """A COPC file is a LAZ 1.4 file whose points are each stored once: its points are read as
    laspy reads them (the classes filter too), its header's bounds compared. Without --stats it is
    still shown as the octree it is."""
    copc = tmp_path / "x.copc.laz"
    assert cli("convert", autzen_path, "-o", copc)[0] == 0
    las = laspy.read(copc)
    xyz = np.column_stack([las.x, las.y, las.z])
    rc, out, err = cli("info", "--stats", "--json", copc)
    assert rc == 0, err
    [s] = map(json.loads, out.splitlines())
    assert s["path"] == str(copc) and s["point_count"] == len(xyz) == 110_000 and s["invalid_points"] == 0
    assert s["bounds"] == {"min": xyz.min(axis=0).tolist(), "max": xyz.max(axis=0).tolist()}
    rc, out, err = cli("info", "--stats", "--json", "--classes", "2", copc)
    assert rc == 0, err
    assert json.loads(out)["point_count"] == int(np.sum(np.asarray(las.classification) == 2))
    rc, out, err = cli("info", copc)
    assert rc == 0 and "  format:      COPC 1.4, point format 7" in out.splitlines(), err


def test_info_stats_of_an_unfinished_conversion_is_refused(cli, tmp_path, stop_conversion_after):
    """Its preview holds a sample of the points, not each once: one line saying what to do."""
    octree = tmp_path / "octree"
    stop_conversion_after(1)
    with pytest.raises(KeyboardInterrupt):
        gp.convert([write_tile(tmp_path / "a.las", 3_000, 1, [2, 6])], octree, max_leaf=300, partition_points=1_000)
    rc, out, err = cli("info", "--stats", octree)
    assert rc == 1 and out == ""
    assert err.strip().splitlines()[-1] == f"error: {octree}: an unfinished conversion; its preview holds a sample of the points: read the point files, or finish the conversion first"
