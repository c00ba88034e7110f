"""Point data in gigapoint's own layout: chunks, Morton order, batches, quantization, selection,
and the Renderable contract every kind of cloud implements.

The names below are imported on first use (PEP 562): most of core's modules define numba
kernels, and ``gigapoint info`` or ``--help`` need none (core/hooks.py). numba's set-up (its
cache fallback, core/kernel_cache.py; its threading layer, core/threads.py) runs when numba is
imported, before any kernel is defined (gigapoint/__init__.py, ``hooks.on_numba_import``)."""

from __future__ import annotations

_LAZY = {
    "BATCH_DTYPE": "layout",
    "BATCH_SIZE": "layout",
    "EMPTY_PIXEL": "layout",
    "DEFAULT_COLOR": "chunk",
    "PointChunk": "chunk",
    "to_rgba8": "chunk",
    "build_cloud_chunked": "chunked",
    "PointCloud": "cloud",
    "build_cloud": "cloud",
    "cloud_from_points": "cloud",
    "from_arrays": "cloud",
}


from .hooks import lazy_names

__getattr__ = lazy_names(__name__, _LAZY)


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
