"""Live clouds (issue #19): depth frames to points, rendering a full ring, push-to-pixels latency,
snapshots, memory over a stream.

    .venv/bin/python benchmarks/bench_live.py                                  # every part, 100 frames kept
    .venv/bin/python benchmarks/bench_live.py --keep 30 --seconds 5 --parts depth stream

Frames come from the synthetic sensor (live/sources.py: 512x424, Kinect v2 intrinsics, flying
over the demo town), rendered once up front so the producer costs only what a driver would.

- ``depth``: the depth-to-points-and-normals kernel (live/depth.py) per 512x424 frame, and a
  whole ``push_depth`` (kernel in the image's Z order, batches, the copy into the ring), medians.
- ``render``: ``keep`` frames in the ring, median frame time at 1280x720 (the view of the town).
- ``stream``: a producer thread pushes at ``--fps`` while the main thread renders a 1280x720
  frame whenever the cloud changed (as the viewer's tabs do), for ``--seconds``: frames in/s
  reached, frames rendered/s, push-to-pixels latency (push called -> a frame holding it drawn:
  LiveCloud.drawn), median and p99.
- ``snapshot``: ``LiveCloud.snapshot()`` of the full ring into the progressive octree: points/s.
- ``memory``: resident memory after 2x and 4x ``keep`` frames pushed: the ring reuses its chunks.

JIT compilation is excluded (one warm-up of each step). Numbers depend on the host: the CPU
model is printed.
"""

from __future__ import annotations

import argparse
import statistics
import threading
import time

import numpy as np

import gigapoint as gp
from gigapoint.live import LiveCloud
from gigapoint.live.depth import depth_to_points
from gigapoint.live.sources import SyntheticSensor


def _cpu() -> str:
    from gigapoint.bench import cpu_model

    return cpu_model()


def _rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * 4096 / 2**20


def _frames(n: int):
    sensor = SyntheticSensor(n_frames=n, scene_points=1_000_000)
    return sensor, [sensor.render(k) for k in range(n)]


def _push(live, f):
    return live.push_depth(f.depth, f.intrinsics, f.pose, f.rgb, f.depth_scale)


def _camera():
    from gigapoint.io.demo import SCENE_SIZE

    return gp.Camera.fit((np.array([0.0, 0.0, -30.0]), np.array([SCENE_SIZE, SCENE_SIZE, 60.0])), view="iso", width=1280, height=720)


def bench_depth(frames) -> None:
    f = frames[0]
    depth_to_points(f.depth, f.intrinsics, f.pose, f.rgb, f.depth_scale)

    def timed(fs, scratch=None):
        times = []
        for f in fs:
            t = time.perf_counter()
            out = depth_to_points(f.depth, f.intrinsics, f.pose, f.rgb, f.depth_scale, scratch=scratch)  # the last frame's held meanwhile
            times.append(time.perf_counter() - t)
        return out[0], times

    # as push_depth calls it (positions, pixel indices and the kernel's metres reused from frame to frame), and with all new arrays
    xyz, times = timed(frames[:30] * 2, {})
    _, fresh = timed(frames[:30] * 2)
    live = LiveCloud(keep=10)
    _push(live, frames[0])
    pushes = []
    for f in frames[:30]:
        t = time.perf_counter()
        _push(live, f)
        pushes.append(time.perf_counter() - t)
    print(f"depth -> points + normals, 512x424 ({len(xyz):,} valid pixels): {statistics.median(times) * 1e3:.2f} ms median "
          f"(all arrays new each frame: {statistics.median(fresh) * 1e3:.2f} ms); "
          f"whole push_depth (+ batches, ring copy): {statistics.median(pushes) * 1e3:.1f} ms median")  # fmt: skip


def _fill(frames, keep):
    live = LiveCloud(keep=keep)
    for k in range(keep):
        _push(live, frames[k % len(frames)])
    return live


def bench_render(frames, keep) -> None:
    live = _fill(frames, keep)
    cam = _camera()
    gp.render_frame(live, cam)
    times = [gp.render_frame(live, cam).stats.time_ms for _ in range(7)]
    print(f"render {keep} frames kept ({live.n_points / 1e6:.1f} M live points), 1280x720: {statistics.median(times):.1f} ms median "
          f"= {1000 / statistics.median(times):.1f} fps")  # fmt: skip


def bench_stream(frames, keep, fps, seconds) -> None:
    live = _fill(frames, keep)
    cam = _camera()
    gp.render_frame(live, cam)
    stop = threading.Event()
    pushed = [0]

    def produce():
        t0 = time.perf_counter()
        k = 0
        while not stop.is_set():
            wait = t0 + k / fps - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            _push(live, frames[k % len(frames)])
            k += 1
            pushed[0] = k

    live.stats.latencies.clear()
    thread = threading.Thread(target=produce, daemon=True)
    t0 = time.perf_counter()
    thread.start()
    drawn, seen, render_ms = 0, live.changes, []
    rss, next_sample = [], t0
    while time.perf_counter() - t0 < seconds:  # as the viewer does: draw again when the cloud changed
        seen = live.wait_frame(seen, timeout=0.1)
        frame = gp.render_frame(live, cam)
        live.drawn(frame)
        render_ms.append(frame.stats.time_ms)
        drawn += 1
        if time.perf_counter() >= next_sample:  # resident memory every 10 s: flat when the ring reuses its chunks
            rss.append((time.perf_counter() - t0, _rss_mb(), pushed[0]))
            next_sample += 10.0
    elapsed = time.perf_counter() - t0
    stop.set()
    thread.join()
    lat = np.array(live.stats.latencies) * 1e3
    print(f"stream {fps:g} frames/s in for {elapsed:.1f} s, {keep} kept ({live.n_points / 1e6:.1f} M live points): "
          f"{pushed[0] / elapsed:.1f} frames/s pushed, {drawn / elapsed:.1f} frames rendered/s (1280x720, "
          f"{statistics.median(render_ms):.0f} ms median), push-to-pixels latency median {np.median(lat):.0f} ms, "
          f"p99 {np.percentile(lat, 99):.0f} ms ({len(lat)} pushes seen)")  # fmt: skip
    if len(rss) > 2:
        later = [mb for t, mb, _ in rss if t >= 10.0]
        print(f"resident memory over the stream: {rss[1][1]:.0f} MB at {rss[1][0]:.0f} s ({rss[1][2]} frames pushed), "
              f"{rss[-1][1]:.0f} MB at {rss[-1][0]:.0f} s ({rss[-1][2]} frames), max {max(later):.0f} MB, "
              f"min {min(later):.0f} MB after 10 s")  # fmt: skip


def bench_snapshot(frames, keep) -> None:
    warm = _fill(frames, 8)  # above one batch (SNAPSHOT_BATCH): the tree shaped first, leaves split; JIT warm-up
    warm.snapshot()
    for k in range(8):
        _push(warm, frames[(k + 8) % len(frames)])  # (with --keep under 16 fewer frames are made)
    warm.snapshot()  # and a second one: stored points moved
    live = _fill(frames, keep)
    from gigapoint.bench.report import machine_pages, pages_since

    pages = machine_pages()
    t = time.perf_counter()
    n = live.snapshot()
    dt = time.perf_counter() - t
    new = pages_since(pages)
    print(f"snapshot of {keep} frames: {n:,} points in {dt:.2f} s = {n / dt / 1e6:.1f} M points/s; "
          f"new pages {new['alloc_mib']:.0f} MiB, given back to the host {new['reported_mib']:.0f} MiB")  # fmt: skip
    for k in range(keep):  # as many new frames, then a second snapshot into the same octree (it accumulates)
        _push(live, frames[(k + len(frames) // 2) % len(frames)])
    spilled = live.snapshots.spilled
    t = time.perf_counter()
    n = live.snapshot()
    dt = time.perf_counter() - t
    print(f"second snapshot of {keep} frames into the same octree: {n:,} points in {dt:.2f} s = {n / dt / 1e6:.1f} M points/s "
          f"({(live.snapshots.spilled - spilled) / n:.2f} points moved between leaves a point added)")  # fmt: skip


def bench_memory(frames, keep) -> None:
    live = LiveCloud(keep=keep)
    for k in range(2 * keep):
        _push(live, frames[k % len(frames)])
    a = _rss_mb()
    for k in range(2 * keep):
        _push(live, frames[k % len(frames)])
    b = _rss_mb()
    print(f"memory: {a:.0f} MB resident after {2 * keep} frames, {b:.0f} MB after {4 * keep} ({keep} kept)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--keep", type=int, default=100)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--parts", nargs="+", default=["depth", "render", "stream", "snapshot", "memory"])
    args = ap.parse_args()
    print(f"CPU: {_cpu()}, {gp.RenderSettings().threads or 'all'} threads")
    _, frames = _frames(min(args.keep, 60))
    for part in args.parts:
        if part == "depth":
            bench_depth(frames)
        elif part == "render":
            bench_render(frames, args.keep)
        elif part == "stream":
            bench_stream(frames, args.keep, args.fps, args.seconds)
        elif part == "snapshot":
            bench_snapshot(frames, args.keep)
        elif part == "memory":
            bench_memory(frames, args.keep)


if __name__ == "__main__":
    main()
