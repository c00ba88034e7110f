"""Point data in gigapoint's own layout: chunks, Morton order, batches, quantization, selection,
and the Renderable contract every kind of cloud implements."""

from .kernel_cache import compile_where_uncachable

compile_where_uncachable()  # before any kernel is defined (core's own modules have some): kernels numba cannot cache compile in memory

from .chunk import DEFAULT_COLOR, PointChunk, to_rgba8
from .chunked import build_cloud_chunked
from .cloud import PointCloud, build_cloud, cloud_from_points, from_arrays
from .layout import BATCH_DTYPE, BATCH_SIZE, EMPTY_PIXEL

__all__ = [
    "BATCH_DTYPE",
    "BATCH_SIZE",
    "DEFAULT_COLOR",
    "EMPTY_PIXEL",
    "PointChunk",
    "PointCloud",
    "build_cloud",
    "build_cloud_chunked",
    "cloud_from_points",
    "from_arrays",
    "to_rgba8",
]
