"""A live stream of small frames (a scanner's packets): pushes, ring memory and drawing, with
small frames packed into shared chunks (``live/cloud.PACK_LIMIT``) and as before (a chunk a frame).

    .venv/bin/python benchmarks/bench_live_small_frames.py
    .venv/bin/python benchmarks/bench_live_small_frames.py --sizes 50,384,2000 --frames 2000 --rounds 3

Each size: ``--frames`` frames of that many points pushed into a LiveCloud keeping all of them
(a moving sensor's patches, near each other), then drawn at 1280x720; packed and one chunk a
frame alternately, ``--rounds`` times (medians; numba's compile before, not counted). Reported:
points pushed per second, bytes of ring arrays per point kept, ring chunks and the time of a
frame drawn (the CPU backend) and the ratios.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import gigapoint as gp
from gigapoint.bench import cpu_model, parse_counts
from gigapoint.live import cloud as live_cloud
from gigapoint.live.cloud import LiveCloud


def _frames(n_frames: int, size: int):
    rng = np.random.default_rng(7)
    return [(rng.uniform(-1, 1, (size, 3)) * [2, 2, 0.5] + [0.02 * k, 0, 0], np.full((size, 3), k % 250, np.uint8)) for k in range(n_frames)]


def _ring_bytes(live: LiveCloud) -> int:
    buf = live.buffers_
    return sum(a.nbytes for a in (buf.low, buf.med, buf.high, buf.color, buf.batches, *buf.attributes.values()))


def _run(frames, pack_limit: float) -> dict:
    kept = live_cloud.PACK_LIMIT
    live_cloud.PACK_LIMIT = pack_limit
    try:
        live = LiveCloud(keep=len(frames))
        t = time.perf_counter()
        for xyz, rgb in frames:
            live.push(xyz, rgb)
        push_s = time.perf_counter() - t
    finally:
        live_cloud.PACK_LIMIT = kept
    cam = gp.Camera.fit(live.bounds, view="iso", width=1280, height=720)
    settings = gp.RenderSettings(size_mode="fixed")
    gp.render_frame(live, cam, settings)  # the render cache filled
    t = time.perf_counter()
    for _ in range(5):
        gp.render_frame(live, cam, settings)
    draw_s = (time.perf_counter() - t) / 5
    chunks = int((live.buffers_.batches["count"][: live.buffers_.n_ring] > 0).sum())
    out = {"push": push_s, "draw": draw_s, "bytes": _ring_bytes(live) / live.n_points, "chunks": chunks}
    live.close()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="50,384,2000", help="points a frame, comma-separated")
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    sizes = parse_counts(ap, *(("--sizes", s) for s in args.sizes.split(",")))
    _run(_frames(50, 300), 0.5)  # numba's compile: not counted
    _run(_frames(50, 300), 0.0)
    print(f"{cpu_model()}; {args.frames:,} frames kept, drawn at 1280x720 on the CPU backend")
    for size in sizes:
        frames = _frames(args.frames, size)
        runs: dict[str, list[dict]] = {"packed": [], "a chunk a frame": []}
        for _ in range(args.rounds):
            runs["packed"].append(_run(frames, live_cloud.PACK_LIMIT))
            runs["a chunk a frame"].append(_run(frames, 0.0))
        med = {k: {f: statistics.median(r[f] for r in v) for f in v[0]} for k, v in runs.items()}
        p, c = med["packed"], med["a chunk a frame"]
        n = args.frames * size
        print(
            f"  {size:>5} points a frame: push {n / p['push'] / 1e6:6.2f} M points/s against {n / c['push'] / 1e6:6.2f} ({c['push'] / p['push']:.2f}x);"
            f" ring {p['bytes']:8.1f} bytes a point in {p['chunks']:,.0f} chunks against {c['bytes']:8.1f} in {c['chunks']:,.0f} ({c['bytes'] / p['bytes']:.1f}x less);"
            f" a frame drawn {p['draw'] * 1e3:6.1f} ms against {c['draw'] * 1e3:6.1f} ({c['draw'] / p['draw']:.2f}x)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
