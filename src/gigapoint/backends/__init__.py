"""Rendering backends, chosen through one registry that checks what is installed."""

from __future__ import annotations

import glob
import os
import sys
import warnings

from ..errors import BackendUnavailableError, GigapointWarning

_instances: dict[str, object] = {}


def _make_cpu():
    from .numba_cpu import NumbaCpuBackend

    return NumbaCpuBackend()


def _make_wgpu(require_hardware: bool):
    try:
        from .wgpu import WgpuBackend  # noqa: PLC0415
    except ImportError as exc:
        raise BackendUnavailableError(f"wgpu backend not available: {exc} (install with: pip install 'gigapoint[gpu]')") from None
    return WgpuBackend(require_hardware=require_hardware)


def gpu_device_present() -> bool:
    """Cheap check for a GPU before asking wgpu (enumerating adapters takes ~1 s)."""
    if os.environ.get("GIGAPOINT_NO_GPU"):
        return False
    if not sys.platform.startswith("linux"):
        return True  # Metal / DX12: let wgpu decide
    return bool(glob.glob("/dev/dri/renderD*") or glob.glob("/dev/nvidia[0-9]*"))


def get_backend(name: str = "auto"):
    """The backend called ``name`` (cpu, wgpu) or, for auto, a real GPU if any else the CPU."""
    if name in _instances:
        return _instances[name]
    if name == "cpu":
        backend = _make_cpu()
    elif name == "wgpu":
        backend = _make_wgpu(require_hardware=False)
    elif name == "auto":
        if not gpu_device_present():
            return get_backend("cpu")
        try:
            backend = _make_wgpu(require_hardware=True)
        except BackendUnavailableError:
            backend = get_backend("cpu")
        except Exception as exc:  # a broken driver must never stop a render
            warnings.warn(f"GPU backend failed to start ({exc}); using the CPU", GigapointWarning, stacklevel=2)
            backend = get_backend("cpu")
    else:
        raise BackendUnavailableError(f"unknown backend {name!r}; choose auto, cpu or wgpu")
    _instances[name] = backend
    return backend
