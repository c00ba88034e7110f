"""WgpuBackend: the paper's compute rasterizer on any WebGPU adapter (wgpu-native).

Same interface and same visibility buffer as NumbaCpuBackend: the host selects batches
and builds float32 per-batch matrices (render/selection.py); the GPU decodes, projects and
depth-tests with the CPU kernel's float32 arithmetic, then resolves colors. Points larger
than a pixel (square / round splats, fixed or attenuated size) are drawn by the same
kernels; the image-quality passes (hole filling, HQS, lighting, eye-dome lighting) run on
the GPU too (passes.py), on buffers that stay on the GPU between passes.

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

import os
import sys
import tempfile
import threading
import weakref
from collections import defaultdict
from contextlib import contextmanager

import numpy as np

from ...errors import BackendUnavailableError, GigapointError
from .layout import GPU_BATCH_DTYPE, MAX_VIEWS, PARAMS_DTYPE
from .memory import BufferCache, PagePlan, batch_ends, plan_pages
from .passes import DeviceArray, GpuPasses
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
#: Storage buffers the HQS accumulate pass binds (point words, footprint, visibility, colors, sums).
HQS_STORAGE_BUFFERS = 9
_EMPTY_WORD = 0xFFFFFFFF

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


class _Views:
    """The batches one draw reads and, per view, their precision, matrix and clip range."""

    __slots__ = ("bits", "fars", "ids", "matrices", "nears")

    def __init__(self, ids, bits, matrices, nears, fars) -> None:
        self.ids, self.bits, self.matrices, self.nears, self.fars = ids, bits, matrices, nears, fars

    @property
    def n(self) -> int:
        return len(self.nears)

    @classmethod
    def of(cls, ids, bits, matrices, nears, fars) -> _Views:
        """Checked and converted: ids (k,), bits (V, k), matrices (V, k, 4, 4), nears/fars (V,)."""
        ids = np.asarray(ids, np.int64).reshape(-1)
        nears = np.asarray(nears, np.float32).reshape(-1)
        fars = np.asarray(fars, np.float32).reshape(-1)
        n, k = len(nears), len(ids)
        bits = np.asarray(bits, np.int64)
        matrices = np.asarray(matrices, np.float32)
        if n == 0 or len(fars) != n or bits.shape != (n, k) or matrices.shape != (n, k, 4, 4):
            raise GigapointError(
                f"wgpu backend: views need bits (V, k), matrices (V, k, 4, 4) and V nears/fars for k = {k} batches; "
                f"got bits {bits.shape}, matrices {matrices.shape}, {n} nears, {len(fars)} fars"
            )
        return cls(ids, bits.astype(np.uint32), matrices, nears, fars)

    def subset(self, v0: int, v1: int) -> _Views:
        return _Views(self.ids, self.bits[v0:v1], self.matrices[v0:v1], self.nears[v0:v1], self.fars[v0:v1])


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
        required = {"max-storage-buffer-binding-size": binding, "max-buffer-size": int(limits["max-buffer-size"])}
        # WebGPU guarantees 8 storage buffers per stage; HQS binds 9 where the adapter allows
        n_storage = int(limits.get("max-storage-buffers-per-shader-stage", 8))
        if n_storage >= HQS_STORAGE_BUFFERS:
            required["max-storage-buffers-per-shader-stage"] = HQS_STORAGE_BUFFERS
        try:
            with _quiet_wayland_probe():
                self.device = self.adapter.request_device_sync(
                    label="gigapoint",
                    required_features=list(_INT64_FEATURES) if self.atomics64 else [],
                    required_limits=required,
                )
        except Exception as exc:  # noqa: BLE001 - wgpu-native reports failures with many types
            raise BackendUnavailableError(f"wgpu backend: cannot open device {info.get('device')} ({exc}); {_INSTALL_HINT}") from None
        self.max_binding = binding
        #: HQS runs on the GPU (else it falls back to the CPU pass on read-back buffers).
        self.hqs_on_gpu = n_storage >= HQS_STORAGE_BUFFERS
        # Three point words of one page must fit the budget together; whole 16-byte rows
        # so the prefetch view (vec4) of a page stays within one binding.
        limit = min(binding, int(memory_budget) // 4, binding if page_bytes is None else int(page_bytes))
        self.page_points = max(4, limit // 16 * 4)
        self.cache = BufferCache(self.device, memory_budget)
        self._plans: dict[int, PagePlan] = {}
        self._pipelines: dict[tuple[str, int], object] = {}
        self._modules: dict[str, object] = {}
        self._frame_buffers: dict[str, object] = {}
        self._dummy = self.device.create_buffer(size=16, usage=wgpu.BufferUsage.STORAGE)
        # One instance serves every caller (registry); frames go one at a time. Re-entrant:
        # reading back a DeviceArray takes it too.
        self._lock = threading.RLock()
        # Frame buffers by role, and which results still read them: a role's generation
        # goes up each time it is written; DeviceArrays of an older generation are stale.
        self._generation: dict[str, int] = defaultdict(int)
        self._arrays: weakref.WeakSet = weakref.WeakSet()
        self._host_copies: dict[str, tuple] = {}  # role -> (weakref to the numpy array it equals, generation)
        self.info = dict(info)
        #: The image-quality passes on GPU buffers (render/passes calls them when present).
        self.passes = GpuPasses(self)

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
            "refreshes": self.cache.refreshes,
            "budget": self.cache.budget,
            "page_points": self.page_points,
        }

    def forget(self, cloud) -> None:
        """Drop a cloud's GPU copies (needed only after changing its arrays in place, for clouds
        without a ``version`` counter: memory.py)."""
        for a in (cloud.low, cloud.med, cloud.high, cloud.color):
            self.cache.forget(a)
        self._plans.pop(id(cloud.batches), None)

    # ------------------------------------------------------------------ plumbing
    def _pipeline(self, pass_name: str, views: int = 1):
        """The compute pipeline of a pass; draw passes per number of views (common.wgsl's
        VIEWS override: the one-view pipeline compiles without the views loops)."""
        key = (pass_name, views)
        if key not in self._pipelines:
            module = self._modules.get(pass_name)
            if module is None:
                module = self._modules[pass_name] = self.device.create_shader_module(label=pass_name, code=shader_source(pass_name))
            compute = {"module": module, "entry_point": "main"}
            if views != 1:
                compute["constants"] = {"VIEWS": views}
            self._pipelines[key] = self.device.create_compute_pipeline(label=f"{pass_name} x{views}", layout="auto", compute=compute)
        return self._pipelines[key]

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
        """The cloud's pages. Clouds with a ``version`` (an LOD arena) refill their batches in
        place: their pages span each batch's room up to the next, so they stay put while
        counts change, and are planned again if a batch outgrows them."""
        for key in [k for k, p in self._plans.items() if p.ref() is None]:
            del self._plans[key]
        batches = cloud.batches
        plan = self._plans.get(id(batches))
        if getattr(cloud, "version", None) is None:
            if plan is None or plan.ref() is not batches:
                starts, stops, page_of = plan_pages(batches, self.page_points)
                plan = PagePlan(weakref.ref(batches), starts, stops, page_of)
                self._plans[id(batches)] = plan
            return plan
        ends = batch_ends(batches, self.page_points, len(cloud.low))
        if plan is None or plan.ref() is not batches or plan.ends is None or not np.array_equal(plan.ends, ends):
            starts, stops, page_of = plan_pages(batches, self.page_points, ends)
            plan = PagePlan(weakref.ref(batches), starts, stops, page_of, ends)
            self._plans[id(batches)] = plan
        return plan

    def _dispatch(self, pass_name: str, entries: list, groups: int, views: int = 1) -> None:
        """Record and submit one dispatch of ``groups`` workgroups (2D past 65535); ``views``:
        of a draw pass (common.wgsl)."""
        pipeline = self._pipeline(pass_name, views)
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

    # ------------------------------------------------------------------ frame buffers between passes
    def _writable(self, role: str, nbytes: int, usage: int):
        """The role's buffer, about to be overwritten: results still reading it are read
        back first (DeviceArray), so no array ever changes under its holder."""
        for array in list(self._arrays):
            if array.role == role:
                array.materialise()
        self._generation[role] += 1
        self._host_copies.pop(role, None)
        return self._frame_buffer(role, nbytes, usage)

    def _remember_host_copy(self, role: str, array: np.ndarray) -> None:
        """``array`` (just read back) equals the role's buffer: passes given it use the buffer."""
        self._host_copies[role] = (weakref.ref(array), self._generation[role])

    def _device_input(self, x, roles: tuple[str, str], dtype, n: int) -> tuple[object, str]:
        """(buffer, role) holding ``x`` (n items of ``dtype``): its own buffer if it is a
        DeviceArray or the array rasterize returned, else uploaded into the first of ``roles``
        (the pass then writes the second)."""
        if isinstance(x, DeviceArray) and x.backend is self and x.valid:
            if x.shape != (n,) or x.dtype != np.dtype(dtype):
                raise GigapointError(f"wgpu backend: a pass needs {n:,} values of {np.dtype(dtype)}, got {x.shape} {x.dtype}")
            return self._frame_buffers[x.role], x.role
        if isinstance(x, np.ndarray):
            for role, (ref, generation) in self._host_copies.items():
                if ref() is x and self._generation[role] == generation and role in self._frame_buffers:
                    return self._frame_buffers[role], role
        host = np.ascontiguousarray(np.asarray(x), dtype).reshape(-1)
        if host.shape != (n,):
            raise GigapointError(f"wgpu backend: a pass needs {n:,} values, got {host.shape[0]:,}")
        role = roles[0]
        usage = self._wgpu.BufferUsage
        buf = self._writable(role, host.nbytes, usage.STORAGE | usage.COPY_SRC | usage.COPY_DST)
        self.device.queue.write_buffer(buf, 0, host)
        return buf, role

    def _output(self, roles: tuple[str, str], avoid: str, nbytes: int) -> tuple[object, str]:
        """A buffer of the pair ``roles`` other than ``avoid`` (ping-pong), ready to be written."""
        role = roles[1] if roles[0] == avoid else roles[0]
        usage = self._wgpu.BufferUsage
        return self._writable(role, nbytes, usage.STORAGE | usage.COPY_SRC | usage.COPY_DST), role

    # ------------------------------------------------------------------ the interface
    def rasterize(
        self,
        cloud,
        selection,
        width: int,
        height: int,
        near: float,
        far: float,
        threads: int | None = None,
        splat=None,
        step: int = 1,
        keep_on_device: bool = False,
    ) -> np.ndarray:
        """The (height * width,) u64 visibility buffer of the selected batches (``threads`` unused).

        ``splat``: (footprint, size, atten) for points larger than a pixel (render/passes/splats.py)
        and ``step`` (> 1: every step-th point of each batch, a point budget), as the CPU backend.
        ``keep_on_device``: return a DeviceArray instead (the frame's passes read it in place;
        ``np.asarray`` reads it back), once the GPU is done."""
        step = max(1, int(step))
        views = _Views.of(selection.ids, np.asarray(selection.bits)[None], np.asarray(selection.matrices)[None], [near], [far])
        with self._lock:
            n_pixels = int(width) * int(height)
            self._check_frame(n_pixels)
            vis = self._draw_views(cloud, views, int(width), int(height), splat, step, "visibility")
            if keep_on_device:
                self._read_back(vis, np.uint64, 1)  # wait for the GPU, so the caller's raster time is real
                return DeviceArray(self, "visibility", np.uint64, n_pixels)
            out = self._read_back(vis, np.uint64, n_pixels)
            self._remember_host_copy("visibility", out)
            return out

    def rasterize_views(self, cloud, ids, bits, matrices, width, height, nears, fars, threads=None, splat=None, step=1) -> np.ndarray:
        """(V, height * width) visibility buffers of V views drawn in ONE pass over batches ``ids``
        (2022 paper, 3.7; the CPU backend's signature): bits (V, k), matrices (V, k, 4, 4) and
        nears/fars (V,) are each view's own. Each workgroup reads its batch's points once and
        writes them into every view's buffer (both atomics paths); views that do not fit one
        buffer binding together, or more than MAX_VIEWS, are drawn in groups."""
        views = _Views.of(ids, bits, matrices, nears, fars)
        width, height, step = int(width), int(height), max(1, int(step))
        n_pixels = width * height
        with self._lock:
            self._check_frame(n_pixels)
            out = np.empty((views.n, n_pixels), np.uint64)
            group = max(1, min(MAX_VIEWS, self.max_binding // (8 * max(n_pixels, 1))))
            for v0 in range(0, views.n, group):
                part = views.subset(v0, min(views.n, v0 + group))
                vis = self._draw_views(cloud, part, width, height, splat, step, "views")
                out[v0 : v0 + part.n] = self._read_back(vis, np.uint64, part.n * n_pixels).reshape(part.n, n_pixels)
            return out

    def resolve(self, visibility: np.ndarray, color: np.ndarray, background_rgba) -> np.ndarray:
        """u32 RGBA per pixel: the winning point's color or the background."""
        with self._lock:
            return np.asarray(self.passes.resolve(visibility, color, background_rgba))

    def _footprint(self, splat, softness: float = 0.0) -> tuple[object, dict]:
        """(GPU footprint rows (dx, dy, need, weight), splat uniforms) of ``splat`` (None: one pixel)."""
        from ..numba_cpu.passes import soft_weight  # the CPU kernels' weight, so both agree

        if splat is None:
            fp, size, atten = np.array([[0, 0, 1]], np.int32), np.float32(1.0), np.float32(0.0)
        else:
            fp, size, atten = np.asarray(splat[0], np.int32).reshape(-1, 3), np.float32(splat[1]), np.float32(splat[2])
        rows = np.ones((len(fp), 4), np.int32)
        rows[:, :3] = fp
        if softness > 0 and len(fp) > 1:
            if atten == 0:  # fixed size: the host's float64 weights
                rows[:, 3] = [int(soft_weight(int(dx), int(dy), size, float(softness))) for dx, dy, _ in fp]
            else:  # per-point size: the shader computes it
                rows[:, 3] = -1
        usage = self._wgpu.BufferUsage
        buf = self._frame_buffer("footprint", rows.nbytes, usage.STORAGE | usage.COPY_DST)
        self.device.queue.write_buffer(buf, 0, rows)
        uniforms = {"fp_count": len(fp), "point_size": size, "atten": atten, "softness": np.float32(softness)}
        return (buf, rows.nbytes), uniforms

    def _draw_batches(self, cloud, views: _Views, pass_names, params: dict, footprint, extra) -> None:
        """Dispatch ``pass_names`` (draw passes: common.wgsl's bindings 0-6) over the batches of
        ``views``, page by page, each workgroup drawing one batch into every view;
        ``extra(start, stop, pinned)`` gives the pass's own bindings (7...) for the page of
        points start..stop."""
        ids = views.ids
        if not len(ids):
            return
        n_views, k = views.n, len(ids)
        if n_views > MAX_VIEWS:
            raise GigapointError(f"wgpu backend: one dispatch draws at most {MAX_VIEWS} views, got {n_views}")
        usage = self._wgpu.BufferUsage
        # arrays that an LOD arena rewrites between frames: pages are checked against its version
        self.cache.track(cloud, (cloud.low, cloud.med, cloud.high, getattr(cloud, "color", None)))
        plan = self._plan(cloud)
        pages = plan.page_of[ids]
        order = np.argsort(pages, kind="stable")  # one run of records per page
        ids, pages = ids[order], pages[order]
        chosen = cloud.batches[ids]
        bounds = np.flatnonzero(np.diff(pages)) + 1
        runs = list(zip(np.concatenate([[0], bounds]).tolist(), np.concatenate([bounds, [k]]).tolist()))
        # per page run r0..r1 (one dispatch), its records view by view: view v's record of
        # the run's b-th batch is record V * r0 + v * (r1 - r0) + b
        run_start = np.repeat([r0 for r0, _ in runs], [r1 - r0 for r0, r1 in runs])
        run_len = np.repeat([r1 - r0 for r0, r1 in runs], [r1 - r0 for r0, r1 in runs])
        j = np.arange(k)
        slot = n_views * run_start + np.arange(n_views)[:, None] * run_len + (j - run_start)  # (V, k)
        records = np.zeros(n_views * k, GPU_BATCH_DTYPE)
        records["rows"][slot] = views.matrices[:, order]
        records["first"][slot] = chosen["first"]
        records["local_first"][slot] = chosen["first"].astype(np.int64) - plan.starts[pages]
        records["count"][slot] = chosen["count"]
        records["bits"][slot] = views.bits[:, order]
        rec_buf = self._frame_buffer("records", records.nbytes, usage.STORAGE | usage.COPY_DST)
        self.device.queue.write_buffer(rec_buf, 0, records)
        table = np.zeros((MAX_VIEWS, 4), np.float32)
        table[:n_views, 0] = views.nears
        table[:n_views, 1] = views.fars
        view_bits = views.bits[:, order]
        for pass_name in pass_names:
            for r0, r1 in runs:
                p = int(pages[r0])
                start, stop = int(plan.starts[p]), int(plan.stops[p])
                max_bits = int(view_bits[:, r0:r1].max())
                pinned: set = set()
                words = [self.cache.get(cloud.low, start, stop, pinned)]
                # Medium/high words go to the GPU only once a frame needs them.
                words.append(self.cache.get(cloud.med, start, stop, pinned) if max_bits >= 20 else self._dummy)
                words.append(self.cache.get(cloud.high, start, stop, pinned) if max_bits >= 30 else self._dummy)
                own = extra(start, stop, pinned)
                uniform = self._params(
                    **params, batch_offset=n_views * r0, batch_count=r1 - r0, page_first=start, page_count=stop - start,
                    near=table[0, 0], far=table[0, 1], views=table,
                )  # fmt: skip
                entries = [(uniform, PARAMS_DTYPE.itemsize), (rec_buf, records.nbytes)]
                entries += [(w, w.size) for w in words]
                entries.append((words[0], words[0].size // 16 * 16))  # low again, as vec4 (prefetch)
                entries.append(footprint)
                self._dispatch(pass_name, entries + own, r1 - r0, n_views)

    def _draw_views(self, cloud, views: _Views, width: int, height: int, splat, step: int, role: str):
        """The visibility buffer (frame buffer ``role``) of ``views``: view v's image at pixels
        v * width * height.., cleared and drawn on the GPU (not read back)."""
        n_pixels = width * height
        if cloud.n_points > 0xFFFFFFFF:
            raise GigapointError(f"{cloud.name}: {cloud.n_points:,} points exceed the 2^32 a visibility buffer can index")
        usage = self._wgpu.BufferUsage
        vis = self._writable(role, views.n * n_pixels * 8, usage.STORAGE | usage.COPY_SRC | usage.COPY_DST)
        self.cache.purge_dead()
        # Clear to EMPTY (all ones) on the GPU rather than uploading a full frame.
        self._clear(vis, _EMPTY_WORD)
        footprint, splat_uniforms = self._footprint(splat)
        params = {"width": width, "height": height, "step": step, **splat_uniforms}
        passes = ("raster64",) if self.atomics64 else ("raster_depth", "raster_index")
        nbytes = views.n * n_pixels * 8
        self._draw_batches(cloud, views, passes, params, footprint, lambda start, stop, pinned: [(vis, nbytes)])
        return vis

    def _clear(self, buffer, value: int) -> None:
        """Every u32 of ``buffer`` = value, in 16-byte rows (buffers are allocated in whole rows)."""
        rows = buffer.size // 16
        uniform = self._params(n_items=rows, fill=value)
        self._dispatch("clear", [(uniform, PARAMS_DTYPE.itemsize), (buffer, buffer.size)], self._linear_groups(rows))
