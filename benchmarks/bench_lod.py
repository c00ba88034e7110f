"""LOD rendering frame rate of a converted demo scene (and the conversion that makes it).

    .venv/bin/python benchmarks/bench_lod.py --points 1000000000 --out /tmp/lod1b --convert --memory-limit 3G
    .venv/bin/python benchmarks/bench_lod.py --out /tmp/lod1b --render --threads 2 [--width 1920 --height 1080]
                                             [--budget 10000000] [--frames 10]

``--convert``: the procedural demo scene (``gigapoint.io.demo_chunks``, generated on the fly:
no input file) is converted into a gigapoint octree in ``--out`` by ``gigapoint.lod.convert``, in a
child process whose peak memory is its maxrss (os.wait4); a small conversion first fills numba's
cache, so JIT compile time is excluded. The demo generation is part of the read phase.

``--render``: the octree is opened (nodes load on demand into the bounded arena) and two views
are drawn at the given size with the default point budget: an overview of the whole town and a
close-up from street level. A tiny frame first compiles the kernels (excluded). For each view
the first frame (cold: its nodes are read from disk into the arena) and then ``--frames``
frames of the same view (warm: everything resident) are timed; fps = 1 / median warm frame; "raster" is the backend's share of it (median).
Reported: points drawn, nodes drawn, nodes loaded into the arena, arena size.
Without ``--convert``/``--render`` both run.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

from gigapoint.bench import run_measured

CHILD = """
import json, sys, tempfile, time
from pathlib import Path
from gigapoint.io import demo_chunks
from gigapoint.lod import convert
a = json.loads(sys.argv[1])
with tempfile.TemporaryDirectory() as d:  # JIT warm-up (numba's on-disk cache)
    convert(demo_chunks(200_000, chunk_size=100_000), Path(d) / "w", memory_limit=a["memory_limit"], partition_points=60_000)
t = time.perf_counter()
r = convert(demo_chunks(a["points"], chunk_size=a["chunk"]), a["out"], memory_limit=a["memory_limit"], overwrite=True, name="demo")
print(json.dumps({"points": r.points, "nodes": r.nodes, "seconds": time.perf_counter() - t, "phases": r.phase_seconds, "first_view": r.first_view_seconds}))
"""


def _du(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def run_convert(args) -> dict:
    child = {"points": args.points, "out": str(args.out), "memory_limit": args.memory_limit, "chunk": args.chunk}
    code, out, err, wall, peak = run_measured([sys.executable, "-c", CHILD, json.dumps(child)])  # (peak: gigapoint.bench.run_measured)
    if code != 0:
        raise SystemExit(f"conversion failed ({code}): {err.decode()[-2000:]}")
    res = json.loads(out.decode().strip().splitlines()[-1])
    res["wall"], res["peak_rss"] = wall, peak
    res["size_bytes"] = _du(Path(args.out))
    return res


def views(oc, width: int, height: int):
    from gigapoint import Camera

    lo, hi = oc.bounds
    cx, cy = (lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2
    ex = hi[0] - lo[0]
    dz = hi[2] - lo[2]
    return {
        "overview": Camera.fit(oc.bounds, view="iso", width=width, height=height),
        # 60 m above the river in the town centre, looking across it at the houses
        "close-up": Camera.look_at(
            (cx - 0.05 * ex, cy + 0.02 * ex, lo[2] + 0.8 * dz),
            (cx + 0.12 * ex, cy + 0.2 * ex, lo[2] + 0.2 * dz),
            width=width,
            height=height,
        ),
    }


def run_render(args) -> list[dict]:
    import numpy as np

    from gigapoint import Camera, RenderSettings, render_frame
    from gigapoint.lod import open_octree

    t = time.perf_counter()
    oc = open_octree(args.out)
    t_open = time.perf_counter() - t
    s = RenderSettings(backend="cpu", threads=args.threads, point_budget=args.budget, size_mode="fixed")  # one-pixel points
    render_frame(oc, Camera.fit(oc.bounds, width=64, height=48), s)  # JIT warm-up
    oc.arena = None  # the warm-up's arena is not measured
    rows = []
    for name, cam in views(oc, args.width, args.height).items():
        loads0 = oc.arena.loads if oc.arena is not None else 0
        t = time.perf_counter()
        f = render_frame(oc, cam, s)
        cold = time.perf_counter() - t
        loaded = oc.arena.loads - loads0
        times, raster = [], []
        for _ in range(args.frames):
            t = time.perf_counter()
            f = render_frame(oc, cam, s)
            times.append(time.perf_counter() - t)
            raster.append(f.stats.raster_ms)
        med = statistics.median(times)
        ids, _, total = oc.select_nodes(cam.view(oc.bounds), s)
        rows.append(
            {
                "view": name,
                "fps": 1.0 / med,
                "ms_median": med * 1e3,
                "ms_min": min(times) * 1e3,
                "raster_ms": statistics.median(raster),
                "cold_ms": cold * 1e3,
                "points_drawn": int(f.stats.points_processed),
                "points_selected": int(total),
                "nodes_drawn": int(np.count_nonzero(oc.nodes["count"][ids] > 0)),
                "nodes_loaded": int(loaded),
                "arena_points": int(oc.arena.n_points),
                "covered": float((~f.empty).mean()),
            }
        )
        if args.save_images:
            from PIL import Image

            Path(args.save_images).mkdir(parents=True, exist_ok=True)
            Image.fromarray(f.image).save(Path(args.save_images) / f"lod_{name}.png")
    print(f"open: {t_open * 1e3:.0f} ms, {oc.n_points:,} points in {len(oc.keys):,} nodes")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=20_000_000)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--convert", action="store_true")
    ap.add_argument("--render", action="store_true")
    ap.add_argument("--memory-limit", default="3G")
    ap.add_argument("--chunk", type=int, default=2_000_000, help="demo points generated per chunk")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--budget", type=int, default=10_000_000)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--save-images", default=None, help="folder for the last frame of each view (PNG)")
    ap.add_argument("--json", action="store_true", help="print the results as JSON too")
    args = ap.parse_args()
    both = not (args.convert or args.render)
    result = {}
    if args.convert or both:
        c = run_convert(args)
        result["convert"] = c
        print(
            f"convert {c['points']:,} points -> {c['nodes']:,} nodes: {c['seconds']:.1f} s in convert() "
            f"({c['points'] / c['seconds'] / 1e6:.2f} M points/s), process {c['wall']:.1f} s, "
            f"peak memory {c['peak_rss'] / 2**20:.0f} MiB, output {c['size_bytes'] / 1e9:.1f} GB"
        )
        print("  phases (s): " + ", ".join(f"{k} {v:.1f}" for k, v in (c["phases"] or {}).items()))
        if c.get("first_view") is not None:
            print(f"  viewable after {c['first_view']:.2f} s (OUT's preview; the octree after {c['seconds']:.1f} s)")
    if args.render or both:
        import numba

        numba.set_num_threads(args.threads)
        rows = run_render(args)
        result["render"] = rows
        print(f"{args.width}x{args.height}, point budget {args.budget:,}, {args.threads} threads, median of {args.frames} warm frames")
        hdr = f"{'view':<10} {'fps':>6} {'ms med':>8} {'ms min':>8} {'raster':>7} {'cold ms':>8} {'points drawn':>13} {'nodes drawn':>11} {'nodes loaded':>12} {'covered':>8}"
        print(hdr)
        print("-" * len(hdr))
        for r in rows:
            print(
                f"{r['view']:<10} {r['fps']:>6.1f} {r['ms_median']:>8.1f} {r['ms_min']:>8.1f} {r['raster_ms']:>7.1f} {r['cold_ms']:>8.0f} "
                f"{r['points_drawn']:>13,} {r['nodes_drawn']:>11,} {r['nodes_loaded']:>12,} {r['covered']:>8.1%}"
            )
    if args.json:
        print(json.dumps(result))


if __name__ == "__main__":
    main()
