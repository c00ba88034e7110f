"""GpuContext: one wgpu device and everything the raster and the passes share on it.

Pipelines (one per pass and view count), reusable frame buffers by role, uniforms,
dispatches, read-back, the page cache of point words (memory.py), and the draw loop
(``draw_batches``) that the rasterizer and HQS both run over a selection's batches.
``WgpuBackend`` (backend.py) and ``GpuPasses`` (passes.py) both work through it, so
neither reaches into the other.

Frame buffers by role pass results between passes without a read-back: a pass writes one
buffer of a pair (ping-pong, ``output``), so an input is never overwritten by the pass
reading it; a :class:`DeviceArray` names a result and reads it back once when asked.
"""

from __future__ import annotations

import threading
import weakref
from collections import defaultdict

import numpy as np

from ...core.compact import color_arrays, ext_bits_per_point, stream_words
from ...core.layout import EXT_FULL_BITS
from ...errors import GigapointError
from ...render.params import soft_weight
from ...render.splats import ONE_PIXEL
from .layout import FULL_LAYOUT, GPU_BATCH_DTYPE, MAX_VIEWS, PARAMS_DTYPE
from .memory import BufferCache, PagePlan, batch_ends, plan_pages
from .shaders import shader_source

_MAX_GROUPS = 65535  # WebGPU's guaranteed workgroups per dispatch dimension
_LINEAR_WORKGROUP = 256  # clear / resolve workgroup size
# Clear / resolve loop over their items (grid stride): 1024 x 256 threads fill any GPU,
# and CPU drivers pay per workgroup (lavapipe: clear 3-4x faster than with 65535).
_LINEAR_GROUPS_MAX = 1024
#: Frame buffers up to this size are kept whatever the frame size (GpuContext.trim).
_TRIM_FLOOR = 64 << 20


class DeviceArray:
    """A pass result held in a GPU frame buffer; ``np.asarray`` reads it back (once).

    1-D, ``dtype`` uint64 (visibility) or uint32 (RGBA). Valid until its buffer is written
    again, which first reads it back if the array is still referenced."""

    __slots__ = ("__weakref__", "_host", "ctx", "dtype", "generation", "role", "shape")

    def __init__(self, ctx: GpuContext, role: str, dtype, n: int) -> None:
        self.ctx = ctx
        self.role = role
        self.generation = ctx.generation[role]
        self.dtype = np.dtype(dtype)
        self.shape = (int(n),)
        self._host: np.ndarray | None = None
        ctx.arrays.add(self)

    @property
    def valid(self) -> bool:
        """True while the GPU buffer still holds this array."""
        return self.ctx.generation[self.role] == self.generation

    @property
    def size(self) -> int:
        return self.shape[0]

    def __len__(self) -> int:
        return self.shape[0]

    def materialise(self) -> np.ndarray:
        """The values as a numpy array (read back on first use)."""
        if self._host is None:
            with self.ctx.lock:
                if self._host is None:
                    if not self.valid:  # cannot happen: buffers are read back before reuse
                        raise GigapointError(f"wgpu backend: the {self.role} buffer was overwritten before it was read")
                    self._host = self.ctx.read_back(self.ctx.frame_buffers[self.role], self.dtype, self.shape[0])
        return self._host

    def __array__(self, dtype=None, copy=None):
        a = self.materialise()
        if dtype is not None and np.dtype(dtype) != a.dtype:
            return a.astype(dtype)
        return a.copy() if copy else a

    def __repr__(self) -> str:
        state = "read back" if self._host is not None else "on the GPU"
        return f"DeviceArray({self.shape[0]:,} x {self.dtype}, {self.role}, {state})"


class Views:
    """The batches one draw reads and, per view, their precision, matrix and clip range."""

    __slots__ = ("bits", "fars", "ids", "matrices", "nears")

    def __init__(self, ids, bits, matrices, nears, fars) -> None:
        self.ids, self.bits, self.matrices, self.nears, self.fars = ids, bits, matrices, nears, fars

    @property
    def n(self) -> int:
        return len(self.nears)

    @classmethod
    def of(cls, ids, bits, matrices, nears, fars) -> Views:
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

    @classmethod
    def single(cls, selection, near: float, far: float) -> Views:
        """The one view of a Selection."""
        return cls.of(selection.ids, np.asarray(selection.bits)[None], np.asarray(selection.matrices)[None], [near], [far])

    def subset(self, v0: int, v1: int) -> Views:
        return Views(self.ids, self.bits[v0:v1], self.matrices[v0:v1], self.nears[v0:v1], self.fars[v0:v1])


class GpuContext:
    """A wgpu device with its pipelines, frame buffers, point-page cache and draw loop.

    ``max_binding``: the largest storage binding; ``page_points``: points of one page of
    point words; ``hqs_on_gpu``: the adapter binds the 9 storage buffers HQS needs;
    ``transparency_on_gpu``: the device has what the transparency pass needs (set by WgpuBackend)."""

    transparency_on_gpu = False

    def __init__(self, wgpu, device, max_binding: int, page_points: int, memory_budget: int, atomics64: bool, hqs_on_gpu: bool) -> None:
        self.wgpu = wgpu
        self.device = device
        self.max_binding = max_binding
        self.page_points = page_points
        self.atomics64 = atomics64
        self.hqs_on_gpu = hqs_on_gpu
        self.cache = BufferCache(device, memory_budget)
        self.plans: dict[int, PagePlan] = {}
        self.pipelines: dict[tuple[str, int], object] = {}
        self.modules: dict[str, object] = {}
        self.frame_buffers: dict[str, object] = {}
        self.dummy = device.create_buffer(size=16, usage=wgpu.BufferUsage.STORAGE)
        # One context serves every caller; frames go one at a time. Re-entrant: reading
        # back a DeviceArray takes it too.
        self.lock = threading.RLock()
        # A role's generation goes up each time its buffer is written; DeviceArrays of an older one are stale.
        self.generation: dict[str, int] = defaultdict(int)
        self.arrays: weakref.WeakSet = weakref.WeakSet()

    # ------------------------------------------------------------------ pipelines and dispatch
    def pipeline(self, pass_name: str, views: int = 1):
        """The compute pipeline of a pass; draw passes per number of views (common.wgsl's
        VIEWS override: the one-view pipeline compiles without the views loops)."""
        key = (pass_name, views)
        if key not in self.pipelines:
            module = self.modules.get(pass_name)
            if module is None:
                module = self.modules[pass_name] = self.device.create_shader_module(label=pass_name, code=shader_source(pass_name))
            compute = {"module": module, "entry_point": "main"}
            if views != 1:
                compute["constants"] = {"VIEWS": views}
            self.pipelines[key] = self.device.create_compute_pipeline(label=f"{pass_name} x{views}", layout="auto", compute=compute)
        return self.pipelines[key]

    def uniform(self, **values) -> tuple[object, int]:
        """A Params uniform binding (layout.PARAMS_DTYPE) with ``values`` set, the rest zero."""
        p = np.zeros(1, PARAMS_DTYPE)
        for k, v in values.items():
            p[k] = v
        return self.device.create_buffer_with_data(data=p, usage=self.wgpu.BufferUsage.UNIFORM), PARAMS_DTYPE.itemsize

    def dispatch(self, pass_name: str, entries: list, groups: int, views: int = 1) -> None:
        """Record and submit one dispatch of ``groups`` workgroups (2D past 65535); ``views``:
        of a draw pass (common.wgsl)."""
        pipeline = self.pipeline(pass_name, views)
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

    def dispatch_screen(self, pass_name: str, entries: list, n_items: int) -> None:
        """A pass over pixels or words: grid-stride loops over ``n_items``."""
        self.dispatch(pass_name, entries, max(1, min(-(-n_items // _LINEAR_WORKGROUP), _LINEAR_GROUPS_MAX)))

    def copy(self, src, dst, nbytes: int) -> None:
        encoder = self.device.create_command_encoder()
        encoder.copy_buffer_to_buffer(src, 0, dst, 0, nbytes)
        self.device.queue.submit([encoder.finish()])

    def clear(self, buffer, value: int) -> None:
        """Every u32 of ``buffer`` = value, in 16-byte rows (buffers are allocated in whole rows)."""
        rows = buffer.size // 16
        self.dispatch_screen("clear", [self.uniform(n_items=rows, fill=value), (buffer, buffer.size)], rows)

    # ------------------------------------------------------------------ buffers
    def frame_buffer(self, role: str, nbytes: int, usage: int):
        """A reusable per-role buffer of at least ``nbytes`` (visibility, records, image...)."""
        buf = self.frame_buffers.get(role)
        if buf is None or buf.size < nbytes:
            if buf is not None:
                buf.destroy()
            buf = self.device.create_buffer(size=max(16, -(-nbytes // 16) * 16), usage=usage)
            self.frame_buffers[role] = buf
        return buf

    def table(self, role: str, rows: np.ndarray) -> tuple[object, int]:
        """A small per-frame table (offsets, windows) as a storage binding."""
        usage = self.wgpu.BufferUsage
        rows = np.ascontiguousarray(rows)
        buf = self.frame_buffer(role, rows.nbytes, usage.STORAGE | usage.COPY_DST)
        self.device.queue.write_buffer(buf, 0, rows)
        return buf, max(16, rows.nbytes)

    def read_back(self, buffer, dtype, n: int) -> np.ndarray:
        """Copy the first ``n`` items of ``buffer`` into a new numpy array (through a kept
        MAP_READ staging buffer: cheaper than a fresh one per frame)."""
        usage = self.wgpu.BufferUsage
        nbytes = n * np.dtype(dtype).itemsize
        staging = self.frame_buffer("staging", nbytes, usage.MAP_READ | usage.COPY_DST)
        self.copy(buffer, staging, nbytes)
        staging.map_sync("READ", 0, staging.size)
        try:
            out = np.frombuffer(staging.read_mapped(0, nbytes, copy=False), dtype).copy()
        finally:
            staging.unmap()
        return out

    def check_frame(self, n_pixels: int) -> None:
        if n_pixels * 8 > self.max_binding:
            raise GigapointError(
                f"wgpu backend: a {n_pixels:,}-pixel frame needs {n_pixels * 8:,} bytes of visibility buffer, "
                f"more than this adapter binds ({self.max_binding:,}); render smaller or use backend 'cpu'"
            )

    def writable(self, role: str, nbytes: int):
        """The role's buffer, about to be overwritten: results still reading it are read
        back first (DeviceArray), so no array ever changes under its holder."""
        self._retire(role)
        usage = self.wgpu.BufferUsage
        return self.frame_buffer(role, nbytes, usage.STORAGE | usage.COPY_SRC | usage.COPY_DST)

    def _retire(self, role: str) -> None:
        """Read back the results still in the role's buffer: it is about to change or go."""
        for array in list(self.arrays):
            if array.role == role:
                array.materialise()
        self.generation[role] += 1

    def trim(self, n_pixels: int) -> None:
        """Free the frame buffers over 64 MiB and over twice what a frame of ``n_pixels`` needs
        (64 bytes a pixel at most: transparency's layers, 8 stereo views), so one big frame's
        buffers (a 4K export) are not held through every small frame after it; the floor spares
        a viewer's full-resolution buffers while it draws small frames in motion."""
        limit = max(_TRIM_FLOOR, 128 * n_pixels)
        for role in [r for r, b in self.frame_buffers.items() if b.size > limit]:
            self._retire(role)  # reading back may make the staging buffer big: freed below
        for role in [r for r, b in self.frame_buffers.items() if b.size > limit]:
            self.frame_buffers.pop(role).destroy()

    def device_input(self, x, roles: tuple[str, str], dtype, n: int) -> tuple[object, str]:
        """(buffer, role) holding ``x`` (n items of ``dtype``): its own buffer if it is a
        DeviceArray, else uploaded into the first of ``roles`` (the pass then writes the second)."""
        if isinstance(x, DeviceArray) and x.ctx is self and x.valid:
            if x.shape != (n,) or x.dtype != np.dtype(dtype):
                raise GigapointError(f"wgpu backend: a pass needs {n:,} values of {np.dtype(dtype)}, got {x.shape} {x.dtype}")
            return self.frame_buffers[x.role], x.role
        # a numpy array is uploaded, even the one rasterize returned: its holder may have changed it
        host = np.ascontiguousarray(np.asarray(x), dtype).reshape(-1)
        if host.shape != (n,):
            raise GigapointError(f"wgpu backend: a pass needs {n:,} values, got {host.shape[0]:,}")
        role = roles[0]
        buf = self.writable(role, host.nbytes)
        self.device.queue.write_buffer(buf, 0, host)
        return buf, role

    def output(self, roles: tuple[str, str], avoid: str, nbytes: int) -> tuple[object, str]:
        """A buffer of the pair ``roles`` other than ``avoid`` (ping-pong), ready to be written."""
        role = roles[1] if roles[0] == avoid else roles[0]
        return self.writable(role, nbytes), role

    # ------------------------------------------------------------------ point pages
    def plan(self, points) -> PagePlan:
        """The buffers' pages. Buffers rewritten in place (``version`` not None: an LOD arena)
        have pages that span each batch's room up to the next, so they stay put while counts
        change, and are planned again if a batch outgrows them."""
        for key in [k for k, p in self.plans.items() if p.ref() is None]:
            del self.plans[key]
        batches = points.batches
        plan = self.plans.get(id(batches))
        # a compact cloud's extension streams hold up to 7.5 bytes a point (wide batches):
        # half-size pages keep them within one binding
        page = self.page_points if points.med is not None else max(1, self.page_points // 2)
        if points.version is None:
            if plan is None or plan.ref() is not batches:
                starts, stops, page_of = plan_pages(batches, page)
                plan = PagePlan(weakref.ref(batches), starts, stops, page_of)
                self.plans[id(batches)] = plan
            return plan
        ends = batch_ends(batches, page, len(points.low))
        if plan is None or plan.ref() is not batches or plan.ends is None or not np.array_equal(plan.ends, ends):
            starts, stops, page_of = plan_pages(batches, page, ends)
            plan = PagePlan(weakref.ref(batches), starts, stops, page_of, ends)
            self.plans[id(batches)] = plan
        return plan

    def footprint(self, splat, softness: float = 0.0) -> tuple[tuple[object, int], dict]:
        """(GPU footprint rows (dx, dy, need, weight), splat uniforms) of ``splat`` (None: one pixel)."""
        fp, size, atten = splat if splat is not None else ONE_PIXEL
        fp, size, atten = np.asarray(fp, np.int32).reshape(-1, 3), np.float32(size), np.float32(atten)
        rows = np.ones((len(fp), 4), np.int32)
        rows[:, :3] = fp
        if softness > 0 and len(fp) > 1:
            if atten == 0:  # fixed size: the host's float64 weights, the CPU kernels' own function
                rows[:, 3] = [int(soft_weight(int(dx), int(dy), size, float(softness))) for dx, dy, _ in fp]
            else:  # per-point size: the shader computes it
                rows[:, 3] = -1
        usage = self.wgpu.BufferUsage
        buf = self.frame_buffer("footprint", rows.nbytes, usage.STORAGE | usage.COPY_DST)
        self.device.queue.write_buffer(buf, 0, rows)
        uniforms = {"fp_count": len(fp), "point_size": size, "atten": atten, "softness": np.float32(softness)}
        return (buf, rows.nbytes), uniforms

    def ext_ranges(self, points, plan: PagePlan) -> tuple[np.ndarray, np.ndarray]:
        """Per page of a compact cloud: the u64 words lo..hi of ``points.ext`` its batches' streams
        span. Computed once per plan for a cloud that never changes; for one refilled in place,
        again whenever its streams move (``in_place_ext_ranges``)."""
        pack = points.packing
        if points.version is None:
            if plan.ext_ranges is None:
                counts = points.batches["count"].astype(np.int64)
                first = pack["ext_first"].astype(np.int64)
                end = first + stream_words(ext_bits_per_point(pack, counts), counts)
                lo = np.full(plan.n_pages, np.iinfo(np.int64).max)
                hi = np.zeros(plan.n_pages, np.int64)
                np.minimum.at(lo, plan.page_of, first)
                np.maximum.at(hi, plan.page_of, end)
                plan.ext_ranges = (lo, np.maximum(hi, lo))
            return plan.ext_ranges
        layout = (pack["ext_first"].copy(), pack["code"].copy(), len(points.ext))
        if plan.ext_ranges is None or plan.ext_layout is None or not _same_layout(plan.ext_layout, layout):
            plan.ext_ranges = in_place_ext_ranges(pack, points.batches, plan, len(points.ext), plan.ext_ranges)
            plan.ext_layout = layout
        return plan.ext_ranges

    def draw_batches(self, points, views: Views, pass_names, params: dict, footprint, extra) -> None:
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
        usage = self.wgpu.BufferUsage
        # arrays that an LOD arena rewrites between frames: pages are checked against its version
        self.cache.track(points, (points.low, points.med, points.high, points.ext if points.med is None else None, *color_arrays(points.color)))
        plan = self.plan(points)
        pages = plan.page_of[ids]
        order = np.argsort(pages, kind="stable")  # one run of records per page
        ids, pages = ids[order], pages[order]
        chosen = points.batches[ids]
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
        pack = points.packing if points.med is None else None  # the compact layout (core/compact.py)
        if pack is None:
            records["code"] = FULL_LAYOUT
        else:
            ext_lo, ext_hi = self.ext_ranges(points, plan)
            records["code"][slot] = pack["code"][ids]
            records["ext_first"][slot] = 2 * (pack["ext_first"][ids].astype(np.int64) - ext_lo[pages])  # u32 words of the page's stream
        rec_buf = self.frame_buffer("records", records.nbytes, usage.STORAGE | usage.COPY_DST)
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
                words = [self.cache.get(points.low, start, stop, pinned)]
                # Medium/high words go to the GPU only once a frame needs them.
                if pack is not None:  # the compact layout: the page's extension streams in med's place
                    words.append(self.cache.get(points.ext, int(ext_lo[p]), int(ext_hi[p]), pinned) if max_bits >= 20 else self.dummy)
                    words.append(self.dummy)
                else:
                    words.append(self.cache.get(points.med, start, stop, pinned) if max_bits >= 20 else self.dummy)
                    words.append(self.cache.get(points.high, start, stop, pinned) if max_bits >= 30 else self.dummy)
                own = extra(start, stop, pinned)
                uniform = self.uniform(
                    **params, batch_offset=n_views * r0, batch_count=r1 - r0, page_first=start, page_count=stop - start,
                    near=table[0, 0], far=table[0, 1], views=table,
                )  # fmt: skip
                entries = [uniform, (rec_buf, records.nbytes)]
                entries += [(w, w.size) for w in words]
                entries.append((words[0], words[0].size // 16 * 16))  # low again, as vec4 (prefetch)
                entries.append(footprint)
                self.dispatch(pass_name, entries + own, r1 - r0, n_views)


def _same_layout(a, b) -> bool:
    return a[2] == b[2] and np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def in_place_ext_ranges(pack, batches, plan: PagePlan, n_words: int, previous=None) -> tuple[np.ndarray, np.ndarray]:
    """Each page's u64 words lo..hi of the extension streams of a cloud refilled in place (an
    LOD arena, the progressive octree's pool), whose streams stay where they are while their
    batches refill but may be handed out as the cloud grows (the pool gives a new point chunk
    the next stream: ``ext_first`` is ``n_words`` until then, and a voxel chunk has none).

    Only batches with stream bits count. A stream's room reaches the next stream; the last
    one's (the frontier, where the pool hands out the next) at most a full batch of the widest
    points (3 x ``EXT_FULL_BITS`` a point). A page's hi never shrinks while its lo stays
    (``previous``), and a page holding the frontier reaches twice as far as it needs (at most
    its batches' widest streams): a page that fills chunk by chunk is uploaded again only each
    time its streams double, not for every new chunk."""
    counts = batches["count"].astype(np.int64)
    first = pack["ext_first"].astype(np.int64)
    has = (ext_bits_per_point(pack, counts) > 0) & (first < n_words)
    room_points = (plan.ends - batches["first"].astype(np.int64)) if plan.ends is not None else counts
    widest = stream_words(np.full(len(first), 3 * EXT_FULL_BITS, np.int64), np.maximum(room_points, 1))
    span = np.zeros(plan.n_pages, np.int64)  # the widest streams a page's batches could hold
    np.add.at(span, plan.page_of, widest)
    ids = np.flatnonzero(has)
    order = ids[np.argsort(first[ids], kind="stable")]
    nxt = np.append(first[order][1:], n_words)
    end = np.minimum(nxt, first[order] + widest[order])
    frontier = nxt >= n_words
    lo = np.full(plan.n_pages, np.iinfo(np.int64).max)
    hi = np.zeros(plan.n_pages, np.int64)
    pages = plan.page_of[order]
    np.minimum.at(lo, pages, first[order])
    np.maximum.at(hi, pages, end)
    growing = np.zeros(plan.n_pages, bool)
    growing[pages[frontier]] = True
    used = hi > 0
    reach = np.where(growing & used, lo + 2 * (hi - lo), hi)
    hi = np.where(used, np.minimum(np.minimum(reach, lo + span), n_words), hi)
    if previous is not None:
        same = used & (previous[0] == lo)
        hi = np.where(same, np.maximum(hi, previous[1]), hi)
    lo = np.where(used, lo, 0)
    return lo, np.maximum(hi, lo)
