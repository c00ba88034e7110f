"""Compact octree payloads (format version 2, lod/compact_octree.py): exact round trips, the
previous format still read, renders equal to the three-word layout, corrupt files named."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gigapoint import Camera, RenderSettings, render_frame
from gigapoint.core import PointChunk
from gigapoint.core.attributes import Attributes
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.errors import InputError
from gigapoint.lod import ConvertError, OctreeCloud, OctreeDir, convert, open_octree
from gigapoint.lod.compact_octree import CompactOctree, from_keys, pack_field, to_keys
from gigapoint.lod.reader import octree_info
from gigapoint.lod.store import ARENA_CHUNK, Arena

AUTZEN = Path(__file__).parents[2] / ".." / "shared" / "data" / "autzen_trim.laz"
laspy = pytest.importorskip("laspy")


def _write_las(path: Path, n: int, scale: float, offset, seed: int = 0) -> Path:
    """A LAS file of n points on a ``scale`` grid at UTM-sized ``offset``, dense in a few
    spots and spread over 2 km (nodes of every size), with RGB, intensity, classification."""
    rng = np.random.default_rng(seed)
    centres = rng.random((6, 3)) * [2000, 1500, 80]
    xyz = centres[rng.integers(0, 6, n)] + rng.normal(0, 30, (n, 3)) * rng.random((n, 1))
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [scale] * 3
    header.offsets = list(offset)
    las = laspy.LasData(header)
    las.x, las.y, las.z = (xyz[:, a] + offset[a] for a in range(3))
    las.red, las.green, las.blue = (rng.integers(0, 256, n).astype(np.uint16) * 257 for _ in range(3))
    las.intensity = rng.integers(0, 4000, n).astype(np.uint16)
    las.classification = rng.integers(0, 8, n).astype(np.uint8)
    las.write(str(path))
    return path


def _source_grid(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    with laspy.open(str(path)) as f:
        las = f.read()
        return np.stack([np.asarray(las.X), np.asarray(las.Y), np.asarray(las.Z)], 1).astype(np.int64), f.header.scales, f.header.offsets


def _decoded_grid(oc, scale, offset) -> np.ndarray:
    """Every decoded point as integer steps of the source grid, asserting each is the source's
    value (q * scale + offset, as laspy reads it) to float64 rounding: 4 units in the last place
    of the octree's largest coordinate (per axis).
    The 30-bit decoder's half cell added to a grid-aligned node's words put them scale * 2^(B - 31)
    past it (6.1e-7 ft in autzen's nodes, 2^17 steps wide)."""
    out = []
    big = np.abs(np.asarray(oc.bounds)).max(axis=0).clip(1.0)  # (a value near 0 holds the rounding of the grid's origin)
    for i in range(len(oc.keys)):
        xyz = oc.node_points(i)["xyz"]
        q = np.round((xyz - np.asarray(offset)) / np.asarray(scale))
        want = q * np.asarray(scale) + np.asarray(offset)
        ulps = np.abs(xyz - want) / np.spacing(big)
        assert ulps.max() <= 4, (i, np.abs(xyz - want).max(axis=0))
        out.append(q.astype(np.int64))
    return np.concatenate(out)


def _sorted_rows(a: np.ndarray) -> np.ndarray:
    return a[np.lexsort(a.T[::-1])]


@pytest.fixture(scope="module")
def las_pair(tmp_path_factory):
    """A LAS file at UTM offsets converted in both formats (several partitions, groups)."""
    base = tmp_path_factory.mktemp("cmp")
    src = _write_las(base / "utm.las", 60_000, 0.01, (500_000.0, 4_800_000.0, 100.0))
    opts = {"max_leaf": 2_000, "partition_points": 20_000}
    convert([src], base / "v2", **opts)
    convert([src], base / "v1", layout="words", **opts)
    return src, base / "v1", base / "v2"


@pytest.mark.parametrize("scale,offset", [(0.01, (500_000.0, 4_800_000.0, 100.0)), (0.001, (-73.0, 10.0, 0.5)), (0.25, (0.0, 0.0, 0.0))])
def test_every_point_exact_at_the_source_scale(tmp_path, scale, offset):
    src = _write_las(tmp_path / "in.las", 20_000, scale, offset, seed=int(scale * 1000))
    convert([src], tmp_path / "oct", max_leaf=1_000, partition_points=8_000)
    oc = open_octree(tmp_path / "oct")
    assert isinstance(oc, CompactOctree) and oc.meta["version"] == 2 and oc.meta["scale"] == [scale] * 3
    grid, scales, offsets = _source_grid(src)
    np.testing.assert_array_equal(_sorted_rows(_decoded_grid(oc, scales, offsets)), _sorted_rows(grid))


def test_autzen_every_point_exact_and_half_the_bytes(tmp_path):
    if not AUTZEN.exists():
        pytest.skip("shared sample autzen_trim.laz not present")
    convert([AUTZEN], tmp_path / "v2")
    convert([AUTZEN], tmp_path / "v1", layout="words")
    oc = open_octree(tmp_path / "v2")
    grid, scales, offsets = _source_grid(AUTZEN)
    np.testing.assert_array_equal(_sorted_rows(_decoded_grid(oc, scales, offsets)), _sorted_rows(grid))
    size = {v: sum(f.stat().st_size for f in (tmp_path / v).iterdir()) for v in ("v1", "v2")}
    assert size["v1"] >= 2 * size["v2"], size


def test_colors_and_attributes_are_the_previous_formats(las_pair):
    """Same nodes, same points in each node, colours and attributes bit for bit; positions
    within version 1's 30-bit cell."""
    _, p1, p2 = las_pair
    a, b = open_octree(p1), open_octree(p2)
    assert type(a) is OctreeCloud and a.meta["version"] == 1 and isinstance(b, CompactOctree)
    np.testing.assert_array_equal(a.keys, b.keys)
    np.testing.assert_array_equal(a.nodes["count"], b.nodes["count"])
    np.testing.assert_array_equal(a.nodes["first"], b.nodes["first"])
    for k in ("color", "rgba"):
        np.testing.assert_array_equal(np.asarray(a.arrays[k]), b.arrays[k], err_msg=k)
    assert set(a.attributes) == set(b.attributes) >= {"intensity", "classification", "gps_time"}
    for k in a.attributes:
        np.testing.assert_array_equal(np.asarray(a.attributes[k]), b.attributes[k], err_msg=k)
        assert b.attributes[k].dtype == a.attributes[k].dtype
    for i in range(len(a.keys)):
        pa, pb = a.node_points(i), b.node_points(i)
        size = a.nodes["bbox_max"][i] - a.nodes["bbox_min"][i]
        assert np.all(np.abs(pa["xyz"] - pb["xyz"]) <= size / 2**30 + 1e-6)
        # the node's arrays as the arena gets them equal the whole-file decoding
        arrays, attrs, first = b.node_arrays(i)
        s = slice(int(b.nodes["first"][i]), int(b.nodes["first"][i] + b.nodes["count"][i]))
        for k in ("low", "med", "high", "color", "rgba"):
            np.testing.assert_array_equal(arrays[k], b.arrays[k][s])
    info = octree_info(p2)
    assert info["format"] == "gigapoint octree 2" and info["point_count"] == 60_000
    assert octree_info(p1)["format"] == "gigapoint octree 1"

    def on_disk(path) -> dict:
        text = octree_info(path)["details"]["on disk"].split(" bytes")[0]
        return {k: float(v) for k, v in (part.split() for part in text.split(", "))}

    old, new = on_disk(p1), on_disk(p2)
    assert old["positions"] == pytest.approx(12.0, abs=0.02) and old["colour"] == pytest.approx(8.0, abs=0.02)
    assert 4.0 < new["positions"] < 7.0 and new["colour"] < 6.0 and new["attributes"] < old["attributes"] / 2


def _twin(oc: CompactOctree) -> OctreeCloud:
    """The same octree in the three-word layout (same boxes), as version 1 holds it."""
    arrays = {k: np.array(oc.arrays[k]) for k in ("low", "med", "high", "color", "rgba")}
    return OctreeCloud(oc.name, oc.meta, oc.nodes.copy(), oc.keys, arrays, {a: np.array(v) for a, v in oc.attributes.items()})


CAMS = [
    lambda b: Camera.fit(b, view="iso", width=320, height=240),
    lambda b: Camera.fit(b, view="top", width=300, height=300),
]


@pytest.mark.parametrize("budget", [10**9, 15_000])
@pytest.mark.parametrize("make_camera", CAMS)
def test_renders_equal_the_three_word_layout(las_pair, make_camera, budget):
    """Nodes decoded into the arena draw exactly as the same boxes in three words do (the LOD
    selection, the budget and the adaptive precision included), and within a pixel of the
    version 1 conversion (its tight boxes quantize differently)."""
    _, p1, p2 = las_pair
    oc = open_octree(p2)
    cam = make_camera(oc.bounds)
    settings = RenderSettings(backend="cpu", size_mode="fixed", point_budget=budget)
    mine = render_frame(oc, cam, settings)
    twin = render_frame(_twin(oc), cam, settings)
    assert (~mine.empty).sum() > 1000
    np.testing.assert_array_equal(mine.image, twin.image)
    np.testing.assert_array_equal(mine.depth, twin.depth)
    old = render_frame(open_octree(p1), cam, settings)
    assert mine.stats.points_processed == old.stats.points_processed
    assert (mine.empty != old.empty).mean() < 0.002
    assert np.all(mine.image == old.image, axis=2).mean() > 0.99


@pytest.fixture(scope="module")
def rgb565_octree(las_pair, tmp_path_factory):
    src, _, _ = las_pair
    out = tmp_path_factory.mktemp("c16") / "oct"
    convert([src], out, max_leaf=2_000, partition_points=20_000, colors="rgb565")
    return out


@pytest.mark.parametrize("colors", ["rgba", "rgb565"])
def test_the_compact_arena_draws_as_the_three_word_arena(las_pair, rgb565_octree, colors):
    """A format-2 octree's arena holds nodes as stored (low word, extension bits, colours in the
    octree's format): through loads, evictions and refilled slots, every frame (with HQS, an
    elevation ramp) and picked point equals the three-word arena's, the same nodes drawn."""
    oc = open_octree(las_pair[2] if colors == "rgba" else rgb565_octree)
    compact = oc.new_arena(20_000)  # too small for every view: nodes evicted, slots reused
    words = Arena(compact.n_points, oc.name, oc.bounds, oc._attribute_dtypes())
    words.source_scale = compact.source_scale  # (new_arena's: point_info rounds to the octree's source grid)
    assert compact.med is None and words.med is not None
    assert compact.color.dtype == (np.uint16 if colors == "rgb565" else np.uint32)
    s = RenderSettings(backend="cpu", size_mode="fixed", point_budget=12_000, lod_threshold_px=10.0)
    cams = [make(oc.bounds) for make in CAMS]
    cams.append(Camera.look_at(oc.bounds[0] + [300, 200, 40], oc.bounds[0] + [900, 700, 0], width=320, height=240))
    for cam, extra in zip(cams * 2, [{}, {"hqs": True}, {"color_mode": "elevation"}] * 2, strict=True):
        frames = []
        for arena in (compact, words):
            oc.arena = arena
            frames.append(render_frame(oc, cam, s.replace(**extra)))
            assert oc.arena is arena
        a, b = frames
        assert (~a.empty).sum() > 500
        np.testing.assert_array_equal(a.visibility, b.visibility)
        np.testing.assert_array_equal(a.image, b.image)
        hit = int(np.flatnonzero(a.visibility.reshape(-1) != EMPTY_PIXEL)[0])
        index = int(a.visibility.reshape(-1)[hit] & np.uint64(0xFFFFFFFF))
        got, want = compact.point_info(index), words.point_info(index)
        # the three-word arena decodes the same words as floor-quantized ones (half a 30-bit cell
        # past: 1.2e-6 in a 2^18-step node, over 1e-4 of a step, so shown to 6 decimals); the
        # compact arena's are the LAS file's values (on main both were 501906.940001)
        assert got.pop("position") == [round(v, 2) for v in want.pop("position")]
        assert got == want
    assert compact.loads > len(compact.resident) and list(compact.resident) == list(words.resident)


def test_the_compact_arena_takes_fewer_bytes_a_point(las_pair, rgb565_octree):
    """Positions in 4 bytes and the widest node's extension bits (each slot's room), colours in
    4 or 2 bytes: 10.6 and 8.6 bytes a point here (nodes up to 21 extension bits) against the
    three-word arena's 16."""
    for path, color_bytes in ((las_pair[2], 4), (rgb565_octree, 2)):
        oc = open_octree(path)
        compact = oc.new_arena(50_000)
        words = Arena(compact.n_points, oc.name, oc.bounds)
        compact.attributes = Attributes()  # attributes: test_the_arena_holds_attributes_in_their_range
        room = compact.room * 8 / ARENA_CHUNK
        assert int(oc.ext_bits.max()) < 24 and room == pytest.approx(oc.ext_bits.max() / 8, abs=0.01)
        assert compact.nbytes / compact.n_points == pytest.approx(4 + color_bytes + room)
        assert words.nbytes / words.n_points == 16
        assert compact.nbytes / compact.n_points < 11


def test_the_arena_holds_attributes_in_their_range(tmp_path):
    """A format-2 arena holds integer attributes as ``value - min`` in the narrowest dtype of the
    octree's range (from the fields' records), a constant one as nothing: the values of every
    resident node read back exactly, and attribute colour modes draw as the full-width arena's."""
    rng = np.random.default_rng(11)
    n = 40_000
    xyz = np.array([500_000.0, 4_800_000.0, 100.0]) + rng.integers(0, 150_000, (n, 3)) * [0.01, 0.01, 0.001]
    rgba = np.full((n, 4), 255, np.uint8)
    attrs = {
        "intensity": rng.integers(1000, 1100, n).astype(np.uint16),  # u8 + 1000
        "classification": rng.integers(2, 7, n).astype(np.uint8),  # u8 already
        "depth": rng.integers(-70_000, -50_000, n).astype(np.int32),  # u16 - 70 000 (the bound: up to twice the range)
        "point_source_id": np.full(n, 7326, np.uint16),  # constant: nothing held
        "gps_time": 245_000.0 + rng.random(n),  # float: full width
    }
    chunks = [PointChunk(xyz[s : s + 10_000], rgba[s : s + 10_000], {k: v[s : s + 10_000] for k, v in attrs.items()}, scale=(0.01, 0.01, 0.001))
              for s in range(0, n, 10_000)]  # fmt: skip
    convert(chunks, tmp_path / "oct", max_leaf=2_000, partition_points=15_000)
    oc = open_octree(tmp_path / "oct")
    ranges = oc.attribute_ranges()
    assert ranges["point_source_id"] == (7326, 7326) and "gps_time" not in ranges
    for a, (lo, hi) in ranges.items():
        values = oc.decode_all(a)
        assert lo <= int(values.min()) and int(values.max()) <= hi, a
    # room for every node: neither arena is replaced, so each frame is drawn from the one set here
    compact = oc.new_arena(oc.n_points + len(oc.nodes) * ARENA_CHUNK)
    words = Arena(compact.n_points, oc.name, oc.bounds, oc._attribute_dtypes())
    words.source_scale = compact.source_scale  # (new_arena's: point_info rounds to the octree's source grid)
    held = {a: compact.attributes.held_dtype(a) for a in compact.attributes}
    assert held["intensity"] == "uint16 in uint8 + 1000" and held["point_source_id"] == "uint16 constant 7326"
    assert held["depth"].startswith("int32 in uint16 - ") and held["gps_time"] == "float64"
    assert compact.attributes.nbytes < words.attributes.nbytes
    s = RenderSettings(backend="cpu", size_mode="fixed", point_budget=12_000, lod_threshold_px=10.0)
    for make in CAMS:
        cam = make(oc.bounds)
        for mode in ("intensity", "classification"):
            frames = []
            for arena in (compact, words):
                oc.arena = arena
                frames.append(render_frame(oc, cam, s.replace(color_mode=mode)))
                assert oc.arena is arena
            np.testing.assert_array_equal(frames[0].image, frames[1].image)
        for nd, slots in compact.resident.items():
            count = int(oc.nodes["count"][nd])
            _, attrs = oc.node_payload(nd)
            for a in compact.attributes:
                got = np.concatenate([compact.attributes[a][sl * ARENA_CHUNK : sl * ARENA_CHUNK + ARENA_CHUNK] for sl in slots])[:count]
                assert got.dtype == attrs[a].dtype
                np.testing.assert_array_equal(got, attrs[a], err_msg=a)


def test_the_points_an_arenas_batches_hold_all_or_an_even_sample():
    """held_points: every point the batches hold (slots' empty tails and empty slots left out),
    or an even sample of them without an index of every point (the automatic colour range's)."""
    from gigapoint.core.layout import BATCH_DTYPE
    from gigapoint.core.renderable import held_points

    rng = np.random.default_rng(0)
    batches = np.zeros(500, BATCH_DTYPE)
    batches["first"] = rng.permutation(500) * 1000  # slots in any order, some empty, some partly filled
    batches["count"] = rng.integers(0, 1000, 500) * (rng.random(500) < 0.8)
    held = np.concatenate([np.arange(f, f + c) for f, c in zip(batches["first"], batches["count"], strict=True)])
    assert np.array_equal(held_points(batches), held)
    assert np.array_equal(held_points(batches, most=1000), held[:: len(held) // 1000])
    assert np.array_equal(held_points(batches, most=len(held)), held)
    assert held_points(batches[:0]).size == 0 and held_points(batches[:0], most=10).size == 0


def test_the_automatic_intensity_range_is_the_points_held(tmp_path):
    """Colour by intensity without ``intensity_range``: the range is the 2nd..98th percentile of
    the points the arena's nodes hold, not of its every slot (the slots no node fills read 0 in
    the words arena, the range's low end in the compact one: 0..1098 washed the grey out, and
    the layouts' frames differed), the same frames in either layout."""
    rng = np.random.default_rng(4)
    n = 40_000
    xyz = np.array([500_000.0, 4_800_000.0, 100.0]) + rng.integers(0, 150_000, (n, 3)) * [0.01, 0.01, 0.001]
    rgba = np.full((n, 4), 255, np.uint8)
    intensity = rng.integers(1000, 1101, n).astype(np.uint16)
    chunks = [PointChunk(xyz[s : s + 10_000], rgba[s : s + 10_000], {"intensity": intensity[s : s + 10_000]}, scale=(0.01, 0.01, 0.001))
              for s in range(0, n, 10_000)]  # fmt: skip
    convert(chunks, tmp_path / "oct", max_leaf=2_000, partition_points=15_000)
    oc = open_octree(tmp_path / "oct")
    assert isinstance(oc, CompactOctree)
    compact = oc.new_arena(oc.n_points + len(oc.nodes) * ARENA_CHUNK)  # room for every node: each frame draws the arena set here
    words = Arena(compact.n_points, oc.name, oc.bounds, oc._attribute_dtypes())
    words.source_scale = compact.source_scale
    s = RenderSettings(backend="cpu", size_mode="fixed", color_mode="intensity", point_budget=10**9, lod_threshold_px=0.0)
    cam = Camera.fit(oc.bounds, view="top", width=300, height=300)
    lo, hi = np.percentile(oc.decode_all("intensity").astype(np.float64), [2.0, 98.0])
    assert 1000 <= lo <= 1004 and 1096 <= hi <= 1100
    frames = []
    for arena in (compact, words):
        oc.arena = arena
        f = render_frame(oc, cam, s)
        assert oc.arena is arena and len(arena.resident) == int((oc.counts > 0).sum())  # every node held: the range is all points'
        np.testing.assert_array_equal(f.image, render_frame(oc, cam, s.replace(intensity_range=(float(lo), float(hi)))).image)
        grey = f.image[f.visibility != EMPTY_PIXEL][:, 0]
        assert grey.min() == 0 and grey.max() == 255  # (the words arena's 0..1098 drew every grey 232 or more)
        frames.append(f.image)
    np.testing.assert_array_equal(frames[0], frames[1])


def test_without_a_source_grid_the_words_are_the_previous_formats(tmp_path):
    """Float inputs (no scale): every node is wide, i.e. version 1's tight box and 30-bit words,
    so the images are the previous format's bit for bit."""
    rng = np.random.default_rng(5)
    xyz = rng.random((30_000, 3)) * [300, 200, 20]
    rgba = rng.integers(0, 256, (30_000, 4), dtype=np.uint8)
    rgba[:, 3] = 255
    chunks = [
        PointChunk(xyz[s : s + 10_000], rgba[s : s + 10_000], {"intensity": np.arange(s, s + 10_000, dtype=np.int32) - 5})
        for s in range(0, 30_000, 10_000)
    ]
    convert(chunks, tmp_path / "v2", max_leaf=1_000)
    convert(chunks, tmp_path / "v1", max_leaf=1_000, layout="words")
    a, b = open_octree(tmp_path / "v1"), open_octree(tmp_path / "v2")
    assert b.meta["scale"] is None
    np.testing.assert_array_equal(a.nodes, b.nodes)
    for k in ("low", "med", "high", "color", "rgba"):
        np.testing.assert_array_equal(np.asarray(a.arrays[k]), b.arrays[k], err_msg=k)
    np.testing.assert_array_equal(np.asarray(a.attributes["intensity"]), b.attributes["intensity"])
    cam = Camera.fit(a.bounds, view="iso", width=320, height=240)
    for budget in (10**9, 8_000):
        s = RenderSettings(backend="cpu", size_mode="fixed", point_budget=budget)
        np.testing.assert_array_equal(render_frame(a, cam, s).image, render_frame(b, cam, s).image)


def test_16_bit_colors_on_request(las_pair, tmp_path):
    src, p1, p2 = las_pair
    convert([src], tmp_path / "c16", max_leaf=2_000, partition_points=20_000, colors="rgb565")
    a, b = open_octree(p2), open_octree(tmp_path / "c16")
    assert b.meta["colors"] == "rgb565" and b.meta["field_dtypes"]["rgba"] == "<u2"
    for k in ("rgba", "color"):
        diff = np.abs(a.arrays[k].view(np.uint8).astype(int) - b.arrays[k].view(np.uint8).astype(int))
        assert diff.max() <= 4, k
    size = {p: sum(f.stat().st_size for f in Path(p).iterdir()) for p in (p2, tmp_path / "c16")}
    assert size[tmp_path / "c16"] < size[p2]


def test_options_are_checked(tmp_path):
    chunks = [PointChunk(np.zeros((10, 3)))]
    with pytest.raises(ConvertError, match="^layout: unknown layout 'bits'; choose compact or words$"):
        convert(chunks, tmp_path / "a", layout="bits")
    with pytest.raises(ConvertError, match="^colors: unknown colour format 'rgb332'; choose rgba or rgb565$"):
        convert(chunks, tmp_path / "b", colors="rgb332")


@pytest.mark.parametrize("dtype", ["u1", "<u2", "<u4", "<u8", "i1", "<i2", "<i4", "<i8", "<f4", "<f8", "?"])
def test_fields_pack_every_dtype_losslessly(dtype):
    rng = np.random.default_rng(1)
    dt = np.dtype(dtype)
    if dt.kind == "f":
        v = rng.normal(0, 1e6, 5_000).astype(dt)
        v[:3] = [np.nan, -np.inf, -0.0]
    elif dt.kind == "b":
        v = rng.random(5_000) < 0.3
    else:
        info = np.iinfo(dt)
        v = rng.integers(info.min, info.max, 5_000, dtype=dt, endpoint=True)
        v[100:300] = 7  # a constant node: 0 bits
    counts = np.array([0, 1, 99, 200, 700, 4_000], np.int64)
    firsts = np.cumsum(counts) - counts
    rec, stream = pack_field(v, firsts, counts)
    assert rec["bits"][0] == 0 and rec["bits"][1] == 0  # empty and one-point nodes hold no bits
    from gigapoint.lod.compact_octree import _field_read_all

    out = np.zeros(len(v), np.uint64)
    _field_read_all(stream, firsts, counts, rec["word0"].copy(), rec["bits"].astype(np.uint64), rec["base"].copy(), out)
    back = from_keys(out, dt)
    np.testing.assert_array_equal(back.view(f"u{dt.itemsize}"), v.view(f"u{dt.itemsize}"))
    np.testing.assert_array_equal(from_keys(to_keys(v), dt).view(f"u{dt.itemsize}"), v.view(f"u{dt.itemsize}"))


# --------------------------------------------------------------------------- corrupt files


@pytest.fixture
def damaged(las_pair, tmp_path):
    """A fresh copy of the version 2 octree to damage."""
    import shutil

    _, _, p2 = las_pair
    shutil.copytree(p2, tmp_path / "oct")
    return OctreeDir(tmp_path / "oct")


def _truncate(path: Path, keep: int) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:keep])


def _shorter_stream(path: Path) -> None:
    a = np.load(path)
    np.save(path, a[: len(a) - 5])


def _fewer_records(path: Path) -> None:
    a = np.load(path)
    np.save(path, a[:-1])


def _garbled_header(path: Path) -> None:
    """Bytes 10-16 of the NPY header (its dict) garbled: numpy's parse raised tokenize's TokenError."""
    data = path.read_bytes()
    path.write_bytes(data[:10] + b"garbage" + data[17:])


def _wrong_count(d: OctreeDir) -> None:
    meta = json.loads(d.meta.read_text())
    meta["points"] += 1
    d.meta.write_text(json.dumps(meta))


def _bad_code(path: Path) -> None:
    a = np.load(path)
    a["code"][0] = 33
    np.save(path, a)


DAMAGE = {
    "truncated low": ("low", lambda d: _truncate(d.array("low"), 1000), "low.npy"),
    "truncated ext": ("ext", lambda d: _truncate(d.array("ext"), 500), "ext.npy"),
    "short ext stream": ("ext", lambda d: _shorter_stream(d.array("ext")), "ext.npy"),
    "short colour stream": ("rgba", lambda d: _shorter_stream(d.array("field.rgba")), "field.rgba.npy"),
    "short attribute stream": ("intensity", lambda d: _shorter_stream(d.array("field.attr.intensity")), "field.attr.intensity.npy"),
    "pack records missing": ("pack", lambda d: _fewer_records(d.array("pack")), "pack.npy"),
    "field records missing": ("fields", lambda d: _fewer_records(d.array("fields")), "fields.npy"),
    "point count mismatch": ("count", _wrong_count, "nodes.npy"),
    "bad layout code": ("code", lambda d: _bad_code(d.array("pack")), "pack.npy"),
    "missing stream": ("missing", lambda d: d.array("field.color").unlink(), "field.color.npy"),
    "checksums missing": ("crc", lambda d: _fewer_records(d.array("crc")), "crc.npy"),
    "garbled attribute header": ("header", lambda d: _garbled_header(d.array("field.attr.intensity")), "field.attr.intensity.npy"),
    "garbled nodes header": ("header", lambda d: _garbled_header(d.array("nodes")), "nodes.npy"),
}


@pytest.mark.parametrize("case", list(DAMAGE))
def test_corrupt_payloads_are_one_line_errors_naming_the_file(damaged, case):
    _, damage, name = DAMAGE[case]
    damage(damaged)
    with pytest.raises(InputError) as err:
        open_octree(damaged.path)
    msg = str(err.value)
    assert "\n" not in msg and name in msg, msg


@pytest.mark.parametrize("name", ["nodes", "med", "attr.intensity"])
def test_a_version_1_folders_garbled_array_is_one_line_naming_it(las_pair, tmp_path, name):
    """The words layout's arrays (version 1): a garbled NPY header was tokenize's TokenError."""
    import shutil

    _, p1, _ = las_pair
    d = OctreeDir(shutil.copytree(p1, tmp_path / "v1"))
    _garbled_header(d.array(name))
    with pytest.raises(InputError) as err:
        open_octree(d.path)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith(f"{d.array(name)}: cannot read it"), msg


def _bounds_far_off(meta: dict) -> None:
    meta["bounds"]["min"][1] = -1e308


@pytest.mark.parametrize(
    "change, problem",
    [  # found by a fuzzer: each was a traceback (numpy's dtype TypeError, a NaN camera)
        (lambda m: m["field_dtypes"].update({"attr.intensity": "u0"}), r"field 'attr.intensity' has dtype 'u0', not a number type"),
        (lambda m: m["field_dtypes"].update({"color": "<f8"}), r"field 'color' has dtype '<f8', not an unsigned integer type"),
        (lambda m: m.update(attributes=5), r"invalid metadata \(attributes is not \{name: dtype\}: 5\)"),
        (_bounds_far_off, r"corrupt metadata \(bounds, cube\): the points' bounds .* lie outside the octree's cube"),
    ],
)
def test_metadata_that_does_not_describe_the_arrays_is_refused_at_open(damaged, change, problem):
    meta = json.loads(damaged.meta.read_text())
    change(meta)
    damaged.meta.write_text(json.dumps(meta))
    with pytest.raises(InputError, match=problem) as err:
        open_octree(damaged.path)
    assert "\n" not in str(err.value) and str(damaged.meta) in str(err.value)


def _flip_in_node(d: OctreeDir, name: str) -> int:
    """Flip one bit inside a node's part of array ``name`` (a node that holds bits there);
    returns the node."""
    oc = open_octree(d.path)
    counts = oc.counts
    if name == "low":
        node, word, size = int(np.argmax(counts)), int(oc.nodes["first"][np.argmax(counts)]) + 7, 4
    elif name == "ext":  # the first word of a stream of more than 64 bits: bits 8-15 are the node's
        node = int(np.flatnonzero(oc.ext_bits * counts > 64)[-1])
        word, size = int(oc.pack["ext_first"][node]), 8
    else:
        rec = oc.fields[:, oc.field_index[name.removeprefix("field.")]]
        node = int(np.flatnonzero(rec["bits"].astype(np.int64) * counts > 64)[0])
        word, size = int(rec["word0"][node]), 8
    path = d.array(name)
    at = np.load(path, mmap_mode="r").offset + word * size + 1
    data = bytearray(path.read_bytes())
    data[at] ^= 0x04
    path.write_bytes(bytes(data))
    return node


@pytest.mark.parametrize("name", ["low", "ext", "field.rgba", "field.color", "field.attr.intensity"])
def test_a_flipped_byte_in_a_payload_is_a_one_line_error(damaged, name):
    """Per node and array a CRC-32 (crc.npy) is checked when the node is first loaded: a
    flipped bit is an error naming the file and the node, not points silently elsewhere."""
    node = _flip_in_node(damaged, name)
    oc = open_octree(damaged.path)  # opens: the records still add up
    cam = Camera.fit(oc.bounds, view="iso", width=200, height=150)
    with pytest.raises(InputError) as err:
        render_frame(oc, cam, RenderSettings(backend="cpu", point_budget=10**9, lod_threshold_px=0.0))
    msg = str(err.value)
    assert "\n" not in msg and f"{name}.npy" in msg and f"(#{node})" in msg and "checksum" in msg, msg
    with pytest.raises(InputError, match=f"#{node}"):
        oc.node_points(node)


def test_octrees_without_checksums_are_read_unchecked(damaged):
    """Octrees written before crc.npy existed open and draw as before (nothing to check)."""
    _flip_in_node(damaged, "field.rgba")
    damaged.array("crc").unlink()
    oc = open_octree(damaged.path)
    assert oc.crc is None
    frame = render_frame(oc, Camera.fit(oc.bounds, view="iso", width=200, height=150), RenderSettings(backend="cpu"))
    assert (~frame.empty).sum() > 500


def test_checksums_are_each_nodes_crc32_of_its_record_and_slices(las_pair):
    """crc.npy, written for all the nodes at once (compact_octree.checksum_table), holds per node
    the zlib CRC-32 of each array's slice, seeded with the CRC of the node's record: computed
    here node by node from the files, and for any range of rows the same."""
    import zlib

    from gigapoint.lod.compact_octree import checksum_table, stream_words

    oc = open_octree(las_pair[2])
    streams = [oc.streams[k] for k in oc.meta["fields"]]
    assert len(oc.nodes) > 20 and len(streams) >= 3
    want = []
    for i, rec in enumerate(oc.nodes):
        first, count = int(rec["first"]), int(rec["count"])
        w0 = int(oc.pack["ext_first"][i])
        row = [
            zlib.crc32(oc.low[first : first + count], zlib.crc32(oc.nodes[i : i + 1].tobytes())),
            zlib.crc32(oc.ext[w0 : w0 + int(stream_words(oc.ext_bits[i], count))], zlib.crc32(oc.pack[i : i + 1].tobytes())),
        ]
        for j, stream in enumerate(streams):
            f = oc.fields[i, j]
            words = int(stream_words(np.int64(f["bits"]), count))
            row.append(zlib.crc32(stream[int(f["word0"]) : int(f["word0"]) + words], zlib.crc32(oc.fields[i, j : j + 1].tobytes())))
        want.append(row)
    want = np.array(want, np.uint32)
    np.testing.assert_array_equal(oc.crc, want)
    args = (oc.nodes, oc.low, oc.ext, oc.pack, oc.ext_bits, oc.fields, streams)
    np.testing.assert_array_equal(checksum_table(*args, 5, 17), want[5:17])


def test_a_too_small_arena_of_the_other_layout_set_by_hand_is_replaced_and_its_nodes_loaded_again(autzen_path, tmp_path):
    """A words arena set on a compact octree, too small for the frame's selection: the grown
    arena (compact) cannot take its slots over (a TypeError before: its med words are None), so
    it loads the nodes again, and the frame is the one of an octree left to its own arena."""
    convert([autzen_path], tmp_path / "oct", max_leaf=2000, progress=False)
    settings = RenderSettings(backend="cpu", size_mode="fixed", point_budget=50_000)
    own = open_octree(tmp_path / "oct")
    cam = Camera.fit(own.bounds, view="top", width=200, height=200)
    expected = render_frame(own, cam, settings)
    oc = open_octree(tmp_path / "oct")
    oc.arena = Arena(5_000, oc.name, oc.bounds, oc._attribute_dtypes())  # words, a tenth of the selection
    got = render_frame(oc, cam, settings)
    assert oc.arena.med is None and oc.arena.n_points > 5_000  # grown, in the octree's own layout
    assert np.array_equal(got.image, expected.image)
    assert np.array_equal(got.visibility >> 32, expected.visibility >> 32)  # the depths (the indices are slots: they differ)
    assert (got.visibility != EMPTY_PIXEL).sum() > 3_000 and got.stats.points_processed > 5_000  # (more than the hand-set arena held)
