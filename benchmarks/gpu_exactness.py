"""Where the wgpu visibility buffer differs from the CPU backend's, and why; with products kept
(shaders/exact.wgsl, as shipped) and with them left to the driver to fuse, in one process.

    python3 benchmarks/gpu_exactness.py                 # on a real GPU (benchmarks/gpu_device.sh)
    .venv/bin/python benchmarks/gpu_exactness.py --timing 20M

For each frame (the GPU tier's five cameras on a 200 k-point demo, the benchmark overview and
close-up of a 2 M-point demo at 1920x1080) it counts the pixels whose key differs and splits
them: the same point at another depth (a depth off by some ulps: arithmetic that rounds
differently), another point, one side empty (a point across a pixel edge). ``--timing N``
then times both shader texts on an N-point demo (the frame kept on the GPU, alternating).
lavapipe fuses nothing, so both columns agree there; NVIDIA's driver fuses (docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import gigapoint
from gigapoint.backends.numba_cpu import NumbaCpuBackend
from gigapoint.backends.wgpu import WgpuBackend, shaders
from gigapoint.bench import benchmark_cameras, comparison_cameras, parse_counts
from gigapoint.core.selection import select

EMPTY = np.uint64(0xFFFFFFFFFFFFFFFF)
#: exact.wgsl's product() as a plain multiply: what the shaders were before it (the driver may fuse)
FUSABLE_PRODUCT = "fn product(a: f32, b: f32) -> f32 {\n    return a * b;\n}\n"


def backend(fusable: bool) -> WgpuBackend:
    """A backend whose pipelines are built from the shipped text or with product() fusable.
    Pipelines are built at a backend's first draw, so it draws a small frame at once."""
    read = shaders._read
    if fusable:
        shaders._read = lambda name: FUSABLE_PRODUCT if name == "exact.wgsl" else read(name)
    shaders.shader_source.cache_clear()
    try:
        gpu = WgpuBackend(memory_budget=8 << 30)
        warm = gigapoint.demo(20_000, scale=None)
        for cam in comparison_cameras(warm).values():
            gpu.rasterize(warm, *frame(warm, cam))
        gpu.forget(warm)
        return gpu
    finally:
        shaders._read = read
        shaders.shader_source.cache_clear()


def frame(cloud, cam):
    near, far = cam.clip_range(cloud.bounds)
    return select(cloud.batches, cam.screen_rows(), cam.width, cam.height, near, far), cam.width, cam.height, near, far


def differences(got: np.ndarray, want: np.ndarray) -> str:
    d = got != want
    g, w = got[d], want[d]
    one_empty = (g == EMPTY) | (w == EMPTY)
    same_point = ~one_empty & ((g & np.uint64(0xFFFFFFFF)) == (w & np.uint64(0xFFFFFFFF)))
    ulps = np.abs((g[same_point] >> np.uint64(32)).astype(np.int64) - (w[same_point] >> np.uint64(32)).astype(np.int64))
    n = int(d.sum())
    return (f"{n:>6,} px ({100 * n / got.size:.3f} %): same point at another depth {int(same_point.sum()):,} "
            f"(up to {int(ulps.max(initial=0))} ulps), another point {n - int(same_point.sum()) - int(one_empty.sum()):,}, "
            f"one side empty {int(one_empty.sum()):,}")  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", nargs=2, default=["200k", "2M"], metavar=("SMALL", "LARGE"),
                    help="the demos of the small frames and of the 1920x1080 ones")  # fmt: skip
    ap.add_argument("--timing", default="0", help="points of the demo to time both shader texts on (0: none)")
    args = ap.parse_args(argv)
    small, large = parse_counts(ap, *(("--points", p) for p in args.points))
    n = parse_counts(ap, ("--timing", args.timing))[0] if args.timing != "0" else 0  # (before minutes of frames)
    cpu = NumbaCpuBackend()
    gpus = {"kept": backend(False), "fusable": backend(True)}
    print(gpus["kept"].describe())
    scenes = [
        (args.points[0], gigapoint.demo(small, scale=None), comparison_cameras),
        (args.points[1], gigapoint.demo(large), lambda cl: benchmark_cameras(cl.bounds, 1920, 1080)),
    ]
    for label, cloud, cameras in scenes:
        for view, cam in cameras(cloud).items():
            f = frame(cloud, cam)
            want = cpu.rasterize(cloud, *f)
            for name, gpu in gpus.items():
                print(f"{label:>5} {view:8s} products {name:8s} {differences(gpu.rasterize(cloud, *f), want)}", flush=True)
        for gpu in gpus.values():
            gpu.forget(cloud)
    if n:
        cloud = gigapoint.demo(n)
        for view, cam in benchmark_cameras(cloud.bounds, 1920, 1080).items():
            f = frame(cloud, cam)
            drawn = int(cloud.batches["count"][f[0].ids].sum())
            times = {name: [] for name in gpus}
            for _ in range(16):
                for name, gpu in gpus.items():
                    t = time.perf_counter()
                    gpu.rasterize(cloud, *f, keep_on_device=True)
                    times[name].append(time.perf_counter() - t)
            rates = ", ".join(
                f"products {k} {statistics.median(v[1:]) * 1e3:.2f} ms ({drawn / statistics.median(v[1:]) / 1e9:.1f} G points/s)"
                for k, v in times.items()
            )
            print(f"{n:,} points, {view}: {rates}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
