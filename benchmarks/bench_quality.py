"""Cost of each image-quality pass relative to the plain render, same run, 1920x1080.

    .venv/bin/python benchmarks/bench_quality.py [--points 2000000] [--repeat 5] [--threads 2]

JIT compilation is excluded (one warm-up render per configuration); each configuration is
timed interleaved with the plain render (median of ``--repeat`` each), so the ratio holds
even on a machine shared with other work. Screen-space passes are also timed alone on the plain
frame's visibility buffer.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import gigapoint as gp


def _median_ms(fn, repeat):
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1000.0)
    return statistics.median(times)


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
    args = ap.parse_args()
    cloud = gp.demo(args.points)
    try:
        from gigapoint.render.normals import estimate_normals

        if "nx" not in cloud.attributes:
            estimate_normals(cloud, store=True)
    except ImportError:
        pass
    cam = gp.Camera.fit(cloud.bounds, view=(-60.0, 35.0), width=args.width, height=args.height, fov=40.0, margin=0.6)
    base = gp.RenderSettings(backend="cpu", threads=args.threads)
    print(f"{cloud.n_points:,} points, {args.width}x{args.height}, threads={args.threads or 'all'}")
    names = args.only.split(",") if args.only else list(CONFIGS)
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
        print(f"{name:28s} {c:8.1f} ms  plain {p:6.1f} ms  {c / p:5.2f}x")
    # screen-space passes alone
    from gigapoint.render.passes.edl import eye_dome_lighting
    from gigapoint.render.passes.holes import fill_holes

    f = gp.render_frame(cloud, cam, base)
    vis = f.visibility.reshape(-1)
    col = np.ascontiguousarray(f.image).reshape(-1, 4).view(np.uint32).reshape(-1)
    print(f"  (covered pixels: {f.stats.visible_pixels:,})")
    print(f"edl pass alone             {_median_ms(lambda: eye_dome_lighting(vis, col, args.width, args.height), args.repeat):8.2f} ms")
    for level in (1, 2, 3):
        print(
            f"fill_holes={level} pass alone    {_median_ms(lambda lv=level: fill_holes(vis, args.width, args.height, lv), args.repeat):8.2f} ms"
        )
    print(f"fill_holes=3 foveated alone {_median_ms(lambda: fill_holes(vis, args.width, args.height, 3, True), args.repeat):8.2f} ms")


if __name__ == "__main__":
    main()
