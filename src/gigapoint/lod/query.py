"""The points of the part of an LOD octree that meets a region, read node by node: what a tool
that needs every point of a small part of an octree reads (a cross-section's corridor, Potree's
profile tool), not the whole octree; or every node, one at a time, for the statistics of all
its points (``octree_stats``: ``gigapoint info --stats``).

In a layered octree every input point lives in exactly one node: inner nodes hold a sample of
the real points, the leaves the rest (a converted gigapoint folder of either sampler, COPC, EPT,
a Potree 2.0 folder that gigapoint wrote). The points of a region are then those of the nodes
whose boxes meet it, at every level. Two kinds are otherwise:

- a ProgressiveOctree's inner nodes hold voxels (representatives at cell centres, not points):
  its points are those of its leaves, which hold every point added;
- PotreeConverter's ``poisson_average`` stores copies of points in inner nodes (its metadata
  counts fewer points than its nodes hold): refused, as no node says which are copies.

A coarser product needs fewer of them: a node at level d holds a sample of its cube's points
about ``spacing / 2^d`` apart (``spacing``: the root's, from the octree's metadata; the grid and
Poisson samplers, COPC, EPT and Potree 2.0 alike), so with ``max_spacing`` only the levels down to
the first whose spacing is at most that are read (``deepest_level``): a sample of the region's
points at least that dense, not every point. A ProgressiveOctree's leaves are read whole then too
(its inner voxels are cell centres, not points).

Nodes are read through what each reader offers (``node_points``; a COPC/EPT octree's hierarchy
pages and nodes fetched together, by ranged reads over HTTP), so only the meeting nodes are read.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np

from ..core.chunk import PointChunk
from ..errors import EmptyCloudError, InputError
from ..io.filters import PointFilter
from ..io.http import as_url, shown_url
from ..io.stats import PointStats, stream_stats
from .potree import PotreeCloud
from .progressive import ProgressiveOctree
from .store import BOX_SLACK, OctreeCloud
from .voxel_octree import DECODE_GROUP_POINTS, VoxelOctree

#: ``meets(lo, hi)``: which of the boxes lo..hi ((k, 3) arrays) meet the region
Meets = Callable[[np.ndarray, np.ndarray], np.ndarray]


def is_octree(cloud) -> bool:
    """An LOD octree ``points_meeting`` reads: an OctreeCloud of any kind or a ProgressiveOctree."""
    return isinstance(cloud, (OctreeCloud, ProgressiveOctree))


def points_meeting(cloud, meets: Meets, max_spacing: float | None = None) -> Iterator[PointChunk]:
    """The points (every attribute) of the nodes of the octree ``cloud`` whose boxes meet the
    region (``meets``), at every level, a node a chunk (leaves only for a ProgressiveOctree, its
    inner nodes holding voxels: its leaves' points a few leaves a chunk). Every point of the
    region is in one of them, once. With ``max_spacing``, only the levels down to
    ``deepest_level(cloud, max_spacing)``: a sample of the region's points about that far apart
    or closer (every point where the octree names no spacing, and for a ProgressiveOctree). A
    one-line InputError for an octree whose nodes hold copies of points."""
    if isinstance(cloud, ProgressiveOctree):
        yield from _progressive_leaves(cloud, meets)
        return
    if isinstance(cloud, PotreeCloud):
        source = cloud.meta.get("source_points")
        if isinstance(source, int) and 0 < source < cloud.n_points:
            raise InputError(
                f"{cloud.path}: its nodes hold {cloud.n_points - source:,} copies of its {source:,} points (PotreeConverter's poisson_average), "
                "which no node tells apart: read the point files instead"
            )
    deepest = deepest_level(cloud, max_spacing)
    if isinstance(cloud, VoxelOctree):
        yield from _voxel_nodes(cloud, meets, deepest)
        return
    for index in _meeting(cloud, meets, cloud.box_min, cloud.box_min + cloud.box_size, deepest).tolist():
        yield _chunk(cloud.node_points(index))


def root_spacing(cloud: OctreeCloud) -> float | None:
    """The spacing of the points of the octree's root node (its level d nodes': that / 2^d), from
    its metadata (an EPT dataset's: its cube's edge / its ``span``); None where it names none."""
    spacing = cloud.meta.get("spacing")
    if spacing is None and cloud.meta.get("span"):  # (EPT: a node is a grid of span³ cells)
        spacing = float(cloud.meta["cube_edge"]) / float(cloud.meta["span"])
    return float(spacing) if spacing else None


def deepest_level(cloud, max_spacing: float | None) -> int | None:
    """The first level of the octree ``cloud`` whose points are at most ``max_spacing`` apart (its
    nodes and those above hold a sample of every place at least that dense); None (every level)
    without ``max_spacing``, for a ProgressiveOctree, or where the octree names no spacing."""
    spacing = None if max_spacing is None or isinstance(cloud, ProgressiveOctree) else root_spacing(cloud)
    if spacing is None:
        return None
    return max(0, math.ceil(math.log2(spacing / max_spacing)))


def kept_points(cloud, keep: PointFilter, label: str, region: str) -> list[PointChunk]:
    """The points of the octree ``cloud`` (named ``label`` in messages) that ``keep`` keeps, read
    from the nodes meeting it only (``points_meeting`` of ``keep.meets``); an EmptyCloudError
    where none passes, or where no node meets ``region`` (what the filter keeps, in words)."""
    kept = [chunk for points in points_meeting(cloud, keep.meets) if len(chunk := keep.kept(points, label))]
    keep.check_passed(label)
    if not kept:  # (no node meets it: none read)
        raise EmptyCloudError(f"{label}: no point passes the filter ({keep.describe()}): no node of the octree meets {region}{keep.polygon_hint()}")
    return kept


@contextmanager
def opened_octree(path, instead: str) -> Iterator[OctreeCloud]:
    """The octree at ``path`` (``open_octree``), closed after (a URL's connections); an unfinished
    conversion's preview (a sample of the points) a one-line InputError: ``instead``, what to do
    instead, ends it."""
    from .reader import open_octree

    octree = open_octree(path)
    try:
        if not is_octree(octree):
            raise InputError(f"{shown_url(path)}: an unfinished conversion; its preview holds a sample of the points: {instead}")
        yield octree
    finally:
        if isinstance(octree, VoxelOctree):  # (a URL's connections)
            octree.close()


def octree_stats(path, point_filter: PointFilter | None = None, on_chunk: Callable[[int], None] | None = None) -> PointStats:
    """The ``PointStats`` of a local octree (gigapoint or Potree 2.0 folder, EPT dataset, COPC
    file), its nodes read one at a time (``points_meeting``: each point once); with
    ``point_filter``, of the points it keeps, the nodes whose boxes miss its region not read (an
    EmptyCloudError where none meets it). ``on_chunk(points)`` after each node (a progress bar).
    No header bounds are compared (an octree's are its metadata's). Over HTTP: a one-line
    InputError (every node would be downloaded)."""
    url = as_url(path)
    if url is not None:
        raise InputError(f"{shown_url(url)}: an octree over HTTP; --stats reads local octrees and point files")
    label = shown_url(path)
    with opened_octree(path, "read the point files, or finish the conversion first") as octree:
        meets = (point_filter or PointFilter()).meets  # (no filter: every box meets it)
        stats = stream_stats(points_meeting(octree, meets), label, point_filter, on_chunk)
        scale = octree.meta.get("scale")  # the grid its source stored positions at, where it says
        stats.scale = None if scale is None else np.array(scale, np.float64)
    if point_filter is not None and stats.read == 0:  # no node meets its region: none read
        raise EmptyCloudError(f"{label}: no point passes the filter ({point_filter.describe()}): no node of the octree meets its region{point_filter.polygon_hint()}")
    return stats


def _meeting(cloud: OctreeCloud, meets: Meets, lo: np.ndarray, hi: np.ndarray, deepest: int | None = None) -> np.ndarray:
    """Indices of the nodes holding points whose boxes lo..hi (widened by ``BOX_SLACK``) meet the
    region, at levels down to ``deepest`` (None: all)."""
    return np.flatnonzero((cloud.counts > 0) & cloud.boxes_meeting(meets, lo, hi) & _down_to(cloud, deepest))


def _down_to(cloud: OctreeCloud, deepest: int | None) -> np.ndarray | bool:
    """Which of the octree's nodes lie at levels down to ``deepest`` (None: all)."""
    return True if deepest is None else cloud.levels <= deepest


def _chunk(points: dict) -> PointChunk:
    """A node's ``node_points`` as a PointChunk: its positions, own colours (not the filtered ones drawn) and attributes."""
    rgba = np.asarray(points["rgba"], np.uint32).view(np.uint8).reshape(-1, 4)
    attributes = {a: v for a, v in points.items() if a not in ("xyz", "color", "rgba")}
    return PointChunk(points["xyz"], rgba, attributes)


def _voxel_nodes(cloud: VoxelOctree, meets: Meets, deepest: int | None) -> Iterator[PointChunk]:
    """A COPC/EPT octree's meeting nodes down to level ``deepest`` (None: all): the hierarchy pages
    of pending nodes that meet the region read first (a pending node's box is its cube; pages of
    nodes deeper than ``deepest`` not read), then the nodes fetched a group at a time, as a frame's are."""
    cloud.read_pages_meeting(lambda lo, hi: cloud.boxes_meeting(meets, lo, hi) & _down_to(cloud, deepest))  # (levels of the hierarchy read so far)
    need = _meeting(cloud, meets, cloud.nodes["bbox_min"], cloud.nodes["bbox_max"], deepest).tolist()
    for _, points in cloud.points_of_nodes(need):
        yield _chunk(points)


def _progressive_leaves(cloud: ProgressiveOctree, meets: Meets) -> Iterator[PointChunk]:
    """The points of a ProgressiveOctree's leaves that meet the region (``chunks``: once loading
    has finished, its error raised), a chunk of up to DECODE_GROUP_POINTS points at a time."""
    pad = BOX_SLACK * float(cloud.edge)
    yield from cloud.chunks(DECODE_GROUP_POINTS, leaves_of=lambda leaves, lo, edge: meets(lo - pad, lo + edge[:, None] + pad))


__all__ = ["BOX_SLACK", "deepest_level", "is_octree", "octree_stats", "opened_octree", "points_meeting"]
