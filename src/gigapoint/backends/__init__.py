"""Rendering backends: numba on the CPU (always there), wgpu on a GPU (where one is).

Each implements the Backend and Passes contracts of gigapoint.render.backend and is
registered there by name; importing this package imports neither backend module (``auto``
loads a class only when it tries it). ``gigapoint`` imports this package at the first
lookup of a backend (gigapoint/__init__.py's wiring, core/hooks.py).
"""

from __future__ import annotations

from ..render.backend import BackendEntry, get_backend, register_backend


def _numba_cpu() -> type:
    from .numba_cpu import NumbaCpuBackend

    return NumbaCpuBackend


def _wgpu() -> type:
    from .wgpu import WgpuBackend

    return WgpuBackend


register_backend(BackendEntry("wgpu", _wgpu, auto_rank=0, auto_options={"require_hardware": True}))  # auto: a real GPU only
register_backend(BackendEntry("cpu", _numba_cpu, auto_rank=1))

__all__ = ["get_backend"]
