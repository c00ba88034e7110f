"""The Renderable contract: what every kind of cloud gives the renderer.

``gigapoint.render`` draws anything that implements :class:`Renderable` and never asks what
it is: a plain PointCloud (core/cloud.py), a converted octree (gigapoint.lod), and the
clouds still to come (progressive, live, COPC/EPT). For one view a Renderable *prepares* a
:class:`DrawList`: the point buffers the backends read and the selection of their batches
to draw, each with its precision and matrix (selection.py). Buffers are in the batch layout
of layout.py, so one set of kernels draws every kind of cloud.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from .selection import Selection, View


def check_classified(name: str, attribute_names, hidden: tuple[int, ...]) -> None:
    """A one-line SettingsError where ``hidden`` classes are to be left out of the cloud ``name``
    and its points have no ``classification`` attribute to tell them by."""
    from ..errors import SettingsError

    if hidden and "classification" not in attribute_names:
        classes = ",".join(map(str, hidden))
        raise SettingsError(f"hidden_classes: {name} has no classification attribute, so no class {classes} to hide")


def hidden_classes_refusal(name: str, kind: str) -> str:
    """Why the cloud ``name`` of ``kind`` (a live cloud) hides no class, in one line (the viewer's
    Classes panel says it too)."""
    return f"hidden_classes: {name} is {kind}, which draws every class; leave them out as it reads instead (--drop-classes, drop_classes=)"


def refuse_hidden_classes(name: str, kind: str, settings: SelectionSettings) -> None:
    """A one-line SettingsError where ``settings`` hide classes of a cloud kind that cannot
    leave them out while drawing (they would be drawn without a word)."""
    from ..errors import SettingsError

    if settings.hidden_classes:
        raise SettingsError(hidden_classes_refusal(name, kind))


def held_points(batches: np.ndarray, most: int | None = None) -> np.ndarray:
    """Indices of the points ``batches`` hold (each its ``first`` .. ``first + count``), in batch
    order; with ``most``, evenly spaced, at most ~2x ``most`` of them (an LOD arena's or pool's
    slots beyond its batches are empty room, or a partial slot's tail)."""
    counts = batches["count"].astype(np.int64)
    firsts = batches["first"].astype(np.int64)
    ends = np.cumsum(counts)
    total = int(ends[-1]) if len(ends) else 0
    if most is None or total <= most:
        return np.repeat(firsts - (ends - counts), counts) + np.arange(total)
    k = np.arange(0, total, total // most)  # a sample, without an index of every point first
    held_by = np.searchsorted(ends, k, "right")
    return firsts[held_by] + k - (ends - counts)[held_by]


def check_point_index(index, n_points: int | None = None, name: str = "") -> None:
    """A one-line PointIndexError unless ``index`` (given to ``point_info``) is a whole number
    (a float such as 3.5 was read as point 3) and, with ``n_points``, -1 (no point) or one of
    the buffers' ``n_points`` points (``name``: whose)."""
    from ..errors import PointIndexError, is_whole_number

    if not is_whole_number(index):
        raise PointIndexError(f"point index must be a whole number (frame.index[y, x]), got {index!r}")
    if n_points is not None and index != -1 and not 0 <= index < n_points:
        raise PointIndexError(f"{name}: point index {index} out of range 0..{n_points - 1} (-1: no point)")


class SelectionSettings(Protocol):
    """The fields of RenderSettings that choosing what to draw reads."""

    precision_threshold_px: float
    adaptive_precision: bool
    frustum_culling: bool
    max_points: int  # plain clouds: every k-th point of each batch within this cap (0: all)
    point_budget: int  # octrees: most points a frame draws
    lod_threshold_px: float
    lod_foveation: float
    hidden_classes: tuple[int, ...]  # LAS classes not drawn (the points drawn are a filtered cloud: DrawList.points)


@runtime_checkable
class PointBuffers(Protocol):
    """Point arrays in the batch layout (layout.py) that backends draw and passes read.

    ``version`` is None for buffers that never changed after they were built (a PointCloud
    until its ``changed()`` or ``set_colors``);
    buffers rewritten in place between frames (an octree's arena) bump it on every write
    and record in ``batch_version`` the version that last wrote each batch, so caches of
    derived arrays (render's RenderCache, the GPU's copies) know what is stale."""

    name: str
    batches: np.ndarray  # BATCH_DTYPE records: first, count, level, bbox
    low: np.ndarray  # u32 per point: bits 20-29 of x, y, z
    # medium and high words; both None in the compact layout (core/compact.py), whose buffers then
    # have ``packing`` (PACK_DTYPE per batch) and ``ext`` (the extension streams) instead
    med: np.ndarray | None
    high: np.ndarray | None
    # u32 RGBA8 per point (u16 RGB565 in a compact cloud; per-block palettes, core/palette.py's
    # PaletteColors, in a cloud built with colors="palette": ``compact.rgba32`` decodes any of them)
    color: np.ndarray
    attributes: dict[str, np.ndarray]
    version: int | None
    batch_version: np.ndarray | None

    @property
    def n_points(self) -> int: ...

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]: ...

    def point_info(self, index: int) -> dict | None: ...  # None for -1; check_point_index's error for another index outside


@dataclass
class DrawList:
    """What one view draws: batches ``selection`` of ``points``."""

    # the arrays the visibility buffer's indices point into: with ``hidden_classes`` those of the
    # points drawn (a plain cloud's filtered copy, an octree's arena of filtered nodes)
    points: PointBuffers
    selection: Selection
    n_batches: int  # batches (octree: nodes) of the whole renderable, for the stats
    step: int = 1  # draw every step-th point of each batch (a point cap on a plain cloud)
    nodes: np.ndarray | None = None  # octree node indices drawn (stats, tests)
    # opacity 0..1 of each selected batch (float, aligned with selection.ids), multiplied with the
    # settings' opacity; None: 1 each. Any batch below 1 makes the frame transparent (a live cloud's
    # fade of its older frames; render/passes/transparency.py). A batch of opacity 0 is better left unselected.
    alpha: np.ndarray | None = None
    # world distance between neighbouring drawn points, for adaptive point sizes, where the batch
    # boxes do not tell it (chunks that share their node's cube: lod/progressive); None: the
    # boxes' (render/splats.point_spacing)
    spacing: float | None = None
    # ``points.version`` as prepared: while it is unchanged, the frame's indices still name the points it drew
    generation: int | None = field(init=False)

    def __post_init__(self) -> None:
        self.generation = self.points.version


@dataclass
class MultiViewDrawList:
    """Several views drawn in ONE pass over the union of their batches (2022 paper, 3.7)."""

    points: PointBuffers
    ids: np.ndarray  # int64 batches any view draws
    bits: np.ndarray  # (V, k) each view's precision for each of them
    matrices: np.ndarray  # (V, k, 4, 4) each view's matrix for each of them
    views: list[DrawList]  # each view's own selection (its passes and stats)


@runtime_checkable
class Renderable(Protocol):
    """Anything ``gigapoint.render`` draws (``isinstance(x, Renderable)`` checks the members are there)."""

    name: str
    attributes: Mapping[str, np.ndarray]  # per-point attributes by name (intensity, classification...)
    load_progress: float  # 0..1: how much of its source is loaded (1 for a finished cloud)

    @property
    def n_points(self) -> int: ...

    @property
    def attribute_names(self) -> Sequence[str]:
        """The names of its points' attributes, known before any point is in memory (an octree
        read node by node has none in ``attributes`` until nodes are read)."""
        ...

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) float64 corners of the box around every point (clip ranges, framing)."""
        ...

    def prepare(self, view: View, settings: SelectionSettings) -> DrawList:
        """The buffers and the batches to draw for ``view``."""
        ...

    def prepare_views(self, views: list[View], settings: SelectionSettings) -> MultiViewDrawList | None:
        """Several views for one pass over shared buffers (stereo), where each view's own
        selection differs from the others only by frustum culling; None where it cannot
        (an octree picks other nodes per view): the renderer then draws them one by one."""
        ...

    def reading(self) -> AbstractContextManager:
        """Held by the renderer from ``prepare`` until the frame is drawn: a cloud that fills
        while it is drawn (a progressive octree) inserts nothing meanwhile. A cloud whose
        buffers never change returns ``contextlib.nullcontext()``."""
        ...


@runtime_checkable
class PointSource(Protocol):
    """A cloud that gives its points back as PointChunks: what ``gigapoint.convert(cloud, out)``
    converts (a plain cloud, a progressive octree once loaded)."""

    name: str
    source_files: Sequence  # the files whose headers give a conversion its CRS and LAS grid (none: empty)
    colors_exact: bool  # chunks() gives the colours it was given (not RGB565's or a palette's approximations)

    def chunks(self, points_per_chunk: int = 1_000_000) -> Iterator:
        """Its points, positions, colours and attributes, as bounded PointChunks."""
        ...
