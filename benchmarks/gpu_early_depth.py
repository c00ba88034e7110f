"""Variants of the wgpu rasterize pass's early-depth test and batch order, timed against each
other on the same frames in the same process (docs/benchmarks.md, "GPU backend"):

    python3 benchmarks/gpu_early_depth.py --points 100M 500M --gpu-memory 100G   # a real GPU
    .venv/bin/python benchmarks/gpu_early_depth.py --points 200k --width 320 --height 240   # lavapipe

Variants of raster64.wgsl's ``visit`` (the shader text is patched here, the backend's is
unchanged):

- ``atomic-load``: the shipped pass: ``atomicLoad`` of the pixel, then ``atomicMin`` when the key
  is smaller (WGSL reads an atomic only atomically: on NVIDIA likely an L2 access).
- ``no-test``: ``atomicMin`` for every point (what the early test saves).
- ``hint``: a second, plain ``array<u32>`` of depths (the paper's non-atomic early test, which
  L1 may serve): a point deeper than the pixel's hint is dropped; a won ``atomicMin`` writes its
  depth there. Every value written was once the pixel's depth, so the hint is never below the
  pixel's depth and drops only losing points; racing writes may leave it higher (fewer points
  dropped), never wrong.
- ``hint+load``: the hint, then the ``atomicLoad`` test, then ``atomicMin``.

Each may also draw its batches front to back (``+f2b``: the selection sorted by the depth of
each batch's centre; the image cannot change, the minimum is order-independent, but more
points meet a near pixel already written), and the two-pass 32-bit-atomics path
(``--fallback``) runs beside them. Frames are "kept on GPU" (waited for, not read back), one
frame of each variant in turn per round, median of ``--repeats`` rounds; every variant's
visibility buffer is compared with the shipped pass's (they must be identical).
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
import time
from dataclasses import replace

import numpy as np
from rich.console import Console
from rich.table import Table

import gigapoint
from gigapoint.bench import benchmark_cameras, cpu_model, one_line_errors, parse_counts
from gigapoint.core.selection import select
from gigapoint.errors import GigapointError

_HINT_BINDING = "@group(0) @binding(8) var<storage, read_write> depth_hint: array<u32>;\n"

VISITS = {
    "atomic-load": None,  # the shipped text
    "no-test": """fn visit(pixel: u32, depth_bits: u32, index: u32, row: u32, size: f32) {
    atomicMin(&visibility[pixel], (u64(depth_bits) << 32u) | u64(index));
}
""",
    "hint": """fn visit(pixel: u32, depth_bits: u32, index: u32, row: u32, size: f32) {
    if (depth_bits > depth_hint[pixel]) {
        return;
    }
    let key = (u64(depth_bits) << 32u) | u64(index);
    if (key < atomicMin(&visibility[pixel], key)) {
        depth_hint[pixel] = depth_bits;
    }
}
""",
    "hint+load": """fn visit(pixel: u32, depth_bits: u32, index: u32, row: u32, size: f32) {
    if (depth_bits > depth_hint[pixel]) {
        return;
    }
    let key = (u64(depth_bits) << 32u) | u64(index);
    if (key < atomicLoad(&visibility[pixel])) {
        if (key < atomicMin(&visibility[pixel], key)) {
            depth_hint[pixel] = depth_bits;
        }
    }
}
""",
}


# Thread t of a workgroup draws points t, t + 128, ... (the shipped loops: a warp's lanes read
# neighbouring words, and in Morton order mostly hit the same few pixels at once); "runs" gives
# thread t one contiguous run of the batch instead (a warp's lanes hit different pixels; a
# thread's next point lands where it just wrote).
_STRIDED_LOOPS = (
    "for (var q = lid; q < quads; q += WORKGROUP_SIZE) {",
    "for (var j = tail + lid; j < n; j += WORKGROUP_SIZE) {",
)
_RUN_LOOPS = (
    (
        "let per_thread = (quads + WORKGROUP_SIZE - 1u) / WORKGROUP_SIZE;\n"
        "        for (var q = lid * per_thread; q < min(quads, (lid + 1u) * per_thread); q++) {"
    ),
    (
        "let per_thread = (n - tail + WORKGROUP_SIZE - 1u) / WORKGROUP_SIZE;\n"
        "    for (var j = tail + lid * per_thread; j < min(n, tail + (lid + 1u) * per_thread); j++) {"
    ),
)


def variant_source(name: str, runs: bool = False) -> str:
    """raster64's WGSL with ``visit`` replaced by the variant's (and the hint's binding added);
    ``runs``: each thread draws one contiguous run of its batch."""
    from gigapoint.backends.wgpu.shaders import shader_source

    text = shader_source("raster64")
    if runs:
        for strided, run in zip(_STRIDED_LOOPS, _RUN_LOOPS):
            if text.count(strided) != 1:
                raise GigapointError(f"common.wgsl: expected one loop {strided!r}")
            text = text.replace(strided, run)
    if VISITS[name] is None:
        return text
    visit = re.compile(r"^fn visit\(.*?^}\n", re.MULTILINE | re.DOTALL)
    if len(visit.findall(text)) != 1:
        raise GigapointError("raster64.wgsl: expected one fn visit to replace")
    text = visit.sub(lambda _: VISITS[name], text)
    if "depth_hint" in VISITS[name]:
        binding = "@group(0) @binding(7) var<storage, read_write> visibility"
        if text.count(binding) != 1:
            raise GigapointError("raster64.wgsl: expected one visibility binding")
        text = text.replace(binding, _HINT_BINDING + binding)
    return text


def variant_backend(budget: int):
    """A WgpuBackend whose rasterize pass is the variant named by ``.variant``."""
    from gigapoint.backends.wgpu import WgpuBackend
    from gigapoint.backends.wgpu.backend import _EMPTY_WORD

    class VariantBackend(WgpuBackend):
        variant = "atomic-load"
        runs = False

        def _draw_views(self, points, views, width, height, splat, step, role):
            ctx = self.ctx
            n_pixels = width * height
            pass_name = f"raster64_{self.variant}{'_runs' if self.runs else ''}"
            if pass_name not in ctx.modules:
                ctx.modules[pass_name] = ctx.device.create_shader_module(label=pass_name, code=variant_source(self.variant, self.runs))
            vis = ctx.writable(role, views.n * n_pixels * 8)
            ctx.clear(vis, _EMPTY_WORD)
            own = [(vis, views.n * n_pixels * 8)]
            if "hint" in self.variant:
                usage = ctx.wgpu.BufferUsage
                hint = ctx.frame_buffer("depth_hint", views.n * n_pixels * 4, usage.STORAGE | usage.COPY_DST)
                ctx.clear(hint, _EMPTY_WORD)
                own.append((hint, hint.size))
            footprint, splat_uniforms = ctx.footprint(splat)
            params = {"width": width, "height": height, "step": step, **splat_uniforms}
            ctx.draw_batches(points, views, (pass_name,), params, footprint, lambda start, stop, pinned: own)
            return vis

    return VariantBackend(memory_budget=budget)


def front_to_back(sel):
    """The selection with its batches sorted by the depth of their centres (nearest first)."""
    centre_depth = sel.matrices[:, 3, :3].astype(np.float64).sum(axis=1) * 512.0 + sel.matrices[:, 3, 3]
    order = np.argsort(centre_depth, kind="stable")
    return replace(sel, ids=sel.ids[order], bits=sel.bits[order], matrices=sel.matrices[order], projected_px=sel.projected_px[order])


def bench_view(cloud, view, cam, args, backend, fallback, out) -> None:
    """One table: each (visit, loops, batch order) run drawing the view, one frame each a round."""
    near, far = cam.clip_range(cloud.bounds)
    sel = select(cloud.batches, cam.screen_rows(), cam.width, cam.height, near, far)
    drawn = int(cloud.batches["count"][sel.ids].sum())
    empty = replace(sel, ids=sel.ids[:0], bits=sel.bits[:0], matrices=sel.matrices[:0], projected_px=sel.projected_px[:0])
    selections = {"selection": sel, "front to back": front_to_back(sel), "no batch": empty}
    orders = ("selection", "front to back") if args.front_to_back else ("selection",)
    runs = [(v, loops, order) for v in VISITS for loops in ("strided", "runs") for order in orders]
    if fallback is not None:
        runs += [("two-pass 32-bit", "strided", order) for order in orders]
    shipped = ("atomic-load", "strided", "selection")

    def frame(variant, loops, order, keep=True):
        s = selections[order]
        if variant == "two-pass 32-bit":
            return fallback.rasterize(cloud, s, cam.width, cam.height, near, far, keep_on_device=keep)
        backend.variant, backend.runs = variant, loops == "runs"
        return backend.rasterize(cloud, s, cam.width, cam.height, near, far, keep_on_device=keep)

    reference = None
    same = {}
    for r in runs:  # compile, upload, and the image each run draws
        vis = np.asarray(frame(*r, keep=False))
        if reference is None:
            reference = vis
        diff = int(np.count_nonzero(vis != reference))
        same[r] = "identical" if diff == 0 else f"{diff:,} px differ"
    fixed = ("atomic-load", "strided", "no batch")  # the fixed cost of a frame: clear, submit, wait
    frame(*fixed)
    runs.append(fixed)
    same[fixed] = "-"
    times = {r: [] for r in runs}
    for _ in range(args.repeats):
        for r in runs:
            times[r].append(_timed(lambda r=r: frame(*r)))
    base = statistics.median(times[shipped])
    table = Table(
        title=f"{view}: {drawn:,} of {cloud.n_points:,} points, {cam.width}x{cam.height}, kept on GPU, median of {args.repeats} rounds"
    )
    for col in ("early-depth test", "loops", "batch order", "ms", "G points/s", "vs shipped", "image"):
        table.add_column(col, justify="right" if col in ("ms", "G points/s", "vs shipped") else "left")
    for r in runs:
        t = statistics.median(times[r])
        rate = "-" if r == fixed else f"{drawn / t / 1e9:.2f}"
        table.add_row(*r, f"{t * 1000:.2f}", rate, f"{base / t:.2f}x", same[r])
    out.print(table)
    ctx = backend.ctx
    vis = ctx.frame_buffers["visibility"]
    wait = statistics.median(_timed(lambda: ctx.read_back(vis, np.uint64, 1)) for _ in range(args.repeats))
    out.print(f"a round trip alone (copy 8 bytes to a mapped buffer, map, read): {wait * 1000:.2f} ms")


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


@one_line_errors
def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", nargs="+", default=["2M"], help="demo scene sizes (e.g. 100M 500M)")
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--views", nargs="+", default=["overview", "closeup"], choices=["overview", "closeup"])
    ap.add_argument("--repeats", type=int, default=10, help="rounds (one frame of each variant a round)")
    ap.add_argument("--fallback", action="store_true", help="also the two-pass 32-bit-atomics path")
    ap.add_argument("--front-to-back", action="store_true", help="also each run with its batches sorted front to back")
    ap.add_argument("--gpu-memory", default="2G", help="GPU memory for point data: e.g. 100G on a big GPU")
    args = ap.parse_args(argv)
    sizes = parse_counts(ap, *(("--points", p) for p in args.points))
    out, err = Console(width=150), Console(stderr=True, width=150)
    from gigapoint.backends.wgpu import WgpuBackend
    from gigapoint.lod import parse_memory

    budget = parse_memory(args.gpu_memory, "--gpu-memory")
    backend = variant_backend(budget)
    fallback = WgpuBackend(atomics64=False, memory_budget=budget) if args.fallback else None
    out.print(f"{cpu_model()}; {backend.describe()}")
    for n in sizes:
        t0 = time.perf_counter()
        cloud = gigapoint.demo(n)
        err.print(f"[dim]demo scene of {n:,} points built in {time.perf_counter() - t0:.1f} s[/dim]")
        cams = benchmark_cameras(cloud.bounds, args.width, args.height)
        for view in args.views:
            bench_view(cloud, view, cams[view], args, backend, fallback, out)
        backend.forget(cloud)
        if fallback is not None:
            fallback.forget(cloud)


if __name__ == "__main__":
    sys.exit(main())
