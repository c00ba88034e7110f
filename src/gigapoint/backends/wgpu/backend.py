"""WgpuBackend: the paper's compute rasterizer on any WebGPU adapter (wgpu-native).

Same interface and same visibility buffer as NumbaCpuBackend: the host selects batches
and builds float32 per-batch matrices (core/selection.py); the GPU decodes, projects and
depth-tests with the CPU kernel's float32 arithmetic, then resolves colors. Points larger
than a pixel (square / round splats, fixed or attenuated size) are drawn by the same
kernels; the image-quality passes (hole filling, HQS, lighting, eye-dome lighting) run on
the GPU too (passes.py), on buffers that stay on the GPU between passes. The device and
everything both share (buffers, pipelines, the draw loop) live in context.py.

Where the adapter offers 64-bit atomics (``shader-int64-atomic-min-max``) one pass does
``atomicMin(depth << 32 | index)``; otherwise two passes of 32-bit atomics give the
identical buffer. Point words are uploaded once per cloud, in pages of whole batches that
fit one storage binding, and kept within a memory budget (memory.py); medium/high words
only once a frame draws a batch at 20/30 bits. Clouds that refill their buffers in place
(the LOD arena: nodes loaded and evicted between frames) bump a ``version``; the slots
written since a page was uploaded are sent again before the page is drawn.

``rasterize_views`` draws several views (a stereo pair) in one pass, as the CPU backend's:
each workgroup reads its batch's words once and projects and writes every point into each
view's buffer, at that view's precision (2022 paper, 3.7).

Adapters: Vulkan, Metal or D3D12 (wgpu's OpenGL backend is not used: no 64-bit atomics,
small storage limits); a hardware GPU is preferred, Mesa lavapipe serves where none is.
"""

from __future__ import annotations

import glob
import importlib.util
import os
import sys
import tempfile
from contextlib import contextmanager

import numpy as np

from ...core.compact import color_arrays
from ...errors import BackendUnavailableError, GigapointError
from ..numba_cpu.passes import CpuPasses
from .context import DeviceArray, GpuContext, Views
from .layout import MAX_VIEWS
from .passes import GpuPasses

_INSTALL_HINT = (
    "install with: pip install 'gigapoint[gpu]' (and a Vulkan driver; on Linux without a GPU: apt-get install mesa-vulkan-drivers)"
)
_INT64_FEATURES = ("shader-int64", "shader-int64-atomic-min-max")
_TYPE_RANK = {"DiscreteGPU": 0, "IntegratedGPU": 1, "Unknown": 2, "CPU": 3}
#: Storage buffers the HQS accumulate pass binds (point words, footprint, visibility, colors, sums).
HQS_STORAGE_BUFFERS = 9
#: Storage buffers the transparency accumulate pass binds (point words, footprint, k-buffer, colors, sums, alphas).
TRANSPARENCY_STORAGE_BUFFERS = 10
#: What the transparency pass's k-buffer needs besides 64-bit atomicMin: atomics that return the old value.
_ALL_OPS = "shader-int64-atomic-all-ops"
_EMPTY_WORD = 0xFFFFFFFF

#: Default bound on GPU memory held for point data (bytes). Frames whose selection needs
#: more are drawn page by page, re-uploading what was evicted.
DEFAULT_MEMORY_BUDGET = 2 << 30


def gpu_device_present() -> bool:
    """Cheap check for a GPU before asking wgpu (enumerating adapters takes ~1 s).
    ``GIGAPOINT_NO_GPU=1`` makes ``auto`` use the CPU; unset, empty or 0 leaves it to the device."""
    if os.environ.get("GIGAPOINT_NO_GPU", "").strip() not in ("", "0"):  # "0" turned the GPU off too
        return False
    if not sys.platform.startswith("linux"):
        return True  # Metal / DX12: let wgpu decide
    return bool(glob.glob("/dev/dri/renderD*") or glob.glob("/dev/nvidia[0-9]*"))


def _import_wgpu():
    try:
        import wgpu  # optional dependency
    except Exception as exc:  # noqa: BLE001 - ImportError, or a missing native library (OSError)
        raise BackendUnavailableError(f"wgpu backend: cannot import wgpu ({exc}); {_INSTALL_HINT}") from None
    return wgpu


@contextmanager
def _quiet_wayland_probe():
    """Mesa's Vulkan drivers probe Wayland and print 'XDG_RUNTIME_DIR is invalid' to stderr on
    headless Linux when the variable is unset; give it a harmless value while adapters load."""
    if sys.platform != "linux" or "XDG_RUNTIME_DIR" in os.environ:
        yield
        return
    os.environ["XDG_RUNTIME_DIR"] = tempfile.gettempdir()
    try:
        yield
    finally:
        os.environ.pop("XDG_RUNTIME_DIR", None)


def _pick_adapter(wgpu, require_hardware: bool):
    try:
        with _quiet_wayland_probe():
            adapters = list(wgpu.gpu.enumerate_adapters_sync())
    except Exception as exc:  # noqa: BLE001 - wgpu-native reports failures with many types
        raise BackendUnavailableError(f"wgpu backend: cannot list GPU adapters ({exc}); {_INSTALL_HINT}") from None
    adapters = [a for a in adapters if a.info.get("backend_type") not in ("OpenGL", "OpenGLES")]
    if not adapters:
        raise BackendUnavailableError(f"wgpu backend: no Vulkan/Metal/D3D12 adapter found; {_INSTALL_HINT}")
    if require_hardware:
        hardware = [a for a in adapters if a.info.get("adapter_type") != "CPU"]
        if not hardware:
            names = ", ".join(str(a.info.get("device", "?")) for a in adapters)
            raise BackendUnavailableError(f"wgpu backend: only CPU adapters ({names}); no hardware GPU")
        adapters = hardware
    return min(adapters, key=lambda a: _TYPE_RANK.get(a.info.get("adapter_type"), 2))


class WgpuBackend:
    """GPU rasterizer. ``require_hardware``: refuse CPU adapters (lavapipe), for backend auto.

    Options for tests and tuning: ``atomics64`` (None = use 64-bit atomics when offered,
    False = force the two-pass fallback, True = require them), ``page_bytes`` (largest
    point page; default the adapter's storage-binding limit), ``memory_budget`` (bytes of
    point data kept on the GPU).
    """

    name = "wgpu"

    def __init__(
        self,
        require_hardware: bool = False,
        *,
        atomics64: bool | None = None,
        page_bytes: int | None = None,
        memory_budget: int = DEFAULT_MEMORY_BUDGET,
    ) -> None:
        if not (isinstance(memory_budget, (int, np.integer)) and memory_budget >= 1 << 16):
            raise GigapointError(f"wgpu backend: memory_budget must be an integer >= 65536 bytes, got {memory_budget!r}")
        if page_bytes is not None and not (isinstance(page_bytes, (int, np.integer)) and page_bytes >= 16):
            raise GigapointError(f"wgpu backend: page_bytes must be an integer >= 16, got {page_bytes!r}")
        wgpu = _import_wgpu()
        self.adapter = _pick_adapter(wgpu, require_hardware)
        info = self.adapter.info
        offered = set(self.adapter.features)
        has64 = all(f in offered for f in _INT64_FEATURES)
        if atomics64 and not has64:
            raise BackendUnavailableError(
                f"wgpu backend: adapter {info.get('device')} has no 64-bit atomics (needs {', '.join(_INT64_FEATURES)})"
            )
        atomics64 = has64 if atomics64 is None else bool(atomics64)
        limits = self.adapter.limits
        binding = int(min(limits["max-storage-buffer-binding-size"], limits["max-buffer-size"]))
        required = {"max-storage-buffer-binding-size": binding, "max-buffer-size": int(limits["max-buffer-size"])}
        # WebGPU guarantees 8 storage buffers per stage; HQS binds 9 where the adapter allows
        n_storage = int(limits.get("max-storage-buffers-per-shader-stage", 8))
        if n_storage >= HQS_STORAGE_BUFFERS:
            required["max-storage-buffers-per-shader-stage"] = min(n_storage, TRANSPARENCY_STORAGE_BUFFERS)
        all_ops = atomics64 and _ALL_OPS in offered  # the transparency pass on the GPU (else the CPU's)
        try:
            with _quiet_wayland_probe():
                device = self.adapter.request_device_sync(
                    label="gigapoint",
                    required_features=[*_INT64_FEATURES, *([_ALL_OPS] if all_ops else [])] if atomics64 else [],
                    required_limits=required,
                )
        except Exception as exc:  # noqa: BLE001 - wgpu-native reports failures with many types
            raise BackendUnavailableError(f"wgpu backend: cannot open device {info.get('device')} ({exc}); {_INSTALL_HINT}") from None
        # Three point words of one page must fit the budget together; whole 16-byte rows
        # so the prefetch view (vec4) of a page stays within one binding.
        limit = min(binding, int(memory_budget) // 4, binding if page_bytes is None else int(page_bytes))
        #: The device, its buffers and the draw loop, shared with the passes.
        self.ctx = GpuContext(wgpu, device, binding, max(4, limit // 16 * 4), memory_budget, atomics64, n_storage >= HQS_STORAGE_BUFFERS)
        self.ctx.transparency_on_gpu = all_ops and n_storage >= TRANSPARENCY_STORAGE_BUFFERS
        self.lock = self.ctx.lock  # one frame at a time; re-entrant: reading back a DeviceArray takes it too
        self.info = dict(info)
        #: The image-quality passes on GPU buffers; where the adapter cannot run one, the CPU's.
        self.passes = GpuPasses(self.ctx, CpuPasses())

    @classmethod
    def is_available(cls) -> bool:
        """A GPU device node and the wgpu package exist (no adapter is opened)."""
        return gpu_device_present() and importlib.util.find_spec("wgpu") is not None

    @property
    def device(self):
        return self.ctx.device

    @property
    def atomics64(self) -> bool:
        """One pass of 64-bit atomicMin (else two passes of 32-bit atomics)."""
        return self.ctx.atomics64

    @property
    def max_binding(self) -> int:
        """Bytes of the largest storage binding (a frame's visibility buffer must fit one)."""
        return self.ctx.max_binding

    @property
    def page_points(self) -> int:
        """Points of one page of point words."""
        return self.ctx.page_points

    # ------------------------------------------------------------------ reporting
    def describe(self) -> str:
        i = self.info
        mode = "64-bit atomics" if self.atomics64 else "two-pass 32-bit atomics"
        cache = self.ctx.cache
        return (
            f"wgpu ({i.get('device')}, {i.get('backend_type')}, {i.get('adapter_type')}; {mode}; "
            f"{cache.bytes_resident / 2**20:.1f} MiB of points resident, {cache.bytes_uploaded / 2**20:.1f} MiB uploaded)"
        )

    @property
    def memory(self) -> dict:
        """GPU memory held and moved, in bytes."""
        cache = self.ctx.cache
        frame = sum(b.size for b in self.ctx.frame_buffers.values())
        return {
            "points_resident": cache.bytes_resident,
            "frame_buffers": frame,
            "total_resident": cache.bytes_resident + frame,
            "uploaded": cache.bytes_uploaded,
            "uploads": cache.uploads,
            "evictions": cache.evictions,
            "refreshes": cache.refreshes,
            "refresh_writes": cache.refresh_writes,
            "refresh_seconds": cache.refresh_seconds,
            "budget": cache.budget,
            "page_points": self.ctx.page_points,
        }

    def forget(self, points) -> None:
        """Drop the GPU copies of point buffers (needed only after changing their arrays in place,
        for buffers without a ``version``: memory.py)."""
        extra = (points.ext,) if points.med is None else ()  # the compact layout's streams (core/compact.py)
        for a in (points.low, points.med, points.high, *extra, *color_arrays(points.color)):
            if a is not None:
                self.ctx.cache.forget(a)
        self.ctx.plans.pop(id(points.batches), None)

    # ------------------------------------------------------------------ the interface
    def rasterize(
        self, points, selection, width: int, height: int, near: float, far: float, threads: int | None = None, splat=None,
        step: int = 1, keep_on_device: bool = False,
    ):  # fmt: skip
        """The (height * width,) u64 visibility buffer of the selected batches (``threads`` unused).

        ``splat``: (footprint, size, atten) for points larger than a pixel (render/splats.py)
        and ``step`` (> 1: every step-th point of each batch, a point budget), as the CPU backend.
        ``keep_on_device``: return a DeviceArray instead (the frame's passes read it in place;
        ``np.asarray`` reads it back), once the GPU is done."""
        step = max(1, int(step))
        views = Views.single(selection, near, far)
        ctx = self.ctx
        with ctx.lock:
            n_pixels = int(width) * int(height)
            ctx.check_frame(n_pixels)
            vis = self._draw_views(points, views, int(width), int(height), splat, step, "visibility")
            if keep_on_device:
                ctx.read_back(vis, np.uint64, 1)  # wait for the GPU, so the caller's raster time is real
                return DeviceArray(ctx, "visibility", np.uint64, n_pixels)
            return ctx.read_back(vis, np.uint64, n_pixels)

    def rasterize_views(self, points, ids, bits, matrices, width, height, nears, fars, threads=None, splat=None, step=1) -> np.ndarray:
        """(V, height * width) visibility buffers of V views drawn in ONE pass over batches ``ids``
        (2022 paper, 3.7; the CPU backend's signature): bits (V, k), matrices (V, k, 4, 4) and
        nears/fars (V,) are each view's own. Each workgroup reads its batch's points once and
        writes them into every view's buffer (both atomics paths); views that do not fit one
        buffer binding together, or more than MAX_VIEWS, are drawn in groups."""
        views = Views.of(ids, bits, matrices, nears, fars)
        width, height, step = int(width), int(height), max(1, int(step))
        n_pixels = width * height
        ctx = self.ctx
        with ctx.lock:
            ctx.check_frame(n_pixels)
            out = np.empty((views.n, n_pixels), np.uint64)
            group = max(1, min(MAX_VIEWS, ctx.max_binding // (8 * max(n_pixels, 1))))
            for v0 in range(0, views.n, group):
                part = views.subset(v0, min(views.n, v0 + group))
                vis = self._draw_views(points, part, width, height, splat, step, "views")
                out[v0 : v0 + part.n] = ctx.read_back(vis, np.uint64, part.n * n_pixels).reshape(part.n, n_pixels)
            return out

    def resolve(self, visibility: np.ndarray, color: np.ndarray, background_rgba) -> np.ndarray:
        """u32 RGBA per pixel: the winning point's color or the background."""
        with self.lock:
            return np.asarray(self.passes.resolve(visibility, color, background_rgba)[0])

    def _draw_views(self, points, views: Views, width: int, height: int, splat, step: int, role: str):
        """The visibility buffer (frame buffer ``role``) of ``views``: view v's image at pixels
        v * width * height.., cleared and drawn on the GPU (not read back)."""
        n_pixels = width * height
        if points.n_points > 0xFFFFFFFF:
            raise GigapointError(f"{points.name}: {points.n_points:,} points exceed the 2^32 a visibility buffer can index")
        ctx = self.ctx
        ctx.trim(n_pixels)  # each frame starts here
        vis = ctx.writable(role, views.n * n_pixels * 8)
        ctx.cache.purge_dead()
        ctx.clear(vis, _EMPTY_WORD)  # to EMPTY (all ones) on the GPU rather than uploading a full frame
        footprint, splat_uniforms = ctx.footprint(splat)
        params = {"width": width, "height": height, "step": step, **splat_uniforms}
        passes = ("raster64",) if ctx.atomics64 else ("raster_depth", "raster_index")
        nbytes = views.n * n_pixels * 8
        ctx.draw_batches(points, views, passes, params, footprint, lambda start, stop, pinned: [(vis, nbytes)])
        return vis
