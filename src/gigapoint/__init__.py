"""gigapoint: render massive point clouds fast, from Python, by software rasterization."""

from __future__ import annotations

from .core import PointChunk, PointCloud, demo_arrays, from_arrays
from .errors import GigapointError, GigapointWarning
from .render import Camera, Frame, RenderSettings, RenderStats, render, render_frame

__version__ = "0.1.0"


def demo(n_points: int = 1_000_000, seed: int = 0) -> PointCloud:
    """The procedural demo scene (terrain, roads, river, buildings, trees) as a PointCloud."""
    from .core import build_cloud, demo_chunks

    return build_cloud(demo_chunks(n_points, seed), name=f"demo({n_points:,})")


def open(*paths, **options) -> PointCloud:  # noqa: A001 - the natural name, like PIL.Image.open
    """Read one or more files or directories (LAS/LAZ/PLY/XYZ/CSV/NPY/NPZ) into one PointCloud."""
    from .io import open_cloud

    return open_cloud(*paths, **options)


__all__ = [
    "Camera",
    "Frame",
    "GigapointError",
    "GigapointWarning",
    "PointChunk",
    "PointCloud",
    "RenderSettings",
    "RenderStats",
    "__version__",
    "demo",
    "demo_arrays",
    "from_arrays",
    "open",
    "render",
    "render_frame",
]
