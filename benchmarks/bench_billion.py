"""A 10⁹-point demo town built in bounded memory and drawn brute force (issue #22).

    /tmp/quiet.sh .venv/bin/python benchmarks/bench_billion.py --points 1G
    .venv/bin/python benchmarks/bench_billion.py --points 100M --rounds 3   # to extrapolate first

The town is generated at ``--scale`` (1 cm: as a LAS export of it would store it) and built by
``gp.demo(n, scale=..., chunked=True)`` (core/chunked.py: three passes over the generator, the
points spilled to per-partition files in a temporary folder, then each partition sorted,
compacted and copied into the finished arrays). Reported: build time and points/s, bytes a
point per component (``cloud.memory()``), the process's peak RSS (VmHWM) after the build and
after the frames, and brute-force frame times (CPU backend, every point, fixed one-pixel
points) of the fitted overview (``Camera.fit_cloud``) and of the benchmark close-up; one frame
of each first (JIT warm-up and the frame buffers), then the median of ``--rounds``.
The JIT is warmed up on a small town before the build is timed.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import sys
import time

import numpy as np

import gigapoint as gp


def peak_rss() -> int:
    """Bytes: the process's peak resident set (VmHWM), ru_maxrss where /proc is missing."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def frames(cloud, cam, settings, rounds: int) -> tuple[float, float, int]:
    """(median wall s, median CPU s, points drawn) of ``rounds`` frames after one untimed frame."""
    gp.render_frame(cloud, cam, settings)
    wall, cpu = [], []
    for _ in range(rounds):
        t, c = time.perf_counter(), time.process_time()
        frame = gp.render_frame(cloud, cam, settings)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return statistics.median(wall), statistics.median(cpu), int(frame.stats.points_processed)


def main(argv=None) -> int:
    from gigapoint.bench import benchmark_cameras, cpu_model, parse_counts

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", default="1G", help="demo town size (100M, 1G)")
    ap.add_argument("--scale", type=float, default=0.01, help="grid the town is stored at (metres)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--no-attributes", action="store_true", help="leave out intensity and classification (3 bytes a point)")
    ap.add_argument("--png", help="write the overview to this PNG")
    args = ap.parse_args(argv)
    (n,) = parse_counts(ap, ("--points", args.points))
    cpu = cpu_model()
    settings = gp.RenderSettings(backend="cpu", size_mode="fixed")
    print(f"bench_billion: {n:,} points at {args.scale:g} m; {cpu}, numba threads {settings.threads or 'all'}", flush=True)
    small = gp.demo(3_000_000, scale=args.scale, chunked=True)  # JIT: the build's kernels (radix sort too) and the frame's
    gp.render_frame(small, gp.Camera.fit(small.bounds, width=64, height=64), settings)
    del small
    rss0 = peak_rss()
    t = time.perf_counter()
    cloud = gp.demo(n, scale=args.scale, chunked=True, attributes=not args.no_attributes)
    build = time.perf_counter() - t
    rss_build = peak_rss()
    mem = cloud.memory()
    print(
        f"built {cloud.n_points:,} points, {len(cloud.batches):,} batches in {build:.1f} s ({cloud.n_points / build / 1e6:.2f} M points/s)"
    )
    print(
        "bytes a point: "
        + ", ".join(f"{k} {v / n:.3f}" for k, v in mem.items())
        + f"; total {sum(mem.values()) / n:.3f} ({sum(mem.values()) / 1e9:.2f} GB)"
    )
    print(f"peak RSS before the build {rss0 / 1e9:.2f} GB, after it {rss_build / 1e9:.2f} GB", flush=True)
    t = time.perf_counter()
    cams = {"overview (fit_cloud)": gp.Camera.fit_cloud(cloud, width=args.width, height=args.height)}
    cams["close-up"] = benchmark_cameras(cloud.bounds, args.width, args.height)["closeup"]
    print(f"(cameras framed in {time.perf_counter() - t:.1f} s)")
    print(f"brute force, CPU backend, {args.width}x{args.height}, every point, fixed size; median of {args.rounds} after one warm-up frame")
    for view, cam in cams.items():
        wall, cpu_s, drawn = frames(cloud, cam, settings, args.rounds)
        print(
            f"  {view:20} {wall * 1e3:9.1f} ms wall {cpu_s * 1e3:9.1f} ms CPU  {drawn:,} points drawn ({drawn / wall / 1e6:.0f} M points/s)",
            flush=True,
        )
    if args.png:
        from PIL import Image

        Image.fromarray(np.asarray(gp.render_frame(cloud, cams["overview (fit_cloud)"], settings).image)).save(args.png)
    print(f"peak RSS {peak_rss() / 1e9:.2f} GB ({peak_rss() / 2**30:.2f} GiB); the cloud's arrays {cloud.nbytes / 1e9:.2f} GB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
