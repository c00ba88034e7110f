"""LOD rendering of converted octrees with the same kernel as brute force: images, budget, arena."""

from __future__ import annotations

import numpy as np
import pytest

import gigapoint as gp
from gigapoint import Camera, RenderSettings, render_frame
from gigapoint.io import demo_chunks
from gigapoint.lod import OctreeCloud, convert, open_octree

N = 300_000


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("lodr") / "oct"
    convert(list(demo_chunks(N, chunk_size=100_000)), out, max_leaf=5_000, partition_points=80_000)
    return gp.demo(N, scale=None), out


CAMERAS = [
    lambda b: Camera.fit(b, view="iso", width=480, height=320),
    lambda b: Camera.fit(b, view="top", width=400, height=400),
    lambda b: Camera.look_at((300, 200, 60), (520, 480, 0), width=480, height=320),  # inside, frustum-culled
]


@pytest.mark.parametrize("adaptive", [False, True])
@pytest.mark.parametrize("make_camera", CAMERAS)
def test_lod_matches_brute_force_when_budget_covers_everything(scene, make_camera, adaptive):
    """Same points, same kernel: only per-node vs per-batch quantization (and depth ties) differ.

    With adaptive precision a whole-scene node under 500 px is drawn with 10 bits (cells of
    up to half a pixel, the paper's rule), so coverage may shift by a few percent of pixels.
    """
    cloud, path = scene
    oc = open_octree(path)
    oc.filtered_colors = False  # compare the points' own colors
    cam = make_camera(cloud.bounds)
    base = RenderSettings(backend="cpu", adaptive_precision=adaptive, size_mode="fixed")  # one-pixel points
    brute = render_frame(cloud, cam, base)
    lod = render_frame(oc, cam, base.replace(point_budget=10**9, lod_threshold_px=0.0))
    assert lod.stats.points_total == N
    # every point in view is drawn: the node selection culls only nodes outside the frustum
    assert brute.stats.points_processed <= lod.stats.points_processed <= N
    covered_b, covered_l = ~brute.empty, ~lod.empty
    assert covered_b.sum() > 2000
    assert (covered_b != covered_l).mean() < (0.05 if adaptive else 0.001)
    same = np.all(brute.image == lod.image, axis=2)
    assert same.mean() > (0.8 if adaptive else 0.94), same.mean()
    both = covered_b & covered_l
    assert np.median(np.abs(brute.depth[both] - lod.depth[both]) / brute.depth[both]) < 1e-3


def test_point_budget_and_threshold_limit_what_is_drawn(scene):
    cloud, path = scene
    oc = open_octree(path)
    cam = Camera.fit(cloud.bounds, view="iso", width=480, height=320)
    s = RenderSettings(backend="cpu")
    full = render_frame(oc, cam, s.replace(point_budget=10**9, lod_threshold_px=0.0)).stats.points_processed
    assert full == N
    small = render_frame(oc, cam, s.replace(point_budget=60_000)).stats.points_processed
    assert 0 < small <= 60_000
    # the selection is closed under parents (additive LOD) and takes the largest nodes first
    near, far = cam.clip_range(oc.bounds)
    ids, sizes, total = oc.select_nodes(cam.view(oc.bounds), s.replace(point_budget=60_000))
    assert total <= 60_000 and ids[0] == 0
    chosen = set(oc.keys[ids].tolist())
    assert all((k >> 3) in chosen for k in chosen if k != 1)
    assert np.all(sizes[:-1] >= sizes[1:])
    # a coarser threshold draws fewer points
    coarse = render_frame(oc, cam, s.replace(lod_threshold_px=400.0)).stats.points_processed
    fine = render_frame(oc, cam, s.replace(lod_threshold_px=50.0)).stats.points_processed
    assert coarse < fine


def test_an_octrees_stats_count_nodes_drawn_and_culled_of_its_nodes(scene):
    """An octree's batches are its nodes: drawn + culled = total, for a converted octree and a
    progressive one (drawn counted its arena slots or pool chunks: 27 + 7 of 31)."""
    cloud, path = scene
    cam = CAMERAS[2](cloud.bounds)  # inside: some nodes culled
    progressive = gp.demo(N, progressive=True)
    progressive.wait()
    for oc in (open_octree(path), progressive):
        for budget in (60_000, 10**9):
            frame = render_frame(oc, cam, RenderSettings(backend="cpu", point_budget=budget))
            st = frame.stats
            assert st.batches_culled > 0 and st.batches_rendered > 0
            assert st.batches_rendered + st.batches_culled == st.batches_total, (type(oc).__name__, budget, st)


def test_arena_reused_between_frames(scene):
    cloud, path = scene
    oc = open_octree(path)
    cam = Camera.fit(cloud.bounds, view="iso", width=320, height=240)
    s = RenderSettings(backend="cpu", point_budget=100_000)
    f1 = render_frame(oc, cam, s)
    arena = oc.arena
    buffers = (arena.low, arena.color)
    loads = arena.loads
    f2 = render_frame(oc, cam, s)
    assert oc.arena is arena and arena.low is buffers[0] and arena.color is buffers[1]
    assert arena.loads == loads  # nothing copied again: every node was resident
    np.testing.assert_array_equal(f1.image, f2.image)
    # another view loads only what it lacks, into the same buffers
    cam2 = Camera.fit(cloud.bounds, view="top", width=320, height=240)
    render_frame(oc, cam2, s)
    assert oc.arena is arena and arena.low is buffers[0]


def test_gigapoint_open_detects_octree_dirs(scene, tmp_path):
    _, path = scene
    oc = gp.open(path)
    assert isinstance(oc, OctreeCloud) and oc.n_points == N
    img = gp.render(oc, Camera.fit(oc.bounds, width=200, height=150), backend="cpu")
    assert img.shape == (150, 200, 4) and (img[..., :3] > 0).any()


def test_filtered_colors_are_averages(scene):
    """With filtering the coarse image's mean color stays that of the full-detail image."""
    cloud, path = scene
    oc = open_octree(path)
    cam = Camera.fit(cloud.bounds, view="top", width=200, height=200)
    s = RenderSettings(backend="cpu", point_budget=30_000, size_mode="fixed")  # one-pixel points
    lod = render_frame(oc, cam, s)
    full = render_frame(cloud, cam, RenderSettings(backend="cpu", size_mode="fixed"))
    assert lod.stats.points_processed <= 30_000
    m_lod = lod.image[..., :3][~lod.empty].reshape(-1, 3).mean(axis=0)
    m_full = full.image[..., :3][~full.empty].reshape(-1, 3).mean(axis=0)
    assert np.all(np.abs(m_lod - m_full) < 12), (m_lod, m_full)


def test_color_modes_read_attributes_through_the_arena(scene):
    cloud, path = scene
    oc = open_octree(path)
    cam = Camera.fit(cloud.bounds, view="top", width=240, height=240)
    # explicit ranges: the auto range is taken over a cloud's whole buffers (an arena's spare slots too)
    s = RenderSettings(
        backend="cpu",
        point_budget=10**9,
        lod_threshold_px=0.0,
        adaptive_precision=False,
        intensity_range=(8000, 45000),
        elevation_range=(-16, 64),
    )
    for mode in ("classification", "intensity", "elevation"):
        lod = render_frame(oc, cam, s.replace(color_mode=mode))
        brute = render_frame(cloud, cam, s.replace(color_mode=mode))
        assert (np.all(lod.image == brute.image, axis=2)).mean() > 0.8, mode  # the rest: depth ties won by another point


@pytest.mark.parametrize("encoding", ["DEFAULT", "BROTLI"])
def test_potree_output_renders_like_the_gigapoint_octree(tmp_path, encoding):
    pytest.importorskip("brotli")
    chunks = list(demo_chunks(80_000, seed=2))
    convert(chunks, tmp_path / "g", max_leaf=4_000)
    convert(chunks, tmp_path / "p", max_leaf=4_000, format="potree", encoding=encoding)
    g, p = gp.open(tmp_path / "g"), gp.open(tmp_path / "p")
    assert isinstance(p, OctreeCloud) and p.n_points == g.n_points == 80_000
    g.filtered_colors = False  # Potree files carry the points' own colors
    cam = Camera.fit(g.bounds, view="iso", width=320, height=240)
    s = RenderSettings(backend="cpu", adaptive_precision=False)
    for budget, threshold in ((10**9, 0.0), (30_000, 100.0)):
        a = render_frame(g, cam, s.replace(point_budget=budget, lod_threshold_px=threshold))
        b = render_frame(p, cam, s.replace(point_budget=budget, lod_threshold_px=threshold))
        assert a.stats.points_processed == b.stats.points_processed
        assert (a.empty != b.empty).mean() < 0.002
        assert np.all(a.image == b.image, axis=2).mean() > 0.97


def test_foveated_threshold_keeps_the_centre_and_thins_the_periphery(scene):
    _, path = scene
    oc = open_octree(path)
    cam = Camera.look_at((500, -150, 250), (500, 500, 0), width=480, height=320)
    # one-pixel points: thinning shows as fewer lit pixels (adaptive sizes would grow the thinned points)
    s = RenderSettings(backend="cpu", lod_threshold_px=60.0, adaptive_precision=False, size_mode="fixed")
    near, far = cam.clip_range(oc.bounds)
    plain, _, n_plain = oc.select_nodes(cam.view(oc.bounds), s)
    fov, _, n_fov = oc.select_nodes(cam.view(oc.bounds), s.replace(lod_foveation=2.0))
    assert n_fov < n_plain and set(fov.tolist()) < set(plain.tolist())
    a = render_frame(oc, cam, s)
    b = render_frame(oc, cam, s.replace(lod_foveation=2.0))
    h, w = a.empty.shape
    centre = (slice(h // 2 - 20, h // 2 + 20), slice(w // 2 - 30, w // 2 + 30))
    assert (a.empty[centre] == b.empty[centre]).mean() > 0.95  # the centre keeps its detail
    assert (~b.empty).sum() < (~a.empty).sum()
