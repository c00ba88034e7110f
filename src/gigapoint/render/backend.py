"""The Backend and Passes contracts, and the registry that picks a backend by name.

The renderer (renderer.py, passes/) orchestrates and never imports a backend: it asks
``get_backend(settings.backend)`` for an object that implements :class:`Backend`. The
backends (``gigapoint.backends``: numba on the CPU, wgpu on a GPU) register themselves here
with ``register_backend`` when ``gigapoint`` is imported; each owns its lock and its
:class:`Passes`. Parameters the CPU and GPU versions of a pass share live in params.py.

Adding a pass: a settings field, one CPU kernel, one WGSL kernel, one method in each
Passes (and a line in passes/__init__.finish_frame that calls it).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ..core.hooks import wire
from ..core.renderable import PointBuffers
from ..core.selection import Selection
from ..errors import BackendUnavailableError, GigapointWarning, warn

#: (footprint (k, 3) int32 rows dx, dy, need; size float32; atten float32): points larger
#: than a pixel (passes/splats.py); None draws one pixel per point.
Splat = tuple[np.ndarray, np.float32, np.float32]


class Passes(Protocol):
    """The image-quality passes of one backend, on its own buffers.

    ``vis`` is a (H*W,) u64 visibility buffer, ``colors`` (H*W,) u32 RGBA; a backend may
    return its own array type (the GPU keeps results on the device) that the next pass of
    the same backend reads in place and ``np.asarray`` reads back. Every pass gives the
    image of its numpy reference in render/passes (bit for bit on the CPU)."""

    def resolve(self, vis, point_colors: np.ndarray, background) -> tuple[Any, int | None]:
        """(u32 RGBA per pixel: the winning point's color or the background, covered pixels
        when counted on the way, else None). ``point_colors``: u32 RGBA8, u16 RGB565 or per-batch
        palettes (core/palette.py's PaletteColors), decoded on the way."""

    def fill_holes(self, vis, width: int, height: int, level: int, foveated: bool = False):
        """Depth-aware hole filling: a filled copy of the visibility buffer."""

    def hqs_colors(
        self, points: PointBuffers, sel: Selection, vis, width: int, height: int, near: float, far: float,
        point_colors: np.ndarray, fallback, tolerance: float = 0.01, threads: int | None = None,
        splat: Splat | None = None, softness: float = 0.0, step: int = 1,
    ):  # fmt: skip
        """High-quality shading: the mean color of the points near each pixel's closest depth;
        ``step`` > 1: of every step-th point of each batch, those the depth pass drew."""

    def transparent_colors(
        self, points: PointBuffers, sel: Selection, vis, width: int, height: int, near: float, far: float,
        point_colors: np.ndarray, alphas: np.ndarray, fallback, background, threads: int | None = None,
        splat: Splat | None = None, step: int = 1,
    ):  # fmt: skip
        """Transparent points: each pixel's fragments composited, the nearest depth-sorted and the rest
        by their mean (render/passes/transparency.py); ``alphas`` (k, 2) u32 per selected batch
        (params.batch_alphas), ``fallback`` the colors of pixels no fragment reaches."""

    def shade(self, vis, colors, normals: np.ndarray, camera, shininess: float = 32.0):
        """Blinn-Phong headlight from per-point float32 (N, 3) normals."""

    def eye_dome_lighting(self, vis, colors, width: int, height: int, strength: float = 1.0, radius: float = 1.4):
        """Eye-dome lighting from the visibility buffer's depth."""

    def downsample(self, vis: np.ndarray, image: np.ndarray, width: int, height: int, s: int) -> tuple[np.ndarray, np.ndarray]:
        """(closest key of each s x s block, rounded mean color of it) of a supersampled frame."""


class Backend(Protocol):
    """A rasterizer: batches of point buffers into a visibility buffer, and its passes."""

    name: str
    lock: threading.RLock  # frames go one at a time: the renderer holds it around the passes
    passes: Passes

    @classmethod
    def is_available(cls) -> bool:
        """A cheap check (no device opened) whether ``auto`` should try this backend."""

    def describe(self) -> str: ...

    def rasterize(
        self, points: PointBuffers, selection: Selection, width: int, height: int, near: float, far: float,
        threads: int | None = None, splat: Splat | None = None, step: int = 1, keep_on_device: bool = False,
    ):  # fmt: skip
        """The (height * width,) u64 visibility buffer of the selected batches. ``step`` > 1:
        every step-th point of each batch. ``keep_on_device``: a result the backend's passes
        read in place (a numpy array where host and device are one)."""

    def rasterize_views(
        self, points: PointBuffers, ids, bits, matrices, width: int, height: int, nears, fars,
        threads: int | None = None, splat: Splat | None = None, step: int = 1,
    ) -> np.ndarray:  # fmt: skip
        """(V, height * width) visibility buffers of V views drawn in one pass over batches
        ``ids`` (bits (V, k), matrices (V, k, 4, 4), nears/fars (V,): each view's own)."""

    def resolve(self, visibility, color: np.ndarray, background) -> np.ndarray:
        """u32 RGBA per pixel as a numpy array (``passes.resolve``, read back)."""


@dataclass
class BackendEntry:
    """A registered backend: ``load()`` imports its class (only when it is asked for),
    ``auto_rank`` orders ``auto``'s choice (lowest first), ``auto_options`` are the
    constructor arguments ``auto`` uses (e.g. refuse a CPU emulation of a GPU)."""

    name: str
    load: Callable[[], type]
    auto_rank: int
    auto_options: dict = field(default_factory=dict)


_REGISTRY: dict[str, BackendEntry] = {}
_instances: dict[str, Backend] = {}
_registry_lock = threading.Lock()


def register_backend(entry: BackendEntry) -> None:
    """Make a backend available by name (``settings.backend``) and to ``auto``."""
    _REGISTRY[entry.name] = entry


def backend_names() -> list[str]:
    wire()  # the backends register on first use (core/hooks.py: gigapoint/__init__.py's wiring)
    return ["auto", *sorted(_REGISTRY, key=lambda n: _REGISTRY[n].auto_rank)]


def get_backend(name: str = "auto") -> Backend:
    """The backend called ``name``; ``auto``: the first available by rank (a real GPU if any,
    else the CPU). One instance per name and process."""
    wire()  # the backends register on first use (core/hooks.py: gigapoint/__init__.py's wiring)
    with _registry_lock:
        if name in _instances:
            return _instances[name]
        if name == "auto":
            backend = _pick_auto()
        elif name in _REGISTRY:
            backend = _REGISTRY[name].load()()
        else:
            raise BackendUnavailableError(f"unknown backend {name!r}; choose {', '.join(backend_names())}")
        _instances[name] = backend
        return backend


def _pick_auto() -> Backend:
    failures = []
    for entry in sorted(_REGISTRY.values(), key=lambda e: e.auto_rank):
        if entry.name in _instances:
            return _instances[entry.name]
        try:
            cls = entry.load()
            if not cls.is_available():
                continue
            backend = cls(**entry.auto_options)
        except BackendUnavailableError as exc:
            failures.append(str(exc))
            continue
        except Exception as exc:  # noqa: BLE001 - a broken driver must never stop a render
            warn(f"{entry.name} backend failed to start ({exc}); trying the next", GigapointWarning)
            continue
        if not entry.auto_options:  # the same object serves its own name
            _instances[entry.name] = backend
        return backend
    raise BackendUnavailableError(f"no rendering backend is available ({'; '.join(failures) or 'none registered'})")
