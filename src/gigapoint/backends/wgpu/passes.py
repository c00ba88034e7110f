"""The image-quality passes on the GPU: resolve, hole filling, HQS, lighting, eye-dome lighting.

Each method has the signature of the CPU pass it replaces (render/passes/*.py) and gives
the same image on the same input: bit for bit where the pass is integer work (hole
filling, HQS, resolve), and within one unit per channel on rare pixels where float rounding
may differ (lighting's ``pow``; EDL's float32 series on GPUs that fuse multiply-adds; soft
splat weights of attenuated points, float32 here, float64 on the CPU). On Mesa lavapipe
all of them are bit for bit. ``render.passes.finish_frame`` calls them when a backend has
``passes``.

Results stay on the GPU: a method returns a :class:`DeviceArray`, which the next pass reads
in place and ``np.asarray`` reads back once. The visibility buffer ``rasterize`` returned is
recognised too, so a frame uploads nothing between passes. Passes write into one of two
buffers per kind (ping-pong): an input is never overwritten by the pass reading it, and a
result still referenced when its buffer is reused is read back first.
"""

from __future__ import annotations

import math

import numpy as np

from ...errors import GigapointError

_VIS_ROLES = ("visibility", "visibility_b")
_IMAGE_ROLES = ("image", "image_b")


class DeviceArray:
    """A pass result held in a GPU frame buffer; ``np.asarray`` reads it back (once).

    1-D, ``dtype`` uint64 (visibility) or uint32 (RGBA). Valid until its buffer is written
    again, which first reads it back if the array is still referenced."""

    __slots__ = ("__weakref__", "_host", "backend", "dtype", "generation", "role", "shape")

    def __init__(self, backend, role: str, dtype, n: int) -> None:
        self.backend = backend
        self.role = role
        self.generation = backend._generation[role]
        self.dtype = np.dtype(dtype)
        self.shape = (int(n),)
        self._host: np.ndarray | None = None
        backend._arrays.add(self)

    @property
    def valid(self) -> bool:
        """True while the GPU buffer still holds this array."""
        return self.backend._generation[self.role] == self.generation

    @property
    def size(self) -> int:
        return self.shape[0]

    def __len__(self) -> int:
        return self.shape[0]

    def materialise(self) -> np.ndarray:
        """The values as a numpy array (read back on first use)."""
        if self._host is None:
            with self.backend._lock:
                if self._host is None:
                    if not self.valid:  # cannot happen: buffers are read back before reuse
                        raise GigapointError(f"wgpu backend: the {self.role} buffer was overwritten before it was read")
                    self._host = self.backend._read_back(self.backend._frame_buffers[self.role], self.dtype, self.shape[0])
        return self._host

    def __array__(self, dtype=None, copy=None):
        a = self.materialise()
        if dtype is not None and np.dtype(dtype) != a.dtype:
            return a.astype(dtype)
        return a.copy() if copy else a

    def __repr__(self) -> str:
        state = "read back" if self._host is not None else "on the GPU"
        return f"DeviceArray({self.shape[0]:,} x {self.dtype}, {self.role}, {state})"


class GpuPasses:
    """The passes of render/passes on one WgpuBackend's buffers (see the module docstring)."""

    def __init__(self, backend) -> None:
        self.b = backend

    # -- helpers -------------------------------------------------------------------------------
    def _uniform(self, **values):
        from .layout import PARAMS_DTYPE

        return (self.b._params(**values), PARAMS_DTYPE.itemsize)

    def _table(self, role: str, rows: np.ndarray):
        """A small per-frame table (offsets, windows) as a storage binding."""
        usage = self.b._wgpu.BufferUsage
        rows = np.ascontiguousarray(rows)
        buf = self.b._frame_buffer(role, rows.nbytes, usage.STORAGE | usage.COPY_DST)
        self.b.device.queue.write_buffer(buf, 0, rows)
        return (buf, max(16, rows.nbytes))

    def _screen(self, pass_name: str, entries: list, n_pixels: int) -> None:
        self.b._dispatch(pass_name, entries, self.b._linear_groups(n_pixels))

    # -- the passes ----------------------------------------------------------------------------
    def resolve(self, vis, color, background_rgba) -> DeviceArray:
        """u32 RGBA per pixel: the winning point's color or the background."""
        b = self.b
        with b._lock:
            color = np.ascontiguousarray(color, np.uint32)  # the same array (cache key) when already u32
            n_pixels = int(np.prod(np.shape(vis)))  # np.shape reads a DeviceArray's shape without reading it back
            b._check_frame(n_pixels)
            bg = int(np.array(background_rgba, np.uint8).view(np.uint32)[0])
            vbuf, _ = b._device_input(vis, _VIS_ROLES, np.uint64, n_pixels)
            image, role = b._output(_IMAGE_ROLES, "", n_pixels * 4)
            b.cache.purge_dead()
            n_colors = len(color)
            step = b.page_points
            for start in range(0, max(n_colors, 1), step):
                stop = min(start + step, n_colors)
                colors = b.cache.get(color, start, stop, set()) if stop > start else b._dummy
                uniform = self._uniform(n_items=n_pixels, page_first=start, page_count=stop - start, background=bg)
                self._screen("resolve", [uniform, (vbuf, n_pixels * 8), (colors, colors.size), (image, n_pixels * 4)], n_pixels)
            return DeviceArray(b, role, np.uint32, n_pixels)

    def fill_holes(self, vis, width: int, height: int, level: int, foveated: bool = False, depth_gap: float | None = None):
        """Hole filling (render/passes/holes.py): a filled copy of the visibility buffer."""
        from ...render.passes.holes import DEPTH_GAP, radius_map, window

        b = self.b
        depth_gap = DEPTH_GAP if depth_gap is None else depth_gap
        with b._lock:
            n_pixels = int(width) * int(height)
            b._check_frame(n_pixels)
            if level <= 0:
                return vis
            vbuf, vrole = b._device_input(vis, _VIS_ROLES, np.uint64, n_pixels)
            offsets, bits, ring = window(level)
            rows = np.column_stack([offsets, bits.astype(np.int32), ring.astype(np.int32)]).astype(np.int32)
            fov = bool(foveated) and level > 1
            if fov:  # radius per pixel, one byte each (uploaded once per size: radius_map is cached)
                radii = radius_map(width, height, level, True)
                rbuf = b.cache.get(radii, 0, height, set())
                rbind = (rbuf, rbuf.size)
            else:
                rbind = (b._dummy, 16)
            out, orole = b._output(_VIS_ROLES, vrole, n_pixels * 8)
            uniform = self._uniform(
                n_items=n_pixels, width=width, height=height, level=level, foveated=int(fov),
                n_offsets=len(rows), inv_gap=np.float32(1.0 / (1.0 + depth_gap)),
            )  # fmt: skip
            entries = [uniform, (vbuf, n_pixels * 8), self._table("holes_window", rows), rbind, (out, n_pixels * 8)]
            self._screen("fill_holes", entries, n_pixels)
            return DeviceArray(b, orole, np.uint64, n_pixels)

    def hqs_colors(
        self, cloud, sel, vis, width, height, near, far, point_colors, fallback, tolerance=0.01, threads=None, splat=None, softness=0.0
    ):
        """High-quality shading (render/passes/hqs.py): the rounded mean color of the points
        within ``tolerance`` of each pixel's closest depth; ``fallback`` elsewhere.

        u32 atomic sums per channel: exact up to 2^24 points a pixel (2^24 / 15 with soft
        splats), the CPU pass's bound too. ``threads`` is unused."""
        from .backend import _Views

        b = self.b
        if not b.hqs_on_gpu:  # the adapter binds fewer than 9 storage buffers: the CPU pass
            from ...render.passes.hqs import hqs_colors

            return hqs_colors(cloud, sel, np.asarray(vis), width, height, near, far, point_colors, np.asarray(fallback),
                              tolerance, threads, splat, softness)  # fmt: skip
        with b._lock:
            n_pixels = int(width) * int(height)
            b._check_frame(n_pixels)
            point_colors = np.ascontiguousarray(point_colors, np.uint32)
            vbuf, _ = b._device_input(vis, _VIS_ROLES, np.uint64, n_pixels)
            fbuf, frole = b._device_input(fallback, _IMAGE_ROLES, np.uint32, n_pixels)
            usage = b._wgpu.BufferUsage
            accum = b._frame_buffer("hqs_sums", n_pixels * 20, usage.STORAGE)
            b._clear(accum, 0)
            b.cache.purge_dead()
            footprint, splat_uniforms = b._footprint(splat, float(softness))
            params = {"width": width, "height": height, "tol1": np.float32(1.0 + tolerance), **splat_uniforms}
            views = _Views.of(sel.ids, np.asarray(sel.bits)[None], np.asarray(sel.matrices)[None], [near], [far])

            def own(start, stop, pinned):
                colors = b.cache.get(point_colors, start, stop, pinned)
                return [(vbuf, n_pixels * 8), (colors, colors.size), (accum, n_pixels * 20)]

            b._draw_batches(cloud, views, ("hqs_accumulate",), params, footprint, own)
            out, orole = b._output(_IMAGE_ROLES, frole, n_pixels * 4)
            # the fallback colors first, then the means where points contributed
            encoder = b.device.create_command_encoder()
            encoder.copy_buffer_to_buffer(fbuf, 0, out, 0, n_pixels * 4)
            b.device.queue.submit([encoder.finish()])
            self._screen("hqs_resolve", [self._uniform(n_items=n_pixels), (accum, n_pixels * 20), (out, n_pixels * 4)], n_pixels)
            return DeviceArray(b, orole, np.uint32, n_pixels)

    def shade(self, cloud, camera, vis, colors, shininess=32.0):
        """Blinn-Phong headlight (render/passes/lighting.py) from the cloud's normals."""
        from ...render.passes.lighting import AMBIENT, DIFFUSE, SPECULAR, _normals, view_directions

        b = self.b
        with b._lock:
            n_pixels = camera.width * camera.height
            b._check_frame(n_pixels)
            normals = _normals(cloud)  # cached on the cloud: uploaded once
            dirs = view_directions(camera)  # cached per camera
            if dirs.nbytes > b.max_binding:
                from ...render.passes.lighting import shade

                return shade(cloud, camera, np.asarray(vis), np.asarray(colors), shininess)
            vbuf, _ = b._device_input(vis, _VIS_ROLES, np.uint64, n_pixels)
            cbuf, crole = b._device_input(colors, _IMAGE_ROLES, np.uint32, n_pixels)
            out, orole = b._output(_IMAGE_ROLES, crole, n_pixels * 4)
            encoder = b.device.create_command_encoder()  # pixels without a point keep their color
            encoder.copy_buffer_to_buffer(cbuf, 0, out, 0, n_pixels * 4)
            b.device.queue.submit([encoder.finish()])
            b.cache.purge_dead()
            pinned: set = set()
            dbuf = b.cache.get(dirs, 0, len(dirs), pinned)
            terms = {
                "ambient": np.float32(AMBIENT), "diffuse": np.float32(DIFFUSE), "specular": np.float32(SPECULAR),
                "shininess": np.float32(shininess), "one_dir": int(len(dirs) == 1),
            }  # fmt: skip
            # 12 bytes a normal: pages of whole 16-byte rows that fit one binding
            step = max(4, min(b.page_points, b.max_binding // 12) // 4 * 4)
            for start in range(0, len(normals), step):
                stop = min(start + step, len(normals))
                nbuf = b.cache.get(normals, start, stop, {*pinned})
                uniform = self._uniform(n_items=n_pixels, page_first=start, page_count=stop - start, **terms)
                entries = [uniform, (vbuf, n_pixels * 8), (nbuf, nbuf.size), (dbuf, dbuf.size), (out, n_pixels * 4)]
                self._screen("lighting", entries, n_pixels)
            return DeviceArray(b, orole, np.uint32, n_pixels)

    def eye_dome_lighting(self, vis, colors, width: int, height: int, strength: float = 1.0, radius: float = 1.4):
        """Eye-dome lighting (render/passes/edl.py) from the visibility buffer's depth."""
        from ...render.passes.edl import neighbour_offsets

        b = self.b
        with b._lock:
            n_pixels = int(width) * int(height)
            b._check_frame(n_pixels)
            offsets = neighbour_offsets(radius)
            rows = np.zeros((len(offsets), 4), np.int32)
            rows[:, :2] = offsets
            vbuf, _ = b._device_input(vis, _VIS_ROLES, np.uint64, n_pixels)
            cbuf, crole = b._device_input(colors, _IMAGE_ROLES, np.uint32, n_pixels)
            out, orole = b._output(_IMAGE_ROLES, crole, n_pixels * 4)
            encoder = b.device.create_command_encoder()
            encoder.copy_buffer_to_buffer(cbuf, 0, out, 0, n_pixels * 4)
            b.device.queue.submit([encoder.finish()])
            logd = b._frame_buffer("edl_logd", n_pixels * 8, b._wgpu.BufferUsage.STORAGE)
            self._screen("log_depth", [self._uniform(n_items=n_pixels), (vbuf, n_pixels * 8), (logd, n_pixels * 8)], n_pixels)
            scale = np.float32(-300.0 * strength / len(offsets) / math.log(2.0))  # as the CPU kernel
            uniform = self._uniform(n_items=n_pixels, width=width, height=height, n_offsets=len(rows), edl_scale=scale)
            self._screen("edl", [uniform, (logd, n_pixels * 8), self._table("edl_offsets", rows), (out, n_pixels * 4)], n_pixels)
            return DeviceArray(b, orole, np.uint32, n_pixels)
