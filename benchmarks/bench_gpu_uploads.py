"""Frames drawn by the wgpu backend while a progressive octree loads: what re-sending its changed
chunks costs, with changed chunks close together sent in one write (``merge_gap_bytes``, by default
``MERGE_GAP_BYTES``) and each run of touching chunks on its own (gap 0), loads alternating in
one process:

    .venv/bin/python benchmarks/bench_gpu_uploads.py --points 4M --width 640 --height 360   # lavapipe
    python3 benchmarks/bench_gpu_uploads.py --points 10M                                     # a real GPU

The demo town loads progressively (its generator spreads every batch over the whole town, so
most chunks change between two frames: the hard case); frames are drawn back to back at a
10 M budget until it is loaded. Reported per setting: median frame time and fps, the
``write_buffer`` calls and MiB a frame (means), the share of frame time spent re-sending. A small load
first compiles the kernels (excluded).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

import gigapoint as gp
from gigapoint.bench import cpu_model, one_line_errors, parse_counts


def frames_while_loading(n: int, width: int, height: int, drawer) -> dict:
    """Per frame drawn while the demo of ``n`` points loads: (seconds, writes, bytes, refresh seconds)."""
    settings = gp.RenderSettings(point_budget=10_000_000, backend="wgpu")
    stats = ("refresh_writes", "uploaded", "refresh_seconds")
    rows = []
    cloud = gp.demo(n, progressive=True)
    while cloud.n_points == 0:
        time.sleep(0.01)
    while cloud.loading:
        cam = gp.Camera.fit(cloud.bounds, view="iso", width=width, height=height)
        before = drawer.memory
        t = time.perf_counter()
        gp.render_frame(cloud, cam, settings)
        after = drawer.memory
        rows.append((time.perf_counter() - t, *(after[k] - before[k] for k in stats)))
    cloud.close()
    r = np.array(rows) if rows else np.zeros((1, 4))
    # writes and bytes: means (a frame after the pool grew uploads it whole, not as re-sends)
    return {"frames": len(rows), "ms": 1e3 * float(np.median(r[:, 0])), "writes": float(np.mean(r[:, 1])),
            "mib": float(np.mean(r[:, 2])) / 2**20, "share": float(r[:, 3].sum() / max(r[:, 0].sum(), 1e-9))}  # fmt: skip


@one_line_errors
def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", default="4M")
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--rounds", type=int, default=2, help="loads per setting, alternating")
    args = ap.parse_args(argv)
    (n,) = parse_counts(ap, ("--points", args.points))
    from gigapoint.backends.wgpu import memory
    from gigapoint.render.backend import get_backend

    drawer = get_backend("wgpu")
    print(f"{cpu_model()}; {drawer.describe()}")
    frames_while_loading(200_000, 320, 240, drawer)  # compiles the kernels
    cache = drawer.ctx.cache
    results: dict[int, list[dict]] = {memory.MERGE_GAP_BYTES: [], 0: []}
    for _ in range(args.rounds):
        for gap, runs in results.items():
            cache.merge_gap_bytes = gap
            runs.append(frames_while_loading(n, args.width, args.height, drawer))
    cache.merge_gap_bytes = memory.MERGE_GAP_BYTES
    for gap, runs in results.items():
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        print(f"demo({n:,}) loading, {args.width}x{args.height}, 10 M budget, changed chunks merged across gaps up to {gap // 1024} KiB: "
              f"{med['ms']:.1f} ms a frame ({1e3 / med['ms']:.1f} fps) over {med['frames']:.0f} frames, {med['writes']:.0f} writes "
              f"and {med['mib']:.1f} MiB a frame, {med['share']:.0%} of frame time re-sending (medians of {len(runs)} loads)")  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
