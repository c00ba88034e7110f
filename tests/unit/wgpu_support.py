"""Shared by the wgpu test modules: a backend or a clean skip, and the two atomics paths."""

from __future__ import annotations

import pytest

from gigapoint.backends.numba_cpu import NumbaCpuBackend
from gigapoint.backends.wgpu import WgpuBackend
from gigapoint.errors import BackendUnavailableError


def wgpu_or_skip(**options) -> WgpuBackend:
    try:
        return WgpuBackend(**options)
    except BackendUnavailableError as exc:
        pytest.skip(f"no wgpu adapter: {exc}")


@pytest.fixture(scope="module")
def gpu():
    """The 64-bit atomicMin path where the adapter has it."""
    return wgpu_or_skip()


@pytest.fixture(scope="module")
def gpu32():
    """The two-pass 32-bit fallback."""
    return wgpu_or_skip(atomics64=False)


@pytest.fixture(scope="module", params=["atomics64", "two-pass"])
def any_gpu(request, gpu, gpu32):
    """Each test using it runs on the 64-bit path (where the adapter has it) and the fallback."""
    return gpu if request.param == "atomics64" else gpu32


@pytest.fixture(scope="module")
def cpu():
    return NumbaCpuBackend()
