"""The raster grid's point reads (survey/raster_grid.py) against an earlier revision, in one
process: ``RasterGrid.bilinear``, ``cells_of`` and ground classification's per-chunk step
(survey/ground.py's ``_classified``: the bilinear model and its cell's tolerance), on random
points over a 1 000 x 1 000 cell grid (8 MB a raster), in two orders: ``scan order`` (sorted
by y, nearby points one after another as a file's scan lines hold them: the raster's reads
hit the cache) and ``shuffled`` (every read a miss: memory, not arithmetic, sets the pace).
Base and new alternate round by round, JIT warm-up
excluded; reported: the median of ``--rounds`` in ms and the ratio base / new (> 1: the new code
is faster), after checking that both give the same numbers bit for bit.

    .venv/bin/python benchmarks/bench_raster_grid.py --base c999df4 [--points 2000000] [--rounds 7]

The base's ``src/gigapoint`` is loaded as ``gigapoint_base`` (bench_ab.py's ``load_base``).
"""

from __future__ import annotations

import argparse
import importlib
import tempfile
from pathlib import Path

import numpy as np
from bench_ab import interleaved, load_base  # a sibling script: its folder is sys.path[0]

from gigapoint.core.chunk import PointChunk
from gigapoint.survey import ground
from gigapoint.survey.raster_grid import RasterGrid


def same(a, b) -> bool:
    """Bit-identical results (arrays, or tuples of them)."""
    if isinstance(a, tuple):
        return all(same(x, y) for x, y in zip(a, b, strict=True))
    return np.array_equal(a, b)


def classes_of(classified) -> np.ndarray:
    """The classification ground._classified set: it returns (chunk, the dem at its points) now,
    the chunk alone in revisions before that (c999df4), which a base may be."""
    chunk = classified[0] if isinstance(classified, tuple) else classified
    return chunk.attributes["classification"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="the revision to compare with (git rev)")
    ap.add_argument("--points", type=int, default=2_000_000)
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        load_base(args.base, Path(folder))
        base_chunks, base_ground, base_grid = (importlib.import_module(f"gigapoint_base.{name}") for name in ("core.chunk", "survey.ground", "survey.raster_grid"))
        rng = np.random.default_rng(1)
        cell, shape = 1.0, (1000, 1000)
        # a little beyond the grid on every side: the edge cells carried on
        shuffled = np.column_stack([rng.uniform(-10, 1010, (args.points, 2)) + (637_000.0, 851_000.0), rng.uniform(100, 200, args.points)])
        dem = rng.uniform(120, 180, shape)
        tolerance = rng.uniform(0.5, 5.0, shape)
        grids = {
            "new": RasterGrid((637_000.0, 851_000.0), cell, shape, rows_north=True, measured_from="corner"),
            "base": base_grid.RasterGrid((637_000.0, 851_000.0), cell, shape, rows_north=True, measured_from="corner"),
        }
        print(f"{args.points:,} points, grid {shape[0]} x {shape[1]}, median of {args.rounds} (base {args.base} / this tree)")
        for order, xyz in {"scan order": shuffled[np.argsort(shuffled[:, 1])], "shuffled": shuffled}.items():
            run_cases(order, xyz, grids, dem, tolerance, base_chunks, base_ground, args.rounds)


def run_cases(order: str, xyz, grids: dict, dem, tolerance, base_chunks, base_ground, rounds: int) -> None:
    """Each case by both sides, checked alike, then timed in alternation."""
    classes = np.zeros(len(xyz), np.uint8)
    chunk, base_chunk = PointChunk(xyz, attributes={"classification": classes}), base_chunks.PointChunk(xyz, attributes={"classification": classes})
    cases = {
        "bilinear": {side: (lambda g=g: g.bilinear(dem, xyz)) for side, g in grids.items()},
        "cells_of": {side: (lambda g=g: g.cells_of(xyz)) for side, g in grids.items()},
        "ground _classified": {
            "new": lambda: classes_of(ground._classified(chunk, grids["new"], dem, tolerance, {1: 0, 2: 0, "noise": 0})),
            "base": lambda: classes_of(base_ground._classified(base_chunk, grids["base"], dem, tolerance, {1: 0, 2: 0, "noise": 0})),
        },
    }
    for name, sides in cases.items():
        results = {side: call() for side, call in sides.items()}  # warm-up: kernels compiled
        if not same(results["base"], results["new"]):
            raise SystemExit(f"{name}: the results differ from the base's")
        times = dict(zip(sides, interleaved([(call,) for call in sides.values()], rounds), strict=True))  # (ABBA: neither side always second)
        base_ms, new_ms = (1000 * float(np.median(times[side])) for side in ("base", "new"))
        print(f"  {order:10s} {name:20s} base {base_ms:7.1f} ms  new {new_ms:7.1f} ms  base / new {base_ms / new_ms:.2f}")


if __name__ == "__main__":
    main()
