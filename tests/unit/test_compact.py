"""The compact layout (core/compact.py): exact at the source's scale, renders identical to the
three-word layout of the same boxes, the wider paths, and the memory it reports."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import gigapoint as gp
from gigapoint import Camera, RenderSettings
from gigapoint.core import PointChunk, build_cloud
from gigapoint.core.compact import (
    expand_tails,
    ext_bits_per_point,
    pack_code,
    read_ext,
    stream_words,
    tail_words,
    wide_batches,
)
from gigapoint.errors import InputError
from gigapoint.render.reference import reference_image, reference_visibility

AUTZEN = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "autzen_trim.laz"
UTM = np.array([636_000.0, 5_012_000.0, 120.0])


def grid_cloud(rng, n, scale, extent, origin=UTM, batch_size=1024, layout="compact"):
    """n points on a grid of step ``scale`` (per axis) over ``extent`` metres, far from the origin."""
    scale = np.asarray(scale, np.float64)
    steps = np.maximum((np.asarray(extent) / scale).astype(np.int64), 1)
    q = rng.integers(0, steps, (n, 3))
    xyz = origin + q * scale
    rgba = rng.integers(0, 256, (n, 4), dtype=np.uint8)
    rgba[:, 3] = 255
    chunk = PointChunk(xyz, rgba, {"intensity": rng.integers(0, 65535, n).astype(np.uint16)}, scale=tuple(scale.tolist()))
    return build_cloud([chunk], name="grid", batch_size=batch_size, layout=layout), xyz


def assert_exact(cloud, xyz, scale):
    """Every point decodes to a source point at the source's scale (same multiset of grid points),
    its very value to float64 rounding (``assert_source_values``)."""
    scale = np.asarray(scale, np.float64)
    pos = cloud.positions()
    got = np.round((pos - UTM) / scale).astype(np.int64)
    want = np.round((xyz - UTM) / scale).astype(np.int64)
    np.testing.assert_array_equal(got[np.lexsort(got.T)], want[np.lexsort(want.T)])
    assert_source_values(pos[np.lexsort(got.T)], xyz[np.lexsort(want.T)])


def assert_source_values(got, want):
    """Decoded positions equal the source's (rows matched) to float64 rounding: 4 units in the last
    place of the largest value of each axis. Decoding a grid-aligned batch's words with 0.5 added as for floor-quantized
    ones put every point scale * 2^(B - 31) past it (3e-7 ft on autzen, 2.5e-3 at 2^29 steps)."""
    err = np.abs(got - want)
    ulps = err / np.spacing(np.abs(want).max(axis=0).clip(1.0))  # (near 0 a value holds the rounding of the cloud's size)
    assert ulps.max() <= 4, (err.max(axis=0), ulps.max())


@pytest.mark.parametrize("scale", [(0.01, 0.01, 0.01), (0.001, 0.001, 0.001), (0.25, 0.25, 0.1), (0.01, 0.02, 0.005)])
def test_round_trip_exact_at_the_source_scale(rng, scale):
    cloud, xyz = grid_cloud(rng, 20_000, scale, (300.0, 200.0, 40.0))
    assert cloud.layout == "compact"
    assert_exact(cloud, xyz, scale)
    assert not wide_batches(cloud.packing).any()
    # bounds are the points' own, not the grid-aligned boxes
    np.testing.assert_allclose(cloud.bounds[0], xyz.min(axis=0))
    np.testing.assert_allclose(cloud.bounds[1], xyz.max(axis=0))


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    scale=st.sampled_from([1e-4, 0.001, 0.005, 0.01, 0.25, 1.0]),
    steps=st.tuples(st.integers(1, 2**22), st.integers(1, 2**22), st.integers(1, 2**16)),
    n=st.integers(1, 3000),
    batch=st.sampled_from([1, 7, 256, 1000, 10_240]),
    far=st.booleans(),
)
def test_round_trip_property(seed, scale, steps, n, batch, far):
    """Any grid, extent (1 to 4 M steps an axis), count and batch size: every point exact."""
    r = np.random.default_rng(seed)
    q = r.integers(0, steps, (n, 3))
    origin = UTM if far else np.zeros(3)
    xyz = origin + q * scale
    cloud = build_cloud([PointChunk(xyz, None, {}, scale=(scale,) * 3)], batch_size=batch, layout="compact")
    got = np.round((cloud.positions() - origin) / scale).astype(np.int64)
    np.testing.assert_array_equal(got[np.lexsort(got.T)], q[np.lexsort(q.T)])
    assert not wide_batches(cloud.packing).any()


def test_ten_bit_batches_hold_four_bytes_a_point(rng):
    # 1024 points in a batch whose extent is < 1024 steps on every axis: the low word only
    cloud, xyz = grid_cloud(rng, 8 * 1024, (0.01,) * 3, (10.0, 10.0, 5.0), batch_size=1024)
    assert (ext_bits_per_point(cloud.packing, cloud.batches["count"]) == 0).all()
    assert cloud.ext.nbytes == 0
    assert cloud.memory()["positions"] == 4 * cloud.n_points
    assert_exact(cloud, xyz, (0.01,) * 3)


def test_wider_batches_take_the_extension_and_stay_exact(rng):
    # extents of ~2^14 steps in x: 4 extension bits on that axis
    cloud, xyz = grid_cloud(rng, 4096, (0.01,) * 3, (160.0, 5.0, 5.0), batch_size=4096)
    code = int(cloud.packing["code"][0])
    assert code & 0xFF == 4 and (code >> 8) & 0xFF == 0 and (code >> 16) & 0xFF == 0
    assert_exact(cloud, xyz, (0.01,) * 3)


# fields of 0, 1, 9, 13, 25 and 19 bits (one u32 load: ONE_LOAD_BITS), 26, 57 and 60 (a wide batch:
# two u64 loads); every axis e <= 9 (the high word is 0) but (10, 0, 9) and the widest three
@pytest.mark.parametrize(
    "widths", [(0, 0, 0), (1, 0, 0), (3, 3, 3), (4, 4, 5), (8, 8, 9), (10, 0, 9), (9, 8, 9), (19, 19, 19), (20, 20, 20)]
)
def test_expand_tails_decodes_every_field_as_tail_words_does(rng, widths):
    # expand_tails reads fields of up to ONE_LOAD_BITS with one unaligned u32 load, wider ones
    # with read_ext's two u64 loads: both against the one-point decoder at every bit offset,
    # from a stream between two others, whole and strided
    code = np.uint32(pack_code(*widths))
    t = sum(widths)
    n = 4099  # a stream that ends inside a word
    words = int(stream_words(np.array([t]), np.array([n]))[0])
    before = 3
    ext = np.frombuffer(rng.bytes(8 * (before + words + 2)), np.uint64).copy()
    for start, step in ((0, 1), (5, 1), (1, 3), (0, 7)):
        count = (n - start + step - 1) // step
        med, high = np.empty(count, np.uint32), np.empty(count, np.uint32)
        expand_tails(ext, np.int64(before), code, np.int64(start), count, np.int64(step), med, high, np.empty(count, np.uint64))
        want = np.array([tail_words(np.uint64(read_ext(ext, before, t, start + j * step)), code) for j in range(count)], np.uint32)
        np.testing.assert_array_equal(med, want[:, 0])
        np.testing.assert_array_equal(high, want[:, 1])
        if t:  # the fields differ: a read at a wrong offset would show
            assert len(np.unique(want[:, 0])) > 1


def test_off_grid_and_huge_batches_are_stored_wide(rng):
    # a batch whose points are off the declared grid (another file's offset) keeps 30 bits
    xyz = UTM + rng.uniform(0, 50, (3000, 3))
    chunk = PointChunk(xyz, None, {}, scale=(0.01, 0.01, 0.01))
    cloud = build_cloud([chunk], batch_size=1000, layout="compact")
    assert wide_batches(cloud.packing).all()
    words = gp.core.cloud_from_points(xyz, chunk.rgba, batch_size=1000)
    np.testing.assert_array_equal(cloud.positions(), words.positions())  # today's 30-bit words exactly
    # a batch spanning more than 2^29 steps (0.1 mm over 100 km) is wide too, the rest compact
    q = np.concatenate([rng.integers(0, 1000, (1000, 3)), [[6 * 10**8, 0, 0], [12 * 10**8, 5, 5]]])
    pts = UTM + q * 1e-4
    cloud = build_cloud([PointChunk(pts, None, {}, scale=(1e-4,) * 3)], batch_size=1000, layout="compact")
    wide = wide_batches(cloud.packing)
    assert wide.any() and not wide.all()
    from scipy.spatial import cKDTree

    # matched by distance, not by sorting: a z exact in a compact batch and 0.1 mm off in the wide
    # one sort two points of one z (the source's) in either order
    dist, idx = cKDTree(cloud.positions()).query(pts, k=1)
    assert dist.max() <= 1e-3 and len(np.unique(idx)) == len(pts)  # 30 bits of 100 km: 0.1 mm


@pytest.mark.parametrize("step", [1e4, 1e9])
def test_a_step_far_wider_than_the_points_spread_does_not_move_them(rng, step):
    """Points a metre apart given a 10 km (or 10^9 m) grid were all within GRID_TOLERANCE of one
    grid node: stored on it, and drawn up to a metre (476 m at 10^9) from where they are."""
    xyz = UTM + rng.uniform(0, 1, (3000, 3))
    cloud = build_cloud([PointChunk(xyz, None, {}, scale=(step,) * 3)], batch_size=1000, layout="compact")
    assert wide_batches(cloud.packing).all()  # off the grid: 30 bits a batch
    words = gp.core.cloud_from_points(xyz, cloud.rgba, batch_size=1000)
    np.testing.assert_array_equal(cloud.positions(), words.positions())
    arrays = gp.from_arrays(xyz, scale=step)
    back = arrays.positions()
    np.testing.assert_allclose(back[np.lexsort(back.T)], xyz[np.lexsort(xyz.T)], rtol=0, atol=1e-6)


def test_autzen_is_compact_and_exact():
    if not AUTZEN.exists():
        pytest.skip("shared sample missing")
    laspy = pytest.importorskip("laspy")
    cloud = gp.open(AUTZEN)
    assert cloud.layout == "compact"
    las = laspy.read(str(AUTZEN))
    scale, offset = np.asarray(las.header.scales), np.asarray(las.header.offsets)
    src = np.stack([las.X, las.Y, las.Z], axis=1).astype(np.int64)
    pos = cloud.positions()
    got = np.round((pos - offset) / scale).astype(np.int64)
    np.testing.assert_array_equal(got[np.lexsort(got.T)], src[np.lexsort(src.T)])
    # laspy's scaled values themselves (not only on their grid): 3.05e-7 ft off before (B = 16 batches)
    assert_source_values(pos[np.lexsort(got.T)], np.stack([las.x, las.y, las.z], axis=1)[np.lexsort(src.T)])
    mem = cloud.memory()
    assert mem["positions"] < 6.5 * cloud.n_points  # 12 bytes a point in three words
    assert cloud.nbytes == sum(mem.values())
    info = cloud.point_info(0)
    assert all(round(v, 2) == v for v in info["position"])


@pytest.mark.parametrize("steps", [10**7, 2**29 + 12_345])
def test_wide_grid_batches_decode_to_the_las_values(tmp_path, steps):
    """A LAS file whose batches span 2^24 and 2^29 steps (B = 24, 29: the widest compact batch):
    ``positions`` and ``point_info`` give laspy's x, y, z. Decoded with the 30-bit words' 0.5 they
    were scale * 2^(B - 31) above them: 7.8e-5 and 2.5e-3 (a quarter of a step)."""
    laspy = pytest.importorskip("laspy")
    r = np.random.default_rng(steps)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = [0.01] * 3, [500_000.0, 4_000_000.0, 0.0]
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = r.integers(0, steps, 3000), r.integers(0, steps, 3000), r.integers(0, 2**20, 3000)
    path = tmp_path / "wide.las"
    las.write(str(path))
    las = laspy.read(str(path))
    cloud = gp.open(path)
    assert cloud.layout == "compact" and not wide_batches(cloud.packing).any()
    assert (cloud.packing["code"] & 0xFF).max() == {10**7: 14, 2**29 + 12_345: 19}[steps]
    src = np.stack([las.X, las.Y, las.Z], axis=1).astype(np.int64)
    pos = cloud.positions()
    got = np.round((pos - header.offsets) / 0.01).astype(np.int64)
    assert_source_values(pos[np.lexsort(got.T)], np.stack([las.x, las.y, las.z], axis=1)[np.lexsort(src.T)])
    i = int(np.argmax(pos[:, 0]))
    assert cloud.point_info(i)["position"] == pos[i].round(2).tolist()


@pytest.mark.parametrize("steps", [2**30 - 100, 2**31 - 10])
def test_batches_over_2_to_29_steps_are_within_half_a_30_bit_cell(rng, steps):
    """Wide batches (B > 29) hold 30 bits of their tight box: half a cell is under half a step up
    to 2^30 steps (rounding gives the grid back: 0.4999 steps measured), a step at 2^31 (0.998)."""
    q = np.concatenate([[[0, 0, 0], [steps, steps, 5]], rng.integers(0, steps, (2000, 3))])
    xyz = np.array([500_000.0, 4_000_000.0, 0.0]) + q * 0.01
    cloud = build_cloud([PointChunk(xyz, None, {}, scale=(0.01,) * 3)], batch_size=10_240, layout="compact")
    assert wide_batches(cloud.packing).all()
    from scipy.spatial import cKDTree

    got = cloud.positions()
    half_cell = (xyz.max(axis=0) - xyz.min(axis=0)) / 2**31
    dist, idx = cKDTree(got / half_cell).query(xyz / half_cell, k=1, p=np.inf)  # in half cells, per axis
    assert dist.max() <= 1 + 1e-6 and len(np.unique(idx)) == len(xyz)
    assert (dist.max() * half_cell[0] < 0.005) == (steps < 2**30)  # under half a step: rounding gives the grid back
    if steps < 2**30:
        k = np.round((got - [500_000.0, 4_000_000.0, 0.0]) / 0.01).astype(np.int64)
        np.testing.assert_array_equal(k[np.lexsort(k.T)], q[np.lexsort(q.T)])


def test_layout_choice_and_errors(rng):
    xyz = UTM + rng.uniform(0, 10, (100, 3))
    assert build_cloud([PointChunk(xyz, None, {})]).layout == "words"  # no scale: today's layout
    with pytest.raises(InputError, match="compact layout needs"):
        build_cloud([PointChunk(xyz, None, {})], layout="compact")
    with pytest.raises(InputError, match="layout must be one of"):
        build_cloud([PointChunk(xyz, None, {})], layout="tiny")
    scaled = PointChunk(np.round(xyz, 2), None, {}, scale=(0.01,) * 3)
    assert build_cloud([scaled]).layout == "compact"
    assert build_cloud([scaled], layout="words").layout == "words"
    words = build_cloud([scaled], layout="words")
    assert words.memory()["positions"] == 12 * 100


def test_from_arrays_with_a_scale(rng):
    xyz = UTM + rng.integers(0, 5000, (3000, 3)) * 0.005
    cloud = gp.from_arrays(xyz, scale=0.005, intensity=np.arange(3000, dtype=np.uint16))
    assert cloud.layout == "compact" and cloud.source_scale == (0.005, 0.005, 0.005)
    assert_exact(cloud, xyz, (0.005,) * 3)
    assert gp.from_arrays(xyz).layout == "words"
    assert gp.from_arrays(xyz, scale=(0.005, 0.005, 0.001)).layout == "compact"
    for bad in (0.0, -1, (0.01, 0.01), "x", float("nan")):
        with pytest.raises(InputError, match="scale must be"):
            gp.from_arrays(xyz, scale=bad)


# --- rendering -------------------------------------------------------------------------------
CAMS = {
    "iso": lambda b: Camera.fit(b, view="iso", width=160, height=120),
    "close": lambda b: Camera.look_at(b[0] + (b[1] - b[0]) * [0.5, -0.2, 2.0], (b[0] + b[1]) / 2, width=160, height=120),
    "ortho": lambda b: Camera.fit(b, view="top", width=120, height=120, projection="orthographic"),
}


@pytest.fixture(scope="module")
def scene():
    rng = np.random.default_rng(7)
    cloud, _ = grid_cloud(rng, 30_000, (0.01, 0.01, 0.005), (80.0, 60.0, 20.0), batch_size=2048)
    return cloud


@pytest.mark.parametrize("view", list(CAMS))
@pytest.mark.parametrize("threshold", [1e9, 40.0, 0.5])  # 10, mixed, 20/30-bit batches
def test_renders_equal_the_three_word_layout(scene, view, threshold):
    cam = CAMS[view](scene.bounds)
    settings = RenderSettings(size_mode="fixed", backend="cpu", precision_threshold_px=threshold)
    a = gp.render_frame(scene, cam, settings)
    b = gp.render_frame(scene.expanded(), cam, settings)
    np.testing.assert_array_equal(a.visibility, b.visibility)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.visibility, reference_visibility(scene, cam, settings))
    np.testing.assert_array_equal(a.image, reference_image(scene, cam, settings))
    assert (a.visibility != np.iinfo(np.uint64).max).sum() > 500


@pytest.mark.parametrize("max_points", [7_000, 0])
def test_subsample_and_splats_equal_the_three_word_layout(scene, max_points):
    cam = CAMS["close"](scene.bounds)
    settings = RenderSettings(size_mode="fixed", backend="cpu", precision_threshold_px=0.5, max_points=max_points, point_size=3.0)
    a = gp.render_frame(scene, cam, settings)
    b = gp.render_frame(scene.expanded(), cam, settings)
    np.testing.assert_array_equal(a.visibility, b.visibility)


def test_stereo_equals_the_three_word_layout(scene):
    cam = CAMS["close"](scene.bounds)
    settings = RenderSettings(size_mode="fixed", backend="cpu", precision_threshold_px=0.5, stereo="side-by-side")
    np.testing.assert_array_equal(gp.render_frame(scene, cam, settings).image, gp.render_frame(scene.expanded(), cam, settings).image)


def test_expanded_twin_has_the_same_boxes(scene):
    twin = scene.expanded()
    assert twin.layout == "words"
    np.testing.assert_array_equal(twin.batches, scene.batches)
    # the same words: the twin's positions (floor-quantized words: + half a 30-bit cell) lie half
    # a 30-bit cell of each batch past the compact cloud's source values, no further
    size = np.repeat(scene.batches["bbox_max"] - scene.batches["bbox_min"], scene.batches["count"].astype(np.int64), axis=0)
    diff = twin.positions() - scene.positions()
    np.testing.assert_allclose(diff, size / 2**31, rtol=0, atol=1e-9)
    assert twin.memory()["positions"] == 12 * scene.n_points > 2 * scene.memory()["positions"]


@pytest.mark.parametrize(
    "kw",
    [
        {"hqs": True},
        {"color_mode": "elevation"},
        {"edl": True, "fill_holes": 1},
        {"point_size": 3, "point_shape": "round", "hqs": True},
        {"opacity": 0.5},
    ],
)
def test_passes_equal_the_three_word_layout(scene, kw):
    cam = CAMS["close"](scene.bounds)
    settings = RenderSettings(size_mode="fixed", backend="cpu", precision_threshold_px=40.0, **kw)
    np.testing.assert_array_equal(gp.render_frame(scene, cam, settings).image, gp.render_frame(scene.expanded(), cam, settings).image)


def test_framing_is_the_same(scene):
    a, b = Camera.fit_cloud(scene, width=200, height=100), Camera.fit_cloud(scene.expanded(), width=200, height=100)
    np.testing.assert_allclose(a.eye, b.eye)
    np.testing.assert_allclose(a.target, b.target)


# --- colors ----------------------------------------------------------------------------------
def test_colors_in_16_bits_within_4_levels(rng):
    cloud, _ = grid_cloud(rng, 5000, (0.01,) * 3, (20.0, 20.0, 5.0))  # random colours: "auto" keeps RGB565
    assert cloud.color.dtype == np.uint16 and cloud.memory()["color"] == 2 * cloud.n_points
    exact = build_cloud([PointChunk(cloud.positions(), cloud.rgba, {}, scale=(0.01,) * 3)], colors="rgba")
    assert exact.color.dtype == np.uint32
    # every 8-bit value through 5/6/5 bits and back: the rounding's bound (4 red/blue, 2 green)
    levels = np.arange(256, dtype=np.uint8)
    rgba = np.stack([levels, levels, levels, np.full(256, 255, np.uint8)], axis=1)
    c = build_cloud([PointChunk(UTM + np.arange(256)[:, None] * 0.01, rgba, {}, scale=(0.01,) * 3)], colors="rgb565")
    back = c.rgba[np.argsort(c.positions()[:, 0])].astype(int)
    err = np.abs(back - rgba.astype(int)).max(axis=0)
    assert err.tolist() == [4, 2, 4, 0]
    assert back[0, :3].tolist() == [0, 0, 0] and back[-1, :3].tolist() == [255, 255, 255]  # black and white exact
    info = c.point_info(0)
    assert info["rgba"] == c.rgba[0].tolist()


@pytest.mark.parametrize("n", [1001, 1000])
def test_resolve_of_16_bit_colors_any_length(rng, n):
    from gigapoint.core.compact import pack_rgb565, rgb565_words

    cloud, _ = grid_cloud(rng, n, (0.01,) * 3, (30.0, 30.0, 5.0), batch_size=256)
    assert cloud.color.dtype == np.uint16 and len(cloud.color) == n
    words = rgb565_words(cloud.color)
    assert np.shares_memory(words, cloud.color)  # no copy a frame
    halves = words.view(np.uint16)[:n]
    np.testing.assert_array_equal(halves, cloud.color)
    loose = pack_rgb565(rgba32_of(cloud))[: n - 1].copy()  # an array not from pack_rgb565: padded copy
    np.testing.assert_array_equal(rgb565_words(loose).view(np.uint16)[: n - 1], loose)
    cam = CAMS["iso"](cloud.bounds)
    s = RenderSettings(size_mode="fixed", backend="cpu")
    a, b = gp.render_frame(cloud, cam, s), gp.render_frame(cloud.expanded(), cam, s)
    np.testing.assert_array_equal(a.image, b.image)
    np.testing.assert_array_equal(a.image, reference_image(cloud, cam, s))
    assert a.stats.visible_pixels > 100


def rgba32_of(cloud):
    return cloud.rgba.view(np.uint32).reshape(-1)


def test_translucent_colors_stay_32_bit(rng):
    xyz = UTM + np.round(rng.uniform(0, 10, (100, 3)), 2)
    rgba = np.full((100, 4), 200, np.uint8)
    cloud = build_cloud([PointChunk(xyz, rgba, {}, scale=(0.01,) * 3)])
    assert cloud.layout == "compact" and cloud.color.dtype == np.uint32
    np.testing.assert_array_equal(cloud.rgba, rgba)
    with pytest.raises(InputError, match="not opaque"):
        build_cloud([PointChunk(xyz, rgba, {}, scale=(0.01,) * 3)], colors="rgb565")
    with pytest.raises(InputError, match="colors must be one of"):
        build_cloud([PointChunk(xyz, rgba, {}, scale=(0.01,) * 3)], colors="rgb8")


# --- the GPU (lavapipe in CI) ----------------------------------------------------------------
@pytest.mark.gpu
@pytest.mark.parametrize("threshold", [1e9, 40.0, 0.5])
def test_wgpu_agrees_with_cpu(scene, threshold):
    from gigapoint.backends.wgpu import WgpuBackend
    from gigapoint.errors import BackendUnavailableError

    try:
        WgpuBackend()
    except BackendUnavailableError as exc:
        pytest.skip(f"no wgpu adapter: {exc}")
    for make_camera in CAMS.values():
        cam = make_camera(scene.bounds)
        cpu = gp.render_frame(scene, cam, RenderSettings(size_mode="fixed", backend="cpu", precision_threshold_px=threshold))
        gpu = gp.render_frame(scene, cam, RenderSettings(size_mode="fixed", backend="wgpu", precision_threshold_px=threshold))
        np.testing.assert_array_equal(gpu.visibility, cpu.visibility)
        np.testing.assert_array_equal(gpu.image, cpu.image)


@pytest.mark.gpu
def test_wgpu_passes_agree_with_cpu(scene):
    from gigapoint.backends.wgpu import WgpuBackend
    from gigapoint.errors import BackendUnavailableError

    try:
        WgpuBackend()
    except BackendUnavailableError as exc:
        pytest.skip(f"no wgpu adapter: {exc}")
    cam = CAMS["close"](scene.bounds)
    for kw in ({"hqs": True}, {"point_size": 2, "stereo": "side-by-side"}):
        cpu = gp.render_frame(scene, cam, RenderSettings(size_mode="fixed", backend="cpu", precision_threshold_px=40.0, **kw))
        gpu = gp.render_frame(scene, cam, RenderSettings(size_mode="fixed", backend="wgpu", precision_threshold_px=40.0, **kw))
        np.testing.assert_array_equal(gpu.image, cpu.image)


# --- memory you can see ----------------------------------------------------------------------
def test_cli_prints_bytes_a_point(tmp_path, capsys):
    if not AUTZEN.exists():
        pytest.skip("shared sample missing")
    from gigapoint.cli import main

    cloud = gp.open(AUTZEN)
    mem = cloud.memory()
    assert main(["info", "--memory", str(AUTZEN)]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("memory:"))
    assert f"positions {mem['positions'] / cloud.n_points:.2f}" in line and f"color {mem['color'] / cloud.n_points:.2f}" in line and "compact layout" in line
    assert f"{sum(mem.values()) / cloud.n_points:.2f} bytes/point" in line
    assert main(["info", "--memory", "--json", str(AUTZEN)]) == 0
    import json

    rows = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    assert rows[-1]["memory"] == mem and rows[-1]["layout"] == "compact"
    out_png = tmp_path / "a.png"
    assert main(["render", str(AUTZEN), "-o", str(out_png), "-W", "64", "-H", "48", "--backend", "cpu", "--stats"]) == 0
    err = capsys.readouterr().err
    assert "memory:" in err and "bytes/point" in err and "peak RSS" in err


@pytest.mark.gpu
def test_wgpu_wide_and_ten_bit_batches_agree_with_cpu(rng):
    from gigapoint.backends.wgpu import WgpuBackend
    from gigapoint.errors import BackendUnavailableError

    try:
        WgpuBackend()
    except BackendUnavailableError as exc:
        pytest.skip(f"no wgpu adapter: {exc}")
    off_grid = build_cloud(
        [PointChunk(UTM + rng.uniform(0, 50, (3000, 3)), None, {}, scale=(0.01,) * 3)], batch_size=1000, layout="compact"
    )
    assert wide_batches(off_grid.packing).all()
    ten_bit, _ = grid_cloud(rng, 4096, (0.01,) * 3, (8.0, 8.0, 3.0), batch_size=1024)
    assert ten_bit.ext.nbytes == 0
    for cloud in (off_grid, ten_bit):
        for threshold in (1e9, 0.5):
            cam = CAMS["close"](cloud.bounds)
            cpu = gp.render_frame(cloud, cam, RenderSettings(size_mode="fixed", backend="cpu", precision_threshold_px=threshold))
            gpu = gp.render_frame(cloud, cam, RenderSettings(size_mode="fixed", backend="wgpu", precision_threshold_px=threshold))
            np.testing.assert_array_equal(gpu.visibility, cpu.visibility)
            np.testing.assert_array_equal(gpu.image, cpu.image)
            assert cpu.stats.visible_pixels > 50


@pytest.mark.gpu
def test_wgpu_pages_of_compact_batches(scene):
    """Pages of 2 batches (page_bytes of 4, halved for the streams), a budget that evicts, ragged
    batches (1001 points: streams not starting on page words), odd colour pages."""
    from gigapoint.backends.numba_cpu import NumbaCpuBackend
    from gigapoint.backends.wgpu import WgpuBackend
    from gigapoint.core.selection import select
    from gigapoint.errors import BackendUnavailableError

    rng = np.random.default_rng(3)
    ragged, _ = grid_cloud(rng, 15_015, (0.01, 0.01, 0.005), (60.0, 40.0, 10.0), batch_size=1001)
    cpu = NumbaCpuBackend()
    for cloud, batch in ((scene, 2048), (ragged, 1001)):
        try:
            page = 4 * batch * 4 + 16
            paged = WgpuBackend(page_bytes=page, memory_budget=max(1 << 16, 3 * page))
        except BackendUnavailableError as exc:
            pytest.skip(f"no wgpu adapter: {exc}")
        assert paged.ctx.plan(cloud).n_pages >= 4
        for threshold in (1e9, 40.0, 0.5):
            cam = CAMS["close"](cloud.bounds)
            near, far = cam.clip_range(cloud.bounds)
            sel = select(cloud.batches, cam.screen_rows(), cam.width, cam.height, near, far, threshold, True, True)
            args = (cam.width, cam.height, near, far)
            want = cpu.rasterize(cloud, sel, *args)
            np.testing.assert_array_equal(np.asarray(paged.rasterize(cloud, sel, *args)), want)
            bg = (10, 20, 30, 255)
            np.testing.assert_array_equal(np.asarray(paged.resolve(want, cloud.color, bg)), cpu.resolve(want, cloud.color, bg))
        assert paged.memory["evictions"] > 0


@pytest.mark.parametrize("n", [1, 7, 8, 9, 1003, 4096])
@pytest.mark.parametrize("covered", [0.0, 0.03, 0.5, 1.0])
def test_resolve_of_compact_colors_by_groups_of_8_pixels(rng, n, covered):
    """The 16-bit and palette resolve tests 8 pixels at a time (simd.resolve8_*): every pixel
    equals the decoded colour of its point (numpy), the count is right, and the lanes past the
    frame's end are neither read (their keys would point past the colours) nor written."""
    from gigapoint.backends.numba_cpu import raster
    from gigapoint.core.compact import pack_rgb565, rgb565_table, rgb565_words, rgba32
    from gigapoint.core.palette import decode, quantize_palettes

    points = 5000
    rgba = rng.integers(0, 256, (points, 4), dtype=np.uint8)
    rgba[:, 3] = 255
    exact = rgba.view(np.uint32).reshape(-1)
    frame = np.full(n + 8, 0xFFFF_FFFF_FFFF_FFF0, np.uint64)  # beyond n: keys of no point
    hit = rng.random(n) < covered
    frame[:n] = np.where(hit, (rng.integers(0, 2**31, n).astype(np.uint64) << np.uint64(32)) | rng.integers(0, points, n).astype(np.uint64), raster.EMPTY)
    bg = np.uint32(0x11223344)
    half = pack_rgb565(exact)
    pal = quantize_palettes(exact, shift=10)
    cases = {
        "rgb565": ((rgb565_words(half), rgb565_table(), raster.NO_TABLE, 0), rgba32(half)),
        "palette": ((pal.words, raster.NO_TABLE, pal.palette, pal.shift), decode(pal)),
    }
    for name, ((colors, table, palette, shift), per_point) in cases.items():
        out = np.full(n + 8, 0xDEADBEEF, np.uint32)
        got = raster.resolve_colors(frame[:n], colors, bg, out[:n], table, palette, shift)
        want = np.where(hit, per_point[(frame[:n] & np.uint64(0xFFFFFFFF)).astype(np.int64) % points], bg)
        np.testing.assert_array_equal(out[:n], want, err_msg=name)
        assert got == hit.sum(), name
        assert (out[n:] == 0xDEADBEEF).all(), name
