"""Per-block colour palettes (core/palette.py, ``colors="palette"``): the quantizer's choices
decode back, blocks of at most 256 colours are exact, renders equal the numpy reference and
the decoded colours' on the CPU and on wgpu, the chunked build equals the in-memory one,
autzen_trim holds at most 7 bytes a point, and ``colors="auto"`` (the default) picks the palette
exactly where its squared error is at most RGB565's."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp
from gigapoint import Camera, RenderSettings
from gigapoint.core import PointChunk, build_cloud
from gigapoint.core.chunked import build_cloud_chunked
from gigapoint.core.compact import colors_at, pack_rgb565, rgba32
from gigapoint.core.palette import (
    PALETTE_SHIFT,
    PALETTE_SIZE,
    PaletteColors,
    block_errors,
    choose_palette,
    decode,
    empty_palettes,
    palette_into,
    quantize_palettes,
)
from gigapoint.errors import InputError
from gigapoint.io.demo import demo_chunks
from gigapoint.render.reference import reference_image

AUTZEN = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "autzen_trim.laz"
UTM = np.array([636_000.0, 5_012_000.0, 120.0])


def expected_decode(pc: PaletteColors) -> np.ndarray:
    """The format's definition, independent of the kernels: entry ``index`` of the block's palette."""
    i = np.arange(pc.n)
    return pc.palette[(i // 2**pc.shift) * PALETTE_SIZE + pc.index.astype(np.int64)]


def random_colors(rng, n, distinct, alpha=False):
    """n u32 RGBA8 colours drawn from ``distinct`` random ones (opaque unless ``alpha``)."""
    base = rng.integers(0, 256, (distinct, 4), dtype=np.uint8)
    if not alpha:
        base[:, 3] = 255
    return np.ascontiguousarray(base[rng.integers(0, distinct, n)]).view(np.uint32).reshape(-1)


def psnr(a, b) -> float:
    x = a.view(np.uint8).reshape(-1, 4)[:, :3].astype(np.float64)
    y = b.view(np.uint8).reshape(-1, 4)[:, :3].astype(np.float64)
    return float(10 * np.log10(255**2 / np.mean((x - y) ** 2)))


# --- the format and the quantizer ------------------------------------------------------------
@pytest.mark.parametrize(("n", "shift"), [(10_240, 13), (5_003, 10), (1, 8), (257, 8), (4096, 9), (20_000, 8), (70_000, 16)])
def test_every_index_decodes_to_the_colour_the_quantizer_chose(rng, n, shift):
    color = random_colors(rng, n, 3000)
    pc = quantize_palettes(color, shift)
    stride = 2**shift
    assert pc.n == n and pc.shift == shift and pc.block == stride
    assert len(pc.words) == -(-n // 4) and len(pc.palette) == -(-n // stride) * PALETTE_SIZE
    want = expected_decode(pc)
    np.testing.assert_array_equal(decode(pc), want)
    np.testing.assert_array_equal(rgba32(pc), want)
    some = rng.integers(0, n, 50)
    np.testing.assert_array_equal(colors_at(pc, some), want[some])
    # the colour chosen for a box is the rounded mean of the colours of its points
    ch = color.view(np.uint8).reshape(-1, 4).astype(np.int64)
    got = want.view(np.uint8).reshape(-1, 4).astype(np.int64)
    batch = np.arange(n) // stride
    for b in np.unique(batch)[:3]:
        for k in np.unique(pc.index[batch == b])[:20]:
            sel = (batch == b) & (pc.index == k)
            mean = (2 * ch[sel].sum(axis=0) + sel.sum()) // (2 * sel.sum())
            np.testing.assert_array_equal(got[sel], np.broadcast_to(mean, got[sel].shape))
    # unused entries are zero, and no index points at one
    for b in range(-(-n // stride)):
        m = min(stride, n - b * stride)
        used = np.unique(pc.index[b * stride : b * stride + m])
        assert used.max() < min(PALETTE_SIZE, m)
    assert quantize_palettes(color, shift).palette.tobytes() == pc.palette.tobytes()  # deterministic
    assert quantize_palettes(color, shift).words.tobytes() == pc.words.tobytes()
    # block by block, as the chunked build fills them: the same arrays
    parts = empty_palettes(n, shift)
    cut = min(n // stride, 2) * stride
    palette_into(parts, 0, color[:cut])
    palette_into(parts, cut, color[cut:])
    np.testing.assert_array_equal(parts.words, pc.words)
    np.testing.assert_array_equal(parts.palette, pc.palette)


@pytest.mark.parametrize("distinct", [1, 2, 17, 255, 256])
@pytest.mark.parametrize("alpha", [False, True])
def test_blocks_of_at_most_256_colours_are_exact(rng, distinct, alpha):
    n, stride = 20_000, 2**PALETTE_SHIFT  # a ragged last block
    color = np.concatenate([random_colors(rng, stride, distinct, alpha) for _ in range(-(-n // stride))])[:n]
    pc = quantize_palettes(color)
    np.testing.assert_array_equal(decode(pc), color)


def test_more_colours_lose_little(rng):
    """Smooth colours (an aerial photo's): the palette beats RGB565's rounding."""
    n = 10_240
    t = np.linspace(0, 1, n)
    rgb = np.stack([120 + 100 * np.sin(7 * t), 90 + 80 * np.cos(11 * t), 60 + 50 * t], 1) + rng.normal(0, 2, (n, 3))
    rgba = np.concatenate([np.clip(np.rint(rgb), 0, 255), np.full((n, 1), 255)], 1).astype(np.uint8)
    color = rgba.view(np.uint32).reshape(-1)
    assert len(np.unique(color)) > 1000
    pc = quantize_palettes(color, 14)
    assert psnr(color, decode(pc)) > psnr(color, rgba32(pack_rgb565(color)))
    assert np.abs(decode(pc).view(np.uint8).reshape(-1, 4).astype(int) - rgba.astype(int)).max() <= 16


def sq_error(a, b) -> int:
    x = a.view(np.uint8).reshape(-1, 4)[:, :3].astype(np.int64)
    y = b.view(np.uint8).reshape(-1, 4)[:, :3].astype(np.int64)
    return int(((x - y) ** 2).sum())


@pytest.mark.parametrize("shift", [8, PALETTE_SHIFT])
def test_block_errors_are_the_decoded_colours_errors(rng, shift):
    """The quantizer's per-block errors (``colors="auto"`` decides on them) are the squared
    errors of the decoded palette and of RGB565 over every point's R, G and B, block by block."""
    n = 3 * (1 << shift) + 77
    color = random_colors(rng, n, 3000)
    sse = block_errors(n, shift)
    pc = quantize_palettes(color, shift, sse=sse)
    got, short = decode(pc), rgba32(pack_rgb565(color))
    for b in range(len(sse)):
        s = slice(b << shift, (b + 1) << shift)
        assert sse[b].tolist() == [sq_error(got[s], color[s]), sq_error(short[s], color[s])]
    parts, pieces = empty_palettes(n, shift), block_errors(n, shift)
    palette_into(parts, 0, color[: 2 << shift], pieces)
    palette_into(parts, 2 << shift, color[2 << shift :], pieces)
    np.testing.assert_array_equal(pieces, sse)


def test_auto_picks_the_more_faithful_format(rng):
    """Smooth colours of an aerial photo: the palette; random colours: RGB565; translucent ones and
    clouds without a source scale: 32 bits, as before."""
    n = 20_000
    xyz = UTM + rng.integers(0, 3000, (n, 3)) * 0.01
    t = np.linspace(0, 1, n)
    rgb = np.stack([120 + 100 * np.sin(7 * t), 90 + 80 * np.cos(11 * t), 60 + 50 * t], 1) + rng.normal(0, 2, (n, 3))
    smooth = np.concatenate([np.clip(np.rint(rgb), 0, 255), np.full((n, 1), 255)], 1).astype(np.uint8)
    noisy = random_colors(rng, n, 20_000).view(np.uint8).reshape(-1, 4)
    for rgba, chosen in ((smooth, PaletteColors), (noisy, np.ndarray)):
        cloud = build_cloud([PointChunk(xyz, rgba, {}, scale=(0.01,) * 3)])
        exact = build_cloud([PointChunk(xyz, rgba, {}, scale=(0.01,) * 3)], colors="rgba").color
        assert isinstance(cloud.color, chosen)
        palette = rgba32(build_cloud([PointChunk(xyz, rgba, {}, scale=(0.01,) * 3)], colors="palette").color)
        short = rgba32(pack_rgb565(exact))
        assert (sq_error(palette, exact) <= sq_error(short, exact)) == (chosen is PaletteColors)
        np.testing.assert_array_equal(cloud.rgba.view(np.uint32).reshape(-1), palette if chosen is PaletteColors else short)
    assert build_cloud([PointChunk(xyz, smooth, {})]).color.dtype == np.uint32  # three words: exact colours
    translucent = smooth.copy()
    translucent[0, 3] = 254
    assert build_cloud([PointChunk(xyz, translucent, {}, scale=(0.01,) * 3)]).color.dtype == np.uint32
    assert choose_palette(np.array([[5, 5]])) and not choose_palette(np.array([[6, 5], [0, 0]]))
    assert isinstance(gp.from_arrays(xyz, smooth, scale=0.01).color, PaletteColors)  # from_arrays: "auto" too
    assert gp.from_arrays(xyz, smooth, scale=0.01, colors="rgb565").color.dtype == np.uint16
    with pytest.raises(InputError, match="colors must be one of"):
        gp.from_arrays(xyz, smooth, scale=0.01, colors="full")


@pytest.mark.parametrize("noisy", [False, True])
def test_auto_chunked_equals_in_memory(rng, noisy, tmp_path):
    """The chunked build decides on the same blocks' errors (an RGB565 copy waits on disk)."""

    def source():
        for chunk in demo_chunks(60_000, seed=3, chunk_size=20_000, scale=0.01):
            if noisy:
                chunk.rgba[:, :3] = np.random.default_rng(len(chunk)).integers(0, 256, (len(chunk), 3))
            yield chunk

    want = build_cloud(source(), batch_size=1000)
    got = build_cloud_chunked(source, batch_size=1000, partition_points=15_000, tmpdir=tmp_path)
    assert isinstance(want.color, np.ndarray if noisy else PaletteColors)
    np.testing.assert_array_equal(got.rgba, want.rgba)
    assert type(got.color) is type(want.color) and got.memory() == want.memory()


def test_bad_arrays_are_refused():
    with pytest.raises(ValueError, match="index words"):
        PaletteColors(np.zeros(2, np.uint32), np.zeros(256, np.uint32), 8, 10)
    with pytest.raises(ValueError, match="palette entries"):
        PaletteColors(np.zeros(75, np.uint32), np.zeros(256, np.uint32), 8, 300)
    for shift in (7, 32):
        with pytest.raises(ValueError, match="shift"):
            quantize_palettes(np.zeros(4, np.uint32), shift)
    with pytest.raises(ValueError, match="whole blocks"):
        palette_into(empty_palettes(1000, 8), 128, np.zeros(256, np.uint32))
    with pytest.raises(ValueError, match="whole blocks"):
        palette_into(empty_palettes(1000, 8), 0, np.zeros(300, np.uint32))


# --- clouds ----------------------------------------------------------------------------------
def grid_cloud(rng, n, batch_size, colors="palette", distinct=5000):
    q = rng.integers(0, 4000, (n, 3))
    xyz = UTM + q * 0.01
    rgba = random_colors(rng, n, distinct).view(np.uint8).reshape(-1, 4)
    chunk = PointChunk(xyz, rgba, {}, scale=(0.01,) * 3)
    return build_cloud([chunk], name="grid", batch_size=batch_size, colors=colors)


def test_cloud_in_palettes(rng):
    cloud = grid_cloud(rng, 12_345, 1000)
    assert isinstance(cloud.color, PaletteColors) and cloud.color.shift == PALETTE_SHIFT and cloud.layout == "compact"
    assert cloud.memory()["color"] == -(-cloud.n_points // 4) * 4 + -(-cloud.n_points // 2**PALETTE_SHIFT) * PALETTE_SIZE * 4
    np.testing.assert_array_equal(cloud.rgba.view(np.uint32).reshape(-1), expected_decode(cloud.color))
    assert cloud.point_info(4321)["rgba"] == cloud.rgba[4321].tolist()
    assert np.array_equal(cloud.expanded().color, expected_decode(cloud.color))
    # at most 200 colours a batch: exact (the same points and colours drawn twice)
    few = grid_cloud(np.random.default_rng(9), 5_000, 1000, distinct=200)
    exact = grid_cloud(np.random.default_rng(9), 5_000, 1000, colors="rgba", distinct=200)
    np.testing.assert_array_equal(few.rgba, exact.rgba)
    with pytest.raises(InputError, match="palette"):
        grid_cloud(rng, 100, 10, colors="pallete")


def render_pair(cloud, cam, settings):
    """(image of the palette cloud, image of the same cloud with its decoded u32 colours)."""
    decoded = dataclasses.replace(cloud, color=rgba32(cloud.color))
    return gp.render_frame(cloud, cam, settings).image, gp.render_frame(decoded, cam, settings).image


@pytest.mark.parametrize("view", ["iso", "top", "front"])
def test_cpu_render_equals_the_reference(rng, view):
    cloud = grid_cloud(rng, 30_000, 2048)
    cam = Camera.fit(cloud.bounds, view=view, width=160, height=120)
    s = RenderSettings(backend="cpu", size_mode="fixed")
    image, decoded = render_pair(cloud, cam, s)
    np.testing.assert_array_equal(image, reference_image(cloud, cam, s))
    np.testing.assert_array_equal(image, decoded)
    assert (image[..., :3] != 0).any(axis=2).mean() > 0.2
    for extra in ({"hqs": True}, {"edl": True}):  # passes that blend RGBA8 colours
        s = RenderSettings(backend="cpu", size_mode="fixed", **extra)
        a, b = render_pair(cloud, cam, s)
        np.testing.assert_array_equal(a, b)


def test_three_word_layout_and_odd_batches():
    cloud = build_cloud(demo_chunks(60_000), colors="palette", batch_size=777)  # no scale: three words a point
    assert cloud.layout == "words" and isinstance(cloud.color, PaletteColors) and cloud.color.shift == PALETTE_SHIFT
    cam = Camera.fit(cloud.bounds, view="iso", width=160, height=120)
    s = RenderSettings(backend="cpu", size_mode="fixed")
    image, decoded = render_pair(cloud, cam, s)
    np.testing.assert_array_equal(image, reference_image(cloud, cam, s))
    np.testing.assert_array_equal(image, decoded)


@pytest.mark.parametrize(("batch_size", "partition_points"), [(1000, 20_000), (10_240, 50_000)])
def test_chunked_equals_in_memory(batch_size, partition_points, tmp_path):
    def source():
        return demo_chunks(120_000, seed=5, chunk_size=30_000, scale=0.01)

    want = build_cloud(source(), batch_size=batch_size, colors="palette")
    got = build_cloud_chunked(source, batch_size=batch_size, colors="palette", partition_points=partition_points, tmpdir=tmp_path)
    assert isinstance(got.color, PaletteColors) and got.color.shift == want.color.shift == PALETTE_SHIFT
    np.testing.assert_array_equal(got.color.words, want.color.words)
    np.testing.assert_array_equal(got.color.palette, want.color.palette)
    np.testing.assert_array_equal(got.low, want.low)
    assert got.memory() == want.memory()


def test_demo_in_palettes():
    a = gp.demo(30_000, scale=0.01, colors="palette")
    b = gp.demo(30_000, scale=0.01, colors="palette", chunked=True)
    assert isinstance(a.color, PaletteColors) and isinstance(b.color, PaletteColors)
    np.testing.assert_array_equal(a.color.words, b.color.words)
    np.testing.assert_array_equal(a.color.palette, b.color.palette)
    assert a.memory()["color"] < 1.2 * a.n_points
    assert isinstance(gp.demo(30_000, scale=0.01).color, PaletteColors)  # the default, "auto", picks it for the town


@pytest.mark.skipif(not AUTZEN.exists(), reason="autzen_trim.laz not present")
def test_autzen_in_at_most_7_bytes_a_point():
    cloud = gp.open(AUTZEN)  # by default: the palette beats RGB565 on its colours
    assert isinstance(cloud.color, PaletteColors)
    np.testing.assert_array_equal(cloud.color.words, gp.open(AUTZEN, colors="palette").color.words)
    exact = gp.open(AUTZEN, colors="rgba")
    mem = cloud.memory()
    per_point = (mem["positions"] + mem["color"] + mem["batches"]) / cloud.n_points
    assert per_point <= 7.0, mem
    np.testing.assert_array_equal(cloud.low, exact.low)  # positions untouched
    assert psnr(exact.color, rgba32(cloud.color)) > psnr(exact.color, rgba32(pack_rgb565(exact.color))) + 2.0


# --- the GPU (lavapipe in CI) ----------------------------------------------------------------
def _wgpu(**options):
    from gigapoint.backends.wgpu import WgpuBackend
    from gigapoint.errors import BackendUnavailableError

    try:
        return WgpuBackend(**options)
    except BackendUnavailableError as exc:
        pytest.skip(f"no wgpu adapter: {exc}")


@pytest.mark.gpu
def test_wgpu_equals_cpu(rng):
    _wgpu()
    cloud = grid_cloud(rng, 30_000, 2048)
    for view in ("iso", "top"):
        cam = Camera.fit(cloud.bounds, view=view, width=160, height=120)
        cpu = gp.render_frame(cloud, cam, RenderSettings(backend="cpu", size_mode="fixed")).image
        gpu = gp.render_frame(cloud, cam, RenderSettings(backend="wgpu", size_mode="fixed")).image
        np.testing.assert_array_equal(gpu, cpu)


@pytest.mark.gpu
@pytest.mark.parametrize("shift", [PALETTE_SHIFT, 14, 8])
def test_wgpu_resolve_in_pages(rng, shift):
    """Pages of colours smaller and larger than a palette's block (pages of ~4 000 points: 8 192,
    16 384 and 256 points a palette), batches of 1001 points across page ends."""
    from gigapoint.backends.numba_cpu import NumbaCpuBackend
    from gigapoint.core.selection import select

    cloud = grid_cloud(rng, 15_015, 1001)
    cloud = dataclasses.replace(cloud, color=quantize_palettes(rgba32(cloud.color), shift))
    cpu = NumbaCpuBackend()
    page = 4 * 1001 * 4 + 16
    paged = _wgpu(page_bytes=page, memory_budget=max(1 << 18, 3 * page))
    cam = Camera.fit(cloud.bounds, view="iso", width=160, height=120)
    near, far = cam.clip_range(cloud.bounds)
    sel = select(cloud.batches, cam.screen_rows(), cam.width, cam.height, near, far, 1e9, True, True)
    vis = cpu.rasterize(cloud, sel, cam.width, cam.height, near, far)
    bg = (10, 20, 30, 255)
    want = cpu.resolve(vis, cloud.color, bg)
    np.testing.assert_array_equal(np.asarray(paged.resolve(vis, cloud.color, bg)), want)
    np.testing.assert_array_equal(want, cpu.resolve(vis, rgba32(cloud.color), bg))
    assert paged.page_points < cloud.n_points // 3


def test_point_info_says_when_a_colour_is_held_approximately():
    """gp.open's colors="auto" may hold RGB565 or palettes: the pick showed 173 where the file
    held 170, as if it were the file's colour."""
    rng = np.random.default_rng(4)
    xyz = UTM + rng.uniform(0, 50, (20_000, 3))
    rgb = rng.integers(0, 256, (20_000, 3)).astype(np.uint8)  # 20 000 colours: palettes cannot keep them all
    rgb[0] = [170, 85, 0]
    said = {}
    for colors in ("rgba", "rgb565", "palette"):
        cloud = gp.from_arrays(xyz, rgb, colors=colors)
        i = int(np.argmin(np.abs(cloud.positions() - xyz[0]).sum(axis=1)))  # the cloud's own order
        info = cloud.point_info(i)
        said[colors] = (info["rgba"], info.get("rgba_approx"))
    assert said["rgba"] == ([170, 85, 0, 255], None)
    assert said["rgb565"] == ([173, 85, 0, 255], "colours held in 16 bits (RGB565)")
    assert said["palette"][1] == "colours held as 256-colour palettes"
