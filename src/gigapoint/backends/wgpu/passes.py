"""The image-quality passes on the GPU: resolve, hole filling, HQS, transparency, lighting, eye-dome lighting.

``GpuPasses`` is the wgpu backend's ``Passes`` (gigapoint.render.backend): each method has
the signature of the CPU's and gives the same image on the same input: bit for bit where
the pass is integer work (hole filling, HQS, transparency, resolve), and within one unit per channel on
rare pixels where float rounding may differ (lighting's ``pow``; EDL's float32 series on
GPUs that fuse multiply-adds; soft splat weights of attenuated points, float32 here,
float64 on the CPU). On Mesa lavapipe all of them are bit for bit. Tables and constants
come from gigapoint.render.params, as the CPU's do.

Results stay on the GPU: a method returns a :class:`DeviceArray`, which the next pass reads
in place and ``np.asarray`` reads back once; so does ``rasterize(keep_on_device=True)``'s
visibility buffer, so a frame uploads nothing between passes (a numpy array is uploaded: its
holder may have changed it). Passes write into one of two
buffers per kind (ping-pong): an input is never overwritten by the pass reading it, and a
result still referenced when its buffer is reused is read back first. Where the adapter
cannot run a pass (HQS needs 9 storage bindings and its sums in one; lighting's per-pixel view directions must
fit one), the ``fallback`` (the CPU's passes) runs it on read-back buffers.
"""

from __future__ import annotations

import numpy as np

from ...core.palette import PALETTE_SIZE, PaletteColors
from ...render.params import (
    AMBIENT,
    DEPTH_GAP,
    DIFFUSE,
    SPECULAR,
    TR_LAYERS,
    edl_scale,
    neighbour_offsets,
    radius_map,
    transmittance_table,
    view_directions,
    window,
)
from .context import DeviceArray, GpuContext, Views

_VIS_ROLES = ("visibility", "visibility_b")
_IMAGE_ROLES = ("image", "image_b")


def _alpha_rows(firsts: np.ndarray, alphas: np.ndarray) -> np.ndarray:
    """(m, 4) u32 rows (first point, 8-bit alpha, revealage term, 0) ascending by first point: the
    shaders find a point's alpha by binary search; one row when every batch has the same."""
    if len(alphas) == 0 or np.all(alphas == alphas[0]):
        rows = np.zeros((1, 4), np.uint32)
        rows[0, 1:3] = alphas[0] if len(alphas) else 0
        return rows
    order = np.argsort(firsts, kind="stable")
    rows = np.zeros((len(firsts), 4), np.uint32)
    rows[:, 0] = firsts[order]
    rows[:, 1:3] = alphas[order]
    return rows


class GpuPasses:
    """The passes on one GpuContext's buffers (see the module docstring)."""

    def __init__(self, ctx: GpuContext, fallback) -> None:
        self.ctx = ctx
        self.fallback = fallback  # the CPU's Passes, for what the adapter cannot run

    def resolve(self, vis, point_colors, background) -> tuple[DeviceArray, None]:
        """(u32 RGBA per pixel: the winning point's color or the background, None: covered
        pixels are not counted on the GPU)."""
        ctx = self.ctx
        with ctx.lock:
            indexed = isinstance(point_colors, PaletteColors)  # per-block palettes (core/palette.py), decoded by the shader
            short = not indexed and point_colors.dtype == np.uint16  # a compact cloud's RGB565 colors, decoded by the shader
            color = point_colors if short or indexed else np.ascontiguousarray(point_colors, np.uint32)  # the same array (cache key) when already u32
            n_pixels = int(np.prod(np.shape(vis)))  # np.shape reads a DeviceArray's shape without reading it back
            ctx.check_frame(n_pixels)
            bg = int(np.array(background, np.uint8).view(np.uint32)[0])
            vbuf, _ = ctx.device_input(vis, _VIS_ROLES, np.uint64, n_pixels)
            image, role = ctx.output(_IMAGE_ROLES, "", n_pixels * 4)
            ctx.cache.purge_dead()
            n_colors = len(color)
            step = ctx.page_points  # a multiple of 4: a page of palette indices is whole u32 words
            for start in range(0, max(n_colors, 1), step):
                stop = min(start + step, n_colors)
                pinned: set = set()
                pal, pal_first = (ctx.dummy, 16), 0
                if stop <= start:
                    colors = ctx.dummy
                elif indexed:
                    colors = ctx.cache.get(color.words, start // 4, -(-stop // 4), pinned)
                    pal_first = (start >> color.shift) * PALETTE_SIZE
                    buf = ctx.cache.get(color.palette, pal_first, (((stop - 1) >> color.shift) + 1) * PALETTE_SIZE, pinned)
                    pal = (buf, buf.size)
                else:
                    colors = ctx.cache.get(color, start, stop, pinned)
                uniform = ctx.uniform(
                    n_items=n_pixels, page_first=start, page_count=stop - start, background=bg, color_bits=8 if indexed else 16 if short else 32,
                    palette_shift=color.shift if indexed else 0, palette_first=pal_first,
                )  # fmt: skip
                ctx.dispatch_screen("resolve", [uniform, (vbuf, n_pixels * 8), (colors, colors.size), (image, n_pixels * 4), pal], n_pixels)
            return DeviceArray(ctx, role, np.uint32, n_pixels), None

    def fill_holes(self, vis, width: int, height: int, level: int, foveated: bool = False, depth_gap: float = DEPTH_GAP):
        """Hole filling (render/passes/holes.py): a filled copy of the visibility buffer."""
        ctx = self.ctx
        with ctx.lock:
            n_pixels = int(width) * int(height)
            ctx.check_frame(n_pixels)
            if level <= 0:
                return vis
            vbuf, vrole = ctx.device_input(vis, _VIS_ROLES, np.uint64, n_pixels)
            offsets, bits, ring = window(level)
            rows = np.column_stack([offsets, bits.astype(np.int32), ring.astype(np.int32)]).astype(np.int32)
            fov = bool(foveated) and level > 1
            if fov:  # radius per pixel, one byte each (uploaded once per size: radius_map is cached)
                radii = radius_map(width, height, level, True)
                rbuf = ctx.cache.get(radii, 0, height, set())
                rbind = (rbuf, rbuf.size)
            else:
                rbind = (ctx.dummy, 16)
            out, orole = ctx.output(_VIS_ROLES, vrole, n_pixels * 8)
            uniform = ctx.uniform(
                n_items=n_pixels, width=width, height=height, level=level, foveated=int(fov),
                n_offsets=len(rows), inv_gap=np.float32(1.0 / (1.0 + depth_gap)),
            )  # fmt: skip
            entries = [uniform, (vbuf, n_pixels * 8), ctx.table("holes_window", rows), rbind, (out, n_pixels * 8)]
            ctx.dispatch_screen("fill_holes", entries, n_pixels)
            return DeviceArray(ctx, orole, np.uint64, n_pixels)

    def hqs_colors(
        self, points, sel, vis, width, height, near, far, point_colors, fallback, tolerance=0.01, threads=None, splat=None, softness=0.0,
        step=1,
    ):  # fmt: skip
        """High-quality shading (render/passes/hqs.py): the rounded mean color of the points
        within ``tolerance`` of each pixel's closest depth; ``fallback`` elsewhere. ``step``: every
        step-th point of each batch, as the depth pass drew them.

        u32 atomic sums per channel: exact up to 2^24 points a pixel (2^24 / 15 with soft
        splats), the CPU pass's bound too. ``threads`` is unused."""
        ctx = self.ctx
        # the CPU pass where the adapter binds fewer than 9 storage buffers, or the sums (20 bytes
        # a pixel) exceed one binding (lavapipe's 128 MiB: 6.7 M pixels, under 4K)
        if not ctx.hqs_on_gpu or int(width) * int(height) * 20 > ctx.max_binding:
            return self.fallback.hqs_colors(points, sel, np.asarray(vis), width, height, near, far, point_colors, np.asarray(fallback),
                                            tolerance, threads, splat, softness, step=step)  # fmt: skip
        with ctx.lock:
            n_pixels = int(width) * int(height)
            ctx.check_frame(n_pixels)
            point_colors = np.ascontiguousarray(point_colors, np.uint32)
            vbuf, _ = ctx.device_input(vis, _VIS_ROLES, np.uint64, n_pixels)
            fbuf, frole = ctx.device_input(fallback, _IMAGE_ROLES, np.uint32, n_pixels)
            accum = ctx.frame_buffer("hqs_sums", n_pixels * 20, ctx.wgpu.BufferUsage.STORAGE)
            ctx.clear(accum, 0)
            ctx.cache.purge_dead()
            footprint, splat_uniforms = ctx.footprint(splat, float(softness))
            params = {"width": width, "height": height, "tol1": np.float32(1.0 + tolerance), "step": max(1, int(step)), **splat_uniforms}

            def own(start, stop, pinned):
                colors = ctx.cache.get(point_colors, start, stop, pinned)
                return [(vbuf, n_pixels * 8), (colors, colors.size), (accum, n_pixels * 20)]

            ctx.draw_batches(points, Views.single(sel, near, far), ("hqs_accumulate",), params, footprint, own)
            out, orole = ctx.output(_IMAGE_ROLES, frole, n_pixels * 4)
            ctx.copy(fbuf, out, n_pixels * 4)  # the fallback colors first, then the means where points contributed
            ctx.dispatch_screen("hqs_resolve", [ctx.uniform(n_items=n_pixels), (accum, n_pixels * 20), (out, n_pixels * 4)], n_pixels)
            return DeviceArray(ctx, orole, np.uint32, n_pixels)

    def transparent_colors(
        self, points, sel, vis, width, height, near, far, point_colors, alphas, fallback, background, threads=None, splat=None, step=1
    ):
        """Transparent points (render/passes/transparency.py): the hybrid composite of the selected
        batches' fragments, bit for bit the CPU's. Three passes: accumulate (k-buffer of 64-bit
        atomicMin cascades, u64 sums), gather (the kept fragments' colors, page by page), resolve.
        Where the adapter lacks 64-bit atomics that return a value, binds fewer than 10 storage
        buffers or the k-buffer (64 bytes a pixel) exceeds a binding: the CPU pass. ``vis`` and
        ``threads`` are unused."""
        ctx = self.ctx
        n_pixels = int(width) * int(height)
        if not ctx.transparency_on_gpu or n_pixels * TR_LAYERS * 8 > ctx.max_binding:
            return self.fallback.transparent_colors(points, sel, None, width, height, near, far, point_colors, alphas,
                                                    np.asarray(fallback), background, threads, splat, step)  # fmt: skip
        with ctx.lock:
            ctx.check_frame(n_pixels)
            point_colors = np.ascontiguousarray(point_colors, np.uint32)
            usage = ctx.wgpu.BufferUsage
            fbuf, frole = ctx.device_input(fallback, _IMAGE_ROLES, np.uint32, n_pixels)
            layers = ctx.frame_buffer("tr_layers", n_pixels * TR_LAYERS * 8, usage.STORAGE)
            sums = ctx.frame_buffer("tr_sums", n_pixels * 40, usage.STORAGE)
            ctx.clear(layers, 0xFFFFFFFF)
            ctx.clear(sums, 0)
            alphas = np.asarray(alphas, np.uint32).reshape(-1, 2)
            firsts = points.batches["first"][sel.ids].astype(np.int64)
            rows = _alpha_rows(firsts, alphas)
            table = ctx.table("tr_alphas", rows)
            ctx.cache.purge_dead()
            footprint, splat_uniforms = ctx.footprint(splat)
            params = {"width": width, "height": height, "step": max(1, int(step)), "n_items": len(rows), **splat_uniforms}

            def own(start, stop, pinned):
                colors = ctx.cache.get(point_colors, start, stop, pinned)
                return [(layers, n_pixels * TR_LAYERS * 8), (colors, colors.size), (sums, n_pixels * 40), table]

            ctx.draw_batches(points, Views.single(sel, near, far), ("transparency_accumulate",), params, footprint, own)
            slots = ctx.frame_buffer("tr_slot_colors", n_pixels * TR_LAYERS * 4, usage.STORAGE)
            n_slots = n_pixels * TR_LAYERS
            for start in range(0, len(point_colors), ctx.page_points):
                stop = min(start + ctx.page_points, len(point_colors))
                colors = ctx.cache.get(point_colors, start, stop, set())
                uniform = ctx.uniform(n_items=n_slots, page_first=start, page_count=stop - start)
                ctx.dispatch_screen("transparency_gather", [uniform, (layers, n_slots * 8), (colors, colors.size), (slots, n_slots * 4)], n_slots)
            out, orole = ctx.output(_IMAGE_ROLES, frole, n_pixels * 4)
            ctx.copy(fbuf, out, n_pixels * 4)  # the fallback colors first, then the composite where fragments landed
            bg = int(np.array(background, np.uint8).view(np.uint32)[0])
            uniform = ctx.uniform(n_items=n_pixels, n_offsets=len(rows), background=bg)
            entries = [uniform, (layers, n_slots * 8), (sums, n_pixels * 40), (slots, n_slots * 4), table,
                       ctx.table("tr_transmittance", transmittance_table()), (out, n_pixels * 4)]  # fmt: skip
            ctx.dispatch_screen("transparency_resolve", entries, n_pixels)
            return DeviceArray(ctx, orole, np.uint32, n_pixels)

    def shade(self, vis, colors, normals, camera, shininess=32.0):
        """Blinn-Phong headlight (render/passes/lighting.py) from float32 (N, 3) normals."""
        ctx = self.ctx
        dirs = view_directions(camera)  # cached per camera
        if dirs.nbytes > ctx.max_binding:
            return self.fallback.shade(np.asarray(vis), np.asarray(colors), normals, camera, shininess)
        with ctx.lock:
            n_pixels = camera.width * camera.height
            ctx.check_frame(n_pixels)
            vbuf, _ = ctx.device_input(vis, _VIS_ROLES, np.uint64, n_pixels)
            cbuf, crole = ctx.device_input(colors, _IMAGE_ROLES, np.uint32, n_pixels)
            out, orole = ctx.output(_IMAGE_ROLES, crole, n_pixels * 4)
            ctx.copy(cbuf, out, n_pixels * 4)  # pixels without a point keep their color
            ctx.cache.purge_dead()
            pinned: set = set()
            dbuf = ctx.cache.get(dirs, 0, len(dirs), pinned)
            terms = {
                "ambient": np.float32(AMBIENT), "diffuse": np.float32(DIFFUSE), "specular": np.float32(SPECULAR),
                "shininess": np.float32(shininess), "one_dir": int(len(dirs) == 1),
            }  # fmt: skip
            # 12 bytes a normal: pages of whole 16-byte rows that fit one binding
            step = max(4, min(ctx.page_points, ctx.max_binding // 12) // 4 * 4)
            for start in range(0, len(normals), step):
                stop = min(start + step, len(normals))
                nbuf = ctx.cache.get(normals, start, stop, {*pinned})
                uniform = ctx.uniform(n_items=n_pixels, page_first=start, page_count=stop - start, **terms)
                entries = [uniform, (vbuf, n_pixels * 8), (nbuf, nbuf.size), (dbuf, dbuf.size), (out, n_pixels * 4)]
                ctx.dispatch_screen("lighting", entries, n_pixels)
            return DeviceArray(ctx, orole, np.uint32, n_pixels)

    def eye_dome_lighting(self, vis, colors, width: int, height: int, strength: float = 1.0, radius: float = 1.4):
        """Eye-dome lighting (render/passes/edl.py) from the visibility buffer's depth."""
        ctx = self.ctx
        with ctx.lock:
            n_pixels = int(width) * int(height)
            ctx.check_frame(n_pixels)
            offsets = neighbour_offsets(radius)
            rows = np.zeros((len(offsets), 4), np.int32)
            rows[:, :2] = offsets
            vbuf, _ = ctx.device_input(vis, _VIS_ROLES, np.uint64, n_pixels)
            cbuf, crole = ctx.device_input(colors, _IMAGE_ROLES, np.uint32, n_pixels)
            out, orole = ctx.output(_IMAGE_ROLES, crole, n_pixels * 4)
            ctx.copy(cbuf, out, n_pixels * 4)
            logd = ctx.frame_buffer("edl_logd", n_pixels * 8, ctx.wgpu.BufferUsage.STORAGE)
            ctx.dispatch_screen("log_depth", [ctx.uniform(n_items=n_pixels), (vbuf, n_pixels * 8), (logd, n_pixels * 8)], n_pixels)
            uniform = ctx.uniform(n_items=n_pixels, width=width, height=height, n_offsets=len(rows), edl_scale=edl_scale(strength, len(offsets)))
            ctx.dispatch_screen("edl", [uniform, (logd, n_pixels * 8), ctx.table("edl_offsets", rows), (out, n_pixels * 4)], n_pixels)
            return DeviceArray(ctx, orole, np.uint32, n_pixels)

    def downsample(self, vis, image, width: int, height: int, s: int):
        """Supersampling's block reduction: on read-back frames, the CPU's kernel."""
        return self.fallback.downsample(np.asarray(vis), np.asarray(image), width, height, s)
