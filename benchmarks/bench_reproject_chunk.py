"""One chunk through ``Reprojection.transformed`` (io/reproject.py), in one process, JIT and
PROJ set-up excluded: the fast path (a control grid within ``--tolerance``) or PROJ for every
point (``--exact``). Prints the median and best of ``--rounds`` and which path ran.

    .venv/bin/python benchmarks/bench_reproject_chunk.py [--points 1000000] [--rounds 7] [--exact]

Compare two trees by running it with ``PYTHONPATH=<tree>/src`` in alternation.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from gigapoint.io.reproject import Reprojection


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--tolerance", type=float, default=1e-4, help="the fast path's bound in metres (a tenth of a 1 mm grid)")
    ap.add_argument("--exact", action="store_true", help="PROJ for every point")
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    n = args.points
    # autzen's area in Oregon Lambert feet, moved to UTM 10N on the same datum (one PROJ operation)
    xyz = np.column_stack([rng.uniform(635_000, 640_000, n), rng.uniform(848_000, 853_000, n), rng.uniform(100, 200, n)])
    moving = Reprojection("EPSG:26910", "EPSG:2992", "bench", args.exact)
    moving.tolerance = None if args.exact else (args.tolerance, args.tolerance)
    moving.transformed(xyz, "bench.las")  # warm-up: kernels compiled, the transformer made
    times = []
    for _ in range(args.rounds):
        t = time.perf_counter()
        moving.transformed(xyz, "bench.las")
        times.append(time.perf_counter() - t)
    path = "exact (PROJ)" if moving.exact_points else "interpolated"
    print(f"{n:,} points, {path}: median {1000 * np.median(times):.1f} ms, best {1000 * min(times):.1f} ms, {n / np.median(times) / 1e6:.2f} M points/s")


if __name__ == "__main__":
    main()
