"""The CPU backend (numba): always available."""

from .backend import NumbaCpuBackend

__all__ = ["NumbaCpuBackend"]
