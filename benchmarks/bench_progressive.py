"""The progressive octree (issue #18): insertion rate, loading overhead, first image, frames while loading, memory.

    .venv/bin/python benchmarks/bench_progressive.py                        # 8 M points, every part
    .venv/bin/python benchmarks/bench_progressive.py --points 20M --parts insert load

- ``insert``: points already decoded (the demo town, in its generator's order, which spreads
  every batch over the whole town, and in scan order: 50 m strips), inserted in batches of 1 M
  with the root cube given (as from LAS headers); JIT warm-up excluded. Reported: points/s,
  voxels per point, memory per point against gigapoint's quantized layout of the same points
  (16 bytes + the attributes).
- ``load``: the same points written as LAZ and LAS (scan order); decoding them alone (every
  chunk of ``gigapoint.io.read_chunks``) against ``gigapoint.open(..., progressive=True)`` to
  completion, alternately, in one process: the ratio is what LOD costs loading.
- ``first``: seconds from ``gigapoint.demo(10**9, progressive=True)`` to its first image with
  points (1920x1080), then the loader is closed.
- ``frames``: median frame time at 1920x1080 with a 10 M budget while the demo loads, and of
  the same octree once loaded.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import gigapoint as gp
from gigapoint.bench import parse_count
from gigapoint.io import demo_arrays, read_chunks
from gigapoint.lod.progressive import ProgressiveOctree


def _cpu() -> str:
    out = subprocess.run(["lscpu"], check=False, capture_output=True, text=True).stdout
    return next((line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("Model name")), "?")


def _scan_order(xyz):
    return np.lexsort((xyz[:, 0], np.floor(xyz[:, 1] / 50.0)))


def _memory(o: ProgressiveOctree) -> int:
    pool = o.pool
    arrays = [pool.low, pool.med, pool.high, pool.color, *pool.attributes.values(), pool.batches, pool.chunk_next, pool.chunk_node]
    arrays += [o.vox_key, o.vox_slot, o.vox_sum, o.vox_first, o._hkeys, o._hvals, o.key, o.children, o.cmin, o.first_chunk, o.last_chunk]
    return sum(a.nbytes for a in arrays)


def bench_insert(n: int, batch: int) -> None:
    xyz, rgba, attrs = demo_arrays(n, seed=1)
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    cube = (lo - 0.5, float(np.max(hi - lo)) + 1.0)
    warm = ProgressiveOctree("warm", cube=cube)
    warm.add(xyz[:300_000], rgba[:300_000], **{a: v[:300_000] for a, v in attrs.items()})
    layout = 16 + sum(v.dtype.itemsize for v in attrs.values())
    for name, order in (("generator order", np.arange(n)), ("scan order", _scan_order(xyz))):
        x, c, at = xyz[order], rgba[order], {a: v[order] for a, v in attrs.items()}
        o = ProgressiveOctree("bench", cube=cube, capacity=n)
        t = time.perf_counter()
        for s in range(0, n, batch):
            o.add(x[s : s + batch], c[s : s + batch], **{a: v[s : s + batch] for a, v in at.items()})
        dt = time.perf_counter() - t
        mem = _memory(o)
        print(f"insert, {name}: {n / dt / 1e6:.2f} M points/s ({dt:.2f} s), {o.n_voxels / n:.2f} voxels a point, "
              f"{mem / n:.1f} bytes a point = {mem / n / layout:.2f}x the quantized layout ({layout} B)")  # fmt: skip


def _write(path: Path, xyz, rgba, attrs) -> Path:
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [0.001] * 3
    header.offsets = np.floor(xyz.min(axis=0))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rgb = rgba[:, :3].astype(np.uint16) * 257
    las.red, las.green, las.blue = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    las.intensity, las.classification = attrs["intensity"], attrs["classification"]
    las.write(str(path))
    return path


def bench_load(n: int, rounds: int) -> None:
    xyz, rgba, attrs = demo_arrays(n, seed=2)
    order = _scan_order(xyz)
    with tempfile.TemporaryDirectory() as tmp:
        for suffix in ("laz", "las"):
            path = _write(Path(tmp) / f"town.{suffix}", xyz[order], rgba[order], {a: v[order] for a, v in attrs.items()})
            gp.open(path, progressive=True).wait()  # warm-up: JIT, page cache
            decode, load = [], []
            for _ in range(rounds):
                t = time.perf_counter()
                for _chunk in read_chunks(path, 1_000_000):
                    pass
                decode.append(time.perf_counter() - t)
                t = time.perf_counter()
                cloud = gp.open(path, progressive=True)
                cloud.wait()
                load.append(time.perf_counter() - t)
                cloud.close()
            d, ld = statistics.median(decode), statistics.median(load)
            print(f"load {suffix.upper()} {n / 1e6:g} M: decode alone {d:.2f} s, progressive to completion {ld:.2f} s = {ld / d:.2f}x")


def bench_first(n: int) -> None:
    cam = None
    t = time.perf_counter()
    cloud = gp.demo(n, progressive=True)
    while True:
        if cloud.n_points:
            cam = cam or gp.Camera.fit(cloud.bounds, view="iso", width=1920, height=1080)
            frame = gp.render_frame(cloud, cam)
            if frame.stats.visible_pixels:
                break
        time.sleep(0.005)
    print(f"first image of demo({n:,}) progressive: {time.perf_counter() - t:.2f} s after open ({frame.stats.points_processed:,} points drawn)")
    cloud.close()


def bench_frames(n: int) -> None:
    cloud = gp.demo(n, progressive=True)
    while cloud.n_points == 0:
        time.sleep(0.01)
    s = gp.RenderSettings(point_budget=10_000_000)
    times = []
    while cloud.loading:
        cam = gp.Camera.fit(cloud.bounds, view="iso", width=1920, height=1080)
        t = time.perf_counter()
        gp.render_frame(cloud, cam, s)
        times.append(time.perf_counter() - t)
    cam = gp.Camera.fit(cloud.bounds, view="iso", width=1920, height=1080)
    after = []
    for _ in range(7):
        t = time.perf_counter()
        gp.render_frame(cloud, cam, s)
        after.append(time.perf_counter() - t)
    m, a = statistics.median(times), statistics.median(after)
    print(f"frames of demo({n:,}) at 1920x1080, 10 M budget: while loading {len(times)} frames, median {m * 1e3:.1f} ms "
          f"({1 / m:.1f} fps; loaded in {cloud.loader.finished_at - cloud.loader.started:.1f} s); once loaded {a * 1e3:.1f} ms ({1 / a:.1f} fps)")  # fmt: skip


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", default="8M")
    ap.add_argument("--batch", default="1M")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--parts", nargs="+", default=["insert", "load", "first", "frames"])
    args = ap.parse_args(argv)
    n = parse_count(args.points)
    print(f"{_cpu()}, 2 cores; {n:,} points")
    if "insert" in args.parts:
        bench_insert(n, parse_count(args.batch))
    if "load" in args.parts:
        bench_load(n, args.rounds)
    if "first" in args.parts:
        bench_first(10**9)
    if "frames" in args.parts:
        bench_frames(n)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
