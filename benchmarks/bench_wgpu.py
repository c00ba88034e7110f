"""wgpu backend vs the CPU backend: rasterize throughput on the demo scene, same run, same selection.

    .venv/bin/python benchmarks/bench_wgpu.py                          # 4 M points, 1920x1080
    .venv/bin/python benchmarks/bench_wgpu.py --points 20M --repeats 10
    .venv/bin/python benchmarks/bench_wgpu.py --points 2M --fallback   # also the two-pass 32-bit path
    python3 benchmarks/bench_wgpu.py --points 100M 500M --views overview closeup --gpu-memory 64G   # a real GPU

Throughput = points drawn (after frustum culling) / median rasterize time. The rasterize
call is timed end to end as the renderer sees it: clear, dispatches and the read-back of
the (H*W,) u64 visibility buffer. Excluded: numba JIT warm-up, and the wgpu backend's first
frame (shader compile + point upload), which is reported on its own. "overhead" is a
frame with no batch selected (clear + read-back only); "w/o overhead" divides by the
frame time less that; "kept on GPU" is the wgpu frame left on the GPU (as the frame's passes
read it: ``keep_on_device``), waited for but not read back. ``--gpu-memory`` bounds the point
data held on the GPU (past it, frames re-upload pages): give a big GPU its size. On a machine
without a GPU, wgpu runs on Mesa lavapipe (Vulkan on the CPU threads, sharing them with
everything else). ``--views``: the fitted overview and the close-up of gigapoint.bench's
benchmark cameras (``--view`` picks the overview's direction).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numba
import numpy as np
from rich.console import Console
from rich.table import Table

import gigapoint
from gigapoint.bench import benchmark_cameras, cpu_model, one_line_errors, parse_counts
from gigapoint.core.selection import Selection, select
from gigapoint.lod import parse_memory


def _time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_view(cloud, view: str, cam, args, backends, out, err) -> None:
    """One table: the cloud drawn from ``cam`` by each backend."""
    near, far = cam.clip_range(cloud.bounds)
    sel = select(cloud.batches, cam.screen_rows(), cam.width, cam.height, near, far)
    drawn = int(cloud.batches["count"][sel.ids].sum())
    empty = Selection(sel.ids[:0], sel.bits[:0], sel.matrices[:0], sel.projected_px[:0], len(cloud.batches))
    table = Table(title=f"{view}: rasterize {drawn:,} of {cloud.n_points:,} points, {cam.width}x{cam.height}, median of {args.repeats}")
    for col in (
        "backend",
        "device / path",
        "first frame ms",
        "overhead ms",
        "frame ms",
        "M points/s",
        "w/o overhead",
        "kept on GPU ms",
        "M points/s kept",
        "resolve ms",
        "same as cpu",
    ):
        table.add_column(col, justify="left" if col in ("backend", "device / path") else "right")
    reference = None
    for name, backend, note in backends:
        err.print(f"[dim]{backend.describe()}[/dim]")
        t0 = time.perf_counter()
        vis = np.asarray(backend.rasterize(cloud, sel, cam.width, cam.height, near, far))  # JIT warm-up / compile + upload
        first = time.perf_counter() - t0
        backend.resolve(vis, cloud.color, (0, 0, 0, 255))
        frame = _time(lambda b=backend: b.rasterize(cloud, sel, cam.width, cam.height, near, far), args.repeats)
        overhead = _time(lambda b=backend: b.rasterize(cloud, empty, cam.width, cam.height, near, far), args.repeats)
        resolve = _time(lambda b=backend, v=vis: b.resolve(v, cloud.color, (0, 0, 0, 255)), args.repeats)
        kept = None  # the frame left on the GPU (as a frame's passes read it), waited for, not read back
        if name == "wgpu":
            kept = _time(lambda b=backend: b.rasterize(cloud, sel, cam.width, cam.height, near, far, keep_on_device=True), args.repeats)
        if reference is None:
            reference, same = vis, "-"
        else:
            diff = int(np.count_nonzero(vis != reference))
            same = "identical" if diff == 0 else f"{diff:,} px differ ({100 * diff / vis.size:.3f} %)"
        device = note or (
            str(backend.info.get("device", "")).split(" (")[0] if name == "wgpu" else f"numba, {numba.get_num_threads()} threads"
        )
        table.add_row(
            name,
            str(device),
            "-" if name == "cpu" else f"{first * 1000:.0f}",
            f"{overhead * 1000:.1f}",
            f"{frame * 1000:.1f}",
            f"{drawn / frame / 1e6:.1f}",
            f"{drawn / (frame - overhead) / 1e6:.1f}" if frame > overhead else "-",
            "-" if kept is None else f"{kept * 1000:.1f}",
            "-" if kept is None else f"{drawn / kept / 1e6:.1f}",
            f"{resolve * 1000:.1f}",
            same,
        )
        if name == "wgpu":
            mem = backend.memory
            err.print(
                f"[dim]wgpu memory: {mem['points_resident'] / 2**20:.1f} MiB points resident, {mem['frame_buffers'] / 2**20:.1f} MiB frame buffers, {mem['uploaded'] / 2**20:.1f} MiB uploaded in {mem['uploads']} uploads[/dim]"
            )
    out.print(table)


def bench_scene(n: int, args, backends, out, err) -> None:
    """One demo scene of ``n`` points, drawn in each view by each backend."""
    err.print(f"[dim]building demo scene of {n:,} points...[/dim]")
    t0 = time.perf_counter()
    cloud = gigapoint.demo(n)
    err.print(f"[dim]built in {time.perf_counter() - t0:.1f} s[/dim]")
    cams = benchmark_cameras(cloud.bounds, args.width, args.height)
    if args.view != "iso":
        cams["overview"] = gigapoint.Camera.fit(cloud.bounds, view=args.view, width=args.width, height=args.height)
    for view in args.views:
        bench_view(cloud, view, cams[view], args, backends, out, err)
    for _, backend, _ in backends:
        if hasattr(backend, "forget"):
            backend.forget(cloud)  # the next scene's points replace these on the GPU


@one_line_errors
def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", nargs="+", default=["4M"], help="demo scene sizes (e.g. 4M, 100M 500M 1G)")
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--view", default="iso", help="camera of the overview (iso, top, front...)")
    ap.add_argument("--views", nargs="+", default=["overview"], choices=["overview", "closeup"], help="the views to draw")
    ap.add_argument("--repeats", type=int, default=5, help="timed frames per backend (median reported)")
    ap.add_argument("--fallback", action="store_true", help="also time the two-pass 32-bit-atomics path")
    ap.add_argument("--gpu-memory", default="2G", help="GPU memory for point data (past it, frames re-upload pages): e.g. 64G on a big GPU")
    ap.add_argument("--no-cpu", action="store_true", help="skip the CPU backend (and the comparison of images)")
    args = ap.parse_args(argv)
    sizes = parse_counts(ap, *(("--points", p) for p in args.points))
    out, err = Console(width=150), Console(stderr=True, width=150)
    from gigapoint.backends.numba_cpu import NumbaCpuBackend
    from gigapoint.backends.wgpu import WgpuBackend

    budget = parse_memory(args.gpu_memory, "--gpu-memory")
    backends = [] if args.no_cpu else [("cpu", NumbaCpuBackend(), "")]
    backends.append(("wgpu", WgpuBackend(memory_budget=budget), ""))
    if args.fallback:
        backends.append(("wgpu", WgpuBackend(atomics64=False, memory_budget=budget), "two-pass 32-bit"))
    out.print(f"{cpu_model()}, {numba.get_num_threads()} threads; " + "; ".join(b.describe() for name, b, _ in backends if name == "wgpu"))
    for n in sizes:
        bench_scene(n, args, backends, out, err)


if __name__ == "__main__":
    sys.exit(main())
