"""Cost of each image-quality pass relative to the plain render, same run, 1920x1080.

    .venv/bin/python benchmarks/bench_quality.py [--points 2000000] [--repeat 5] [--threads 2] [--markdown]

JIT compilation is excluded (one warm-up render per configuration); each configuration is
timed interleaved with the plain render (median of ``--repeat`` each), and the ratio is the
median of the per-pair ratios (each frame over the plain frame drawn just before it), so it
holds even on a machine shared with other work; the ratio of the fastest frames of each is
printed too (what a quiet machine would show). Screen-space passes are also timed alone on the plain
frame's visibility buffer. ``--markdown`` also prints the results as a table for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import gigapoint as gp


def _median_ms(fn, repeat):
    """(median, min) ms of ``repeat`` calls after a warm-up call."""
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1000.0)
    return statistics.median(times), min(times)


CONFIGS = {
    "plain": {},
    "color_mode=elevation": {"color_mode": "elevation", "colormap": "turbo"},
    "color_mode=classification": {"color_mode": "classification"},
    "edl": {"edl": True},
    "fill_holes=1": {"fill_holes": 1},
    "fill_holes=3": {"fill_holes": 3},
    "fill_holes=3 foveated": {"fill_holes": 3, "fill_holes_foveated": True},
    "hqs": {"hqs": True},
    "point_size=3": {"point_size": 3},
    "point_size=5 round": {"point_size": 5, "point_shape": "round"},
    "supersample=2": {"supersample": 2},
    "stereo=side-by-side": {"stereo": "side-by-side"},
    "lighting": {"lighting": True},
}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=2_000_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--only", default=None, help="comma-separated config names")
    ap.add_argument("--markdown", action="store_true", help="also print a markdown table of the results")
    args = ap.parse_args()
    cloud = gp.demo(args.points)
    try:
        from gigapoint.render.normals import estimate_normals

        if "nx" not in cloud.attributes:
            estimate_normals(cloud, store=True)
    except ImportError:
        pass
    cam = gp.Camera.fit(cloud.bounds, view=(-60.0, 35.0), width=args.width, height=args.height, fov=40.0, margin=0.6)
    base = gp.RenderSettings(backend="cpu", threads=args.threads, size_mode="fixed")  # passes over the one-pixel render
    print(f"{cloud.n_points:,} points, {args.width}x{args.height}, threads={args.threads or 'all'}")
    names = args.only.split(",") if args.only else list(CONFIGS)
    rows = []  # (configuration, ms, plain ms in the same run, median pair ratio, ratio of the minimums)
    plain_fn = lambda: gp.render_frame(cloud, cam, base)
    plain_fn()
    for name in names:
        if name == "plain":
            continue
        try:
            s = base.replace(**CONFIGS[name])
            fn = lambda s=s: gp.render_frame(cloud, cam, s)
            fn()  # warm-up (JIT compile, caches)
        except gp.GigapointError as exc:  # a pass not available (e.g. lighting without scipy)
            print(f"{name:28s} skipped: {exc}")
            continue
        # interleaved with the plain render, so load from other processes hits both alike
        tp, tc = [], []
        for _ in range(args.repeat):
            for f, acc in ((plain_fn, tp), (fn, tc)):
                t = time.perf_counter()
                f()
                acc.append((time.perf_counter() - t) * 1000.0)
        p, c = statistics.median(tp), statistics.median(tc)
        ratios = [b / a for a, b in zip(tp, tc)]
        r, best = statistics.median(ratios), min(tc) / min(tp)
        print(f"{name:28s} {c:8.1f} ms  plain {p:6.1f} ms  {r:5.2f}x (fastest frames {best:.2f}x)")
        rows.append((name, c, p, r, best))
    # screen-space passes alone
    from gigapoint.backends.numba_cpu.passes import eye_dome_lighting, fill_holes

    f = gp.render_frame(cloud, cam, base)
    vis = f.visibility.reshape(-1)
    col = np.ascontiguousarray(f.image).reshape(-1, 4).view(np.uint32).reshape(-1)
    print(f"  (covered pixels: {f.stats.visible_pixels:,})")
    alone = {"edl": _median_ms(lambda: eye_dome_lighting(vis, col, args.width, args.height), args.repeat)}
    for level in (1, 2, 3):
        alone[f"fill_holes={level}"] = _median_ms(lambda lv=level: fill_holes(vis, args.width, args.height, lv), args.repeat)
    alone["fill_holes=3 foveated"] = _median_ms(lambda: fill_holes(vis, args.width, args.height, 3, True), args.repeat)
    for name, (ms, lo) in alone.items():
        print(f"{name + ' pass alone':33s} {ms:8.2f} ms (min {lo:.2f})")
    if args.markdown:
        print(f"\n{cloud.n_points:,} points, {args.width}x{args.height}, threads={args.threads or 'all'}, median of {args.repeat}\n")
        print(
            "| configuration | frame ms | plain frame ms (same run) | ratio (median of pairs) | ratio of the fastest frames |\n|---|---:|---:|---:|---:|"
        )
        for name, c, p, r, best in rows:
            print(f"| {name} | {c:.1f} | {p:.1f} | {r:.2f}x | {best:.2f}x |")
        print("\n| pass alone, on the plain frame's visibility buffer | median ms | min ms |\n|---|---:|---:|")
        for name, (ms, lo) in alone.items():
            print(f"| {name} | {ms:.2f} | {lo:.2f} |")


if __name__ == "__main__":
    main()
