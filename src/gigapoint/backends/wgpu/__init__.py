"""The GPU backend (wgpu: Vulkan, Metal, D3D12; Mesa lavapipe on machines without a GPU).

Importing this package does not import wgpu; WgpuBackend() does, and turns any failure
to load it or to find an adapter into BackendUnavailableError with an install hint.
"""

from .backend import WgpuBackend

__all__ = ["WgpuBackend"]
