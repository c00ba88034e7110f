"""Adaptive point size of a converted octree (issue #17): its spacing comes from its nodes' levels
(DrawList.spacing), so its default render sizes points like a plain cloud of the points it draws."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import gigapoint as gp
from gigapoint.core.layout import EMPTY_PIXEL
from gigapoint.render.camera import VIEWS
from gigapoint.render.passes import splat_for
from gigapoint.render.splats import batch_spacings, finest_spacing, point_spacing, weighted_median


def rolling_surface(n: int = 150_000, size: float = 150.0, seed: int = 3) -> np.ndarray:
    """n random points on a gently rolling 150 m square: sqrt(size^2 / n) = 0.39 m apart."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, size, (n, 2))
    z = 3.0 * np.sin(xy[:, 0] / 25.0) + 2.0 * np.cos(xy[:, 1] / 30.0)
    return np.column_stack([xy, z])


@pytest.fixture(scope="module")
def surface_octree(tmp_path_factory):
    from gigapoint.lod import convert, open_octree

    xyz = rolling_surface()
    out = tmp_path_factory.mktemp("adaptive_octree") / "oct"
    convert([gp.PointChunk(xyz, np.full((len(xyz), 4), 200, np.uint8))], out, max_leaf=5_000)
    return open_octree(out)


def drawn_points(octree, draw) -> np.ndarray:
    return np.concatenate([octree.node_points(int(n))["xyz"] for n in draw.nodes])


def lit(cloud, cam, settings) -> int:
    return int(np.count_nonzero(gp.render_frame(cloud, cam, settings).visibility != EMPTY_PIXEL))


@pytest.mark.parametrize("view", ["iso", "top"])
@pytest.mark.parametrize("everything", [True, False])
def test_octree_points_are_sized_like_a_plain_cloud_of_the_same_points(surface_octree, view, everything):
    """Every node in view drawn, or a coarser level of detail (300 px nodes: a subset): the
    octree's adaptive size and coverage within 25 % / 15 % of a plain cloud made of the points
    it draws. (Without the octree's own DrawList.spacing the spacing came from each drawn node's
    points alone, sparser than all that is drawn there: 1.5-1.7 times the plain cloud's here,
    the node boxes' estimate before that 2-2.4 times on the demo town.)"""
    octree = surface_octree
    s = gp.RenderSettings(backend="cpu", threads=1)
    s = s.replace(lod_threshold_px=1e-6, point_budget=10_000_000) if everything else s.replace(lod_threshold_px=300.0)
    lo, hi = octree.bounds
    cam = gp.Camera.orbit((lo + hi) / 2, *VIEWS[view], 45.0, width=480, height=270)  # close: points several pixels apart
    view_ = cam.view(octree.bounds)
    draw = octree.prepare(view_, s)
    xyz = drawn_points(octree, draw)
    if not everything:  # a level of detail: fewer points than every node in view holds
        every = octree.prepare(view_, s.replace(lod_threshold_px=1e-6, point_budget=10_000_000))
        assert len(xyz) < 0.9 * octree.nodes["count"][every.nodes].sum()
    plain = gp.from_arrays(xyz, name="same points")
    spacing = draw.spacing if draw.spacing is not None else point_spacing(draw.points)  # (what the renderer takes)
    assert spacing == pytest.approx(point_spacing(plain), rel=0.25)
    splat_o = splat_for(s, cam, draw, view_.near)
    splat_p = splat_for(s, cam, plain.prepare(cam.view(plain.bounds), s), cam.view(plain.bounds).near)
    assert float(splat_o[2]) == pytest.approx(float(splat_p[2]), rel=0.25)  # the perspective size scale
    lo, lp = lit(octree, cam, s), lit(plain, cam, s)
    assert lo == pytest.approx(lp, rel=0.15), (lo, lp)
    assert lo > 2 * lit(octree, cam, s.replace(size_mode="fixed"))  # and the surface closes


def two_nodes(coarse, fine) -> SimpleNamespace:
    """Point buffers holding two clouds' batches, coarse's first (what an arena holds)."""
    fb = fine.batches.copy()
    fb["first"] += len(coarse.low)
    return SimpleNamespace(batches=np.concatenate([coarse.batches, fb]), low=np.concatenate([coarse.low, fine.low]))


def all_points_spacing(cloud) -> float:
    """``point_spacing`` from every point of every batch (what ``finest_spacing`` measures a node with)."""
    _, spacing, drawn = batch_spacings(cloud, sample=1 << 30, limit=None)
    return weighted_median(spacing, drawn)


def test_finest_spacing_reads_the_nodes_drawn_without_their_children():
    """A coarse node (1 in 16 points) and its child (the other 15) drawn together: the spacing
    of all their points where the child is; the coarse node drawn alone: its own."""
    xyz = rolling_surface(n=64_000, size=60.0)
    coarse, fine = gp.from_arrays(xyz[::16]), gp.from_arrays(np.delete(xyz, np.s_[::16], axis=0))
    both = two_nodes(coarse, fine)
    slots = np.arange(len(both.batches))
    slot_node = (slots >= len(coarse.batches)).astype(np.int64)  # node 0: the coarse level, node 1: its child
    children = np.array([[1, -1, -1, -1, -1, -1, -1, -1], [-1] * 8])
    counts = np.array([len(coarse.low), len(fine.low)])
    everything = all_points_spacing(gp.from_arrays(xyz))
    got = finest_spacing(both, slots, slot_node, np.array([0, 1]), children, counts)
    assert got == pytest.approx(everything, rel=0.05)
    assert all_points_spacing(fine) > 1.02 * got  # the child's own points: 15 of 16
    mine = slots[slot_node == 0]
    alone = finest_spacing(both, mine, np.zeros(len(mine), np.int64), np.array([0]), children, counts)
    assert alone == pytest.approx(all_points_spacing(coarse), rel=1e-9) and alone > 3 * everything
