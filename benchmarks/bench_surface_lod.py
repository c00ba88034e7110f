"""Points read and seconds of ``gp.change`` of a converted octree against itself at coarse gsds:
its levels down to a quarter-pixel spacing (the default, survey/change.py's SURFACE_SPACING)
against every node (``full=True``), the two alternated ``--repeat`` times after a warm-up run of
each (other processes share the cores); and how far the default's surface lies below every point's.

    .venv/bin/python benchmarks/bench_surface_lod.py [--points 5000000] [--gsd 4 8] [--repeat 3] [--octree DIR]

The demo scene (``gp.demo(points)``, 1 000 x 1 000 units) is converted to DIR first (once: an
existing octree there is reused).
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

import gigapoint as gp
from gigapoint.io.filters import PointFilter
from gigapoint.lod.query import deepest_level, points_meeting
from gigapoint.survey.change import SURFACE_SPACING


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=5_000_000)
    ap.add_argument("--gsd", type=float, nargs="+", default=[4.0, 8.0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--octree", type=Path, default=Path(tempfile.gettempdir()) / "bench_surface_lod")
    args = ap.parse_args()
    if not args.octree.exists():
        gp.convert(gp.demo(args.points, colors="rgba"), args.octree)
    octree = gp.open(args.octree)
    levels = np.bincount(octree.levels, weights=octree.counts).astype(int).tolist()
    print(f"{octree!r}: points per level {levels}, root spacing {octree.meta['spacing']:.4g}")
    for full in (False, True):  # numba's compile: not timed (else the first run holds it: --repeat 1 read 0.01x)
        gp.change(args.octree, args.octree, args.gsd[0], full=full)
    for gsd in args.gsd:
        read = sum(map(len, points_meeting(octree, PointFilter().meets, SURFACE_SPACING * gsd)))
        seconds: dict = {"levels": [], "every node": []}
        surfaces: dict = {}
        for _ in range(args.repeat):
            for name, full in (("levels", False), ("every node", True)):
                start = time.perf_counter()
                result = gp.change(args.octree, args.octree, gsd, full=full)
                seconds[name].append(time.perf_counter() - start)
                surfaces[name] = result.before
        sampled, every = surfaces["levels"], surfaces["every node"]
        both = ~np.isnan(sampled) & ~np.isnan(every)
        below = (every - sampled)[both]
        print(json.dumps({
            "gsd": gsd, "levels_read": f"0-{deepest_level(octree, SURFACE_SPACING * gsd)}", "points_read": read, "of": octree.n_points,
            "seconds_levels": [round(s, 2) for s in seconds["levels"]], "seconds_every_node": [round(s, 2) for s in seconds["every node"]],
            "median_speedup": round(statistics.median(seconds["every node"]) / statistics.median(seconds["levels"]), 2),
            "pixels_within_0.1": round(float((np.abs(below) <= 0.1).mean()), 4), "pixels_within_0.5": round(float((np.abs(below) <= 0.5).mean()), 4),
            "pixels_empty_in_levels_only": int((np.isnan(sampled) & ~np.isnan(every)).sum()),
        }))  # fmt: skip


if __name__ == "__main__":
    main()
