"""Level of detail on the wgpu backend: converted octrees render through an arena that loads
and evicts nodes between frames, refilling its buffers in place. The GPU copies of those
buffers must follow (the arena's ``version`` / ``batch_version``): every frame equals the CPU
backend's frame of the same arena (<= 0.1 % of pixels; identical on lavapipe), and only the
slots written since a page's upload are sent again."""

from __future__ import annotations

import numpy as np
import pytest
from wgpu_support import any_gpu, cpu, gpu, gpu32, wgpu_or_skip  # noqa: F401 - fixtures

from gigapoint import Camera, RenderSettings, render_frame
from gigapoint.core import PointChunk
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.errors import BackendUnavailableError
from gigapoint.io import demo_chunks
from gigapoint.lod import convert, open_octree
from gigapoint.lod.store import ARENA_CHUNK, Arena

pytestmark = pytest.mark.gpu

MAX_DIFF_FRACTION = 0.001
N = 150_000


def _grid_chunks():
    """The demo town on a 1 cm grid (a survey's): nodes of 0..~20 extension bits, not wide."""
    for c in demo_chunks(N, chunk_size=75_000):
        yield PointChunk(np.round(c.xyz / 0.01) * 0.01, c.rgba, c.attributes, scale=(0.01,) * 3)


@pytest.fixture(scope="module", params=["wide", "grid"])
def octree(tmp_path_factory, request):
    """Format-2 octrees, drawn through the compact arena: the demo town's float points (every
    node wide: 60 extension bits a point) and the same on a 1 cm grid (16-bit colours)."""
    out = tmp_path_factory.mktemp("wgpu_lod") / "oct"
    if request.param == "wide":
        convert(list(demo_chunks(N, chunk_size=75_000)), out, max_leaf=4_000, partition_points=60_000)
    else:
        convert(list(_grid_chunks()), out, max_leaf=4_000, partition_points=60_000, colors="rgb565")
    return out


def _cameras(bounds, width=240, height=180):
    lo, hi = bounds
    c = (lo + hi) / 2
    return [
        Camera.fit(bounds, view="iso", width=width, height=height),
        Camera.look_at((c[0] - 350, c[1] - 300, 80.0), (c[0] - 100, c[1] - 100, 0.0), width=width, height=height),
        Camera.fit(bounds, view="top", width=width, height=height),
        Camera.look_at((c[0] + 350, c[1] + 300, 80.0), (c[0] + 100, c[1] + 150, 0.0), width=width, height=height),
    ]


def _small_arena(oc, points: int, words: bool = False) -> Arena:
    """An arena too small for every view's nodes: frames evict nodes and reuse their slots.
    ``words``: the three-word layout instead of the octree's compact one."""
    oc.arena = Arena(points, oc.name, oc.bounds, oc._attribute_dtypes()) if words else oc.new_arena(points)
    assert (oc.arena.med is None) != words
    return oc.arena


SETTINGS = RenderSettings(point_budget=45_000, lod_threshold_px=12.0, size_mode="fixed")  # the exact one-pixel render


def _n_differ(a, b) -> int:
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    return int(np.count_nonzero(a != b))


def _assert_frames_close(got, want):
    n_vis = _n_differ(got.visibility, want.visibility)
    assert n_vis <= MAX_DIFF_FRACTION * want.visibility.size, f"{n_vis} of {want.visibility.size} pixels differ"
    n_img = int(np.count_nonzero(np.any(got.image != want.image, axis=-1)))
    assert n_img <= MAX_DIFF_FRACTION * want.visibility.size + 25 * n_vis
    assert np.count_nonzero(want.visibility != EMPTY_PIXEL) > 500


def _wgpu_settings(**kw) -> RenderSettings:
    from gigapoint.backends import get_backend

    try:
        get_backend("wgpu")
    except BackendUnavailableError as exc:
        pytest.skip(str(exc))
    return SETTINGS.replace(backend="wgpu", **kw)


@pytest.mark.parametrize("passes", [{}, {"hqs": True, "edl": True}, {"point_size": 3, "fill_holes": 1}])
def test_lod_frames_equal_cpu_while_the_arena_changes(octree, passes):
    """Frames from several views, with loads and evictions between them: each wgpu frame equals
    the CPU frame of the same arena contents (no stale uploaded pages)."""
    oc = open_octree(octree)
    settings = _wgpu_settings(**passes)
    arena = _small_arena(oc, 60_000)
    seen_versions = []
    reused = False
    owner_before = None
    for cam in _cameras(oc.bounds) * 2:
        frame = render_frame(oc, cam, settings)
        assert oc.arena is arena, "the test needs one arena throughout"
        loads = arena.loads
        ref = render_frame(oc, cam, settings.replace(backend="cpu"))
        assert arena.loads == loads  # the CPU frame drew the same arena contents
        assert frame.stats.backend == "wgpu" and frame.stats.points_processed == ref.stats.points_processed
        _assert_frames_close(frame, ref)
        owner = {int(s): nd for nd, slots in arena.resident.items() for s in slots}
        if owner_before is not None:
            reused |= any(owner_before.get(s, nd) != nd for s, nd in owner.items())
        owner_before = owner
        seen_versions.append(arena.version)
    assert len(set(seen_versions)) > 2  # the arena was written between frames
    assert reused  # ... and slots of evicted nodes were refilled with other nodes


def test_each_atomics_path_follows_the_arena(any_gpu, cpu, octree):
    oc = open_octree(octree)
    arena = _small_arena(oc, 60_000)
    settings = SETTINGS
    for cam in _cameras(oc.bounds) * 2:
        draw = oc.prepare(cam.view(oc.bounds), settings)
        cloud, sel = draw.points, draw.selection
        assert cloud is arena
        near, far = cam.clip_range(oc.bounds)
        args = (cam.width, cam.height, near, far)
        want = cpu.rasterize(cloud, sel, *args)
        got = any_gpu.rasterize(cloud, sel, *args)
        assert _n_differ(got, want) <= MAX_DIFF_FRACTION * want.size
        assert np.count_nonzero(want != EMPTY_PIXEL) > 500


@pytest.mark.parametrize("words", [False, True], ids=["compact", "words"])
def test_only_rewritten_slots_are_uploaded_again(gpu, cpu, octree, words):
    oc = open_octree(octree)
    arena = _small_arena(oc, 60_000, words)
    settings = SETTINGS.replace(adaptive_precision=False)  # every frame reads all three word arrays
    cams = _cameras(oc.bounds)
    for cam in (cams[0], cams[1], cams[3]):
        draw = oc.prepare(cam.view(oc.bounds), settings)
        cloud, sel = draw.points, draw.selection
        near, far = cam.clip_range(oc.bounds)
        gpu.rasterize(cloud, sel, cam.width, cam.height, near, far)
    # back to the second view: its nodes evicted by the last one come back into freed slots
    cam = cams[1]
    version = arena.version
    before = gpu.memory["uploaded"]
    draw = oc.prepare(cam.view(oc.bounds), settings)
    cloud, sel = draw.points, draw.selection
    changed = arena.batch_version > version
    changed_points = int(arena.batches["count"][changed].astype(np.int64).sum())
    assert 0 < changed_points < arena.n_points // 4
    near, far = cam.clip_range(oc.bounds)
    got = gpu.rasterize(cloud, sel, cam.width, cam.height, near, far)
    sent = gpu.memory["uploaded"] - before
    # low, med, high words of the new slots only; low words and the streams' bits in the compact layout
    per_point = 12 if words else 4 + int(oc.ext_bits.max()) / 8
    assert 0 < sent <= per_point * changed_points + 16 * int(changed.sum())
    want = cpu.rasterize(cloud, sel, cam.width, cam.height, near, far)
    assert _n_differ(got, want) <= MAX_DIFF_FRACTION * want.size
    # the same arena again: nothing to send
    before = gpu.memory["uploaded"]
    gpu.rasterize(cloud, sel, cam.width, cam.height, near, far)
    assert gpu.memory["uploaded"] == before


@pytest.mark.parametrize("words", [False, True], ids=["compact", "words"])
def test_arena_over_several_pages(cpu, octree, words):
    """Pages of three slots: pages stay put while slots refill, and each is refreshed on its own.
    (A compact cloud's pages hold half the points: its streams take up to 7.5 bytes a point.)"""
    paged = wgpu_or_skip(page_bytes=(3 if words else 6) * ARENA_CHUNK * 4)
    oc = open_octree(octree)
    arena = _small_arena(oc, 60_000, words)
    plans = []
    for cam in _cameras(oc.bounds) * 2:
        draw = oc.prepare(cam.view(oc.bounds), SETTINGS)
        cloud, sel = draw.points, draw.selection
        near, far = cam.clip_range(oc.bounds)
        args = (cam.width, cam.height, near, far)
        want = cpu.rasterize(cloud, sel, *args)
        assert _n_differ(paged.rasterize(cloud, sel, *args), want) <= MAX_DIFF_FRACTION * want.size
        plan = paged.ctx.plan(arena)
        assert plan.n_pages == -(-arena.n_slots // 3)
        plans.append(plan)
    assert all(p is plans[0] for p in plans)  # planned once, though the slots' counts changed


class _Frames:
    """A cloud whose points are replaced in place (a sensor stream): a ``version`` only, no
    per-batch versions, so a change re-sends whole pages."""

    def __init__(self, cloud):
        self.name = "frames"
        self.bounds = cloud.bounds
        self.batches = cloud.batches
        self.low, self.med, self.high, self.color = (np.array(a) for a in (cloud.low, cloud.med, cloud.high, cloud.color))
        self.n_points = cloud.n_points
        self.attributes = {}
        self.version = 0
        self.batch_version = None  # the PointBuffers contract: no per-batch versions


def test_the_compact_arena_uploads_fewer_bytes(gpu, cpu, octree):
    """The same frames through the compact and the three-word arena: the same images, fewer
    bytes sent to the GPU (every frame at 30 bits, so each reads every word it has)."""
    settings = SETTINGS.replace(adaptive_precision=False)
    sent, images_of = [], []
    for words in (False, True):
        oc = open_octree(octree)
        arena = _small_arena(oc, 60_000, words)
        gpu.ctx.cache.clear()
        before = gpu.memory["uploaded"]
        images = []
        for cam in _cameras(oc.bounds) * 2:
            draw = oc.prepare(cam.view(oc.bounds), settings)
            near, far = cam.clip_range(oc.bounds)
            images.append(gpu.rasterize(draw.points, draw.selection, cam.width, cam.height, near, far))
        assert oc.arena is arena
        sent.append(gpu.memory["uploaded"] - before)
        images_of.append(images)
    for got, want in zip(*images_of, strict=True):
        assert _n_differ(got, want) == 0
    wide = int(oc.ext_bits.max()) == 60
    assert sent[0] < (0.97 if wide else 0.6) * sent[1], sent


def test_a_cloud_with_a_version_only_is_resent_when_it_changes(any_gpu, cpu):
    import gigapoint
    from gigapoint.core.selection import select

    stream = _Frames(gigapoint.demo(40_000, scale=None))
    cam = Camera.fit(stream.bounds, view="iso", width=160, height=120)
    near, far = cam.clip_range(stream.bounds)
    sel = select(stream.batches, cam.screen_rows(), cam.width, cam.height, near, far, 500.0, False)
    args = (cam.width, cam.height, near, far)
    first = any_gpu.rasterize(stream, sel, *args)
    # a new frame: every point moves to its batch's low x face, in the same buffers
    for a in (stream.low, stream.med, stream.high):
        a &= np.uint32(~0x3FF & 0xFFFFFFFF)
    stream.version += 1
    want = cpu.rasterize(stream, sel, *args)
    assert _n_differ(want, first) > 100
    got = any_gpu.rasterize(stream, sel, *args)
    assert _n_differ(got, want) <= MAX_DIFF_FRACTION * want.size
