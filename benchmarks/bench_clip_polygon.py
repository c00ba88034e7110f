"""Points per second of the clip polygon's point-in-polygon test (io/polygon.py), for a 4-vertex
square and a 10 000-vertex wiggly site boundary, on uniformly spread points of which about half
fall inside.

    .venv/bin/python benchmarks/bench_clip_polygon.py [--points 20000000] [--repeat 5] [--threads N]

Each polygon's test runs once on a few points first (JIT compile and the y buckets, excluded);
then ``--repeat`` times over all points: the median is reported, with the buckets' count and how
many edges a point's bucket holds on average (all the edges of a 10 000-vertex polygon would be
10 000 tests a point). Then the seconds ``check_holes`` takes over a 90 x 90 grid of touching
square holes (8,100 holes sharing edges: the median of ``--repeat``).
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
    results["8,100 touching holes"] = {"check_holes_s": round(_hole_check_seconds(args.repeat), 3)}
    print(json.dumps({"points": args.points, "results": results}, indent=1))


def _hole_check_seconds(repeat: int) -> float:
    """The median seconds of io.polygon.check_holes over a 90 x 90 grid of unit square holes that share their edges, in a square outline."""
    from gigapoint.io.polygon import ClipPolygon, check_holes

    outline = np.array([[-1, -1], [91, -1], [91, 91], [-1, 91]], float)
    holes = [np.array([[i, j], [i + 1, j], [i + 1, j + 1], [i, j + 1]], float) for i in range(90) for j in range(90)]
    polygon = ClipPolygon([[outline, *holes]], "grid")
    check_holes(polygon)  # (compile)
    seconds = []
    for _ in range(repeat):
        t = time.perf_counter()
        check_holes(polygon)
        seconds.append(time.perf_counter() - t)
    return statistics.median(seconds)


if __name__ == "__main__":
    main()
