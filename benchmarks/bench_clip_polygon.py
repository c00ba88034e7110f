"""Points per second of the clip polygon's point-in-polygon test (io/polygon.py), for a 4-vertex
square and a 10 000-vertex wiggly site boundary, on uniformly spread points of which about half
fall inside.

    .venv/bin/python benchmarks/bench_clip_polygon.py [--points 20000000] [--repeat 5] [--threads N]

Each polygon's test runs once on a few points first (JIT compile and the y buckets, excluded);
then ``--repeat`` times over all points: the median is reported, with the buckets' count and how
many edges a point's bucket holds on average (all the edges of a 10 000-vertex polygon would be
10 000 tests a point).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np


def polygons() -> dict:
    """{name: GeoJSON geometry}: a square, and a star of 10 000 vertices radius 50 to 150."""
    t = np.linspace(0, 2 * np.pi, 10_000, endpoint=False)
    r = 100 + 50 * np.sin(37 * t)
    return {
        "4 vertices": {"type": "Polygon", "coordinates": [[[-100, -100], [100, -100], [100, 100], [-100, 100]]]},
        "10 000 vertices": {"type": "Polygon", "coordinates": [np.column_stack([r * np.cos(t), r * np.sin(t)]).tolist()]},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=20_000_000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    if args.threads:
        import numba

        numba.set_num_threads(args.threads)
    from gigapoint.io.polygon import clip_polygon_of

    xyz = np.random.default_rng(1).uniform(-150, 150, (args.points, 3))
    results = {}
    for name, geometry in polygons().items():
        polygon = clip_polygon_of(geometry, name)
        polygon.inside(xyz[:1000])  # compile, bucket
        seconds = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            kept = polygon.inside(xyz)
            seconds.append(time.perf_counter() - t)
        starts, _members = polygon.buckets()
        results[name] = {
            "points_per_s": round(args.points / statistics.median(seconds)),
            "kept": int(np.count_nonzero(kept)),
            "buckets": len(starts) - 1,
            "edges_per_bucket": round(float(np.mean(np.diff(starts))), 1),
        }
    print(json.dumps({"points": args.points, "results": results}, indent=1))


if __name__ == "__main__":
    main()
