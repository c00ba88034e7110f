"""Small batches into the progressive octree (``add``) and a live cloud (``push``): what a call costs.

    .venv/bin/python benchmarks/bench_small_batches.py --sizes 50,1000,20000 --points 200000
    NUMBA_THREADING_LAYER=omp OMP_WAIT_POLICY=passive .venv/bin/python benchmarks/bench_small_batches.py

A program producing points (a sensor's packets, a simulation's steps) hands them over in
batches of ``--sizes`` points, ``--points`` in all; each size is timed as gigapoint runs it
(batches below ``core/threads.SMALL_BATCH`` on the calling thread alone, but for ``add`` where
idle threads take up work at once: spinning OpenMP, TBB) and as before that rule (every batch on all of numba's threads:
SMALL_BATCH 0), alternately, ``--rounds`` times (medians; numba's compile before, not
counted). Reported: points/s and the ratio. On OpenMP (``NUMBA_THREADING_LAYER=omp``: where
the tbb wheel is missing) run it with and without ``OMP_WAIT_POLICY=passive`` (``gigapoint
view`` sets it; a Python program has OpenMP's default, spinning a while).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numba

from gigapoint.bench import cpu_model, parse_counts
from gigapoint.core import threads
from gigapoint.io import demo_arrays
from gigapoint.live.cloud import LiveCloud
from gigapoint.lod.progressive import ProgressiveOctree


def _fill_octree(xyz, rgb, size: int) -> None:
    cloud = ProgressiveOctree("bench")
    for i in range(0, len(xyz), size):
        cloud.add(xyz[i : i + size], rgb[i : i + size])
    cloud.close()


def _fill_live(xyz, rgb, size: int) -> None:
    cloud = LiveCloud()  # its ring of 100 frames: a push replaces the oldest, as a sensor's stream does
    for i in range(0, len(xyz), size):
        cloud.push(xyz[i : i + size], rgb[i : i + size])
    cloud.close()


def _timed(fill, xyz, rgb, size: int, small_batch: int) -> float:
    kept = threads.SMALL_BATCH
    threads.SMALL_BATCH = small_batch
    try:
        t = time.perf_counter()
        fill(xyz, rgb, size)
        return time.perf_counter() - t
    finally:
        threads.SMALL_BATCH = kept


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="50,1000,5000,20000,100000", help="points a call, comma-separated")
    ap.add_argument("--points", type=int, default=400_000, help="points in all, per size (at most 2 000 calls)")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    sizes = parse_counts(ap, *(("--sizes", s) for s in args.sizes.split(",")))
    xyz, rgb, _ = demo_arrays(args.points, seed=5)
    for fill in (_fill_octree, _fill_live):  # numba's compile: not counted
        for size in sizes:  # the smallest batches take paths of their own (add of 50 points compiled 6 s in)
            for small_batch in (threads.SMALL_BATCH, 0):  # two calls of each size: at 100 000, 4 were a whole timed round
                _timed(fill, xyz[: 2 * size], rgb[: 2 * size], size, small_batch)
    idle = "take up work at once" if threads.threads_awake() else "sleep"
    print(f"{cpu_model()}; numba {numba.threading_layer()} layer, {numba.get_num_threads()} threads whose idle ones {idle}; SMALL_BATCH {threads.SMALL_BATCH:,}")
    for name, fill in (("ProgressiveOctree.add", _fill_octree), ("LiveCloud.push", _fill_live)):
        for size in sizes:
            n = min(args.points, 2000 * size)
            times: dict[str, list[float]] = {"now": [], "all threads": []}
            for _ in range(args.rounds):
                times["now"].append(_timed(fill, xyz[:n], rgb[:n], size, threads.SMALL_BATCH))
                times["all threads"].append(_timed(fill, xyz[:n], rgb[:n], size, 0))
            med = {k: statistics.median(v) for k, v in times.items()}
            calls = -(-n // size)
            print(
                f"  {name} of {size:>7,} points: {n / med['now'] / 1e6:7.3f} M points/s ({med['now'] / calls * 1e3:.3f} ms a call),"
                f" every batch on all threads {n / med['all threads'] / 1e6:7.3f} M points/s: {med['all threads'] / med['now']:.2f}x"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
