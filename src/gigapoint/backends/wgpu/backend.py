"""WgpuBackend: the paper's compute rasterizer on any WebGPU adapter (wgpu-native).

Same interface and same visibility buffer as NumbaCpuBackend: the host selects batches
and builds float32 per-batch matrices (render/selection.py); the GPU decodes, projects and
depth-tests with the CPU kernel's float32 arithmetic, then resolves colors.

Where the adapter offers 64-bit atomics (``shader-int64-atomic-min-max``) one pass does
``atomicMin(depth << 32 | index)``; otherwise two passes of 32-bit atomics give the
identical buffer. Point words are uploaded once per cloud, in pages of whole batches that
fit one storage binding, and kept within a memory budget (memory.py); medium/high words
only once a frame draws a batch at 20/30 bits.

Adapters: Vulkan, Metal or D3D12 (wgpu's OpenGL backend is not used: no 64-bit atomics,
small storage limits); a hardware GPU is preferred, Mesa lavapipe serves where none is.
"""

from __future__ import annotations

import os
import sys
import tempfile
import threading
import weakref
from contextlib import contextmanager

import numpy as np

from ...errors import BackendUnavailableError, GigapointError
from .layout import GPU_BATCH_DTYPE, PARAMS_DTYPE
from .memory import BufferCache, PagePlan, plan_pages
from .shaders import shader_source

_INSTALL_HINT = (
    "install with: pip install 'gigapoint[gpu]' (and a Vulkan driver; on Linux without a GPU: apt-get install mesa-vulkan-drivers)"
)
_INT64_FEATURES = ("shader-int64", "shader-int64-atomic-min-max")
_TYPE_RANK = {"DiscreteGPU": 0, "IntegratedGPU": 1, "Unknown": 2, "CPU": 3}
_MAX_GROUPS = 65535  # WebGPU's guaranteed workgroups per dispatch dimension
_LINEAR_WORKGROUP = 256  # clear / resolve workgroup size
# Clear / resolve loop over their items (grid stride): 1024 x 256 threads fill any GPU,
# and CPU drivers pay per workgroup (lavapipe: clear 3-4x faster than with 65535).
_LINEAR_GROUPS_MAX = 1024

#: Default bound on GPU memory held for point data (bytes). Frames whose selection needs
#: more are drawn page by page, re-uploading what was evicted.
DEFAULT_MEMORY_BUDGET = 2 << 30


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
        self._wgpu = wgpu
        self.adapter = _pick_adapter(wgpu, require_hardware)
        info = self.adapter.info
        offered = set(self.adapter.features)
        has64 = all(f in offered for f in _INT64_FEATURES)
        if atomics64 and not has64:
            raise BackendUnavailableError(
                f"wgpu backend: adapter {info.get('device')} has no 64-bit atomics (needs {', '.join(_INT64_FEATURES)})"
            )
        self.atomics64 = has64 if atomics64 is None else bool(atomics64)
        limits = self.adapter.limits
        binding = int(min(limits["max-storage-buffer-binding-size"], limits["max-buffer-size"]))
        try:
            with _quiet_wayland_probe():
                self.device = self.adapter.request_device_sync(
                    label="gigapoint",
                    required_features=list(_INT64_FEATURES) if self.atomics64 else [],
                    required_limits={"max-storage-buffer-binding-size": binding, "max-buffer-size": int(limits["max-buffer-size"])},
                )
        except Exception as exc:  # noqa: BLE001 - wgpu-native reports failures with many types
            raise BackendUnavailableError(f"wgpu backend: cannot open device {info.get('device')} ({exc}); {_INSTALL_HINT}") from None
        self.max_binding = binding
        # Three point words of one page must fit the budget together; whole 16-byte rows
        # so the prefetch view (vec4) of a page stays within one binding.
        limit = min(binding, int(memory_budget) // 4, binding if page_bytes is None else int(page_bytes))
        self.page_points = max(4, limit // 16 * 4)
        self.cache = BufferCache(self.device, memory_budget)
        self._plans: dict[int, PagePlan] = {}
        self._pipelines: dict[str, object] = {}
        self._frame_buffers: dict[str, object] = {}
        self._dummy = self.device.create_buffer(size=16, usage=wgpu.BufferUsage.STORAGE)
        self._lock = threading.Lock()  # one instance serves every caller (registry); frames go one at a time
        self.info = dict(info)

    # ------------------------------------------------------------------ reporting
    def describe(self) -> str:
        i = self.info
        mode = "64-bit atomics" if self.atomics64 else "two-pass 32-bit atomics"
        return (
            f"wgpu ({i.get('device')}, {i.get('backend_type')}, {i.get('adapter_type')}; {mode}; "
            f"{self.cache.bytes_resident / 2**20:.1f} MiB of points resident, {self.cache.bytes_uploaded / 2**20:.1f} MiB uploaded)"
        )

    @property
    def memory(self) -> dict:
        """GPU memory held and moved, in bytes."""
        frame = sum(b.size for b in self._frame_buffers.values())
        return {
            "points_resident": self.cache.bytes_resident,
            "frame_buffers": frame,
            "total_resident": self.cache.bytes_resident + frame,
            "uploaded": self.cache.bytes_uploaded,
            "uploads": self.cache.uploads,
            "evictions": self.cache.evictions,
            "budget": self.cache.budget,
            "page_points": self.page_points,
        }

    def forget(self, cloud) -> None:
        """Drop a cloud's GPU copies (needed only after changing its arrays in place)."""
        for a in (cloud.low, cloud.med, cloud.high, cloud.color):
            self.cache.forget(a)
        self._plans.pop(id(cloud.batches), None)

    # ------------------------------------------------------------------ plumbing
    def _pipeline(self, pass_name: str):
        if pass_name not in self._pipelines:
            module = self.device.create_shader_module(label=pass_name, code=shader_source(pass_name))
            self._pipelines[pass_name] = self.device.create_compute_pipeline(
                label=pass_name, layout="auto", compute={"module": module, "entry_point": "main"}
            )
        return self._pipelines[pass_name]

    def _frame_buffer(self, role: str, nbytes: int, usage: int):
        """A reusable per-role buffer of at least ``nbytes`` (visibility, records, image...)."""
        buf = self._frame_buffers.get(role)
        if buf is None or buf.size < nbytes:
            if buf is not None:
                buf.destroy()
            buf = self.device.create_buffer(size=max(16, -(-nbytes // 16) * 16), usage=usage)
            self._frame_buffers[role] = buf
        return buf

    def _params(self, **values):
        p = np.zeros(1, PARAMS_DTYPE)
        for k, v in values.items():
            p[k] = v
        return self.device.create_buffer_with_data(data=p, usage=self._wgpu.BufferUsage.UNIFORM)

    def _plan(self, cloud) -> PagePlan:
        for key in [k for k, p in self._plans.items() if p.ref() is None]:
            del self._plans[key]
        plan = self._plans.get(id(cloud.batches))
        if plan is None or plan.ref() is not cloud.batches:
            starts, stops, page_of = plan_pages(cloud.batches, self.page_points)
            plan = PagePlan(weakref.ref(cloud.batches), starts, stops, page_of)
            self._plans[id(cloud.batches)] = plan
        return plan

    def _dispatch(self, pass_name: str, entries: list, groups: int) -> None:
        """Record and submit one dispatch of ``groups`` workgroups (2D past 65535)."""
        pipeline = self._pipeline(pass_name)
        bind_group = self.device.create_bind_group(
            layout=pipeline.get_bind_group_layout(0),
            entries=[{"binding": i, "resource": {"buffer": b, "offset": 0, "size": s}} for i, (b, s) in enumerate(entries)],
        )
        encoder = self.device.create_command_encoder()
        compute = encoder.begin_compute_pass()
        compute.set_pipeline(pipeline)
        compute.set_bind_group(0, bind_group)
        compute.dispatch_workgroups(min(groups, _MAX_GROUPS), -(-groups // _MAX_GROUPS), 1)
        compute.end()
        # Submitted at once: the next page may evict buffers this one reads.
        self.device.queue.submit([encoder.finish()])

    def _read_back(self, buffer, dtype, n: int) -> np.ndarray:
        """Copy the first ``n`` items of ``buffer`` into a new numpy array (through a kept
        MAP_READ staging buffer: cheaper than a fresh one per frame)."""
        usage = self._wgpu.BufferUsage
        nbytes = n * np.dtype(dtype).itemsize
        staging = self._frame_buffer("staging", nbytes, usage.MAP_READ | usage.COPY_DST)
        encoder = self.device.create_command_encoder()
        encoder.copy_buffer_to_buffer(buffer, 0, staging, 0, nbytes)
        self.device.queue.submit([encoder.finish()])
        staging.map_sync("READ", 0, staging.size)
        try:
            out = np.frombuffer(staging.read_mapped(0, nbytes, copy=False), dtype).copy()
        finally:
            staging.unmap()
        return out

    def _linear_groups(self, n_items: int) -> int:
        return max(1, min(-(-n_items // _LINEAR_WORKGROUP), _LINEAR_GROUPS_MAX))

    def _check_frame(self, n_pixels: int) -> None:
        if n_pixels * 8 > self.max_binding:
            raise GigapointError(
                f"wgpu backend: a {n_pixels:,}-pixel frame needs {n_pixels * 8:,} bytes of visibility buffer, "
                f"more than this adapter binds ({self.max_binding:,}); render smaller or use backend 'cpu'"
            )

    # ------------------------------------------------------------------ the interface
    def rasterize(self, cloud, selection, width: int, height: int, near: float, far: float, threads: int | None = None) -> np.ndarray:
        """The (height * width,) u64 visibility buffer of the selected batches (``threads`` unused)."""
        with self._lock:
            return self._rasterize(cloud, selection, int(width), int(height), float(near), float(far))

    def resolve(self, visibility: np.ndarray, color: np.ndarray, background_rgba) -> np.ndarray:
        """u32 RGBA per pixel: the winning point's color or the background."""
        with self._lock:
            return self._resolve(visibility, color, background_rgba)

    def _rasterize(self, cloud, selection, width: int, height: int, near: float, far: float) -> np.ndarray:
        wgpu = self._wgpu
        n_pixels = int(width) * int(height)
        self._check_frame(n_pixels)
        if cloud.n_points > 0xFFFFFFFF:
            raise GigapointError(f"{cloud.name}: {cloud.n_points:,} points exceed the 2^32 a visibility buffer can index")
        usage = wgpu.BufferUsage
        vis = self._frame_buffer("visibility", n_pixels * 8, usage.STORAGE | usage.COPY_SRC | usage.COPY_DST)
        self.cache.purge_dead()
        params = {"width": width, "height": height, "near": np.float32(near), "far": np.float32(far)}

        # Clear to EMPTY (all ones) on the GPU rather than uploading a full frame; in 16-byte
        # rows (the buffer is allocated in whole rows).
        rows = vis.size // 16
        self._dispatch("clear", [(self._params(n_items=rows), PARAMS_DTYPE.itemsize), (vis, vis.size)], self._linear_groups(rows))

        ids = np.asarray(selection.ids, np.int64)
        if len(ids):
            plan = self._plan(cloud)
            pages = plan.page_of[ids]
            order = np.argsort(pages, kind="stable")  # one run of records per page
            ids, pages = ids[order], pages[order]
            chosen = cloud.batches[ids]
            records = np.zeros(len(ids), GPU_BATCH_DTYPE)
            records["rows"] = np.asarray(selection.matrices, np.float32)[order]
            records["first"] = chosen["first"]
            records["local_first"] = chosen["first"].astype(np.int64) - plan.starts[pages]
            records["count"] = chosen["count"]
            records["bits"] = np.asarray(selection.bits)[order]
            rec_buf = self._frame_buffer("records", records.nbytes, usage.STORAGE | usage.COPY_DST)
            self.device.queue.write_buffer(rec_buf, 0, records)
            bounds = np.flatnonzero(np.diff(pages)) + 1
            runs = list(zip(np.concatenate([[0], bounds]).tolist(), np.concatenate([bounds, [len(ids)]]).tolist()))
            passes = ("raster64",) if self.atomics64 else ("raster_depth", "raster_index")
            for pass_name in passes:
                for r0, r1 in runs:
                    p = int(pages[r0])
                    start, stop = int(plan.starts[p]), int(plan.stops[p])
                    max_bits = int(records["bits"][r0:r1].max())
                    pinned: set = set()
                    words = [self.cache.get(cloud.low, start, stop, pinned)]
                    # Medium/high words go to the GPU only once a frame needs them.
                    words.append(self.cache.get(cloud.med, start, stop, pinned) if max_bits >= 20 else self._dummy)
                    words.append(self.cache.get(cloud.high, start, stop, pinned) if max_bits >= 30 else self._dummy)
                    uniform = self._params(**params, batch_offset=r0, batch_count=r1 - r0)
                    entries = [(uniform, PARAMS_DTYPE.itemsize), (rec_buf, records.nbytes)]
                    entries += [(w, w.size) for w in words]
                    entries.append((words[0], words[0].size // 16 * 16))  # low again, as vec4 (prefetch)
                    entries.append((vis, n_pixels * 8))
                    self._dispatch(pass_name, entries, r1 - r0)

        return self._read_back(vis, np.uint64, n_pixels)

    def _resolve(self, visibility: np.ndarray, color: np.ndarray, background_rgba) -> np.ndarray:
        usage = self._wgpu.BufferUsage
        color = np.ascontiguousarray(color, np.uint32)  # the same array (cache key) when already u32
        visibility = np.ascontiguousarray(visibility, np.uint64).reshape(-1)
        n_pixels = visibility.shape[0]
        self._check_frame(n_pixels)
        bg = int(np.array(background_rgba, np.uint8).view(np.uint32)[0])
        # rasterize's buffer: its content was read back already
        vis = self._frame_buffer("visibility", n_pixels * 8, usage.STORAGE | usage.COPY_SRC | usage.COPY_DST)
        self.device.queue.write_buffer(vis, 0, visibility)
        image = self._frame_buffer("image", n_pixels * 4, usage.STORAGE | usage.COPY_SRC)
        self.cache.purge_dead()
        n_colors = len(color)
        step = self.page_points
        for start in range(0, max(n_colors, 1), step):
            stop = min(start + step, n_colors)
            colors = self.cache.get(color, start, stop, set()) if stop > start else self._dummy
            uniform = self._params(n_items=n_pixels, page_first=start, page_count=stop - start, background=bg)
            entries = [(uniform, PARAMS_DTYPE.itemsize), (vis, n_pixels * 8), (colors, colors.size), (image, n_pixels * 4)]
            self._dispatch("resolve", entries, self._linear_groups(n_pixels))
        return self._read_back(image, np.uint32, n_pixels)
